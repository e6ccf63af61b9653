"""Graded checks for Lesson 4, "When the simulator lies".

Each check calls the student's function on small seeded inputs, compares with the reference
(the kit's own model functions) within a tolerance, and explains a failure: what was expected,
what came back and a hint. A function that still raises ``NotImplementedError`` fails with
"not implemented yet".
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, graded
from plm_highway.vehicle.kinematic import KinematicBicycleParams, kinematic_bicycle_rates

GEOMETRIES = ((2.5, 2.5), (1.35, 1.45))  # (cg_to_front_m, cg_to_rear_m): the simulator's car, a sedan


def _inputs(seed: int, n: int = 300):
    rng = np.random.default_rng(seed)
    steer = np.cumsum(rng.normal(0.0, 0.01, n))
    steer = np.clip(steer - steer.mean(), -0.35, 0.35)
    speed = rng.uniform(3.0, 35.0) + np.cumsum(rng.normal(0.0, 0.05, n))
    return steer, np.clip(speed, 1.0, 40.0)


def _reference_yaw_rate(steer, speed, front, rear):
    return kinematic_bicycle_rates(steer, speed, KinematicBicycleParams(front, rear))[0]


def _array(what: str, value, n: int):
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise CheckFailed(f"{what}: expected an array of {n} numbers, received {value!r}") from None
    expect_true(array.shape == (n,), f"{what}: expected an array of shape ({n},), received shape {array.shape}",
                hint="return one value per sample, e.g. with numpy operations on the whole arrays")
    return array


@graded(points=2)
def check_replay(replay_yaw_rate) -> None:
    """The simulator's yaw rate: r = v sin(beta) / lr with beta = atan(lr / L tan(delta))."""
    for seed, (front, rear) in enumerate(GEOMETRIES):
        steer, speed = _inputs(seed)
        received = call_student(replay_yaw_rate, steer, speed, front, rear, what="replay_yaw_rate")
        received = _array("replay_yaw_rate", received, len(steer))
        expect_close(f"replay_yaw_rate with lf={front}, lr={rear}", _reference_yaw_rate(steer, speed, front, rear),
                     received, atol=1e-9,
                     hint="beta = arctan(lr / (lf + lr) * tan(steer)); yaw rate = speed * sin(beta) / lr "
                          "(highway-env's Vehicle.step, with its LENGTH / 2 = lr)")


def reference_windows(t_s, residual, noise_sigma, window_s=1.0, factor=2.0) -> list[list[float]]:
    """Contiguous stretches where the centred running RMS over ``window_s`` exceeds factor x noise."""
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    size = max(1, round(window_s / dt))
    rms = np.sqrt(uniform_filter1d(np.asarray(residual, float) ** 2, size))
    above = np.concatenate([[False], rms > factor * noise_sigma, [False]])
    edges = np.flatnonzero(np.diff(above.astype(int)))
    return [[float(t_s[s]), float(t_s[e - 1])] for s, e in zip(edges[::2], edges[1::2])]


@graded(points=2)
def check_windows(mismatch_windows) -> None:
    """Two bursts of model error in noise: exactly two windows, edges within 0.6 s."""
    rng = np.random.default_rng(7)
    t = np.arange(0, 60, 0.02)
    residual = 0.01 * rng.standard_normal(len(t))
    bursts = [(10.0, 15.0), (30.0, 33.0)]
    for start, stop in bursts:
        inside = (t >= start) & (t <= stop)
        residual[inside] += 0.08 * np.sin(2 * np.pi * 0.5 * (t[inside] - start) + 0.3)
    expected = reference_windows(t, residual, 0.01)
    received = call_student(mismatch_windows, t, residual, 0.01, what="mismatch_windows")
    try:
        received = [[float(a), float(b)] for a, b in received]
    except (TypeError, ValueError):
        raise CheckFailed(f"mismatch_windows: expected a list of [t_start, t_end] pairs like {expected}, "
                          f"received {received!r}") from None
    expect_true(len(received) == len(expected),
                f"mismatch_windows: expected {len(expected)} windows {np.round(expected, 2).tolist()}, "
                f"received {len(received)}: {np.round(received, 2).tolist()}",
                hint="running RMS = sqrt(centred moving average of residual**2 over window_s); a window is a "
                     "contiguous run of samples where it exceeds factor * noise_sigma")
    expect_close("window edges [s]", expected, received, atol=0.6,
                 hint="report the times of the first and last sample of each run above the threshold")
    quiet = call_student(mismatch_windows, t, 0.01 * rng.standard_normal(len(t)), 0.01, what="mismatch_windows")
    expect_true(len(list(quiet)) == 0, f"pure noise at the noise level should give no window, received {quiet!r}",
                hint="compare the running RMS (not single samples) with factor * noise_sigma")


def _reference_delayed(steer, speed, dt_s, delay_s, front, rear):
    shift = round(delay_s / dt_s)
    delayed = np.concatenate([np.full(shift, steer[0]), steer[: len(steer) - shift]]) if shift else steer
    return _reference_yaw_rate(delayed, speed, front, rear)


@graded(points=2)
def check_delay_model(delayed_yaw_rate) -> None:
    """Hypothesis 1: the simulator fed the steering ``delay_s`` late (whole samples, first value held)."""
    steer, speed = _inputs(11)
    dt = 0.02
    for delay_s, (front, rear) in ((0.0, GEOMETRIES[0]), (0.2, GEOMETRIES[1]), (0.13, GEOMETRIES[0])):
        received = call_student(delayed_yaw_rate, steer, speed, dt, delay_s, front, rear, what="delayed_yaw_rate")
        received = _array("delayed_yaw_rate", received, len(steer))
        expect_close(f"delayed_yaw_rate with delay {delay_s} s", _reference_delayed(steer, speed, dt, delay_s, front,
                                                                                     rear),
                     received, atol=1e-9,
                     hint="shift the steering by round(delay_s / dt_s) samples, repeat steer[0] at the start, "
                          "keep the speed as recorded, then replay")


@graded(points=2)
def check_understeer_model(understeer_yaw_rate) -> None:
    """Hypothesis 2: steady-state understeer scales the simulator's yaw rate by L / (L + K v^2)."""
    steer, speed = _inputs(12)
    for k, (front, rear) in ((0.0, GEOMETRIES[0]), (0.004, GEOMETRIES[1]), (0.0015, GEOMETRIES[0])):
        expected = _reference_yaw_rate(steer, speed, front, rear) * (front + rear) / (front + rear + k * speed**2)
        received = call_student(understeer_yaw_rate, steer, speed, k, front, rear, what="understeer_yaw_rate")
        received = _array("understeer_yaw_rate", received, len(steer))
        expect_close(f"understeer_yaw_rate with K = {k}", expected, received, atol=1e-9,
                     hint="multiply the replayed yaw rate by L / (L + K * speed**2), with L = lf + lr; "
                          "K = 0 must give the simulator back")


@graded(points=2)
def check_fit_on_grid(fit_on_grid) -> None:
    """The grid value with the least RMSE on the *train* samples only, and that RMSE."""
    rng = np.random.default_rng(13)
    x = rng.normal(0.0, 1.0, 400)
    train = np.arange(400) % 80 < 40
    measured = np.where(train, 3.0 * x, 1.0 * x) + 0.05 * rng.standard_normal(400)
    grid = np.linspace(0.0, 5.0, 51)

    def predict(slope):
        return slope * x

    errors = [np.sqrt(np.mean((predict(v)[train] - measured[train]) ** 2)) for v in grid]
    best = int(np.argmin(errors))
    received = call_student(fit_on_grid, predict, grid, measured, train, what="fit_on_grid")
    expect_true(isinstance(received, tuple) and len(received) == 2,
                f"fit_on_grid must return (best_value, train_rmse), received {received!r}")
    value, rmse = received
    expect_close("best grid value", grid[best], value, atol=1e-12,
                 hint="score every grid value on measured[train] only: the held-out samples follow another "
                      "slope here, and fitting on them is cheating")
    expect_close("train RMSE at the best value", errors[best], rmse, atol=1e-9,
                 hint="sqrt(mean((predict(value)[train] - measured[train]) ** 2))")
