"""Where the bus contract's data files live: the drives' EDS files and the DBC.

Both sides read them from here: the controller at bring-up, the emulated
drives for their object dictionaries, the DBC generator and its test.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

PROTOCOL_DIR: Final = Path(__file__).resolve().parent
EDS_DIR: Final = PROTOCOL_DIR / "eds"
DBC_PATH: Final = PROTOCOL_DIR / "rakedrive.dbc"
