"""The tine-mount check before the first arming (pure): is the mount as soft as the clamp
assumes, down and sideways?

The clamp's dynamic budget rests on ``clamp.contact_stiffness_n_per_m`` and
``side_contact_stiffness_n_per_m``: no contact is stiffer than the tines' compliant mount,
vertically or horizontally. A mount whose springs were swapped for stiffer ones, or
blocked, makes every impact harder than the bound allows (rigid tines with the clamp set
for the mount: 279 N on a stone; a tine rigid sideways meets a stone's side at 0.1 m/s
with several hundred newtons). Nothing on the robot measures the mount, so with
``selftest.press`` on, after the weight check, the daemon presses the tines on the anvil:
a rigid block on the robot's frame whose flat top is at ``selftest.anvil_reach_m``,
``selftest.anvil_height_m``, and whose near side, a flat vertical face toward the robot,
is ``selftest.anvil_width_m`` / 2 nearer (a hardware requirement, like the mount; its top
and its side known within 5 mm). The tip goes up to the travel height (the start's, or
``CLEARANCE_M`` above the anvil's top if that is higher), across, and down to
``CLEARANCE_M`` above the anvil, at ``selftest.travel_speed_m_per_s``; then down at
``selftest.press_speed_m_per_s`` until the vertical force read through the motor
currents is ``selftest.press_force_n`` above its reading in the press's first
``BASELINE_S`` (in free air), holds ``HOLD_S`` and goes back up. Then it goes over to
``CLEARANCE_M`` short of the near side, down beside it to ``selftest.anvil_side_height_m``,
and presses the side the same way, moving away from the robot with its height held, until
the force along the reach is ``press_force_n`` above its free-air reading; it holds, backs
off, rises, and goes back to where it started. Each move waits for the measured tip to
arrive (``ARRIVED_M``, at most ``ARRIVE_TIMEOUT_S`` after its reference did).

On a rigid anvil the arm's travel past the first touch is the mount's compression, so
the slope of the force against the arm's travel (its encoders, before the mount: its
depth, and sideways its reach) is the mount's stiffness that way; what stays constant
during a press drops out of a slope: the weight, friction at a steady speed, where
exactly the anvil's face is. The force is the joints' loads from their currents (the
motor model's band, on the side the press moves each joint to, as the weight check reads
them), the configured weight taken off, through J⁻ᵀ
(:func:`rakectl.core.supervision.tip_force_from_loads_n`), low-passed (``FILTER_S``: a
joint creeping a few encoder counts per tick sticks and slips), and the travel through
the same low-pass, so that each force is paired with its travel. The slope is fitted by
least squares over the press's ticks whose force lies within ``FIT_WINDOW`` of
``press_force_n`` (:mod:`rakectl.core.mount_press` fits and judges each press). Above
the configured stiffness by more than
``selftest.mount_stiffer_tolerance`` (0.2: the clamp takes that stiffness as the
stiffest contact), or below it by more than ``mount_softer_tolerance`` (0.5), either
press fails the check, naming both values and the setting. A mount too stiff for the
encoders to see it give is at least ΔF/(``MIN_SPREAD_COUNTS`` counts of the travel)
stiff, and fails the same way. Only a press that reached its force is weighed: one whose
reference ran ``STALL_LAG_M`` ahead of the arm was held by the clamp (its stalled ticks
would read any mount as soft) and fails naming it; one whose reference went
``press_depth_m`` past the face's configured place without the force fails as nothing
met, or (the force rose less than ``MIN_FORCE_SPAN`` of the press) as too little to
weigh.

On the emulated arm (tests/core/test_mount_check.py) the default 5000 N/m mount reads
4984 N/m down and 4474 N/m sideways at the test's anvil (1 m of reach, its top 30 mm up,
its side pressed 15 mm up), 4465 and 5478 N/m at the robot's (0.45 m, 0.1 m, 0.05 m:
config/rakectl.yaml). Down, 4000 reads 3985 and passes; 2000 reads about 2000 and fails;
6500 (1.3 times) fails; ten times stiffer (springs swapped) and 10⁶ N/m (blocked), whose
presses last a few filter times, read lower than they are but far above the tolerance.
Sideways: rigid reads 63 824 and 50 878 N/m, ten times stiffer 28 502 and 32 330, 2000
reads 1803 and 2214: each fails; 4000 reads 3595 and 4393 and passes; 6500 reads 5743 at
the test's anvil and passes, 6982 at the robot's and fails. So the sideways reading errs
by −11 to +10 % with the pose, down by −11 to 0 %: enough to catch a mount blocked,
swapped or missing either way, not one 1.3 times stiffer everywhere. The true push on
the anvil stayed under 20 N, and under 37 N with a mount rigid sideways (a steel block
met at 5 mm/s, the read force lagging its low-pass). The push is the clamp's to bound,
whatever the mount: a press asked for 15 N at the test's pose was held near 13 N (and
asked for 30 N, near 18 N true) by the clamp's worst-case model.

The ratio of the two stiffnesses, each way within its tolerance, is judged too. One way
softer than the other stores energy a rounded edge turns into a push √ratio times what the
clamp's energy envelope allows for (:mod:`rakectl.core.envelope`); the two tolerances alone
admit a ratio of 1.2/0.5 = 2.4 as read, and about 3 true at the robot's anvil, whose
readings err most. The readings' ratio errs with the anvil's pose and with the mount: a
correct mount read 0.82 (the robot's anvil) to 1.11 (the test's) times its configured ratio
over twelve poses from 0.45 to 1.4 m of reach, and a dozen unequal mounts at the two anvils
read 0.81 to 1.14 times theirs. ``selftest.mount_ratio_tolerance`` (1.5) passes a correct
mount with a margin and refuses a true ratio more than 1.5/0.81 = 1.85 times the configured
one or less than 1/(1.5 · 1.14) = 1/1.71 (measured: a vertical mount half the sideways one,
2900 N/m under 5800, read 0.56 at the test's anvil, and 2750 under 5000 read 0.55 at the
robot's; 5300 N/m down over 3100 sideways, a true 1.71, read 1.91 at the test's anvil: each
within its own way's tolerance, each refused; 5000 N/m down over 2750 sideways, a true
1.82, read 1.47 at the robot's anvil and passed). Held to the stiffer side's √1.2 the ratio
would need readings within a few per cent, so between 1.2 and 1.85 the mount's isotropy
stays an assembly check. Nor is the mount's damping judged (the presses are quasi-static).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from rakectl.config.service import SelfTestSettings
from rakectl.config.settings import ClampSettings, anvil_side_reach_m, press_depth_m
from rakectl.core import kinematics
from rakectl.core.envelope import unbalanced_weight_n
from rakectl.core.motor_model import MotorParams, joint_load_band, joint_resolution
from rakectl.core.mount_press import FIT_WINDOW, Press, PressResult
from rakectl.core.supervision import tip_force_from_loads_n
from rakectl.errors import KinematicsError

CLEARANCE_M = 0.01  # from the anvil's face, where each press starts
SETTLE_S = 0.2  # held at the press's start before the baseline (the arm just arrived)
BASELINE_S = 0.5  # the press's first ticks, in free air: the force read there is its zero
FILTER_S = 0.05  # low-pass on the force read (a joint creeping at a few counts per tick
# sticks and slips: its current swings by amperes from one tick to the next)
ARRIVED_M = 0.002  # a move ends once the measured tip is this close to its end
ARRIVE_TIMEOUT_S = 3.0  # after the reference arrived
HOLD_S = 0.3  # at the press's end
STALL_LAG_M = 0.003  # the reference this far past the arm: the clamp holds the press
PATH_STEP_M = 0.01  # the way to the anvil is checked against the joints' limits this often


class Phase(enum.Enum):
    RISE = "rise"
    ACROSS = "across"
    DOWN = "down"
    PRESS = "press"
    HOLD = "hold"
    UP = "up"
    OVER = "over to the side"
    BESIDE = "down beside"
    SIDE_PRESS = "side press"
    SIDE_HOLD = "side hold"
    OFF = "off the side"
    CLEAR = "up from the side"
    BACK = "back"
    RETURN = "return"
    LOWER = "lower"
    DONE = "done"


@dataclass(frozen=True)
class MountResult:
    passed: bool
    down: PressResult  # pressed from above (clamp.contact_stiffness_n_per_m)
    side: PressResult  # pressed on the near side (clamp.side_contact_stiffness_n_per_m)
    ratio: float  # measured vertical over sideways stiffness, over the configured ratio; nan
    message: str


class MountCheck:
    """Drives the tip reference to the anvil, through both presses and back; see the
    module."""

    def __init__(self, settings: SelfTestSettings, clamp: ClampSettings, motor_r: MotorParams,
                 motor_theta: MotorParams, workspace: kinematics.Workspace, dt_s: float,
                 reach_m: float, depth_m: float) -> None:
        self._s, self._clamp = settings, clamp
        self._ws, self._dt_s = workspace, dt_s
        self._weight_n = unbalanced_weight_n(clamp)
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._motors = (motor_r, motor_theta)
        self.start = (reach_m, depth_m)
        anvil_depth_m = -settings.anvil_height_m
        approach_depth_m = anvil_depth_m - CLEARANCE_M
        travel_depth_m = min(depth_m, approach_depth_m)
        self._side_reach_m = anvil_side_reach_m(settings)
        beside_reach_m = self._side_reach_m - CLEARANCE_M
        side_depth_m = -settings.anvil_side_height_m
        self._settle_ticks = round(SETTLE_S / dt_s)
        reach, travel = settings.anvil_reach_m, settings.travel_speed_m_per_s
        self._legs = {
            Phase.RISE: (reach_m, travel_depth_m),
            Phase.ACROSS: (reach, travel_depth_m),
            Phase.DOWN: (reach, approach_depth_m),
            Phase.UP: (reach, approach_depth_m),
            Phase.OVER: (beside_reach_m, approach_depth_m),
            Phase.BESIDE: (beside_reach_m, side_depth_m),
            Phase.OFF: (beside_reach_m, side_depth_m),
            Phase.CLEAR: (beside_reach_m, approach_depth_m),
            Phase.BACK: (beside_reach_m, travel_depth_m),
            Phase.RETURN: (reach_m, travel_depth_m),
            Phase.LOWER: (reach_m, depth_m),
        }
        self._speed = travel
        baseline_ticks = max(1, round(BASELINE_S / dt_s))
        alpha = 1.0 - math.exp(-dt_s / FILTER_S)
        # each press's joint motion: down with the reach held, or away from the robot with
        # the height held; J⁻¹ of that way gives each joint's direction, J's row its travel
        j11, j12, j21, j22 = _jacobian(workspace, reach, settings.anvil_height_m)
        det = j11 * j22 - j12 * j21
        self.down = Press(clamp.contact_stiffness_n_per_m,
                           (math.copysign(1.0, j12 / det), math.copysign(1.0, -j11 / det)),
                           self._resolution(j21, j22), baseline_ticks, alpha,
                           anvil_depth_m + press_depth_m(settings, clamp))
        j11, j12, j21, j22 = _jacobian(workspace, self._side_reach_m,
                                       settings.anvil_side_height_m)
        det = j11 * j22 - j12 * j21
        self.side = Press(clamp.side_contact_stiffness_n_per_m,
                           (math.copysign(1.0, j22 / det), math.copysign(1.0, -j21 / det)),
                           self._resolution(j11, j12), baseline_ticks, alpha,
                           self._side_reach_m + press_depth_m(settings, clamp, sideways=True))
        self.reach_m, self.depth_m = reach_m, depth_m
        self.phase = Phase.RISE
        self._ticks = 0  # in this phase, since its reference arrived for a move
        self.result: MountResult | None = None
        self._failure = self._outside_workspace()
        if self._failure:
            self._finish()

    def _resolution(self, along_r: float, along_theta: float) -> float:
        """The encoders' resolution of a travel whose Jacobian row is given."""
        motor_r, motor_theta = self._motors
        return max(abs(along_r) * joint_resolution(motor_r),
                   abs(along_theta) * joint_resolution(motor_theta))

    def _outside_workspace(self) -> str:
        """Why the path to the anvil and around it leaves the joints' limits ("" if it does
        not): its legs, straight in (reach, height), checked every ``PATH_STEP_M``."""
        here = self.start
        for phase in (Phase.RISE, Phase.ACROSS, Phase.DOWN, Phase.UP, Phase.OVER,
                      Phase.BESIDE):
            there = self._legs[phase]
            parts = max(1, math.ceil(math.dist(here, there) / PATH_STEP_M))
            for i in range(parts + 1):
                reach_m = here[0] + (there[0] - here[0]) * i / parts
                depth_m = here[1] + (there[1] - here[1]) * i / parts
                try:
                    kinematics.inverse(self._ws, reach_m, -depth_m)
                except KinematicsError as error:
                    return (f"tine-mount check: the way to the anvil from reach "
                            f"{self.start[0]:.3f} m, height {-self.start[1]:.3f} m leaves the "
                            f"workspace ({phase.value}): {error}: arm from another pose")
            here = there
        return ""

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    def step(self, reach_m: float, depth_m: float) -> None:
        """Advance the reference one tick, given the measured tip (depth > 0 down)."""
        phase = self.phase
        if phase is Phase.DONE:
            return
        self._ticks += 1
        if phase is Phase.PRESS:
            self._press(self.down, self.depth_m, depth_m, Phase.HOLD, Phase.UP)
        elif phase is Phase.SIDE_PRESS:
            self._press(self.side, self.reach_m, reach_m, Phase.SIDE_HOLD, Phase.OFF)
        elif phase in (Phase.HOLD, Phase.SIDE_HOLD):
            if self._ticks * self._dt_s >= HOLD_S:
                self._next(Phase.UP if phase is Phase.HOLD else Phase.OFF)
        else:
            self._move(phase, reach_m, depth_m)

    def _press(self, press: Press, reference_m: float, measured_m: float, held: Phase,
               ended: Phase) -> None:
        """One tick of a press whose reference travels along ``reference_m`` (the depth
        down, the reach sideways) and whose arm is at ``measured_m`` along it."""
        if press.peak_force_n >= self._s.press_force_n:
            self._next(held)
        elif reference_m - measured_m > STALL_LAG_M:
            press.stalled = True  # judged in the end: held short of the press
            self._next(ended)
        elif reference_m >= press.limit_m:
            self._next(ended)  # judged in the end: nothing met where configured
        elif self._ticks > self._settle_ticks:
            step_m = self._s.press_speed_m_per_s * self._dt_s
            if press is self.down:
                self.depth_m += step_m
            else:
                self.reach_m += step_m

    def _move(self, phase: Phase, reach_m: float, depth_m: float) -> None:
        goal_reach_m, goal_depth_m = self._legs[phase]
        step_m = self._speed * self._dt_s
        d_reach, d_depth = goal_reach_m - self.reach_m, goal_depth_m - self.depth_m
        distance = math.hypot(d_reach, d_depth)
        if distance > step_m:
            self.reach_m += d_reach * step_m / distance
            self.depth_m += d_depth * step_m / distance
            self._ticks = 0
            return
        self.reach_m, self.depth_m = goal_reach_m, goal_depth_m
        if math.hypot(reach_m - goal_reach_m, depth_m - goal_depth_m) <= ARRIVED_M:
            self._next(_AFTER[phase])
        elif self._ticks * self._dt_s > ARRIVE_TIMEOUT_S:
            away_mm = math.hypot(reach_m - goal_reach_m, depth_m - goal_depth_m) * 1e3
            self._failure = (f"tine-mount check: the arm did not reach reach "
                             f"{goal_reach_m:.3f} m, height {-goal_depth_m:.3f} m within "
                             f"{ARRIVE_TIMEOUT_S:g} s ({phase.value}): it is {away_mm:.0f} "
                             "mm away")
            self._finish()

    def _next(self, phase: Phase) -> None:
        self.phase, self._ticks = phase, 0
        if phase is Phase.DONE:
            self._finish()

    def observe(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float,
                current_r_a: float, current_theta_a: float) -> None:
        """One tick's feedback; read while pressing."""
        if self.phase is Phase.PRESS:
            press = self.down
        elif self.phase is Phase.SIDE_PRESS:
            press = self.side
        else:
            return
        if self._ticks < self._settle_ticks:
            return
        loads = [joint_load_band(m, i, v)[0 if sign > 0.0 else 1] for m, i, v, sign in zip(
            self._motors, (current_r_a, current_theta_a), (r_vel, theta_vel), press.sign,
            strict=True)]
        reach_n, down_n = tip_force_from_loads_n(r_m, theta_rad, loads[0], loads[1],
                                                 self._weight_n, self._half_length_m)
        window = (FIT_WINDOW[0] * self._s.press_force_n, FIT_WINDOW[1] * self._s.press_force_n)
        if press is self.down:  # travel: the arm's depth below the pivot
            press.add(down_n, r_m * math.sin(theta_rad) - self._ws.pivot_height_m, window)
        else:  # the near side pushes the tines toward the robot; travel: the arm's reach
            press.add(-reach_n, r_m * math.cos(theta_rad), window)

    def _finish(self) -> None:
        self.phase = Phase.DONE
        self.result = self._judge()

    def _judge(self) -> MountResult:
        s = self._s
        top = (f"the anvil (selftest.anvil_reach_m {s.anvil_reach_m:g} m, "
               f"anvil_height_m {s.anvil_height_m:g} m)")
        near = (f"the anvil's near side (reach {self._side_reach_m:.3f} m: selftest."
                f"anvil_reach_m − anvil_width_m/2; anvil_side_height_m "
                f"{s.anvil_side_height_m:g} m)")
        down = self.down.judge(s, top, "contact_stiffness_n_per_m", "pressed down",
                                 press_depth_m(s, self._clamp), "below the top of", "height")
        side = self.side.judge(s, near, "side_contact_stiffness_n_per_m",
                                 "pressed sideways",
                                 press_depth_m(s, self._clamp, sideways=True), "past",
                                 "position and width")
        if self._failure:
            return MountResult(False, down, side, math.nan, self._failure)
        ratio = math.nan
        passed = down.passed and side.passed
        parts = [down.message, "sideways: " + side.message]
        if passed:  # each way matches: is one way much softer than the other?
            ratio = (down.stiffness_n_per_m / side.stiffness_n_per_m) / (
                down.expected_n_per_m / side.expected_n_per_m)
            tolerance = s.mount_ratio_tolerance
            passed = 1.0 / tolerance <= ratio <= tolerance
            if not passed:
                softer = "sideways" if ratio > 1.0 else "vertically"
                parts.append(
                    f"but the mount is softer {softer} than the other way: its two "
                    f"stiffnesses' ratio (down over sideways) is {ratio:.2f} times the "
                    f"configured one, outside 1/{tolerance:g} … {tolerance:g} (selftest."
                    "mount_ratio_tolerance): a rounded edge turns the energy the softer "
                    "way stores into a larger push than the clamp allows for: check the "
                    "tines' springs before arming")
        return MountResult(passed, down, side, ratio, "tine-mount check: " + "; ".join(parts))

def _jacobian(workspace: kinematics.Workspace, reach_m: float, height_m: float
              ) -> tuple[float, float, float, float]:
    r_m, theta_rad = kinematics.inverse(workspace, reach_m, height_m)
    return kinematics.jacobian(r_m, theta_rad)


_AFTER = {Phase.RISE: Phase.ACROSS, Phase.ACROSS: Phase.DOWN, Phase.DOWN: Phase.PRESS,
          Phase.UP: Phase.OVER, Phase.OVER: Phase.BESIDE, Phase.BESIDE: Phase.SIDE_PRESS,
          Phase.OFF: Phase.CLEAR, Phase.CLEAR: Phase.BACK, Phase.BACK: Phase.RETURN,
          Phase.RETURN: Phase.LOWER, Phase.LOWER: Phase.DONE}
