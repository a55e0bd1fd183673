"""Properties of the r-θ kinematics."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from rakectl.core import kinematics as kin
from rakectl.errors import KinematicsError

WS = kin.Workspace(pivot_height_m=0.6, r_min_m=0.35, r_max_m=1.6,
                   theta_min_rad=-0.2, theta_max_rad=1.3)
r_st = st.floats(WS.r_min_m, WS.r_max_m)
theta_st = st.floats(WS.theta_min_rad, WS.theta_max_rad)
force_st = st.floats(-500, 500)


@given(r_st, theta_st)
def test_inverse_undoes_forward_inside_the_workspace(r: float, theta: float) -> None:
    reach, height = kin.forward(WS, r, theta)
    r2, theta2 = kin.inverse(WS, reach, height)
    assert r2 == pytest.approx(r, abs=1e-12)
    assert theta2 == pytest.approx(theta, abs=1e-12)


@given(r_st, theta_st)
def test_jacobian_matches_finite_differences(r: float, theta: float) -> None:
    h = 1e-6
    j11, j12, j21, j22 = kin.jacobian(r, theta)
    (xp, zp), (xm, zm) = kin.forward(WS, r + h, theta), kin.forward(WS, r - h, theta)
    assert (xp - xm) / (2 * h) == pytest.approx(j11, abs=1e-7)
    assert (zp - zm) / (2 * h) == pytest.approx(j21, abs=1e-7)
    (xp, zp), (xm, zm) = kin.forward(WS, r, theta + h), kin.forward(WS, r, theta - h)
    assert (xp - xm) / (2 * h) == pytest.approx(j12, abs=1e-7)
    assert (zp - zm) / (2 * h) == pytest.approx(j22, abs=1e-7)


@given(r_st, theta_st, force_st, force_st)
def test_joint_loads_and_tip_force_are_inverse(r: float, theta: float, fx: float,
                                               fz: float) -> None:
    f_r, tau = kin.joint_loads(r, theta, fx, fz)
    fx2, fz2 = kin.tip_force(r, theta, f_r, tau)
    assert fx2 == pytest.approx(fx, abs=1e-9)
    assert fz2 == pytest.approx(fz, abs=1e-9)


@given(r_st, theta_st, force_st, force_st, st.floats(-1, 1), st.floats(-1, 1))
def test_virtual_work_is_preserved(r: float, theta: float, fx: float, fz: float,
                                   r_dot: float, theta_dot: float) -> None:
    """Jᵀ maps forces so that power at the tip equals power at the joints."""
    vx, vz = kin.tip_velocity(r, theta, r_dot, theta_dot)
    f_r, tau = kin.joint_loads(r, theta, fx, fz)
    assert fx * vx + fz * vz == pytest.approx(f_r * r_dot + tau * theta_dot, abs=1e-9)


def test_straight_down_force_loads_the_pivot_with_r_times_cos() -> None:
    """At θ = 0 a downward tip force acts on the pivot with lever arm r."""
    f_r, tau = kin.joint_loads(1.0, 0.0, 0.0, -90.0)
    assert f_r == pytest.approx(0.0)
    assert tau == pytest.approx(90.0)


@pytest.mark.parametrize(
    ("reach", "height", "match"),
    [
        (0.0, 0.6, "behind the pivot"),
        (-0.5, 0.0, "behind the pivot"),
        (3.0, 0.0, "outside"),
        (0.2, 0.55, "outside"),
        (math.nan, 0.0, "finite"),
        (1.0, math.inf, "finite"),
    ],
)
def test_unreachable_points_raise_a_clear_error(reach: float, height: float, match: str) -> None:
    with pytest.raises(KinematicsError, match=match):
        kin.inverse(WS, reach, height)


@given(st.floats(-1e-4, 1e-4), theta_st, force_st, force_st)
def test_singular_pose_raises_never_nan(r: float, theta: float, f_r: float, tau: float) -> None:
    assume(abs(r) < kin.MIN_REACH_M)
    with pytest.raises(KinematicsError, match="singular"):
        kin.tip_force(r, theta, f_r, tau)


def test_workspace_rejects_bad_limits() -> None:
    with pytest.raises(KinematicsError):
        kin.Workspace(0.6, 1.0, 0.5, 0.0, 1.0)
    with pytest.raises(KinematicsError):
        kin.Workspace(0.6, 0.3, 1.5, 1.0, 0.5)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_every_mapping_names_its_non_finite_argument(bad: float) -> None:
    calls = {
        "r_m": lambda x: kin.forward(WS, x, 0.3),
        "theta_rad": lambda x: kin.jacobian(1.0, x),
        "force_reach_n": lambda x: kin.joint_loads(1.0, 0.3, x, 5.0),
        "force_height_n": lambda x: kin.joint_loads(1.0, 0.3, 5.0, x),
        "torque_theta_nm": lambda x: kin.tip_force(1.0, 0.3, 5.0, x),
        "height_m": lambda x: kin.inverse(WS, 1.0, x),
    }
    for name, call in calls.items():
        with pytest.raises(KinematicsError, match=f"{name} must be finite"):
            call(bad)
    with pytest.raises(KinematicsError, match="theta_rad must be finite"):
        kin.tip_velocity(1.0, bad, 0.1, 0.1)
