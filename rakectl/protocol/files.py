"""Where the bus contract's data files live: the drives' EDS files and the DBC, and the
drive profiles they declare.

Both sides read them from here: the controller at bring-up, the emulated
drives for their object dictionaries, the DBC generator and its test.
"""

from __future__ import annotations

import enum
from pathlib import Path
from typing import Final

PROTOCOL_DIR: Final = Path(__file__).resolve().parent
EDS_DIR: Final = PROTOCOL_DIR / "eds"
DBC_PATH: Final = PROTOCOL_DIR / "rakedrive.dbc"


class DriveProfile(enum.StrEnum):
    """The object layouts a drive may speak (``drives.profile``)."""

    CIA402 = "cia402"  # the project's own: CiA 402, voltage 0x2000 in mV (dc_servo/geared_motor)
    ROBOTEQ = "roboteq"  # Roboteq-class: motor command 0x2000:01 in ‰, no CiA 402
