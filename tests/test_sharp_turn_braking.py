"""The original run scripts' speed logic (``config["sharp_turn_braking"]``, ``calibrate --speed-logic``):
full throttle, braking for a fixed time whenever the command is a sharp turn or the car is too fast."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.envs.speed import SharpTurnBraking, parse_sharp_turn_braking
from plm_highway.errors import BadInput
from plm_highway.road.track import load_track
from plm_highway.rollout.conditions import CONDITIONS, scored_steps, top_speed_mps, with_speed_logic

LOGIC = SharpTurnBraking()
STRAIGHT = {"name": "long", "lanes": 3, "lane_width_m": 4.0, "segments": [{"type": "straight", "length_m": 3000}]}
speeds = st.floats(0.0, 40.0, allow_nan=False)
commands = st.floats(-1.0, 1.0, allow_nan=False)
times = st.floats(0.0, 1000.0, allow_nan=False)


def test_original_configuration_values():
    # The original run_neural configuration: max_vel 22, sharp_turn_min 0.25 (x 450 deg of hand wheel), brake 1.7 s,
    # velocity_0 5. 0.25 of 450 deg is 112.5 deg of hand wheel, 9.375 deg at the front wheels at 12:1.
    assert (LOGIC.max_speed_mps, LOGIC.min_speed_mps, LOGIC.brake_hold_s) == (22.0, 5.0, 1.7)
    assert LOGIC.sharp_turn_rad == pytest.approx(math.radians(9.375))


@given(times, st.floats(0.0, 100.0), speeds, commands)
def test_a_brake_already_applied_runs_its_course(time_s, remaining_s, speed_mps, command_rad):
    until_s = time_s + remaining_s + 1e-6
    assert LOGIC.decide(until_s, time_s, speed_mps, command_rad) == until_s


@given(times, speeds, commands)
def test_brakes_exactly_on_a_sharp_turn_or_overspeed_unless_slow(time_s, speed_mps, command_rad):
    until_s = LOGIC.decide(-math.inf, time_s, speed_mps, command_rad)
    should_brake = speed_mps >= 5.0 and (abs(command_rad) > LOGIC.sharp_turn_rad or speed_mps > 22.0)
    assert until_s == (time_s + 1.7 if should_brake else -math.inf)


@given(speeds, st.booleans(), st.floats(1e-3, 1.0))
def test_speed_never_negative_and_moves_the_right_way(speed_mps, braking, dt_s):
    after = LOGIC.speed_after(speed_mps, braking, dt_s)
    assert after >= 0.0
    assert (after <= speed_mps) if braking else (after > speed_mps)


def speeds_under_constant_steering(action: float, steps: int, **logic) -> list[float]:
    env = gymnasium.make(ENV_ID, config={"track": STRAIGHT, "policy_frequency": 10, "simulation_frequency": 10,
                                         "speed_mps": 16.1, "sharp_turn_braking": logic, "max_steering_rad": 0.4})
    _, info = env.reset(seed=0)
    values = [info["speed_mps"]]
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        values.append(info["speed_mps"])
        assert not (terminated or truncated)
    env.close()
    return values


def test_env_accelerates_to_the_limit_then_brakes_for_the_hold():
    # Straight ahead: full throttle 3 m/s^2 from 16.1 m/s (0.3 m/s per 0.1-s step) until above 22 m/s, then 1.7 s
    # (17 steps) of braking at 4 m/s^2 (0.4 m/s per step), then throttle again.
    values = speeds_under_constant_steering(0.0, 45)
    assert values[:3] == pytest.approx([16.1, 16.4, 16.7])
    first_over = next(i for i, v in enumerate(values) if v > 22.0)
    assert (first_over, values[first_over]) == (20, pytest.approx(22.1))
    braking = np.diff(values[first_over:first_over + 18])
    assert braking == pytest.approx([-0.4] * 17)
    assert values[first_over + 18] - values[first_over + 17] == pytest.approx(0.3)


def test_env_brakes_on_a_sharp_command_and_not_on_a_gentle_one():
    # 0.5 of 0.4 rad = 0.2 rad > 0.1636 rad: brakes from the first step; 0.3 of it (0.12 rad) is gentle.
    sharp = speeds_under_constant_steering(0.5, 5)
    gentle = speeds_under_constant_steering(0.3, 5)
    assert np.diff(sharp) == pytest.approx([-0.4] * 5)
    assert np.diff(gentle) == pytest.approx([0.3] * 5)


def test_constant_speed_is_the_default():
    env = gymnasium.make(ENV_ID, config={"track": STRAIGHT, "speed_mps": 16.0})
    env.reset(seed=0)
    for _ in range(20):
        _, _, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    assert info["speed_mps"] == 16.0


@pytest.mark.parametrize(("value", "message"), [
    ("yes", "must be None or a dict"),
    ({"brake_hold": 1.0}, "unknown keys ['brake_hold']"),
    ({"brake_hold_s": -1.0}, "'brake_hold_s'] = -1.0"),
    ({"max_speed_mps": float("nan")}, "'max_speed_mps'] = nan"),
    ({"min_speed_mps": 30.0}, "min_speed_mps 30 must be below max_speed_mps 22"),
])
def test_bad_settings_are_refused_by_name(value, message):
    with pytest.raises(BadInput) as caught:
        parse_sharp_turn_braking(value)
    assert message in str(caught.value)


def test_a_speed_schedule_and_the_braking_logic_are_refused_together():
    with pytest.raises(BadInput, match="needs a constant speed_mps"):
        gymnasium.make(ENV_ID, config={"track": STRAIGHT, "speed_mps": [[0, 10], [5, 20]],
                                       "sharp_turn_braking": {}}).reset(seed=0)


def test_scored_steps_count_on_the_top_speed():
    paper = CONDITIONS["paper"]
    braking = with_speed_logic(paper, "original-braking")
    # 22 m/s plus one 1/30-s step of 3 m/s^2 of throttle
    assert top_speed_mps(braking) == pytest.approx(22.1)
    assert top_speed_mps(paper) == 16.7
    spec = load_track("test")
    # the same scored distance, covered at 22.1 instead of 16.7 m/s per step
    assert scored_steps(spec, braking) == pytest.approx(scored_steps(spec, paper) * 16.7 / 22.1, abs=1.5)
    with pytest.raises(BadInput, match="--speed-logic 'fast'"):
        with_speed_logic(paper, "fast")
