"""The tip controller's own faults (rakectl.core.control.TipController.step): any
non-finite number is one, the reference included.

A NaN or infinite tip reference (reach, or the depth the impedance filter makes of it)
was caught by the joint servo's inverse kinematics as an unreachable point and held
there, no fault; a NaN in the impedance filter's state went the same way.
"""

from __future__ import annotations

import math

import pytest

from rakectl.config.settings import Settings
from rakectl.core import kinematics
from rakectl.core.control import TipController, workspace_of

REACH_M, DEPTH_M = 1.0, -0.2  # a pose in the air


def _controller() -> tuple[TipController, float, float]:
    settings = Settings()
    r_m, theta_rad = kinematics.inverse(workspace_of(settings), REACH_M, -DEPTH_M)
    controller = TipController(settings)
    controller.reset(r_m, theta_rad)
    return controller, r_m, theta_rad


def test_a_finite_reference_is_no_fault() -> None:
    controller, r_m, theta_rad = _controller()
    controller.step(REACH_M, DEPTH_M, r_m, theta_rad, 0.0, 0.0, mount_force_n=0.0)
    assert controller.fault == ""


@pytest.mark.parametrize(("reach_m", "depth_m"), [
    (math.nan, DEPTH_M), (math.inf, DEPTH_M), (REACH_M, math.nan), (REACH_M, -math.inf)])
def test_a_non_finite_reference_is_a_fault_at_0_v(reach_m: float, depth_m: float) -> None:
    controller, r_m, theta_rad = _controller()
    voltages = controller.step(reach_m, depth_m, r_m, theta_rad, 0.0, 0.0, mount_force_n=0.0)
    assert controller.fault == "non-finite tip reference"
    assert voltages == (0.0, 0.0)


def test_a_non_finite_impedance_state_is_a_fault_at_0_v() -> None:
    controller, r_m, theta_rad = _controller()
    controller.impedance.filter.x_c_m = math.nan
    voltages = controller.step(REACH_M, DEPTH_M, r_m, theta_rad, 0.0, 0.0, mount_force_n=0.0)
    assert controller.fault == "non-finite tip reference"
    assert voltages == (0.0, 0.0)
