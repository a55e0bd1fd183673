"""Deterministic replay of a recorded bus trace (rakectl.daemon.replay, ``rakectl replay``).

The recording is a real run: the daemon (``rakectl run`` with ``bus.trace_path``) and the
emulated drives as separate processes on udp_multicast in a private network namespace
(rakectl.sim.rig), driven over the command socket. Its wall-clock inputs are provoked
on purpose: the emulator is stopped (SIGSTOP) until the daemon finds its heartbeats
lost, and the daemon itself is stopped for tens of milliseconds (an overrun of many
deadlines). The replay then runs offline and must reproduce every frame the daemon sent.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from rakectl.api.schema import decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.cli.main import main
from rakectl.config.loader import load_settings
from rakectl.config.settings import Settings
from rakectl.daemon.events import EventLog
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.inputs import MAX_SEND_FAILURES, InputLog, sidecar_path
from rakectl.daemon.loop import Daemon
from rakectl.daemon.recording import read_inputs
from rakectl.daemon.replay import replay
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.states import DaemonState
from rakectl.drive.canbus import DEFAULT_TRACE_CAPACITY, TraceRecorder
from rakectl.drive.client import DriveClient
from rakectl.errors import ApiError, CommandRejected
from rakectl.sim.rig import Bench, emulated_bench, namespaces_unavailable

CONFIG = Path(__file__).resolve().parents[2] / "config"
EMULATOR = CONFIG / "emulator-demo.yaml"
DAEMON = CONFIG / "rakectl-emulated.yaml"

_reason = namespaces_unavailable()
needs_namespace = pytest.mark.skipif(_reason is not None,
                                     reason=f"no network namespace: {_reason}")


@dataclass(frozen=True)
class Recording:
    trace: Path
    inputs: list[dict[str, object]]

    @property
    def start_frame(self) -> int:
        return int(self.inputs[0]["frame"])  # type: ignore[call-overload]


def _emulator_pid(bench: Bench) -> int:
    """The emulator's process: the bench script's child running ``-m drivers``."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            status = (entry / "status").read_text()
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        parent = next(int(line.split()[1]) for line in status.splitlines()
                      if line.startswith("PPid:"))
        if parent == bench.process.pid and b"drivers" in cmdline:
            return int(entry.name)
    raise AssertionError("the emulator's process was not found")


def _paused(pid: int, seconds: float) -> None:
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        os.kill(pid, signal.SIGCONT)


def _reset_until_disarmed(bench: Bench) -> None:
    for _ in range(5):
        try:
            bench.request("reset")
            bench.wait_for_state(["disarmed"], 3.0)
            return
        except (ApiError, TimeoutError):
            time.sleep(0.3)
    raise AssertionError(f"no reset: {bench.request('status')}")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    out = tmp_path_factory.mktemp("replay")
    trace = out / "trace.log"
    with emulated_bench(out, EMULATOR, DAEMON,
                        daemon_args=[f"--set bus.trace_path={trace}"]) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        _paused(_emulator_pid(bench), 1.0)  # no heartbeat for 1 s: above the 0.5 s timeout
        faulted = bench.wait_for_state(["fault"], 5.0)
        assert "no heartbeat" in str(faulted["fault"]), faulted
        _reset_until_disarmed(bench)
        state: dict[str, object] = {"state": "never armed"}
        for _ in range(3):  # the arming is not under test: a loaded host may fault its check,
            try:  # and the drives, paused with the emulator, may report the lost heartbeat late
                bench.request("arm")
            except CommandRejected:  # faulted again after the reset: reset once more
                _reset_until_disarmed(bench)
                continue
            state = bench.wait_for_state(["armed", "fault"], 15.0)
            if state["state"] == "armed":
                break
            _reset_until_disarmed(bench)
        assert state["state"] == "armed", state
        daemon_pid = int(bench.request("status")["pid"])  # type: ignore[call-overload]
        _paused(daemon_pid, 0.03)  # the loop sleeps through ~30 deadlines
        for _ in range(5):
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        bench.request("stop")
        time.sleep(0.2)
        bench.request("estop")
        time.sleep(0.2)
        _reset_until_disarmed(bench)
    lines = sidecar_path(trace).read_text().splitlines()
    return Recording(trace, [json.loads(line) for line in lines])


def _sent_after(trace: Path, start: int) -> int:
    """Frames the daemon sent in its loop, counted from the file itself."""
    lines = [line for line in trace.read_text().splitlines() if line.strip()]
    return sum(1 for line in lines[start:] if line.endswith(" T"))


@pytest.mark.crossprocess
@needs_namespace
def test_the_sidecar_holds_the_commands_overruns_and_the_lost_heartbeat(
        recording: Recording) -> None:
    kinds = [entry["kind"] for entry in recording.inputs]
    assert kinds[0] == "start" and kinds[-1] == "end"
    commands = [entry["request"]["cmd"] for entry in recording.inputs  # type: ignore[index]
                if entry["kind"] == "command"]
    for cmd in ("arm", "jog", "stop", "estop", "reset", "shutdown"):
        assert cmd in commands, commands
    assert "status" not in commands  # read-only requests are not inputs
    assert "heartbeat_lost" in kinds
    assert max(int(e["skipped"]) for e in recording.inputs  # type: ignore[call-overload]
               if e["kind"] == "overrun") >= 10


@pytest.mark.crossprocess
@needs_namespace
def test_a_recorded_run_is_reproduced_frame_for_frame(recording: Recording) -> None:
    settings = load_settings(DAEMON, [], root=Settings)
    result = replay(recording.trace, settings)
    assert result.ok, result.message()
    assert result.reproduced == _sent_after(recording.trace, recording.start_frame) > 1000
    for state in ("DISARMED", "FAULT", "CHECKING", "ARMED", "JOG", "HOLD", "ESTOP"):
        assert state in result.states, result.states
    assert "no heartbeat" in result.faults[0], result.faults  # as the run's status said
    end = recording.inputs[-1]
    assert result.ticks == end["after_tick"]


@pytest.mark.crossprocess
@needs_namespace
def test_the_cli_says_how_many_frames_it_reproduced(recording: Recording,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(recording.trace), "--config", str(DAEMON)]) == 0
    out = capsys.readouterr().out.strip()
    sent = _sent_after(recording.trace, recording.start_frame)
    assert out.startswith(f"replay: {sent} frames reproduced, frame for frame"), out


@pytest.mark.crossprocess
@needs_namespace
@pytest.mark.parametrize("left_out", ["heartbeat_lost", "overrun"])
def test_without_a_wall_clock_input_the_replay_diverges(recording: Recording, tmp_path: Path,
                                                        left_out: str) -> None:
    """The sidecar's record is what the run depended on: without it, the replay does not
    do what the run did (a heartbeat lost while disarmed changes no frame by itself when a
    drive's own fault follows: then the reason of the fault differs)."""
    def kept(entry: dict[str, object]) -> bool:
        if left_out == "overrun":  # the daemon stopped for 30 ms, not the machine's jitter
            return not (entry["kind"] == "overrun"
                        and int(entry["skipped"]) >= 10)  # type: ignore[call-overload]
        return entry["kind"] != left_out

    inputs = tmp_path / "inputs.jsonl"
    inputs.write_text("".join(json.dumps(e) + "\n" for e in recording.inputs if kept(e)))
    result = replay(recording.trace, load_settings(DAEMON, [], root=Settings), inputs)
    heartbeat_faults = [reason for reason in result.faults if "no heartbeat" in reason]
    assert result.mismatch or (left_out == "heartbeat_lost" and not heartbeat_faults), \
        (result.message(), result.faults)


def _ticks_of_lines(recording: Recording) -> dict[int, int]:
    """The tick (the daemon's counter) of each loop frame's line, from the trace's SYNCs
    and the overruns in the sidecar: a tick's frames end with its SYNC (and heartbeat)."""
    skipped = {int(e["after_tick"]): int(e["skipped"])  # type: ignore[call-overload]
               for e in recording.inputs if e["kind"] == "overrun"}
    numbered = [(n, line) for n, line in enumerate(recording.trace.read_text().splitlines(), 1)
                if line.strip()]
    tick, ticks, after_sync = 0, {}, True
    for number, line in numbered[recording.start_frame:]:
        frame = line.split()[2]
        if after_sync and not frame.startswith("70A#"):  # the controller's heartbeat
            tick += 1 + skipped.get(tick, 0)
            after_sync = False
        ticks[number] = tick
        if frame.startswith("080#") and line.endswith(" T"):
            after_sync = True
    return ticks


@pytest.mark.crossprocess
@needs_namespace
def test_a_changed_feedback_frame_is_the_first_mismatch_at_its_tick(
        recording: Recording, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    jogs = [int(e["after_tick"]) for e in recording.inputs  # type: ignore[call-overload]
            if e["kind"] == "command" and e["request"]["cmd"] == "jog"]  # type: ignore[index]
    ticks = _ticks_of_lines(recording)
    lines = recording.trace.read_text().splitlines()

    def last_of_its_drain(n: int) -> bool:  # no later r TPDO1 before the tick's sends
        for line in lines[n:]:
            if line.endswith(" T"):
                return True
            if line.split()[2].startswith("181#"):
                return False
        return False

    target = next(n for n, tick in ticks.items()  # the r drive's TPDO1, mid-jog, the one
                  if tick > jogs[0] + 50  # its tick decodes (a loaded host delivers several)
                  and lines[n - 1].split()[2].startswith("181#") and last_of_its_drain(n))
    head, data = lines[target - 1].split()[2].split("#")
    counts = int.from_bytes(bytes.fromhex(data[:8]), "little", signed=True) + 2000
    changed = counts.to_bytes(4, "little", signed=True).hex().upper() + data[8:]
    lines[target - 1] = lines[target - 1].replace(f"{head}#{data}", f"{head}#{changed}")
    tampered = tmp_path / "tampered.log"
    tampered.write_text("\n".join(lines) + "\n")
    sidecar_path(tampered).write_text(sidecar_path(recording.trace).read_text())

    assert main(["replay", str(tampered), "--config", str(DAEMON)]) == 1
    out = capsys.readouterr().out.strip()
    assert "\n" not in out
    tick = ticks[target]
    sent_in_tick = [n for n, t in ticks.items() if t == tick and lines[n - 1].endswith(" T")]
    assert out.startswith(f"replay: mismatch at tick {tick}, trace line "), out
    line = int(out.split("trace line ")[1].split(":")[0])
    assert line in sent_in_tick and line > target, (out, target, sent_in_tick)
    assert "expected 201#" in out or "expected 202#" in out, out


def _cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = main(args)
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    return status, captured.err.strip()


@pytest.mark.crossprocess
@needs_namespace
def test_bad_input_is_one_line_and_exit_status_2(recording: Recording, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    lines = recording.trace.read_text().splitlines()
    garbled = tmp_path / "garbled.log"
    garbled.write_text("\n".join([*lines[:9], "(12.5) can0 not-a-frame R", *lines[9:]]) + "\n")
    sidecar_path(garbled).write_text(sidecar_path(recording.trace).read_text())
    status, err = _cli(["replay", str(garbled), "--config", str(DAEMON)], capsys)
    assert status == 2 and err.startswith(f"rakectl: error: {garbled}, line 10: not a candump")
    assert "\n" not in err

    lonely = tmp_path / "lonely.log"
    lonely.write_text(recording.trace.read_text())
    status, err = _cli(["replay", str(lonely), "--config", str(DAEMON)], capsys)
    assert status == 2 and f"{sidecar_path(lonely)}: no such file" in err, err

    status, err = _cli(["replay", str(tmp_path / "absent.log")], capsys)
    assert status == 2 and err == f"rakectl: error: {tmp_path / 'absent.log'}: no such trace"

    status, err = _cli(["replay", str(recording.trace), "--config", str(DAEMON),
                        "--set", "drives.feedback_timeout_cycles=3"], capsys)
    assert status == 2 and "drives.feedback_timeout_cycles is 3 here but was 25" in err, err

    cut = tmp_path / "cut.log"
    cut.write_text(recording.trace.read_text())
    sidecar = sidecar_path(recording.trace).read_text().splitlines()
    sidecar_path(cut).write_text("\n".join([*sidecar[:3], sidecar[3][:20], *sidecar[4:]]))
    status, err = _cli(["replay", str(cut), "--config", str(DAEMON)], capsys)
    assert status == 2 and f"{sidecar_path(cut)}, line 4: not JSON" in err, err

    def hostile(entry: str) -> str:  # a sidecar with one more line after the start entry
        path = tmp_path / f"hostile-{len(list(tmp_path.iterdir()))}.log"
        path.write_text(recording.trace.read_text())
        sidecar_path(path).write_text("\n".join([sidecar[0], entry, *sidecar[1:]]) + "\n")
        status, err = _cli(["replay", str(path), "--config", str(DAEMON)], capsys)
        assert status == 2 and "\n" not in err, err
        assert err.startswith(f"rakectl: error: {sidecar_path(path)}, line 2: "), err
        return err

    victim = tmp_path / "victim.txt"
    victim.write_text("kept")
    err = hostile(json.dumps({"kind": "command", "after_tick": 0,
                              "request": {"cmd": "dump", "path": str(victim)}}))
    assert "'dump' is not a command a run records" in err and victim.read_text() == "kept"
    assert "not an entry of the trace's inputs (ValueError)" in hostile(
        '{"kind": "overrun", "after_tick": ' + "9" * 5000 + ', "skipped": 1}')
    assert "not an entry of the trace's inputs (RecursionError)" in hostile(
        "[" * 100000 + "]" * 100000)
    assert "'skipped' must be an integer from 1 to 2**53, got a huge integer" in hostile(
        json.dumps({"kind": "overrun", "after_tick": 0, "skipped": 10 ** 400}))

    accent = tmp_path / "accent.log"  # a byte that is not text, far into the file
    data = recording.trace.read_bytes().splitlines(keepends=True)
    accent.write_bytes(b"".join([*data[:150], b"(1.0) can0 201#00\xe9 T\n", *data[150:]]))
    sidecar_path(accent).write_text(sidecar_path(recording.trace).read_text())
    status, err = _cli(["replay", str(accent), "--config", str(DAEMON)], capsys)
    assert status == 2 and err == f"rakectl: error: {accent}, line 151: not text", err


@pytest.mark.crossprocess
@needs_namespace
def test_a_trace_cut_short_in_a_line_is_replayed_up_to_its_end(recording: Recording,
                                                              tmp_path: Path) -> None:
    """A daemon killed while its trace's writer held part of a line leaves a last line
    with no end: the frames before it are compared, and the replay says where the trace
    ends (not that it is garbled)."""
    data = recording.trace.read_bytes()
    lines = data.splitlines(keepends=True)
    keep = len(lines) * 2 // 3
    cut = tmp_path / "cut.log"
    cut.write_bytes(b"".join(lines[:keep]) + lines[keep][:17])
    sidecar_path(cut).write_text(sidecar_path(recording.trace).read_text())
    result = replay(cut, load_settings(DAEMON, [], root=Settings))
    assert not result.ok and not result.mismatch, result.message()
    assert f"the trace ends at frame {keep} of the" in result.incomplete
    sent = sum(1 for line in lines[recording.start_frame:keep] if line.rstrip().endswith(b" T"))
    assert result.reproduced == sent > 1000



# --------------------------------------------------------------------------- failed sends


class _LinkDown(can.BusABC):
    """The controller's side of a real virtual bus whose link can be taken down: every
    send then fails as socketcan's does (ENETDOWN), as the drive client meets it."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(channel="link")
        self._bus, self.down = bus, False

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._bus.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.down:
            raise can.CanOperationError("Failed to transmit: Network is down", 100)
        self._bus.send(msg, timeout)


def _recorded_in_lockstep(out: Path, capacity: int = DEFAULT_TRACE_CAPACITY,
                          undrained_ticks: int = 0) -> tuple[Path, Settings, LockstepRig]:
    """A lock-step run (rakectl.bench.tick's rig: the daemon and the emulated drives on a
    virtual bus) recorded as the service records one, with the link down for 5 ticks
    while armed: the drives hear no SYNC, the daemon faults. ``undrained_ticks`` armed
    ticks before that go by with no slack to write the trace's ring of ``capacity``."""
    rig = LockstepRig(out)
    settings = rig.daemon.settings
    trace_path = out / "lockstep.log"
    trace = TraceRecorder(can.CanutilsLogWriter(trace_path, channel="can0"), "can0",
                          capacity)
    inputs = InputLog(open(sidecar_path(trace_path), "w", encoding="utf-8"))  # noqa: SIM115
    link = _LinkDown(rig.controller_bus)
    client = DriveClient(link, settings.drives, settings.motors, settings.rate_hz, trace)
    daemon = Daemon(settings, client, Notifier(None), out)
    daemon.trace, daemon.inputs, rig.daemon = trace, inputs, daemon
    handle = make_handler(daemon)

    def ticks(count: int) -> None:
        for _ in range(count):
            rig.tick()
            trace.drain(64)
            inputs.drain()

    rig.bring_up()
    ticks(300)
    assert daemon.state is DaemonState.DISARMED, daemon.fault_reason
    handle(decode_request(b'{"cmd": "arm"}'))  # type: ignore[arg-type]
    for _ in range(60):
        ticks(100)
        if daemon.state is DaemonState.ARMED:
            break
    assert daemon.state is DaemonState.ARMED, daemon.fault_reason
    ticks(100)
    for _ in range(undrained_ticks):
        rig.tick()
    link.down = True
    ticks(5)
    link.down = False
    ticks(100)
    daemon.finish()
    trace.close()
    inputs.close()
    link.shutdown()  # (the virtual bus under it: rig.close)
    return trace_path, settings, rig


def test_failed_sends_are_recorded_and_fail_again_in_the_replay(tmp_path: Path) -> None:
    trace, settings, rig = _recorded_in_lockstep(tmp_path)
    try:
        assert rig.daemon.state is DaemonState.FAULT  # stale feedback, or the sends
    finally:
        rig.close()
    entries = [json.loads(line) for line in sidecar_path(trace).read_text().splitlines()]
    failed = [e for e in entries if e["kind"] == "send_failed"]
    assert len(failed) >= 15 and all("Network is down" in e["error"] for e in failed)
    result = replay(trace, settings)
    assert result.ok, result.message()
    assert result.reproduced == _sent_after(trace, entries[0]["frame"])
    assert result.states[-1] == "FAULT"

    without = tmp_path / "without.jsonl"  # the failures are what made it fault
    without.write_text("".join(json.dumps(e) + "\n" for e in entries
                               if e["kind"] != "send_failed"))
    diverged = replay(trace, settings, without)
    assert not diverged.ok and diverged.mismatch.startswith(f"tick {failed[0]['tick']}, ")
    assert "no end entry" not in diverged.mismatch

    cut = tmp_path / "cut.jsonl"  # cut short by hand before the arm command: no end entry
    arm = next(i for i, e in enumerate(entries) if e["kind"] == "command")
    cut.write_text("".join(json.dumps(e) + "\n" for e in entries[:arm]))
    last = max([0, *(e.get("after_tick", e.get("tick", 0)) for e in entries[1:arm])])
    diverged = replay(trace, settings, cut)
    assert not diverged.ok and diverged.mismatch.endswith(
        f" (its inputs {cut} have no end entry: the run was killed, or the file was cut "
        f"short; their last entry is at tick {last})"), diverged.mismatch


def test_a_trace_whose_ring_overflowed_is_replayed_up_to_its_first_lost_frame(
        tmp_path: Path) -> None:
    """300 armed ticks with no slack to write a ring of 1024 frames (5 frames a tick; the
    ring holds the bring-up's frames too, written out at the first tick): the trace is
    complete only up to the first frame the ring dropped. The replay reproduces every frame
    sent before it, then stops there, saying so (not as a mismatch)."""
    trace, settings, rig = _recorded_in_lockstep(tmp_path, capacity=1024, undrained_ticks=300)
    rig.close()
    entries = [json.loads(line) for line in sidecar_path(trace).read_text().splitlines()]
    end = entries[-1]
    assert end["kind"] == "end" and end["dropped"] > 0, end
    first_lost = int(end["first_dropped_at"])
    lines = [line for line in trace.read_text().splitlines() if line.strip()]
    sent_before = sum(1 for line in lines[entries[0]["frame"]:first_lost] if line.endswith(" T"))
    result = replay(trace, settings)
    assert not result.ok and not result.mismatch, result.message()
    assert f"lost {end['dropped']} frames from frame {first_lost} on" in result.incomplete
    assert result.reproduced == sent_before > 1000


def test_a_link_down_for_long_is_recorded_up_to_a_bound_then_as_lost(tmp_path: Path) -> None:
    """Sends failing every tick (a link down while disarmed: nothing faults) would write
    ~2 GB an hour: past MAX_SEND_FAILURES the inputs count them as lost, and every entry
    after; the end entry is still written, and a replay stops before the first tick that
    may be incomplete."""
    path = tmp_path / "flood.log.inputs.jsonl"
    log = InputLog(open(path, "w", encoding="utf-8"))  # noqa: SIM115 (closed below)
    log.start(0, (0x0237, 0x0237), Settings())
    msg = can.Message(arbitration_id=0x201, data=b"\x00\x00\x0f\x00", is_extended_id=False)
    error = can.CanOperationError("Failed to transmit: Network is down", 100)
    extra = 25
    for attempt in range(MAX_SEND_FAILURES + extra):
        log.send_failed(1 + attempt // 3, attempt, 0, msg, error)
        if attempt % 100 == 0:
            log.drain(1000)
    stop = decode_request(b'{"cmd": "stop"}')
    assert not isinstance(stop, str)
    log.command(MAX_SEND_FAILURES, stop)  # after the loss: lost too
    log.end(MAX_SEND_FAILURES + 1, "stop requested", None)
    log.close()
    entries = [json.loads(line) for line in path.read_text().splitlines()]
    kinds = [e["kind"] for e in entries]
    assert kinds.count("send_failed") == MAX_SEND_FAILURES
    assert "command" not in kinds and kinds[-2:] == ["end", "lost"]
    lost = [e for e in entries if e["kind"] == "lost"]  # written as the slack can
    assert sum(e["entries"] for e in lost) == extra + 1
    assert all(e["complete_entries"] == 1 + MAX_SEND_FAILURES for e in lost)
    assert entries[1]["data"] == "00000f00" and entries[1]["id"] == 0x201
    inputs = read_inputs(path)
    last = entries[MAX_SEND_FAILURES]["tick"]
    assert inputs.end is not None and inputs.complete_until_tick == last


def test_a_trace_the_disk_cannot_take_ends_the_recording_not_the_loop(tmp_path: Path) -> None:
    """The trace and its inputs on /dev/full (every write: ENOSPC): the slack's writing
    fails, one trace_failed event is logged, the recording stops, the loop goes on."""
    rig = LockstepRig(tmp_path)
    settings = rig.daemon.settings
    trace = TraceRecorder(can.CanutilsLogWriter("/dev/full", channel="can0"), "can0")
    inputs = InputLog(open("/dev/full", "w", encoding="utf-8"))  # noqa: SIM115
    client = DriveClient(rig.controller_bus, settings.drives, settings.motors,
                         settings.rate_hz, trace)
    daemon = Daemon(settings, client, Notifier(None), tmp_path)
    daemon.trace, rig.daemon = trace, daemon
    events: list[str] = []

    class Log:
        def __getattr__(self, level: str) -> Callable[..., None]:
            return lambda name, **fields: events.append(name)

    daemon.events = EventLog(Log())
    try:
        rig.bring_up()  # (the inputs' start entry is written at once: not on /dev/full)
        daemon.inputs = inputs
        inputs.overrun(daemon.ticks, 1)  # something pending for the inputs too
        for _ in range(300):
            rig.tick()
            daemon._write_trace()
            daemon.events.flush(daemon.state.name)
        assert events.count("trace_failed") == 1, events
        assert daemon.trace is None and daemon.inputs is None
        assert daemon.state is DaemonState.DISARMED and daemon.ticks >= 300
    finally:
        rig.close()
        for recording in (trace, inputs):
            with contextlib.suppress(OSError):
                recording.close()


@pytest.mark.crossprocess
@needs_namespace
def test_a_run_on_roboteq_class_drives_is_reproduced_frame_for_frame(tmp_path: Path) -> None:
    """drives.profile: roboteq on both processes: the trace holds the commands in ‰ and the
    power requests over SDO the hot path sent (on to arm, off at the e-stop), and the
    replay with the same profile reproduces every frame of them."""
    trace = tmp_path / "trace.log"
    profile = "--set drives.profile=roboteq"
    with emulated_bench(tmp_path, EMULATOR, DAEMON, emulator_args=[profile],
                        daemon_args=[f"--set bus.trace_path={trace}", profile]) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        bench.request("arm")
        assert bench.wait_for_state(["armed", "fault"], 15.0)["state"] == "armed"
        for _ in range(5):
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        bench.request("estop")
        time.sleep(0.3)
        _reset_until_disarmed(bench)
    start = int(json.loads(sidecar_path(trace).read_text().splitlines()[0])["frame"])
    loop_frames = list(can.CanutilsLogReader(str(trace)))[start:]
    power = [f for f in loop_frames if not f.is_rx and 0x601 <= f.arbitration_id <= 0x602]
    assert {(f.arbitration_id, f.data[1]) for f in power} >= {
        (0x601, 0x0D), (0x601, 0x0C), (0x602, 0x0D), (0x602, 0x0C)}  # 0x200D on, 0x200C off
    settings = load_settings(DAEMON, ["drives.profile=roboteq"], root=Settings)
    result = replay(trace, settings)
    assert result.ok, result.message()
    assert result.reproduced == _sent_after(trace, start) > 1000
    for state in ("DISARMED", "CHECKING", "ARMED", "JOG", "ESTOP"):
        assert state in result.states, result.states


def test_a_trace_shorter_than_its_inputs_start_is_one_line(
        caplog: pytest.LogCaptureFixture) -> None:
    """A trace of another run (fewer frames than its inputs say came before the loop): the
    refusal was followed by python-can's 'ReplayBus was not properly shut down'."""
    import gc

    from rakectl.daemon.replay import ReplayBus
    from rakectl.errors import TraceError

    with pytest.raises(TraceError, match="0 frames in the trace, but its inputs say the loop "
                       "began after frame 406: not this run's trace"):
        ReplayBus(iter([]), 406, {}, None)
    gc.collect()
    assert "not properly shut down" not in caplog.text
