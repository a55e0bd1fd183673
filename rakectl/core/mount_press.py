"""One press of the tine-mount check (pure): the force read along the press against the
arm's travel, and the mount's stiffness that way judged against the configured one
(:mod:`rakectl.core.mount_check` drives the presses and says how the figures are read).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rakectl.config.service import SelfTestSettings

FIT_WINDOW = (0.2, 1.0)  # of press_force_n: the ticks the slope is fitted over
MIN_FIT_SAMPLES = 20
MIN_SPREAD_COUNTS = 5.0  # least spread of the arm's travel, in encoder counts, for a slope
MIN_FORCE_SPAN = 0.5  # of press_force_n: the least rise of the force over the fit's ticks


@dataclass(frozen=True)
class PressResult:
    """One press's verdict: the mount's stiffness that way against the configured one."""

    passed: bool
    stiffness_n_per_m: float  # measured (a lower bound when ``at_least``); nan if none
    expected_n_per_m: float  # configured
    at_least: bool
    samples: int
    peak_force_n: float  # the press's largest force read through the currents, over free air
    message: str  # what was measured, or why nothing was


class Press:
    """One press's readings: the force along the press read through the currents above its
    free-air baseline and the arm's travel along it, low-passed alike (each force is paired
    with its travel), summed for the least-squares slope of one against the other."""

    def __init__(self, expected_n_per_m: float, sign: tuple[float, float],
                 resolution_m: float, baseline_ticks: int, alpha: float,
                 limit_m: float) -> None:
        self.expected_n_per_m = expected_n_per_m
        self.sign = sign  # the side of each joint's load band: the way the press moves it
        self.resolution_m = resolution_m  # of the travel, from the encoders
        self.limit_m = limit_m  # the reference's furthest travel
        self._baseline_ticks, self._alpha = baseline_ticks, alpha
        self.sums = [0.0] * 5  # n, Σs, ΣF, Σs², ΣsF over the fit's ticks
        self.spread = (math.inf, -math.inf, math.inf, -math.inf)  # s and F, min and max
        self.peak_force_n = 0.0  # above the baseline
        self.stalled = False
        self._baseline = [0.0, 0.0]  # ticks, Σ force read
        self._filtered_n = self._filtered_m = math.nan

    def add(self, force_n: float, travel_m: float, window: tuple[float, float]) -> None:
        """One tick's force read along the press and the arm's travel along it."""
        baseline = self._baseline
        if baseline[0] < self._baseline_ticks:
            baseline[0] += 1.0
            baseline[1] += force_n
            self._filtered_n = baseline[1] / baseline[0]
            self._filtered_m = travel_m
            return
        alpha = self._alpha
        self._filtered_n += alpha * (force_n - self._filtered_n)
        self._filtered_m += alpha * (travel_m - self._filtered_m)
        force_n = self._filtered_n - baseline[1] / baseline[0]
        travel_m = self._filtered_m
        self.peak_force_n = max(self.peak_force_n, force_n)
        if not window[0] <= force_n <= window[1]:
            return
        sums = self.sums
        sums[0] += 1.0
        sums[1] += travel_m
        sums[2] += force_n
        sums[3] += travel_m * travel_m
        sums[4] += travel_m * force_n
        s_lo, s_hi, f_lo, f_hi = self.spread
        self.spread = (min(s_lo, travel_m), max(s_hi, travel_m), min(f_lo, force_n),
                       max(f_hi, force_n))

    def judge(self, settings: SelfTestSettings, anvil: str, key: str, verb: str,
              depth_m: float, where: str, check: str) -> PressResult:
        """One press's verdict (its message without the check's name)."""
        expected = self.expected_n_per_m
        stiffer, softer = settings.mount_stiffer_tolerance, settings.mount_softer_tolerance
        n, ss, sf, sss, ssf = self.sums
        peak, force_n = self.peak_force_n, settings.press_force_n
        s_lo, s_hi, f_lo, f_hi = self.spread

        def result(passed: bool, k: float, at_least: bool, message: str) -> PressResult:
            return PressResult(passed, k, expected, at_least, int(n), peak, message)

        if self.stalled and peak < force_n:
            return result(False, math.nan, False,
                          f"the press was held at {peak:.1f} N of the {force_n:g} N asked for "
                          f"(selftest.press_force_n) on {anvil}: the clamp's bound at this "
                          "pose; lower the press or put the anvil where the arm pushes "
                          "harder")
        if peak < force_n and n < MIN_FIT_SAMPLES:
            return result(False, math.nan, False,
                          f"the tines met nothing: {verb} to {1e3 * depth_m:.0f} mm {where} "
                          f"{anvil}, the force read through the currents reached {peak:.1f} N "
                          f"of the {force_n:g} N pressed for: check the anvil's {check} in "
                          "the configuration")
        if peak < force_n or f_hi - f_lo < MIN_FORCE_SPAN * force_n:
            return result(False, math.nan, False,
                          f"the press reached {peak:.1f} N of the {force_n:g} N pressed for, "
                          f"{1e3 * depth_m:.0f} mm {where} {anvil}: too little to weigh the "
                          f"mount (the anvil elsewhere than configured, or a mount much softer "
                          f"than {expected:.0f} N/m)")
        spread_m = s_hi - s_lo
        if n >= MIN_FIT_SAMPLES and spread_m >= MIN_SPREAD_COUNTS * self.resolution_m:
            k, at_least = (n * ssf - ss * sf) / (n * sss - ss * ss), False
        else:  # the arm did not give measurably: at least this stiff
            k = (f_hi - f_lo) / max(spread_m, MIN_SPREAD_COUNTS * self.resolution_m)
            at_least = True
        ratio = k / expected
        passed = not at_least and 1.0 - softer <= ratio <= 1.0 + stiffer
        bound = "at least " if at_least else ""
        verdict = "matches" if passed else "does not match"
        message = (f"stiffness {bound}{k:.0f} N/m measured on {anvil} {verdict} "
                   f"{expected:.0f} N/m configured (clamp.{key}; ratio {bound}{ratio:.2f}, "
                   f"tolerance +{stiffer:g}/−{softer:g}, {int(n)} samples)")
        if not passed:
            message += (": the mount is stiffer than the clamp's bound assumes: check the "
                        "tines' springs before arming" if ratio > 1.0 else
                        ": check the tines' mount and the anvil before arming")
        return result(passed, k, at_least, message)
