"""The checks before the first arming after start-up, run in the state CHECKING.

First the weight (:mod:`rakectl.core.selftest`), then, with ``selftest.press``, the tine
mount (:mod:`rakectl.core.mount_check`). :meth:`ArmingChecks.start` builds the checks
not yet passed when ``arm`` is handled (off the tick: the tine-mount check's way to the
anvil is checked against the joints' limits then); :meth:`ArmingChecks.step` runs the
current one each tick and returns its verdict when it ends. Verdicts are kept until the
daemon ends: a check passed is not run again, one that failed runs at the next arming.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rakectl.config.settings import Settings
from rakectl.core import kinematics
from rakectl.core.mount_check import MountCheck, MountResult
from rakectl.core.selftest import WeightCheck, WeightResult
from rakectl.drive.health import Feedback


@dataclass(frozen=True)
class Verdict:
    """A check that ended: its event for the log and what the daemon does next."""

    event: str  # "weight_check" or "mount_check"
    fields: dict[str, Any]
    passed: bool
    message: str
    start: tuple[float, float]  # (reach, depth) it started from and brought the tip back to


class ArmingChecks:
    """The weight and tine-mount checks, their running instances and their verdicts."""

    def __init__(self, settings: Settings, workspace: kinematics.Workspace, dt_s: float
                 ) -> None:
        self._settings, self._workspace, self._dt_s = settings, workspace, dt_s
        self.weight_check: WeightCheck | None = None  # running, or waiting for CHECKING
        self.weight_result: WeightResult | None = None  # the last one's
        self.mount_check: MountCheck | None = None  # runs once the weight passed
        self.mount_result: MountResult | None = None
        self.interrupted = ""  # why the last checks left unfinished were, "" if none

    @property
    def weight_passed(self) -> bool:
        """Passed since start-up, or disabled."""
        result = self.weight_result
        return not self._settings.selftest.enabled or (result is not None and result.passed)

    @property
    def mount_passed(self) -> bool:
        """Passed since start-up, or not configured."""
        t, result = self._settings.selftest, self.mount_result
        return not (t.enabled and t.press) or (result is not None and result.passed)

    @property
    def passed(self) -> bool:
        return self.weight_passed and self.mount_passed

    def start(self, reach_m: float, depth_m: float) -> str:
        """Build the checks not yet passed, from this pose; the reason for CHECKING."""
        s, self.interrupted = self._settings, ""
        if not self.weight_passed:
            self.weight_check = WeightCheck(s.selftest, s.clamp, s.motors.r, s.motors.theta,
                                            self._dt_s, reach_m, depth_m)
        if not self.mount_passed:
            self.mount_check = MountCheck(s.selftest, s.clamp, s.motors.r, s.motors.theta,
                                          self._workspace, self._dt_s, reach_m, depth_m)
        return "weight check first" if self.weight_check is not None else \
            "tine-mount check first"

    def stop(self, reason: str = "") -> None:
        """Leaving CHECKING (``reason``: why): what did not end is judged again at the next
        arming, and :attr:`interrupted` says why it did not end."""
        if self.weight_check is not None or self.mount_check is not None:
            self.interrupted = reason or "left unfinished"
        self.weight_check = self.mount_check = None

    def step(self, fb: Feedback, reach_m: float, depth_m: float
             ) -> tuple[float, float, Verdict | None]:
        """One tick of the running check, given the feedback and the measured tip: its
        reference (reach, depth) and, on the tick it ends, its verdict."""
        weight = self.weight_check
        if weight is not None:
            weight.observe(fb.r_m, fb.theta_rad, fb.r_vel_m_per_s, fb.theta_vel_rad_per_s,
                           fb.current_r_a, fb.current_theta_a)
            weight.step()
            return weight.reach_m, weight.depth_m, self._judge_weight(weight)
        mount = self.mount_check
        if mount is None:
            raise AssertionError("no check to run in CHECKING")
        mount.observe(fb.r_m, fb.theta_rad, fb.r_vel_m_per_s, fb.theta_vel_rad_per_s,
                      fb.current_r_a, fb.current_theta_a)
        mount.step(reach_m, depth_m)
        return mount.reach_m, mount.depth_m, self._judge_mount(mount)

    def _judge_weight(self, check: WeightCheck) -> Verdict | None:
        result = check.result
        if result is None:
            return None
        self.weight_result, self.weight_check = result, None
        return Verdict("weight_check", {"passed": result.passed,
                                        "weight_n": _json_number(result.weight_n),
                                        "expected_n": result.expected_n,
                                        "samples": result.samples},
                       result.passed, result.message, check.start)

    def _judge_mount(self, check: MountCheck) -> Verdict | None:
        result = check.result
        if result is None:
            return None
        self.mount_result, self.mount_check = result, None
        down, side = result.down, result.side
        return Verdict("mount_check", {"passed": result.passed,
                                       "stiffness_n_per_m": _json_number(
                                           down.stiffness_n_per_m),
                                       "expected_n_per_m": down.expected_n_per_m,
                                       "at_least": down.at_least, "samples": down.samples,
                                       "press_n": down.peak_force_n,
                                       "side_stiffness_n_per_m": _json_number(
                                           side.stiffness_n_per_m),
                                       "side_expected_n_per_m": side.expected_n_per_m,
                                       "side_at_least": side.at_least,
                                       "side_samples": side.samples,
                                       "side_press_n": side.peak_force_n,
                                       "ratio": _json_number(result.ratio)},
                       result.passed, result.message, check.start)


def _json_number(value: float) -> float | None:
    """A figure for the log's JSON: None for nan (no figure: the check could not measure)."""
    return value if math.isfinite(value) else None
