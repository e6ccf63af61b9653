"""Graded checks for Lesson 5, "Predicting through the delay": the delayed-measurement re-estimation.

The exercises are the three steps of seed paper 004's delay compensation (Eqs. (28)-(29)):
``capture_index`` (re-stamp: the history step nearest the frame's capture time), ``reestimate`` (roll back
to that step and re-run the filter to now) and ``fuse_late`` (both, for one late camera measurement).

Each check builds a real filter history (the kit's lane EKF driven by synthetic sensor data), computes the
reference on a copy before the student's code runs, and compares within a tolerance; a ``seed``
(nbgrader's hidden tests) draws further cases.
"""

from __future__ import annotations

import copy

import numpy as np

from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, graded
from plm_highway.lane_ekf.ekf import EstimatorConfig, LaneStateEstimator, filter_step
from plm_highway.latency.estimate import estimate_stream
from plm_highway.latency.synthetic import StreamSpec, Weave, synthetic_stream

CONFIG = EstimatorConfig()


def reference_capture_index(times_s, capture_time_s: float) -> int:
    """The step nearest ``capture_time_s`` (a tie goes to the later step), clamped to the history."""
    times = np.asarray(times_s, float)
    index = int(np.searchsorted(times, capture_time_s))
    if index == len(times) or (index > 0 and capture_time_s - times[index - 1] < times[index] - capture_time_s):
        index -= 1
    return max(0, min(index, len(times) - 1))


def reference_reestimate(history, start: int, step):
    """Re-run ``step`` from ``history[start]``'s entering estimate to the newest step, storing each result."""
    x, p = history[start].x_before, history[start].p_before
    for record in history[start:]:
        record.x_before, record.p_before = x, p
        x, p = step(x, p, record)
        record.x, record.p = x, p
    return x, p


def reference_fuse_late(history, z, capture_time_s: float, step):
    index = reference_capture_index([record.time_s for record in history], capture_time_s)
    history[index].cameras.append(np.asarray(z, float))
    return reference_reestimate(history, index, step)


def kit_step(x, p, record):
    """One filter step of the kit's lane EKF (predict to the record's time, update with its measurements)."""
    return filter_step(x, p, record, CONFIG)


def make_history(seed: int, steps: int = 40, step_s: float = 0.01):
    """A filter history of ``steps`` sensor samples (a weaving car at 15-25 m/s), no camera yet."""
    rng = np.random.default_rng(seed)
    estimator = LaneStateEstimator(CONFIG, compensate_delay=False)
    speed = float(rng.uniform(15.0, 25.0))
    t0 = float(rng.uniform(0.0, 5.0))
    phase = float(rng.uniform(0, 2 * np.pi))
    for k in range(steps):
        t = t0 + k * step_s
        steer = 0.01 * np.sin(2 * np.pi * 0.4 * t + phase) + 0.001 * rng.standard_normal()
        yaw_rate = speed * steer / 2.8 + 0.002 * rng.standard_normal()
        estimator.step(t, steer, speed, np.array([speed * yaw_rate + 0.1 * rng.standard_normal(), yaw_rate]))
    return estimator.history


def _camera(rng) -> np.ndarray:
    return np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.05, 0.05), rng.uniform(-0.005, 0.005)])


def _pair(what: str, value):
    try:
        x, p = value
        x, p = np.asarray(x, float), np.asarray(p, float)
    except (TypeError, ValueError):
        raise CheckFailed(what, "a pair (x, p): the newest state (6,) and covariance (6, 6)", repr(value)[:80]) from None
    expect_true(x.shape == (6,) and p.shape == (6, 6), what, "return (x, p) of the newest step",
                expected="shapes (6,) and (6, 6)", received=f"shapes {x.shape} and {p.shape}")
    return x, p


@graded(points=2)
def check_capture_index(capture_index, seed: int | None = None) -> None:
    """The history step nearest the capture time; a tie goes to the later step; clamped to the history."""
    rng = np.random.default_rng(51 if seed is None else seed)
    times = [round(3.0 + 0.01 * k, 2) for k in range(50)]
    cases = [(times, 3.25), (times, 3.253), (times, 3.257), (times, 3.255), (times, 2.0), (times, 9.0), (times, 3.49)]
    if seed is not None:
        jittered = list(np.cumsum(rng.uniform(0.005, 0.02, 60)) + rng.uniform(0, 10))
        cases = [(jittered, float(rng.uniform(jittered[0] - 0.05, jittered[-1] + 0.05))) for _ in range(6)]
        cases.append((jittered, (jittered[10] + jittered[11]) / 2))
    for grid, capture_s in cases:
        expected = reference_capture_index(grid, capture_s)
        received = call_student(capture_index, list(grid), capture_s, what=f"capture_index(times, {capture_s:.4f})",
                                exercise="lesson5.capture_index")
        expect_true(isinstance(received, (int, np.integer)) and int(received) == expected,
                    f"capture_index for a capture at {capture_s:.4f} s (history {grid[0]:.3f} .. {grid[-1]:.3f} s)",
                    "the nearest step; exactly halfway goes to the later step; before the oldest step -> 0, "
                    "after the newest -> len(times) - 1", expected=expected, received=repr(received))


@graded(points=3)
def check_reestimate(reestimate, seed: int | None = None) -> None:
    """Re-running the filter from ``start`` gives the kit's estimates at every step from there, and the newest."""
    rng = np.random.default_rng(52 if seed is None else seed)
    for _ in range(2 if seed is None else 3):
        history = make_history(int(rng.integers(1 << 30)))
        start = int(rng.integers(0, len(history) - 1))
        history[start].cameras.append(_camera(rng))
        expected_history = copy.deepcopy(history)
        before = [record.x.copy() for record in history[:start]]
        x_expected, p_expected = reference_reestimate(expected_history, start, kit_step)
        received = call_student(reestimate, history, start, kit_step,
                                what=f"reestimate(history of {len(history)} steps, start={start}, step)",
                                exercise="lesson5.reestimate")
        x, p = _pair("what reestimate returned", received)
        hint = ("start from history[start].x_before and .p_before (what entered that step), apply step(x, p, record) "
                "to every record from start to the end, and store each record's x_before, p_before, x, p")
        expect_close(f"newest state after a camera measurement filed {len(history) - start} steps back", x_expected, x,
                     atol=1e-9, rtol=1e-7, hint=hint)
        expect_close("newest covariance", p_expected, p, atol=1e-12, rtol=1e-7, hint=hint)
        expect_close("every re-run step's stored state (record.x)", np.array([r.x for r in expected_history[start:]]),
                     np.array([r.x for r in history[start:]]), atol=1e-9, rtol=1e-7,
                     hint="store the re-run result in each record: the next late measurement rolls back to them")
        expect_close("the steps before start (untouched)", np.array(before) if before else np.zeros((0, 6)),
                     np.array([r.x for r in history[:start]]) if start else np.zeros((0, 6)), atol=0.0,
                     hint="the re-run starts at history[start]; older steps are not affected")


@graded(points=3)
def check_fuse_late(fuse_late, seed: int | None = None) -> None:
    """A late camera measurement: filed at its capture step and re-estimated to now, as the kit's delay compensation."""
    rng = np.random.default_rng(53 if seed is None else seed)
    for _ in range(2 if seed is None else 3):
        history = make_history(int(rng.integers(1 << 30)))
        capture_s = float(rng.uniform(history[0].time_s, history[-2].time_s))
        z = _camera(rng)
        expected_history = copy.deepcopy(history)
        x_expected, p_expected = reference_fuse_late(expected_history, z, capture_s, kit_step)
        index = reference_capture_index([r.time_s for r in history], capture_s)
        received = call_student(fuse_late, history, z, capture_s, kit_step,
                                what=f"fuse_late(history, z, capture {history[-1].time_s - capture_s:.3f} s ago, step)",
                                exercise="lesson5.fuse_late")
        x, p = _pair("what fuse_late returned", received)
        filed = [k for k, record in enumerate(history) if record.cameras]
        expect_true(filed == [index], "where the measurement was filed", "append z to the cameras of the step "
                    "capture_index gives (the capture step, not the newest)", expected=f"step {index}",
                    received=f"steps {filed}")
        expect_close("newest state after the late measurement", x_expected, x, atol=1e-9, rtol=1e-7,
                     hint="re-estimate from the capture step to the newest with your reestimate")
        expect_close("newest covariance", p_expected, p, atol=1e-12, rtol=1e-7,
                     hint="re-estimate from the capture step to the newest with your reestimate")


def phase_lag_s(estimate, truth, step_s: float, max_lag_s: float = 0.6) -> float:
    """The delay [s] that best aligns ``estimate`` with ``truth`` (least squares over whole samples)."""
    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    lags = range(int(round(max_lag_s / step_s)) + 1)
    errors = [np.mean((estimate[lag:] - truth[: len(truth) - lag]) ** 2) for lag in lags]
    return float(np.argmin(errors) * step_s)


# ------------------------------------------------------------------------------------------------------------
# Part 7: how late is the camera? A hidden latency estimated from a short log (no capture timestamps).
# ------------------------------------------------------------------------------------------------------------

LOG_RATE_HZ = 20.0  # the log's loop rate: one frame period is 0.05 s
LOG_DURATION_S = 12.0
HIDDEN_LATENCIES_S = (0.1, 0.15, 0.2, 0.25, 0.3)  # on the log's frame grid
DIP_SPAN_S = 0.1  # how far from the best lag the dip is judged
WHY_ESTIMABLE = "b"  # the car turning relative to the lane: seen at once by the gyro and late by the camera


class SealedLatency:
    """The hidden latency, printed only when asked: ``answer.reveal()``."""

    def __init__(self, latency_s: float):
        self._latency_s = latency_s

    def reveal(self) -> float:
        return self._latency_s

    def __repr__(self) -> str:
        return "<hidden latency, sealed: answer.reveal() at the end of the lesson>"


def latency_log(seed: int, latency_s: float, weave_rad: float = 0.02, duration_s: float = LOG_DURATION_S) -> dict:
    """A log of a car on a straight lane weaving with ``weave_rad`` of front-wheel angle (0: no steering): its
    fast sensors and the camera's late lane offset and heading, ``latency_s`` late, with noise
    (:func:`plm_highway.latency.synthetic.synthetic_stream`)."""
    rng = np.random.default_rng(seed)
    weave = Weave((weave_rad, 0.5 * weave_rad), (float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.8, 1.2))),
                  tuple(float(v) for v in rng.uniform(0, 2 * np.pi, 2)))
    stream = synthetic_stream(StreamSpec(duration_s=duration_s, rate_hz=LOG_RATE_HZ, latency=latency_s, weave=weave),
                              rng)
    return {name: values for name, values in stream.items() if name != "true_latency_s"}


def hidden_latency_log(seed: int) -> tuple[dict, SealedLatency]:
    """The lesson's log: the seed picks the latency (from :data:`HIDDEN_LATENCIES_S`), the weave and the noise."""
    latency_s = float(np.random.default_rng([seed, 6]).choice(HIDDEN_LATENCIES_S))
    return latency_log(seed, latency_s), SealedLatency(latency_s)


def reference_heading(log: dict) -> np.ndarray:
    """The heading turned since the log began: the trapezoidal integral of the yaw rate."""
    t, rate = np.asarray(log["time_s"], float), np.asarray(log["yaw_rate_radps"], float)
    return np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])


def reference_alignment_cost(log: dict, lag_s: float) -> float:
    """How badly the camera's heading fits the car's own heading ``lag_s`` earlier: the variance, over the samples
    whose capture time ``t - lag_s`` lies in the log, of camera heading minus integrated yaw rate at that time (on a
    straight the lane's own heading is a constant, which the variance removes)."""
    t = np.asarray(log["time_s"], float)
    heading = reference_heading(log)
    camera = np.asarray(log["lane_heading_rad"], float)
    capture = t - lag_s
    use = (capture >= t[0] - 1e-9) & np.isfinite(camera)
    return float(np.var(camera[use] - np.interp(capture[use], t, heading)))


def reference_estimate_latency(log: dict, lags_s) -> tuple[float, np.ndarray]:
    costs = np.array([reference_alignment_cost(log, lag) for lag in lags_s])
    return float(np.asarray(lags_s, float)[int(np.argmin(costs))]), costs


def reference_relative_dip(costs, lags_s, span_s: float = DIP_SPAN_S) -> float:
    """How much worse the best fit ``span_s`` or more away from the best lag is, relative to the best fit."""
    costs, lags = np.asarray(costs, float), np.asarray(lags_s, float)
    best = int(np.argmin(costs))
    far = np.abs(lags - lags[best]) >= span_s - 1e-9
    return float((costs[far].min() - costs[best]) / costs[best])


LAGS_S = np.round(np.arange(0.0, 0.5001, 0.05), 2)


@graded(points=3)
def check_alignment_cost(alignment_cost, seed: int | None = None) -> None:
    """The alignment cost of a lag: variance of camera heading minus the integrated yaw rate at the capture time."""
    rng = np.random.default_rng(61 if seed is None else seed)
    for _ in range(2 if seed is None else 3):
        log = latency_log(int(rng.integers(1 << 30)), float(rng.choice(HIDDEN_LATENCIES_S)), duration_s=6.0)
        if rng.random() < 0.5:  # a lost frame or two: NaN in the camera's columns
            lost = rng.integers(0, len(log["time_s"]), 3)
            log["lane_heading_rad"] = log["lane_heading_rad"].copy()
            log["lane_heading_rad"][lost] = np.nan
        for lag_s in (0.0, float(rng.choice(LAGS_S[1:])), 0.475):
            expected = reference_alignment_cost(log, lag_s)
            received = call_student(alignment_cost, dict(log), lag_s, what=f"alignment_cost(log, {lag_s})",
                                    exercise="lesson5.alignment_cost")
            expect_close(f"alignment_cost at a lag of {lag_s} s", expected, received, atol=1e-12, rtol=1e-6,
                         hint="integrate the yaw rate with the trapezoidal rule from 0 at the first sample; keep the "
                              "samples whose capture time t - lag is not before the first sample and whose camera "
                              "heading is not NaN; np.interp the integrated heading at the capture times; np.var of "
                              "camera heading minus that")


@graded(points=3)
def check_estimate_latency(estimate_latency, seed: int | None = None) -> None:
    """The lag of the smallest cost, on logs whose latency is known to the check: within one frame of the truth."""
    rng = np.random.default_rng(62 if seed is None else seed)
    for _ in range(2 if seed is None else 3):
        truth_s = float(rng.choice(HIDDEN_LATENCIES_S))
        log = latency_log(int(rng.integers(1 << 30)), truth_s, duration_s=8.0)
        expected, expected_costs = reference_estimate_latency(log, LAGS_S)
        received = call_student(estimate_latency, dict(log), LAGS_S.copy(), what="estimate_latency(log, LAGS_S)",
                                exercise="lesson5.estimate_latency")
        if not (isinstance(received, tuple) and len(received) == 2):
            raise CheckFailed("what estimate_latency returned", "(best_lag_s, costs)", repr(received)[:80])
        lag, costs = received
        expect_close("the costs, one per lag", expected_costs, costs, atol=1e-12, rtol=1e-6,
                     hint="call your alignment_cost for every lag of lags_s, in order")
        expect_close(f"the best lag (the log's latency is {truth_s} s)", expected, lag, atol=1e-9,
                     hint="the lag whose cost is smallest: lags_s[np.argmin(costs)]")
        expect_true(abs(float(lag) - truth_s) <= 1.0 / LOG_RATE_HZ + 1e-9, "the best lag against the truth",
                    "within one frame period (0.05 s) of the latency", expected=truth_s, received=lag)


@graded(points=2)
def check_relative_dip(relative_dip, seed: int | None = None) -> None:
    """The dip of a cost curve: (best cost at least span_s away - best cost) / best cost."""
    rng = np.random.default_rng(63 if seed is None else seed)
    cases = [(np.array([4.0, 2.0, 1.0, 1.5, 3.0, 5.0]), np.array([0.0, 0.05, 0.1, 0.15, 0.2, 0.25]), 0.1),
             (np.array([1.0, 1.01, 1.02, 1.0, 0.99]), np.array([0.0, 0.1, 0.2, 0.3, 0.4]), 0.1)]
    if seed is not None:
        lags = np.round(np.arange(0, 0.5001, 0.05), 2)
        cases = [(rng.uniform(0.5, 3.0, len(lags)), lags, float(rng.choice([0.05, 0.1, 0.15]))) for _ in range(4)]
    for costs, lags, span_s in cases:
        expected = reference_relative_dip(costs, lags, span_s)
        received = call_student(relative_dip, costs.copy(), lags.copy(), span_s,
                                what=f"relative_dip(costs, lags, {span_s})", exercise="lesson5.relative_dip")
        expect_close(f"the relative dip of {np.round(costs, 3).tolist()} at span {span_s} s", expected, received,
                     atol=1e-12, rtol=1e-9, hint="best = argmin(costs); among the lags at least span_s from "
                     "lags[best] take the smallest cost; (that - costs[best]) / costs[best]")


@graded(points=2)
def check_why_estimable(why_estimable) -> None:
    """The one thing that makes a latency estimable from the stream."""
    answer = call_student(why_estimable, what="why_estimable()", exercise="lesson5.why_estimable")
    expect_true(isinstance(answer, str) and answer.strip().lower() == WHY_ESTIMABLE, "your answer to the question",
                "compare the two cost curves above: which log's curve has a dip, and what differs between the logs?",
                expected="one letter: the right one", received=repr(answer))


def kit_estimate(log: dict) -> tuple[float, float] | None:
    """The kit's own estimator over a log (:mod:`plm_highway.latency.estimate`): its last estimable estimate and
    standard deviation, or None where it never had one."""
    result = estimate_stream(log["time_s"], log["yaw_rate_radps"], log["speed_mps"], log["steer_rad"],
                             log["lane_offset_m"], log["lane_heading_rad"])
    estimable = np.flatnonzero(result["estimable"])
    return None if not estimable.size else (float(result["latency_s"][estimable[-1]]),
                                            float(result["std_s"][estimable[-1]]))
