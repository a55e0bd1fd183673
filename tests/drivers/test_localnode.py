"""The controller against a CANopen slave the project did not write: canopen's LocalNode.

tests/drivers/localnode_drives.py plays both drives on canopen's LocalNode (its SDO server,
NMT states, heartbeat producer and PDO packing) with a thin CiA 402 and SYNC layer and the
emulator's physics. As processes over udp_multicast in a private network namespace (the
emulated bench): `rakectl drives` reads them back, and the daemon brings them up, passes
its weight check, jogs, stops and e-stops on them, as the project's own CiA 402 drives and
as Roboteq-class drives. The pair of configurations is the
vcan bench's (50 Hz, long timeouts): canopen's stack runs in Python per frame.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rakectl.sim.rig import NAMESPACE_SETUP, emulated_bench, namespaces_unavailable, unshare_command
from tests.drivers.localnode_drives import (
    FAULT,
    OPERATION_ENABLED,
    READY_TO_SWITCH_ON,
    SWITCH_ON_DISABLED,
    SWITCHED_ON,
    next_state,
)

ROOT = Path(__file__).resolve().parents[2]
EMULATOR = ROOT / "config" / "emulator-vcan.yaml"
DAEMON = ROOT / "config" / "rakectl-vcan.yaml"
MODULE = "tests.drivers.localnode_drives"
BUS = ["--set", "bus.interface=udp_multicast", "--set", "bus.channel=239.74.163.7"]
_reason = namespaces_unavailable()
needs_namespace = pytest.mark.skipif(_reason is not None,
                                     reason=f"no network namespace: {_reason}")

_SCRIPT = """\
set -u
{setup}
"$PY" -m {module} --config "$EMU_CONFIG" {bus} > "$OUT/slave.log" 2>&1 &
SLAVE=$!
for _ in $(seq 200); do
    grep -q "emulator: ready" "$OUT/slave.log" 2>/dev/null && break
    sleep 0.1
done
"$PY" -m rakectl drives --config "$DAEMON_CONFIG" {bus} \\
    --set daemon.socket_path="$OUT/none.sock" --json > "$OUT/check.json" 2> "$OUT/check.err"
echo $? > "$OUT/check.rc"
kill -TERM $SLAVE
wait $SLAVE
"""


def test_cia402_transitions_of_the_slave() -> None:
    """The standard's sequence, one transition per SYNC; quick stop and disable voltage drop
    to SWITCH ON DISABLED; a fault leaves only on a rising fault-reset bit."""
    state = SWITCH_ON_DISABLED
    for controlword, expected in ((0x06, READY_TO_SWITCH_ON), (0x0F, SWITCHED_ON),
                                  (0x0F, OPERATION_ENABLED), (0x07, SWITCHED_ON),
                                  (0x0F, OPERATION_ENABLED), (0x02, SWITCH_ON_DISABLED)):
        state = next_state(state, controlword, 0)
        assert state == expected, hex(controlword)
    assert next_state(FAULT, 0x0F, 0) == FAULT
    assert next_state(FAULT, 0x80, 0x80) == FAULT
    assert next_state(FAULT, 0x80, 0x00) == SWITCH_ON_DISABLED


@pytest.mark.crossprocess
@needs_namespace
def test_the_dry_run_reads_a_localnode_slave_back(tmp_path: Path) -> None:
    script = _SCRIPT.format(setup=NAMESPACE_SETUP, module=MODULE, bus=" ".join(BUS))
    env = {"PY": sys.executable, "OUT": str(tmp_path), "EMU_CONFIG": str(EMULATOR),
           "DAEMON_CONFIG": str(DAEMON), "PATH": "/usr/sbin:/usr/bin:/sbin:/bin",
           "PYTHONPATH": str(ROOT)}
    subprocess.run([*unshare_command(), "sh", "-c", script], env=env, timeout=120,
                   check=True, cwd=ROOT)
    err = (tmp_path / "check.err").read_text()
    assert (tmp_path / "check.rc").read_text().split() == ["0"], (
        err + (tmp_path / "slave.log").read_text())
    report = json.loads((tmp_path / "check.json").read_text())
    r, theta = report["drives"]
    assert (r["node_id"], theta["node_id"]) == (1, 2)
    assert r["state"] == theta["state"] == "SWITCH_ON_DISABLED"
    assert (r["identity"]["serial"], theta["identity"]["serial"]) == (1001, 2001)
    assert r["device_name"] == "Rake DC-servo drive"  # a segmented upload, from the EDS
    watchdog = {limit["object"]: limit["value"] for limit in theta["limits"]}["0x2003"]
    assert watchdog == 1000  # config/rakectl-vcan.yaml, written and read back
    assert [p["name"] for p in r["pdos"]] == ["RPDO1", "TPDO1", "TPDO2"]


def _truth(out: Path) -> list[dict[str, str]]:
    with open(out / "truth.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.crossprocess
@needs_namespace
@pytest.mark.parametrize("profile", ["cia402", "roboteq"])
def test_the_daemon_brings_up_arms_and_jogs_a_localnode_slave(tmp_path: Path,
                                                              profile: str) -> None:
    """Either drive profile (drives.profile on both sides): the slave's CANopen side is
    LocalNode's over the profile's EDS."""
    args = [*BUS, "--set", f"drives.profile={profile}"]
    with emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_args=args, daemon_args=args,
                        emulator_module=MODULE) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        bench.request("arm")
        armed = bench.wait_for_state(["armed"], 60.0)
        check = armed["weight_check"]
        assert isinstance(check, dict) and check["passed"], check
        before = bench.request("status")["tip"]
        assert isinstance(before, dict)
        for _ in range(10):  # 1 s of jog down at 3 cm/s
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        after = bench.wait_for_state(["hold"], 30.0)["tip"]
        assert isinstance(after, dict)
        assert after["depth_m"] > before["depth_m"] + 0.01, (before, after)
        drives = bench.request("status")["drives"]
        assert isinstance(drives, list)
        assert [d["state"] for d in drives] == ["operation_enabled"] * 2, drives
        bench.request("estop")
        bench.wait_for_state(["estop"], 30.0)
        bench.request("reset")
        bench.wait_for_state(["disarmed"], 30.0)
    assert bench.process.returncode == 0, (tmp_path / "daemon.log").read_text()[-3000:]
    states = [json.loads(line)["new"] for line in (tmp_path / "daemon.log").read_text()
              .splitlines() if line.startswith("{") and '"event": "state"' in line]
    assert states == ["DISARMED", "CHECKING", "ARMED", "JOG", "HOLD", "ESTOP", "DISARMED"]
    truth = _truth(tmp_path)
    heights = [float(row["tip_height_m"]) for row in truth]
    assert min(heights) < heights[0] - 0.01  # the slave's physics moved under its commands
    assert float(truth[-1]["voltage_r_v"]) == float(truth[-1]["voltage_theta_v"]) == 0.0
