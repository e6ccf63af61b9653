"""Graded checks for Lesson 4, "When the simulator lies", and the lesson's concealed recording.

Each check calls the student's function on small seeded inputs, compares with the reference
(the kit's own model functions, computed before the student's code runs) within a tolerance, and
explains a failure: what was expected, what came back and a hint. A ``seed`` (nbgrader's hidden
tests) draws further inputs.

:func:`concealed_recording` makes the lesson's "real" car: the seed picks which effect the
simulator leaves out and how strong it is, so no cell before the answer key names it.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, graded
from plm_highway.sim2real.physics.synth import make_recording
from plm_highway.vehicle.kinematic import KinematicBicycleParams, kinematic_bicycle_rates

GEOMETRIES = ((2.5, 2.5), (1.35, 1.45))  # (cg_to_front_m, cg_to_rear_m): the simulator's car, a sedan

# What the lesson's recording may hide, and the range its size is drawn from. Both are driven by the same
# dynamic single-track car (so the geometry printed by the lesson gives nothing away); both are cases the
# lesson's two hypotheses can tell apart on held-out data (tests/test_lessons_lesson4.py checks it).
CONCEALED_EFFECTS = {
    "tire_slip": (0.003, 0.0045),  # understeer gradient [rad per m/s^2]: a soft front axle
    "transport_delay": (0.18, 0.3),  # delay [s] between the logged command and the wheels
}


class SealedAnswer:
    """The answer key, printed only when asked: ``answer_key.reveal()``."""

    def __init__(self, truth: dict):
        self._truth = truth

    def reveal(self) -> dict:
        """{effect: {parameter: value}}, values to four significant digits."""
        return {effect: {name: float(f"{value:.4g}") for name, value in params.items()}
                for effect, params in self._truth["effects"].items()}

    def __repr__(self) -> str:
        return "<answer key, sealed: answer_key.reveal() at the end of the lesson>"


def concealed_recording(seed: int, duration_s: float):
    """The lesson's recording: the seed picks the concealed effect and its size. Returns (Recording, SealedAnswer)."""
    rng = np.random.default_rng(seed)
    names = sorted(CONCEALED_EFFECTS)
    name = names[int(rng.integers(len(names)))]
    low, high = CONCEALED_EFFECTS[name]
    value = round(float(rng.uniform(low, high)), 4 if name == "tire_slip" else 2)
    recording, truth = make_recording({name: value}, rng=rng, duration_s=duration_s, model="single-track")
    # The single-track car's own understeer is listed among the truth's effects too; the lesson asks
    # for the one effect the seed concealed.
    return recording, SealedAnswer({**truth, "effects": {name: truth["effects"][name]}})


def _inputs(seed: int, n: int = 300):
    rng = np.random.default_rng(seed)
    steer = np.cumsum(rng.normal(0.0, 0.01, n))
    steer = np.clip(steer - steer.mean(), -0.35, 0.35)
    speed = rng.uniform(3.0, 35.0) + np.cumsum(rng.normal(0.0, 0.05, n))
    return steer, np.clip(speed, 1.0, 40.0)


def reference_yaw_rate(steer, speed, front, rear):
    return kinematic_bicycle_rates(steer, speed, KinematicBicycleParams(front, rear))[0]


def _array(what: str, value, n: int):
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise CheckFailed(what, f"an array of {n} numbers", repr(value)[:80]) from None
    expect_true(array.shape == (n,), what, "return one value per sample, e.g. with numpy operations on the whole "
                "arrays", expected=f"shape ({n},)", received=f"shape {array.shape}")
    return array


def _geometries(seed: int | None):
    if seed is None:
        return list(enumerate(GEOMETRIES))
    rng = np.random.default_rng(seed)
    return [(int(rng.integers(1000, 2000)), (round(float(rng.uniform(1.0, 2.8)), 2), round(float(rng.uniform(1.0, 2.8)), 2)))
            for _ in range(3)]


@graded(points=2)
def check_replay(replay_yaw_rate, seed: int | None = None) -> None:
    """The simulator's yaw rate: r = v sin(beta) / lr with beta = atan(lr / L tan(delta))."""
    for input_seed, (front, rear) in _geometries(seed):
        steer, speed = _inputs(input_seed)
        expected = reference_yaw_rate(steer, speed, front, rear)
        received = call_student(replay_yaw_rate, steer, speed, front, rear,
                                what=f"replay_yaw_rate(steer, speed, {front}, {rear}) on {len(steer)} samples",
                                exercise="lesson4.replay_yaw_rate")
        received = _array("what replay_yaw_rate returned", received, len(steer))
        expect_close(f"replay_yaw_rate with lf={front}, lr={rear}", expected, received, atol=1e-9,
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


def _burst_residual(rng: np.random.Generator, t: np.ndarray, bursts, spiky: bool = False) -> np.ndarray:
    residual = 0.01 * rng.standard_normal(len(t))
    for start, stop in bursts:
        inside = (t >= start) & (t <= stop)
        if spiky:  # rare large spikes: a running RMS rises above 2 x noise, a running mean of |residual| does not
            residual[inside] += np.where(rng.random(int(inside.sum())) < 0.08, 0.09, 0.0)
        else:
            residual[inside] += 0.08 * np.sin(2 * np.pi * 0.5 * (t[inside] - start) + 0.3)
    return residual


def _windows(mismatch_windows, t, residual, what: str) -> list[list[float]]:
    received = call_student(mismatch_windows, t, residual, 0.01, what=what, exercise="lesson4.mismatch_windows")
    try:
        return [[float(a), float(b)] for a, b in received]
    except (TypeError, ValueError):
        raise CheckFailed(f"what {what} returned", "a list of [t_start, t_end] pairs", repr(received)[:80]) from None


WINDOW_HINT = ("running RMS = sqrt(centred moving average of residual**2 over window_s), as "
               "scipy.ndimage.uniform_filter1d computes it; a window is a contiguous run of samples above "
               "factor * noise_sigma, from its first to its last sample")


@graded(points=2)
def check_windows(mismatch_windows, seed: int | None = None) -> None:
    """Bursts of model error in noise: the same windows as the centred running RMS gives, edges within half a sample."""
    rng = np.random.default_rng(7 if seed is None else seed)
    t = np.arange(0, 60, 0.02)
    cases = [([(10.0, 15.0), (30.0, 33.0)], False), ([(20.0, 26.0)], True)]
    if seed is not None:
        starts = np.sort(rng.choice(np.arange(3, 55), 2, replace=False))
        cases = [([(float(s), float(s) + float(rng.uniform(1.5, 3.0))) for s in starts], bool(rng.random() < 0.5))]
    for bursts, spiky in cases:
        residual = _burst_residual(rng, t, bursts, spiky)
        expected = reference_windows(t, residual, 0.01)
        what = f"mismatch_windows on 60 s of noise with {'spiky' if spiky else 'smooth'} error bursts at {bursts} s"
        received = _windows(mismatch_windows, t, residual, what)
        expect_true(len(received) == len(expected), f"number of windows from {what}", WINDOW_HINT,
                    expected=f"{len(expected)}: {[[round(a, 2), round(b, 2)] for a, b in expected]}",
                    received=f"{len(received)}: {[[round(a, 2), round(b, 2)] for a, b in received][:4]}")
        expect_close(f"window edges [s] from {what}", expected, received, atol=0.01, hint=WINDOW_HINT)
    quiet = _windows(mismatch_windows, t, 0.01 * rng.standard_normal(len(t)), "mismatch_windows on pure noise")
    expect_true(len(quiet) == 0, "mismatch_windows on pure noise at the noise level", expected="no window",
                received=f"{len(quiet)} windows", hint="compare the running RMS (not single samples) with factor * "
                "noise_sigma")


def reference_delayed(steer, speed, dt_s, delay_s, front, rear):
    shift = round(delay_s / dt_s)
    delayed = np.concatenate([np.full(shift, steer[0]), steer[: len(steer) - shift]]) if shift else steer
    return reference_yaw_rate(delayed, speed, front, rear)


@graded(points=2)
def check_delay_model(delayed_yaw_rate, seed: int | None = None) -> None:
    """Hypothesis 1: the simulator fed the steering ``delay_s`` late (whole samples, first value held)."""
    steer, speed = _inputs(11 if seed is None else seed)
    dt = 0.02
    cases = ((0.0, GEOMETRIES[0]), (0.2, GEOMETRIES[1]), (0.13, GEOMETRIES[0]), (0.07, GEOMETRIES[1]))
    if seed is not None:
        rng = np.random.default_rng(seed)
        cases = tuple((round(float(rng.uniform(0, 0.4)), 2), GEOMETRIES[int(rng.integers(2))]) for _ in range(4))
    for delay_s, (front, rear) in cases:
        expected = reference_delayed(steer, speed, dt, delay_s, front, rear)
        received = call_student(delayed_yaw_rate, steer, speed, dt, delay_s, front, rear,
                                what=f"delayed_yaw_rate(steer, speed, {dt}, {delay_s}, {front}, {rear})",
                                exercise="lesson4.delayed_yaw_rate")
        received = _array("what delayed_yaw_rate returned", received, len(steer))
        expect_close(f"delayed_yaw_rate with delay {delay_s} s (dt {dt} s)", expected, received, atol=1e-9,
                     hint="shift the steering by round(delay_s / dt_s) samples, repeat steer[0] at the start, "
                          "keep the speed as recorded, then replay")


@graded(points=2)
def check_understeer_model(understeer_yaw_rate, seed: int | None = None) -> None:
    """Hypothesis 2: steady-state understeer scales the simulator's yaw rate by L / (L + K v^2)."""
    steer, speed = _inputs(12 if seed is None else seed)
    cases = ((0.0, GEOMETRIES[0]), (0.004, GEOMETRIES[1]), (0.0015, GEOMETRIES[0]))
    if seed is not None:
        rng = np.random.default_rng(seed)
        cases = tuple((float(rng.uniform(0, 0.01)), GEOMETRIES[int(rng.integers(2))]) for _ in range(3))
    for k, (front, rear) in cases:
        expected = reference_yaw_rate(steer, speed, front, rear) * (front + rear) / (front + rear + k * speed**2)
        received = call_student(understeer_yaw_rate, steer, speed, k, front, rear,
                                what=f"understeer_yaw_rate(steer, speed, {k:g}, {front}, {rear})",
                                exercise="lesson4.understeer_yaw_rate")
        received = _array("what understeer_yaw_rate returned", received, len(steer))
        expect_close(f"understeer_yaw_rate with K = {k}", expected, received, atol=1e-9,
                     hint="multiply the replayed yaw rate by L / (L + K * speed**2), with L = lf + lr; "
                          "K = 0 must give the simulator back")


@graded(points=2)
def check_fit_on_grid(fit_on_grid, seed: int | None = None) -> None:
    """The grid value with the least RMSE on the *train* samples only, and that RMSE."""
    rng = np.random.default_rng(13 if seed is None else seed)
    x = rng.normal(0.0, 1.0, 400)
    train = np.arange(400) % 80 < 40
    slope_train, slope_held = (3.0, 1.0) if seed is None else tuple(np.round(rng.uniform(0.5, 4.5, 2), 1))
    measured = np.where(train, slope_train * x, slope_held * x) + 0.05 * rng.standard_normal(400)
    grid = np.linspace(0.0, 5.0, 51)

    def predict(slope):
        return slope * x

    errors = [np.sqrt(np.mean((predict(v)[train] - measured[train]) ** 2)) for v in grid]
    best = int(np.argmin(errors))
    received = call_student(fit_on_grid, predict, grid, measured, train,
                            what="fit_on_grid(slope -> slope * x, 51 slopes from 0 to 5, measured, train)",
                            exercise="lesson4.fit_on_grid")
    expect_true(isinstance(received, tuple) and len(received) == 2, "what fit_on_grid returned",
                expected="(best_value, train_rmse)", received=repr(received)[:80])
    value, rmse = received
    expect_close("best grid value", grid[best], value, atol=1e-12,
                 hint="score every grid value on measured[train] only: the held-out samples follow another "
                      "slope here, and fitting on them is cheating")
    expect_close("train RMSE at the best value", errors[best], rmse, atol=1e-9,
                 hint="sqrt(mean((predict(value)[train] - measured[train]) ** 2))")
