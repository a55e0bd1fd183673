"""The generated references: every configuration option and every command of the API.

``rakectl config-docs`` and ``rakectl api-docs`` print them; docs/configuration.md
and docs/api.md hold them between markers, and a test keeps those in sync.
"""

from __future__ import annotations

import dataclasses

from drivers.settings import EmulatorConfig, EmulatorSettings
from rakectl.api.schema import api_reference
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
