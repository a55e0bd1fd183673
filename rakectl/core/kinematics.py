"""Kinematics of the r-θ rake in its vertical plane (pure: numbers in, numbers out).

The platform pivots about a horizontal axis at height ``pivot_height_m`` above
the ground. The rake of length ``r_m`` points at ``theta_rad`` *below* the
horizontal. Tip coordinates: ``reach_m`` is the horizontal distance from the
pivot, ``height_m`` the height above the ground (negative below the surface)::

    reach_m  = r cos θ
    height_m = h − r sin θ

Joint forces are (F_r along the rake in N, τ_θ about the pivot in N·m) with
τ = Jᵀ F and F = J⁻ᵀ τ, where J = ∂(reach, height)/∂(r, θ) and det J = −r.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rakectl.errors import KinematicsError

# Below this rake length the Jacobian is treated as singular.
MIN_REACH_M = 1e-3
# Round-off allowed at the joint limits (m or rad), so forward∘inverse is exact there.
LIMIT_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Workspace:
    """Geometry and joint limits of the rake."""

    pivot_height_m: float
    r_min_m: float
    r_max_m: float
    theta_min_rad: float
    theta_max_rad: float

    def __post_init__(self) -> None:
        if not self.r_min_m >= MIN_REACH_M:
            raise KinematicsError(f"r_min_m must be >= {MIN_REACH_M}, got {self.r_min_m}")
        if not self.r_max_m > self.r_min_m:
            raise KinematicsError("r_max_m must be > r_min_m")
        if not -math.pi / 2 < self.theta_min_rad < self.theta_max_rad < math.pi / 2:
            raise KinematicsError("need -pi/2 < theta_min_rad < theta_max_rad < pi/2")

    def contains(self, r_m: float, theta_rad: float) -> bool:
        tol = LIMIT_TOLERANCE
        return (
            self.r_min_m - tol <= r_m <= self.r_max_m + tol
            and self.theta_min_rad - tol <= theta_rad <= self.theta_max_rad + tol
        )


def _check_finite(**values: float) -> None:
    """Raise naming the first non-finite value. Called only once a value is known not to
    be finite: the checks below test with math.isfinite first, since building the
    keywords costs more than the kinematics (20 000 calls a simulated second)."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise KinematicsError(f"{name} must be finite, got {value}")


def forward(ws: Workspace, r_m: float, theta_rad: float) -> tuple[float, float]:
    """Tip (reach_m, height_m) of joint position (r_m, theta_rad)."""
    if not (math.isfinite(r_m) and math.isfinite(theta_rad)):
        _check_finite(r_m=r_m, theta_rad=theta_rad)
    return r_m * math.cos(theta_rad), ws.pivot_height_m - r_m * math.sin(theta_rad)


def inverse(ws: Workspace, reach_m: float, height_m: float) -> tuple[float, float]:
    """Joint position (r_m, theta_rad) that puts the tip at (reach_m, height_m).

    Raises KinematicsError if the point is outside the joint limits.
    """
    if not (math.isfinite(reach_m) and math.isfinite(height_m)):
        _check_finite(reach_m=reach_m, height_m=height_m)
    drop_m = ws.pivot_height_m - height_m
    r_m = math.hypot(reach_m, drop_m)
    if r_m < MIN_REACH_M or reach_m <= 0.0:
        raise KinematicsError(
            f"tip ({reach_m:.4f} m, {height_m:.4f} m) is at or behind the pivot: unreachable"
        )
    theta_rad = math.atan2(drop_m, reach_m)
    if not ws.contains(r_m, theta_rad):
        raise KinematicsError(
            f"tip ({reach_m:.4f} m, {height_m:.4f} m) needs r={r_m:.4f} m, "
            f"theta={theta_rad:.4f} rad: outside r [{ws.r_min_m}, {ws.r_max_m}] m, "
            f"theta [{ws.theta_min_rad}, {ws.theta_max_rad}] rad"
        )
    return r_m, theta_rad


def jacobian(r_m: float, theta_rad: float) -> tuple[float, float, float, float]:
    """J = ∂(reach, height)/∂(r, θ) as (j11, j12, j21, j22), row-major."""
    if not (math.isfinite(r_m) and math.isfinite(theta_rad)):
        _check_finite(r_m=r_m, theta_rad=theta_rad)
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    return c, -r_m * s, -s, -r_m * c


def tip_velocity(
    r_m: float, theta_rad: float, r_dot_m_per_s: float, theta_dot_rad_per_s: float
) -> tuple[float, float]:
    """Tip (reach, height) velocity from joint velocities: ẋ = J q̇."""
    j11, j12, j21, j22 = jacobian(r_m, theta_rad)
    return (
        j11 * r_dot_m_per_s + j12 * theta_dot_rad_per_s,
        j21 * r_dot_m_per_s + j22 * theta_dot_rad_per_s,
    )


def joint_loads(
    r_m: float, theta_rad: float, force_reach_n: float, force_height_n: float
) -> tuple[float, float]:
    """Joint loads (F_r in N, τ_θ in N·m) balancing a tip force: τ = Jᵀ F."""
    if not (math.isfinite(force_reach_n) and math.isfinite(force_height_n)):
        _check_finite(force_reach_n=force_reach_n, force_height_n=force_height_n)
    j11, j12, j21, j22 = jacobian(r_m, theta_rad)
    return (
        j11 * force_reach_n + j21 * force_height_n,
        j12 * force_reach_n + j22 * force_height_n,
    )


def tip_force(
    r_m: float, theta_rad: float, force_r_n: float, torque_theta_nm: float
) -> tuple[float, float]:
    """Tip force (reach, height) in N from joint loads: F = J⁻ᵀ τ.

    Raises KinematicsError at the singular pose r → 0.
    """
    if not (math.isfinite(force_r_n) and math.isfinite(torque_theta_nm)):
        _check_finite(force_r_n=force_r_n, torque_theta_nm=torque_theta_nm)
    if abs(r_m) < MIN_REACH_M:
        raise KinematicsError(f"singular pose: r={r_m} m is below {MIN_REACH_M} m")
    j11, j12, j21, j22 = jacobian(r_m, theta_rad)
    det = j11 * j22 - j12 * j21  # = -r
    # Jᵀ = [[j11, j21], [j12, j22]]; (Jᵀ)⁻¹ = [[j22, -j21], [-j12, j11]] / det
    return (
        (j22 * force_r_n - j21 * torque_theta_nm) / det,
        (-j12 * force_r_n + j11 * torque_theta_nm) / det,
    )
