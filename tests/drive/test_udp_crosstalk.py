"""Two emulated benches on different udp_multicast groups, in one network namespace:
neither hears the other (each group has its own port, BusSettings.udp_port), where one
port for both would let a bench receive the other's frames."""

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
    import sys, can
    from rakectl.config.service import BusInterface, BusSettings
    from rakectl.drive.canbus import open_bus
    same_port = sys.argv[1] == "same"
    def bus(group):
        settings = BusSettings(interface=BusInterface.UDP_MULTICAST, channel=group)
        if same_port:
            return can.Bus(interface="udp_multicast", channel=group, fd=False)
        return open_bus(settings, ())
    a, b = bus("239.74.163.2"), bus("239.74.163.3")
    try:
        a.send(can.Message(arbitration_id=0x80, data=b"\\x01", is_extended_id=False))
        print("heard" if b.recv(0.5) is not None else "quiet")
    finally:
        a.shutdown(); b.shutdown()
""")


def _probe(mode: str) -> str:
    done = subprocess.run([*unshare_command(), "sh", "-c",
                           f"{NAMESPACE_SETUP} && exec {sys.executable} -c \"$0\" {mode}",
                           PROBE], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_benches_on_different_groups_do_not_hear_each_other() -> None:
    assert _probe("derived") == "quiet"
    assert _probe("same") == "heard"  # python-can's one default port: the cross-talk seen
