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

from plm_highway.estimation.ekf import EstimatorConfig, LaneStateEstimator, filter_step
from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, graded

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
