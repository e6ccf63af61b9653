"""The lane-keeping env: API conformance, determinism, termination, sign conventions, start options."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import ExpertPolicy

SPEED_MPS = 16.7
DT_S = 0.05

LONG_STRAIGHT = {"name": "long_straight", "lanes": 3, "lane_width_m": 4.0,
                 "segments": [{"type": "straight", "length_m": 400}]}
# 60 m straight, a 45-degree left arc of radius 50 m (39.27 m), 30 m straight: 129.27 m in all.
SHORT_LEFT = {"name": "short_left", "lanes": 3, "lane_width_m": 4.0, "segments": [
    {"type": "straight", "length_m": 60},
    {"type": "arc", "radius_m": 50, "angle_deg": 45, "direction": "left"},
    {"type": "straight", "length_m": 30},
]}
SHORT_RIGHT = {**SHORT_LEFT, "name": "short_right",
               "segments": [SHORT_LEFT["segments"][0], {**SHORT_LEFT["segments"][1], "direction": "right"},
                            SHORT_LEFT["segments"][2]]}
QUARTER = {"name": "quarter", "lanes": 3, "lane_width_m": 4.0, "segments": [
    {"type": "straight", "length_m": 100},
    {"type": "arc", "radius_m": 50, "angle_deg": 90, "direction": "left"},
    {"type": "straight", "length_m": 100},
]}

INFO_KEYS = {"lateral_offset_m", "heading_error_rad", "lane_index", "segment", "arc_length_m", "position", "time"}


def make(track=LONG_STRAIGHT, **config):
    return gymnasium.make(ENV_ID, config={"track": track, **config})


def act(value: float) -> np.ndarray:
    return np.array([value], dtype=np.float32)


def drive_expert(env, max_steps: int = 10_000):
    expert = ExpertPolicy()
    obs, info = env.reset(seed=0)
    infos = [info]
    for _ in range(max_steps):
        obs, _, terminated, truncated, info = env.step(act(expert(obs, info)))
        infos.append(info)
        if terminated or truncated:
            return infos, terminated, truncated
    raise AssertionError("the episode did not end")


# -- API -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_check_env_passes(render_mode):
    env = gymnasium.make(ENV_ID, config={"track": "test"}, render_mode=render_mode)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)  # raises on any failure
    # The checker reports soft problems as UserWarnings (deprecations elsewhere are not its concern).
    assert [str(w.message) for w in caught if issubclass(w.category, UserWarning)] == []


@pytest.mark.parametrize("vehicle_model", ["kinematic", "dynamic"])
@pytest.mark.parametrize("latency", [None, "const:0.15", "steps:0.05-0.3:0.5"])
def test_check_env_passes_with_each_vehicle_model_and_with_the_latency_wrapper(vehicle_model, latency):
    from plm_highway.latency import LatencyWrapper

    env = gymnasium.make(ENV_ID, config={"track": "test", "vehicle_model": vehicle_model})
    env = env.unwrapped if latency is None else LatencyWrapper(env, latency)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    # The checker always advises checking the raw env when it is given a wrapper; that advice aside, nothing.
    messages = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    assert [m for m in messages if "recommend using the raw environment" not in m] == []


def test_observation_is_a_66x200_uint8_frame():
    env = make()
    obs, _ = env.reset(seed=0)
    assert env.observation_space.shape == (66, 200)
    assert env.observation_space.dtype == np.uint8
    assert obs.shape == (66, 200) and obs.dtype == np.uint8
    assert env.observation_space.contains(obs)
    obs, *_ = env.step(act(0.0))
    assert obs.shape == (66, 200) and obs.dtype == np.uint8
    assert env.action_space.shape == (1,)
    assert env.action_space.low[0] == -1.0 and env.action_space.high[0] == 1.0


def test_camera_size_option():
    env = make(camera={"height_px": 160, "width_px": 160})
    obs, _ = env.reset(seed=0)
    assert obs.shape == (160, 160) and obs.dtype == np.uint8
    assert env.observation_space.shape == (160, 160)
    obs, *_ = env.step(act(0.0))
    assert obs.shape == (160, 160)


def test_unknown_camera_key_and_reset_option_raise():
    with pytest.raises(ValueError, match="zoom"):
        make(camera={"zoom": 2})
    env = make()
    with pytest.raises(ValueError, match="start_ofset_m"):  # a typo must not be silently ignored
        env.reset(options={"start_ofset_m": 1.0})
    with pytest.raises(ValueError, match="start_lane"):  # a config key, not a per-episode option
        env.reset(options={"start_lane": 0})


def test_info_keys_and_time():
    env = make()
    _, info = env.reset(seed=0)
    assert INFO_KEYS <= set(info)
    assert info["time"] == 0.0
    for n in range(1, 4):
        _, _, terminated, truncated, info = env.step(act(0.0))
        assert INFO_KEYS <= set(info)
        assert info["time"] == pytest.approx(n * DT_S)
        assert not terminated and not truncated
    assert info["position"].shape == (2,)
    assert info["arc_length_m"] == pytest.approx(3 * DT_S * SPEED_MPS, rel=1e-6)
    assert info["position"] == pytest.approx((3 * DT_S * SPEED_MPS, 0.0), abs=1e-6)
    assert info["lane_index"] == 1 and info["segment"] == "straight"
    assert info["lateral_offset_m"] == pytest.approx(0.0, abs=1e-9)


def test_policy_frequency_below_simulation_frequency_records_every_simulation_step():
    env = make(simulation_frequency=20, policy_frequency=10)
    env.reset(seed=0)
    _, _, _, _, info = env.step(act(0.0))
    assert info["time"] == pytest.approx(0.1)
    times = [snap.time_s for snap in env.unwrapped.new_snapshots]
    assert times == pytest.approx([0.05, 0.1])


@pytest.mark.parametrize(("sim_hz", "policy_hz"), [(20, 15), (20, 40), (20, 0), (20.0, 20)])
def test_bad_frequency_ratio_raises(sim_hz, policy_hz):
    with pytest.raises(ValueError, match="_frequency"):
        env = make(simulation_frequency=sim_hz, policy_frequency=policy_hz)
        env.reset(seed=0)


def test_render_rgb_array():
    env = gymnasium.make(ENV_ID, config={"track": LONG_STRAIGHT, "screen_width": 320, "screen_height": 240},
                         render_mode="rgb_array")
    env.reset(seed=0)
    image = env.render()
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    assert image.std() > 5  # road, verge and the car: not a flat image
    # The car (drawn blue-ish) sits at the centre of the view.
    centre = image[118:122, 158:162].reshape(-1, 3).astype(int)
    assert np.all(centre[:, 2] > centre[:, 0] + 50)


# -- determinism -----------------------------------------------------------------------------------

_EPISODE_SCRIPT = r"""
import hashlib, sys
import numpy as np, gymnasium
import plm_highway
env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": "test"})
keys = ("lateral_offset_m", "heading_error_rad", "arc_length_m", "time", "segment", "lane_index")
for amplitude in map(float, sys.argv[2].split(",")):
    obs, info = env.reset(seed=int(sys.argv[1]))
    digest = hashlib.sha256(obs.tobytes())
    for step in range(60):
        action = amplitude * np.sin(0.3 * step)
        obs, reward, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        digest.update(obs.tobytes())
        digest.update(repr([info[k] for k in keys] + info["position"].tolist()
                           + [reward, terminated, truncated]).encode())
    print(digest.hexdigest())
"""


def test_seeded_episode_is_identical_across_processes():
    def start(amplitudes: str, hash_seed: str):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed}
        return subprocess.Popen([sys.executable, "-c", _EPISODE_SCRIPT, "7", amplitudes],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)

    runs = [start("0.3", "1"), start("0.3,0.25", "2")]
    digests = []
    for process in runs:
        out, err = process.communicate(timeout=180)
        assert process.returncode == 0, err
        digests.append(out.split())
    (first,), (second, other_actions) = digests
    assert len(first) == 64
    assert first == second
    assert second != other_actions  # the hash does see the actions


def test_reset_with_the_same_seed_repeats_the_episode_in_process():
    env = make(track="test")
    actions = [0.2 * math.sin(0.4 * i) for i in range(30)]

    def episode():
        obs, _ = env.reset(seed=3)
        frames = [obs.copy()]
        offsets = []
        for a in actions:
            obs, _, _, _, info = env.step(act(a))
            frames.append(obs.copy())
            offsets.append(info["lateral_offset_m"])
        return np.stack(frames), offsets

    frames_a, offsets_a = episode()
    frames_b, offsets_b = episode()
    assert np.array_equal(frames_a, frames_b)
    assert offsets_a == offsets_b
    assert not np.array_equal(frames_a[0], frames_a[-1])  # the car moved: the frames changed


# -- episode end -----------------------------------------------------------------------------------


def test_terminates_when_the_car_leaves_the_road():
    env = make()
    env.reset(seed=0)
    half_road_m = 6.0  # 3 lanes of 4 m, starting in the middle one
    previous = 0.0
    for step in range(200):  # noqa: B007  (the count is asserted after the loop)
        _, reward, terminated, truncated, info = env.step(act(1.0))
        assert not truncated
        # Full left: the offset grows to the left (positive) monotonically.
        assert info["lateral_offset_m"] >= previous - 1e-9
        previous = info["lateral_offset_m"]
        if terminated:
            break
        assert info["on_road"] and abs(info["lateral_offset_m"]) <= half_road_m
    else:
        raise AssertionError("full-left steering never left the road")
    assert info["lateral_offset_m"] > half_road_m
    assert info["on_road"] is False
    assert reward == 0.0
    # A full-left circle has radius ~25 m: y = x^2 / (2R) reaches 6 m after ~17 m, about 1 s.
    assert 10 <= step <= 40


def test_truncated_at_the_end_of_an_open_track():
    env = make(track=SHORT_LEFT)
    infos, terminated, truncated = drive_expert(env)
    length_m = 60 + 50 * math.pi / 4 + 30
    assert truncated and not terminated
    assert infos[-1]["arc_length_m"] >= length_m - 1e-6
    assert infos[-2]["arc_length_m"] < length_m
    assert infos[-1]["completed_fraction"] == 1.0
    # Driving the lane centre at 16.7 m/s covers 0.835 m per step.
    expected_steps = math.ceil(length_m / (SPEED_MPS * DT_S))
    assert abs((len(infos) - 1) - expected_steps) <= 2


def test_duration_truncates():
    env = make(duration_s=1.0)
    env.reset(seed=0)
    for step in range(1, 100):  # noqa: B007  (the count is asserted after the loop)
        _, _, terminated, truncated, info = env.step(act(0.0))
        if truncated:
            break
    assert step == 20 and not terminated
    assert info["time"] == pytest.approx(1.0)


@pytest.mark.parametrize(("track", "kind"), [(SHORT_LEFT, "left"), (SHORT_RIGHT, "right")])
def test_segment_names_the_arc_the_car_is_on(track, kind):
    infos, _, _ = drive_expert(make(track=track))
    arc_start_m, arc_end_m = 60.0, 60 + 50 * math.pi / 4
    for info in infos:
        s = info["arc_length_m"]
        if s < arc_start_m - 0.5 or s > arc_end_m + 0.5:
            assert info["segment"] == "straight", s
        elif arc_start_m + 0.5 < s < arc_end_m - 0.5:
            assert info["segment"] == kind, s
            # The expert stays close to the middle lane.
            assert info["lane_index"] == 1
    assert sum(info["segment"] == kind for info in infos) >= 40  # 39 m at 0.835 m per step


# -- sign conventions ------------------------------------------------------------------------------


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_positive_steering_turns_left(sign):
    env = make()
    env.reset(seed=0)
    headings, ys = [], []
    for _ in range(10):
        _, _, _, _, info = env.step(act(0.5 * sign))
        headings.append(info["heading_rad"])
        ys.append(info["position"][1])
    # Heading east, turning left raises the heading and moves the car north (y up).
    assert sign * headings[-1] > 0.05
    assert np.all(sign * np.diff(headings) > 0)
    assert sign * ys[-1] > 0.1
    assert sign * info["lateral_offset_m"] > 0.1
    assert sign * info["heading_error_rad"] > 0.05
    assert info["steering"] == pytest.approx(0.5 * sign)


def test_steering_is_clipped_to_the_action_range():
    env_a, env_b = make(), make()
    env_a.reset(seed=0)
    env_b.reset(seed=0)
    for _ in range(5):
        *_, info_a = env_a.step(act(3.0))
        *_, info_b = env_b.step(act(1.0))
    assert info_a["heading_rad"] == pytest.approx(info_b["heading_rad"])


def test_start_offset_moves_the_car_left():
    env = make()
    _, info = env.reset(seed=0, options={"start_offset_m": 1.0})
    assert info["lateral_offset_m"] == pytest.approx(1.0)
    # The reference line runs along y = 0 heading east: 1 m left is 1 m north.
    assert info["position"] == pytest.approx((0.0, 1.0))
    _, info = env.reset(seed=0, options={"start_offset_m": -1.5})
    assert info["lateral_offset_m"] == pytest.approx(-1.5)
    assert info["position"][1] == pytest.approx(-1.5)
    # The override lasts one episode.
    _, info = env.reset(seed=0)
    assert info["lateral_offset_m"] == pytest.approx(0.0)


def test_start_lane_zero_is_the_left_lane():
    env = make(start_lane=0)
    _, info = env.reset(seed=0)
    assert info["position"] == pytest.approx((0.0, 4.0))
    assert info["lane_index"] == 0
    assert info["lateral_offset_m"] == pytest.approx(0.0)  # relative to the starting lane


def test_start_on_an_arc_with_a_heading_error():
    env = make(track=QUARTER)
    s_m = 100 + 50 * math.pi / 4  # 45 degrees into the left arc around (100, 50)
    _, info = env.reset(seed=0, options={"start_arc_length_m": s_m, "start_heading_error_rad": 0.1})
    expected = (100 + 50 * math.sin(math.pi / 4), 50 - 50 * math.cos(math.pi / 4))
    assert info["position"] == pytest.approx(expected, abs=1e-6)
    assert info["heading_rad"] == pytest.approx(math.pi / 4 + 0.1)
    assert info["heading_error_rad"] == pytest.approx(0.1)
    assert info["arc_length_m"] == pytest.approx(s_m, abs=1e-6)
    assert info["segment"] == "left"
    assert info["curvature_1pm"] == pytest.approx(1 / 50)


def test_start_offset_on_a_left_arc_points_to_the_centre():
    env = make(track=QUARTER)
    s_m = 100 + 50 * math.pi / 4
    _, info = env.reset(seed=0, options={"start_arc_length_m": s_m, "start_offset_m": 2.0})
    # Left of a left arc is towards its centre (100, 50): 48 m from it.
    assert np.hypot(info["position"][0] - 100, info["position"][1] - 50) == pytest.approx(48.0)
    assert info["lateral_offset_m"] == pytest.approx(2.0)


def test_two_lane_track_starts_in_the_right_lane_and_measures_arc_length():
    two_lanes = {**SHORT_LEFT, "name": "two_lanes", "lanes": 2}
    env = make(track=two_lanes)
    _, info = env.reset(seed=0)
    # Lanes at +2 m (lane 0) and -2 m (lane 1); the default start is lanes // 2 = lane 1, south of y = 0.
    assert info["position"] == pytest.approx((0.0, -2.0))
    assert info["lane_index"] == 1 and info["lateral_offset_m"] == pytest.approx(0.0)
    infos, terminated, truncated = drive_expert(env)
    assert truncated and not terminated
    assert max(abs(i["lateral_offset_m"]) for i in infos) < 0.3
    # Arc length is measured on the reference line even though the car drives 2 m right of it:
    # at the end of the track it matches the reference length, not the (longer) right lane's.
    length_m = 60 + 50 * math.pi / 4 + 30
    assert infos[-1]["arc_length_m"] == pytest.approx(length_m, abs=SPEED_MPS * DT_S)
    assert infos[-1]["position"][0] == pytest.approx(60 + 52 * math.sin(math.pi / 4) + 30 * math.cos(math.pi / 4),
                                                     abs=1.0)
