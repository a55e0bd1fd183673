"""The one requirement that must never fail, declared once.

Anti-personnel mines are pressure-fused (80–100 N fuses): the force on the
ground, or on a buried object from any direction, must never exceed this. The
clamp's limit may be set lower, never higher; the safety campaign, the
benchmarks and the plots judge against this value.
"""

from typing import Final

FORCE_LIMIT_N: Final = 90.0
