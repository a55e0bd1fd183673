"""What another node on the bus can do to the drives while the daemon runs, and what the
daemon does about it: the real daemon and drive client against the emulated drives on a
python-can `virtual` channel in lock-step (rakectl.bench.tick.LockstepRig), and a third
bus on the same channel playing another CANopen master (an SDO or NMT tool, a second SYNC
producer). A drive taken out of OPERATION ENABLED or out of NMT OPERATIONAL by someone
else is a latched fault naming it and never enabled again behind the operator's back; a
reset recovers from what a reset can recover from."""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from rakectl.bench.tick import LockstepRig
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.nmt import NmtState
from tests.rig_commands import command, disarmed_rig


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[LockstepRig]:
    with disarmed_rig(tmp_path) as rig:
        yield rig


@pytest.fixture
def other(rig: LockstepRig) -> Iterator[can.BusABC]:
    """Another node on the daemon's channel."""
    bus = can.Bus(interface="virtual", channel=rig.controller_bus.channel_id)
    yield bus
    bus.shutdown()


def _send(other: can.BusABC, can_id: int, data: bytes) -> None:
    other.send(can.Message(arbitration_id=can_id, is_extended_id=False, data=data))


def _controlword(other: can.BusABC, node: int, value: int) -> None:
    """An expedited SDO download of 0x6040 from another master."""
    _send(other, 0x600 + node, struct.pack("<BHBH", 0x2B, 0x6040, 0, value) + bytes(2))


def _ticks(rig: LockstepRig, n: int) -> None:
    for _ in range(n):
        rig.tick()


def _arm(rig: LockstepRig) -> None:
    command(rig, b'{"cmd": "arm"}')
    rig.until(DaemonState.ARMED, 8000)
    _ticks(rig, 300)
    assert rig.daemon.state is DaemonState.ARMED, rig.daemon.fault_reason


def _reset(rig: LockstepRig) -> None:
    command(rig, b'{"cmd": "reset"}')
    _ticks(rig, 1200)


@pytest.mark.parametrize(("controlword", "left_for"), [
    (0x0000, "SWITCH ON DISABLED"), (0x0002, "QUICK STOP ACTIVE")])
def test_a_drive_taken_out_of_operation_enabled_while_armed_is_a_fault(
        rig: LockstepRig, other: can.BusABC, controlword: int, left_for: str) -> None:
    """Another tool writes controlword 0 (disable voltage) or 2 (quick stop) to the r drive
    while armed. Before, the daemon stayed armed and silent, and the next RPDO1's 0x0F
    enabled a quick-stopped drive again (CiA 402 transition 16). Now: FAULT naming the
    drive and the state it was taken to, 0 V, and the drive left disabled; a reset and an
    arm bring it back."""
    _arm(rig)
    _controlword(other, 1, controlword)
    _ticks(rig, 50)
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    assert f"r drive (node 1): left OPERATION ENABLED for {left_for} while armed" in (
        d.fault_reason)
    assert d.voltages == (0.0, 0.0)
    assert rig.emulator.nodes[0].state is not DriveState.OPERATION_ENABLED
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason
    _arm(rig)


@pytest.mark.parametrize("armed", [False, True])
def test_a_foreign_nmt_stop_is_a_fault_named_and_a_reset_restarts_the_drives(
        rig: LockstepRig, other: can.BusABC, armed: bool) -> None:
    """NMT 'stop' to all nodes from another master: the heartbeat's state is the fault's
    reason (a drive sends one as its state changes), and a reset starts the drives again
    (a stopped node keeps its values)."""
    if armed:
        _arm(rig)
    _send(other, 0x000, bytes([0x02, 0]))
    _ticks(rig, 300)
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    assert ("r drive (node 1): its heartbeat says NMT STOPPED, not OPERATIONAL (an NMT "
            "command from another master; reset starts it again)" in d.fault_reason)
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason
    _arm(rig)


PRE_OPERATIONAL_FAULT = (
    "r drive (node 1): its heartbeat says NMT PRE OPERATIONAL, not OPERATIONAL (an NMT "
    "command from another master, or a restart whose boot-up was lost, with its power-on "
    "values: restart the service, whose bring-up configures it again)")


@pytest.mark.parametrize("armed", [False, True])
def test_a_foreign_enter_pre_operational_is_a_fault_a_reset_does_not_undo(
        rig: LockstepRig, other: can.BusABC, armed: bool) -> None:
    """NMT 'enter PRE-OPERATIONAL' to all nodes from another master. Before e50cc6c,
    disarmed, nothing faulted and every arm and reset was refused, unexplained, until a
    restart. It is a fault naming the state, and, since a drive that restarted with its
    boot-up lost says the same while holding its power-on values, a reset does not start
    it again: it names the service's restart (whose bring-up configures the drives)."""
    if armed:
        _arm(rig)
    _send(other, 0x000, bytes([0x80, 0]))
    _ticks(rig, 300)
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    assert PRE_OPERATIONAL_FAULT in d.fault_reason
    _reset(rig)
    assert d.state is DaemonState.FAULT and PRE_OPERATIONAL_FAULT in d.fault_reason
    assert [n.nmt for n in rig.emulator.nodes] == [NmtState.PRE_OPERATIONAL] * 2


@pytest.mark.parametrize("then", [None, 0x01, 0x02])
def test_a_drive_restarted_unseen_after_bring_up_is_never_started_by_the_daemon(
        tmp_path: Path, then: int | None) -> None:
    """The r drive restarts (reset node) with its boot-up lost once bring-up has returned,
    before the loop has fresh feedback: it holds its power-on watchdog (20 ms, not 3 ms).
    Before, the loop took its PRE-OPERATIONAL heartbeat for a lost NMT start and started
    it again, reached DISARMED and armed with it. It is a fault from INIT, which is the
    service's start all the same (READY=1, else systemd kills it at TimeoutStartSec even
    once reset), latched whatever the drive says next: another node's NMT start (then
    OPERATIONAL) or stop (then STOPPED, which a reset starts) does not let a reset arm it."""
    systemd = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    systemd.bind(str(tmp_path / "notify"))
    systemd.settimeout(1.0)
    rig = LockstepRig(tmp_path)
    rig.daemon.notifier = Notifier(str(tmp_path / "notify"))
    other = can.Bus(interface="virtual", channel=rig.controller_bus.channel_id)
    try:
        rig.bring_up()
        r = rig.emulator.nodes[0]
        r._reset(True, rig.now_s, [])  # NMT reset node; its boot-up (the frames out) lost
        assert r.watchdog_timeout_s == pytest.approx(0.020)
        rig.until(DaemonState.FAULT, 3000)
        d = rig.daemon
        assert d.state is DaemonState.FAULT and PRE_OPERATIONAL_FAULT in d.fault_reason
        ready = systemd.recv(4096).decode()
        assert ready.startswith(f"READY=1\nSTATUS=fault: {PRE_OPERATIONAL_FAULT}"), ready
        if then is not None:
            _send(other, 0x000, bytes([then, 1]))
            _ticks(rig, 300)
        _reset(rig)
        assert d.state is DaemonState.FAULT
        assert ("r drive (node 1): said NMT PRE OPERATIONAL after bring-up" in d.fault_reason
                or PRE_OPERATIONAL_FAULT in d.fault_reason), d.fault_reason
        assert r.nmt is (NmtState.OPERATIONAL if then == 0x01 else NmtState.STOPPED
                         if then == 0x02 else NmtState.PRE_OPERATIONAL)
        with pytest.raises(CommandRejected):
            command(rig, b'{"cmd": "arm"}')
        _ticks(rig, 300)
        assert d.state is DaemonState.FAULT and r.state is not DriveState.OPERATION_ENABLED
    finally:
        other.shutdown()
        rig.close()
        systemd.close()


def test_an_emcy_warning_the_drives_never_clear_does_not_block_a_reset(
        rig: LockstepRig, other: can.BusABC) -> None:
    """One SYNC of the wrong length from another node: both drives send EMCY 0x8240 and
    no NO_ERROR after it (a warning: they stay as they were, error register 0). The daemon
    faults on it; before, every reset failed on the EMCY forever. Now a reset clears an
    EMCY that a later TPDO2 contradicts."""
    _ticks(rig, 100)
    _send(other, 0x080, b"")
    _ticks(rig, 20)
    d = rig.daemon
    assert d.state is DaemonState.FAULT and "EMCY 0x8240" in d.fault_reason
    assert "(a SYNC of a length the drive does not take: another node sends SYNC, or " \
        "drives.sync_counter_overflow is not the drive's)" in d.fault_reason
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_a_lost_no_error_emcy_does_not_block_a_reset(rig: LockstepRig) -> None:
    """The drives' watchdog trips (the controller silent for 0.2 s of their time), then the
    r drive's NO_ERROR EMCY after its fault reset is lost on the bus. Before, the drive
    healthy and its error register 0, every reset failed on the stale EMCY."""
    _arm(rig)
    for _ in range(200):
        rig.now_s += 0.001
        rig.emulator.service(0.0)
    _ticks(rig, 20)
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    bus = rig.controller_bus
    receive, dropped = bus.recv, []

    def lossy(timeout: float | None = None) -> can.Message | None:
        msg = receive(timeout)
        if (msg is not None and msg.arbitration_id == 0x081 and not dropped
                and bytes(msg.data[:2]) == b"\0\0"):
            dropped.append(msg)
            return receive(timeout)
        return msg

    bus.recv = lossy  # type: ignore[method-assign]
    _reset(rig)
    assert len(dropped) == 1
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_a_second_daemon_leaves_the_running_ones_drives_alone(tmp_path: Path) -> None:
    """`rakectl run` while a daemon listens on the configured socket: refused, naming the
    socket, before it opens the bus. Before, it ran its whole bring-up first (NMT reset
    communication of both drives), which faulted the running daemon for good ("rebooted:
    bring-up needed"), and only then found the socket in use."""
    from rakectl.api.server import CommandServer
    from rakectl.daemon.service import run
    from rakectl.errors import ApiError

    path = tmp_path / "rakectl.sock"
    server = CommandServer(path, None, lambda request: {})
    channel = f"second-daemon-{tmp_path.name}"
    watcher = can.Bus(interface="virtual", channel=channel)
    try:
        with pytest.raises(ApiError, match=f"another daemon is already listening at {path}"):
            run(None, [f"daemon.socket_path={path}", "bus.interface=virtual",
                       f"bus.channel={channel}", "daemon.startup_cyclictest_s=0"])
        assert watcher.recv(timeout=0.2) is None  # not one frame: no NMT, no SDO
    finally:
        watcher.shutdown()
        server.close()


def _from(client: int, line: bytes, rig: LockstepRig) -> dict[str, object]:
    """``line`` as the server hands it over from connection number ``client``."""
    from rakectl.api.schema import Request, decode_request
    from rakectl.daemon.handlers import make_handler

    request = decode_request(line, client)
    assert isinstance(request, Request), request
    return dict(make_handler(rig.daemon)(request))


JOG_UP = b'{"cmd": "jog", "space": "task", "height_m_per_s": 0.01}'


@pytest.mark.parametrize("ended_by", ["stop", "force limit"])
def test_a_jog_ended_by_someone_else_is_not_started_again_by_its_own_requests(
        rig: LockstepRig, ended_by: str) -> None:
    """Operator A jogs (connection 1, repeating its request as the dead-man wants); B's
    stop (connection 2), or the force limit, ends it. Before, A's next request started the
    jog again 30-70 ms later and both CLIs reported success. Now A's requests are refused,
    naming why the jog ended, B cannot take over a running jog, and a new connection
    starts a new jog."""
    from rakectl.errors import CommandRejected

    open_connections = {1, 2, 3}
    rig.daemon.connected = open_connections.__contains__  # the command server's, in-process
    _arm(rig)
    assert _from(1, JOG_UP, rig)["state"] == "jog"
    _ticks(rig, 50)
    with pytest.raises(CommandRejected, match="another client is jogging"):
        _from(2, JOG_UP, rig)
    if ended_by == "stop":
        _from(2, b'{"cmd": "stop"}', rig)
        reason = "operator stop"
    else:
        rig.daemon._back_off()  # what the hard force level does (rakectl.daemon.loop)
        reason = "force limit: backing off"
    _ticks(rig, 50)
    assert rig.daemon.state is DaemonState.HOLD
    with pytest.raises(CommandRejected, match=f"this jog has ended \\({reason}\\): start a "
                       "new jog, on a new connection, to move again"):
        _from(1, JOG_UP, rig)
    assert rig.daemon.state is DaemonState.HOLD  # nothing changed
    assert _from(3, JOG_UP, rig)["state"] == "jog"
    # Another connection's jog, ended too, did not free A's: its next jog moved the rake.
    _from(3, b'{"cmd": "stop"}', rig)
    _ticks(rig, 50)
    with pytest.raises(CommandRejected, match=f"this jog has ended \\({reason}\\)"):
        _from(1, JOG_UP, rig)
    with pytest.raises(CommandRejected, match="this jog has ended \\(operator stop\\)"):
        _from(3, JOG_UP, rig)
    assert rig.daemon.state is DaemonState.HOLD


def test_a_refusal_names_the_next_step(rig: LockstepRig) -> None:
    """After an e-stop every command but reset is refused; the refusal says what to do."""
    from rakectl.errors import CommandRejected

    with pytest.raises(CommandRejected, match="cannot jog while disarmed: arm first"):
        _from(1, JOG_UP, rig)
    with pytest.raises(CommandRejected, match="cannot reset while disarmed: nothing to "
                       "reset: a reset clears a fault or an e-stop"):  # said nothing more
        _from(1, b'{"cmd": "reset"}', rig)
    _from(1, b'{"cmd": "estop"}', rig)
    with pytest.raises(CommandRejected, match=r"cannot arm while estop \(operator e-stop\): "
                       "reset clears it, then arm"):
        _from(1, b'{"cmd": "arm"}', rig)


def test_a_client_with_a_connection_per_request_keeps_its_jog_going(rig: LockstepRig) -> None:
    """A client may open a connection for each request (rakectl.api.client.call does):
    once the jog's connection is closed, the next connection's request continues it."""
    rig.daemon.connected = lambda client: False  # each closed after its reply
    _arm(rig)
    for client in range(1, 6):
        assert _from(client, JOG_UP, rig)["state"] == "jog"
        _ticks(rig, 100)
    assert rig.daemon.state is DaemonState.JOG


def test_answers_beyond_the_syncs_from_one_drive_only_are_not_named_another_master(
        rig: LockstepRig, other: can.BusABC) -> None:
    """Another node sends on the r drive's TPDO1 COB-ID (as a drive answering each SYNC
    twice would): one drive's answers outnumber the SYNCs, the other's do not. A fault,
    which named another SYNC producer before; a foreign SYNC is answered by both."""
    _ticks(rig, 100)
    for _ in range(30):
        _send(other, 0x181, bytes(8))
        rig.tick()
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    assert ("r drive (node 1): 11 TPDO1s more than the SYNCs sent: the other drive's are "
            "not: this one answers a SYNC more than once, or another node sends on its TPDO1 "
            "COB-ID (0x181)") in d.fault_reason
    assert "another CANopen master" not in d.fault_reason


def test_another_sync_producer_is_a_fault_named(rig: LockstepRig, other: can.BusABC) -> None:
    """Another node sends SYNC every millisecond as well: each drive answers twice a tick,
    and the force estimate counted two samples a tick, its delay halved in time (F̂ in a
    plunge 26 → 14 N mean); the extra answers were only counted. Now more TPDO1s than
    SYNCs sent is a fault naming it."""
    _arm(rig)
    counter = 0
    for _ in range(30):
        counter = counter % 240 + 1
        _send(other, 0x080, bytes([counter]))
        rig.tick()
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    assert "another node sends SYNC on this bus (another CANopen master)" in d.fault_reason
    _reset(rig)  # the other producer gone: the answers counted before do not fault again
    assert d.state is DaemonState.DISARMED, d.fault_reason
    _ticks(rig, 100)
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_a_tpdo1_remapped_by_another_tool_is_named_in_the_fault(rig: LockstepRig,
                                                               other: can.BusABC) -> None:
    """Another tool remaps the r drive's TPDO1 to 6 bytes over SDO while armed: the drive
    sends none while the PDO is invalid (the fault: no TPDO1), then 6-byte ones. Before,
    every reset then failed on "no TPDO1 for N cycles" while 6-byte TPDO1s arrived every
    cycle; now it says what came."""
    _arm(rig)
    for index, sub, value, size in ((0x1800, 1, 0x80000181, 4), (0x1A00, 0, 0, 1),
                                    (0x1A00, 1, 0x60640020, 4), (0x1A00, 2, 0x606C0010, 4),
                                    (0x1A00, 0, 2, 1), (0x1800, 1, 0x00000181, 4)):
        command_specifier = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
        _send(other, 0x601, struct.pack("<BHB", command_specifier, index, sub)
              + value.to_bytes(size, "little") + bytes(4 - size))
        rig.tick()
    _ticks(rig, 20)
    d = rig.daemon
    assert d.state is DaemonState.FAULT and "r drive (node 1): no TPDO1" in d.fault_reason
    _reset(rig)
    assert d.fault_reason.startswith("reset failed: ")
    assert ("(its last TPDO1 had 6 bytes, 8 expected: its PDO mapping was changed)"
            in d.fault_reason)


def test_an_estop_calls_off_a_reset_asked_before_it(rig: LockstepRig, other: can.BusABC) -> None:
    """A reset asked in FAULT waits for its cause to clear; an e-stop meanwhile was
    cleared by that reset once the cause went (DISARMED, no reset after the e-stop). The
    e-stop latches until a reset asked after it, and keeps the fault's cause named."""
    _ticks(rig, 100)
    for _ in range(30):  # SYNCs of the wrong length from another node: EMCY 0x8240 faults
        _send(other, 0x080, b"")
        rig.tick()
    d = rig.daemon
    assert d.state is DaemonState.FAULT
    cause = d.fault_reason
    command(rig, b'{"cmd": "reset"}')  # its cause still there while the SYNCs come
    for _ in range(100):
        _send(other, 0x080, b"")
        rig.tick()
    assert d.state is DaemonState.FAULT
    _from(2, b'{"cmd": "estop"}', rig)
    assert d.fault_reason == f"operator e-stop (in fault: {cause})"
    _ticks(rig, 1200)  # the cause gone
    assert d.state is DaemonState.ESTOP
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_a_reset_waits_out_a_sync_producer_still_on_the_bus(
        rig: LockstepRig, other: can.BusABC) -> None:
    """Another node sends SYNC every millisecond: a fault naming it. A reset while it goes
    on gave DISARMED at once (the answers counted before were forgiven) and the fault again
    9 ticks later; it now fails, naming it, and succeeds once the producer is gone."""
    _arm(rig)
    counter, d = 0, rig.daemon

    def foreign_syncs(ticks: int) -> None:
        nonlocal counter
        for _ in range(ticks):
            counter = counter % 240 + 1
            _send(other, 0x080, bytes([counter]))
            rig.tick()

    foreign_syncs(30)
    assert d.state is DaemonState.FAULT
    command(rig, b'{"cmd": "reset"}')
    foreign_syncs(1100)
    assert d.state is DaemonState.FAULT
    assert d.fault_reason.startswith("reset failed: ") and "another node sends SYNC" in \
        d.fault_reason
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_an_excavation_is_not_replaced_by_another_without_a_stop(rig: LockstepRig) -> None:
    """A second excavate during a lane replaced it, the first lane never ending nor
    reporting; it is refused, saying to stop first, as jog and excavate are."""
    from rakectl.errors import CommandRejected

    _arm(rig)
    lane = (b'{"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 1.15, '
            b'"target_depth_m": 0.005}')
    assert _from(1, lane, rig)["lane"] == 1
    _ticks(rig, 200)
    with pytest.raises(CommandRejected, match=r"^cannot excavate while excavate: stop first$"):
        _from(2, lane, rig)
    with pytest.raises(CommandRejected, match=r"^cannot jog while excavate: stop first$"):
        _from(2, JOG_UP, rig)
    assert rig.daemon.state is DaemonState.EXCAVATE and rig.daemon.lanes_started == 1
    _from(1, b'{"cmd": "stop"}', rig)
    with pytest.raises(CommandRejected, match=r"^cannot arm while hold: it is armed, holding$"):
        _from(1, b'{"cmd": "arm"}', rig)
    _from(1, b'{"cmd": "disarm"}', rig)
    with pytest.raises(CommandRejected, match=r"^cannot stop while disarmed: nothing moves"):
        _from(1, b'{"cmd": "stop"}', rig)


def test_another_masters_rpdo1_is_a_fault_named(rig: LockstepRig, other: can.BusABC) -> None:
    """Another node sends the θ drive RPDO1s of its own (8 V, enabled), as a second master
    would: the drive applies the last RPDO1 before a SYNC, its own whenever it comes
    after the daemon's (8 V on two ticks in a run of the emulated bench), and nothing but
    the echo counters said so. Now the first one not sent by this daemon is a fault naming
    it; a reset once it has stopped clears it."""
    from rakectl.protocol.codec import encode_rpdo

    _arm(rig)
    d = rig.daemon
    _send(other, 0x202, encode_rpdo(8000, 0x0F))
    rig.tick()
    assert d.state is DaemonState.FAULT
    assert ("θ drive (node 2): an RPDO1 on its COB-ID 0x202 that this daemon did not send "
            f"(data {encode_rpdo(8000, 0x0F).hex()}): another node commands the drive "
            "(another CANopen master)") in d.fault_reason
    assert d.client.stats.foreign_rpdos == [0, 1]
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason


def test_a_stall_past_the_drives_watchdog_is_named_as_the_cause(rig: LockstepRig) -> None:
    """The loop stopped for 200 ms (the process stopped, the machine busy): the drives'
    watchdog stops them, and the fault named only what the drives then said ('left
    OPERATION ENABLED ... another CANopen master, or the drive itself', EMCY 0x8250).
    It now names the stall first, as their cause."""
    _arm(rig)
    for _ in range(200):  # 200 ms of the drives' time without a tick
        rig.now_s += 0.001
        rig.emulator.service(0.0)
    d = rig.daemon
    d.tick(skipped=199)  # the loop's wake-up, 200 periods late
    assert d.state is DaemonState.FAULT
    assert d.fault_reason.startswith("the loop stalled 200 ms, past the drives' 3 ms command "
                                     "watchdog, which stopped them: "), d.fault_reason
    assert "EMCY 0x8250" in d.fault_reason


def test_status_asks_no_voltage_outside_the_armed_states(rig: LockstepRig) -> None:
    """The requested voltages kept their last armed values after a disarm or an e-stop
    (-0.67 V on θ in ESTOP, the applied ones 0): nothing is asked once disarmed."""
    _arm(rig)
    held = _from(1, b'{"cmd": "status"}', rig)["voltages"]
    assert isinstance(held, dict) and held["requested_theta_v"] != 0.0  # holding the rake
    for request in (b'{"cmd": "disarm"}', b'{"cmd": "estop"}'):
        _from(1, request, rig)
        _ticks(rig, 5)
        voltages = _from(1, b'{"cmd": "status"}', rig)["voltages"]
        assert voltages == {"requested_r_v": 0.0, "requested_theta_v": 0.0,
                            "applied_r_v": 0.0, "applied_theta_v": 0.0}
        if request == b'{"cmd": "disarm"}':
            _arm(rig)


def test_checks_an_estop_interrupted_say_so(rig: LockstepRig) -> None:
    """An e-stop during the checks before arming: status said "not run"; it says they
    were interrupted, and why, and they run at the next arming."""
    assert _from(1, b'{"cmd": "arm"}', rig)["state"] == "checking"
    _ticks(rig, 100)
    _from(1, b'{"cmd": "estop"}', rig)
    weight = _from(1, b'{"cmd": "status"}', rig)["weight_check"]
    assert weight == {"passed": None, "message": "interrupted (operator e-stop): runs at the "
                      "next arming"}
    _reset(rig)
    assert _from(1, b'{"cmd": "arm"}', rig)["state"] == "checking"
    weight = _from(1, b'{"cmd": "status"}', rig)["weight_check"]
    assert weight == {"passed": None, "message": "running"}


@pytest.mark.parametrize(("arg", "value", "top"), [("stroke_speed_m_per_s", 1.0, 0.15),
                                                   ("depth_step_m", 0.1, 0.04)])
def test_an_adaptive_lane_refuses_what_it_would_cap_naming_the_setting(
        rig: LockstepRig, arg: str, value: float, top: float) -> None:
    """An adaptive lane (the rig's) took a stroke speed of 1 m/s and capped it at 0.15
    unsaid, status showing 1.0; a depth step of 0.1 m was refused with the settings' own
    words. Both are refused now, naming the lane's setting."""
    from rakectl.errors import CommandRejected

    _arm(rig)
    lane = (b'{"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 1.15, '
            b'"target_depth_m": 0.05, "' + arg.encode() + b'": ' + str(value).encode() + b"}")
    with pytest.raises(CommandRejected) as refused:
        _from(1, lane, rig)
    assert str(refused.value) == (f"cannot excavate: {arg} {value:g} is above this adaptive "
                                  f"lane's largest, {top:g} (lane.max_{arg})")
    assert rig.daemon.state is DaemonState.ARMED and rig.daemon.lanes_started == 0


def test_a_sync_producer_after_a_reset_from_lost_answers_is_found_at_once(
        rig: LockstepRig, other: can.BusABC) -> None:
    """600 TPDO1s lost (a bus outage, stale feedback), a reset, then another node sends
    SYNC every millisecond: the count of answers beyond the SYNCs starts from 0 at the
    reset, so the producer faults the daemon within its 10 extra answers (with the count
    kept from before the reset, 600 below 0, it took 612 ticks)."""
    _arm(rig)
    bus, d = rig.controller_bus, rig.daemon
    receive = bus.recv

    def lossy(timeout: float | None = None) -> can.Message | None:
        msg = receive(timeout)
        while msg is not None and msg.arbitration_id in (0x181, 0x182):
            msg = receive(timeout)
        return msg

    bus.recv = lossy  # type: ignore[method-assign]
    _ticks(rig, 600)
    bus.recv = receive  # type: ignore[method-assign]
    assert d.state is DaemonState.FAULT and "no TPDO1" in d.fault_reason
    _reset(rig)
    assert d.state is DaemonState.DISARMED, d.fault_reason
    counter, ticks = 0, 0
    while d.state is not DaemonState.FAULT and ticks < 60:
        counter = counter % 240 + 1
        _send(other, 0x080, bytes([counter]))
        rig.tick()
        ticks += 1
    assert d.state is DaemonState.FAULT and "another node sends SYNC" in d.fault_reason
    assert ticks <= 20
