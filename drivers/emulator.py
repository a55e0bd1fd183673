"""The emulator: both drives and the arm/soil physics on one injected CAN bus, in one thread.

:class:`Emulator` works on the bus it is given (a ``can.BusABC``; only the composition
root, ``python -m drivers``, opens and shuts one), owns two :class:`~drivers.node.DriveNode`
and the physics (:class:`drivers.arm.ArmPlant` against :class:`drivers.ground.Ground`).
:meth:`Emulator.service` does one round of the loop: wait for a frame (at most
``timeout_s``, less if a timer is due), hand it and every other pending frame to the
drives that listen to its COB-ID, send what they answer, run their timers, advance the
physics if it is due. Tests call it between their own sends; :meth:`Emulator.run` loops.

Filters pass only SYNC, NMT, the drives' RPDO1 and SDO requests and heartbeats (not
udp_multicast's echo of its own): the kernel's on socketcan, else :meth:`Emulator.service`'s
(python-can's own returns None from ``recv(0)`` at a frame that fails it, holding back
those behind); what they drop is not counted, as a drive's acceptance filter counts
nothing. What they pass that nobody listens to, a remote, error or FD frame, and what
the bus cannot decode, is counted in :attr:`Emulator.stats`, bad content by the drives;
logged at most once per second per kind (structlog ``bad_frame``).

Time. Both drives share one physics step per control period (the arm couples
the joints). LOCKSTEP: each valid SYNC advances the physics by exactly one
period after the drives have sampled it and latched their commands, so the
run is deterministic however slow the controller is. WALLCLOCK: physics time
follows the wall clock in whole periods; at a SYNC it catches up (rounded)
before the drives sample, in between it catches up once two periods are due,
and more than ``max_catch_up_s`` at once is dropped and counted. In LOCKSTEP
with no SYNC, the physics stands still, until a drive faults for lost
communication (watchdog or heartbeat) while the SYNCs stay away: from then on
it follows the wall clock at the drives' 0 V (dynamic braking), so a killed
controller is seen as the arm braking, until the next SYNC.

Faults injected from the configuration act here, at the bus edge: a drive
misses a received frame or loses one it sends with a seeded probability, and a
drive can fall silent (send nothing more) after a given time.

Ground truth: with ``truth`` (a text file), one CSV row per physics step,
written in batches and flushed by :meth:`Emulator.close`.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Sequence
from typing import Any, Final, TextIO

import can
import structlog
from can.interfaces.socketcan import SocketcanBus
from can.typechecking import CanFilter

from drivers.arm import ArmPlant
from drivers.drive_spec import DriveSpec, Frame
from drivers.drives import drive_node, drive_specs, workspace
from drivers.ground import Ground
from drivers.node import DriveNode
from drivers.objects import Contact
from drivers.records import TRUTH_ROW, EmulatorStats, RateLimitedLog, TruthRecorder
from drivers.settings import EmulatorConfig, TimingMode
from drivers.stats import BadInput
from rakectl.core.motor_model import MotorParams, joint_per_motor_rad
from rakectl.protocol.codec import SYNC_COB_ID
from rakectl.protocol.nmt import EmcyCode

UNREADABLE_LIMIT: Final = 1000  # undecodable receptions in a row: the bus is broken
REPORT_INTERVAL_S: Final = 0.25  # how often counters are checked for the rate-limited log
COMM_FAULTS: Final = frozenset({EmcyCode.COMMAND_WATCHDOG_TIMEOUT, EmcyCode.HEARTBEAT_LOST})


class Emulator:
    """Two drives and the physics on ``bus``; see the module docstring."""

    def __init__(self, config: EmulatorConfig, bus: can.BusABC, *,
                 clock: Callable[[], float] = time.monotonic, truth: TextIO | None = None,
                 trace: can.Listener | None = None, log: Any = None,
                 specs: tuple[DriveSpec, DriveSpec] | None = None) -> None:
        """``specs``: the (r, θ) drives, when not those :func:`drive_specs` makes of
        ``config`` (a drive whose stored values or RTR differ: ``DriveSpec``)."""
        self.config, self.bus, self._clock, self._trace = config, bus, clock, trace
        self._log = log if log is not None else structlog.get_logger("drivers.emulator")
        self._limited = RateLimitedLog(self._log)
        self.stats = EmulatorStats()
        self.r_node, self.theta_node = (drive_node(spec)
                                        for spec in specs or drive_specs(config))
        self.nodes = (self.r_node, self.theta_node)
        self._routes: dict[int, tuple[DriveNode, ...]] = {}
        for node in self.nodes:
            for can_id in node.listens_to:
                self._routes[can_id] = (*self._routes.get(can_id, ()), node)
        self.workspace = workspace(config)
        physics = config.physics
        self.ground = Ground(physics.ground, physics.seed)
        self._mines = [b for b in self.ground.bodies if b.kind is Contact.MINE]
        self._plant_motors = self._motors()
        self.plant = self._new_plant()
        self.plant.set_pose_at_rest(config.drives.start_r_m, config.drives.start_theta_rad)
        self._truth = TruthRecorder(truth) if truth is not None else None
        self._pool: dict[int, can.Message] = {}
        faults = config.faults
        self._rng = random.Random(faults.seed)
        self._lossy = frozenset(n.node_id for n in self.nodes
                                if faults.loss_node_id in (0, n.node_id))
        self._period_s = config.drives.control_period_s
        self._max_periods = max(1, int(config.drives.max_catch_up_s / self._period_s + 1e-9))
        self._lockstep = config.drives.timing is TimingMode.LOCKSTEP
        self.time_s, self.sync_counter = 0.0, 0
        self._free_running = False
        self._t0_s = self._now_s = self._anchor_s = self._last_sync_s = 0.0
        self._next_report_s = 0.0
        self._last_tx_error = ""

    # ------------------------------------------------------------------- lifecycle

    def bus_filters(self) -> list[CanFilter]:
        """SYNC, NMT, each drive's RPDO1 and SDO request, and every heartbeat."""
        ids = sorted(i for i in self._routes if not 0x700 <= i < 0x780)
        return ([CanFilter(can_id=i, can_mask=0x7FF, extended=False) for i in ids]
                + [CanFilter(can_id=0x700, can_mask=0x780, extended=False)])

    def start(self) -> None:
        """Set the bus filters (socketcan's) and power the drives on (boot-ups)."""
        now_s = self._clock()
        self._t0_s = self._now_s = self._anchor_s = self._last_sync_s = now_s
        if isinstance(self.bus, SocketcanBus):
            self.bus.set_filters(self.bus_filters())
        self._sense(0.0)
        for node in self.nodes:
            self._transmit(node, node.boot(now_s))
        self._after_activity(now_s)
        self._log.info("emulator_started", node_ids=[n.node_id for n in self.nodes],
                       timing=self.config.drives.timing.value,
                       channel=str(self.bus.channel_info))

    def close(self) -> None:
        """Flush the ground truth and log the counters; the bus stays open (its owner's)."""
        if self._truth is not None:
            self._truth.flush()
        protocol_us, physics_us = self.stats.per_sync_us()
        self._log.info("emulator_stopped", syncs=self.stats.syncs,
                       physics_steps=self.stats.physics_steps,
                       protocol_us_per_sync=round(protocol_us, 1),
                       physics_us_per_period=round(physics_us, 1),
                       frames_in=self.stats.frames_in, frames_out=self.stats.frames_out,
                       bad_frames=self.stats.bad.total + sum(n.stats.bad.total
                                                             for n in self.nodes))

    def run(self, should_stop: Callable[[], bool], poll_s: float = 0.1) -> None:
        """Service the bus until ``should_stop()``."""
        while not should_stop():
            self.service(poll_s)

    # ------------------------------------------------------------------- the loop

    def service(self, timeout_s: float) -> int:
        """Handle every pending frame (waiting ≤ timeout_s for the first), then the timers.

        The drives' heartbeats also go out between frames once due: an emulator slower
        than the frames it is sent (software emulation) must not hold them back until
        its queue is empty, as a real drive's hardware timer is not held back. What
        checks the frames received (heartbeat consumer, command watchdog) waits until
        they are read. Returns the number of frames handled.
        """
        now_s = self._clock()
        wait_s = max(0.0, min(timeout_s, self._next_deadline_s() - now_s))
        msg = self._recv(wait_s)
        handled = 0
        while msg is not None:
            self.handle(msg, self._clock())
            handled += 1
            now_s = self._clock()
            for node in self.nodes:
                self._transmit(node, node.heartbeat(now_s))
            msg = self._recv(0.0)
        now_s = self._now_s = self._clock()
        for node in self.nodes:
            self._transmit(node, node.poll(now_s))
        self._advance_idle(now_s)
        self._after_activity(now_s)
        return handled

    def _recv(self, timeout_s: float) -> can.Message | None:
        """The next frame :meth:`bus_filters` pass (and error frames, to be counted), waiting
        ≤ timeout_s for the first; the others dropped. What the bus cannot decode (a
        udp_multicast datagram that is no frame) is counted; ``UNREADABLE_LIMIT`` of it in
        a row raise (a bus that no longer works)."""
        routes, unreadable = self._routes, 0
        while True:
            try:
                msg = self.bus.recv(timeout_s)
            except can.CanError as error:
                unreadable += 1
                if unreadable >= UNREADABLE_LIMIT:
                    raise
                self.stats.bad.count(BadInput.UNREADABLE, 0, str(error).encode()[:32])
                timeout_s = 0.0
                continue
            if msg is None or msg.is_error_frame or (not msg.is_extended_id and (
                    msg.arbitration_id in routes or 0x700 <= msg.arbitration_id < 0x780)):
                return msg
            timeout_s = 0.0

    def handle(self, msg: can.Message, now_s: float) -> None:
        """One received frame (bus filters bypassed)."""
        started_s = time.perf_counter()
        physics_before_s = self.stats.physics_s
        self._now_s = now_s
        self.stats.frames_in += 1
        if self._trace is not None:
            self._trace.on_message_received(msg)
        can_id, data = msg.arbitration_id, msg.data
        nodes = self._routes.get(can_id)
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            self.stats.bad.count(BadInput.UNSUPPORTED, can_id, data)
        elif nodes is None:
            self.stats.bad.count(BadInput.UNKNOWN_ID, can_id, data)
        elif can_id == SYNC_COB_ID:
            self._on_sync(data, now_s)
        else:
            for node in nodes:
                if not self._rx_lost(node):
                    self._transmit(node, node.receive(can_id, data, now_s))
            self._update_plant_params()
        self.stats.protocol_s += (time.perf_counter() - started_s
                                  - (self.stats.physics_s - physics_before_s))

    def _on_sync(self, data: bytearray, now_s: float) -> None:
        valid = any(node.takes_sync(data) for node in self.nodes)  # 0x1019 sets the length
        if valid and not self._lockstep:
            self._catch_up(now_s, at_sync=True)
        for node in self.nodes:
            if not self._rx_lost(node):
                self._transmit(node, node.receive(SYNC_COB_ID, data, now_s))
        if not valid:
            return  # the drives count it
        self.stats.syncs += 1
        self.sync_counter = data[0] if data else 0
        self._last_sync_s, self._free_running = now_s, False
        if self._lockstep:
            self._anchor_s = now_s
            self._step_physics(1)

    def _next_deadline_s(self) -> float:
        deadline = min(node.next_deadline_s() for node in self.nodes)
        if self._free_running or not self._lockstep:
            deadline = min(deadline, self._anchor_s + 2 * self._period_s)
        return min(deadline, self._next_report_s)

    # ------------------------------------------------------------------- physics

    def _new_plant(self) -> ArmPlant:
        p, (motor_r, motor_theta) = self.config.physics, self._plant_motors
        return ArmPlant(p.arm, motor_r, motor_theta, self.workspace, p.substep_s, p.seed)

    def _motors(self) -> tuple[MotorParams, MotorParams]:
        return self.r_node.motor_params, self.theta_node.motor_params

    def _update_plant_params(self) -> None:
        """A drive's current limit (0x2002) changed: rebuild the plant in the same state."""
        motors = self._motors()
        if motors[0] is not self._plant_motors[0] or motors[1] is not self._plant_motors[1]:
            state, self._plant_motors = self.plant.state(), motors
            self.plant = self._new_plant()
            self.plant.set_state(state)

    def _advance_idle(self, now_s: float) -> None:
        if self._free_running or not self._lockstep:
            self._catch_up(now_s, at_sync=False)
        elif now_s - self._last_sync_s >= min(n.watchdog_timeout_s for n in self.nodes) and any(
                n.fault in COMM_FAULTS for n in self.nodes):
            self._free_running, self._anchor_s = True, now_s
            self._log.info("physics_free_running", reason="no SYNC and a drive lost "
                           "communication", t_s=round(self.time_s, 4))

    def _catch_up(self, now_s: float, at_sync: bool) -> None:
        due = (now_s - self._anchor_s) / self._period_s
        periods = round(due) if at_sync else int(due) - 1
        if periods <= 0:
            return
        if periods > self._max_periods:
            self.stats.dropped_periods += periods - self._max_periods
            periods, self._anchor_s = self._max_periods, now_s
        else:
            self._anchor_s += periods * self._period_s
        self._step_physics(periods)

    def _step_physics(self, periods: int) -> None:
        started_s = time.perf_counter()
        plant, ground, dt_s, r, theta = self.plant, self.ground, self._period_s, *self.nodes
        for _ in range(periods):
            plant.step(r.output_voltage_v, theta.output_voltage_v, ground, dt_s)
            self.time_s += dt_s
            self._sense(dt_s)
            if self._truth is not None:
                self._record_truth()
        self.stats.physics_steps += periods
        self.stats.physics_s += time.perf_counter() - started_s

    def _sense(self, dt_s: float) -> None:
        plant, ws, r, theta = self.plant, self.workspace, *self.nodes
        m = plant.measure()
        r_at_stop = not ws.r_min_m < plant.r_m < ws.r_max_m
        theta_at_stop = not ws.theta_min_rad < plant.theta_rad < ws.theta_max_rad
        r_motor_vel = m.r_vel_m_per_s / joint_per_motor_rad(r.motor_params)
        theta_motor_vel = m.theta_vel_rad_per_s / joint_per_motor_rad(theta.motor_params)
        self._transmit(r, r.sense(m.r_m, r_motor_vel, m.current_r_a, r_at_stop, dt_s))
        self._transmit(theta, theta.sense(m.theta_rad, theta_motor_vel, m.current_theta_a,
                                          theta_at_stop, dt_s))

    def _record_truth(self) -> None:
        assert self._truth is not None
        plant, truth, (r, theta) = self.plant, self.ground.truth, self.nodes
        reach_m, height_m = plant.tip_m()
        plate_n = side_n = 0.0  # the largest so far on any mine
        for mine in self._mines:
            plate_n, side_n = max(plate_n, mine.peak_down_n), max(side_n, mine.peak_side_n)
        self._truth.add(TRUTH_ROW % (
            self.time_s, self.sync_counter, plant.r_m, plant.theta_rad, r.output_voltage_v,
            theta.output_voltage_v, plant.current_r_a, plant.current_theta_a, reach_m, height_m,
            truth.force_down_n, truth.force_drag_n, truth.contact.value, truth.mine_activated,
            r.state.name, r.nmt.name, theta.state.name, theta.nmt.name, plate_n, side_n,
            time.time()))  # the wall clock: recordings line it up with the daemon's status

    # ------------------------------------------------------------------- bus edge

    def _rx_lost(self, node: DriveNode) -> bool:
        probability = self.config.faults.rx_loss_probability
        if probability and node.node_id in self._lossy and self._rng.random() < probability:
            self.stats.rx_dropped += 1
            return True
        return False

    def _transmit(self, node: DriveNode, frames: Sequence[Frame]) -> None:
        if not frames:
            return
        faults = self.config.faults
        if node.node_id == faults.silence_node_id and (
                self._now_s - self._t0_s >= faults.silence_after_s):
            self.stats.tx_silenced += len(frames)
            return
        for can_id, data in frames:
            if faults.tx_loss_probability and node.node_id in self._lossy and (
                    self._rng.random() < faults.tx_loss_probability):
                self.stats.tx_dropped += 1
                continue
            self._send(can_id, data)

    def _send(self, can_id: int, data: bytes | bytearray) -> None:
        msg = self._pool.get(can_id)
        if msg is None or msg.data is not data:  # reuse the message around a node's buffer
            msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=False)
            if isinstance(data, bytearray):
                self._pool[can_id] = msg
        try:
            self.bus.send(msg)
        except can.CanError as exc:
            self.stats.tx_errors += 1
            self._last_tx_error = str(exc)
            return
        self.stats.frames_out += 1
        if self._trace is not None:
            msg.timestamp = time.time()
            self._trace.on_message_received(msg)

    # ------------------------------------------------------------------- logging

    def _after_activity(self, now_s: float) -> None:
        for node in self.nodes:
            for event, detail in node.notes:
                self._log.info(event, node_id=node.node_id, detail=detail.name,
                               state=node.state.name, nmt=node.nmt.name,
                               t_s=round(self.time_s, 4))
            node.notes.clear()
        if now_s >= self._next_report_s:
            self._next_report_s = now_s + REPORT_INTERVAL_S
            self._report_counters(now_s)

    def _report_counters(self, now_s: float) -> None:
        sources = [(0, self.stats.bad)] + [(n.node_id, n.stats.bad) for n in self.nodes]
        for node_id, bad in sources:
            for kind, count in bad.counts.items():
                if count:
                    can_id, data = bad.last[kind]
                    self._limited.update("bad_frame", f"{node_id}:{kind.value}", count, now_s,
                                         node_id=node_id or None, kind=kind.value,
                                         last_id=f"0x{can_id:03X}", last_data=data.hex())
        for key in ("tx_errors", "dropped_periods", "rx_dropped", "tx_dropped", "tx_silenced"):
            count = getattr(self.stats, key)
            if count:
                self._limited.update("bus_edge", key, count, now_s, counter=key,
                                     last_error=self._last_tx_error or None)
