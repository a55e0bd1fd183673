"""The tine mount's vertical solve: its compression against the ground's laws.

The tines are massless on a spring-damper (k, c); each substep the compression d
is solved by backward Euler against the piecewise-linear laws the tines are
below (:class:`drivers.soil.VerticalLaw`: the soil's interface with its
saw-tooth collapse, objects' tops with their yield), with an active set. Used by
:class:`drivers.mount.TineMount`, which couples it with the sideways solve.
"""

from __future__ import annotations

import math

from drivers.soil import VerticalLaw

# Rounds of the active-set iteration (contacts, yields, soil collapses).
_MOUNT_ITERATIONS = 16


def compression(k: float, c: float, h: float, d0: float, laws: list[VerticalLaw],
                height_m: float, height_vel_m_per_s: float) -> float:
    """The compression of a mount (k, c; d0 at the start of a substep of h) at the end
    of the substep, the arm's tip at ``height_m`` moving up at ``height_vel_m_per_s``
    (backward Euler).

    The tines are massless: the mount's force k·δ + c·δ̇ equals the ground's, the
    sum over the laws the tines are below of K (ref − z − δ) − B (ż + δ̇), each as the
    ground itself computes it: an object's elastic part held at its cap where it
    yields, the soil's interface lowered by whole steps of cap/K where it collapses
    (:class:`drivers.soil.VerticalLaw`). The laws in contact, yielding, and the
    collapsed interfaces are found by iteration (piecewise linear, active set); each
    only changes one way within a substep, so a stiff top cannot make it chatter.
    Solved implicitly, so a stiff ground (a stone, 10⁷ N/m) is stable at the
    substep and meets the tines without a force spike.
    """
    relaxed = c * d0 / (c + h * k)  # no ground force: the mount relaxes
    d = relaxed
    refs = [law.ref_m for law in laws]
    active = [height_m + d0 < ref_m for ref_m in refs]
    yielding = [False] * len(laws)
    above = [False] * len(laws)  # the tines stay above it this substep
    slack = [False] * len(laws)  # the tines leave it faster than it pushes: it reads 0
    for _ in range(_MOUNT_ITERATIONS):
        stiff = damp = force = 0.0
        for law, ref_m, on, cap in zip(laws, refs, active, yielding, strict=True):
            if on:
                damp += law.damping_ns_per_m
                if cap:
                    force += law.cap_n
                else:
                    stiff += law.stiffness_n_per_m
                    force += law.stiffness_n_per_m * (ref_m - height_m)
        if any(active):
            force += (damp + c) * d0 / h - damp * height_vel_m_per_s
            d = force / (stiff + k + (damp + c) / h)
            if k * d + c * (d - d0) / h <= 0.0:  # the ground would pull: it lets go
                d = relaxed
        changed = False
        rate_m_per_s = height_vel_m_per_s + (d - d0) / h  # the tines' speed up
        for i, law in enumerate(laws):
            if not active[i]:
                if height_m + d < refs[i] and not above[i] and (
                        not slack[i] or min(law.stiffness_n_per_m * (refs[i] - height_m - d),
                                            law.cap_n) > law.damping_ns_per_m * rate_m_per_s):
                    # the solution reaches it (one let go as pulling joins again once
                    # it would push there: the others moved the tines back into it,
                    # 20261127/8181: a soil that gave way under tines leaving a mine's
                    # plate put them 14 µm into it at 233 mm/s, 302 N on the plate
                    # with the mount carrying 22 N)
                    active[i], slack[i], changed = True, False, True
                continue
            elastic_n = law.stiffness_n_per_m * (refs[i] - height_m - d)
            if elastic_n < 0.0 and not changed:
                # in contact, yet the solution is above it: the contact force jumps at
                # the surface (damping). Either the tines rest on it this substep, or
                # the other laws already hold the mount above it there.
                rest = _rest_on(refs[i], height_m, relaxed)
                if _others_n(laws, refs, active, yielding, i, height_m,
                             height_vel_m_per_s, rest, d0, h) < (
                        k * rest + c * (rest - d0) / h):
                    return rest
                active[i], above[i], changed = False, True, True
                break
            held_n = law.cap_n if yielding[i] else elastic_n
            if not changed and held_n < law.damping_ns_per_m * rate_m_per_s:
                # it would pull: a contact only pushes (Soil.step and Body.touch clip its
                # force at 0), so it carries nothing this substep and the others hold the
                # tines (else its damping pulled the mount down while the ground read the
                # others' force unrelieved: a tine lifted up a rounded edge out of the soil
                # read 90-170 N with the mount carrying 17-47 N, seed 7's lanes 429, 606,
                # 732, 735)
                active[i], slack[i], changed = False, True, True
                break
        if not changed:
            # every law in contact pushes: what gives way (the soil collapsing, an object
            # yielding) is decided on this solution only, never on one where another law
            # pulled the tines down (a collapse is kept for the substep: decided so, a
            # soil gave way under tines an edge's law drew 0.36 µm past its collapse, the
            # tines were rested on the collapsed interface and the soil read its damping
            # at their 0.08 m/s, 62.6 N with the mount carrying 12.7 N, 20261128 edge 7013)
            for i, law in enumerate(laws):
                if not active[i] or yielding[i]:
                    continue
                elastic_n = law.stiffness_n_per_m * (refs[i] - height_m - d)
                if elastic_n > law.cap_n:
                    changed = True
                    if law.collapses:  # the soil gives way as Soil._push does
                        steps = math.floor(elastic_n / law.cap_n)
                        refs[i] -= steps * law.cap_n / law.stiffness_n_per_m
                    else:
                        yielding[i] = True
        if not changed:
            break
    for i, ref_m in enumerate(refs):
        if above[i] and height_m + d < ref_m:  # left out, yet reached: rest on it
            return _rest_on(ref_m, height_m, relaxed)
    return d


def _rest_on(ref_m: float, height_m: float, relaxed_m: float) -> float:
    """The compression that puts the tines on ``ref_m``, not below it by a rounding (the
    ground would read its damping at the speed they fell in this substep), and never
    extending faster than the mount relaxes (its force stays ≥ 0)."""
    d = max(ref_m - height_m, relaxed_m)
    while height_m + d < ref_m:
        d = math.nextafter(d, math.inf)
    return d


def _others_n(laws: list[VerticalLaw], refs: list[float], active: list[bool],
              yielding: list[bool], skip: int, height_m: float, height_vel_m_per_s: float,
              d_m: float, d0: float, h: float) -> float:
    """The force of the active laws but ``skip`` on tines at compression ``d_m``."""
    tine_m = height_m + d_m
    rate_m_per_s = height_vel_m_per_s + (d_m - d0) / h
    total_n = 0.0
    for j, law in enumerate(laws):
        if j == skip or not active[j] or tine_m >= refs[j]:
            continue
        elastic_n = (law.cap_n if yielding[j]
                     else law.stiffness_n_per_m * (refs[j] - tine_m))
        total_n += max(0.0, elastic_n - law.damping_ns_per_m * rate_m_per_s)
    return total_n

