"""Position-based impedance control on the vertical axis (pure).

Following the seed paper (Fig. 5, eq. 12): the impedance filter

    M_d ẍ_c + B_d ẋ_c + K_d x_c = F_d − F̂,    x_ref = x_d + x_c

turns the force error into a position correction x_c, and the position loop
makes the measured x follow x_ref. F̂ comes from the delayed-position
estimator F̂ = K_e (x(t) − x(t − α)): the undeformed soil is assumed to lie
where the tip was α seconds ago (α = 0: free space, F̂ = 0, pure position
control). x is the depth into the soil, positive down.

Every block fixes its period at construction and exposes ``step``; the
per-tick work is plain float arithmetic on precomputed coefficients.
"""

from __future__ import annotations

import math

import numpy as np

from rakectl.core.discretize import zoh
from rakectl.errors import ConfigError


class ImpedanceFilter:
    """M ẍ_c + B ẋ_c + K x_c = u, discretized exactly with u held over each tick."""

    __slots__ = ("_a11", "_a12", "_a21", "_a22", "_b1", "_b2", "dt_s", "velocity_m_per_s",
                 "x_c_m")

    def __init__(self, mass_kg: float, damping_ns_per_m: float, stiffness_n_per_m: float,
                 dt_s: float) -> None:
        if not (mass_kg > 0 and damping_ns_per_m > 0 and stiffness_n_per_m > 0 and dt_s > 0):
            raise ConfigError("impedance: mass, damping, stiffness and dt must all be > 0")
        a = np.array([[0.0, 1.0], [-stiffness_n_per_m / mass_kg, -damping_ns_per_m / mass_kg]])
        b = np.array([[0.0], [1.0 / mass_kg]])
        ad, bd = zoh(a, b, dt_s)
        self._a11, self._a12 = float(ad[0, 0]), float(ad[0, 1])
        self._a21, self._a22 = float(ad[1, 0]), float(ad[1, 1])
        self._b1, self._b2 = float(bd[0, 0]), float(bd[1, 0])
        self.dt_s = dt_s
        self.x_c_m = 0.0
        self.velocity_m_per_s = 0.0

    def reset(self) -> None:
        self.x_c_m = 0.0
        self.velocity_m_per_s = 0.0

    def step(self, force_error_n: float) -> float:
        """Advance one period with ``force_error_n`` = F_d − F̂ held; return the new x_c."""
        x, v = self.x_c_m, self.velocity_m_per_s
        self.x_c_m = self._a11 * x + self._a12 * v + self._b1 * force_error_n
        self.velocity_m_per_s = self._a21 * x + self._a22 * v + self._b2 * force_error_n
        return self.x_c_m


class DelayForceEstimator:
    """F̂ = K_e (x(t) − x(t − α)) from a ring of measured positions, floored at 0.

    The ring always records, so α can be switched from 0 (free space) to a
    contact value at any tick without waiting for history. Two deviations
    from the paper, which only considers an increasing x: soil takes no
    tension, so F̂ is never negative (a negative F̂ would make the impedance
    filter push the tip deeper while it rises); and on entering contact the
    history is re-anchored at the current position (:meth:`enter_contact`),
    because the soil is undeformed where the tip meets it: the free-space
    motion before that is not soil deformation (at 0.15 m/s it would read as
    300 N with α = 10 ms).

    The ring holds one position per sampling instant (SYNC), not per tick at
    which feedback happened to be read: :meth:`step` takes how many instants
    the measurement advanced. A late answer (0: the same sample again) holds
    F̂; a burst (n > 1: only the newest of n samples kept) records the n − 1
    skipped ones on the straight line to it. Counting ticks instead, a drive
    answering 3 ms late then twice in one tick makes x(t) − x(t − α) span up
    to α + 3 ms of motion: +30 % of F̂ at α = 10 ms, and in free-space descent
    (K_e v α: 40 N at 2 cm/s) that is the step to a false force limit.
    """

    __slots__ = ("_delay_ticks", "_index", "_ring", "_size", "dt_s", "f_hat_n",
                 "stiffness_n_per_m", "x_e_m")

    def __init__(self, stiffness_n_per_m: float, delay_s: float, max_delay_s: float,
                 dt_s: float) -> None:
        if not (stiffness_n_per_m > 0 and dt_s > 0 and max_delay_s >= delay_s >= 0):
            raise ConfigError("estimator: need stiffness > 0, dt > 0, 0 <= delay <= max_delay")
        self.dt_s = dt_s
        self.stiffness_n_per_m = stiffness_n_per_m
        self._size = round(max_delay_s / dt_s) + 1
        self._ring = [0.0] * self._size
        self._index = 0
        self._delay_ticks = 0
        self.x_e_m = 0.0
        self.f_hat_n = 0.0
        self.set_delay(delay_s)

    @property
    def delay_s(self) -> float:
        return self._delay_ticks * self.dt_s

    def set_delay(self, delay_s: float) -> None:
        """Change α (rounded to whole ticks); α = 0 means free space."""
        ticks = round(delay_s / self.dt_s) if math.isfinite(delay_s) else -1
        if not 0 <= ticks < self._size:
            raise ConfigError(
                f"estimator: delay {delay_s} s outside [0, {(self._size - 1) * self.dt_s}] s"
            )
        self._delay_ticks = ticks

    def enter_contact(self, delay_s: float, x_m: float) -> None:
        """Switch to α = ``delay_s`` with the undeformed soil at ``x_m`` (the tip, now)."""
        self.set_delay(delay_s)
        self.reset(x_m)

    def reset(self, x_m: float) -> None:
        """Fill the history with ``x_m``: the soil is undeformed at the start."""
        self._ring = [x_m] * self._size
        self._index = 0
        self.x_e_m = x_m
        self.f_hat_n = 0.0

    def step(self, x_m: float, samples: int = 1) -> float:
        """Record the measured position ``x_m``, ``samples`` sampling instants after the
        last one recorded, and return F̂ in N (held when ``samples`` is 0)."""
        if samples <= 0:
            return self.f_hat_n
        ring = self._ring
        if samples == 1:  # the common case: one SYNC answered per tick
            i = self._index + 1
            if i == self._size:
                i = 0
            ring[i] = x_m
        else:
            i = record_samples(ring, self._index, x_m, samples)
        self._index = i
        x_e = ring[i - self._delay_ticks]  # a negative index wraps around the ring
        self.x_e_m = x_e
        f_hat = self.stiffness_n_per_m * (x_m - x_e) if x_m > x_e else 0.0
        self.f_hat_n = f_hat
        return f_hat


def record_samples(ring: list[float], index: int, x: float, samples: int) -> int:
    """Write ``samples`` values into ``ring`` after position ``index``: the sampling
    instants skipped on the straight line from ``ring[index]`` to ``x``, then ``x`` (only
    ``x`` when ``ring[index]`` is NaN: nothing recorded yet). Returns ``x``'s position.
    Shared by the force estimate's history and the lane's settle window."""
    size, last = len(ring), ring[index]
    gap = min(samples, size) if last == last else 1  # last != last: NaN
    for k in range(1, gap + 1):
        index = index + 1 if index + 1 < size else 0
        ring[index] = last + (x - last) * k / gap if k < gap else x
    return index


class ImpedanceController:
    """Estimator + impedance filter: measured x and desired x_d in, x_ref out."""

    __slots__ = ("desired_force_n", "estimator", "f_hat_n", "filter")

    def __init__(self, impedance: ImpedanceFilter, estimator: DelayForceEstimator,
                 desired_force_n: float = 0.0) -> None:
        if impedance.dt_s != estimator.dt_s:
            raise ConfigError("impedance filter and estimator must share one period")
        self.filter = impedance
        self.estimator = estimator
        self.desired_force_n = desired_force_n
        self.f_hat_n = 0.0

    def reset(self, x_m: float) -> None:
        self.filter.reset()
        self.estimator.reset(x_m)
        self.f_hat_n = 0.0

    def step(self, x_d_m: float, x_m: float, samples: int = 1) -> float:
        """One tick: estimate F̂ from ``x_m`` (``samples`` sampling instants after the last,
        see :class:`DelayForceEstimator`), return x_ref = x_d + x_c, advance the filter.

        x_c is the filter's state at this tick (it depends on F̂ up to the
        previous tick: the filter has no direct feedthrough), so there is no
        algebraic loop; this tick's F̂ is held over the next period.
        """
        f_hat = self.estimator.step(x_m, samples)
        self.f_hat_n = f_hat
        x_ref = x_d_m + self.filter.x_c_m
        self.filter.step(self.desired_force_n - f_hat)
        return x_ref
