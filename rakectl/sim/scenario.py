"""A scenario for offline simulation: the controller's settings plus the emulated hardware.

This is the only place where rakectl's settings meet drivers': the daemon's
own configuration (rakectl.config.settings.Settings) knows nothing of the emulator.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.settings import EmulatorSettings
from rakectl.config.declare import section
from rakectl.config.settings import Settings


@dataclass(frozen=True)
class Scenario(Settings):
    """Settings of the controller under test and of the hardware it runs against."""

    emulator: EmulatorSettings = section(EmulatorSettings)
