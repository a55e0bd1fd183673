"""Force-adaptive stroke speed: the contact stroke rides just under a force target (pure).

The lane planner (rakectl.core.lane) asks the governor, once per tick of a
contact stroke, for the speed limit of the reference. The input is the
conservative force estimate: the larger of the paper's delayed-position F̂
and the force supervision's current-based estimate. The set point is a share
of supervision's caution level (0.8 × 55 N = 44 N by default), so in soft
soil the stroke runs at the top speed and in hard soil it slows until the
force sits just under the level at which supervision would hold the motion.

A second margin keeps the stroke clear of the lane planner's stall detector:
the tip's distance from its reference L against half the stall error, L*.
At speed the tip lags (about 20 ms of travel) and in stiff soil the drag
lifts it (the joint that must hold it down is the one the clamp cuts); past
the stall error the planner would take the soil for a rigid object.

The law is an integrator on the smaller relative margin
e = min((F* − F)/F*, (L* − L)/L*), with asymmetric rates:

    e ≥ 0:  v ← v + g · v_max · e · dt                (at most g · v_max per second)
    e < 0:  v ← min(v, v_ref) + r · g · v_max · e · dt

clipped to [v_min, v_max], with r = SLOWDOWN_RATIO when the force is above
its set point and r = 1 when only the lag is (slowing down abruptly makes the
tip lurch, a lag is not a force). A third margin, the tip riding above its
reference depth R against R*, slows the stroke where the voltage clamp's
budget cannot hold the tine down at that speed (the joints' velocity
uncertainty grows with speed and takes budget): a tine riding high and then
dropping reads as force in F̂. It never speeds up while F is above F* or
L above L*, and it slows from the speed the reference actually has (after an
acceleration ramp the limit may be above it). At F = 2 F* with the defaults
(g = 2 /s, v_max = 0.25 m/s) the limit falls at 4 m/s², from full speed to
the minimum in about 55 ms. The planner applies its acceleration limit to
increases; decreases act at once.

Why speed is the handle: in steady state the estimate of a tip moving into
soil at speed v is F̂ = K_e · v · α (the seed paper), so force and speed
trade linearly where the path goes into the soil, and the inertial and
frictional loads the current-based estimate sees grow with speed too. Where
the force does not fall with speed (a drag that does not depend on it), the
governor settles at v_min and supervision's caution level still holds the
motion if the force keeps rising: it errs toward slow.

The plunge is governed the same way (the same force set point, no lag term),
from the lane's ``plunge_speed_m_per_s`` up to ``max_plunge_speed_m_per_s``:
F̂ = K_e · v · α is the plunge's own estimate, so the plunge runs as fast as
that leaves the force under its set point, and never slower than the lane's
fixed plunge.

The depth of cut adapts too, once per cycle (:func:`next_depth_step_m`): a
stroke that stayed well under its set points is followed by a deeper cut. On
the benchmark's lane the strokes are a third of the time and the free-space
return the largest part, so fewer, deeper cuts are what halves the time in soft
soil; stroke speed alone cannot (see bench/BENCHMARKS.md).
"""

from __future__ import annotations

import math

# Above the force set point the limit falls this many times faster than it rises below it.
SLOWDOWN_RATIO = 8.0
# The next cut is at most this many times deeper than the last.
DEPTH_GROWTH_MAX = 2.0


class StrokeGovernor:
    """Speed limit of a contact stroke from the force estimate, one tick at a time."""

    __slots__ = ("dt_s", "gain_per_s", "max_speed_m_per_s", "min_speed_m_per_s", "speed_m_per_s")

    def __init__(self, min_speed_m_per_s: float, max_speed_m_per_s: float, gain_per_s: float,
                 dt_s: float, start_speed_m_per_s: float) -> None:
        if not (0.0 < min_speed_m_per_s <= max_speed_m_per_s and gain_per_s > 0 and dt_s > 0):
            raise ValueError("governor: need 0 < min speed <= max speed, gain > 0, dt > 0")
        self.min_speed_m_per_s = min_speed_m_per_s
        self.max_speed_m_per_s = max_speed_m_per_s
        self.gain_per_s = gain_per_s
        self.dt_s = dt_s
        self.speed_m_per_s = self._clip(start_speed_m_per_s)

    def _clip(self, speed_m_per_s: float) -> float:
        return min(self.max_speed_m_per_s, max(self.min_speed_m_per_s, speed_m_per_s))

    def update(self, force_n: float, target_n: float, lag_m: float, lag_target_m: float,
               reference_speed_m_per_s: float, rise_m: float = 0.0,
               rise_target_m: float = math.inf) -> float:
        """The new speed limit from this tick's force estimate ``force_n`` against its set
        point ``target_n``, the tip's lag ``lag_m`` against ``lag_target_m`` and how far it
        rides above its reference depth, ``rise_m`` against ``rise_target_m``;
        ``reference_speed_m_per_s`` is the reference's speed now. A non-finite input or a
        non-positive set point counts as far above it."""
        force_margin = _margin(force_n, target_n)
        margin = min(force_margin, _margin(lag_m, lag_target_m))
        if math.isfinite(rise_target_m):
            margin = min(margin, _margin(rise_m, rise_target_m))
        step = self.gain_per_s * self.max_speed_m_per_s * self.dt_s
        if margin >= 0.0:
            speed = self.speed_m_per_s + step * margin
        else:
            ratio = SLOWDOWN_RATIO if force_margin < 0.0 else 1.0
            speed = min(self.speed_m_per_s, reference_speed_m_per_s) + ratio * step * margin
        self.speed_m_per_s = self._clip(speed)
        return self.speed_m_per_s


def _margin(value: float, target: float) -> float:
    """(target − value)/target; −1 (well above) for a non-finite value or target ≤ 0."""
    if math.isfinite(value) and target > 0.0:
        return (target - value) / target
    return -1.0


def next_depth_step_m(step_m: float, peak_force_n: float, target_n: float, peak_lag_m: float,
                      lag_target_m: float, min_step_m: float, max_step_m: float) -> float:
    """Depth step of the next cut from how the last stroke went (the adaptive lane).

    The cut's loads grow with its depth (the drag on the rake's face, and with it the
    current-based estimate and the tip's lag), so the step scales with the smaller
    ratio of set point to the stroke's peak, target/peak, for the force and the lag:
    at most ×DEPTH_GROWTH_MAX per cycle, within [min_step_m, max_step_m]. A stroke
    above either set point makes the next cut shallower, down to ``min_step_m`` (the
    lane's own depth step). A non-finite peak gives ``min_step_m``.
    """
    ratios = [DEPTH_GROWTH_MAX]
    for peak, target in ((peak_force_n, target_n), (peak_lag_m, lag_target_m)):
        if not math.isfinite(peak):
            return min_step_m
        if peak > 0.0:
            ratios.append(target / peak)
    return min(max_step_m, max(min_step_m, step_m * min(ratios)))
