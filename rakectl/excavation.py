"""Raking a lane as in the seed paper's Fig. 3 (pure).

Each cycle: approach the far end of the lane in free space, descend into the
soil, drag the tip toward the robot at the cycle's depth (the contact
stroke), lift clear and return. The depth grows by a step each cycle until
the target depth. The planner gives the reference tip position every tick
and says whether the tip is meant to be in contact (impedance control with
α > 0) or in free space (α = 0, pure position control).

Depth is positive below ground level 0 (the same axis as the impedance
controller's x).
"""

from __future__ import annotations

import enum
import math

from rakectl.settings import LaneSettings

# Free-space descent stops this far above the previous cycle's floor; the rest
# of the way down is at plunge speed.
PLUNGE_MARGIN_M = 0.005


class LanePhase(enum.Enum):
    APPROACH = enum.auto()  # free space: to above the far end of the lane
    LOWER = enum.auto()  # free space: down to just above the last floor
    PLUNGE = enum.auto()  # contact: down into the soil to this cycle's depth
    STROKE = enum.auto()  # contact: toward the robot at this cycle's depth
    LIFT = enum.auto()  # free space: up to the clearance height
    DONE = enum.auto()  # holding above the lane


CONTACT_PHASES = frozenset({LanePhase.PLUNGE, LanePhase.STROKE})


class LanePlanner:
    """Reference tip position for raking a lane, advanced one tick at a time."""

    def __init__(self, lane: LaneSettings, dt_s: float, reach_m: float, depth_m: float) -> None:
        self.lane = lane
        self.dt_s = dt_s
        self.reach_m = reach_m
        self.depth_m = depth_m
        self.phase = LanePhase.APPROACH
        self.cycle = 1
        self.floor_m = 0.0  # deepest completed stroke so far (ground level at first)
        self.found_at: tuple[float, float] | None = None  # (reach, depth) of a rigid object
        self.stopped_by_force = False
        self.speed_m_per_s = 0.0  # along the path; trapezoidal, zero at every corner

    @property
    def contact(self) -> bool:
        return self.phase in CONTACT_PHASES

    @property
    def done(self) -> bool:
        return self.phase is LanePhase.DONE

    @property
    def cycle_depth_m(self) -> float:
        return min(self.cycle * self.lane.depth_step_m, self.lane.target_depth_m)

    def observe(self, reach_m: float, depth_m: float) -> None:
        """The measured tip, once per tick (see :meth:`check_stall`)."""
        self.check_stall(reach_m, depth_m)

    def check_stall(self, reach_m: float, depth_m: float) -> bool:
        """During a contact stroke, a tip lagging its reference by more than the stall error
        has met something rigid: remember where, lift clear from where the tip IS (so the
        reference stops pushing), and finish after the lift. Returns True on the find."""
        if self.phase is not LanePhase.STROKE or self.found_at is not None:
            return False
        if math.hypot(self.reach_m - reach_m, self.depth_m - depth_m) <= self.lane.stall_error_m:
            return False
        self.found_at = (reach_m, depth_m)
        self.reach_m, self.depth_m = reach_m, depth_m
        self.speed_m_per_s = 0.0
        self.phase = LanePhase.LIFT
        return True

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
        if self.phase is LanePhase.APPROACH:
            return lane.reach_far_m, above, lane.travel_speed_m_per_s
        if self.phase is LanePhase.LOWER:
            return lane.reach_far_m, self.floor_m - PLUNGE_MARGIN_M, lane.travel_speed_m_per_s
        if self.phase is LanePhase.PLUNGE:
            return lane.reach_far_m, self.cycle_depth_m, lane.plunge_speed_m_per_s
        if self.phase is LanePhase.STROKE:
            return lane.reach_near_m, self.cycle_depth_m, lane.stroke_speed_m_per_s
        return self.reach_m, above, lane.travel_speed_m_per_s  # LIFT, DONE

    def _next_phase(self) -> LanePhase:
        if self.phase is LanePhase.LIFT:
            if (self.found_at is not None or self.stopped_by_force
                    or self.floor_m >= self.lane.target_depth_m - 1e-12):
                return LanePhase.DONE
            self.cycle += 1
            return LanePhase.APPROACH
        if self.phase is LanePhase.STROKE:
            self.floor_m = self.cycle_depth_m
        order = (LanePhase.APPROACH, LanePhase.LOWER, LanePhase.PLUNGE, LanePhase.STROKE,
                 LanePhase.LIFT)
        return order[order.index(self.phase) + 1]

    def step(self) -> None:
        """Advance the reference by one tick."""
        if self.phase is LanePhase.DONE:
            return
        reach, depth, top_speed = self._target()
        d_reach, d_depth = reach - self.reach_m, depth - self.depth_m
        distance = math.hypot(d_reach, d_depth)
        accel = self.lane.accel_m_per_s2
        self.speed_m_per_s = min(top_speed, self.speed_m_per_s + accel * self.dt_s,
                                 math.sqrt(2.0 * accel * distance))
        travel = max(self.speed_m_per_s, accel * self.dt_s) * self.dt_s
        if distance <= travel:
            self.reach_m, self.depth_m = reach, depth
            self.speed_m_per_s = 0.0
            self.phase = self._next_phase()
            return
        self.reach_m += d_reach * travel / distance
        self.depth_m += d_depth * travel / distance
