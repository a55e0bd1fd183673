"""Each EDS states what its emulated drive does: a PDO mapping that is remapped is declared
modifiable (Granularity 8), an object declared writable takes another value, one that
takes none is read-only; the files load in canopen without a warning and their comments
name files that exist.

Tier 2 (no bus, no thread): the drive by scripted exchange (tests/drivers/test_node.py's
bench), the EDS as canopen and as an INI file read it.
"""

from __future__ import annotations

import configparser
import itertools
import logging
import re
import warnings
from pathlib import Path
from typing import Any

import canopen
import pytest

from drivers.drive_spec import DriveKind, DriveSpec
from drivers.drives import drive_node
from rakectl.core.motor_model import R_MOTOR_DEFAULT
from rakectl.protocol.nmt import NmtCommand
from tests.drivers.test_node import Bench, sdo_download, sdo_upload

ROOT = Path(__file__).resolve().parents[2]
KINDS = list(DriveKind)
PDO_COMMUNICATION = (0x1400, 0x1800, 0x1801)
READ_ONLY = 0x06010002
NODE_ID = 1
TPDO2 = 0x280 + NODE_ID


def bench(kind: DriveKind) -> Bench:
    return Bench(drive_node(DriveSpec(NODE_ID, kind, R_MOTOR_DEFAULT, serial_number=1,
                                      controller_node_id=10)))


def eds_ini(kind: DriveKind) -> configparser.ConfigParser:
    ini = configparser.ConfigParser(interpolation=None)  # option names in lower case
    ini.read(kind.eds_path)
    return ini


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.value)
def test_each_eds_loads_in_canopen_without_a_warning(kind: DriveKind,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    with warnings.catch_warnings(), caplog.at_level(logging.WARNING, logger="canopen"):
        warnings.simplefilter("error")
        canopen.import_od(str(kind.eds_path), NODE_ID)
    assert not caplog.records, [r.getMessage() for r in caplog.records]


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.value)
def test_the_mapping_is_declared_modifiable_byte_by_byte(kind: DriveKind) -> None:
    """CiA 306: Granularity 0 is "mapping not modifiable"; the drives remap in CiA 301's
    order (drivers/pdo_map.py), whole bytes at least."""
    ini = eds_ini(kind)
    assert ini["DeviceInfo"]["granularity"] == "8"
    od = canopen.import_od(str(kind.eds_path), NODE_ID)
    for index in (0x1600, 0x1A00, 0x1A01):
        record: Any = od[index]
        assert all(record[sub].writable for sub in record.subindices), hex(index)


def _other_value(variable: canopen.objectdictionary.ODVariable) -> int:
    present = variable.default
    assert isinstance(present, int)
    return present + 1 if present < 200 else present - 1


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.value)
def test_pdo_communication_objects_declared_writable_take_another_value(
        kind: DriveKind) -> None:
    """Sub 2 … 6 of each PDO's communication parameter (the COB-ID, sub 1, follows CiA
    301's remapping rules: tests/drivers/test_pdo_map.py): declared rw, another value is
    taken and read back; declared ro, a write is refused as read-only. They were declared
    rw while the drive refused any value but its own."""
    drive = bench(kind)
    od = canopen.import_od(str(kind.eds_path), NODE_ID)
    for index in PDO_COMMUNICATION:
        record: Any = od[index]
        for subindex in sorted(record.subindices):
            if subindex < 2:
                continue
            variable = record[subindex]
            where, value = f"0x{index:04X}:{subindex}", _other_value(variable)
            request = sdo_download(index, subindex, value, len(variable) // 8)
            if variable.writable:
                assert drive.sdo(request) == ("ok", 0), where
                assert drive.sdo(sdo_upload(index, subindex)) == ("value", value), where
            else:
                assert drive.sdo(request) == ("abort", READ_ONLY), where


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.value)
def test_tpdo2_goes_out_every_event_timer_period_besides_on_change(kind: DriveKind) -> None:
    drive = bench(kind)
    assert drive.sdo(sdo_download(0x1801, 5, 10, 2)) == ("ok", 0)  # ms
    assert TPDO2 in [i for i, _ in drive.nmt(NmtCommand.START)]  # on entering OPERATIONAL
    sent_ms = [k for k in range(1, 46) if TPDO2 in [i for i, _ in drive.at(k * 0.001).poll()]]
    assert len(sent_ms) == 4 and all(9 <= b - a <= 11 for a, b in itertools.pairwise(sent_ms))
    drive.nmt(NmtCommand.RESET_COMMUNICATION)
    assert drive.sdo(sdo_upload(0x1801, 5)) == ("value", 0)  # the EDS's again
    drive.nmt(NmtCommand.START)
    assert not [i for k in range(50, 90) for i, _ in drive.at(k * 0.001).poll() if i == TPDO2]


_FILE = re.compile(r"\b[\w./-]+\.(?:py|dbc|eds|md)\b")


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.value)
def test_the_eds_comments_name_files_that_exist(kind: DriveKind) -> None:
    named = [name for line in kind.eds_path.read_text().splitlines() if line.startswith(";")
             for name in _FILE.findall(line)]
    missing = [name for name in named
               if not (ROOT / name).exists() and not (kind.eds_path.parent / name).exists()]
    assert named and not missing, missing
