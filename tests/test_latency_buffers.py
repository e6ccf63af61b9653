"""The wrapper never hands out its own buffers."""

from __future__ import annotations

import itertools
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.latency import LatencyWrapper

SPECS = ["const:0.2", "steps:0.0-0.35:0.5", "sine:0.2:0.1:2", "ramp:0-0.3:2", "frames:9-21:60@60", "TRACE"]
_BASE_ENVS: dict[int, gymnasium.Env] = {}


def base_env(policy_hz: int = 20) -> gymnasium.Env:
    if policy_hz not in _BASE_ENVS:
        config = {"track": "test", "simulation_frequency": policy_hz, "policy_frequency": policy_hz}
        _BASE_ENVS[policy_hz] = gymnasium.make(ENV_ID, config=config)
    return _BASE_ENVS[policy_hz]


def spec_for(spec: str, tmp_path) -> str:
    if spec != "TRACE":
        return spec
    path = tmp_path / "trace.csv"
    path.write_text("t,latency_s\n0.0,0.0\n0.5,0.3\n1.0,0.1\n")
    return f"trace:{path}"


def drive(env, steps: int, seed: int = 0):
    """The (frame, info) pairs delivered over ``steps`` steps of a steady steer, as delivered."""
    obs, info = env.reset(seed=seed)
    delivered = [(obs, info)]
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(np.array([0.05], dtype=np.float32))
        delivered.append((obs, info))
        if terminated or truncated:
            break
    return delivered


def drive_writing_into_deliveries(env, steps: int, seed: int = 0):
    """Like ``drive``, but zeroes every frame and edits every observed state once it was delivered."""
    obs, info = env.reset(seed=seed)
    seen = [(obs.copy(), dict(info["observed_state"]))]
    for _ in range(steps):
        obs[:] = 0
        info["observed_state"]["lateral_offset_m"] = 99.0
        obs, _, terminated, truncated, info = env.step(np.array([0.05], dtype=np.float32))
        seen.append((obs.copy(), dict(info["observed_state"])))
        if terminated or truncated:
            break
    return seen


@pytest.mark.parametrize("injection", ["time", "legacy-fifo"])
def test_writing_into_a_delivered_frame_changes_nothing_later(injection):
    spec = "steps:0.0-0.35:0.5"  # re-delivers snapshots whenever the latency grows
    clean = drive(LatencyWrapper(base_env(), spec, injection=injection), 60)
    written = drive_writing_into_deliveries(LatencyWrapper(base_env(), spec, injection=injection), 60)
    assert len(written) == len(clean) == 61
    for (clean_obs, clean_info), (obs, state) in zip(clean, written, strict=True):
        assert np.array_equal(obs, clean_obs) and obs.any()
        assert state == clean_info["observed_state"] and state["lateral_offset_m"] != 99.0


def test_issue_reproduction_zeroed_reset_frame_is_not_delivered_again():
    env = LatencyWrapper(base_env(), "const:0.2")
    obs, _ = env.reset(seed=0)
    reference = obs.copy()
    obs[:] = 0
    later, *_ = env.step(np.array([0.0], dtype=np.float32))
    # At t = 0.05 s the 0.2 s old frame does not exist yet: the reset frame is delivered again, intact.
    assert later is not obs
    assert np.array_equal(later, reference) and later.any()


@pytest.mark.parametrize("injection", ["time", "legacy-fifo"])
@pytest.mark.parametrize("spec", SPECS)
def test_no_two_deliveries_share_memory(spec, injection, tmp_path):
    env = LatencyWrapper(base_env(), spec_for(spec, tmp_path), injection=injection)
    delivered = drive(env, 80)
    frames = [obs for obs, _ in delivered]
    states = [info["observed_state"] for _, info in delivered]
    # The snapshot at one instant is delivered several times here (latency grows, or start-up) ...
    observed_times = [info["observed_state"]["time_s"] for _, info in delivered]
    assert len(set(observed_times)) < len(observed_times)
    # ... yet every delivery is its own array and its own state dict.
    for first, second in itertools.combinations(range(len(frames)), 2):
        assert not np.shares_memory(frames[first], frames[second]), (first, second)
        assert states[first] is not states[second]
    assert all(frame.flags.writeable and frame.flags.owndata for frame in frames)


@pytest.mark.parametrize("injection", ["time", "legacy-fifo"])
@pytest.mark.parametrize("spec", SPECS)
def test_gymnasium_check_env_passes_wrapped(spec, injection, tmp_path):
    env = LatencyWrapper(base_env(), spec_for(spec, tmp_path), injection=injection)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the checker also warns about style (e.g. float32 bounds)
        check_env(env)


def test_gymnasium_check_env_passes_unwrapped():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(base_env().unwrapped)


def test_spec_rebuilds_the_same_wrapper(tmp_path):
    spec = spec_for("TRACE", tmp_path)
    env = LatencyWrapper(base_env(), spec, max_latency_s=0.5, injection="legacy-fifo")
    rebuilt = env.spec.make()
    assert isinstance(rebuilt, LatencyWrapper)
    assert (rebuilt.profile.spec, rebuilt.max_latency_s, rebuilt.injection) == (spec, 0.5, "legacy-fifo")
    rebuilt.close()
