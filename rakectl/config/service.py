"""The service's options, declared once (pure): the CAN bus, the drives' bring-up and
supervision, the daemon (real time, socket, recorder) and the weight check before the
first arming. Sections of :class:`rakectl.config.settings.Settings`.
"""

from __future__ import annotations

import enum
import zlib
from dataclasses import dataclass

from rakectl.config.declare import setting
from rakectl.protocol.files import DriveProfile

UDP_PORT_BASE = 43113  # python-can's default udp_multicast port
UDP_PORT_SPAN = 1000


class BusInterface(enum.StrEnum):
    """python-can interfaces the controller and the emulator can use."""

    VIRTUAL = "virtual"  # in one process (tests)
    UDP_MULTICAST = "udp_multicast"  # across processes, only inside a private network namespace
    SOCKETCAN = "socketcan"  # can0 / vcan0 on Linux


class RtModeSetting(enum.StrEnum):
    """What the daemon does when a real-time set-up step fails."""

    ENFORCE = "enforce"  # refuse to start, naming what failed
    IGNORE = "ignore"  # warn and run anyway
    OFF = "off"  # do not try (tests, development)


@dataclass(frozen=True)
class BusSettings:
    """The CAN bus to the drives."""

    interface: BusInterface = setting(BusInterface.VIRTUAL, "python-can interface.")
    channel: str = setting("rakectl", "Channel: vcan0/can0 for socketcan, a group address "
                           "(239.74.163.2) for udp_multicast, any name for virtual.")
    bitrate: int = setting(1_000_000, "The link's bit rate, which rakectl does not set "
                           "(80-can0.network's BitRate=, or ip link): the loop's frames "
                           "must take at most 60 % of it.", unit="bit/s", ge=125_000,
                           le=1_000_000)
    trace_path: str = setting("", "Record every frame to this candump .log file, and what "
                              "else decides the frames sent to FILE.inputs.jsonl, for "
                              "`rakectl replay`; empty: off.")
    trace_keep: int = setting(3, "Earlier runs' traces kept at start, the last as "
                              "TRACE.1 (and TRACE.1.inputs.jsonl), the one before as "
                              "TRACE.2 …; 0: each start overwrites the last run's.",
                              ge=0, le=100)

    @property
    def udp_port(self) -> int:
        """udp_multicast's UDP port, derived from the group address (``channel``): a socket
        bound to a port receives every group joined on that port, so benches on different
        groups get different ports and cannot hear each other."""
        return UDP_PORT_BASE + zlib.crc32(self.channel.encode()) % UDP_PORT_SPAN


@dataclass(frozen=True)
class DrivesSettings:
    """The two CANopen drives: node-IDs, limits written at bring-up, supervision."""

    profile: DriveProfile = setting(
        DriveProfile.CIA402, "The drives' object layout (rakectl.drive.profiles): cia402, the "
        "project's own (dc_servo_drive.eds, geared_motor_drive.eds: CiA 402, voltage in mV); "
        "roboteq, Roboteq-class motor controllers (roboteq_class_drive.eds: motor command in "
        "‰ of motors.<joint>.supply_voltage_v, no CiA 402).")
    r_node_id: int = setting(1, "Node-ID of the r (DC-servo) drive.", ge=1, le=127)
    theta_node_id: int = setting(2, "Node-ID of the θ (geared-motor) drive.", ge=1, le=127)
    controller_node_id: int = setting(10, "Node-ID of the controller's heartbeat.", ge=1, le=127)
    r_vendor_id: int = setting(
        -1, "Vendor-ID (0x1018:1) the r drive must report at bring-up; -1: its EDS's "
        "VendorNumber. A vendor's drive reports the vendor's own, not the 0 of the EDS files "
        "of the drive types (docs/installation.md, section 6).", ge=-1, le=0xFFFFFFFF)
    r_product_code: int = setting(
        -1, "Product code (0x1018:2) the r drive must report at bring-up; -1: its EDS's "
        "ProductNumber.", ge=-1, le=0xFFFFFFFF)
    theta_vendor_id: int = setting(
        -1, "Vendor-ID (0x1018:1) the θ drive must report at bring-up; -1: its EDS's.",
        ge=-1, le=0xFFFFFFFF)
    theta_product_code: int = setting(
        -1, "Product code (0x1018:2) the θ drive must report at bring-up; -1: its EDS's.",
        ge=-1, le=0xFFFFFFFF)
    watchdog_timeout_ms: int = setting(
        3, "Drive command watchdog: no RPDO or SYNC this long → 0 V, quick stop, fault. The "
        "last command of a stalled or dead controller (or the one a lost command leaves) "
        "acts this long: clamp.reaction_latency_s must cover it plus one loop period, or "
        "the voltage clamp's bound does not hold while it does (with daemon.rt_mode "
        "enforce, arming is refused; otherwise the daemon warns).", unit="ms", ge=2, le=1000)
    heartbeat_period_ms: int = setting(100, "Heartbeat period of every node.", unit="ms",
                                       ge=10, le=1000)
    heartbeat_timeout_ms: int = setting(250, "Heartbeat silence that counts as a lost node.",
                                        unit="ms", ge=20, le=5000)
    sdo_timeout_s: float = setting(0.5, "Timeout of one SDO exchange at bring-up.", unit="s",
                                   gt=0, le=10)
    feedback_timeout_cycles: int = setting(
        3, "Cycles in a row without a drive's TPDO before the feedback counts as stale.",
        ge=1, le=100)
    sync_counter_overflow: int = setting(
        240, "SYNC counter overflow (0x1019), written to every drive at bring-up: 0 sends "
        "SYNC without data (what most masters and PLCs send), 2 … 240 a counter 1 … N.",
        ge=0, le=240)


@dataclass(frozen=True)
class SelfTestSettings:
    """The checks before the first arming: the rake's weight (rakectl.core.selftest) and,
    with ``press``, the tine mount's stiffness (rakectl.core.mount_check)."""

    enabled: bool = setting(
        True, "Before the first arming after start-up, lift the tip and lower it back and "
        "compare the rake's unbalanced weight, measured through the motor currents, with "
        "the clamp's model (clamp.rake_mass_kg, counterweight_kg, counterbalance_share); a "
        "mismatch faults instead of arming.")
    lift_m: float = setting(0.02, "How far the tip is lifted (straight up).", unit="m", gt=0,
                            le=0.1)
    speed_m_per_s: float = setting(0.02, "Lift and lowering speed.", unit="m/s", gt=0, le=0.1)
    tolerance: float = setting(
        0.3, "Largest relative difference between the measured and the configured unbalanced "
        "weight (a missing counterweight doubles it).", gt=0, lt=1)
    press: bool = setting(
        False, "After the weight check, press the tines on the anvil from above and on its near "
        "side and compare the tine mount's stiffness each way, measured through the motor "
        "currents and encoders, with clamp.contact_stiffness_n_per_m and "
        "side_contact_stiffness_n_per_m (rakectl.core.mount_check); a mismatch faults instead "
        "of arming. Needs the anvil: a rigid block on the robot's frame.")
    anvil_reach_m: float = setting(0.45, "Reach of the anvil's centre (from the pivot).",
                                   unit="m", gt=0, le=3)
    anvil_height_m: float = setting(0.1, "Height of the anvil's flat top above ground level 0, "
                                    "known within 5 mm.", unit="m", ge=-0.5, le=1)
    anvil_width_m: float = setting(
        0.06, "Width of the anvil along the reach: its near side, the flat vertical face toward "
        "the robot at anvil_reach_m − anvil_width_m/2, is pressed sideways; known within 5 mm.",
        unit="m", gt=0, le=1)
    anvil_side_height_m: float = setting(
        0.05, "Height above ground level 0 at which the tines press the anvil's near side: on "
        "its flat face, at least 10 mm below the anvil's top (its rounded edge) and clear of "
        "the soil.", unit="m", ge=-0.5, le=1)
    press_force_n: float = setting(
        10.0, "How hard the tines press the anvil, read through the currents above their "
        "reading in free air; the clamp's worst-case model holds a press near 18 N at best "
        "(a press it holds short fails, naming it).", unit="N", ge=5, le=20)
    press_speed_m_per_s: float = setting(0.005, "Speed of the press.", unit="m/s", ge=0.001,
                                         le=0.02)
    travel_speed_m_per_s: float = setting(0.05, "Speed to the anvil and back.", unit="m/s",
                                          ge=0.01, le=0.1)
    mount_stiffer_tolerance: float = setting(
        0.2, "How much stiffer than configured (clamp.contact_stiffness_n_per_m, "
        "side_contact_stiffness_n_per_m) the measured mount may be, each way (the clamp takes "
        "the configured stiffnesses as the stiffest contacts: 20 % stiffer raises the spring "
        "part of an impact's bound √1.2 ≈ 1.1 times, inside clamp.model_margin).",
        gt=0, le=0.2)
    mount_softer_tolerance: float = setting(
        0.5, "How much softer than configured the measured mount may be, each way (much "
        "softer is another mount). Softer both ways alike is safe for the clamp; one way "
        "softer than the other is mount_ratio_tolerance's to judge.", gt=0, lt=1)
    mount_ratio_tolerance: float = setting(
        1.5, "How far the measured ratio of the mount's two stiffnesses (down over "
        "sideways) may stray from the configured ratio, as a factor either way. One way "
        "softer than the other stores energy a rounded edge turns into a push √ratio times "
        "larger. The readings' own error moves the ratio 0.81–1.14 times with the anvil's "
        "pose and the mount, so 1.5 passes a correct mount and refuses one whose true ratio "
        "is off by more than 1.85 either way (rakectl.core.mount_check); it may be tightened, "
        "not loosened.", ge=1.25, le=1.5)


@dataclass(frozen=True)
class DaemonSettings:
    """The service: real-time set-up, command socket, flight recorder, supervision."""

    rt_mode: RtModeSetting = setting(RtModeSetting.IGNORE, "Real-time set-up failures: "
                                     "enforce, ignore or off.")
    rt_priority: int = setting(80, "SCHED_FIFO priority of the loop.", ge=1, le=99)
    cpu: int = setting(-1, "CPU to pin the loop to; -1: no pinning.", ge=-1, le=1023)
    socket_path: str = setting("", "Command socket; empty: /run/rakectl/rakectl.sock under "
                               "systemd, a per-user path otherwise.")
    socket_group: str = setting("", "Group that may use the command socket (mode 0660); "
                                "empty: the daemon's own group.")
    dump_dir: str = setting("", "Where flight-recorder dumps go; empty: $STATE_DIRECTORY "
                            "under systemd, else the current directory.")
    recorder_s: float = setting(4.0, "History kept by the flight recorder.", unit="s", ge=2,
                                le=60)
    boot_timeout_s: float = setting(3.0, "How long bring-up waits for each drive's boot-up "
                                    "and, after NMT start, for its heartbeat to say "
                                    "OPERATIONAL; and the loop for both drives' first "
                                    "valid feedback.", unit="s", gt=0, le=60)
    enable_timeout_s: float = setting(0.5, "How long arming waits for both drives to report "
                                      "OPERATION ENABLED.", unit="s", gt=0, le=10)
    overrun_fault_streak: int = setting(
        50, "Late ticks in a row that count as a fault (the loop cannot keep time).", ge=2,
        le=100000)
    stats_interval_s: float = setting(10.0, "How often timing statistics are logged.", unit="s",
                                      gt=0, le=3600)
    arm_timing_s: float = setting(
        2.0, "Before the first arming, the loop measures its own timing for at least this "
        "long; with rt_mode enforce, arming is refused before.", unit="s", ge=0, le=600)
    arm_max_latency_p99_us: float = setting(
        500.0, "With rt_mode enforce, arming is refused while the p99 of the loop's wake-up "
        "latency (how late its sleep woke, as cyclictest measures; since start-up) is above "
        "this; otherwise it is logged.",
        unit="µs", gt=0, le=1e6)
    arm_max_late_share: float = setting(
        0.001, "With rt_mode enforce, arming is refused while the share of late ticks "
        "(overruns per tick, since start-up) is above this; otherwise it is logged.",
        ge=0, le=1)
    startup_cyclictest_s: float = setting(
        3.0, "At start-up, before bring-up, cyclictest (rt-tests) measures the machine's own "
        "wake-up latency this long, the reference the loop's is compared with (status, "
        "journal); 0: not measured. Without cyclictest the reason is reported instead.",
        unit="s", ge=0, le=60)
    arm_max_latency_ratio: float = setting(
        3.0, "With rt_mode enforce and a start-up cyclictest, arming is refused while the "
        "loop's p99 wake-up latency is more than this many times cyclictest's p99; otherwise "
        "it is logged. 0: not compared.", ge=0, le=1000)
