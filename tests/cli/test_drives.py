"""`rakectl drives`, the bring-up dry run: as a process against the emulated drives as a
process (udp_multicast in a private network namespace, as the emulated bench), and its
refusal while a daemon answers on the command socket."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from rakectl.api.schema import Request
from rakectl.api.server import CommandServer
from rakectl.cli.main import main
from rakectl.sim.rig import NAMESPACE_SETUP, namespaces_unavailable, unshare_command

ROOT = Path(__file__).resolve().parents[2]
EMULATOR = ROOT / "config" / "emulator-demo.yaml"
DAEMON = ROOT / "config" / "rakectl-emulated.yaml"

_reason = namespaces_unavailable()
needs_namespace = pytest.mark.skipif(_reason is not None,
                                     reason=f"no network namespace: {_reason}")

_SCRIPT = """\
set -u
{setup}
"$PY" -m drivers --config "$EMU_CONFIG" $PROFILE > "$OUT/emulator.log" 2>&1 &
EMU=$!
for _ in $(seq 200); do
    grep -q "emulator: ready" "$OUT/emulator.log" 2>/dev/null && break
    sleep 0.1
done
"$PY" -m rakectl drives --config "$DAEMON_CONFIG" --set daemon.socket_path="$OUT/none.sock" \\
    $PROFILE > "$OUT/check.txt" 2> "$OUT/check.err"
echo $? > "$OUT/check.rc"
"$PY" -m rakectl drives --config "$DAEMON_CONFIG" --set daemon.socket_path="$OUT/none.sock" \\
    $PROFILE --json > "$OUT/check.json" 2>> "$OUT/check.err"
echo $? >> "$OUT/check.rc"
"$PY" -m rakectl drives --config "$DAEMON_CONFIG" --set daemon.socket_path="$OUT/none.sock" \\
    --set drives.r_node_id=5 --set daemon.boot_timeout_s=1 > /dev/null 2> "$OUT/absent.err"
echo $? >> "$OUT/check.rc"
kill -TERM $EMU
wait $EMU
"""


@pytest.mark.crossprocess
@needs_namespace
def test_the_dry_run_reads_both_emulated_drives_back_and_leaves_them_stopped(
        tmp_path: Path) -> None:
    script = _SCRIPT.format(setup=NAMESPACE_SETUP)
    _run(script, tmp_path, "")
    err = (tmp_path / "check.err").read_text()
    assert (tmp_path / "check.rc").read_text().split() == ["0", "0", "1"], err
    text = (tmp_path / "check.txt").read_text()
    print("\n" + text)
    assert "r drive (node 1): 'Rake DC-servo drive' (dc_servo_drive.eds)" in text
    assert "0x2003    watchdog timeout" in text and "drives.watchdog_timeout_ms" in text
    assert "TPDO1  COB-ID 0x182, every SYNC: 0x6064:0 (32 bit)" in text
    assert text.rstrip().endswith("not started (PRE-OPERATIONAL, 0 V)")
    report = json.loads((tmp_path / "check.json").read_text())
    assert report["started"] is False
    r, theta = report["drives"]
    assert (r["node_id"], theta["node_id"]) == (1, 2)
    assert r["state"] == theta["state"] == "SWITCH_ON_DISABLED"
    watchdog = {limit["object"]: limit["value"] for limit in theta["limits"]}["0x2003"]
    assert watchdog == 100  # config/rakectl-emulated.yaml, written and read back
    assert [p["name"] for p in r["pdos"]] == ["RPDO1", "TPDO1", "TPDO2"]
    absent = (tmp_path / "absent.err").read_text()
    assert absent.startswith("rakectl: error: r drive (node 5): no heartbeat or boot-up "
                             "within 1 s"), absent
    events = [json.loads(line) for line in (tmp_path / "emulator.log").read_text().splitlines()
              if line.startswith("{")]
    served = [e for e in events if e["event"] == "emulator_stopped"]
    assert served and served[0]["frames_in"] > 100  # three bring-ups' SDO and NMT frames
    assert {e["nmt"] for e in events if e["event"] == "nmt_state"} == {"PRE_OPERATIONAL"}


def test_the_dry_run_is_refused_while_a_daemon_answers(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Its NMT reset would take the drives from under a running daemon: refused before the
    bus is opened, naming the socket."""
    path = tmp_path / "rakectl.sock"

    def handler(request: Request) -> dict[str, object]:
        return {"state": "armed"}

    server = CommandServer(path, None, handler)
    stop = threading.Event()
    thread = threading.Thread(target=lambda: [server.poll(0.01) for _ in iter(stop.is_set,
                                                                                True)])
    thread.start()
    try:
        status = main(["drives", "--config", str(DAEMON), "--set",
                       f"daemon.socket_path={path}"])
    finally:
        stop.set()
        thread.join(5.0)
        server.close()
    assert status == 1
    err = capsys.readouterr().err
    assert err.startswith(f"rakectl: error: the daemon answers on {path} (state armed): "
                          "stop it first"), err


def _run(script: str, out: Path, profile: str) -> None:
    env = {"PY": sys.executable, "OUT": str(out), "EMU_CONFIG": str(EMULATOR),
           "DAEMON_CONFIG": str(DAEMON), "PATH": "/usr/sbin:/usr/bin:/sbin:/bin",
           "PROFILE": profile}
    subprocess.run([*unshare_command(), "sh", "-c", script], env=env, timeout=120,
                   check=True)


@pytest.mark.crossprocess
@needs_namespace
def test_the_dry_run_reads_roboteq_class_drives_in_their_own_units(tmp_path: Path) -> None:
    """drives.profile: roboteq on both sides: the identity, the limits written in the
    drive's units (0x3002 in 0.1 A), the supply the commands are scaled by, and the drives
    left switched off (their emergency stop flag)."""
    _run(_SCRIPT.format(setup=NAMESPACE_SETUP), tmp_path, "--set drives.profile=roboteq")
    err = (tmp_path / "check.err").read_text()
    assert (tmp_path / "check.rc").read_text().split() == ["0", "0", "1"], err
    text = (tmp_path / "check.txt").read_text()
    print("\n" + text)
    assert ("r drive (node 1): 'Roboteq-class motor controller' (roboteq_class_drive.eds)"
            in text)
    assert "profile roboteq: reads as CiA 402 state SWITCH_ON_DISABLED (fault flags 0x0010" in text
    assert "commands scaled by 24 V" in text
    assert "0x3001    command watchdog" in text
    report = json.loads((tmp_path / "check.json").read_text())
    r, theta = report["drives"]
    assert r["eds"] == theta["eds"] == "roboteq_class_drive.eds"
    limits = {limit["object"]: limit["value"] for limit in theta["limits"]}
    assert (limits["0x3002"], limits["0x3001"]) == (100, 100)  # 10 A in 0.1 A; 100 ms
    assert [p["name"] for p in r["pdos"]] == ["RPDO1", "TPDO1", "TPDO2"]
    assert r["pdos"][0]["mapped"] == [{"index": 0x2000, "subindex": 1, "bits": 32}]
