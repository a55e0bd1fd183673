"""Raking a lane as in the seed paper's Fig. 3 (pure).

Each cycle: approach the far end of the lane in free space, descend into the
soil, drag the tip toward the robot at the cycle's depth (the contact
stroke), lift clear and return. The depth grows by a step each cycle until
the target depth. The planner gives the reference tip position every tick
and says whether the tip is meant to be in contact (impedance control with
α > 0) or in free space (α = 0, pure position control).

With ``lane.adaptive`` the stroke's speed is not fixed: :meth:`LanePlanner.govern`
feeds the force estimate to a :class:`~rakectl.core.governor.StrokeGovernor` every
tick, whose limit replaces ``stroke_speed_m_per_s`` (soft soil fast, hard soil
slow, under the caution level); the plunge's speed follows the same set point
between ``plunge_speed_m_per_s`` and ``max_plunge_speed_m_per_s``. Nor is the
depth of cut: each cycle's step is the last one's scaled by the last stroke's margin
(:func:`~rakectl.core.governor.next_depth_step_m`), from ``depth_step_m`` up to
``max_depth_step_m``: soft soil in few deep cuts, hard soil in many shallow ones.
That law runs per bin of reach (:mod:`rakectl.core.cut_profile`): each bin's next cut
follows the force and lag met there and the floor the tip really left there, so where
the arm holds the tine down well (far from the robot) the lane goes down in deep cuts
while near the robot it goes in shallow ones; once the far part is at the target depth
the strokes start where the lane is not yet done (partial strokes).

Depth is positive below ground level 0 (the same axis as the impedance
controller's x).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable

from rakectl.config.settings import LaneSettings
from rakectl.core.cut_profile import FLOOR_TOLERANCE_M, CutProfile
from rakectl.core.governor import StrokeGovernor
from rakectl.core.impedance import record_samples

# Free-space descent stops this far above the previous cycle's floor; the rest
# of the way down is at plunge speed.
PLUNGE_MARGIN_M = 0.005
# The floor the next descent lands on is where the tip really was at the start of the
# last stroke, within this reach of the lane's far end: a tip that rode up there (clay
# drags it up as it starts) left soil above the stroke's depth, which a descent at travel
# speed would hit in free space (33 N true at 0.1 m/s in clay).
LANDING_BAND_M = 0.02
# A plunge starts once the measured tip has arrived above the soil: the delayed-position
# estimate is re-anchored where contact begins, so a tip still moving down there reads as
# force (K_e·α = 2000 N per m/s with the paper's values). LOWER ends when the tip moved less
# than SETTLE_TRAVEL_M over the last SETTLE_TICKS sampling instants (F̂ ≲ 10 N at the
# entry; about 3 encoder quanta of depth at 1.4 m reach) within SETTLE_ERROR_M of its
# reference, or after SETTLE_TIMEOUT_S all the same. Still alone is not enough: a tip
# that overshot the landing stands still for those ticks at its turning point, then
# swings back (3 mm overshoot, 0.5 s period on the emulated bench: 111 N of F̂ at 50
# mm/s); within 0.5 mm of the reference such a swing reads ≲ 12 N.
SETTLE_TICKS = 10
SETTLE_TRAVEL_M = 5e-5
SETTLE_ERROR_M = 5e-4
SETTLE_TIMEOUT_S = 1.0
# An adaptive stroke also keeps the tip's lag under this share of the stall error, so that
# raking fast through stiff soil is not taken for a rigid object.
LAG_TARGET_SHARE = 0.5
# Every stroke's reference waits for a tip that lags it by more than this share of the
# stall error: where the voltage clamp caps the push (deep cuts near the robot, a drag
# that the side budget cannot pay at speed), the stroke slows to what the tip can do
# instead of running away from it. A tip that advances less than STALL_PROGRESS_M in
# STALL_WAIT_S of waiting has met something rigid.
WAIT_SHARE = 0.5
STALL_WAIT_S = 0.5
STALL_PROGRESS_M = 0.002
# Outside contact, a reference that waits this long for a tip that does not advance by
# STALL_PROGRESS_M ends the lane: the arm cannot follow.
BLOCKED_S = 2.0
# The first ticks of a stroke still read the plunge: the tip settles onto the cut's depth
# and F̂ reads its descent (K_e·α·v, 40 N after a 20 mm/s plunge, gone in about 60 ms).
# The depth of the next cut is judged on the stroke's force after this.
PLUNGE_TAIL_S = 0.1
# With a descent limit, each bin's cap is the limit's least over this many points across it
# (its ends included: 5 mm apart in a 20 mm bin, the ground map's cell).
CAP_SAMPLES = 5
class LanePhase(enum.Enum):
    APPROACH = enum.auto()  # free space: to above where the next stroke starts
    LOWER = enum.auto()  # free space: down to just above the floor there
    PLUNGE = enum.auto()  # contact: down into the soil to this cycle's depth
    STROKE = enum.auto()  # contact: toward the robot along this cycle's depths
    LIFT = enum.auto()  # free space: up to the clearance height
    DONE = enum.auto()  # holding above the lane


CONTACT_PHASES = frozenset({LanePhase.PLUNGE, LanePhase.STROKE})




class LanePlanner:
    """Reference tip position for raking a lane, advanced one tick at a time."""

    def __init__(self, lane: LaneSettings, dt_s: float, reach_m: float, depth_m: float,
                 depth_limit: Callable[[float], float] | None = None) -> None:
        """``depth_limit``: the deepest the descent limiter allows at a reach (the
        controller's ground map, :meth:`rakectl.core.ground_map.DescentLimiter.limit_at_m`),
        or None without it: the lane plans within it instead of stalling against it."""
        self.lane = lane
        self._depth_limit = depth_limit
        self.dt_s = dt_s
        self.reach_m = reach_m
        self.depth_m = depth_m
        self.phase = LanePhase.APPROACH
        self.cycle = 1
        self.profile = CutProfile(lane)
        self._apply_caps()
        self.floor_m = 0.0  # shallowest depth the strokes have been along the whole lane
        self.found_at: tuple[float, float] | None = None  # (reach, depth) of a rigid object
        self.stopped_by_force = False
        self.speed_m_per_s = 0.0  # along the path; trapezoidal, zero at every corner
        self.lag_m = 0.0  # how far the tip is from its reference on a stroke (check_stall)
        self.rise_m = 0.0  # how far above its reference depth the tip rides (check_stall)
        self._tip_depths = [math.nan] * SETTLE_TICKS  # measured, the last ticks (a ring)
        self._tip_index = 0
        self._tip_reach_m = reach_m  # measured, the last tick
        self._tip_depth_m = depth_m
        self._observed = False  # whether observe() has been called (simulations that do not)
        self._waiting_ticks = 0  # ticks the stroke's reference has waited for the tip
        self._waiting_from_m = 0.0  # where the tip was when this wait's window began
        self._blocked_ticks = 0  # outside strokes: ticks the reference has waited (_blocked)
        self._blocked_from = (reach_m, depth_m)
        self._settling_ticks = 0
        self._stroke_ticks = 0
        self._caution_n = math.inf  # supervision's caution level, from govern()
        self.governor: StrokeGovernor | None = None
        self.plunge_governor: StrokeGovernor | None = None
        if lane.adaptive:
            self.governor = StrokeGovernor(lane.min_stroke_speed_m_per_s,
                                           lane.max_stroke_speed_m_per_s,
                                           lane.governor_gain_per_s, dt_s,
                                           lane.stroke_speed_m_per_s)
            self.plunge_governor = StrokeGovernor(lane.plunge_speed_m_per_s,
                                                  lane.max_plunge_speed_m_per_s,
                                                  lane.governor_gain_per_s, dt_s,
                                                  lane.plunge_speed_m_per_s)

    def plan_within(self, depth_limit: Callable[[float], float]) -> None:
        """Plan within the descent limiter from now on (see ``__init__``)."""
        self._depth_limit = depth_limit
        self._apply_caps()

    def _limit_m(self, reach_m: float) -> float:
        return math.inf if self._depth_limit is None else self._depth_limit(reach_m)

    def _apply_caps(self) -> None:
        """Each bin's deepest allowed depth (the limit at CAP_SAMPLES points across it)."""
        if self._depth_limit is None:
            return
        p, limit = self.profile, self._depth_limit
        step = p.width_m / (CAP_SAMPLES - 1)
        p.apply_caps([min(limit(p.near_m + b * p.width_m + k * step)
                          for k in range(CAP_SAMPLES)) for b in range(p.n_bins)])

    @property
    def contact(self) -> bool:
        return self.phase in CONTACT_PHASES

    @property
    def done(self) -> bool:
        return self.phase is LanePhase.DONE

    @property
    def held_by_descent(self) -> bool:
        """Whether the descent limiter kept part of the lane short of the target depth."""
        return self.profile.held

    def observe(self, reach_m: float, depth_m: float, samples: int = 1) -> bool:
        """The measured tip, once per tick (see :meth:`check_stall` and :meth:`_blocked`);
        True at the tick a rigid object is found."""
        if self.check_stall(reach_m, depth_m, samples):
            return True
        unknown = self.found_at is None
        self._blocked(reach_m, depth_m)
        return unknown and self.found_at is not None

    def _blocked(self, reach_m: float, depth_m: float) -> None:
        """Outside a stroke, a reference that has waited for a tip that does not come (see
        :meth:`_far_behind`): in a plunge the tine can go no deeper (something rigid, or soil
        harder than the push the clamp allows: found there); in free space the arm cannot
        follow (the lane stops, as at supervision's hard level)."""
        if self.phase in (LanePhase.STROKE, LanePhase.DONE) or not self._far_behind():
            self._blocked_ticks = 0
            return
        if self._blocked_ticks == 0:
            self._blocked_from = (reach_m, depth_m)
        self._blocked_ticks += 1
        plunge = self.phase is LanePhase.PLUNGE
        if self._blocked_ticks * self.dt_s < (STALL_WAIT_S if plunge else BLOCKED_S):
            return
        moved_m = math.hypot(reach_m - self._blocked_from[0], depth_m - self._blocked_from[1])
        self._blocked_ticks = 0
        if moved_m >= STALL_PROGRESS_M:
            return  # it comes, slowly: a new window
        self.reach_m, self.depth_m, self.speed_m_per_s = reach_m, depth_m, 0.0
        if plunge:
            self.found_at = (reach_m, depth_m)
        else:
            self.stopped_by_force = True
        self.phase = LanePhase.LIFT if self.phase is not LanePhase.LIFT else LanePhase.DONE

    def check_stall(self, reach_m: float, depth_m: float, samples: int = 1) -> bool:
        """During a contact stroke, a tip lagging its reference by more than the stall error,
        or one the reference has waited for without it advancing, has met something rigid:
        remember where, lift clear from where the tip IS (so the reference stops pushing),
        and finish after the lift. Returns True on the find. The measured depth of every
        sampling instant is also kept to see the tip settle before a plunge: ``samples``
        is how many the measurement advanced (rakectl.drive.health.Feedback.samples; 0, a
        late answer, adds none: a drive answering late is not a tip standing still)."""
        if samples > 0:
            self._tip_index = record_samples(self._tip_depths, self._tip_index, depth_m,
                                             samples)
        self._tip_reach_m, self._tip_depth_m, self._observed = reach_m, depth_m, True
        if self.phase is not LanePhase.STROKE or self.found_at is not None:
            self.lag_m = self.rise_m = 0.0
            self._waiting_ticks = 0
            return False
        self.lag_m = math.hypot(self.reach_m - reach_m, self.depth_m - depth_m)
        self.rise_m = max(0.0, self.depth_m - depth_m)
        self.profile.record(reach_m, depth_m, self.lag_m)
        if self.lag_m <= self.lane.stall_error_m and not self._stalled(reach_m):
            return False
        self.found_at = (reach_m, depth_m)
        self.reach_m, self.depth_m = reach_m, depth_m
        self.speed_m_per_s = 0.0
        self.phase = LanePhase.LIFT
        return True

    def _stalled(self, reach_m: float) -> bool:
        """Whether the reference has waited STALL_WAIT_S for a tip that did not advance."""
        if self.lag_m <= WAIT_SHARE * self.lane.stall_error_m:
            self._waiting_ticks = 0
            return False
        if self._waiting_ticks == 0:
            self._waiting_from_m = reach_m
        self._waiting_ticks += 1
        if self._waiting_ticks * self.dt_s < STALL_WAIT_S:
            return False
        if self._waiting_from_m - reach_m < STALL_PROGRESS_M:
            return True
        self._waiting_ticks = 0  # it advances, slowly: a new window
        return False

    def _far_behind(self) -> bool:
        """Outside a stroke, whether the measured tip lags the reference by more than
        WAIT_SHARE of the stall error: where the clamp caps the push (a lift that also
        pushes sideways, a fast return), the reference waits rather than run away, and the
        joint loops are never asked for what the clamp will not give."""
        if not self._observed or self.phase is LanePhase.STROKE:
            return False
        lag_m = math.hypot(self.reach_m - self._tip_reach_m, self.depth_m - self._tip_depth_m)
        return lag_m > WAIT_SHARE * self.lane.stall_error_m

    def govern(self, force_n: float, caution_n: float) -> None:
        """The conservative force estimate of this tick (the larger of F̂ and the
        current-based one) and supervision's caution level: during a contact stroke of an
        adaptive lane, the stroke's speed limit follows it and the tip's lag (from the last
        :meth:`check_stall`; rakectl.core.governor). During a plunge, the plunge's limit follows
        the same force set point (no lag: the stall detector does not watch plunges). The
        stroke's limit carries over from one stroke to the next; each plunge starts at
        ``plunge_speed_m_per_s``. Outside them, or on a fixed-speed lane, this does nothing."""
        if self.plunge_governor is not None and self.phase is LanePhase.PLUNGE:
            self.plunge_governor.update(force_n, self.lane.force_target_share * caution_n,
                                        0.0, self.lane.stall_error_m, self.speed_m_per_s)
        if self.governor is not None and self.phase is LanePhase.STROKE:
            lane = self.lane
            self.governor.update(force_n, lane.force_target_share * caution_n, self.lag_m,
                                 LAG_TARGET_SHARE * lane.stall_error_m, self.speed_m_per_s,
                                 self.rise_m, FLOOR_TOLERANCE_M)
            self._stroke_ticks += 1
            if self._stroke_ticks * self.dt_s > PLUNGE_TAIL_S or not math.isfinite(force_n):
                self.profile.record_force(self._tip_reach_m, force_n)
            self._caution_n = caution_n

    @property
    def cycle_depth_m(self) -> float:
        """Where this cycle's stroke starts (during LIFT: the next one's)."""
        return self.profile.start_depth_m

    @property
    def plunge_speed_m_per_s(self) -> float:
        """The plunge's speed limit now: the governor's, or the lane's fixed one."""
        if self.plunge_governor is not None:
            return self.plunge_governor.speed_m_per_s
        return self.lane.plunge_speed_m_per_s

    @property
    def stroke_speed_m_per_s(self) -> float:
        """The stroke's speed limit now: the governor's, or the lane's fixed one."""
        if self.governor is not None:
            return self.governor.speed_m_per_s
        return self.lane.stroke_speed_m_per_s

    def force_stop(self, reach_m: float, depth_m: float) -> None:
        """The force supervision's hard level: lift clear from where the tip is, then end."""
        if self.phase in (LanePhase.LIFT, LanePhase.DONE):
            return
        self.stopped_by_force = True
        self.reach_m, self.depth_m = reach_m, depth_m
        self.speed_m_per_s = 0.0
        self.phase = LanePhase.LIFT

    def _target(self) -> tuple[float, float, float]:
        """(reach, depth, speed) the current phase moves toward."""
        lane, above = self.lane, -self.lane.clearance_m
        profile = self.profile
        if self.phase is LanePhase.APPROACH:
            return profile.start_reach_m, above, lane.travel_speed_m_per_s
        if self.phase is LanePhase.LOWER:
            reach_m = profile.start_reach_m
            landing_m = min(profile.landing_m(LANDING_BAND_M) - PLUNGE_MARGIN_M,
                            self._limit_m(reach_m))
            return reach_m, landing_m, lane.travel_speed_m_per_s
        if self.phase is LanePhase.PLUNGE:
            reach_m = profile.start_reach_m
            return (reach_m, min(profile.start_depth_m, self._limit_m(reach_m)),
                    self.plunge_speed_m_per_s)
        if self.phase is LanePhase.STROKE:
            return (lane.reach_near_m, min(profile.plan_m[0], self._limit_m(lane.reach_near_m)),
                    self.stroke_speed_m_per_s)
        return self.reach_m, above, lane.travel_speed_m_per_s  # LIFT, DONE

    def _tip_settled(self) -> bool:
        """Whether the measured tip has stopped at its reference (True when the tip is not
        observed)."""
        depths = self._tip_depths
        unknown = sum(math.isnan(d) for d in depths)
        if unknown:
            return unknown == SETTLE_TICKS  # never observed: nothing to wait for
        return (max(depths) - min(depths) <= SETTLE_TRAVEL_M
                and abs(depths[self._tip_index] - self.depth_m) <= SETTLE_ERROR_M)

    def _next_phase(self) -> LanePhase:
        if self.phase is LanePhase.LIFT:
            if self.found_at is not None or self.stopped_by_force or self.profile.complete:
                return LanePhase.DONE
            self.cycle += 1
            return LanePhase.APPROACH
        if self.phase is LanePhase.STROKE:
            self._finish_stroke()
        if self.phase is LanePhase.LOWER and self.plunge_governor is not None:
            # each plunge starts at the lane's own speed: the tip meets the soil there
            self.plunge_governor.speed_m_per_s = self.lane.plunge_speed_m_per_s
        order = (LanePhase.APPROACH, LanePhase.LOWER, LanePhase.PLUNGE, LanePhase.STROKE,
                 LanePhase.LIFT)
        return order[order.index(self.phase) + 1]

    def _finish_stroke(self) -> None:
        """At a stroke's end: the next cycle's depths (:class:`CutProfile`; an adaptive lane
        that was not governed, told no caution level, cuts like a fixed one)."""
        lane = self.lane
        self.profile.finish(lane.force_target_share * self._caution_n,
                            LAG_TARGET_SHARE * lane.stall_error_m)
        self._apply_caps()
        self.floor_m = self.profile.depth_reached_m
        self._stroke_ticks = 0
        self._caution_n = math.inf

    def step(self) -> None:
        """Advance the reference by one tick."""
        if self.phase is LanePhase.DONE:
            return
        reach, depth, top_speed = self._target()
        d_reach, d_depth = reach - self.reach_m, depth - self.depth_m
        stroke = self.phase is LanePhase.STROKE  # along the profile: distance in reach
        distance = -d_reach if stroke else math.hypot(d_reach, d_depth)
        accel = self.lane.accel_m_per_s2
        # a lower limit (the governor slowing) is met at the lane's acceleration too: the
        # arm, whose braking the clamp bounds like any push, can follow the reference
        slowed = max(top_speed, self.speed_m_per_s - accel * self.dt_s)
        self.speed_m_per_s = min(slowed, self.speed_m_per_s + accel * self.dt_s,
                                 math.sqrt(2.0 * accel * distance))
        travel = max(self.speed_m_per_s, accel * self.dt_s) * self.dt_s
        if distance <= travel:
            self.reach_m, self.depth_m = reach, depth
            self.speed_m_per_s = 0.0
            if (self.phase is LanePhase.LOWER and not self._tip_settled()
                    and self._settling_ticks * self.dt_s < SETTLE_TIMEOUT_S):
                self._settling_ticks += 1  # hold above the soil until the tip has arrived
                return
            self._settling_ticks = 0
            self.phase = self._next_phase()
            return
        if (stroke and self._waiting_ticks) or self._far_behind():  # wait for the tip
            self.speed_m_per_s = 0.0
            return
        if stroke:  # the path's speed, not the reach's, is the limit
            _, slope = self.profile.depth_and_slope_at(self.reach_m)
            self.reach_m -= travel / math.hypot(1.0, slope)
            depth_m, _ = self.profile.depth_and_slope_at(self.reach_m)
            self.depth_m = min(depth_m, self._limit_m(self.reach_m))
            return
        self.reach_m += d_reach * travel / distance
        self.depth_m += d_depth * travel / distance
