"""Where the service's unit lets it write, as systemd reports the installed unit.

``rakectl run --check`` judges the daemon's places as the service's user
(:mod:`rakectl.daemon.places`); the unit's sandbox narrows them further, and a place the
user may write but the sandbox keeps read-only passed the check and was refused at the
service's start. With the unit installed (``systemctl show rakectl.service``), the check
also judges each place against its sandbox: ``ProtectSystem=strict`` leaves writable only
the unit's state, runtime, logs and cache directories and its ``ReadWritePaths=``;
``ProtectHome=`` hides /home, /root and /run/user; ``PrivateTmp=`` gives the service a
/tmp and /var/tmp of its own, emptied when it stops (a warning: a trace there is lost).
A place configured relative is taken from the unit's ``WorkingDirectory=`` (/ unless it
sets one), where the service resolves it, not from where the check is run. Without
systemd, or without the unit, the sandbox is said to be not judged.
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
              "StateDirectory", "RuntimeDirectory", "LogsDirectory", "CacheDirectory",
              "WorkingDirectory", "User")
SYSTEMCTL_TIMEOUT_S = 10.0
HOMES = ("/home", "/root", "/run/user")
TMPS = ("/tmp", "/var/tmp")
READ_ONLY = {"yes": ("/usr", "/boot", "/efi"),  # by ProtectSystem=, below "strict"
             "full": ("/usr", "/boot", "/efi", "/etc")}
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


def writable_roots(properties: dict[str, str]) -> list[Path]:
    """Where a unit with ``ProtectSystem=strict`` may write: its own directories and its
    ``ReadWritePaths=`` (a "-" or "+" prefix dropped), and its /tmp and /var/tmp if they
    are its own (``PrivateTmp=yes``)."""
    roots = [Path(base) / entry.split(":")[0]
             for key, base in UNIT_DIRECTORIES.items()
             for entry in properties.get(key, "").split()]
    roots += [Path(entry.lstrip("-+")) for entry in properties.get("ReadWritePaths", "").split()]
    private_tmp = properties.get("PrivateTmp") == "yes"
    return roots + [Path(tmp) for tmp in TMPS if private_tmp]


def _under(path: Path, roots: Iterable[Path | str]) -> bool:
    return any(path == Path(root) or Path(root) in path.parents for root in roots)


def sandbox_verdict(setting: str, path: Path, properties: dict[str, str]) -> str | None:
    """ConfigError naming ``setting`` if the unit's sandbox keeps the service from writing
    ``path``; a warning (a line for a person) if it writes there privately; else None."""
    path = Path(os.path.abspath(path))
    home = properties.get("ProtectHome", "no")
    if home != "no" and _under(path, HOMES):
        raise ConfigError(f"{setting}: {path} is hidden from the service ({UNIT}: "
                          f"ProtectHome={home}): a place outside /home, /root and /run/user")
    protect = properties.get("ProtectSystem", "no")
    if _under(path, READ_ONLY.get(protect, ())):
        raise ConfigError(f"{setting}: {path} is read-only to the service ({UNIT}: "
                          f"ProtectSystem={protect})")
    if protect == "strict":
        roots = writable_roots(properties)
        if not _under(path, roots):
            listed = ", ".join(str(root) for root in roots)
            raise ConfigError(f"{setting}: {path} is read-only to the service ({UNIT}: "
                              f"ProtectSystem=strict; it may write under {listed}): a place "
                              "there, or ReadWritePaths= for it in a drop-in (systemctl "
                              "edit rakectl)")
    if properties.get("PrivateTmp") == "yes" and _under(path, TMPS):
        return (f"warning: {setting}: {path} is in the service's own /tmp (PrivateTmp=yes), "
                "emptied when it stops")
    return None
