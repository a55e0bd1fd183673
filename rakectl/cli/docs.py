"""The generated references: every configuration option and every command of the API.

``rakectl config-docs`` and ``rakectl api-docs`` print them; docs/configuration.md
and docs/api.md hold them between markers, and a test keeps those in sync.
"""

from __future__ import annotations

import dataclasses

from drivers.settings import EmulatorConfig, EmulatorSettings
from rakectl.api.schema import (
    COMMANDS,
    MAX_REQUEST_BYTES,
    SERVICE_RUNTIME_DIR,
    SOCKET_NAME,
    Arg,
)
from rakectl.config.reference import reference, table
from rakectl.config.settings import Settings
from rakectl.sim.scenario import Scenario

__all__ = ["api_reference", "configuration_reference"]


def configuration_reference() -> str:
    """The daemon's options, what a scenario adds, and the emulator's."""
    daemon_keys = {f.name for f in dataclasses.fields(Settings)}
    process_keys = {"bus", "geometry", "physics"}
    return reference([
        ("The daemon (`rakectl.yaml`; every scenario too)", table(Settings)),
        ("Simulation only (scenarios: `config/scenarios/*.yaml`)",
         table(Scenario, skip=daemon_keys | {"emulator"})),
        ("Emulated hardware (`emulator.…` in a scenario, `physics.…` in `emulator.yaml`)",
         table(EmulatorSettings, "emulator.")),
        ("The emulator process (`emulator.yaml`; `bus` and `geometry` as the daemon's)",
         table(EmulatorConfig, skip=process_keys)),
    ])


def api_reference() -> str:
    """Markdown reference of the protocol and every command, from :data:`COMMANDS`."""
    lines = [
        "One JSON object per line, UTF-8, on the Unix socket (default "
        f"`{SERVICE_RUNTIME_DIR / SOCKET_NAME}` for the service). Request: "
        '`{"cmd": "<command>", <arguments>…}`, optionally with `"id"` (an integer or a string), '
        'echoed in the reply. Reply: `{"ok": true, …}` or `{"ok": false, "error": "…"}`. '
        f"A request is at most {MAX_REQUEST_BYTES} bytes; a larger one is answered with an "
        "error and the connection is closed. An invalid request changes nothing. Peers must be "
        "root, the daemon's user or members of the socket's group.", "",
        "| command | arguments | meaning |", "|---|---|---|",
    ]
    for spec in COMMANDS.values():
        args = ", ".join(f"`{a.name}`" if a.required else f"[`{a.name}`]" for a in spec.args)
        lines.append(f"| `{spec.command}` | {args or '—'} | {spec.doc} |")
    for spec in COMMANDS.values():
        if spec.args:
            lines += ["", f"#### `{spec.command}`", "", spec.doc, "", *_arg_table(spec.args)]
    return "\n".join(lines)


def _arg_table(args: tuple[Arg, ...]) -> list[str]:
    rows = ["| argument | type | required | unit | bounds | meaning |", "|---|---|---|---|---|---|"]
    for a in args:
        kind = " \\| ".join(f"`{c}`" for c in a.choices) if a.choices else a.kind.value
        need = "yes" if a.required else (f"no (default {a.default:g})"
                                        if a.default is not None else "no")
        when = f" Only with {a.only_with[0]}={a.only_with[1]}." if a.only_with else ""
        rows.append(f"| `{a.name}` | {kind} | {need} | {a.unit} | {a.bounds.describe()} "
                    f"| {a.doc}{when} |")
    return rows
