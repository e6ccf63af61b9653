"""Lesson 4's graded checks: pass on correct answers, fail on the generator's stubs and on typical mistakes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d

from plm_highway.grading import lesson4
from plm_highway.grading.checks import CheckFailed

# Correct answers written as a student would, without the kit's own implementations (the checks
# switch those off while they run, so calling them is caught as delegation).


def replay(steer, speed, front, rear):
    slip = np.arctan(rear / (front + rear) * np.tan(np.asarray(steer, float)))
    return np.asarray(speed, float) * np.sin(slip) / rear


def windows(t_s, residual, noise_sigma, window_s=1.0, factor=2.0):
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    rms = np.sqrt(uniform_filter1d(np.asarray(residual, float) ** 2, max(1, round(window_s / dt))))
    above = np.concatenate([[False], rms > factor * noise_sigma, [False]])
    edges = np.flatnonzero(np.diff(above.astype(int)))
    return [[float(t_s[s]), float(t_s[e - 1])] for s, e in zip(edges[::2], edges[1::2])]


def delayed(steer, speed, dt, delay, front, rear):
    n = round(delay / dt)
    return replay(np.concatenate([np.full(n, steer[0]), steer[: len(steer) - n]]), speed, front, rear)


def understeer(steer, speed, k, front, rear):
    return replay(steer, speed, front, rear) * (front + rear) / (front + rear + k * speed**2)


def fit_on_grid(predict, grid, measured, train):
    errors = [np.sqrt(np.mean((predict(v)[train] - measured[train]) ** 2)) for v in grid]
    return float(grid[int(np.argmin(errors))]), float(min(errors))


CORRECT = {
    "check_replay": replay,
    "check_windows": windows,
    "check_delay_model": delayed,
    "check_understeer_model": understeer,
    "check_fit_on_grid": fit_on_grid,
}


def _stub(*args, **kwargs):
    raise NotImplementedError("your code here")


@pytest.mark.parametrize("check", sorted(CORRECT))
def test_check_passes_on_a_correct_answer(check, capsys):
    getattr(lesson4, check)(CORRECT[check])
    assert f"PASSED {check}" in capsys.readouterr().out


@pytest.mark.parametrize("check", sorted(CORRECT))
def test_check_fails_on_the_stub_with_not_implemented_yet(check):
    with pytest.raises(AssertionError, match="not implemented yet"):
        getattr(lesson4, check)(_stub)


def _kinematic_small_angle(steer, speed, front, rear):
    return speed * steer / (front + rear)


def _delay_wrapping_around(steer, speed, dt, delay, front, rear):
    return replay(np.roll(steer, round(delay / dt)), speed, front, rear)


def _fit_on_everything(predict, grid, measured, train):
    errors = [np.sqrt(np.mean((predict(v) - measured) ** 2)) for v in grid]
    return float(grid[int(np.argmin(errors))]), float(min(errors))


def _windows_of_single_samples(t_s, residual, noise_sigma, window_s=1.0, factor=2.0):
    above = np.abs(residual) > factor * noise_sigma
    return [[float(t), float(t)] for t in t_s[above]]


@pytest.mark.parametrize("check, wrong, hint", [
    ("check_replay", _kinematic_small_angle, "beta = arctan"),
    ("check_delay_model", _delay_wrapping_around, "repeat steer[0]"),
    ("check_fit_on_grid", _fit_on_everything, "measured[train] only"),
    ("check_windows", _windows_of_single_samples, "running RMS"),
])
def test_check_explains_a_typical_mistake(check, wrong, hint):
    with pytest.raises(CheckFailed) as failure:
        getattr(lesson4, check)(wrong)
    message = str(failure.value)
    assert "expected" in message and hint in message, message
