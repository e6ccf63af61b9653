"""Lesson 4 conceals its effect: the seed picks it, no cell before the answer key names it, and the lesson's
own method (fit each hypothesis on training blocks, compare on held-out blocks) can find it."""

from __future__ import annotations

from pathlib import Path

import nbformat
import numpy as np
import pytest

from plm_highway.grading.lesson4 import (
    CONCEALED_EFFECTS,
    SealedAnswer,
    concealed_recording,
    reference_delayed,
    reference_yaw_rate,
)

REPO = Path(__file__).resolve().parents[1]
LESSON = "04_when_the_simulator_lies.ipynb"
FULL_DURATION_S = 120.0  # the lesson's full mode


@pytest.mark.parametrize("folder", ["solutions", "lessons"])
def test_no_cell_before_the_answer_key_names_the_concealed_effect(folder):
    cells = nbformat.read(REPO / folder / LESSON, as_version=4).cells
    key_cell = next(i for i, cell in enumerate(cells) if "answer_key.reveal()" in cell.source)
    for index, cell in enumerate(cells[:key_cell]):
        for name in (*CONCEALED_EFFECTS, "make_recording("):
            assert name not in cell.source, f"{folder}/{LESSON} cell {index} names {name!r} before the answer key"
    assert "concealed_recording(LESSON_SEED" in cells[1].source


def test_the_answer_is_sealed_until_revealed():
    _, answer = concealed_recording(5, duration_s=20.0)
    assert isinstance(answer, SealedAnswer)
    assert not any(name in repr(answer) or name in str(answer) for name in CONCEALED_EFFECTS)
    (effect,) = answer.reveal()
    assert effect in CONCEALED_EFFECTS


def test_the_seed_picks_both_effects_and_the_car_does_not_give_them_away():
    picked, geometries = set(), set()
    for seed in range(12):
        recording, answer = concealed_recording(seed, duration_s=20.0)
        (effect, params), = answer.reveal().items()
        picked.add(effect)
        geometries.add((recording.vehicle.cg_to_front_m, recording.vehicle.cg_to_rear_m))
        low, high = CONCEALED_EFFECTS[effect]
        assert low <= next(iter(params.values())) <= high
    assert picked == set(CONCEALED_EFFECTS)
    assert len(geometries) == 1


def _held_out_winner(seed: int, duration_s: float) -> tuple[str, str]:
    recording, answer = concealed_recording(seed, duration_s)
    t, steer, speed, measured = recording.t_s, recording.steer_rad, recording.speed_mps, recording.yaw_rate_radps
    front, rear, dt = recording.vehicle.cg_to_front_m, recording.vehicle.cg_to_rear_m, recording.dt_s
    usable = t > 1.0
    train = usable & (((t - t[0]) // 8.0) % 2 == 0)
    heldout = usable & ~train

    def best(predict, grid):
        errors = [np.sqrt(np.mean((predict(v) - measured)[train] ** 2)) for v in grid]
        prediction = predict(grid[int(np.argmin(errors))])
        return np.sqrt(np.mean((prediction - measured)[heldout] ** 2))

    wheelbase = front + rear
    delay = best(lambda d: reference_delayed(steer, speed, dt, d, front, rear), np.arange(0.0, 0.41, dt))
    understeer = best(lambda k: reference_yaw_rate(steer, speed, front, rear) * wheelbase / (wheelbase + k * speed ** 2),
                      np.linspace(0.0, 0.008, 81))
    (truth,) = answer.reveal()
    return truth, "transport_delay" if delay < understeer else "tire_slip"


@pytest.mark.parametrize("seed", [2024, *range(12)])
def test_the_lessons_method_finds_the_concealed_effect_in_full_mode(seed):
    truth, winner = _held_out_winner(seed, FULL_DURATION_S)
    assert winner == truth
