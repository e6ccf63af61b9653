"""Plausibility checks before a discovered term (or a library effect) is named as the car's physics.

A fit can improve held-out data for the wrong reason. Before naming, each term is checked:

* it must not need the chain around it to move a lot: a term that explains the data only together
  with a large change of the steering offset (over 0.005 rad and three times its interval) or gain
  (over 25%) is doubtful;
* its size must be one a car can have: a dead band over half the median steering command, a play
  over the median command, end stops below the median command (the car could hardly steer), a gyro
  bias over 0.05 rad/s (3 deg/s) (each term's check is its registry entry's ``doubts``), a bank over
  0.35 rad (20 deg);
* a bank must belong to places: one that falls outwards (or inwards) in every curve, left and right
  alike, follows the curvature and is a handling effect standing in for the road;
* a delay must fit the recording's own steering-to-turn response (the lag at which the steering
  best explains the heading's turning, from the consistency checks): a delay longer than that lag
  plus ``DELAY_MARGIN_S`` is doubtful, and a gyro said to be late by more than its lag behind the
  heading plus ``DELAY_MARGIN_S``.

Doubtful terms are reported with the reason and never make the verdict ``discovered``.
"""

from __future__ import annotations

import math

from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem
from plm_highway.sim2real.physics.effects import acts_on_gyro, delay_estimates
from plm_highway.sim2real.physics.terms import TERMS
from plm_highway.sim2real.record.consistency import Consistency

OFFSET_CHANGE_RAD = 0.005
GAIN_CHANGE = 0.25
MAX_BANK_RAD = 0.35
DELAY_MARGIN_S = 0.15


def _half_width(ci: list[float]) -> float:
    return 0.5 * (ci[1] - ci[0])


def compensation_doubts(before: CandidateFit, after: CandidateFit) -> list[str]:
    """A term that needs a large change of the chain's offset or gain to fit is doubtful."""
    doubts = []
    offset_before = before.estimates.get("steering_offset", {}).get("offset_rad")
    offset_after = after.estimates.get("steering_offset", {}).get("offset_rad")
    if offset_before is not None and offset_after is not None:
        change = offset_after - offset_before
        width = _half_width(after.ci95["steering_offset"]["offset_rad"])
        if abs(change) > max(OFFSET_CHANGE_RAD, 3 * width):
            doubts.append(f"it fits only together with a steering offset moved by {change:+.4f} rad "
                          f"({offset_before:+.4f} -> {offset_after:+.4f})")
    gain_before = before.estimates.get("steering_gain", {}).get("gain")
    gain_after = after.estimates.get("steering_gain", {}).get("gain")
    if gain_before and gain_after and abs(gain_after / gain_before - 1) > GAIN_CHANGE:
        doubts.append(f"it fits only together with a steering gain moved from {gain_before:.3f} to {gain_after:.3f}")
    return doubts


def size_doubts(problem: FitProblem, name: str, estimates: dict[str, float]) -> list[str]:
    """A term whose size no working car has."""
    if name in TERMS and TERMS[name].doubts is not None:
        return TERMS[name].doubts(estimates, problem.ctx)
    if name == "bank_along_track":
        doubts = []
        if estimates["max_abs_bank_rad"] > MAX_BANK_RAD:
            doubts.append(f"a bank of {math.degrees(estimates['max_abs_bank_rad']):.0f} deg is steeper than roads "
                          "are built")
        left, right = estimates.get("bank_left_rad"), estimates.get("bank_right_rad")
        if left is not None and right is not None and left * right < 0 and min(abs(left), abs(right)) > \
                0.5 * max(abs(left), abs(right)):
            doubts.append(f"it falls {'outwards' if left < 0 else 'inwards'} in every curve, left "
                          f"({math.degrees(left):+.1f} deg) and right ({math.degrees(right):+.1f} deg): it follows the "
                          "curvature, not the places (a handling effect such as tires at the limit, not a road)")
        return doubts
    return []


def delay_doubts(estimate_s: float, what: str, consistency: Consistency | None, gyro: bool = False) -> list[str]:
    """A delay (``estimate_s``) longer than the recording's own response allows."""
    if consistency is None:
        return []
    check = consistency.check("yaw_rate_vs_heading" if gyro else "steer_vs_turning")
    if check.status != "consistent" or not math.isfinite(check.lag_s):
        return []
    limit = max(check.lag_s, 0.0) + DELAY_MARGIN_S
    if estimate_s > limit:
        against = "the gyro runs behind the heading" if gyro else "the heading answers the steering"
        return [f"{what} of {estimate_s:.3f} s is longer than the recording allows: {against} within "
                f"{max(check.lag_s, 0.0):.2f} s"]
    return []


def library_doubts(winner: CandidateFit, consistency: Consistency | None) -> list[str]:
    """Doubts about the delays the library named, against the recording's own responses."""
    doubts = []
    # The car's delays first, then the gyro's (a late car and a late gyro are judged against different lags).
    delays = sorted(delay_estimates(winner.estimates).items(), key=lambda item: acts_on_gyro(item[0]))
    for name, estimate_s in delays:
        gyro = acts_on_gyro(name)
        doubts += delay_doubts(estimate_s, "a late gyro" if gyro else name.replace("_", " "), consistency, gyro=gyro)
    return doubts
