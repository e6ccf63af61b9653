"""The human-like demonstrator: reaction delay, bounded hand, seeded noise, the paper's spread, on the road."""

from __future__ import annotations

import math
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import HUMAN_PARAM_SOURCES, HumanDemonstrator, HumanParams, paper_units
from plm_highway.expert.human import hand_step
from plm_highway.rollout.conditions import CONDITIONS

LOOP_HZ = 30
# The paper's Table 1 (units of 450 deg of steering wheel): std 0.177, quartiles -0.069 and 0.059.
PAPER_STD, PAPER_Q25, PAPER_Q75 = 0.177, -0.069, 0.059
# The band the demonstrator is held to on the whole train track, under the paper conditions' loop, actuator and
# 0.4 rad steering range. Its std reaches only ~0.11 (measured 0.108-0.110 on seeds 1 and 2): the paper's std comes
# from tails down to -1.0 (37.5 deg at the wheels), and a driver stiff or noisy enough to reach 0.177 weaves out of
# its lane (measured at natural frequency 1.9 rad/s with a 0.6 rad/s hand: std 0.19-0.22, lane offsets up to 6 m).
# So the quartiles are matched and the std is held to [0.085, 0.135], i.e. 48-76% of the paper's.
STD_BAND = (0.085, 0.135)
QUARTILE_TOLERANCE = 0.02


def drive_train_track(seed: int, params: HumanParams | None = None):
    env = gymnasium.make(ENV_ID, config={"track": "train", "policy_frequency": LOOP_HZ,
                                         "simulation_frequency": LOOP_HZ,
                                         "steering_time_constant_s": CONDITIONS["paper"].steering_time_constant_s,
                                         "max_steering_rad": CONDITIONS["paper"].max_steering_rad})
    obs, info = env.reset(seed=seed)
    driver = HumanDemonstrator(LOOP_HZ, params or HumanParams(), np.random.default_rng(seed))
    steering, offsets_m, lanes = [], [], []
    terminated = truncated = False
    while not (terminated or truncated):
        action = driver(obs, info)
        steering.append(action)
        offsets_m.append(info["lateral_offset_m"])
        lanes.append(info["lane_index"])
        obs, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
    env.close()
    return np.array(steering), np.array(offsets_m), lanes, terminated, info


@pytest.fixture(scope="module")
def train_runs():
    return [drive_train_track(seed) for seed in (1, 2)]


def test_keeps_the_car_in_its_lane_over_the_whole_train_track(train_runs):
    for _steering, offsets_m, lanes, terminated, info in train_runs:
        assert not terminated and info["completed_fraction"] == 1.0
        assert np.max(np.abs(offsets_m)) < 2.0  # half the 4 m lane: never crosses a marking with its centre
        assert set(lanes) == {1}


def test_steering_spread_matches_the_papers_quartiles_and_the_stated_std_band(train_runs):
    for steering, *_ in train_runs:
        in_paper_units = paper_units(steering, CONDITIONS["paper"].max_steering_rad)
        assert STD_BAND[0] <= in_paper_units.std() <= STD_BAND[1]
        q25, q75 = np.percentile(in_paper_units, [25, 75])
        assert abs(q25 - PAPER_Q25) <= QUARTILE_TOLERANCE and abs(q75 - PAPER_Q75) <= QUARTILE_TOLERANCE
        assert np.max(np.abs(steering)) <= 1.0


def test_it_is_noisier_than_the_expert_and_the_noise_is_what_makes_it_so(train_runs):
    quiet = replace(HumanParams(), offset_noise_m=0.0, heading_noise_rad=0.0, motor_noise_rad=0.0)
    quiet_steering, quiet_offsets_m, *_ = drive_train_track(1, quiet)
    steering, offsets_m, *_ = train_runs[0]
    # Step-to-step jitter and lane wander both come from the noise.
    assert np.std(np.diff(steering)) > 3 * np.std(np.diff(quiet_steering))
    assert np.std(offsets_m) > 2 * np.std(quiet_offsets_m)


def lagged_response(params: HumanParams, n_steps: int = 3000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Open loop: a white, small lateral-offset input on a straight road; returns (input, steering)."""
    rng = np.random.default_rng(seed)
    offsets_m = 0.05 * rng.standard_normal(n_steps)
    driver = HumanDemonstrator(LOOP_HZ, params, np.random.default_rng(seed + 1))
    steering = np.array([driver(None, {"speed_mps": 16.7, "lateral_offset_m": offset, "heading_error_rad": 0.0,
                                       "curvature_1pm": 0.0, "curvature_preview_1pm": 0.0})
                         for offset in offsets_m])
    return offsets_m, steering


def cross_correlation_peak_lag(x: np.ndarray, y: np.ndarray, max_lag: int) -> int:
    """The lag k >= 0 (y later than x) at which |corr(x_t, y_{t+k})| is largest."""
    x, y = x - x.mean(), y - y.mean()
    values = [abs(np.dot(x[:len(x) - k], y[k:])) for k in range(max_lag + 1)]
    return int(np.argmax(values))


@pytest.mark.parametrize("delay_s", [0.1, 0.2, 0.3])
def test_reaction_delay_is_the_peak_of_the_cross_correlation(delay_s):
    params = replace(HumanParams(), reaction_delay_s=delay_s, motor_noise_rad=0.0, offset_noise_m=0.0,
                     heading_noise_rad=0.0)
    offsets_m, steering = lagged_response(params)
    # A first-order hand after a pure delay: the response starts, and peaks, one step after the delay
    # (the hand moves within the step it receives the command).
    assert cross_correlation_peak_lag(offsets_m, steering, 30) == round(delay_s * LOOP_HZ)
    # And nothing before the delay: the input cannot reach the steering earlier.
    early = [abs(np.corrcoef(offsets_m[:len(offsets_m) - k], steering[k:])[0, 1]) for k in range(round(delay_s * LOOP_HZ))]
    assert max(early) < 0.1


def test_same_generator_seed_same_run_other_seed_other_run():
    first = lagged_response(HumanParams(), seed=3)[1]
    again = lagged_response(HumanParams(), seed=3)[1]
    other = lagged_response(HumanParams(), seed=4)[1]
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, other)


def test_reset_with_a_generator_replays_the_episode():
    state = {"speed_mps": 16.7, "lateral_offset_m": 0.3, "heading_error_rad": 0.0, "curvature_1pm": 0.0,
             "curvature_preview_1pm": 0.0}
    driver = HumanDemonstrator(LOOP_HZ)
    driver.reset(np.random.default_rng(7))
    first = [driver(None, state) for _ in range(50)]
    driver.reset(np.random.default_rng(7))
    assert [driver(None, state) for _ in range(50)] == first


@settings(max_examples=60, deadline=None)
@given(steering=st.floats(-1, 1), command=st.floats(-5, 5), dt_s=st.sampled_from([1 / 60, 1 / 30, 1 / 20]))
def test_hand_moves_towards_the_command_within_its_rate_and_range(steering, command, dt_s):
    params = HumanParams()
    after = hand_step(steering, command, dt_s, params)
    max_step = params.max_steering_rate_radps / params.max_steering_rad * dt_s
    assert -1.0 <= after <= 1.0
    assert abs(after - steering) <= max_step + 1e-12
    # Never overshoots the (clipped) command and never moves away from it.
    clipped = max(-1.0, min(1.0, command))
    assert (after - steering) * (clipped - steering) >= -1e-12
    assert abs(clipped - after) <= abs(clipped - steering) + 1e-12


def test_every_parameter_names_its_source_and_units_follow_the_protocol():
    assert set(HUMAN_PARAM_SOURCES) == set(HumanParams.__dataclass_fields__)
    # 1 in the paper's unit = 450 deg of hand wheel = 37.5 deg at the front wheels (12:1) = 0.654 rad.
    assert paper_units(1.0) == pytest.approx(0.2 / math.radians(37.5))
