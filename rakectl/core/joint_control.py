"""Joint position loops: joint reference in, motor voltage out (pure).

These are the physical counterpart of the seed paper's position loop P(s):
a PID per joint with the derivative on the measured velocity (the D term
gives no kick on a reference step; the velocity feed-forward, which the
caller computes from the reference's change in one tick, does: a step of the
reference is a one-tick feed-forward of its size over the period, which the
voltage clamp bounds like any other request), a velocity feed-forward for
the back-EMF, saturation at
the supply voltage and anti-windup by conditional integration (the integral
only grows while the output is not saturated in the same direction).
The integral term carries the gravity load; the voltage clamp of the safety
case comes after this stage, never before.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PidGains:
    """Gains of one joint loop; units per joint (m or rad)."""

    kp_v_per_unit: float
    ki_v_per_unit_s: float
    kd_v_s_per_unit: float
    kff_v_s_per_unit: float
    voltage_limit_v: float


class JointPositionLoop:
    """PID position loop of one joint at a fixed period."""

    __slots__ = ("_gains", "dt_s", "integral_v", "voltage_v")

    def __init__(self, gains: PidGains, dt_s: float) -> None:
        if not dt_s > 0 or not gains.voltage_limit_v > 0:
            raise ValueError("joint loop: dt_s and voltage_limit_v must be > 0")
        self._gains = gains
        self.dt_s = dt_s
        self.integral_v = 0.0
        self.voltage_v = 0.0

    def reset(self, integral_v: float = 0.0) -> None:
        """Start again; ``integral_v`` pre-loads the integrator (e.g. the holding voltage)."""
        self.integral_v = integral_v
        self.voltage_v = 0.0

    def step(self, position_ref: float, velocity_ref: float, position: float,
             velocity: float) -> float:
        """Voltage for this tick from the reference and the measured state."""
        g = self._gains
        error = position_ref - position
        unsaturated = (g.kp_v_per_unit * error + self.integral_v
                       - g.kd_v_s_per_unit * velocity + g.kff_v_s_per_unit * velocity_ref)
        limit = g.voltage_limit_v
        voltage = min(limit, max(-limit, unsaturated))
        # conditional integration: never wind further into a saturated output
        increment = g.ki_v_per_unit_s * error * self.dt_s
        if voltage == unsaturated or (increment > 0) != (unsaturated > 0):
            self.integral_v = min(limit, max(-limit, self.integral_v + increment))
        self.voltage_v = voltage
        return voltage
