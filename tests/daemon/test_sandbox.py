"""The service's places judged against its unit's sandbox (rakectl.daemon.sandbox), with
the properties systemd reports for the shipped unit (systemd/rakectl.service). The same
judged from the unit systemd has loaded: tests/service/test_service.py, in the VM."""

from __future__ import annotations

import pwd
from pathlib import Path

import pytest

from rakectl.daemon.sandbox import sandbox_verdict, working_directory, writable_roots
from rakectl.errors import ConfigError

SHIPPED = {"LoadState": "loaded", "ProtectSystem": "strict", "ProtectHome": "yes",
           "PrivateTmp": "yes", "ReadWritePaths": "", "StateDirectory": "rakectl",
           "RuntimeDirectory": "rakectl", "LogsDirectory": "", "CacheDirectory": ""}


def test_the_shipped_unit_writes_in_its_own_directories_and_private_tmp() -> None:
    assert writable_roots(SHIPPED) == [Path("/var/lib/rakectl"), Path("/run/rakectl"),
                                       Path("/tmp"), Path("/var/tmp")]
    for place in ("/var/lib/rakectl/dumps", "/var/lib/rakectl", "/run/rakectl/x.log"):
        assert sandbox_verdict("daemon.dump_dir", Path(place), SHIPPED) is None
    assert sandbox_verdict("bus.trace_path", Path("/tmp/bus.log"), SHIPPED) == (
        "warning: bus.trace_path: /tmp/bus.log is in the service's own /tmp "
        "(PrivateTmp=yes), emptied when it stops")


@pytest.mark.parametrize(("place", "expected"), [
    ("/var/log/rakectl/bus.log", "bus.trace_path: /var/log/rakectl/bus.log is read-only to "
     "the service (rakectl.service: ProtectSystem=strict; it may write under "
     "/var/lib/rakectl, /run/rakectl, /tmp, /var/tmp): a place there, or ReadWritePaths= "
     "for it in a drop-in (systemctl edit rakectl)"),
    ("/var/lib/rakectl-other/bus.log", "bus.trace_path: /var/lib/rakectl-other/bus.log is "
     "read-only to the service (rakectl.service: ProtectSystem=strict; it may write under "
     "/var/lib/rakectl, /run/rakectl, /tmp, /var/tmp): a place there, or ReadWritePaths= "
     "for it in a drop-in (systemctl edit rakectl)"),
    ("/home/field/bus.log", "bus.trace_path: /home/field/bus.log is hidden from the service "
     "(rakectl.service: ProtectHome=yes): a place outside /home, /root and /run/user"),
])
def test_a_place_the_sandbox_keeps_from_the_service_is_refused(place: str,
                                                               expected: str) -> None:
    with pytest.raises(ConfigError) as refused:
        sandbox_verdict("bus.trace_path", Path(place), SHIPPED)
    assert str(refused.value) == expected


def test_a_drop_in_or_a_looser_unit_lets_it_write_there() -> None:
    dropped_in = {**SHIPPED, "ReadWritePaths": "-/var/log/rakectl /srv/traces",
                  "LogsDirectory": "rakectl-logs"}
    assert writable_roots(dropped_in) == [
        Path("/var/lib/rakectl"), Path("/run/rakectl"), Path("/var/log/rakectl-logs"),
        Path("/var/log/rakectl"), Path("/srv/traces"), Path("/tmp"), Path("/var/tmp")]
    for place in ("/var/log/rakectl/bus.log", "/srv/traces/a/bus.log"):
        assert sandbox_verdict("bus.trace_path", Path(place), dropped_in) is None
    full = {**SHIPPED, "ProtectSystem": "full", "ProtectHome": "no", "PrivateTmp": "no"}
    assert sandbox_verdict("bus.trace_path", Path("/var/log/rakectl/bus.log"), full) is None
    assert sandbox_verdict("bus.trace_path", Path("/home/field/bus.log"), full) is None
    with pytest.raises(ConfigError, match=r"^bus\.trace_path: /etc/rakectl/bus\.log is "
                                          r"read-only to the service \(rakectl\.service: "
                                          r"ProtectSystem=full\)$"):
        sandbox_verdict("bus.trace_path", Path("/etc/rakectl/bus.log"), full)


@pytest.mark.parametrize(("shown", "expected"), [
    ("", "/"), ("/srv/rakectl", "/srv/rakectl"), ("!/srv/rakectl", "/srv/rakectl"),
    ("~", "/var/lib/rakectl-home"), ("!~", "/var/lib/rakectl-home")])
def test_a_relative_place_is_taken_from_the_units_working_directory(shown: str,
                                                                    expected: str) -> None:
    """As `systemctl show` reports WorkingDirectory=: empty where the unit sets none (a
    system service runs in /), "~" for its user's home, "!" before a directory that may
    be missing (the unit's "-")."""
    unit = {**SHIPPED, "WorkingDirectory": shown}
    assert working_directory(unit, "/var/lib/rakectl-home") == Path(expected)


def test_the_units_home_is_its_users_not_the_one_judged_as() -> None:
    """WorkingDirectory=~ is the home of the unit's User=, whoever `--user` judges as."""
    unit = {**SHIPPED, "WorkingDirectory": "~", "User": "nobody"}
    assert working_directory(unit, "/root") == Path(pwd.getpwnam("nobody").pw_dir)
    assert working_directory({**unit, "User": "no-such-user-here"}, "/root") == Path("/root")


@pytest.mark.parametrize(("unit", "place", "expected"), [
    ({"ReadOnlyPaths": "/var/lib/rakectl/dumps"}, "/var/lib/rakectl/dumps/a",
     "daemon.dump_dir: /var/lib/rakectl/dumps/a is read-only to the service "
     "(rakectl.service: ReadOnlyPaths=/var/lib/rakectl/dumps)"),
    ({"ReadOnlyPaths": "-/var/lib/rakectl", "ReadWritePaths": "/var/lib/rakectl"},
     "/var/lib/rakectl/dumps", "daemon.dump_dir: /var/lib/rakectl/dumps is read-only to "
     "the service (rakectl.service: ReadOnlyPaths=/var/lib/rakectl)"),
    ({"InaccessiblePaths": "/var/lib/rakectl", "ReadWritePaths": "/var/lib/rakectl/dumps"},
     "/var/lib/rakectl/dumps", "daemon.dump_dir: /var/lib/rakectl/dumps is hidden from the "
     "service (rakectl.service: InaccessiblePaths=/var/lib/rakectl)"),
    ({"ProtectHome": "read-only", "ProtectSystem": "full"}, "/root/dumps",
     "daemon.dump_dir: /root/dumps is read-only to the service (rakectl.service: "
     "ProtectHome=read-only): a place outside /home, /root and /run/user"),
])
def test_read_only_and_inaccessible_paths_keep_a_place_from_the_service(
        unit: dict[str, str], place: str, expected: str) -> None:
    """ReadOnlyPaths= and InaccessiblePaths= (a drop-in's) narrow the unit's own
    directories: a place under one is refused, naming it; a path listed both read-only
    and writable is read-only, and nothing nested in a hidden path is reachable."""
    with pytest.raises(ConfigError) as refused:
        sandbox_verdict("daemon.dump_dir", Path(place), {**SHIPPED, **unit})
    assert str(refused.value) == expected


def test_the_innermost_path_decides() -> None:
    """As systemd nests its mounts: a writable path inside a read-only one is writable,
    and a read-only one inside it read-only again, under ProtectSystem=strict and =full."""
    nested = {**SHIPPED, "ReadOnlyPaths": "/var/lib/rakectl/archive",
              "ReadWritePaths": "/var/lib/rakectl/archive/incoming"}
    assert sandbox_verdict("daemon.dump_dir", Path("/var/lib/rakectl/archive/incoming/d"),
                           nested) is None
    assert sandbox_verdict("daemon.dump_dir", Path("/var/lib/rakectl/dumps"), nested) is None
    with pytest.raises(ConfigError, match=r"ReadOnlyPaths=/var/lib/rakectl/archive\)$"):
        sandbox_verdict("daemon.dump_dir", Path("/var/lib/rakectl/archive/d"), nested)
    full = {**SHIPPED, "ProtectSystem": "full", "ReadWritePaths": "/etc/rakectl/traces"}
    assert sandbox_verdict("bus.trace_path", Path("/etc/rakectl/traces/bus.log"),
                           full) is None
    with pytest.raises(ConfigError, match=r"ProtectSystem=full\)$"):
        sandbox_verdict("bus.trace_path", Path("/etc/rakectl/bus.log"), full)
    private = {**SHIPPED, "ReadOnlyPaths": "/tmp/ro"}
    with pytest.raises(ConfigError, match=r"ReadOnlyPaths=/tmp/ro\)$"):
        sandbox_verdict("bus.trace_path", Path("/tmp/ro/bus.log"), private)
    no_private = {**SHIPPED, "PrivateTmp": "no", "ReadWritePaths": "/tmp"}
    assert sandbox_verdict("bus.trace_path", Path("/tmp/bus.log"), no_private) is None
