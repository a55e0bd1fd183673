"""The tine mount's sideways solve: its offset e along the reach at a given compression.

The tines are massless on a spring-damper (k_h, c_h) along the reach; each substep
their offset e is solved by backward Euler against the soil's drag −H·tanh(v/v_s)
(:class:`Drag`) and every object's side or edge law the tines are in, linearized
where they were (:class:`Coupled`). Used by :class:`drivers.mount.TineMount`, which
couples it with the vertical solve (:func:`drivers.mount_vertical.compression`) and
takes the laws again where the tines end up (:func:`read_as_assumed`,
:func:`relinearized`).
"""

from __future__ import annotations

import math

from drivers.objects import NormalLaw

# A linearized penetration this close to the ground's own reading is taken as settled
# (0.1 µm: 1 N on a stone).
SETTLED_M = 1e-7
_NEWTON_STEPS = 60


class Coupled:
    """An object's side or edge law linearized where the tines were: its force along the
    normal is α − β·(n_reach·e + n_up·d), clipped to [0, cap]."""

    __slots__ = ("_reference_m", "alpha", "beta", "cap_n", "damping_ns_per_m", "index",
                 "n_reach", "n_up", "stiffness_n_per_m")

    def __init__(self, index: int, law: NormalLaw, at: tuple[float, float],
                 start: tuple[float, float], reach_vel: float, height_vel: float, h: float
                 ) -> None:
        """``law`` as read with the tines at offset ``at`` = (e, d); ``start``: the mount's
        state at the start of the substep (the rate is taken from there)."""
        n_x, n_z = law.n_reach, law.n_up
        (e_at, d_at), (e0, d0) = at, start
        k, b = law.stiffness_n_per_m, law.damping_ns_per_m
        # the arm's approach along n, the mount's own motion being in the (e, d) terms: the
        # tines' whole approach, as the ground reads it (Body.touch). Not only a reach speed
        # INTO the face, as an edge's vertical law takes it (Body.vertical_law: tines put on
        # a reference): the tines are solved here, and an arm leaving the face along the
        # reach damps their push by B times its speed (20261130/8268: 25 N)
        approach = -(n_x * reach_vel + n_z * height_vel)
        self.index, self.n_reach, self.n_up, self.cap_n = index, n_x, n_z, law.cap_n
        self.stiffness_n_per_m, self.damping_ns_per_m = k, b
        self.beta = k + b / h
        self.alpha = (k * (law.depth_m + n_x * e_at + n_z * d_at) + b * approach
                      + b * (n_x * e0 + n_z * d0) / h)
        self._reference_m = law.depth_m + n_x * e_at + n_z * d_at

    def penetration_m(self, e: float, d: float) -> float:
        """The penetration this linearization gives with the tines at (e, d)."""
        return self._reference_m - self.n_reach * e - self.n_up * d


def read_as_assumed(coupled: list[Coupled], inside: dict[int, NormalLaw], e: float,
                    d: float) -> bool:
    """Whether the laws the ground reads with the tines at (e, d) (``inside``) are the
    coupled ones, each within :data:`SETTLED_M` of its linearization's penetration."""
    return len(inside) == len(coupled) and all(
        c.index in inside and abs(c.penetration_m(e, d) - inside[c.index].depth_m) < SETTLED_M
        for c in coupled)


def relinearized(coupled: list[Coupled], inside: dict[int, NormalLaw], at: tuple[float, float],
                 start: tuple[float, float], reach_vel: float, height_vel: float, h: float
                 ) -> list[Coupled]:
    """The laws ``inside`` linearized again at ``at`` (objects the tines reach join); the
    coupled ones the tines have left keep their last linearization."""
    kept = [c for c in coupled if c.index not in inside]
    return kept + [Coupled(i, law, at, start, reach_vel, height_vel, h)
                   for i, law in inside.items()]


class Drag:
    """The soil's drag on the tines, −H·tanh(v/v_s), and what a linear solve takes of it."""

    __slots__ = ("resist_n", "smooth_m_per_s")

    def __init__(self, resist_n: float, smooth_m_per_s: float) -> None:
        self.resist_n, self.smooth_m_per_s = resist_n, smooth_m_per_s

    def at(self, v: float) -> tuple[float, float]:
        """The drag at speed v and its slope there (≤ 0)."""
        if self.resist_n <= 0.0:
            return 0.0, 0.0
        t = math.tanh(v / self.smooth_m_per_s)
        return -self.resist_n * t, -self.resist_n * (1.0 - t * t) / self.smooth_m_per_s

    def balance(self, k_h: float, c_h: float, e0: float, reach_vel: float, v_lin: float,
                h: float) -> tuple[float, float]:
        """(a, b) of the sideways balance a·e = b (+ Σ n_reach·f of the objects), the drag
        linearized at the tines' speed ``v_lin``."""
        force, slope = self.at(v_lin)
        a = k_h + (c_h - slope) / h
        b = (c_h - slope) * e0 / h + force + slope * (reach_vel - v_lin)
        return a, b


def offset(k_h: float, c_h: float, h: float, e0: float, coupled: list[Coupled], drag: Drag,
           reach_vel: float, d: float, guess: float) -> float:
    """e from the sideways balance at compression d, exactly: the mount (k_h, c_h; e0 at
    the start of a substep of h), the drag (tanh) and the coupled laws (each pressing,
    capped or slack). The residual rises strictly with e and is continuous, so Newton's
    steps are kept inside a bracket that always holds the root, and the bracket is
    halved instead where Newton does not converge: a step that leaves it, or one not
    under half the step before the last (safeguarded Newton, as ``rtsafe``). Where the
    drag turns over within a micron (its tanh: v_s·h = 0.5 µm at 0.01 m/s and 50 µs)
    just as an edge's contact ends, Newton alone jumps to and fro across the root
    forever and stopped 22 N out of balance (20261128/6387, a stone read 35.6 N up
    with the mount carrying 17.0 N)."""
    stiff = k_h + c_h / h
    lo, hi = -math.inf, math.inf
    e = guess
    step_m = step_before_m = math.inf  # the last step and the one before it
    for _ in range(_NEWTON_STEPS):
        v = reach_vel + (e - e0) / h
        force, slope = drag.at(v)
        r = stiff * e - c_h * e0 / h - force
        dr = stiff - slope / h
        for c in coupled:
            f = c.alpha - c.beta * (c.n_reach * e + c.n_up * d)
            if f <= 0.0:
                continue
            if f >= c.cap_n:
                r -= c.n_reach * c.cap_n
            else:
                r -= c.n_reach * f
                dr += c.beta * c.n_reach * c.n_reach
        if r == 0.0:
            return e
        if r > 0.0:
            hi = e
        else:
            lo = e
        step = e - r / dr
        if not lo < step < hi:  # Newton left the bracket: halve it (widen it if open)
            if math.isinf(lo) or math.isinf(hi):
                width = max(abs(r / dr), 1e-9)
                step = e - 2.0 * width if r > 0.0 else e + 2.0 * width
            else:
                step = 0.5 * (lo + hi)
        elif abs(step - e) > 0.5 * abs(step_before_m) and math.isfinite(lo) and math.isfinite(hi):
            step = 0.5 * (lo + hi)  # Newton not converging: halve the bracket
        step_before_m, step_m = step_m, step - e
        if abs(step - e) < 1e-13:
            return step
        e = step
    return e
