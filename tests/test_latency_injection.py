"""The two latency injections: exact ages by time, and the original PLM-Net FIFO."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import expert_steering
from plm_highway.latency import LatencyWrapper
from plm_highway.latency.profiles import LatencyProfile

_BASE_ENVS: dict[int, gymnasium.Env] = {}
EPS = 1e-9


def base_env(rate_hz: int) -> gymnasium.Env:
    """Simulation and policy at one rate: a 'frame' of the loop is one step."""
    if rate_hz not in _BASE_ENVS:
        config = {"track": "test", "simulation_frequency": rate_hz, "policy_frequency": rate_hz}
        _BASE_ENVS[rate_hz] = gymnasium.make(ENV_ID, config=config)
    return _BASE_ENVS[rate_hz]


class FrameSchedule(LatencyProfile):
    """A requested delay given frame by frame (``frames[i]`` at step ``i``, then held)."""

    def __init__(self, frames: list[int], rate_hz: int) -> None:
        self.frames, self.rate_hz, self.spec = list(frames), rate_hz, "schedule"

    def latency_s(self, t_s: float) -> float:
        step = min(round(t_s * self.rate_hz), len(self.frames) - 1)
        return self.frames[step] / self.rate_hz

    @property
    def max_latency_s(self) -> float:
        return max(self.frames) / self.rate_hz


def run(env, steps: int, seed: int = 0):
    """Steps driven by the expert on the true state (in ``info``), so the car stays on the road."""
    obs, info = env.reset(seed=seed)
    records = [(obs, info)]
    for _ in range(steps):
        action = np.array([np.clip(expert_steering(info), -1.0, 1.0)], dtype=np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        records.append((obs, info))
        assert not (terminated or truncated)
    return records


def ages_in_frames(records, rate_hz: int) -> list[int]:
    ages = [info["observation_age_s"] * rate_hz for _, info in records]
    assert all(abs(age - round(age)) < 1e-6 for age in ages)
    return [round(age) for age in ages]


def legacy_ages_from_the_description(requested: list[int]) -> list[int]:
    """The ages the notes describe, assuming each delay holds long enough to settle before the next change.

    Start-up and growth from d1 to d2: the current frame (age 0) for d2 - d1 frames while the FIFO
    refills, then d2. Shrinking from d1 to d2: d1 - 1, d1 - 2, ..., d2 (one frame per frame).
    """
    ages = []
    for step, delta in enumerate(requested):
        if step == 0 or delta != requested[step - 1]:
            change_step, previous = step, (requested[step - 1] if step else 0)
        since = step - change_step
        if delta > previous:
            ages.append(0 if since < delta - previous else delta)
        else:
            ages.append(max(previous - 1 - since, delta))
    return ages


# -- legacy-fifo, by hand --------------------------------------------------------------------------


def test_legacy_fifo_ages_step_by_step():
    # 5 frames for 2 s, 10 frames for 2 s, then 3 frames, at 20 Hz.
    requested = [5] * 40 + [10] * 40 + [3] * 40
    env = LatencyWrapper(base_env(20), FrameSchedule(requested, 20), injection="legacy-fifo")
    records = run(env, 119)
    expected = ([0] * 5 + [5] * 35          # start-up: fresh frames until the FIFO holds 5
                + [0] * 5 + [10] * 35       # growth 5 -> 10: five fresh (zero-latency) frames while it refills
                + [9, 8, 7, 6, 5, 4, 3] + [3] * 33)  # shrink 10 -> 3: down one frame per frame
    assert ages_in_frames(records, 20) == expected
    # info reports the requested latency beside the true age.
    assert [round(info["latency_s"] * 20) for _, info in records] == requested


def test_time_injection_follows_the_same_schedule_exactly():
    requested = [5] * 40 + [10] * 40 + [3] * 40
    records = run(LatencyWrapper(base_env(20), FrameSchedule(requested, 20)), 119)
    expected = list(range(5)) + [5] * 35 + [10] * 40 + [3] * 40  # only the first 0.25 s lacks history
    assert ages_in_frames(records, 20) == expected


def test_legacy_fifo_delivers_the_frame_of_its_age():
    requested = [4] * 30 + [9] * 30 + [2] * 30
    plain = [obs.copy() for obs, _ in run(LatencyWrapper(base_env(20), "none"), 89, seed=3)]
    records = run(LatencyWrapper(base_env(20), FrameSchedule(requested, 20), injection="legacy-fifo"), 89, seed=3)
    for step, (obs, info) in enumerate(records):
        age = round(info["observation_age_s"] * 20)
        assert np.array_equal(obs, plain[step - age])
        assert info["observed_state"]["time_s"] == pytest.approx(info["time"] - info["observation_age_s"], abs=EPS)


def test_legacy_fifo_zero_delay_bypasses_and_keeps_stale_frames():
    # The original skipped its FIFO when delta was 0 and left it as it was: when the delay came back,
    # the frames from before the pause were served, as old as the pause plus the delay.
    requested = [5] * 20 + [0] * 10 + [5] * 20
    records = run(LatencyWrapper(base_env(20), FrameSchedule(requested, 20), injection="legacy-fifo"), 49)
    assert ages_in_frames(records, 20) == [0] * 5 + [5] * 15 + [0] * 10 + [15] * 5 + [5] * 15


def test_legacy_fifo_counts_non_multiple_latencies_like_the_time_lookup():
    # 0.12 s at 20 Hz is served as 3 frames (0.15 s) by both injections.
    legacy = run(LatencyWrapper(base_env(20), "const:0.12", injection="legacy-fifo"), 20)
    timed = run(LatencyWrapper(base_env(20), "const:0.12"), 20)
    assert ages_in_frames(legacy, 20)[-10:] == ages_in_frames(timed, 20)[-10:] == [3] * 10
    assert ages_in_frames(legacy, 20)[:3] == [0, 0, 0]  # start-up: fresh frames, not the reset frame
    assert ages_in_frames(timed, 20)[:3] == [0, 1, 2]


def test_legacy_fifo_memory_is_bounded_by_the_largest_delay():
    env = LatencyWrapper(base_env(20), "steps:0.05-1.0:0.3", injection="legacy-fifo", max_latency_s=1.0)
    env.reset(seed=0)
    sizes = []
    for _ in range(400):
        env.step(np.array([0.02], dtype=np.float32))
        sizes.append(len(env._history))
    assert max(sizes) <= 20  # 1.0 s at 20 Hz


def test_unknown_injection_is_refused():
    with pytest.raises(ValueError, match="'fifo'.*time, legacy-fifo"):
        LatencyWrapper(base_env(20), "const:0.1", injection="fifo")


# -- legacy-fifo, as a property over schedules ----------------------------------------------------


@settings(max_examples=15, deadline=None)
@given(segments=st.lists(st.tuples(st.integers(1, 15), st.integers(16, 30)), min_size=1, max_size=6),
       seed=st.integers(0, 2**16))
def test_legacy_fifo_property(segments, seed):
    requested = [delta for delta, hold in segments for _ in range(hold)]
    env = LatencyWrapper(base_env(20), FrameSchedule(requested, 20), injection="legacy-fifo")
    records = run(env, len(requested) - 1, seed=seed)
    ages = ages_in_frames(records, 20)
    assert ages == legacy_ages_from_the_description(requested)
    # Once settled the age is the request; after a rise it is not, for a while (the FIFO refills and serves
    # fresher frames). A fall by one frame can be served at once (hypothesis found 2 -> 1 frames).
    first_change = segments[0][1]
    assert ages[first_change - 1] == requested[0]
    if len(segments) > 1 and segments[1][0] > segments[0][0]:
        assert ages[first_change:] != requested[first_change:]


@pytest.mark.parametrize("rate_hz", [30, 60])
def test_the_original_profile_under_both_injections(rate_hz):
    # frames:9-21:60@RATE in a loop at RATE Hz: the original experiment in its two timebase readings.
    spec = f"frames:9-21:60@{rate_hz}"
    steps = 60 * 6  # six redraw blocks
    legacy = run(LatencyWrapper(base_env(rate_hz), spec, injection="legacy-fifo"), steps - 1, seed=11)
    timed = run(LatencyWrapper(base_env(rate_hz), spec), steps - 1, seed=11)
    requested = [round(info["latency_s"] * rate_hz) for _, info in legacy]
    assert requested == [round(info["latency_s"] * rate_hz) for _, info in timed]  # one realisation per seed
    assert all(9 <= delta <= 21 for delta in requested) and len(set(requested)) >= 3
    assert all(len(set(requested[block:block + 60])) == 1 for block in range(0, steps, 60))
    # Time injection: the age is the request (once that much history exists).
    timed_ages = ages_in_frames(timed, rate_hz)
    assert timed_ages == [min(delta, step) for step, delta in enumerate(requested)]
    # Legacy FIFO: fresh frames after every increase, a ramp after every decrease.
    legacy_ages = ages_in_frames(legacy, rate_hz)
    assert legacy_ages == legacy_ages_from_the_description(requested)
    grew = [block for block in range(60, steps, 60) if requested[block] > requested[block - 1]]
    for block in grew:
        assert legacy_ages[block] == 0  # zero latency served while the requested one just grew
    assert legacy_ages != timed_ages
