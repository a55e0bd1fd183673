"""The drives' bring-up over CANopen (blocking, once before the loop).

Bring-up (:meth:`DriveClient.bring_up` through :func:`run_bring_up`, blocking, run once
before the loop): a ``canopen.Network`` on the injected bus whose listeners are fed by a
*temporary* ``can.Notifier``, stopped and joined before bring-up returns: no
thread survives it. :class:`BringUp` does the work through the network alone,
so a test can run it on a bus-less network without any thread. For each drive
in turn (r, then θ), with the node-IDs of :class:`~rakectl.config.service.DrivesSettings`:

1. NMT reset communication, and wait for its boot-up (the node is then
   PRE-OPERATIONAL with the stored values of its communication objects). Nothing is
   awaited before it: a drive already booted whose producer heartbeat 0x1017 is 0 (CiA
   301's default) says nothing until it is reset. Sent ``nmt_link.ATTEMPTS`` times in all,
   ``boot_timeout_s`` / ``nmt_link.ATTEMPTS`` apart, while no boot-up comes (either frame
   may be lost, or the drive still be powering up: the boot-up it sends at power-on
   counts too); then :class:`~rakectl.errors.CommsTimeout` naming the node and whether
   anything at all was heard from it;
2. SDO read the identity 0x1018: vendor-ID and product code must be those of
   the drive type's EDS (``rakectl/protocol/eds/*.eds``, read with ``importlib.resources``),
   revision and serial number are recorded;
3. SDO write the limits (those of ``drives.profile``, :mod:`rakectl.drive.profiles`: a
   Roboteq-class drive's in its own objects and units, after its supply is read and
   checked against the configured one): 0x2001 max voltage [mV]
   (``motors.<joint>.supply_voltage_v``),
   0x2002 current limit [mA] (``motors.<joint>.current_limit_a``), 0x2003 command
   watchdog [ms] (``drives.watchdog_timeout_ms``), 0x2004 encoder counts per turn,
   0x1017 producer heartbeat [ms] (``drives.heartbeat_period_ms``) and 0x1016:1
   consumer heartbeat of the controller (``controller_node_id << 16 | heartbeat_timeout_ms``)
   and 0x1019 SYNC counter overflow (``drives.sync_counter_overflow``), which CiA 301
   lets change only while the communication cycle period 0x1006 is 0: 0x1006 is read,
   set to 0 and restored around it. A drive without 0x1019 (abort 0x06020000) takes SYNC
   without a counter only: accepted when that is what is configured (0);
   a value outside the EDS's data type or limits is a ConfigError before anything is sent;
4. SDO read every one of them back and compare;
5. SDO read every PDO's communication and mapping parameters the EDS declares
   (0x1400 + n and 0x1600 + n, 0x1800 + n and 0x1A00 + n): COB-ID (bit 30, no RTR,
   is the drive's own: neither compared nor changed), transmission type, inhibit time,
   event timer and each mapped entry must be the EDS's, because the hot path's codecs
   decode that layout and the bus-load budget counts those frames. Reset
   communication restores a drive's *stored* values, so a mapping another tool
   changed and saved is found here: that PDO is written back to the EDS's in
   CiA 301's order (COB-ID not valid, what differs and the EDS declares writable, sub 0
   = 0, the entries, sub 0 = n, the COB-ID valid) and read again; a drive that refuses
   it or keeps its own is refused, naming the object and both values. A PDO beyond
   the EDS's that the drive has and holds valid is made not valid (bit 31 of its
   COB-ID): a drive that keeps such a TPDO valid, or such an RPDO mapping what it acts
   on (``POWER_OBJECTS``, the EDS's RPDOs' objects, what step 3 writes), is refused; an
   RPDO it keeps that maps nothing of that is named (:mod:`rakectl.drive.pdos`).
   The dry run (``start=False``) also reads the device name 0x1008.

Then a drive still in FAULT from the previous run (it lost that run's
heartbeat) is fault-reset over SDO, now that reset communication has cleared the
cause (:class:`rakectl.drive.profiles.DriveStart`): controlword 0x6040 = 0, then 0x80,
each held ``FAULT_RESET_HOLD_S`` (a drive samples its controlword once a cycle), the
statusword read until it leaves FAULT (``DriveFault`` naming ``FAULT_RESET_TIMEOUT_S``,
0.5 s, if it stays), then 0 again; a Roboteq-class drive is released (0x200D) and its
flags read the same way. Then
the statusword 0x6041 of each (the CiA 402 state the hot path starts
from: the TPDO2 a drive sends on entering OPERATIONAL may reach the bring-up
Notifier instead). A drive that restarted since its configuration (a brown-out, another
node's NMT reset) holds its power-on values: a boot-up heard during a drive's steps 1
to 5 (with a failure of theirs, or after them) configures it again from step 1
(``CONFIGURE_ATTEMPTS`` times in all: it may be the late answer to a reset sent again, or
a restart between a write and its reading back), one heard after them is a DriveFault,
and everything steps 3 and 5 wrote is read again (a restart whose boot-up was lost),
naming the first object that differs. Then NMT start for each node, sent again until
its heartbeat says OPERATIONAL (``nmt_link.ATTEMPTS`` times within ``boot_timeout_s``),
and the boot-ups, the PDOs, the limits and a Roboteq-class drive's emergency shutdown
checked once more: a restart since the reading. From then on a heartbeat in any other
state is a fault of the drive client's. A failure after NMT start puts both nodes back
in PRE-OPERATIONAL: no PDO taken from whoever sends one. Start ticking right away: an
enabled drive faults when RPDO1 or SYNC stop for 0x2003 ms, and every drive once the
controller's heartbeat (first sent with the first SYNC) stops.

Every failure is one line naming the drive, e.g.
``DriveFault("r drive (node 1): wrong identity: product code 2, expected 1 (dc_servo_drive.eds)")``,
``DriveFault("θ drive (node 2): read-back mismatch: 0x2003 watchdog timeout: wrote 3 ms,
read 15 ms")``, ``DriveFault("r drive (node 1): SDO abort 0x06090030 writing 0x2003
watchdog timeout = 3 ms: Value range of parameter exceeded")``
(raised ``from`` the canopen error; an answer shorter than the object's type, or an SDO
frame too short to decode, is one too), ``CommsTimeout`` when a node or an SDO
answer does not come; the transfers, and which of them are made again, are
:mod:`rakectl.drive.sdo`'s. The power stage is NOT enabled here: that is the
controlword sent cyclically in RPDO1 (:meth:`DriveClient.command`), and the
daemon enables the drives only while it is armed.
"""

from __future__ import annotations

import contextlib

import can
import canopen

from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.canbus import BusError, CanopenFrames, TracedNetwork, TraceRecorder
from rakectl.drive.joints import (
    JOINTS,
    DriveInfo,
    DriveLimits,
    ExtraPdo,
    Identity,
    Joint,
    Parameter,
    PdoReading,
    configured_identity,
    drive_label,
    load_drive_od,
    motor_of,
    node_ids,
    own_ids,
)
from rakectl.drive.nmt_link import NmtLink
from rakectl.drive.pdos import PdoCheck
from rakectl.drive.profiles import (
    CYCLE_PERIOD_OBJECT,
    SUPPLY_OBJECT,
    SYNC_OVERFLOW_OBJECT,
    DriveStart,
    check_parameter_ranges,
    drive_parameters,
    eds_file,
    supply_problem,
)
from rakectl.drive.sdo import SDO_RETRIES, DriveSdo, abort_code, no_such_object
from rakectl.errors import CommsTimeout, DriveFault, RakeError
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import NmtCommand

NOTIFIER_POLL_S = 0.02  # bring-up Notifier's recv timeout: how fast it stops
NOTIFIER_JOIN_S = 2.0
POWER_OBJECTS = frozenset({(0x6040, 0), (0x200C, 0), (0x200D, 0)})  # controlword, a
# Roboteq-class drive's emergency shutdown and release: what switches a power stage
CONFIGURE_ATTEMPTS = 3  # a drive configured again from its reset after a boot-up
Configured = tuple[Identity, DriveLimits, tuple[PdoReading, ...], tuple[PdoReading, ...],
                   tuple[ExtraPdo, ...]]  # the identity, limits, PDOs, written back, extra
RESTARTED = ("the drive restarted during bring-up (its boot-up lost) and holds its power-on "
             "values; bring-up again (restart the service)")


class BringUp:
    """The bring-up sequence of the module docstring, over any ``canopen.Network``: its
    NMT side (heartbeats, boot-ups, NMT commands) is :class:`NmtLink`'s, its SDO
    transfers :class:`DriveSdo`'s. Subscribes to the drives' heartbeats on construction.
    """

    def __init__(self, network: canopen.Network, drives: DrivesSettings,
                 motors: MotorsSettings, boot_timeout_s: float) -> None:
        self._network = network
        self._drives = drives
        self._motors = motors
        self._written: dict[Joint, list[Parameter]] = {}  # by _configure, read again
        self._nodes: dict[Joint, canopen.RemoteNode] = {}
        self._node_id = dict(zip(JOINTS, node_ids(drives), strict=True))
        for joint, node_id in self._node_id.items():
            node = canopen.RemoteNode(node_id, load_drive_od(eds_file(drives, joint), node_id))
            node.sdo.RESPONSE_TIMEOUT = drives.sdo_timeout_s
            node.sdo.MAX_RETRIES = SDO_RETRIES  # a lossy bus loses the odd request
            network.add_node(node)
            self._nodes[joint] = node
        self._nmt = NmtLink(network, self._node_id, self._label, boot_timeout_s)
        self._roboteq = drives.profile is DriveProfile.ROBOTEQ
        self._sdo = DriveSdo(self._nodes, self._label, drives.sdo_timeout_s)
        self._start = DriveStart(drives.profile, self._sdo.read, self._sdo.write, self._label)
        self._pdos = PdoCheck(self._sdo.read, self._sdo.write, self._sdo.read_if_present,
                              self._label,
                              lambda joint: self._nodes[joint].object_dictionary,
                              lambda joint: eds_file(drives, joint),
                              lambda joint: frozenset(
                                  (p.index, p.subindex)
                                  for p in drive_parameters(joint, drives, motors))
                              | POWER_OBJECTS)

    def close(self) -> None:
        """Unsubscribe from the network."""
        self._sdo.close()
        self._nmt.close()
        for node_id in self._node_id.values():
            del self._network[node_id]

    def run(self, start: bool = True) -> tuple[DriveInfo, DriveInfo]:
        """Configure and verify both drives, read their statusword, start them (OPERATIONAL);
        ``start=False`` (a dry run, ``rakectl drives``) leaves them PRE-OPERATIONAL."""
        check_parameter_ranges(self._drives, self._motors)  # before anything is sent
        configured = [self._configure(joint) for joint in JOINTS]
        # the device name is a segmented transfer, the one a lossy bus breaks most easily
        # (a lost segment is a toggle-bit abort): read for the dry run only
        names = ["" if start else self._sdo.read_text(joint, 0x1008, 0, "device name")
                 for joint in JOINTS]
        cleared = [self._start.clear_old_fault(joint) for joint in JOINTS]
        statuswords = [self._start.status(joint) for joint in JOINTS]
        if start:
            for joint, (*_, extra) in zip(JOINTS, configured, strict=True):
                self._check_kept(joint, extra)
            try:
                for joint in JOINTS:
                    self._nmt.start(joint)
                for joint, (*_, extra), statusword in zip(JOINTS, configured, statuswords,
                                                          strict=True):
                    self._check_started(joint, extra, statusword)
            except RakeError:  # neither drive left taking RPDOs from whoever sends them
                for joint in JOINTS:
                    with contextlib.suppress(BusError):
                        self._nmt.send(joint, NmtCommand.ENTER_PRE_OPERATIONAL)
                raise
        r_info, theta_info = (
            DriveInfo(joint, self._node_id[joint], identity, limits, statusword,
                      self._start.state_of(joint, statusword), code, name, pdos, rewritten,
                      extra)
            for joint, (identity, limits, pdos, rewritten, extra), name, statusword, code
            in zip(JOINTS, configured, names, statuswords, cleared, strict=True))
        return r_info, theta_info

    def _label(self, joint: Joint) -> str:
        return drive_label(joint, self._node_id[joint])

    def _configure(self, joint: Joint) -> Configured:
        """Reset communication and steps 2 to 5, again from the reset if a boot-up came
        meanwhile (``CONFIGURE_ATTEMPTS`` times in all): the late answer to a reset sent
        again, or a drive still powering up; one that keeps restarting is a DriveFault."""
        for _ in range(CONFIGURE_ATTEMPTS):
            self._nmt.reset_communication(joint)
            try:
                configured = self._configure_once(joint)
            except (DriveFault, CommsTimeout):
                if not self._nmt.boot_ups_since_reset(joint):
                    raise  # the drive's own answer: a restart would have said boot-up
                continue  # restarted between a write and its reading: its stored values
            if not self._nmt.boot_ups_since_reset(joint):
                return configured
        raise DriveFault(f"{self._label(joint)}: a boot-up during its configuration, "
                         f"{CONFIGURE_ATTEMPTS} times: it keeps restarting")

    def _configure_once(self, joint: Joint) -> Configured:
        identity = self._check_identity(joint)
        supply_mv = round(motor_of(self._motors, joint).supply_voltage_v * 1000)
        if self._roboteq:
            self._check_supply(joint)
        parameters = drive_parameters(joint, self._drives, self._motors)
        absent = [p for p in parameters if not self._write_parameter(joint, p)]
        read_back = [p.value if p in absent
                     else self._sdo.read(joint, p.index, p.subindex, p.name)
                     for p in parameters]
        self._written[joint] = [p for p in parameters if p not in absent]
        for p, value in zip(parameters, read_back, strict=True):
            if value != p.value:
                unit = f" {p.unit}" if p.unit else ""
                raise DriveFault(f"{self._label(joint)}: read-back mismatch: {p.where()} {p.name}: "
                                 f"wrote {p.value}{unit}, read {value}{unit}")
        limits = {p.limit: value * p.limit_scale for p, value in zip(parameters, read_back,
                                                                     strict=True)}
        limits.setdefault("max_voltage_mv", supply_mv)  # a drive with no limit of its own
        return identity, DriveLimits(**limits), *self._pdos.check(joint)

    def _check_kept(self, joint: Joint, extra: tuple[ExtraPdo, ...]) -> None:
        """Before NMT start, everything :meth:`_configure` wrote read again: a drive that
        restarted since its configuration (a brown-out, another node's NMT reset) holds
        its power-on values. DriveFault naming a boot-up heard since the reset, else the
        first object that differs."""
        self._check_no_boot_up(joint)
        self._check_parameters(joint, "before NMT start")
        self._pdos.check_kept(joint, extra, "before NMT start", RESTARTED)

    def _check_started(self, joint: Joint, extra: tuple[ExtraPdo, ...],
                       statusword: int) -> None:
        """Once the drive says OPERATIONAL: no boot-up heard since the reset, the PDOs and
        the limits read again (a restart since :meth:`_check_kept`, its boot-up lost: a
        lost NMT start gives it time), and a Roboteq-class drive still in the emergency
        shutdown that keeps its power stage off until armed (a restart clears it). Nothing
        waits on it: the drives are not enabled, and a drive's heartbeat consumer starts
        with the controller's first heartbeat."""
        self._check_no_boot_up(joint)
        self._pdos.check_kept(joint, extra, "after NMT start", RESTARTED)
        if self._roboteq:
            state = self._start.state_of(joint, statusword)
            now = self._start.state_of(joint, self._start.read_status(joint))
            if now is not state:
                raise DriveFault(f"{self._label(joint)}: after NMT start, it reads as "
                                 f"{now.name}, {state.name} before: {RESTARTED}")
        self._check_parameters(joint, "after NMT start")

    def _check_no_boot_up(self, joint: Joint) -> None:
        booted = self._nmt.boot_ups_since_reset(joint)
        if booted:
            raise DriveFault(f"{self._label(joint)}: {booted} boot-up(s) heard after its "
                             f"configuration: {RESTARTED.replace(' (its boot-up lost)', '')}")

    def _check_parameters(self, joint: Joint, when: str) -> None:
        for p in self._written[joint]:
            value = self._sdo.read(joint, p.index, p.subindex, p.name)
            if value != p.value:
                unit = f" {p.unit}" if p.unit else ""
                raise DriveFault(f"{self._label(joint)}: {when}, {p.where()} {p.name} reads "
                                 f"{value}{unit}, {p.value}{unit} was written and read back: "
                                 f"{RESTARTED}")

    def _write_parameter(self, joint: Joint, p: Parameter) -> bool:
        """``p`` written; False if the drive has no such object and needs none (0x1019)."""
        if (p.index, p.subindex) == SYNC_OVERFLOW_OBJECT:
            return self._write_sync_overflow(joint, p)
        self._sdo.write(joint, p)
        return True

    def _write_sync_overflow(self, joint: Joint, p: Parameter) -> bool:
        """0x1019, which CiA 301 lets change only while the communication cycle period 0x1006
        is 0 (CANopenNode aborts 0x08000022 otherwise): 0x1006 read, set to 0 and restored
        around it (a drive without 0x1006 has no period to clear). A drive without 0x1019
        takes SYNC without a counter only: False if that is what ``p`` asks (0)."""
        index, subindex, name = CYCLE_PERIOD_OBJECT
        period_us = self._sdo.read_if_present(joint, index, subindex, name)
        why = "0x1019 changes only while it is 0 (CiA 301)"
        if period_us:
            self._sdo.write(joint, Parameter(index, subindex, name, "µs", 0, why))
        written = True
        try:
            self._sdo.write(joint, p)
        except DriveFault as error:
            if not no_such_object(error):
                raise
            if p.value:
                raise DriveFault(f"{self._label(joint)}: no {p.where()} {p.name} (SDO abort "
                                 f"0x{abort_code(error):08X} writing {p.value}): the drive "
                                 f"takes SYNC without a counter only; set {p.setting}: 0"
                                 ) from error
            written = False
        if period_us:
            self._sdo.write(joint, Parameter(index, subindex, name, "µs", period_us, why))
        return written

    def _check_supply(self, joint: Joint) -> None:
        """A Roboteq-class drive's command is a share of its supply, scaled by the
        configured one: refused if its supply reads higher (rakectl.drive.profiles)."""
        index, subindex, name = SUPPLY_OBJECT
        problem = supply_problem(self._sdo.read(joint, index, subindex, name),
                                 motor_of(self._motors, joint).supply_voltage_v)
        if problem is not None:
            raise DriveFault(f"{self._label(joint)}: {problem}".replace(
                "<joint>", joint.name.lower()))

    def _check_identity(self, joint: Joint) -> Identity:
        """0x1018 against the configured identity (``drives.<joint>_vendor_id``,
        ``_product_code``) where one is set, else against the EDS's."""
        info = self._nodes[joint].object_dictionary.device_information
        identity = Identity(*(self._sdo.read(joint, 0x1018, sub, "identity")
                              for sub in (1, 2, 3, 4)))
        vendor_id, product_code = configured_identity(self._drives, joint)
        for name, option, configured, from_eds, found in (
                ("vendor-ID", "vendor_id", vendor_id, info.vendor_number, identity.vendor_id),
                ("product code", "product_code", product_code, info.product_number,
                 identity.product_code)):
            wanted: int | None = configured
            source = f"drives.{joint.name.lower()}_{option}"
            if configured < 0:
                wanted, source = from_eds, eds_file(self._drives, joint)
            if wanted is not None and found != wanted:
                raise DriveFault(f"{self._label(joint)}: wrong identity: {name} {found}, "
                                 f"expected {wanted} ({source})")
        return identity


def run_bring_up(bus: can.BusABC, drives: DrivesSettings, motors: MotorsSettings,
                 boot_timeout_s: float, trace: TraceRecorder | None = None,
                 start: bool = True) -> tuple[DriveInfo, DriveInfo]:
    """:class:`BringUp` on a ``canopen.Network`` over ``bus``, fed by a temporary
    ``can.Notifier`` that is stopped and joined before this returns (the module docstring);
    with ``trace``, its frames go to the bus trace too. Only CiA 301's 11-bit data frames
    reach the network (:class:`~rakectl.drive.canbus.CanopenFrames`)."""
    listeners: list[can.Listener] = []
    if trace is None:
        network = canopen.Network(bus)
    else:
        network = TracedNetwork(bus, trace, frozenset(own_ids(drives)))
        listeners.append(network.trace_listener)
    sequence = BringUp(network, drives, motors, boot_timeout_s)
    notifier = can.Notifier(bus, [CanopenFrames(network.listeners), *listeners],
                            timeout=NOTIFIER_POLL_S)
    try:
        infos = sequence.run(start)
    finally:
        notifier.stop(NOTIFIER_JOIN_S)
        sequence.close()
    return infos

