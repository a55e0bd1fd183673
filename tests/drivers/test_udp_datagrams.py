"""udp_multicast datagrams that are no CAN frame (not msgpack, truncated, a list, a 60 kB
block), sent from a plain UDP socket to the bench's group and port, in a private network
namespace: python-can raises CanOperationError from ``recv`` for each.

Before: one such datagram ended the emulator's process (``could not unpack received
message``), and one during the drives' bring-up ended the bring-up's notifier thread,
which then reported "no heartbeat or boot-up within 2 s" with both drives running. Now
the emulator counts them (``unreadable``) and serves on; the bring-up counts them and
completes; and the daemon's drain reads on past a burst of 30 (it ended after 4, and a
burst of 300 held the TPDO1s behind it into a false stale-feedback fault).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from rakectl.sim.rig import NAMESPACE_SETUP, namespaces_unavailable, unshare_command

_reason = namespaces_unavailable()
pytestmark = [pytest.mark.crossprocess,
              pytest.mark.skipif(_reason is not None, reason=f"no network namespace: {_reason}")]

PROBE = textwrap.dedent("""
    import dataclasses, socket, threading, time
    import msgpack
    from drivers.cli import load_config, open_bus as emulator_bus
    from drivers.emulator import Emulator
    from drivers.stats import BadInput
    from rakectl.config.service import BusInterface, BusSettings, DrivesSettings
    from rakectl.config.settings import MotorsSettings
    from rakectl.drive.bringup import run_bring_up
    from rakectl.drive.canbus import open_bus
    from rakectl.drive.client import DriveClient
    from rakectl.drive.joints import receive_ids

    GROUP = "239.74.163.11"
    bus_settings = BusSettings(interface=BusInterface.UDP_MULTICAST, channel=GROUP)
    frame = {"timestamp": 0.0, "arbitration_id": 0x701, "is_extended_id": False,
             "is_remote_frame": False, "is_error_frame": False, "channel": None, "dlc": 1,
             "data": b"\\x05", "is_fd": False, "bitrate_switch": False,
             "error_state_indicator": False}
    BAD = [b"\\xc1garbage", msgpack.packb(frame, use_bin_type=True)[:20],
           msgpack.packb([1, 2, 3]), b"\\x00" * 60000]
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)

    def inject(payload):
        raw.sendto(payload, (GROUP, bus_settings.udp_port))

    config = load_config(None, [])
    emulator = Emulator(config, emulator_bus(dataclasses.replace(
        config.bus, interface=BusInterface.UDP_MULTICAST, channel=GROUP)))
    emulator.start()
    for payload in BAD:
        inject(payload)
        time.sleep(0.01)
        emulator.service(0.05)
    print("RESULT emulator unreadable", emulator.stats.bad.counts[BadInput.UNREADABLE])

    stop, served = threading.Event(), threading.Event()
    def serve():
        while not served.is_set():
            emulator.service(0.005)
    def pester():
        while not stop.is_set():
            for payload in BAD:
                inject(payload)
            time.sleep(0.005)
    threads = [threading.Thread(target=serve), threading.Thread(target=pester)]
    for thread in threads:
        thread.start()
    drives = DrivesSettings()
    controller = open_bus(bus_settings, receive_ids(drives))
    try:
        infos = run_bring_up(controller, drives, MotorsSettings(), 2.0)
        print("RESULT bring-up", [info.node_id for info in infos])
        stop.set()
        threads[1].join()  # the pestering ends; the drives are served on
        client = DriveClient(controller, drives, MotorsSettings(), rate_hz=1000.0)
        while client.receive():
            pass
        heard, errors = client.stats.heartbeats_received, client.stats.receive_errors
        for _ in range(30):
            inject(BAD[0])
        inject(msgpack.packb(frame, use_bin_type=True))  # r's heartbeat, behind them
        time.sleep(0.05)
        client.receive()  # one drain: it read on past the 30 (it ended after 4 before)
        print("RESULT one drain", client.stats.receive_errors - errors,
              client.stats.heartbeats_received - heard >= 1)
    finally:
        stop.set()
        served.set()
        for thread in threads:
            thread.join()
        controller.shutdown()
    print("RESULT emulator served on", emulator.stats.bad.counts[BadInput.UNREADABLE] > len(BAD))
""")


def test_datagrams_that_are_no_frame_are_counted_and_served_past() -> None:
    done = subprocess.run([*unshare_command(), "sh", "-c",
                           f"{NAMESPACE_SETUP} && exec {sys.executable} -c \"$0\"", PROBE],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    results = [line.removeprefix("RESULT ") for line in done.stdout.splitlines()
               if line.startswith("RESULT ")]  # the emulator logs to stdout too
    assert results == ["emulator unreadable 4", "bring-up [1, 2]", "one drain 30 True",
                       "emulator served on True"]
