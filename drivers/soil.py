"""Soil of one raking lane: the ground truth the rake tip meets (pure model).

Coordinates are the tip's ``reach_m`` (horizontal distance from the pivot; a
contact stroke drags the tip toward the robot, reach decreasing) and
``height_m`` (above the original ground level 0). Forces are those ON the tip.

Vertical: the paper's collapsing interface (seed paper, sections IV–VI)
    F = K_e (x_e − x) + B ẋ_pen   while the tip is below the interface x_e,
with x_e the *undeformed* interface under the tip. x_e stays put while the tip
pushes in; when the elastic force K_e (x_e − x) exceeds the local collapse
force F_c (equivalently the stored energy exceeds ½ F_c²/K_e) the interface
collapses to the tip, x_e(t_r) = x_max(t_{r−1}), so a steady descent at speed v
gives a saw-tooth 0 → F_c with period F_c/(K_e v). Several collapses inside one
step are resolved exactly (linear motion over the step), so sampled peaks stay
within K_e·v·dt below F_c and ``peak_up_n`` reports the true in-step peak.
The dashpot B = K_e·τ is a Kelvin–Voigt term standing for radiation damping
of the contact (τ ≈ ρ V_La A / K_e ≈ 1 ms for a tined rake on loose soil, with
Lysmer's analog wave speed V_La; Gazetas 1991, J. Geotech. Eng. 117(9)). It
makes the mean force of a steady descent F_c/2 + K_e τ v: it grows with v and
K_e, and the paper's estimate K_e v α bounds the peaks when α ≥ F_c/(K_e v) + τ.
Soil takes no tension: the force is clipped at 0 and only pushes the tip up.

How the interface follows horizontal motion (the modelling choice): the tip
carries its interface x_e. Moving into another cell, x_e ← min(surface there,
max(x_e, previous tip height)): compression (x_e − x) can only grow by the
tip's own descent, never by crossing the grid, so a flat stroke at constant
depth — fresh or already cut — produces no vertical force beyond what it
carried in, while a stroke whose path descends builds the same saw-tooth as a
plunge. The compressed bulb under the tine is assumed to move with the tine.

Horizontal: the fundamental earthmoving equation (Reece 1964; McKyes 1985,
"Soil Cutting and Tillage", ch. 4, two-dimensional wedge):
    P = (γ d² N_γ + c d N_c + q d N_q) w,     H = P sin(α + δ),
    N_γ = ½ (cot α + cot β) / D,  N_c = (1 + cot β cot(β+φ)) / D,  N_q = 2 N_γ,
    D = cos(α + δ) + sin(α + δ) cot(β + φ),
with rake angle α, soil friction φ, soil–tool friction δ, cut depth d, width w,
and the failure-plane angle β that minimises N_γ (used for all factors, as in
McKyes' charts). Soil–tool adhesion and the vertical component of the wedge
force are neglected (the vertical interaction is the interface model above).
d is the surface just ahead of the tip (one cell in the direction of motion)
minus the tip height; H opposes the horizontal velocity smoothly,
−H tanh(v/v_s'), which never injects energy (effective damping H/v_s' near 0),
with v_s' = max(v_s, H/c_max): the damping slope never exceeds c_max, so the
arm's explicit contact coupling stays stable at its substep (h·c_max/M_tip ≈ 0.6
at 50 µs and the lightest tip, 1.7 kg). A tine stalled against a cut it cannot
move therefore creeps at about F/c_max (2 mm/s at 40 N) instead of sticking:
a regularization, documented rather than hidden.
Properties are those of the layer at the tip's depth.

Raking removes soil: the lane keeps a surface height map (piecewise constant
per cell), lowered to the tip's interface wherever the tip passes below it.
Cut soil is assumed carried away (no surcharge build-up, q is a constant).

Layers are declared by depth below the *original* surface profile. Per cell
and layer, K_e and the strength (collapse force and cutting force) are scaled
by independent lognormal factors of mean 1, drawn once from the seed. Beyond
the lane the edge cells are used.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from drivers.soil_params import SoilLayer, SoilParams
from rakectl.errors import ConfigError

_STANDARD_GRAVITY_M_PER_S2 = 9.80665


@dataclass(frozen=True)
class CuttingFactors:
    """Dimensionless factors of the earthmoving equation for one soil and tine."""

    n_gamma: float
    n_c: float
    n_q: float
    failure_angle_rad: float  # β, minimising N_γ


def _wedge(rake_rad: float, phi_rad: float, delta_rad: float, beta_rad: float
           ) -> tuple[float, float]:
    """(N_γ, N_c) for failure angle β; inf where the wedge is not admissible."""
    den = math.cos(rake_rad + delta_rad) + math.sin(rake_rad + delta_rad) / math.tan(
        beta_rad + phi_rad)
    if den <= 0.0 or beta_rad + phi_rad >= math.pi:
        return math.inf, math.inf
    n_gamma = 0.5 * (1.0 / math.tan(rake_rad) + 1.0 / math.tan(beta_rad)) / den
    n_c = (1.0 + 1.0 / (math.tan(beta_rad) * math.tan(beta_rad + phi_rad))) / den
    return n_gamma, n_c


@functools.lru_cache(maxsize=64)
def cutting_factors(rake_angle_rad: float, friction_angle_rad: float,
                    tool_friction_angle_rad: float) -> CuttingFactors:
    """McKyes' N_γ, N_c, N_q with β minimising N_γ (grid search, then refinement)."""
    best_beta, best = 0.0, math.inf
    lo, hi = 1e-3, math.pi / 2 - 1e-3
    for _ in range(4):
        step = (hi - lo) / 400
        for i in range(401):
            beta = lo + i * step
            n_gamma = _wedge(rake_angle_rad, friction_angle_rad, tool_friction_angle_rad,
                             beta)[0]
            if n_gamma < best:
                best_beta, best = beta, n_gamma
        lo, hi = max(1e-4, best_beta - step), min(math.pi / 2, best_beta + step)
    if not math.isfinite(best):
        raise ConfigError("rake_angle_rad: no admissible failure wedge for these angles")
    n_gamma, n_c = _wedge(rake_angle_rad, friction_angle_rad, tool_friction_angle_rad,
                          best_beta)
    return CuttingFactors(n_gamma, n_c, 2.0 * n_gamma, best_beta)


def cutting_force_n(layer: SoilLayer, params: SoilParams, depth_m: float) -> float:
    """Horizontal cutting resistance H(d) = P sin(α+δ) of homogeneous soil (closed form)."""
    if depth_m <= 0.0:
        return 0.0
    f = cutting_factors(params.rake_angle_rad, layer.friction_angle_rad,
                        layer.tool_friction_angle_rad)
    p_n = (layer.unit_weight_n_per_m3 * depth_m**2 * f.n_gamma
           + layer.cohesion_pa * depth_m * f.n_c
           + params.surcharge_pa * depth_m * f.n_q) * params.width_m
    return p_n * math.sin(params.rake_angle_rad + layer.tool_friction_angle_rad)


def original_surface_height_m(params: SoilParams, reach_m: float) -> float:
    """Height of the untouched surface at ``reach_m``: slope about the lane centre + waves."""
    centre_m = 0.5 * (params.lane_reach_min_m + params.lane_reach_max_m)
    height_m = params.surface_slope * (reach_m - centre_m)
    for w in params.surface_waves:
        height_m += w.amplitude_m * math.sin(2 * math.pi * reach_m / w.wavelength_m
                                             + w.phase_rad)
    return height_m


def _lognormal_factors(rng: np.random.Generator, rel_std: float, n: int) -> list[float]:
    """n lognormal factors with mean 1 and relative std ``rel_std``."""
    sigma = math.sqrt(math.log1p(rel_std * rel_std))
    return [float(x) for x in rng.lognormal(-0.5 * sigma * sigma, sigma, n)]


@dataclass(frozen=True)
class CellProperties:
    """The soil properties met at one place (for inspection and tests)."""

    layer_index: int
    stiffness_n_per_m: float
    collapse_force_n: float
    strength_factor: float


class VerticalLaw(NamedTuple):
    """What the tines meet below ``ref_m``: F = K (ref − z) − B ż, its elastic part at most
    ``cap_n``. Past the cap the soil ``collapses`` (its interface gives way by whole
    steps of cap/K and the elastic part starts again from the remainder: the saw-tooth
    of :meth:`Soil._push`); a buried object instead holds at its cap (it yields)."""

    ref_m: float
    stiffness_n_per_m: float
    damping_ns_per_m: float
    cap_n: float
    collapses: bool


class Soil:
    """State of the lane: surface map, the interface the tip carries, the last forces.

    :meth:`step` writes its results into attributes (no allocation on the hot path):
    ``force_up_n`` (vertical force on the tip, ≥ 0), ``force_reach_n``,
    ``peak_up_n`` (largest vertical force within the step, collapses included),
    ``interface_height_m`` (x_e under the tip), ``surface_height_m`` (top of the
    soil just ahead of the tip), ``cut_depth_m`` and ``touching`` (any soil force).
    """

    __slots__ = ("_a_cq", "_a_gamma", "_collapse", "_damping_s", "_floor_m", "_from_depth",
                 "_inv_cell", "_inv_max_damping", "_last", "_original", "_prev_height_m",
                 "_prev_tip_m",
                 "_reach_min_m", "_smooth_m_per_s", "_stiffness", "_strength", "_surface", "cell_m",
                 "cut_depth_m", "force_reach_n", "force_up_n", "interface_height_m",
                 "peak_up_n", "surface_height_m", "touching")

    def __init__(self, params: SoilParams, seed: int) -> None:
        n = round((params.lane_reach_max_m - params.lane_reach_min_m) / params.cell_m)
        self.cell_m = (params.lane_reach_max_m - params.lane_reach_min_m) / n
        self._reach_min_m, self._last = params.lane_reach_min_m, n - 1
        self._inv_cell = 1.0 / self.cell_m
        self._original = [original_surface_height_m(params, self.cell_centre_m(i))
                          for i in range(n)]
        self._surface = list(self._original)
        self._from_depth = [layer.from_depth_m for layer in params.layers]
        self._damping_s = [layer.damping_time_s for layer in params.layers]
        self._init_cutting(params)
        self._init_heterogeneity(params, np.random.default_rng(seed), n)
        self._smooth_m_per_s = params.drag_smoothing_speed_m_per_s
        self._inv_max_damping = 1.0 / params.drag_max_damping_ns_per_m
        self._floor_m = self._prev_tip_m = -math.inf
        self._prev_height_m = math.inf  # where the tip was: its layer is this substep's
        self.force_up_n = self.force_reach_n = self.peak_up_n = self.cut_depth_m = 0.0
        self.interface_height_m = self.surface_height_m = 0.0
        self.touching = False

    def _init_cutting(self, params: SoilParams) -> None:
        """Per layer, H(d) = (a_γ d + a_cq) d with the closed-form coefficients."""
        self._a_gamma, self._a_cq = [], []
        for layer in params.layers:
            f = cutting_factors(params.rake_angle_rad, layer.friction_angle_rad,
                                layer.tool_friction_angle_rad)
            scale = params.width_m * math.sin(params.rake_angle_rad
                                              + layer.tool_friction_angle_rad)
            self._a_gamma.append(layer.unit_weight_n_per_m3 * f.n_gamma * scale)
            self._a_cq.append((layer.cohesion_pa * f.n_c + params.surcharge_pa * f.n_q) * scale)

    def _init_heterogeneity(self, params: SoilParams, rng: np.random.Generator, n: int) -> None:
        self._stiffness, self._collapse, self._strength = [], [], []
        for layer in params.layers:
            k = _lognormal_factors(rng, params.stiffness_rel_std, n)
            s = _lognormal_factors(rng, params.strength_rel_std, n)
            self._stiffness.append([layer.stiffness_n_per_m * x for x in k])
            self._collapse.append([layer.collapse_force_n * x for x in s])
            self._strength.append(s)

    def cell_centre_m(self, index: int) -> float:
        return self._reach_min_m + (index + 0.5) * self.cell_m

    def cell_edges_m(self, index: int) -> tuple[float, float]:
        """The reach interval [low, high) that :meth:`cell_index` maps to cell ``index`` (the
        edge cells reach on beyond the lane)."""
        low_m = -math.inf if index == 0 else self._first_reach_m(index)
        high_m = math.inf if index == self._last else self._first_reach_m(index + 1)
        return low_m, high_m

    def _first_reach_m(self, index: int) -> float:
        """The least reach :meth:`cell_index` maps to ``index`` or beyond. min + index·cell
        can round to the cell below (0.33 m is in cell 5 of the default lane, not 6), and
        tines pinned there would meet the soil of a cell their mount never solved against
        (20261127-3448: 114 N read at 1.055 m, the mount carrying 0 N)."""
        reach_m = self._reach_min_m + index * self.cell_m
        while self.cell_index(reach_m) < index:
            reach_m = math.nextafter(reach_m, math.inf)
        while self.cell_index(math.nextafter(reach_m, -math.inf)) >= index:
            reach_m = math.nextafter(reach_m, -math.inf)
        return reach_m

    def cell_index(self, reach_m: float) -> int:
        """The grid cell holding ``reach_m`` (edge cells beyond the lane)."""
        j = int((reach_m - self._reach_min_m) * self._inv_cell)
        return 0 if j < 0 else (self._last if j > self._last else j)

    def surface_heights_m(self) -> list[float]:
        """A copy of the current surface map, one height per cell."""
        return list(self._surface)

    def properties_at(self, reach_m: float, height_m: float) -> CellProperties:
        j = self.cell_index(reach_m)
        i = self._layer(self._original[j] - height_m)
        return CellProperties(i, self._stiffness[i][j], self._collapse[i][j],
                              self._strength[i][j])

    def _layer(self, depth_m: float) -> int:
        i = len(self._from_depth) - 1
        while i > 0 and depth_m < self._from_depth[i]:
            i -= 1
        return i

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, shield_height_m: float = -math.inf) -> None:
        """Advance by one substep; below ``shield_height_m`` an object replaces the soil."""
        j = self.cell_index(reach_m)
        shielded = height_m < shield_height_m
        tip_m = shield_height_m if shielded else height_m
        surface = self._surface
        carried_m = self._floor_m if self._floor_m > self._prev_tip_m else self._prev_tip_m
        floor_m = surface[j] if surface[j] < carried_m else carried_m
        # the layer where the tip was at the previous substep (explicit in the layer, so the
        # arm's implicit tine mount, which cannot know the new height first, sees the same)
        layer = self._layer(self._original[j] - self._prev_height_m)
        self._prev_height_m = height_m
        self.force_up_n = self.peak_up_n = 0.0
        if floor_m > tip_m:
            rate = 0.0 if shielded else -height_vel_m_per_s
            floor_m = self._push(j, layer, floor_m, tip_m, rate)
        self._floor_m, self._prev_tip_m = floor_m, tip_m
        left_m = floor_m if floor_m > tip_m else tip_m  # soil left standing under the tip
        if left_m < surface[j]:
            surface[j] = left_m
        self.interface_height_m = surface[j]
        self._drag(j, layer, height_m, reach_vel_m_per_s)
        self.touching = self.force_up_n > 0.0 or self.cut_depth_m > 0.0

    def vertical_law(self, reach_m: float, height_m: float) -> VerticalLaw | None:
        """The vertical law a tip at (reach_m, height_m) would meet in the next step, or None:
        (interface height, K_e, B, collapse force); F = K_e (ref − z) − B ż below ref, in
        the layer :meth:`step` will use (where the tip was at the previous substep)."""
        j = self.cell_index(reach_m)
        carried_m = self._floor_m if self._floor_m > self._prev_tip_m else self._prev_tip_m
        floor_m = self._surface[j] if self._surface[j] < carried_m else carried_m
        if floor_m <= height_m:
            return None
        layer = self._layer(self._original[j] - self._prev_height_m)
        stiffness = self._stiffness[layer][j]
        return VerticalLaw(floor_m, stiffness, stiffness * self._damping_s[layer],
                           self._collapse[layer][j], True)

    def _push(self, j: int, layer: int, floor_m: float, tip_m: float, rate_m_per_s: float
              ) -> float:
        """Vertical force against the interface; returns the interface after collapses."""
        stiffness = self._stiffness[layer][j]
        limit_n = self._collapse[layer][j]
        viscous_n = stiffness * self._damping_s[layer] * rate_m_per_s
        elastic_n = stiffness * (floor_m - tip_m)
        if elastic_n > limit_n:
            self.peak_up_n = limit_n + (viscous_n if viscous_n > 0.0 else 0.0)
            elastic_n -= math.floor(elastic_n / limit_n) * limit_n
            floor_m = tip_m + elastic_n / stiffness
        force_n = elastic_n + viscous_n
        self.force_up_n = force_n if force_n > 0.0 else 0.0
        if self.force_up_n > self.peak_up_n:
            self.peak_up_n = self.force_up_n
        return floor_m

    def _drag(self, j: int, layer: int, height_m: float, reach_vel_m_per_s: float) -> None:
        """Cutting resistance from the soil just ahead of the tip."""
        resist_n, smooth, surface_m = self._resistance(j, layer, height_m, reach_vel_m_per_s)
        self.surface_height_m = surface_m
        self.cut_depth_m = surface_m - height_m if resist_n > 0.0 else 0.0
        self.force_reach_n = -resist_n * math.tanh(reach_vel_m_per_s / smooth)

    def _resistance(self, j: int, layer: int, height_m: float, reach_vel_m_per_s: float
                    ) -> tuple[float, float, float]:
        """(H, v_s', surface ahead): the drag is −H·tanh(v/v_s') at this cut."""
        ahead = j - 1 if reach_vel_m_per_s < 0.0 else j + 1
        ahead = 0 if ahead < 0 else (self._last if ahead > self._last else ahead)
        surface_m = self._surface[ahead]
        cut_m = surface_m - height_m
        if cut_m <= 0.0:
            return 0.0, self._smooth_m_per_s, surface_m
        resist_n = (self._a_gamma[layer] * cut_m + self._a_cq[layer]) * cut_m
        resist_n *= self._strength[layer][j]
        return resist_n, max(self._smooth_m_per_s, resist_n * self._inv_max_damping), surface_m

    def drag_law(self, reach_m: float, height_m: float, reach_vel_m_per_s: float
                 ) -> tuple[float, float]:
        """(H, v_s') of the drag −H·tanh(v/v_s') a tip here would meet in the next step, in the
        layer :meth:`step` will use (for the tine mount's horizontal solve)."""
        j = self.cell_index(reach_m)
        layer = self._layer(self._original[j] - self._prev_height_m)
        resist_n, smooth, _ = self._resistance(j, layer, height_m, reach_vel_m_per_s)
        return resist_n, smooth
