"""The privileged expert: tracks the lane, inverts the bicycle, and zig-zags when its view is late."""

from __future__ import annotations

import math
import re
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import ExpertPolicy, expert_steering, steering_for_curvature
from plm_highway.latency import LatencyWrapper

MAX_STEERING_RAD = 0.2


def drive(env, policy=None, options=None, max_steps: int = 10_000):
    policy = policy or ExpertPolicy()
    obs, info = env.reset(seed=0, options=options)
    infos = [info]
    for _ in range(max_steps):
        obs, _, terminated, truncated, info = env.step(np.array([policy(obs, info)], dtype=np.float32))
        infos.append(info)
        if terminated or truncated:
            return infos, terminated, truncated
    return infos, False, False


def offsets(infos) -> np.ndarray:
    return np.array([info["lateral_offset_m"] for info in infos])


TRACKS = ("train", "test", "unseen")
DOCS = Path(__file__).resolve().parents[1] / "docs" / "expert-and-data.md"


def documented(pattern: str) -> tuple[float, ...]:
    """The numbers docs/expert-and-data.md quotes where ``pattern`` matches (whitespace-insensitive)."""
    match = re.search(pattern, re.sub(r"\s+", " ", DOCS.read_text(encoding="utf-8")))
    assert match, f"docs/expert-and-data.md no longer says {pattern!r}"
    return tuple(float(value) for value in match.groups())


@pytest.fixture(scope="module")
def whole_track_runs() -> dict:
    return {track: drive(gymnasium.make(ENV_ID, config={"track": track})) for track in TRACKS}


def test_the_documented_lane_keeping_bound_is_the_measured_one(whole_track_runs):
    (bound_m,) = documented(r"It stays within ([\d.]+) m of the lane centre on all three tracks")
    worst_m = max(float(np.max(np.abs(offsets(infos)))) for infos, _, _ in whole_track_runs.values())
    assert round(worst_m, 2) == bound_m


@pytest.mark.parametrize("track", TRACKS)
def test_expert_stays_near_the_lane_centre_on_the_whole_track(track, whole_track_runs):
    infos, terminated, truncated = whole_track_runs[track]
    assert truncated and not terminated  # reached the end of the track
    assert infos[-1]["completed_fraction"] == 1.0
    assert np.max(np.abs(offsets(infos))) <= 0.3
    assert all(info["lane_index"] == 1 for info in infos)
    # It did go round curves both ways.
    assert {info["segment"] for info in infos} == {"straight", "left", "right"}


def test_steering_for_curvature_by_hand():
    # sin(beta) = (L/2) kappa = 2.5 * 0.01; tan(delta) = 2 tan(beta).
    beta = math.asin(0.025)
    assert steering_for_curvature(0.01) == pytest.approx(math.atan(2 * math.tan(beta)))
    assert steering_for_curvature(0.01) == pytest.approx(0.04997, abs=1e-4)
    assert steering_for_curvature(0.0) == 0.0
    assert steering_for_curvature(-0.02) == pytest.approx(-steering_for_curvature(0.02))
    assert math.isfinite(steering_for_curvature(10.0))  # saturates instead of failing


def fit_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares circle: x^2 + y^2 = 2 a x + 2 b y + c, radius^2 = c + a^2 + b^2."""
    design = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    (a, b, c), *_ = np.linalg.lstsq(design, x ** 2 + y ** 2, rcond=None)
    return float(a), float(b), float(math.sqrt(c + a * a + b * b))


@pytest.mark.parametrize("direction", ["left", "right"])
def test_constant_steering_for_a_curvature_drives_that_circle(direction):
    sign = 1.0 if direction == "left" else -1.0
    # A closed ring of radius 100 m, so the car can go round without leaving the road.
    ring = {"name": f"ring_{direction}", "lanes": 3, "lane_width_m": 4.0, "closed": True,
            "segments": [{"type": "arc", "radius_m": 100, "angle_deg": 360, "direction": direction}]}
    env = gymnasium.make(ENV_ID, config={"track": ring})
    env.reset(seed=0)
    action = np.array([steering_for_curvature(sign / 100.0) / MAX_STEERING_RAD], dtype=np.float32)
    positions = []
    for _ in range(300):  # 250 m: 0.4 of a lap
        _, _, terminated, truncated, info = env.step(action)
        assert not terminated and not truncated
        positions.append(info["position"])
    x, y = np.array(positions).T
    centre_x, centre_y, radius = fit_circle(x, y)
    assert radius == pytest.approx(100.0, abs=0.5)
    # The car's velocity points at heading + beta (sin beta = 2.5 m / 100 m), so its circle's centre
    # is R sin(beta) = 2.5 m behind the start; the explicit Euler step puts the polygon's circumcentre
    # half a step (0.4175 m) further on. The centre is on the driver's side: north for a left turn.
    assert centre_x == pytest.approx(0.5 * 16.7 * 0.05 - 2.5, abs=0.05)
    assert sign * centre_y == pytest.approx(100.0 * math.cos(math.asin(0.025)), abs=0.1)
    assert np.all(np.abs(np.hypot(x - centre_x, y - centre_y) - radius) < 0.05)


def test_expert_steering_signs_and_curvature_feed_forward():
    # Steady state on a left curve of radius 100 m: the bicycle's body points inward by its slip angle
    # beta = asin(2.5 / 100), so the direction of travel follows the lane and only feed-forward remains.
    beta_rad = math.asin(2.5 * 0.01)
    state = {"speed_mps": 16.7, "lateral_offset_m": 0.0, "heading_error_rad": -beta_rad, "curvature_1pm": 0.01,
             "curvature_preview_1pm": 0.01}
    assert expert_steering(state) == pytest.approx(steering_for_curvature(0.01) / MAX_STEERING_RAD)
    assert expert_steering(state) == pytest.approx(0.2499, abs=1e-3)
    # Left of the centre, or heading left of the lane: steer right (negative).
    straight = {**state, "heading_error_rad": 0.0, "curvature_1pm": 0.0, "curvature_preview_1pm": 0.0}
    assert expert_steering({**straight, "lateral_offset_m": 0.5}) < 0
    assert expert_steering({**straight, "heading_error_rad": 0.05}) < 0
    assert expert_steering({**straight, "lateral_offset_m": -0.5}) > 0
    # Far off: saturates at the action limits.
    assert expert_steering({**state, "lateral_offset_m": -50.0}) == 1.0
    assert expert_steering({**state, "lateral_offset_m": 50.0}) == -1.0


def test_expert_policy_prefers_the_observed_state():
    true = {"speed_mps": 16.7, "lateral_offset_m": 1.0, "heading_error_rad": 0.0, "curvature_1pm": 0.0,
            "curvature_preview_1pm": 0.0}
    observed = {**true, "lateral_offset_m": -1.0}
    policy = ExpertPolicy()
    assert policy(None, true) < 0
    assert policy(None, {**true, "observed_state": observed}) > 0


@pytest.mark.parametrize(("offset_m", "heading_deg"), [(1.5, 0.0), (-1.5, 6.0), (0.0, -6.0)])
def test_expert_recovers_from_a_displaced_start(offset_m, heading_deg):
    env = gymnasium.make(ENV_ID, config={"track": "test"})
    infos, terminated, _ = drive(env, options={"start_offset_m": offset_m,
                                               "start_heading_error_rad": math.radians(heading_deg)},
                                 max_steps=100)
    assert not terminated
    lateral = offsets(infos)
    assert lateral[0] == pytest.approx(offset_m)
    # Natural frequency 3 rad/s, damping 0.9: settled well within 3 s (60 steps) ...
    assert np.all(np.abs(lateral[60:]) < 0.1)
    # ... and without a large overshoot to the other side.
    if offset_m:
        assert np.max(-np.sign(offset_m) * lateral) < 0.3


def test_latency_makes_the_expert_zig_zag():
    rms = {}
    for spec in ("const:0", "const:0.25"):
        env = LatencyWrapper(gymnasium.make(ENV_ID, config={"track": "test"}), spec)
        infos, terminated, truncated = drive(env)
        assert truncated and not terminated
        if spec == "const:0.25":
            assert all(info["observation_age_s"] == pytest.approx(min(0.25, info["time"])) for info in infos)
        lateral = offsets(infos)
        rms[spec] = float(np.sqrt(np.mean(lateral ** 2)))
    assert rms["const:0.25"] >= 2 * rms["const:0"]
    assert rms["const:0"] < 0.1
    late_m, on_time_m = documented(r"it weaves \(offset RMS ([\d.]+) m against ([\d.]+) m on the test track\)")
    assert (round(rms["const:0.25"], 2), round(rms["const:0"], 2)) == (late_m, on_time_m)
