"""``rakectl drives``: the daemon's bring-up as a dry run, for a field engineer adding or
replacing a drive: every step of rakectl.drive.bringup (boot-up after NMT reset
communication, identity against the EDS, limits written and read back, device name,
PDO communication and mapping read back against the EDS, no other TPDO valid, a fault
left by a previous run reset), then what each drive is and holds, printed. The drives
are not started: they stay PRE-OPERATIONAL, their power stage disabled (0 V). The first
thing that differs is one line naming the drive, the object and both values, exit
status 1.

Never while the daemon runs: its NMT reset would take the drives from under it."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from rakectl.errors import DaemonUnreachable, RakeError

STATUS_TIMEOUT_S = 1.0  # how long a running daemon may take to answer before it counts as absent


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    p = sub.add_parser("drives", help="bring the drives up as the daemon would, without "
                       "starting them, and print identity, PDO mapping and limits read back "
                       "(exit status 1 on the first difference; never while the daemon runs)")
    p.add_argument("--config", type=Path, help="the daemon's YAML configuration (e.g. "
                   "/etc/rakectl/rakectl.yaml)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one option (repeatable)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")


def cmd_drives(args: argparse.Namespace) -> int:
    from rakectl.config.loader import load_settings
    from rakectl.config.settings import Settings
    from rakectl.drive.bringup import run_bring_up
    from rakectl.drive.canbus import open_bus
    from rakectl.drive.joints import receive_ids
    from rakectl.drive.profiles import drive_parameters, eds_file

    settings = load_settings(args.config, args.overrides, root=Settings)
    _refuse_if_the_daemon_runs(settings.daemon.socket_path)
    from rakectl.api.client import socket_path
    from rakectl.api.endpoint import claim

    claimed = claim(socket_path(settings.daemon.socket_path or None))  # a daemon starting
    try:  # (not answering yet) holds it: its drives are left alone
        bus = open_bus(settings.bus, receive_ids(settings.drives))
        try:
            infos = run_bring_up(bus, settings.drives, settings.motors,
                                 settings.daemon.boot_timeout_s, start=False)
        finally:
            bus.shutdown()
    finally:
        os.close(claimed)
    reports = [report(info, drive_parameters(info.joint, settings.drives, settings.motors),
                      eds_file(settings.drives, info.joint), settings.drives.profile.value)
               for info in infos]
    if args.json:
        print(json.dumps({"drives": reports, "started": False}))
    else:
        print("\n".join(text(r) for r in reports))
        print("both drives as configured; not started (PRE-OPERATIONAL, 0 V)")
    return 0


def _refuse_if_the_daemon_runs(configured: str) -> None:
    from rakectl.api.client import call, socket_path

    path = socket_path(configured or None)
    try:
        status = call(path, {"cmd": "status"}, timeout_s=STATUS_TIMEOUT_S)
    except (DaemonUnreachable, OSError):
        return
    raise RakeError(f"the daemon answers on {path} (state {status.get('state', '?')}): stop "
                    "it first (systemctl stop rakectl); a bring-up now would reset its drives")


def report(info: Any, parameters: Any, eds: str, profile: str) -> dict[str, Any]:
    """A DriveInfo (rakectl.drive.joints) and what bring-up wrote (each value read back, in
    the drive's unit), as plain data."""
    from rakectl.drive.joints import drive_label

    return {
        "drive": drive_label(info.joint, info.node_id), "node_id": info.node_id,
        "eds": eds, "profile": profile, "device_name": info.device_name,
        "identity": vars(info.identity), "state": info.state.name,
        "statusword": info.statusword, "cleared_fault": info.cleared_fault,
        "max_voltage_mv": info.limits.max_voltage_mv,
        "limits": [{"object": p.where(), "name": p.name,
                    "value": getattr(info.limits, p.limit) // p.limit_scale, "unit": p.unit,
                    "setting": p.setting} for p in parameters],
        "pdos": [{"name": pdo.name, "cob_id": pdo.cob_id,
                  "transmission_type": pdo.transmission_type,
                  "mapped": [{"index": i, "subindex": s, "bits": b} for i, s, b in pdo.entries()]}
                 for pdo in info.pdos],
        "rewritten": [{"name": pdo.name, "cob_id": pdo.cob_id,
                       "transmission_type": pdo.transmission_type,
                       "mapped": [m for m in pdo.mapped if m >= 0],
                       "longer": any(m < 0 for m in pdo.mapped),
                       "timers": dict(pdo.timers)} for pdo in info.rewritten],
        "extra": [{"name": pdo.name, "cob_id": pdo.cob_id, "kept": pdo.kept}
                  for pdo in info.extra],
    }


def text(r: dict[str, Any]) -> str:
    """A :func:`report` for people."""
    ident = r["identity"]
    lines = [f"{r['drive']}: {r['device_name']!r} ({r['eds']}): vendor-ID "
             f"0x{ident['vendor_id']:08X}, product code {ident['product_code']}, revision "
             f"0x{ident['revision']:08X}, serial {ident['serial']}",
             (f"  CiA 402 state {r['state']} (statusword 0x{r['statusword']:04X})"
              if r["profile"] == "cia402" else
              f"  profile {r['profile']}: reads as CiA 402 state {r['state']} (fault flags "
              f"0x{r['statusword'] >> 16:04X}, status flags 0x{r['statusword'] & 0xFFFF:04X}); "
              f"commands scaled by {r['max_voltage_mv'] / 1000:g} V")
             + (f"; a fault left by a previous run, 0x{r['cleared_fault']:04X}, was reset"
                if r["cleared_fault"] else ""),
             "  written and read back:"]
    for limit in r["limits"]:
        value = f"{limit['value']}" + (f" {limit['unit']}" if limit["unit"] else "")
        if limit["object"] == "0x1016:1":  # consumer heartbeat: node-ID << 16 | timeout ms
            value = f"node {limit['value'] >> 16}, {limit['value'] & 0xFFFF} ms"
        lines.append(f"    {limit['object']:<9} {limit['name']:<22} {value:>12}   "
                     f"{limit['setting']}")
    lines.append("  PDOs read back, as the EDS declares them:")
    for pdo in r["pdos"]:
        kind = pdo["transmission_type"]
        when = ("every SYNC" if kind == 1 else f"every {kind}th SYNC" if kind <= 240
                else "on change")
        mapped = ", ".join(f"0x{m['index']:04X}:{m['subindex']} ({m['bits']} bit)"
                           for m in pdo["mapped"])
        no_rtr = ", no RTR" if pdo["cob_id"] & 1 << 30 else ""  # bit 30: the drive's own
        lines.append(f"    {pdo['name']:<6} COB-ID 0x{pdo['cob_id'] & 0x7FF:03X}{no_rtr}, {when}: "
                     f"{mapped}")
    if r["rewritten"]:
        lines.append("  held otherwise by the drive, the EDS's written back (not stored: at "
                     "every bring-up):")
    for pdo in r["rewritten"]:
        mapped = ", ".join(f"0x{m:08X}" for m in pdo["mapped"]) + (", …" if pdo["longer"]
                                                                   else "")
        timers = "".join(f", {what} {value}" for what, value in pdo["timers"].items())
        lines.append(f"    {pdo['name']:<6} COB-ID 0x{pdo['cob_id']:X}, transmission type "
                     f"{pdo['transmission_type']}{timers}, mapped [{mapped}]")
    if r["extra"]:
        lines.append("  beyond the EDS's and valid, made not valid (not stored: at every "
                     "bring-up):")
    for pdo in r["extra"]:
        kept = (f": kept valid by the drive ({pdo['kept']}); it takes any frame sent on "
                f"0x{pdo['cob_id'] & 0x7FF:03X}" if pdo["kept"] else "")
        lines.append(f"    {pdo['name']:<6} COB-ID 0x{pdo['cob_id']:X}{kept}")
    return "\n".join(lines)
