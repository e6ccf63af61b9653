"""Latency profiles and the wrapper that serves old frames by time."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import expert_steering
from plm_highway.latency import LatencyWrapper, parse_profile

SIM_DT_S = 0.05
EPS = 1e-9
_BASE_ENVS: dict[int, gymnasium.Env] = {}


def base_env(policy_hz: int = 20) -> gymnasium.Env:
    """One env per policy rate for the whole module (the wrappers around it are made per test)."""
    if policy_hz not in _BASE_ENVS:
        _BASE_ENVS[policy_hz] = gymnasium.make(ENV_ID, config={"track": "test", "policy_frequency": policy_hz})
    return _BASE_ENVS[policy_hz]


def write_trace(path: Path, rows) -> Path:
    path.write_text("t,latency_s\n" + "".join(f"{t},{v}\n" for t, v in rows))
    return path


def noisy_expert_actions(rng: np.random.Generator, info: dict, amplitude: float = 0.15) -> np.ndarray:
    """The expert on the TRUE state plus noise: random actions that keep the car on the road."""
    value = expert_steering(info) + amplitude * rng.uniform(-1.0, 1.0)
    return np.array([np.clip(value, -1.0, 1.0)], dtype=np.float32)


def run_episode(env, steps: int, seed: int = 0, action_seed: int = 0, options=None):
    rng = np.random.default_rng(action_seed)
    obs, info = env.reset(seed=seed, options=options)
    records = [(obs, info)]
    actions = []
    for _ in range(steps):
        action = noisy_expert_actions(rng, info)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        records.append((obs, info))
        if terminated or truncated:
            break
    return records, actions


def assert_age_follows_latency(info: dict, expected_latency_s: float) -> None:
    t, age = info["time"], info["observation_age_s"]
    assert info["latency_s"] == pytest.approx(expected_latency_s, abs=1e-9)
    if t >= expected_latency_s - EPS:
        assert expected_latency_s - EPS <= age <= expected_latency_s + SIM_DT_S + EPS, (t, expected_latency_s, age)
    else:
        assert age == pytest.approx(t, abs=EPS), (t, expected_latency_s, age)  # the reset snapshot
    # The observed state is the one recorded at t - age.
    assert info["observed_state"]["time_s"] == pytest.approx(t - age, abs=EPS)


# -- parsing ---------------------------------------------------------------------------------------


def test_parse_each_kind(tmp_path):
    const = parse_profile("const:0.2")
    assert const.latency_s(0.0) == 0.2 and const.latency_s(7.3) == 0.2 and const.max_latency_s == 0.2
    for spec in ("none", "0", 0, 0.0, " none "):
        assert parse_profile(spec).latency_s(3.0) == 0.0
    assert parse_profile(0.15).latency_s(1.0) == 0.15
    assert str(parse_profile(" const:0.2 ")) == "const:0.2"

    steps = parse_profile("steps:0.1-0.3:0.5")
    assert steps.max_latency_s == 0.3
    steps.reset(np.random.default_rng(0))
    values = [steps.latency_s(t) for t in np.arange(0.0, 5.0, 0.05)]
    assert all(0.1 <= v <= 0.3 for v in values)
    assert len(set(values)) == 10  # 5 s redrawn every 0.5 s
    assert steps.latency_s(0.0) == steps.latency_s(0.49) != steps.latency_s(0.5)

    sine = parse_profile("sine:0.2:0.1:2")
    assert sine.latency_s(0.0) == pytest.approx(0.2)
    assert sine.latency_s(0.5) == pytest.approx(0.3)  # a quarter period: the crest
    assert sine.latency_s(1.5) == pytest.approx(0.1)
    assert sine.max_latency_s == pytest.approx(0.3)

    ramp = parse_profile("ramp:0-0.4:2")
    assert [ramp.latency_s(t) for t in (0.0, 1.0, 2.0, 9.0)] == pytest.approx([0.0, 0.2, 0.4, 0.4])
    down = parse_profile("ramp:0.3-0.1:1")
    assert down.latency_s(0.5) == pytest.approx(0.2) and down.max_latency_s == pytest.approx(0.3)

    path = write_trace(tmp_path / "trace.csv", [(0.0, 0.1), (1.0, 0.3), (2.0, 0.2)])
    trace = parse_profile(f"trace:{path}")
    assert [trace.latency_s(t) for t in (-1.0, 0.0, 0.5, 1.0, 1.5, 5.0)] == pytest.approx([0.1, 0.1, 0.2, 0.3, 0.25, 0.2])
    assert trace.max_latency_s == pytest.approx(0.3)


def test_ranges_accept_exponent_notation():
    steps = parse_profile("steps:1e-05-0.3:1")
    assert (steps.low_s, steps.high_s, steps.period_s) == (1e-05, 0.3, 1.0)
    assert parse_profile("ramp:0.1-2e-1:1").latency_s(5.0) == pytest.approx(0.2)
    with pytest.raises(ValueError, match="-0.1"):
        parse_profile("steps:-0.1-0.3:1")


def test_steps_needs_a_reset_first():
    with pytest.raises(RuntimeError, match="reset"):
        parse_profile("steps:0-0.3:1").latency_s(0.0)


@pytest.mark.parametrize(
    "spec",
    ["const:-0.1", "const:nan", "const:inf", "const:abc", "foo:1", "const", "const:0.1:2", "steps:0.3-0.1:1",
     "steps:0.1:1", "steps:0-0.3:0", "steps:0-0.3:-1", "sine:0.1:0.2:1", "sine:0.1:0.05:0", "sine:-0.1:0:1",
     "ramp:0-0.4:0", "ramp:0.4:1", "ramp:0-inf:1", "trace:/definitely/not/here.csv"],
)
def test_bad_specs_quote_the_offending_text(spec):
    with pytest.raises(ValueError) as excinfo:
        parse_profile(spec)
    assert spec in str(excinfo.value)


def test_trace_with_a_bad_row_names_the_row(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("t,latency_s\n0.0,0.1\n0.5,oops\n1.0,0.2\n")
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    assert "row 3" in str(excinfo.value) and "oops" in str(excinfo.value) and str(path) in str(excinfo.value)


@pytest.mark.parametrize(
    ("content", "fragments"),
    [
        ("t,latency_s\n0.0,0.1\n1.0,-0.2\n", ["row 3", "negative"]),
        ("t,latency_s\n0.0,0.1\n1.0,0.2\n1.0,0.3\n", ["row 4", "increase"]),
        ("t,latency_s\n0.0,nan\n", ["row 2", "finite"]),
        ("time,latency\n0.0,0.1\n", ["missing columns"]),
        ("t,latency_s\n", ["no rows"]),
    ],
)
def test_trace_errors(tmp_path, content, fragments):
    path = tmp_path / "trace.csv"
    path.write_text(content)
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    for fragment in fragments:
        assert fragment in str(excinfo.value)


def test_profile_beyond_the_buffer_is_rejected():
    with pytest.raises(ValueError) as excinfo:
        LatencyWrapper(base_env(), "const:1.5", max_latency_s=1.0)
    assert "const:1.5" in str(excinfo.value)
    with pytest.raises(ValueError, match="sine:0.6:0.5:1"):
        LatencyWrapper(base_env(), "sine:0.6:0.5:1", max_latency_s=1.0)
    LatencyWrapper(base_env(), "const:1.5", max_latency_s=2.0)  # a larger buffer accepts it


# -- property: the observation age follows the latency, for every profile kind ---------------------

latency = st.floats(0.0, 0.8)
period = st.floats(0.1, 2.0)
episode = st.fixed_dictionaries({
    "steps": st.integers(1, 100), "seed": st.integers(0, 2**16), "action_seed": st.integers(0, 2**16),
    "policy_hz": st.sampled_from([20, 20, 10, 5]),
})


def check_episode(spec: str, expected, episode: dict) -> None:
    env = LatencyWrapper(base_env(episode["policy_hz"]), spec)
    records, _ = run_episode(env, episode["steps"], episode["seed"], episode["action_seed"])
    assert records[0][1]["observation_age_s"] == 0.0
    for _, info in records:
        assert_age_follows_latency(info, expected(info["time"]))


@settings(max_examples=25, deadline=None)
@given(value=latency, episode=episode)
def test_age_property_const(value, episode):
    check_episode(f"const:{value!r}", lambda t: value, episode)


@settings(max_examples=25, deadline=None)
@given(mean_frac=st.tuples(st.floats(0.0, 0.45), st.floats(0.0, 1.0)), period_s=period, episode=episode)
def test_age_property_sine(mean_frac, period_s, episode):
    mean, fraction = mean_frac
    amplitude = mean * fraction
    check_episode(f"sine:{mean!r}:{amplitude!r}:{period_s!r}",
                  lambda t: mean + amplitude * math.sin(2 * math.pi * t / period_s), episode)


@settings(max_examples=25, deadline=None)
@given(start=latency, end=latency, duration_s=st.floats(0.05, 4.0), episode=episode)
def test_age_property_ramp(start, end, duration_s, episode):
    check_episode(f"ramp:{start!r}-{end!r}:{duration_s!r}",
                  lambda t: start + (end - start) * min(t / duration_s, 1.0), episode)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(values=st.lists(latency, min_size=1, max_size=8), gaps=st.lists(st.floats(0.05, 1.5), min_size=8, max_size=8),
       episode=episode)
def test_age_property_trace(values, gaps, episode):
    times = np.concatenate([[0.0], np.cumsum(gaps)])[:len(values)]
    with tempfile.TemporaryDirectory() as tmp:
        path = write_trace(Path(tmp) / "trace.csv", [(repr(float(t)), repr(v)) for t, v in zip(times, values)])
        check_episode(f"trace:{path}", lambda t: float(np.interp(t, times, values)), episode)


@settings(max_examples=25, deadline=None)
@given(bounds=st.tuples(latency, latency).map(sorted), period_s=period, episode=episode)
def test_age_property_steps(bounds, period_s, episode):
    low, high = bounds
    env = LatencyWrapper(base_env(episode["policy_hz"]), f"steps:{low!r}-{high!r}:{period_s!r}")
    records, _ = run_episode(env, episode["steps"], episode["seed"], episode["action_seed"])
    by_period: dict[int, float] = {}
    for _, info in records:
        value = info["latency_s"]
        assert low - EPS <= value <= high + EPS
        # One value per period (indices computed by hand from the time since reset).
        index = math.floor(info["time"] / period_s + 1e-9)
        assert by_period.setdefault(index, value) == value
        assert_age_follows_latency(info, value)


@settings(max_examples=25, deadline=None)
@given(low=st.integers(0, 12), width=st.integers(0, 12), every=st.integers(1, 40), rate_hz=st.sampled_from([20, 30, 60]),
       episode=episode)
def test_age_property_frames(low, width, every, rate_hz, episode):
    high = low + width
    env = LatencyWrapper(base_env(episode["policy_hz"]), f"frames:{low}-{high}:{every}@{rate_hz}")
    records, _ = run_episode(env, episode["steps"], episode["seed"], episode["action_seed"])
    by_block: dict[int, float] = {}
    for _, info in records:
        frames = info["latency_s"] * rate_hz
        assert frames == pytest.approx(round(frames), abs=1e-9) and low <= round(frames) <= high
        # One draw per block of `every` frames of the loop (indices computed by hand from the time).
        block = math.floor(info["time"] * rate_hz / every + 1e-9)
        assert by_block.setdefault(block, info["latency_s"]) == info["latency_s"]
        assert_age_follows_latency(info, info["latency_s"])


# -- growing latency: the age never drops below it (the original ROS bug) --------------------------


@pytest.mark.parametrize("kind", ["trace", "ramp"])
def test_latency_jump_serves_older_frames_not_fresher(tmp_path, kind):
    if kind == "trace":
        spec = f"trace:{write_trace(tmp_path / 'jump.csv', [(0.0, 0.0), (1.0, 0.0), (1.05, 0.3)])}"
    else:
        spec = "ramp:0-0.3:0.05"  # 0 to 0.3 s within the first step
    env = LatencyWrapper(base_env(), spec)
    records, _ = run_episode(env, 60)
    jump_t = 1.05 if kind == "trace" else 0.05
    for _, info in records:
        t = info["time"]
        target = 0.3 if t >= jump_t - EPS else 0.0
        assert info["latency_s"] == pytest.approx(target, abs=1e-9)
        if t >= target:
            assert info["observation_age_s"] >= target - EPS, (t, info["observation_age_s"])
            assert info["observation_age_s"] == pytest.approx(target, abs=EPS)  # multiples of 0.05: exact
        else:
            assert info["observation_age_s"] == pytest.approx(t)
    # At the jump the observation goes back in time: the same instant is served again, 0.3 s later.
    observed = [info["observed_state"]["time_s"] for _, info in records]
    k = round(jump_t / SIM_DT_S)
    if kind == "trace":
        assert observed[k - 1] == pytest.approx(1.0) and observed[k] == pytest.approx(0.75)
    else:
        assert observed[k - 1] == 0.0 and observed[k] == 0.0 and observed[7] == pytest.approx(0.05)


def test_non_multiple_latency_rounds_to_the_older_snapshot():
    env = LatencyWrapper(base_env(), "const:0.12")
    records, _ = run_episode(env, 20)
    for _, info in records:
        if info["time"] >= 0.15 - EPS:
            assert info["observation_age_s"] == pytest.approx(0.15)  # 0.12 is served 0.15 old, not 0.10
        elif info["time"] >= 0.12:
            assert info["observation_age_s"] == pytest.approx(info["time"])


@pytest.mark.parametrize(("spec", "max_latency_s", "served_s"),
                         [("const:1.0", 1.0, 1.0), ("const:0.3", 0.3, 0.3), ("const:0.27", 0.3, 0.3)])
def test_latency_at_the_buffer_maximum(spec, max_latency_s, served_s):
    env = LatencyWrapper(base_env(), spec, max_latency_s=max_latency_s)
    records, _ = run_episode(env, 120)
    assert len(records) == 121
    for _, info in records:
        if info["time"] >= served_s - EPS:
            assert info["observation_age_s"] == pytest.approx(served_s)
        else:
            assert info["observation_age_s"] == pytest.approx(info["time"])
    # Old snapshots are dropped: the buffer holds about max_latency_s of history, not the episode.
    assert len(env._history) <= max_latency_s / SIM_DT_S + 4


# -- the frames and the dynamics -------------------------------------------------------------------


def test_delivered_frame_is_the_env_frame_from_t_minus_age():
    # The unwrapped run of the same seed and actions gives the frame at every time.
    plain = base_env()
    records, actions = run_episode(LatencyWrapper(plain, "steps:0.0-0.6:0.4"), 80, seed=5, action_seed=9)
    obs, info = plain.reset(seed=5)
    frames, offsets = [obs.copy()], [info["lateral_offset_m"]]
    for action in actions:
        obs, _, _, _, info = plain.step(action)
        frames.append(obs.copy())
        offsets.append(info["lateral_offset_m"])
    assert len(frames) == len(records)
    ages = set()
    for step, (delivered, info) in enumerate(records):
        age_steps = round(info["observation_age_s"] / SIM_DT_S)
        ages.add(age_steps)
        assert np.array_equal(delivered, frames[step - age_steps])
        assert info["observed_state"]["lateral_offset_m"] == offsets[step - age_steps]
    assert len(ages) >= 4  # the latency did vary
    assert not np.array_equal(frames[0], frames[-1])


def test_steps_realisation_depends_only_on_the_reset_seed():
    def realisation(seed: int, action_seed: int) -> list[float]:
        env = LatencyWrapper(base_env(), "steps:0.0-0.35:0.5")
        records, _ = run_episode(env, 100, seed=seed, action_seed=action_seed)
        return [info["latency_s"] for _, info in records]

    first = realisation(1, 0)
    assert realisation(1, 3) == first  # different actions: the same latency draws
    assert realisation(2, 0) != first
    assert len(set(first)) >= 8  # ~10 periods in 5 s


def test_wrapper_does_not_change_the_dynamics():
    plain = base_env()
    records, actions = run_episode(LatencyWrapper(plain, "sine:0.3:0.2:1.3"), 120, seed=4, action_seed=2)
    _, info = plain.reset(seed=4)
    true_infos = [info]
    for action in actions:
        *_, info = plain.step(action)
        true_infos.append(info)
    keys = ("lateral_offset_m", "heading_error_rad", "heading_rad", "arc_length_m", "x_m", "y_m", "time", "segment",
            "lane_index", "on_road", "completed_fraction")
    for (_, wrapped), plain_info in zip(records, true_infos, strict=True):
        assert {k: wrapped[k] for k in keys} == {k: plain_info[k] for k in keys}
        assert np.array_equal(wrapped["position"], plain_info["position"])


def test_wrapper_reset_with_start_options_passes_them_on():
    env = LatencyWrapper(base_env(), "const:0.2")
    _, info = env.reset(seed=0, options={"start_offset_m": 1.0})
    assert info["lateral_offset_m"] == pytest.approx(1.0)
    assert info["observed_state"]["lateral_offset_m"] == pytest.approx(1.0)
    assert info["observation_age_s"] == 0.0
