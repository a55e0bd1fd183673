"""Where the service's unit lets it write, as systemd reports the installed unit.

``rakectl run --check`` judges the daemon's places as the service's user
(:mod:`rakectl.daemon.places`); the unit's sandbox narrows them further, and a place the
user may write but the sandbox keeps read-only passed the check and was refused at the
service's start. With the unit installed (``systemctl show rakectl.service``), the check
also judges each place against its sandbox, as systemd builds it: ``ProtectSystem=``
makes / (``strict``) or /usr, /boot, /efi (and /etc, ``full``) read-only;
``ProtectHome=`` hides /home, /root and /run/user (or makes them read-only);
``ReadOnlyPaths=`` and ``InaccessiblePaths=`` do so for their paths; the unit's state,
runtime, logs and cache directories and its ``ReadWritePaths=`` are writable; the
innermost of these that holds a place decides, as systemd nests them, except that
nothing nests inside a hidden path. ``PrivateTmp=`` gives the service a /tmp and /var/tmp
of its own, emptied when it stops (a warning: a trace there is lost). A place configured
relative is taken from the unit's ``WorkingDirectory=`` (/ unless it sets one), where the
service resolves it, not from where the check is run. Without systemd, or without the
unit, the sandbox is said to be not judged.
"""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
from collections.abc import Iterable
from pathlib import Path

from rakectl.errors import ConfigError

UNIT = "rakectl.service"
PROPERTIES = ("LoadState", "ProtectSystem", "ProtectHome", "PrivateTmp", "ReadWritePaths",
              "ReadOnlyPaths", "InaccessiblePaths", "StateDirectory", "RuntimeDirectory",
              "LogsDirectory", "CacheDirectory", "WorkingDirectory", "User")
SYSTEMCTL_TIMEOUT_S = 10.0
HOMES = ("/home", "/root", "/run/user")
TMPS = ("/tmp", "/var/tmp")
READ_ONLY = {"yes": ("/usr", "/boot", "/efi"),  # by ProtectSystem=, below "strict"
             "full": ("/usr", "/boot", "/efi", "/etc")}
# what a unit's sandbox makes of a path (path_rules)
HIDDEN, READ_ONLY_PATH, WRITABLE, PRIVATE = "hidden", "read-only", "writable", "private"
UNIT_DIRECTORIES = {"StateDirectory": "/var/lib", "RuntimeDirectory": "/run",
                    "LogsDirectory": "/var/log", "CacheDirectory": "/var/cache"}


def unit_sandbox(unit: str = UNIT) -> tuple[dict[str, str] | None, str]:
    """The installed unit's sandbox properties (None where there is none to judge by) and,
    for a person, what was found."""
    systemctl = shutil.which("systemctl")
    if systemctl is None:
        return None, f"{unit}'s sandbox not judged (no systemctl here)"
    try:
        done = subprocess.run([systemctl, "show", unit, "-p", ",".join(PROPERTIES)],
                              capture_output=True, timeout=SYSTEMCTL_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        return None, f"{unit}'s sandbox not judged (systemctl: {error})"
    text = done.stdout.decode(errors="replace")
    properties = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
    if done.returncode != 0 or properties.get("LoadState") != "loaded":
        said = done.stderr.decode(errors="replace").strip().splitlines()
        why = said[0] if said else f"LoadState={properties.get('LoadState', '?')}"
        return None, f"{unit}'s sandbox not judged ({why})"
    return properties, f"in {unit}'s sandbox"


def working_directory(properties: dict[str, str], home: str) -> Path:
    """Where the service takes a relative path from: its ``WorkingDirectory=`` ("~" the
    home of its ``User=``, else ``home``; the "!" systemd shows for "-", a directory that
    may be missing, dropped), else / (a system service's default)."""
    value = properties.get("WorkingDirectory", "").lstrip("!-")
    if value != "~":
        return Path(value or "/")
    try:
        return Path(pwd.getpwnam(properties["User"]).pw_dir)
    except KeyError:  # no User= (root's service), or one not on this machine
        return Path(home)


def _paths(properties: dict[str, str], key: str) -> list[Path]:
    """A path list as `systemctl show` reports it, each "-" (ignore if missing) or "+"
    (the unit's root directory's) prefix dropped."""
    return [Path(entry.lstrip("-+")) for entry in properties.get(key, "").split()]


def _own_roots(properties: dict[str, str]) -> list[Path]:
    """The unit's own directories and its ``ReadWritePaths=``."""
    return [Path(base) / entry.split(":")[0]
            for key, base in UNIT_DIRECTORIES.items()
            for entry in properties.get(key, "").split()] + _paths(properties, "ReadWritePaths")


def writable_roots(properties: dict[str, str]) -> list[Path]:
    """Where a unit with ``ProtectSystem=strict`` may write: its own directories and its
    ``ReadWritePaths=``, and its /tmp and /var/tmp if they are its own
    (``PrivateTmp=yes``)."""
    private_tmp = properties.get("PrivateTmp") == "yes"
    return _own_roots(properties) + [Path(tmp) for tmp in TMPS if private_tmp]


def _under(path: Path, roots: Iterable[Path | str]) -> bool:
    return any(path == Path(root) or Path(root) in path.parents for root in roots)


def path_rules(properties: dict[str, str]) -> list[tuple[Path, str, str]]:
    """Each path the unit's sandbox sets, with what it makes of it and the setting that
    does: (path, one of HIDDEN, READ_ONLY_PATH, WRITABLE, PRIVATE, setting)."""
    protect, home = properties.get("ProtectSystem", "no"), properties.get("ProtectHome", "no")
    rules = [(Path(root), READ_ONLY_PATH, f"ProtectSystem={protect}")
             for root in READ_ONLY.get(protect, ("/",) if protect == "strict" else ())]
    home_access = READ_ONLY_PATH if home == "read-only" else HIDDEN  # yes, tmpfs: emptied
    rules += [(Path(root), home_access, f"ProtectHome={home}") for root in HOMES
              if home != "no"]
    rules += [(root, WRITABLE, "") for root in _own_roots(properties)]
    if properties.get("PrivateTmp") == "yes":
        rules += [(Path(tmp), PRIVATE, "PrivateTmp=yes") for tmp in TMPS]
    rules += [(root, READ_ONLY_PATH, f"ReadOnlyPaths={root}")
              for root in _paths(properties, "ReadOnlyPaths")]
    return rules + [(root, HIDDEN, f"InaccessiblePaths={root}")
                    for root in _paths(properties, "InaccessiblePaths")]


def sandbox_verdict(setting: str, path: Path, properties: dict[str, str]) -> str | None:
    """ConfigError naming ``setting`` if the unit's sandbox keeps the service from writing
    ``path``; a warning (a line for a person) if it writes there privately; else None.

    A hidden path hides all below it; otherwise the innermost path that holds ``path``
    decides (systemd mounts the outer first), read-only before writable where one path
    is listed both ways."""
    path = Path(os.path.abspath(path))
    holding = [rule for rule in path_rules(properties) if _under(path, (rule[0],))]
    for _, access, by in holding:
        if access == HIDDEN:
            raise _refused(setting, path, access, by, properties)
    if not holding:
        return None
    order = (READ_ONLY_PATH, PRIVATE, WRITABLE)
    _, access, by = min(holding, key=lambda rule: (-len(rule[0].parts), order.index(rule[1])))
    if access == READ_ONLY_PATH:
        raise _refused(setting, path, access, by, properties)
    if access == PRIVATE:
        return (f"warning: {setting}: {path} is in the service's own /tmp (PrivateTmp=yes), "
                "emptied when it stops")
    return None


def _refused(setting: str, path: Path, access: str, by: str,
             properties: dict[str, str]) -> ConfigError:
    """The error naming ``setting``, the place, the unit's setting that keeps the service
    from writing it and where it could write instead."""
    said = f"{setting}: {path} is {access} {'from' if access == HIDDEN else 'to'} the service"
    if by == "ProtectSystem=strict":
        listed = ", ".join(str(root) for root in writable_roots(properties))
        return ConfigError(f"{said} ({UNIT}: {by}; it may write under {listed}): a place "
                           "there, or ReadWritePaths= for it in a drop-in (systemctl edit "
                           "rakectl)")
    if by.startswith("ProtectHome"):
        return ConfigError(f"{said} ({UNIT}: {by}): a place outside /home, /root and "
                           "/run/user")
    return ConfigError(f"{said} ({UNIT}: {by})")
