"""How deep the tines may go below the soil beside them (pure).

Where an object's rounded edge forces descending tines sideways, the soil beside
them resists with its cutting resistance H(c) at their depth c below it, and the
object carries H(c) on top of what the mount pushes (docs/safety.md, "Not
covered"). The clamp bounds the mount's share by F_L = (1 − model_margin) ·
force_limit_n; the descent budget keeps H within the rest,

    H_budget = force_limit_n · model_margin − descent.drag_margin_n   (18 N on the robot),

so a descent may take the tines at most d* below the soil beside them, the root of

    f_s · (γ N_γ d² + (c N_c + q N_q) d) · w · sin(α + δ) = H_budget,

the fundamental earthmoving equation (Reece 1964; McKyes 1985, "Soil Cutting and
Tillage", ch. 4: a two-dimensional wedge failing at the angle β that minimises N_γ)
for the strongest admitted soil (``descent.*_max``), its strongest spot f_s times
its mean (``descent.strength_factor``). H grows with c, q, γ, φ and δ over the
admitted angles (tests/core/test_descent.py checks it), so their largest values
bound it. The emulator's own drag (drivers.soil.cutting_force_n) is a separate
implementation of the same equation and the test's reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from rakectl.errors import ConfigError

if TYPE_CHECKING:
    from rakectl.config.descent import DescentSettings

# The descent limiter (rakectl.core.ground_map) holds the tip this far above the floor:
# stopping there, the tip dips under its reference while the joint loops' integrators take
# the load (measured through the full chain: plunges of 0.05-1 m/s 0.24 mm, the daemon's
# jog at 0.1 m/s 0.61 mm; tests/sim/test_descent_limit.py, tests/daemon/test_descent.py).
# It comes out of the step d*.
TRACKING_MARGIN_M = 0.001

# With the descent limiter on, supervision stops the motion (its hard level) when the drag
# read from the currents exceeds the cutting resistance's budget by more than this: the
# reading errs high by 2.2-3.4 N while the motors drive a stroke (tests/sim/
# test_rake_plant.py), so the true drag is then at most about the budget. A drag over it
# means soil stronger than declared, or an object the tines push.
DRAG_TOLERANCE_N = 2.0

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
_SCAN_POINTS = 64  # the coarse scan that brackets β before the golden-section search


@dataclass(frozen=True)
class WedgeFactors:
    """Dimensionless factors of the earthmoving equation for one soil and tine."""

    n_gamma: float
    n_c: float
    n_q: float
    failure_angle_rad: float  # β, minimising N_γ


def _factors_at(rake_rad: float, phi_rad: float, delta_rad: float, beta_rad: float
                ) -> tuple[float, float]:
    """(N_γ, N_c) of the wedge failing at β; inf where no such wedge is admissible."""
    cot_beta_phi = math.cos(beta_rad + phi_rad) / math.sin(beta_rad + phi_rad)
    denominator = math.cos(rake_rad + delta_rad) + math.sin(rake_rad + delta_rad) * cot_beta_phi
    if denominator <= 0.0:
        return math.inf, math.inf
    cot_beta = math.cos(beta_rad) / math.sin(beta_rad)
    n_gamma = 0.5 * (math.cos(rake_rad) / math.sin(rake_rad) + cot_beta) / denominator
    return n_gamma, (1.0 + cot_beta * cot_beta_phi) / denominator


def wedge_factors(rake_angle_rad: float, friction_angle_rad: float,
                  tool_friction_angle_rad: float) -> WedgeFactors:
    """N_γ, N_c and N_q = 2 N_γ at the failure angle β that minimises N_γ (a scan that
    brackets the minimum, then a golden-section search). Raises ConfigError when no
    wedge is admissible (the tine's face and friction leave no failure plane)."""
    def n_gamma(beta_rad: float) -> float:
        return _factors_at(rake_angle_rad, friction_angle_rad, tool_friction_angle_rad,
                           beta_rad)[0]

    high = math.pi - friction_angle_rad  # β + φ < π
    step = high / (_SCAN_POINTS + 1)
    values = [n_gamma(step * (i + 1)) for i in range(_SCAN_POINTS)]
    best = min(range(_SCAN_POINTS), key=values.__getitem__)
    if not math.isfinite(values[best]):
        raise ConfigError(f"no admissible failure wedge for a face at "
                          f"{math.degrees(rake_angle_rad):.1f}° with φ = "
                          f"{math.degrees(friction_angle_rad):.1f}° and δ = "
                          f"{math.degrees(tool_friction_angle_rad):.1f}°")
    a, b = step * best, step * (best + 2)  # the neighbours of the scan's least value
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = n_gamma(c), n_gamma(d)
    while b - a > 1e-12:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = n_gamma(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = n_gamma(d)
    beta_rad = 0.5 * (a + b)
    n_g, n_c = _factors_at(rake_angle_rad, friction_angle_rad, tool_friction_angle_rad,
                           beta_rad)
    return WedgeFactors(n_g, n_c, 2.0 * n_g, beta_rad)


@dataclass(frozen=True)
class SoilBound:
    """The cutting resistance H(d) = a d² + b d of the strongest admitted spot of soil, and
    the budget it must stay within."""

    quadratic_n_per_m2: float  # a = f_s γ N_γ w sin(α + δ)
    linear_n_per_m: float  # b = f_s (c N_c + q N_q) w sin(α + δ)
    budget_n: float  # H_budget

    @classmethod
    def from_settings(cls, descent: DescentSettings, force_limit_n: float,
                      model_margin: float) -> SoilBound:
        d = descent
        f = wedge_factors(d.rake_angle_rad, d.friction_angle_max_rad,
                          d.tool_friction_angle_max_rad)
        scale = d.strength_factor * d.rake_width_m * math.sin(
            d.rake_angle_rad + d.tool_friction_angle_max_rad)
        return cls(scale * d.unit_weight_max_n_per_m3 * f.n_gamma,
                   scale * (d.cohesion_max_pa * f.n_c + d.surcharge_max_pa * f.n_q),
                   force_limit_n * model_margin - d.drag_margin_n)

    def resistance_n(self, depth_m: float) -> float:
        """H at a cut ``depth_m`` below the soil (0 above it)."""
        if depth_m <= 0.0:
            return 0.0
        return (self.quadratic_n_per_m2 * depth_m + self.linear_n_per_m) * depth_m

    def depth_m(self, force_n: float) -> float:
        """The cut at which H reaches ``force_n`` (the positive root, in its stable form)."""
        if force_n <= 0.0:
            return 0.0
        a, b = self.quadratic_n_per_m2, self.linear_n_per_m
        return 2.0 * force_n / (b + math.sqrt(b * b + 4.0 * a * force_n))

    @property
    def first_step_m(self) -> float:
        """d*: the deepest the tines may go below the soil beside them before any stroke
        has measured it."""
        return self.depth_m(self.budget_n)


def drag_limit_n(descent: DescentSettings, force_limit_n: float, model_margin: float) -> float:
    """The drag read from the currents above which supervision stops the motion: the
    cutting resistance's budget plus DRAG_TOLERANCE_N with ``descent.enforce``, else
    none (inf)."""
    if not descent.enforce:
        return math.inf
    return force_limit_n * model_margin - descent.drag_margin_n + DRAG_TOLERANCE_N
