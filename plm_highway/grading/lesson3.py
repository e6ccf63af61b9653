"""Graded checks for Lesson 3, "Measuring mitigation".

Students write the steering errors (MAE, MSE, RMSE) and PLM-Net's reduction, the discrete Frechet
distance and arc-length resampling, drive the three runs of the paper's Table 3 and measure them. A last
part drives the runs again at 0.25 s, where the steering error and the lane keeping disagree: students
measure the lateral offset, find which feedback PLM-Net weakens and pick the explanation.
Every check calls the student's code first, so that a stub fails fast with "not implemented yet".
A ``seed`` (nbgrader's hidden tests) draws further cases, compared with the kit's implementations
computed before the student's code runs.
"""

from __future__ import annotations

import functools

import numpy as np

from plm_highway.evaluation.comparison import steering_comparison
from plm_highway.evaluation.trajectory import LaneCentre
from plm_highway.grading.checks import call_student, expect_close, expect_equal, expect_true, graded
from plm_highway.metrics import frechet_dist, resample_by_arc_length
from plm_highway.metrics.steering import common_span
from plm_highway.metrics.steering import steering_errors as kit_steering_errors
from plm_highway.road.track import load_track
from plm_highway.rollout.closed_loop import drive
from plm_highway.rollout.policies import make_policy

TABLE_3_LATENCY = "const:0.2"
TRAP_LATENCY = "const:0.25"  # where PLM-Net's steering follows the reference's and its car still drifts
RUNS = ("reference", "baseline", "mitigated")
LESSON_SPACING_M = 1.0  # the lesson resamples every 1 m so that a pure-Python Frechet stays quick


def _random_curves(seed: int, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t_p, t_q = np.sort(rng.uniform(0, 10, n)), np.sort(rng.uniform(0, 10, m))
    return (np.column_stack([t_p, np.sin(t_p) + rng.normal(0, 0.1, n)]),
            np.column_stack([t_q, np.sin(t_q) + 0.3 + rng.normal(0, 0.1, m)]))


def _errors(steering_errors, reference, other, what: str) -> dict:
    result = call_student(steering_errors, reference, other, what=what, exercise="lesson3.steering_errors")
    expect_true(isinstance(result, dict) and {"mae", "mse", "rmse"} <= set(result), f"what {what} returned",
                expected="a dict with keys 'mae', 'mse', 'rmse'", received=repr(result)[:80])
    return result


@graded(points=2)
def check_steering_errors(steering_errors, seed: int | None = None) -> None:
    """MAE, MSE and RMSE of one steering series against another, over their common length."""
    if seed is not None:

        def kit_errors(reference, other):  # the lesson's rule: over the steps both runs reached
            return kit_steering_errors(*common_span(reference, other))

        rng = np.random.default_rng(seed)
        for _ in range(5):
            reference = rng.uniform(-1, 1, int(rng.integers(5, 400)))
            n_other = int(rng.integers(3, len(reference) + 40))  # a run may also be longer than the reference
            other = np.resize(reference, n_other) + rng.normal(0.05, 0.2) * rng.random() + rng.normal(0, 0.1, n_other)
            expected = kit_errors(reference, other)
            result = _errors(steering_errors, reference, other,
                             f"steering_errors on {len(reference)} and {len(other)} random steps")
            for metric in ("mae", "mse", "rmse"):
                expect_close(f"{metric.upper()} on {len(reference)} and {len(other)} random steps", expected[metric],
                             result[metric], atol=1e-12)
        return
    reference = np.array([0.0, 0.1, -0.2, 0.3])
    other = np.array([0.1, 0.1, 0.0, -0.1])
    result = _errors(steering_errors, reference, other, "steering_errors([0, 0.1, -0.2, 0.3], [0.1, 0.1, 0, -0.1])")
    # differences 0.1, 0, 0.2, -0.4: MAE = 0.7 / 4, MSE = (0.01 + 0.04 + 0.16) / 4, RMSE = sqrt(MSE)
    expect_close("MAE", 0.175, result["mae"], atol=1e-12, hint="mean of |other - reference|")
    expect_close("MSE", 0.0525, result["mse"], atol=1e-12, hint="mean of (other - reference)^2")
    expect_close("RMSE", np.sqrt(0.0525), result["rmse"], atol=1e-12, hint="square root of the MSE")
    same = _errors(steering_errors, reference, reference, "steering_errors(reference, reference)")
    expect_close("MAE of a series against itself", 0.0, same["mae"], atol=0)
    short = _errors(steering_errors, np.array([0.0, 0.1, 0.2, 0.3, 0.4]), np.array([0.5, 0.1, 0.2]),
                    "steering_errors([0, 0.1, 0.2, 0.3, 0.4], [0.5, 0.1, 0.2])")
    expect_close("MAE when the other run is shorter (it left the road)", 0.5 / 3, short["mae"], atol=1e-12,
                 hint="compare over the common length: the first min(len(reference), len(other)) steps")


@graded(points=1)
def check_reduction(reduction_pct, seed: int | None = None) -> None:
    """PLM-Net's error reduction against the baseline's, in %."""
    cases = [((0.1915, 0.0726), 100 * (1 - 0.0726 / 0.1915), "the paper's Table 3 MAE: 62.1%"),
             ((0.2, 0.2), 0.0, "equal errors"), ((0.1, 0.2), -100.0, "a mitigation that doubles the error"),
             ((0.0, 0.0), 0.0, "a zero baseline error: define the reduction as 0")]
    if seed is not None:
        rng = np.random.default_rng(seed)
        pairs = [(float(b), float(m)) for b, m in rng.uniform(0.001, 0.5, (8, 2))] + [(0.0, float(rng.random()))]
        cases = [((b, m), 100 * (1 - m / b) if b > 0 else 0.0, "random errors") for b, m in pairs]
    for (baseline, mitigated), expected, what in cases:
        received = call_student(reduction_pct, baseline, mitigated, what=f"reduction_pct({baseline}, {mitigated})",
                                exercise="lesson3.reduction_pct")
        expect_close(f"reduction_pct({baseline}, {mitigated}) ({what})", expected, received, atol=1e-9,
                     hint="100 * (1 - mitigated / baseline), and 0.0 when the baseline error is 0")


@graded(points=3)
def check_frechet(discrete_frechet, seed: int | None = None) -> None:
    """The discrete Frechet distance, by hand on small curves and against the kit's on random ones."""
    if seed is not None:
        rng = np.random.default_rng(seed)
        for _ in range(4):
            n, m = (int(v) for v in rng.integers(2, 45, 2))
            p, q = _random_curves(int(rng.integers(1_000_000)), n, m)
            q = q if rng.random() < 0.5 else q[::-1]
            expected = frechet_dist(p, q)
            received = call_student(discrete_frechet, p, q, what=f"discrete_frechet on random curves of {n} and "
                                    f"{m} points", exercise="lesson3.discrete_frechet")
            expect_close(f"Frechet distance of random curves with {n} and {m} points", expected, received, atol=1e-9)
        return

    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    cases = [
        (line, line, 0.0, "a curve against itself"),
        (line, line + [0.0, 0.3], 0.3, "a copy 0.3 m to the side"),
        (line, line[::-1], 2.0, "the same points in reverse order (the ends must be coupled)"),
        (line[[0, 2]], np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]]), np.sqrt(2.0),
         "a detour: (1, 1) is sqrt(2) from both ends of the other curve"),
        (line[:1], np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 0.0]]), 3.0,
         "one point against a curve that goes 3 m away and back (the leash must reach every point)"),
        (np.array([[0.0, 0.0], [0.0, 3.0], [0.0, 0.0]]), line[:1], 3.0, "the same with the curves swapped"),
    ]
    for p, q, expected, what in cases:
        received = call_student(discrete_frechet, p, q, what=f"discrete_frechet for {what}",
                                exercise="lesson3.discrete_frechet")
        expect_close(f"Frechet distance for {what}", expected, received, atol=1e-12,
                     hint="dynamic programming: ca[i, j] = max(d(p_i, q_j), min(ca[i-1, j], ca[i, j-1], ca[i-1, j-1]))")
    for seed, (n, m) in enumerate([(7, 7), (12, 30), (40, 9)]):
        p, q = _random_curves(seed, n, m)
        expected = frechet_dist(p, q)
        received = call_student(discrete_frechet, p, q, what=f"discrete_frechet on random curves of {n} and {m} "
                                "points", exercise="lesson3.discrete_frechet")
        expect_close(f"Frechet distance of random curves with {n} and {m} points", expected, received,
                     atol=1e-9, hint="the first row and column can only be reached along the row / column")


def _resample(resample, xy, spacing_m, what: str):
    return call_student(resample, xy, spacing_m, what=what, exercise="lesson3.resample")


@graded(points=2)
def check_resample(resample, seed: int | None = None) -> None:
    """Arc-length resampling: a point every ``spacing_m`` along the polyline, plus its end."""
    if seed is not None:
        rng = np.random.default_rng(seed)
        for _ in range(4):
            xy, _ = _random_curves(int(rng.integers(1_000_000)), int(rng.integers(2, 40)), 2)
            xy = np.repeat(xy, rng.integers(1, 3, len(xy)), axis=0)  # some points repeated
            spacing_m = float(rng.choice([0.25, 0.5, 0.9, 1.3]))
            expected = resample_by_arc_length(xy, spacing_m)
            expect_close(f"resample(random curve of {len(xy)} points, {spacing_m})", expected,
                         _resample(resample, xy, spacing_m, f"resample(random curve of {len(xy)} points, {spacing_m})"),
                         atol=1e-9)
        return

    corner = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    expected = [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.0, 0.5], [1.0, 1.0]]
    expect_close("resample([[0, 0], [1, 0], [1, 1]], 0.5)", expected,
                 _resample(resample, corner, 0.5, "resample([[0, 0], [1, 0], [1, 1]], 0.5)"),
                 atol=1e-12, hint="walk along the polyline: the corner is 1 m from the start")
    segment = np.array([[0.0, 0.0], [1.0, 0.0]])
    expect_close("resample(a 1 m segment, 0.4)", [[0.0, 0.0], [0.4, 0.0], [0.8, 0.0], [1.0, 0.0]],
                 _resample(resample, segment, 0.4, "resample([[0, 0], [1, 0]], 0.4)"), atol=1e-12,
                 hint="keep the last point even when the last gap is shorter than the spacing")
    short = np.array([[0.0, 0.0], [0.9, 0.0]])
    expect_close("resample([[0, 0], [0.9, 0]], 0.3)", [[0.0, 0.0], [0.3, 0.0], [0.6, 0.0], [0.9, 0.0]],
                 _resample(resample, short, 0.3, "resample([[0, 0], [0.9, 0]], 0.3)"), atol=1e-12,
                 hint="0.9 / 0.3 is 3.0000000000000004 in floating point: a last station within rounding of the end "
                      "IS the end (no extra point)")
    repeated = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    expect_close("resample with a repeated point", [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]],
                 _resample(resample, repeated, 1.0, "resample([[0, 0], [1, 0], [1, 0], [2, 0]], 1.0)"), atol=1e-12,
                 hint="drop points that repeat the previous one before interpolating (np.interp needs increasing x)")
    for seed in range(3):
        xy, _ = _random_curves(seed, 25, 2)
        spacing_m = (0.3, 0.7, 1.1)[seed]
        expected = resample_by_arc_length(xy, spacing_m)
        expect_close(f"resample(random curve {seed}, {spacing_m})", expected,
                     _resample(resample, xy, spacing_m, f"resample(random curve {seed}, {spacing_m})"), atol=1e-9,
                     hint="np.interp of each coordinate against the cumulative arc length")


@functools.lru_cache(maxsize=8)
def kit_table_3_runs(max_steps: int | None, checkpoints: str | None, latency: str = TABLE_3_LATENCY) -> dict:
    """The three runs of Table 3 driven by the kit (what a correct ``drive_table_3`` returns)."""
    return {
        "reference": drive("reference", make_policy("bm", checkpoints), "test", "const:0", 0, max_steps=max_steps),
        "baseline": drive("baseline", make_policy("bm", checkpoints), "test", latency, 0, max_steps=max_steps),
        "mitigated": drive("mitigated", make_policy("plm", checkpoints), "test", latency, 0, max_steps=max_steps),
    }


@graded(points=3)
def check_table_3(drive_table_3, steering_errors, reduction_pct, max_steps=None, checkpoints=None) -> dict:
    """The student's three runs are the paper's (BM without latency, BM and PLM-Net with 0.2 s, one
    seed) and their Table 3 numbers equal the kit's. Returns the student's runs."""
    logs = call_student(drive_table_3, TABLE_3_LATENCY, max_steps=max_steps, checkpoints=checkpoints,
                        what=f"drive_table_3({TABLE_3_LATENCY!r}, max_steps={max_steps})",
                        exercise="lesson3.drive_table_3")
    expect_true(isinstance(logs, dict) and set(logs) == set(RUNS), "what drive_table_3 returned",
                expected="{'reference': RunLog, 'baseline': RunLog, 'mitigated': RunLog}",
                received=sorted(logs) if isinstance(logs, dict) else type(logs).__name__)
    expected = kit_table_3_runs(max_steps, None if checkpoints is None else str(checkpoints))
    hints = {"reference": "the Base Model ('bm') with latency 'const:0'",
             "baseline": f"the Base Model ('bm') with latency {TABLE_3_LATENCY!r}",
             "mitigated": f"PLM-Net ('plm') with latency {TABLE_3_LATENCY!r}"}
    for name in RUNS:
        theirs, ours = logs[name].columns["steering"], expected[name].columns["steering"]
        expect_true(len(theirs) == len(ours), f"number of steps of the {name!r} run", expected=len(ours),
                    received=len(theirs), hint=f"{hints[name]}, seed 0, track 'test', the same max_steps for every run")
        expect_close(f"steering of the {name!r} run", ours, theirs, atol=1e-6,
                     hint=f"{hints[name]}, seed 0, track 'test', the same max_steps for every run")
    kit = steering_comparison(logs)
    reference = logs["reference"].columns["steering"]
    for run in ("baseline", "mitigated"):
        errors = _errors(steering_errors, reference, logs[run].columns["steering"],
                         f"steering_errors(reference run, {run} run)")
        for metric in ("mae", "mse", "rmse"):
            expect_close(f"{metric.upper()} of the {run} run", kit[run][metric], errors[metric], atol=1e-9)
    received = call_student(reduction_pct, kit["baseline"]["mae"], kit["mitigated"]["mae"],
                            what="reduction_pct(baseline MAE, mitigated MAE)", exercise="lesson3.reduction_pct")
    expect_close("MAE reduction", kit["mae_reduction_pct"], received, atol=1e-9)
    return logs


@graded(points=2)
def check_trajectory_frechet(discrete_frechet, resample, max_steps=None, checkpoints=None) -> dict:
    """Each Table 3 run's Frechet distance to the lane centre, both curves resampled every 1 m,
    equals the kit's. Returns {run: Frechet distance in m}."""
    _resample(resample, np.array([[0.0, 0.0], [1.0, 0.0]]), 0.5, "resample([[0, 0], [1, 0]], 0.5)")
    call_student(discrete_frechet, np.zeros((2, 2)), np.ones((2, 2)), what="discrete_frechet(zeros, ones)",
                 exercise="lesson3.discrete_frechet")
    logs = kit_table_3_runs(max_steps, None if checkpoints is None else str(checkpoints))
    centre = LaneCentre(load_track("test"))
    values = {}
    for name in RUNS:
        c = logs[name].columns
        path = np.column_stack([c["x_m"], c["y_m"]])
        lane = centre.between(float(c["arc_length_m"].min()), float(c["arc_length_m"].max()))
        lane_points, path_points = (resample_by_arc_length(xy, LESSON_SPACING_M) for xy in (lane, path))
        expected = frechet_dist(lane_points, path_points)
        their_path = _resample(resample, path, LESSON_SPACING_M, f"resample({name} path, 1)")
        expect_close(f"the {name!r} path resampled every 1 m", path_points, their_path, atol=1e-9,
                     hint="a point every metre along the path from its start, plus its end")
        received = call_student(discrete_frechet, _resample(resample, lane, LESSON_SPACING_M, "resample(lane centre, 1)"),
                                their_path, what=f"discrete_frechet of the resampled lane centre and {name} path",
                                exercise="lesson3.discrete_frechet")
        expect_close(f"Frechet distance of the {name!r} run to the lane centre [m]", expected, received, atol=1e-9,
                     hint="resample the lane centre and the path with the same spacing, lane centre first")
        values[name] = float(received)
    return values


# --- The trap at 0.25 s: steering error against lane keeping -------------------------------------------------


def _lane(lane_keeping, offset_m, what: str) -> dict:
    result = call_student(lane_keeping, offset_m, what=what, exercise="lesson3.lane_keeping")
    expect_true(isinstance(result, dict) and {"rms_m", "max_m"} <= set(result), f"what {what} returned",
                expected="a dict with keys 'rms_m', 'max_m'", received=repr(result)[:80])
    return result


def _expected_lane(offset_m) -> dict:
    offset_m = np.asarray(offset_m, dtype=float)
    return {"rms_m": float(np.sqrt(np.mean(offset_m ** 2))), "max_m": float(np.max(np.abs(offset_m)))}


@graded(points=1)
def check_lane_keeping(lane_keeping, seed: int | None = None) -> None:
    """RMS and largest magnitude of a lateral-offset series."""
    cases = [(np.array([0.3, -0.4]), "[0.3, -0.4]"),
             (np.full(10, 0.5), "a car 0.5 m left of the centre all the time (a drift, not a weave)"),
             (np.array([0.1, -1.2, 0.4, 0.0]), "[0.1, -1.2, 0.4, 0] (the largest offset is to the right)")]
    if seed is not None:
        rng = np.random.default_rng(seed)
        cases = [(rng.normal(rng.normal(0, 0.5), rng.uniform(0.05, 1.0), int(rng.integers(1, 500))),
                  "random offsets") for _ in range(6)]
    hints = {"rms_m": "sqrt(mean(offset ** 2)): a constant offset counts in full, it is not removed like a mean",
             "max_m": "the largest |offset|: to the right (negative) counts as much as to the left"}
    for offset_m, what in cases:
        result = _lane(lane_keeping, offset_m, f"lane_keeping({what})")
        expected = _expected_lane(offset_m)
        for key in ("rms_m", "max_m"):
            expect_close(f"{key} of {what} ({len(offset_m)} steps)", expected[key], result[key], atol=1e-12,
                         hint=hints[key])


@graded(points=2)
def check_trap_table(drive_table_3, trap_table, max_steps=None, checkpoints=None) -> dict:
    """The student's runs at 0.25 s are the kit's, and their table (steering MAE and its reduction, offset RMS and
    largest offset of each run, the offset RMS reduction) equals what the kit's runs give. Returns the runs."""
    logs = call_student(drive_table_3, TRAP_LATENCY, max_steps=max_steps, checkpoints=checkpoints,
                        what=f"drive_table_3({TRAP_LATENCY!r}, max_steps={max_steps})",
                        exercise="lesson3.drive_table_3")
    expect_true(isinstance(logs, dict) and set(logs) == set(RUNS), "what drive_table_3 returned",
                expected="{'reference': RunLog, 'baseline': RunLog, 'mitigated': RunLog}",
                received=sorted(logs) if isinstance(logs, dict) else type(logs).__name__)
    kit = kit_table_3_runs(max_steps, None if checkpoints is None else str(checkpoints), TRAP_LATENCY)
    for name in RUNS:
        expect_close(f"steering of the {name!r} run at {TRAP_LATENCY}", kit[name].columns["steering"],
                     logs[name].columns["steering"], atol=1e-6,
                     hint="pass the latency on to the baseline and the mitigated run")
    table = call_student(trap_table, kit, what="trap_table(runs at 0.25 s)", exercise="lesson3.trap_table")
    keys = {"mae", "mae_reduction_pct", "offset_rms_m", "offset_max_m", "offset_rms_reduction_pct"}
    expect_true(isinstance(table, dict) and keys <= set(table), "what trap_table returned",
                expected=f"a dict with keys {sorted(keys)}", received=repr(table)[:80])

    reference = kit["reference"].columns["steering"]
    mae = {run: kit_steering_errors(*common_span(reference, kit[run].columns["steering"]))["mae"]
           for run in ("baseline", "mitigated")}
    lane = {run: _expected_lane(kit[run].columns["lateral_offset_m"]) for run in RUNS}
    for run in ("baseline", "mitigated"):
        expect_close(f"table['mae'][{run!r}]", mae[run], table["mae"][run], atol=1e-9,
                     hint="your steering_errors of the reference run and this run")
    expect_close("table['mae_reduction_pct']", 100 * (1 - mae["mitigated"] / mae["baseline"]),
                 table["mae_reduction_pct"], atol=1e-9, hint="your reduction_pct of the two MAEs")
    for run in RUNS:
        for key, column in (("rms_m", "offset_rms_m"), ("max_m", "offset_max_m")):
            expect_close(f"table[{column!r}][{run!r}]", lane[run][key], table[column][run], atol=1e-9,
                         hint="your lane_keeping of the run's 'lateral_offset_m' column, over every step it drove")
    expect_close("table['offset_rms_reduction_pct']",
                 100 * (1 - lane["mitigated"]["rms_m"] / lane["baseline"]["rms_m"]),
                 table["offset_rms_reduction_pct"], atol=1e-9,
                 hint="your reduction_pct of the baseline's and the mitigated run's offset RMS")
    return logs


# Feedback gains measured by posing the car on the test track's longest straight (ideal conditions, the shipped
# pair): normalised steering per metre of offset and per radian of heading error.
SHIPPED_GAINS = {"bm": {"offset_gain_per_m": -0.934, "heading_gain_per_rad": -5.48},
                 "plm@0.25": {"offset_gain_per_m": 0.0106, "heading_gain_per_rad": -1.67}}


def _gains(bm: tuple[float, float], plm: dict[float, tuple[float, float]]) -> dict:
    gains = {"bm": {"offset_gain_per_m": bm[0], "heading_gain_per_rad": bm[1]}}
    for latency_s, (offset, heading) in plm.items():
        gains[f"plm@{latency_s:g}"] = {"offset_gain_per_m": offset, "heading_gain_per_rad": heading}
    return gains


def _share(gains: dict, latency_s: float, key: str) -> float:
    return gains[f"plm@{latency_s:g}"][key] / gains["bm"][key]


@graded(points=2)
def check_weaker_feedback(weaker_feedback, seed: int | None = None) -> None:
    """Which feedback PLM-Net told a latency keeps the smaller share of the BM's: the offset or the heading one."""
    cases = [
        (SHIPPED_GAINS, 0.25, "offset", "the shipped pair's gains (its offset gain even changed sign)"),
        (_gains((-0.9, -5.5), {0.25: (-0.8, -2.0)}), 0.25, "heading",
         "a PLM-Net that keeps 89% of the offset gain and 36% of the heading gain"),
        (_gains((-0.9, -5.5), {0.25: (0.9, -1.5)}), 0.25, "offset",
         "a PLM-Net whose offset gain has the opposite sign (it steers away from the centre)"),
        (_gains((-0.9, -5.5), {0.15: (-0.2, -5.0), 0.3: (-0.85, -1.0)}), 0.3, "heading",
         "gains at 0.15 s and 0.3 s, asked about 0.3 s"),
        (_gains((-0.9, -5.5), {0.15: (-0.2, -5.0), 0.3: (-0.85, -1.0)}), 0.15, "offset",
         "gains at 0.15 s and 0.3 s, asked about 0.15 s"),
    ]
    if seed is not None:
        rng = np.random.default_rng(seed)
        cases = []
        for _ in range(8):
            latencies = [0.1, 0.2, 0.25, 0.3]
            bm = (-rng.uniform(0.2, 2.0), -rng.uniform(2.0, 10.0))
            plm = {lat: (bm[0] * rng.uniform(-0.5, 1.2), bm[1] * rng.uniform(-0.5, 1.2)) for lat in latencies}
            gains, latency_s = _gains(bm, plm), float(rng.choice(latencies))
            shares = {which: _share(gains, latency_s, f"{which}_gain_per_{unit}")
                      for which, unit in (("offset", "m"), ("heading", "rad"))}
            if abs(shares["offset"] - shares["heading"]) < 0.05:
                continue  # too close to call from printed gains
            cases.append((gains, latency_s, min(shares, key=shares.get), f"random gains at {latency_s:g} s"))
    for gains, latency_s, expected, what in cases:
        received = call_student(weaker_feedback, gains, latency_s, what=f"weaker_feedback({what})",
                                exercise="lesson3.weaker_feedback")
        offset = _share(gains, latency_s, "offset_gain_per_m")
        heading = _share(gains, latency_s, "heading_gain_per_rad")
        expect_equal(f"weaker_feedback for {what}: PLM-Net keeps {offset:.2f} of the BM's offset gain and "
                     f"{heading:.2f} of its heading gain", expected, received,
                     hint="compare PLM-Net's gain over the BM's gain (a signed share), not the gains themselves: "
                          "they have different units")


WHY_THE_LANE_DRIFTS = "B"  # the explanation of the options the lesson lists that the posed gains support


@graded(points=1)
def check_why_the_lane_drifts(why_the_lane_drifts) -> None:
    """The student picks the explanation the measurements support."""
    received = call_student(why_the_lane_drifts, what="why_the_lane_drifts()")
    expect_true(isinstance(received, str) and received.strip().upper() in "ABCD" and len(received.strip()) == 1,
                "what why_the_lane_drifts returned", expected="one letter, 'A', 'B', 'C' or 'D'",
                received=repr(received)[:40])
    expect_equal("the explanation the offset traces and the posed gains support", WHY_THE_LANE_DRIFTS,
                 received.strip().upper(),
                 hint="which feedback did your weaker_feedback find PLM-Net weakens, and how does a small steering "
                      "bias that nothing corrects move the car over many seconds?")
