"""``rakectl run --check``: what a field engineer runs after editing the service's
configuration, before restarting it. It opens nothing: no bus, no socket, no file
written."""

from __future__ import annotations

import os
from pathlib import Path


def check_config(config: Path | None, overrides: list[str], user_name: str | None) -> int:
    """``rakectl run --check``: the configuration loaded and cross-checked as the daemon
    loads it, and what bring-up would write checked against the drives' EDS limits (a
    ConfigError names the key), the command socket's path and group and the CAN link's
    bit rate as the daemon checks them before bring-up, where it writes (its dumps, its
    bus trace) and that it can read the file, as the service's user
    (:func:`rakectl.daemon.places.service_user`), then what the daemon would drive."""
    from rakectl.api.client import socket_path
    from rakectl.api.endpoint import check_endpoint
    from rakectl.config.loader import load_settings
    from rakectl.config.service import RtModeSetting
    from rakectl.config.settings import Settings, held_command_gap
    from rakectl.daemon.places import (
        SERVICE_USER,
        check_places,
        check_readable,
        judged_as,
        places_of,
        relative_places,
        service_user,
    )
    from rakectl.daemon.sandbox import sandbox_verdict, unit_sandbox, working_directory
    from rakectl.drive.link import check_link_bitrate
    from rakectl.drive.profiles import check_parameter_ranges

    s = load_settings(config, overrides, root=Settings)
    check_parameter_ranges(s.drives, s.motors)  # bring-up's own check, before it sends
    check_endpoint(socket_path(s.daemon.socket_path or None), s.daemon.socket_group or None)
    _, link = check_link_bitrate(s.bus)
    user = service_user(user_name)
    sandbox: dict[str, str] | None = None  # the unit's, judged for its user
    base: Path | None = None  # the service's working directory, where the unit gives it
    if user is not None:
        sandbox, in_sandbox = unit_sandbox()
        base = None if sandbox is None else working_directory(sandbox, user.pw_dir)

    def judge() -> list[str]:
        if config is not None:
            check_readable(config, "--config")
        return check_places(s, base)

    if user is None:
        places, judged = judge(), f"as this process (uid {os.geteuid()})"
        if os.geteuid() == 0:  # no service user here (a bench, a test machine)
            judged += (f", not the service's user (no user {SERVICE_USER} here): root may "
                       "write where it may not; --user NAME judges as another")
        else:
            judged += f", not the service's user: judging as {SERVICE_USER} takes root"
    else:  # then the unit's sandbox, where systemd has it
        places = judged_as(user, judge)
        judged = f"as user {user.pw_name} (uid {user.pw_uid}), {in_sandbox}"
    warnings = [] if sandbox is None else [
        warning for setting, path in places_of(s, base)
        if (warning := sandbox_verdict(setting, path, sandbox)) is not None]
    for setting, value in relative_places(s):
        warnings.append(
            f"warning: {setting}: {value} is relative: the daemon takes it from its working "
            + (f"directory, {base} in the unit" if base is not None else
               f"directory (judged from this one, {Path.cwd()}; the service's is / unless "
               "its unit sets WorkingDirectory=)"))
    d = s.drives
    print(f"{config or '<defaults>'}: the configuration loads")
    print(f"  bus {s.bus.interface.value}:{s.bus.channel} at {s.bus.bitrate} bit/s; drives "
          f"{d.profile.value}, r node {d.r_node_id}, θ node {d.theta_node_id}, watchdog "
          f"{d.watchdog_timeout_ms} ms; loop {s.rate_hz:g} Hz, rt_mode {s.daemon.rt_mode.value}")
    print(f"  link: {link}")
    checks = ("weight check" + (" and tine-mount check" if s.selftest.press else "")
              if s.selftest.enabled else "none (selftest.enabled: false)")
    print(f"  force limit {s.clamp.force_limit_n:g} N; checks before arming: {checks}; "
          f"surveyed points: {len(s.descent.survey)}")
    print(f"  {'; '.join(places)}; judged {judged}")
    for warning in warnings:
        print(f"  {warning}")
    gap = held_command_gap(s)
    if gap:
        refusal = ("arming is refused" if s.daemon.rt_mode is RtModeSetting.ENFORCE else
                   "logged as clamp_warning at start-up and at each arming")
        print(f"  warning: {gap} ({refusal})")
    return 0
