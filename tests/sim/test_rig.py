"""The daemon and the emulated drives as separate processes on one bus (tier 3).

udp_multicast inside a private network namespace that each test creates
(rakectl.sim.rig); the test talks to the daemon over its Unix socket and
checks the emulator's ground truth afterwards. Behaviour is asserted; timing
is printed, never asserted.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import time
from pathlib import Path

import pytest

from rakectl.errors import ApiError, RakeError
from rakectl.sim.rig import Bench, emulated_bench, namespaces_unavailable
from tests.cli_run import run_rakectl

CONFIG = Path(__file__).resolve().parents[2] / "config"
EMULATOR = CONFIG / "emulator-demo.yaml"
DAEMON = CONFIG / "rakectl-emulated.yaml"

_reason = namespaces_unavailable()
pytestmark = [pytest.mark.crossprocess,
              pytest.mark.skipif(_reason is not None, reason=f"no network namespace: {_reason}")]


def _truth(out: Path) -> list[dict[str, str]]:
    with open(out / "truth.csv", newline="") as f:
        return list(csv.DictReader(f))


def _states(out: Path) -> list[str]:
    states = []
    for line in (out / "daemon.log").read_text().splitlines():
        if line.startswith("{") and '"event": "state"' in line:
            states.append(json.loads(line)["new"])
    return states


def _armed(bench: Bench) -> None:
    bench.wait_for_state(["disarmed"], 60.0)
    bench.request("arm")
    armed = bench.wait_for_state(["armed"], 15.0)  # through the weight check, about 3 s
    assert armed["weight_check"]["passed"], armed["weight_check"]
    time.sleep(0.3)
    assert all(d["state"] == "operation_enabled" for d in bench.request("status")["drives"])


def test_arm_jog_excavate_stop_against_the_ground_truth(tmp_path: Path) -> None:
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        _armed(bench)
        before = bench.request("status")["tip"]
        for _ in range(10):  # 1 s of jog down at 3 cm/s, commands every 0.1 s
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        time.sleep(0.6)  # silence: the dead-man stops the jog by itself
        after = bench.request("status")
        assert after["state"] == "hold"
        assert after["tip"]["depth_m"] > before["depth_m"] + 0.01
        bench.request("excavate", reach_far_m=1.25, reach_near_m=1.15, target_depth_m=0.01,
                      depth_step_m=0.01, stroke_speed_m_per_s=0.05)
        final = bench.wait_for_state(["hold", "fault"], 120.0)
        assert final["state"] == "hold", final.get("fault")
        excavation = final["excavation"]
        assert excavation["done"] and excavation["object_found"] is None
        assert not excavation["stopped_by_force"]  # a force-limit stop also ends in hold
        bench.request("disarm")
        bench.wait_for_state(["disarmed"], 5.0)
    assert _states(tmp_path) == ["DISARMED", "CHECKING", "ARMED", "JOG", "HOLD", "EXCAVATE",
                                 "HOLD", "DISARMED"]
    truth = _truth(tmp_path)
    # while armed (drives enabled); disarmed, the rake sinks slowly under its own weight
    heights = [float(row["tip_height_m"]) for row in truth
               if row["r_state"] == "OPERATION_ENABLED"]
    assert min(heights) == pytest.approx(-0.01, abs=0.004)  # the lane's depth, really reached
    assert max(float(row["force_down_n"]) for row in truth) < 90.0
    assert all(row["mine_activated"] == "0" for row in truth)
    dumps = list(tmp_path.glob("rakectl-*-shutdown.csv"))
    assert dumps and dumps[0].read_text().startswith("t_s,state,")


def test_an_arm_without_its_counterweight_is_refused_by_the_weight_check(tmp_path: Path
                                                                         ) -> None:
    """The emulated arm without the 8 kg counterweight the clamp is configured for: the
    first arming tries to lift the tip, which the clamp's upward budget (set by the
    configured weight) barely allows with twice the weight: the check faults, that the
    arm did not follow or that it weighs more than configured, naming the counterweight;
    the second arming checks again (the rake never becomes ARMED)."""
    emulator_args = ["--set", "physics.arm.counterweight_kg=0"]
    with emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_args=emulator_args) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        bench.request("arm")
        final = bench.wait_for_state(["fault", "armed"], 15.0)
        assert final["state"] == "fault"  # not lifted, or lifted and weighed too heavy
        assert "19.6 N configured" in final["fault"] and "counterweight" in final["fault"]
        bench.request("reset")
        bench.wait_for_state(["disarmed"], 5.0)
        bench.request("arm")
        assert bench.wait_for_state(["fault", "armed"], 15.0)["state"] == "fault"
    print(f"\nno counterweight → {final['fault']}")
    assert "ARMED" not in _states(tmp_path)


def test_a_bench_whose_emulator_dies_says_why(tmp_path: Path) -> None:
    """The emulator failing at start-up (here: a slave module that does not exist; in the
    field, python-can without msgpack) is named with its log's last line, not only "the
    bench stopped"."""
    with (emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_module="no_such_slave") as bench,
          pytest.raises(RakeError) as stopped):
        bench.wait_for_state(["disarmed"], 60.0)
    message = str(stopped.value)
    assert message.startswith("the bench stopped (exit 4): emulator.log: ")
    assert "No module named no_such_slave" in message
    assert f"see {tmp_path}/daemon.log and {tmp_path}/emulator.log" in message


def test_a_loop_that_cannot_keep_time_is_not_armed_in_enforce_mode(tmp_path: Path) -> None:
    """rt_mode enforce with a p99 limit no loop meets (1 µs): arming is refused with one
    line naming the key and the excess, and status says why; nothing moved."""
    daemon_args = ["--set", "daemon.rt_mode=enforce", "--set",
                   "daemon.arm_max_latency_p99_us=1", "--set", "daemon.arm_timing_s=0.5"]
    with emulated_bench(tmp_path, EMULATOR, DAEMON, daemon_args=daemon_args) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        time.sleep(1.0)
        with pytest.raises(ApiError) as refused:
            bench.request("arm")
        status = bench.request("status")
    message = str(refused.value)
    assert "cannot arm: the loop's p99 wake-up latency is" in message
    assert "above daemon.arm_max_latency_p99_us (1 µs) by" in message
    assert "daemon.rt_mode: enforce" in message
    assert status["state"] == "disarmed" and "arm_max_latency_p99_us" in status["timing_check"]
    print(f"\nenforce → {message}")


def test_a_dump_to_a_path_it_cannot_write_is_refused_and_the_loop_goes_on(tmp_path: Path
                                                                          ) -> None:
    """A dump request is refused, with the file and why, when its path cannot be written
    (no request may end the daemon); `rakectl dump` returns once the file is complete."""
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        _armed(bench)
        socket_path = str(bench.socket)
        bad = run_rakectl("dump", "--socket", socket_path, "--path", "/nonexistent/x.csv")
        assert bad.returncode != 0
        assert "cannot dump" in bad.stderr and "/nonexistent/x.csv" in bad.stderr
        assert "no directory '/nonexistent'" in bad.stderr and len(bad.stderr.splitlines()) == 1
        with pytest.raises(ApiError, match="must be absolute"):
            bench.request("dump", path="relative.csv")
        good = run_rakectl("dump", "--socket", socket_path, "--path", str(tmp_path / "asked.csv"))
        assert good.returncode == 0, good.stderr
        assert (tmp_path / "asked.csv").read_text().startswith("t_s,state,")
        assert not (tmp_path / "asked.csv.partial").exists()
        status = bench.request("status")
        assert status["state"] == "armed" and status["dumps"] == {"pending": [], "failed": []}
        bench.request("disarm")


def test_the_operator_flow_on_the_cli_with_its_exit_statuses(tmp_path: Path) -> None:
    """What an operator types, as processes: each command's exit status says what happened."""
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        sock = ["--socket", str(bench.socket)]
        steps = [
            (("arm",), 0, "arm: armed"),
            (("jog", "--height", "-0.02", "--duration", "0.5"), 0, "jogged"),
            (("excavate", "--reach-far", "1.25", "--reach-near", "1.15", "--depth", "0.005",
              "--step", "0.005"), 0, "excavate"),
            (("estop",), 0, "estop: estop"),
            (("jog", "--height", "0.01", "--duration", "0.3"), 1, "cannot jog while estop"),
            (("reset",), 0, "reset: disarmed"),
            (("dump", "--path", str(tmp_path / "flow.csv")), 0, "dump: "),
            (("arm",), 0, "arm: armed"),
            (("disarm",), 0, "disarm: disarmed"),
            (("shutdown",), 0, "shutdown"),
        ]
        for args, status, text in steps:
            done = run_rakectl(args[0], *sock, *args[1:])
            assert done.returncode == status, (args, done.stdout, done.stderr)
            assert text in done.stdout + done.stderr, (args, done.stdout, done.stderr)
        bench.process.wait(20.0)
    assert (tmp_path / "flow.csv").read_text().startswith("t_s,state,")
    assert _states(tmp_path) == ["DISARMED", "CHECKING", "ARMED", "JOG", "HOLD", "EXCAVATE",
                                 "HOLD", "ESTOP", "DISARMED", "ARMED", "DISARMED"]


def test_sigkill_of_the_controller_leaves_the_drives_at_0_v(tmp_path: Path) -> None:
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        _armed(bench)
        pid = bench.request("status")["pid"]
        killed_at = time.time()
        os.kill(pid, signal.SIGKILL)
        time.sleep(1.0)
    faults = [json.loads(line) for line in (tmp_path / "emulator.log").read_text().splitlines()
              if '"drive_fault"' in line]
    watchdog = [f for f in faults if "WATCHDOG" in f.get("detail", "")]
    assert {f["node_id"] for f in watchdog} == {1, 2}
    truth = _truth(tmp_path)
    last = truth[-1]
    assert float(last["voltage_r_v"]) == 0.0 and float(last["voltage_theta_v"]) == 0.0
    assert last["r_state"] == "FAULT" and last["theta_state"] == "FAULT"
    first_s = min(_epoch(f["timestamp"]) for f in watchdog)
    print(f"\nSIGKILL → first watchdog EMCY after {1e3 * (first_s - killed_at):.1f} ms "
          "(configured watchdog 100 ms on the emulated bench; includes the kill's delivery)")


def _epoch(stamp: str) -> float:
    from datetime import datetime

    return datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


def test_a_drive_that_goes_silent_faults_the_controller(tmp_path: Path) -> None:
    emulator_args = ["--set", "faults.silence_node_id=2", "--set", "faults.silence_after_s=6"]
    with emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_args=emulator_args) as bench:
        _armed(bench)
        final = bench.wait_for_state(["fault"], 20.0)
        reset = run_rakectl("reset", "--socket", str(bench.socket))  # the drive is still silent
    assert reset.returncode == 1, reset.stdout + reset.stderr
    assert "reset: fault (reset failed: " in reset.stdout and "θ drive" in reset.stdout
    assert "θ drive (node 2)" in final["fault"]
    bus = final["bus"]
    assert bus["tpdo_received_r"] > bus["tpdo_received_theta"]  # r kept answering
    print(f"\nsilent drive → {final['fault']}")


def test_five_percent_frame_loss_degrades_but_keeps_running(tmp_path: Path) -> None:
    emulator_args = ["--set", "faults.rx_loss_probability=0.05",
                     "--set", "faults.tx_loss_probability=0.05"]
    with emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_args=emulator_args) as bench:
        _armed(bench)
        time.sleep(5.0)
        status = bench.request("status")
    assert status["state"] == "armed", status.get("fault")
    bus = status["bus"]
    missed = bus["tpdo_missed_r"] + bus["tpdo_missed_theta"]
    received = bus["tpdo_received_r"] + bus["tpdo_received_theta"]
    assert missed > 0 and received > 0
    print(f"\n5 % loss each way: TPDO1 missed {missed} of {missed + received} "
          f"({100 * missed / (missed + received):.1f} %), state still armed")


def test_systemd_notify_sequence_and_sigterm(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Under a test-owned NOTIFY_SOCKET: READY=1 only after bring-up and valid feedback,
    WATCHDOG=1 while the loop runs, STOPPING=1 on SIGTERM; then 0 V, drives disabled,
    the recorder dumped and exit status 0."""
    notify_path = tmp_path / "notify.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(notify_path))
    listener.settimeout(0.05)
    monkeypatch.setenv("NOTIFY_SOCKET", str(notify_path))
    monkeypatch.setenv("WATCHDOG_USEC", "1000000")
    messages: list[str] = []

    def drain() -> None:
        while True:
            try:
                messages.append(listener.recv(4096).decode())
            except TimeoutError:
                return

    try:
        with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
            bench.wait_for_state(["disarmed"], 60.0)
            bench.request("arm")
            bench.wait_for_state(["armed"], 10.0)
            time.sleep(1.0)
            drain()
            os.kill(bench.request("status")["pid"], signal.SIGTERM)
            bench.process.wait(20.0)
            assert bench.process.returncode == 0
            drain()
    finally:
        listener.close()
    kinds = [m.split("\n")[0].split("=")[0] for m in messages]
    ready = kinds.index("READY")
    assert any("bringing up" in m for m in messages[:ready])  # READY only after bring-up
    assert "WATCHDOG" in kinds[ready:]
    assert kinds.index("STOPPING") > ready
    assert any("disarmed" in m for m in messages if m.startswith("READY"))
    assert list(tmp_path.glob("rakectl-*-shutdown.csv"))
    last = _truth(tmp_path)[-1]
    assert float(last["voltage_r_v"]) == 0.0 and float(last["voltage_theta_v"]) == 0.0
    assert last["r_state"] != "OPERATION_ENABLED" and last["theta_state"] != "OPERATION_ENABLED"


def test_sighup_stops_the_daemon_as_sigterm_does(tmp_path: Path) -> None:
    """SIGHUP (its terminal closed) ended the daemon at once: no stop, no dump, the drives
    at 0 V only by their watchdog, the socket left. It stops it as SIGTERM does."""
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        bench.request("arm")
        bench.wait_for_state(["armed"], 10.0)
        os.kill(bench.request("status")["pid"], signal.SIGHUP)
        bench.process.wait(20.0)
        assert bench.process.returncode == 0
        assert not bench.socket.exists()
    assert list(tmp_path.glob("rakectl-*-shutdown.csv"))
    last = _truth(tmp_path)[-1]
    assert float(last["voltage_r_v"]) == 0.0 and float(last["voltage_theta_v"]) == 0.0
    assert last["r_state"] != "OPERATION_ENABLED" and last["theta_state"] != "OPERATION_ENABLED"


def test_the_start_up_cyclictest_is_the_reference_in_status(tmp_path: Path) -> None:
    """daemon.startup_cyclictest_s: before bring-up the daemon measures the machine's own
    wake-up latency with cyclictest, reports it in status and the journal; without
    cyclictest it says why (the install line)."""
    with emulated_bench(tmp_path, EMULATOR, DAEMON,
                        daemon_args=["--set", "daemon.startup_cyclictest_s=1"]) as bench:
        reference = bench.wait_for_state(["disarmed"], 60.0)["timing_reference"]
    print(f"\nstart-up reference: {reference}")
    if shutil.which("cyclictest") is None:
        assert "apt-get install -y rt-tests" in reference["reason"]
    else:
        assert reference["label"].startswith("cyclictest -m -p 80")
        assert 0.0 < reference["p50_us"] <= reference["p99_us"] <= reference["max_us"]
        assert reference["samples"] >= 500
    assert any('"event": "timing_reference"' in line
               for line in (tmp_path / "daemon.log").read_text().splitlines())
