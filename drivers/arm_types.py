"""The arm plant's interface (pure): :class:`ContactModel`, the ground as the tip feels
it, which :meth:`drivers.arm.ArmPlant.step` is handed; :class:`ArmState`, the arm's true
state, which the plant is put in and reports; and :class:`Measurement`, the drives'
report of that state at the end of a step. The plant itself, its substep and the
integration it rests on are in :mod:`drivers.arm`, which re-exports these.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


class ContactModel(Protocol):
    """The ground as the tip feels it (implemented by the soil model).

    A model that also has ``vertical_laws(reach_m, height_m, face_height_m, step_s,
    reach_vel_m_per_s)`` and
    ``transmitted(force_down_n)`` (Ground) lets the arm solve its compliant tine mount
    implicitly; one without them (the tests' idealized contacts) meets a rigid mount.
    """

    def step(
        self,
        reach_m: float,
        height_m: float,
        reach_vel_m_per_s: float,
        height_vel_m_per_s: float,
        dt_s: float,
    ) -> tuple[float, float]:
        """Force ON the tip by the ground (f_reach_n, f_height_n); advance the ground by dt_s."""
        ...


@dataclass(frozen=True)
class ArmState:
    """True state of the arm and its motor currents."""

    r_m: float
    theta_rad: float
    r_vel_m_per_s: float = 0.0
    theta_vel_rad_per_s: float = 0.0
    current_r_a: float = 0.0
    current_theta_a: float = 0.0


@dataclass(frozen=True)
class Measurement:
    """What the drives report at the end of a step.

    Positions are encoder counts converted back to joint units (incremental
    encoders zeroed at joint position 0, so the error is in (−1, 0] count);
    velocities are the difference of the last two such samples over the step;
    currents carry seeded Gaussian noise.
    """

    r_m: float
    theta_rad: float
    r_vel_m_per_s: float
    theta_vel_rad_per_s: float
    current_r_a: float
    current_theta_a: float
