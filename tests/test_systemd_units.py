"""The systemd files: parsed strictly, their required keys, and systemd's own checks.

``systemd-analyze verify`` runs against a throw-away root holding a copy of the
system's units and stubs for the ExecStart= programs (it refuses units whose program
is not installed); the networkd files are checked against the keys that
systemd-networkd knows; the sysusers file is applied to a throw-away /etc.
"""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rakectl.api.schema import SERVICE_RUNTIME_DIR
from rakectl.config.service import BusSettings

SYSTEMD = Path(__file__).resolve().parents[1] / "systemd"
UNITS = ("rakectl.service", "rakectl-emulator.service", "rakectl-view.service")
NETWORKD = ("80-can0.network", "80-vcan0.netdev", "80-vcan0.network")
SYSTEM_UNITS = Path("/usr/lib/systemd/system")
NETWORKD_BINARY = Path("/usr/lib/systemd/systemd-networkd")

Sections = dict[str, list[tuple[str, str]]]


def parse(path: Path) -> Sections:
    """A unit-style file: [Section] headers and Key=value lines, nothing else."""
    sections: Sections = {}
    current: list[tuple[str, str]] | None = None
    for number, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.strip()
        where = f"{path.name}:{number}"
        if not line or line[0] in "#;":
            continue
        if re.fullmatch(r"\[[A-Za-z]+\]", line):
            assert line[1:-1] not in sections, f"{where}: section {line} given twice"
            current = sections[line[1:-1]] = []
            continue
        key, sep, value = line.partition("=")
        assert current is not None, f"{where}: a key before any section"
        assert sep and re.fullmatch(r"[A-Z][A-Za-z0-9]*", key), f"{where}: not Key=value: {raw!r}"
        assert not value.endswith("\\"), f"{where}: no continuation lines, please"
        current.append((key, value.strip()))
    return sections


def values(sections: Sections, section: str, key: str) -> list[str]:
    return [value for name, value in sections.get(section, []) if name == key]


def value(sections: Sections, section: str, key: str) -> str:
    found = values(sections, section, key)
    assert found, f"[{section}] {key}= is missing"
    return found[-1]


def words(sections: Sections, section: str, key: str) -> set[str]:
    return {word for line in values(sections, section, key) for word in line.split()}


@pytest.fixture(scope="module")
def service() -> Sections:
    return parse(SYSTEMD / "rakectl.service")


def test_every_file_parses() -> None:
    for name in (*UNITS, *NETWORKD):
        assert parse(SYSTEMD / name)
    assert not (SYSTEMD / "README").exists()


def test_service_runs_the_daemon_as_a_notify_service(service: Sections) -> None:
    expected = {
        "Type": "notify", "NotifyAccess": "main", "User": "rakectl", "Group": "rakectl",
        "ExecStart": "/usr/local/bin/rakectl run --config /etc/rakectl/rakectl.yaml",
        "RuntimeDirectory": "rakectl", "RuntimeDirectoryMode": "0750",
        "StateDirectory": "rakectl", "WatchdogSec": "1s", "Restart": "on-failure",
        "KillSignal": "SIGTERM", "LimitRTPRIO": "90", "LimitMEMLOCK": "infinity",
    }
    for key, wanted in expected.items():
        assert value(service, "Service", key) == wanted, key
    for key in ("RestartSec", "TimeoutStopSec"):
        assert value(service, "Service", key)
    assert "sys-subsystem-net-devices-can0.device" in words(service, "Unit", "After")
    assert "sys-subsystem-net-devices-can0.device" in words(service, "Unit", "Wants")
    assert value(service, "Install", "WantedBy") == "multi-user.target"


def test_service_is_real_time_capable_and_hardened(service: Sections) -> None:
    caps = {"CAP_SYS_NICE", "CAP_IPC_LOCK"}
    assert words(service, "Service", "AmbientCapabilities") == caps
    assert words(service, "Service", "CapabilityBoundingSet") == caps
    assert not values(service, "Service", "RestrictRealtime")  # it would forbid SCHED_FIFO
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp", "ProtectKernelTunables",
                "ProtectKernelModules", "ProtectControlGroups", "RestrictNamespaces",
                "LockPersonality", "MemoryDenyWriteExecute"):
        assert value(service, "Service", key) == "yes", key
    assert value(service, "Service", "ProtectSystem") == "strict"
    assert value(service, "Service", "SystemCallArchitectures") == "native"
    families = words(service, "Service", "RestrictAddressFamilies")
    assert families == {"AF_UNIX", "AF_CAN", "AF_NETLINK"}


def test_service_agrees_with_the_code(service: Sections) -> None:
    runtime = Path("/run") / value(service, "Service", "RuntimeDirectory")
    assert runtime == SERVICE_RUNTIME_DIR
    sysusers = (SYSTEMD / "rakectl.sysusers").read_text().splitlines()
    users = [line.split()[1] for line in sysusers if line.startswith("u ")]
    assert users == [value(service, "Service", "User")]
    bitrate = value(parse(SYSTEMD / "80-can0.network"), "CAN", "BitRate")
    assert bitrate == f"{BusSettings().bitrate // 1_000_000}M"


def test_emulator_service_drives_vcan0() -> None:
    unit = parse(SYSTEMD / "rakectl-emulator.service")
    assert value(unit, "Service", "ExecStart").endswith(
        " -m drivers --config /etc/rakectl/emulator.yaml --interface socketcan --channel vcan0")
    assert "sys-subsystem-net-devices-vcan0.device" in words(unit, "Unit", "BindsTo")
    assert "rakectl.service" in words(unit, "Unit", "Before")
    assert words(unit, "Service", "RestrictAddressFamilies") == {"AF_UNIX", "AF_CAN",
                                                                 "AF_NETLINK"}


def test_networkd_files() -> None:
    can0 = parse(SYSTEMD / "80-can0.network")
    assert value(can0, "Match", "Name") == "can0"
    assert value(can0, "Link", "RequiredForOnline") == "no"
    netdev = parse(SYSTEMD / "80-vcan0.netdev")
    assert (value(netdev, "NetDev", "Name"), value(netdev, "NetDev", "Kind")) == ("vcan0", "vcan")
    assert value(parse(SYSTEMD / "80-vcan0.network"), "Match", "Name") == "vcan0"


def test_networkd_knows_every_key() -> None:
    if not NETWORKD_BINARY.exists():
        pytest.skip(f"{NETWORKD_BINARY} is not installed (apt-get install systemd)")
    known = NETWORKD_BINARY.read_bytes()  # its gperf tables hold "Section.Key" strings
    for name in NETWORKD:
        for section, pairs in parse(SYSTEMD / name).items():
            for key, _ in pairs:
                entry = f"\0{section}.{key}\0".encode()
                assert entry in known, f"{name}: [{section}] {key}= is unknown to networkd"


def test_systemd_analyze_verify(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None or not SYSTEM_UNITS.is_dir():
        pytest.skip("systemd-analyze is not installed (apt-get install systemd)")
    root = tmp_path / "root"
    shutil.copytree(SYSTEM_UNITS, root / SYSTEM_UNITS.relative_to("/"), symlinks=True)
    (root / "etc/systemd/system").mkdir(parents=True)
    for name in UNITS:
        shutil.copy(SYSTEMD / name, root / "etc/systemd/system" / name)
        program = value(parse(SYSTEMD / name), "Service", "ExecStart").split()[0]
        stub = root / program.lstrip("/")
        stub.parent.mkdir(parents=True, exist_ok=True)
        stub.write_text("#!/bin/sh\n")
        stub.chmod(0o755)
    done = subprocess.run([analyze, "verify", f"--root={root}", "--man=no", *UNITS],
                          capture_output=True, text=True, timeout=120)
    complaints = [line for line in (done.stdout + done.stderr).splitlines() if "rakectl" in line]
    assert done.returncode == 0 and not complaints, done.stdout + done.stderr


EXPOSURE_LIMIT = 1.5  # systemd-analyze security's score; docs/installation.md explains it


def test_security_exposure_stays_low() -> None:
    """systemd's own rating of the unit's sandbox (offline: no running systemd needed)."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (apt-get install systemd)")
    done = subprocess.run([analyze, "security", "--offline=yes", "--no-pager",
                           str(SYSTEMD / "rakectl.service")],
                          capture_output=True, text=True, timeout=120)
    found = re.search(r"Overall exposure level for rakectl.service: ([0-9.]+)", done.stdout)
    assert found, done.stdout + done.stderr
    score = float(found.group(1))
    print(f"\nsystemd-analyze security: exposure {score}")
    assert score <= EXPOSURE_LIMIT, done.stdout


def test_sysusers_creates_the_user_and_group(tmp_path: Path) -> None:
    sysusers = shutil.which("systemd-sysusers")
    if sysusers is None:
        pytest.skip("systemd-sysusers is not installed (apt-get install systemd)")
    (tmp_path / "etc").mkdir()
    subprocess.run([sysusers, f"--root={tmp_path}", str(SYSTEMD / "rakectl.sysusers")],
                   check=True, capture_output=True, timeout=60)
    user = [line for line in (tmp_path / "etc/passwd").read_text().splitlines()
            if line.startswith("rakectl:")]
    assert len(user) == 1 and user[0].endswith(":/var/lib/rakectl:/usr/sbin/nologin")
    assert "\nrakectl:" in "\n" + (tmp_path / "etc/group").read_text()


_MDWE_WORKLOAD = textwrap.dedent("""
    import mmap, tempfile, pathlib
    import numpy, yaml, structlog, can, canopen, drivers
    import rakectl.api.server, rakectl.config.loader, rakectl.daemon.sdnotify, rakectl.sim.simulate
    assert numpy.allclose(numpy.linalg.solve(2 * numpy.eye(3), numpy.ones(3)), 0.5)
    bus = can.Bus(interface="virtual", channel="mdwe")
    bus.send(can.Message(arbitration_id=0x80, data=b""))
    bus.shutdown()
    rakectl.config.loader.load_settings()
    with tempfile.TemporaryDirectory() as d:
        with rakectl.api.server.CommandServer(pathlib.Path(d) / "s", None, lambda r: {}) as server:
            server.poll(0.001)
    try:
        mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    except PermissionError:
        print("refused")
""")


def test_cpython_runs_under_memory_deny_write_execute() -> None:
    """The kernel's prctl(PR_SET_MDWE) refuses what MemoryDenyWriteExecute=yes refuses."""
    libc = ctypes.CDLL(None, use_errno=True)
    probe = subprocess.run([sys.executable, "-c", "import ctypes, sys; sys.exit(ctypes.CDLL("
                            "None).prctl(65, 1, 0, 0, 0) != 0)"], timeout=60)
    if probe.returncode != 0 or not hasattr(libc, "prctl"):
        pytest.skip("the kernel has no PR_SET_MDWE (Linux >= 6.3)")
    wrapper = ("import ctypes, os, sys\n"
               "assert ctypes.CDLL(None).prctl(65, 1, 0, 0, 0) == 0\n"  # PR_SET_MDWE, REFUSE
               "os.execv(sys.executable, [sys.executable, '-c', sys.argv[1]])\n")
    done = subprocess.run([sys.executable, "-c", wrapper, _MDWE_WORKLOAD],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "refused"  # the filter was on: W+X memory is refused


def test_view_service_only_reads_and_serves_loopback() -> None:
    """The live view's unit: the viewer, no capabilities, loopback only, never real-time,
    started and stopped with the controller; systemd's sandbox rating printed."""
    view = parse(SYSTEMD / "rakectl-view.service")
    exec_start = value(view, "Service", "ExecStart")
    assert exec_start.split()[1:3] == ["view", "--socket"] and "--host" not in exec_start
    assert value(view, "Service", "CapabilityBoundingSet") == ""
    assert value(view, "Service", "IPAddressAllow") == "localhost"
    assert value(view, "Service", "RestrictRealtime") == "yes"
    assert value(view, "Unit", "PartOf") == "rakectl.service"
    assert value(view, "Service", "SupplementaryGroups") == "rakectl"
    analyze = shutil.which("systemd-analyze")
    if analyze is not None:
        done = subprocess.run([analyze, "security", "--offline=yes", "--no-pager",
                               str(SYSTEMD / "rakectl-view.service")],
                              capture_output=True, text=True, timeout=120)
        found = re.search(r"Overall exposure level for rakectl-view.service: ([0-9.]+)",
                          done.stdout)
        assert found, done.stdout + done.stderr
        print(f"\nsystemd-analyze security rakectl-view.service: exposure {found.group(1)}")
