"""The EDS files, the DBC and the codec agree (golden tests), and the EDS serves bring-up.

canopen reads the PDO maps from the EDS without SDO traffic with
``node.tpdo.read(from_od=True)``; that call also subscribes the PDOs, so the
node must first be associated with a ``canopen.Network`` — one without a bus,
which starts no thread.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import canopen
import cantools
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes
from canopen.sdo.exceptions import SdoAbortedError
from hypothesis import given
from hypothesis import strategies as st

from rakectl.protocol import codec, gen_dbc, nmt
from rakectl.protocol.codec import Field, FunctionCode
from rakectl.protocol.files import DBC_PATH

DRIVES = [
    pytest.param(gen_dbc.DC_SERVO_EDS, codec.R_DRIVE_NODE_ID, "R_DRIVE", id="dc-servo"),
    pytest.param(gen_dbc.GEARED_MOTOR_EDS, codec.THETA_DRIVE_NODE_ID, "THETA_DRIVE", id="geared"),
]

# (kind, communication index, mapping index, function code, codec fields, transmission type)
PDOS = [
    ("TPDO1", 0x1800, 0x1A00, FunctionCode.TPDO1, codec.TPDO1_FIELDS, 1),
    ("TPDO2", 0x1801, 0x1A01, FunctionCode.TPDO2, codec.TPDO2_FIELDS, 255),
    ("RPDO1", 0x1400, 0x1600, FunctionCode.RPDO1, codec.RPDO1_FIELDS, 1),
]

SIGNED = {datatypes.INTEGER8, datatypes.INTEGER16, datatypes.INTEGER32}


class LoopbackNetwork(canopen.Network):
    """A bus-less network that hands every sent frame straight to the subscribers."""

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.notify(can_id, bytearray(data), 0.0)


def variable(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    entry = od[index]
    if isinstance(entry, (ODRecord, ODArray)):
        entry = entry[subindex]
    assert isinstance(entry, ODVariable)
    return entry


@pytest.fixture(scope="module")
def db() -> Any:
    return cantools.database.load_file(str(DBC_PATH))


# --------------------------------------------------------------------------- the EDS loads


@pytest.mark.parametrize(("path", "node_id", "label"), DRIVES)
def test_eds_is_ascii_and_loads_at_any_node_id(path: Path, node_id: int, label: str) -> None:
    path.read_bytes().decode("ascii")
    for nid in (node_id, 5, 127):
        od = canopen.import_od(str(path), nid)
        assert variable(od, 0x1800, 1).default == 0x180 + nid
        assert variable(od, 0x1801, 1).default == 0x280 + nid
        assert variable(od, 0x1400, 1).default == 0x200 + nid
        assert variable(od, 0x1014).default == 0x080 + nid
    assert od.device_information.allowed_baudrates == {1_000_000}
    assert (od.device_information.nr_of_RXPDO, od.device_information.nr_of_TXPDO) == (1, 2)


# (index, subindex, data type, access, default or None)
COMMON_OBJECTS = [
    (0x1000, 0, datatypes.UNSIGNED32, "ro", 0x00020192),
    (0x1001, 0, datatypes.UNSIGNED8, "ro", 0),
    (0x1005, 0, datatypes.UNSIGNED32, "rw", codec.SYNC_COB_ID),
    (0x1008, 0, datatypes.VISIBLE_STRING, "const", None),
    (0x1016, 1, datatypes.UNSIGNED32, "rw",
     codec.CONTROLLER_NODE_ID << 16 | codec.CONTROLLER_HEARTBEAT_TIMEOUT_MS),
    (0x1017, 0, datatypes.UNSIGNED16, "rw", codec.DRIVE_HEARTBEAT_PERIOD_MS),
    (0x1018, 1, datatypes.UNSIGNED32, "ro", None),
    (0x1018, 2, datatypes.UNSIGNED32, "ro", None),
    (0x1018, 3, datatypes.UNSIGNED32, "ro", 0x00010000),
    (0x1018, 4, datatypes.UNSIGNED32, "ro", None),
    (0x1019, 0, datatypes.UNSIGNED8, "rw", codec.SYNC_COUNTER_MAX),
    (0x2000, 0, datatypes.INTEGER16, "rw", 0),
    (0x2001, 0, datatypes.UNSIGNED16, "rw", 24000),
    (0x2002, 0, datatypes.UNSIGNED16, "rw", None),
    (0x2003, 0, datatypes.UNSIGNED16, "rw", 20),
    (0x2004, 0, datatypes.UNSIGNED32, "rw", 2000),
    (0x2005, 0, datatypes.UNSIGNED8, "rw", codec.TPDO2_REFRESH_SYNCS),
    (0x2100, 0, datatypes.INTEGER16, "ro", 0),
    (0x603F, 0, datatypes.UNSIGNED16, "ro", 0),
    (0x6040, 0, datatypes.UNSIGNED16, "rw", 0),
    (0x6041, 0, datatypes.UNSIGNED16, "ro", 0),
    (0x6060, 0, datatypes.INTEGER8, "rw", -1),
    (0x6061, 0, datatypes.INTEGER8, "ro", -1),
    (0x6064, 0, datatypes.INTEGER32, "ro", 0),
    (0x606C, 0, datatypes.INTEGER16, "ro", 0),
]


@pytest.mark.parametrize(("path", "node_id", "label"), DRIVES)
def test_objects_have_their_types_access_and_defaults(path: Path, node_id: int, label: str) -> None:
    od = canopen.import_od(str(path), node_id)
    for index, subindex, data_type, access, default in COMMON_OBJECTS:
        var = variable(od, index, subindex)
        where = f"0x{index:04X}:{subindex}"
        assert (var.data_type, var.access_type) == (data_type, access), where
        if default is not None:
            assert var.default == default, where
    assert variable(od, 0x2003).min == 1  # the command watchdog cannot be switched off


def test_drive_types_differ_where_they_should() -> None:
    servo = canopen.import_od(str(gen_dbc.DC_SERVO_EDS), 1)
    geared = canopen.import_od(str(gen_dbc.GEARED_MOTOR_EDS), 2)
    assert variable(servo, 0x1008).default == "Rake DC-servo drive"
    assert variable(geared, 0x1008).default == "Rake geared-motor drive"
    assert (variable(servo, 0x1018, 2).default, variable(geared, 0x1018, 2).default) == (1, 2)
    assert servo.device_information.product_number == 1
    assert geared.device_information.product_number == 2
    assert (variable(servo, 0x2002).default, variable(geared, 0x2002).default) == (6000, 10000)


# --------------------------------------------------------------------------- PDO maps


def _node_pdos(node: canopen.LocalNode | canopen.RemoteNode) -> dict[str, Any]:
    node.associate_network(canopen.Network())  # read() subscribes; no bus, no thread
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    return {"TPDO1": node.tpdo[1], "TPDO2": node.tpdo[2], "RPDO1": node.rpdo[1]}


@pytest.mark.parametrize("node_class", [canopen.LocalNode, canopen.RemoteNode])
@pytest.mark.parametrize(("path", "node_id", "label"), DRIVES)
def test_canopen_reads_the_pdo_maps_from_the_eds(
    node_class: type, path: Path, node_id: int, label: str
) -> None:
    pdos = _node_pdos(node_class(node_id, canopen.import_od(str(path), node_id)))
    for kind, _, _, function, fields, transmission_type in PDOS:
        pdo_map = pdos[kind]
        assert (pdo_map.cob_id, pdo_map.enabled) == (codec.cob_id(function, node_id), True)
        assert pdo_map.trans_type == transmission_type
        layout = [(v.index, v.subindex, v.offset, v.length) for v in pdo_map.map]
        offsets = [sum(8 * _size(f) for f in fields[:i]) for i in range(len(fields))]
        assert layout == [(f.od_index, f.od_subindex, off, 8 * _size(f))
                          for f, off in zip(fields, offsets, strict=True)]
    assert pdos["TPDO2"].inhibit_time == 0


def _size(field: Field) -> int:
    low, high = codec.field_range(field.code)
    return (high - low).bit_length() // 8


@pytest.mark.parametrize(("path", "node_id", "label"), DRIVES)
def test_eds_mapping_is_the_codec_layout(path: Path, node_id: int, label: str) -> None:
    od = canopen.import_od(str(path), node_id)
    for kind, com_index, map_index, function, fields, _ in PDOS:
        assert variable(od, com_index, 1).default == codec.cob_id(function, node_id), kind
        mapping = gen_dbc.pdo_mapping(od, map_index)
        assert [(i, s) for i, s, _ in mapping] == [(f.od_index, f.od_subindex) for f in fields]
        for (index, subindex, bits), field in zip(mapping, fields, strict=True):
            mapped = variable(od, index, subindex)
            assert bits == 8 * _size(field) == len(mapped), f"{kind} {field.name}"
            assert (mapped.data_type in SIGNED) == field.code.islower(), f"{kind} {field.name}"
            assert mapped.pdo_mappable, f"{kind} {field.name}"


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**15), 2**15 - 1),
       st.integers(-(2**15), 2**15 - 1))
def test_canopen_decodes_a_codec_tpdo1(counts: int, rpm: int, ma: int) -> None:
    pdo_map = _node_pdos(canopen.RemoteNode(1, canopen.import_od(str(gen_dbc.DC_SERVO_EDS), 1)))[
        "TPDO1"]
    pdo_map.data = bytearray(codec.encode_tpdo1(counts, rpm, ma))
    assert [v.raw for v in pdo_map.map] == [counts, rpm, ma]


# --------------------------------------------------------------------------- DBC


def test_committed_dbc_is_generated_from_the_eds() -> None:
    expected = gen_dbc.dbc_text(gen_dbc.default_drives())
    stale = "stale: run python -m rakectl.protocol.gen_dbc > rakectl/protocol/rakedrive.dbc"
    assert DBC_PATH.read_text() == expected, stale


def test_dbc_has_every_frame_at_the_codecs_id_and_size(db: Any) -> None:
    expected = {codec.NMT_COB_ID: 2, codec.SYNC_COB_ID: codec.SYNC_SIZE,
                codec.cob_id(FunctionCode.HEARTBEAT, codec.CONTROLLER_NODE_ID): 1}
    for node in (codec.R_DRIVE_NODE_ID, codec.THETA_DRIVE_NODE_ID):
        expected |= {codec.cob_id(FunctionCode.TPDO1, node): codec.TPDO1_SIZE,
                     codec.cob_id(FunctionCode.TPDO2, node): codec.TPDO2_SIZE,
                     codec.cob_id(FunctionCode.RPDO1, node): codec.RPDO1_SIZE,
                     codec.cob_id(FunctionCode.EMCY, node): nmt.EMCY_SIZE,
                     codec.cob_id(FunctionCode.HEARTBEAT, node): 1}
    assert {m.frame_id: m.length for m in db.messages} == expected


def _decoded(db: Any, frame_id: int, data: bytes) -> dict[str, Any]:
    return dict(db.decode_message(frame_id, data, decode_choices=False))


NODES = st.sampled_from([codec.R_DRIVE_NODE_ID, codec.THETA_DRIVE_NODE_ID])


@given(NODES, st.integers(-(2**31), 2**31 - 1), st.integers(-(2**15), 2**15 - 1),
       st.integers(-(2**15), 2**15 - 1))
def test_tpdo1_physical_values_agree(db: Any, node: int, counts: int, rpm: int, ma: int) -> None:
    frame_id = codec.cob_id(FunctionCode.TPDO1, node)
    signals = _decoded(db, frame_id, codec.encode_tpdo1(counts, rpm, ma))
    assert signals["position_counts"] == counts
    assert math.isclose(signals["velocity_rad_per_s"], codec.rpm_to_rad_per_s(rpm),
                        rel_tol=1e-12, abs_tol=1e-12)
    assert math.isclose(signals["current_a"], codec.current_ma_to_a(ma), abs_tol=1e-12)
    assert codec.decode_tpdo1(db.encode_message(frame_id, signals)) == (counts, rpm, ma)


@given(NODES, st.integers(-(2**15), 2**15 - 1), st.integers(0, 2**16 - 1))
def test_rpdo1_physical_values_agree(db: Any, node: int, mv: int, controlword: int) -> None:
    frame_id = codec.cob_id(FunctionCode.RPDO1, node)
    signals = _decoded(db, frame_id, codec.encode_rpdo(mv, controlword))
    assert math.isclose(signals["voltage_v"], codec.voltage_mv_to_v(mv), abs_tol=1e-12)
    assert signals["controlword"] == controlword
    assert codec.decode_rpdo(db.encode_message(frame_id, signals)) == (mv, controlword)


@given(NODES, st.integers(0, 2**16 - 1), st.integers(0, 255))
def test_tpdo2_values_agree(db: Any, node: int, statusword: int, error_register: int) -> None:
    frame_id = codec.cob_id(FunctionCode.TPDO2, node)
    signals = _decoded(db, frame_id, codec.encode_tpdo2(statusword, error_register))
    assert signals == {"statusword": statusword, "error_register": error_register}


@given(NODES, st.sampled_from(nmt.EmcyCode), st.integers(0, 255), st.binary(min_size=5,
                                                                                 max_size=5))
def test_emcy_values_agree(db: Any, node: int, code: int, register: int, extra: bytes) -> None:
    frame_id = codec.cob_id(FunctionCode.EMCY, node)
    signals = _decoded(db, frame_id, nmt.encode_emcy(code, register, extra))
    assert signals == {"error_code": code, "error_register": register,
                       "manufacturer_data": int.from_bytes(extra, "little")}


@pytest.mark.parametrize(
    ("frame_id", "data", "expected"),
    [
        (codec.SYNC_COB_ID, codec.encode_sync(240), {"sync_counter": 240}),
        (codec.NMT_COB_ID, nmt.encode_nmt(nmt.NmtCommand.START, 2),
         {"command": 1, "node_id": 2}),
        (0x70A, nmt.encode_heartbeat(nmt.NmtState.OPERATIONAL), {"nmt_state": 5}),
        (0x701, nmt.encode_heartbeat(nmt.NmtState.PRE_OPERATIONAL), {"nmt_state": 127}),
    ],
)
def test_fixed_frames_agree(db: Any, frame_id: int, data: bytes, expected: dict[str, int]) -> None:
    assert _decoded(db, frame_id, data) == expected


def test_dbc_value_tables_name_the_codes(db: Any) -> None:
    choices = db.get_message_by_name("R_DRIVE_EMCY").get_signal_by_name("error_code").choices
    assert choices[0x8250] == "COMMAND_WATCHDOG_TIMEOUT"
    rpdo = db.get_message_by_name("THETA_DRIVE_RPDO1").get_signal_by_name("controlword")
    assert rpdo.choices[0x0007] == "SWITCH_ON / DISABLE_OPERATION"


def test_dbc_signals_carry_units_and_scales(db: Any) -> None:
    units = {(m.name.split("_DRIVE_")[-1], s.name): (s.unit, s.scale)
             for m in db.messages for s in m.signals if "DRIVE_" in m.name}
    assert units[("RPDO1", "voltage_v")] == ("V", 0.001)
    assert units[("TPDO1", "current_a")] == ("A", 0.001)
    assert units[("TPDO1", "velocity_rad_per_s")] == ("rad/s", codec.RAD_PER_S_PER_RPM)
    assert units[("TPDO1", "position_counts")] == ("counts", 1)


# --------------------------------------------------------------------------- SDO bring-up


@pytest.fixture(params=[(gen_dbc.DC_SERVO_EDS, 1), (gen_dbc.GEARED_MOTOR_EDS, 2)],
                ids=["dc-servo", "geared"])
def sdo_pair(request: pytest.FixtureRequest) -> tuple[canopen.RemoteNode, canopen.LocalNode]:
    path, node_id = request.param
    network = LoopbackNetwork()
    server = canopen.LocalNode(node_id, canopen.import_od(str(path), node_id))
    client = canopen.RemoteNode(node_id, canopen.import_od(str(path), node_id))
    server.associate_network(network)
    client.associate_network(network)
    return client, server


def test_sdo_bring_up_exchange(sdo_pair: tuple[canopen.RemoteNode, canopen.LocalNode]) -> None:
    client, server = sdo_pair
    assert client.sdo[0x2003].raw == 20
    client.sdo[0x2003].raw = 15
    client.sdo[0x2001].raw = 12000
    assert (server.sdo[0x2003].raw, server.sdo[0x2001].raw) == (15, 12000)
    assert client.sdo[0x6060].raw == -1
    assert client.sdo[0x1018][2].raw == server.object_dictionary.device_information.product_number
    assert client.sdo[0x1008].raw.startswith("Rake ")


@pytest.mark.parametrize("index", [0x6041, 0x6064, 0x2100, 0x1000, 0x603F])
def test_sdo_write_to_read_only_object_is_aborted(
    sdo_pair: tuple[canopen.RemoteNode, canopen.LocalNode], index: int
) -> None:
    client, _ = sdo_pair
    with pytest.raises(SdoAbortedError) as aborted:
        client.sdo[index].raw = 1
    assert aborted.value.code == 0x06010002


def test_pdo_maps_also_come_over_sdo(
    sdo_pair: tuple[canopen.RemoteNode, canopen.LocalNode],
) -> None:
    client, _ = sdo_pair
    client.tpdo.read()  # reads 0x1800…/0x1A00… from the drive by SDO
    assert [v.index for v in client.tpdo[1].map] == [f.od_index for f in codec.TPDO1_FIELDS]


