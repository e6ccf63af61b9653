"""Profiles draw lazily in bounded memory, and every spec and trace size has a checked bound."""

from __future__ import annotations

import math
import pickle
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.latency import parse_profile
from plm_highway.latency import profiles as latency_profiles
from plm_highway.latency.profiles import MAX_TRACE_BYTES, FramesProfile, StepsProfile


def seeded(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


# -- lazy draws: the same values as drawing one after another, in O(1) memory -------------------


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), low=st.floats(0.0, 0.5), width=st.floats(0.0, 0.5),
       period_s=st.floats(0.001, 3.0), order=st.randoms(use_true_random=False))
def test_steps_values_are_the_sequential_draws_in_any_query_order(seed, low, width, period_s, order):
    high = low + width
    profile = StepsProfile(low, high, period_s)
    profile.reset(seeded(seed))
    expected = seeded(seed).uniform(low, high, size=40)  # draw i holds during period i
    indices = list(range(40)) * 2
    order.shuffle(indices)
    for index in indices:
        t_s = (index + 0.5) * period_s
        assert profile.latency_s(t_s) == expected[index]


def test_steps_values_for_todays_spec_are_unchanged():
    # steps:0.0-0.35:1.0 redraws at whole seconds; the values are numpy's uniform draws in order, as before.
    profile = parse_profile("steps:0.0-0.35:1.0")
    profile.reset(seeded(7))
    values = [profile.latency_s(t) for t in np.arange(0.0, 30.0, 0.05)]
    expected = np.repeat(seeded(7).uniform(0.0, 0.35, size=30), 20)
    assert values == list(expected)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), low=st.integers(0, 30), width=st.integers(0, 30),
       every=st.integers(1, 100), rate=st.sampled_from([20, 30, 60]))
def test_frames_values_are_integer_frames_of_the_sequential_draws(seed, low, width, every, rate):
    high = low + width
    profile = FramesProfile(low, high, every, float(rate))
    profile.reset(seeded(seed))
    uniforms = seeded(seed).random(size=6)
    for block, u in enumerate(uniforms):
        expected_frames = low + math.floor(u * (width + 1))
        for frame in (block * every, block * every + every - 1):
            t_s = frame / rate
            assert profile.frames(t_s) == expected_frames
            assert profile.latency_s(t_s) == expected_frames / rate


@pytest.mark.parametrize(("spec", "latencies_s", "redraw_s"),
                         [("frames:9-21:60@30", [k / 30 for k in range(9, 22)], 2.0),
                          ("frames:9-21:60@60", [k / 60 for k in range(9, 22)], 1.0)])
def test_the_original_frames_profile_in_both_timebases(spec, latencies_s, redraw_s):
    # @30: the original's 30 Hz loop, 0.30..0.70 s every 2 s; @60: the paper's reading, 0.15..0.35 s every 1 s.
    profile = parse_profile(spec)
    profile.reset(seeded(3))
    by_block: dict[int, float] = {}
    for t_s in np.arange(0.0, 600.0, 1 / 30):
        value = profile.latency_s(t_s)
        assert any(value == pytest.approx(allowed, abs=1e-12) for allowed in latencies_s)
        assert by_block.setdefault(math.floor(t_s / redraw_s + 1e-9), value) == value
    assert {round(value * 1e6) for value in by_block.values()} == {round(v * 1e6) for v in latencies_s}
    assert profile.max_latency_s == pytest.approx(latencies_s[-1])


@settings(max_examples=30, deadline=None)
@given(spec=st.sampled_from(["steps:0.0-0.35:0.001", "steps:0-0.3:1", "frames:9-21:60@30", "frames:0-1000:1@1000"]),
       times_s=st.lists(st.floats(0.0, 1e6), min_size=1, max_size=30), seed=st.integers(0, 2**16))
def test_profile_state_does_not_grow_with_the_times_asked(spec, times_s, seed):
    profile = parse_profile(spec)
    profile.reset(seeded(seed))
    profile.latency_s(0.0)
    size = len(pickle.dumps(profile))
    for t_s in times_s:
        profile.latency_s(t_s)
    # The pickled state is the generator's start state, the last index and its draw: its size does not
    # depend on how many times were asked (a stored draw is 9 bytes; the index, below 2**128, at most 17).
    assert len(pickle.dumps(profile)) <= size + 17


def test_200k_fine_grained_redraws_allocate_nothing_that_stays():
    # The audit's case: steps:0.0-0.35:0.001 stored 50 draws per 0.05 s step (329 MB over 200k steps).
    profile = parse_profile("steps:0.0-0.35:0.001")
    profile.reset(seeded(0))
    profile.latency_s(0.0)
    tracemalloc.start()
    try:
        for step in range(20_000):
            profile.latency_s(step * 0.05)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert current < 4096 and peak < 16384, (current, peak)  # stored draws would be 1M floats here


def test_query_far_in_the_future_is_immediate():
    profile = parse_profile("steps:0-0.3:0.001")
    profile.reset(seeded(0))
    value = profile.latency_s(1e12)  # period 1e15: jumps ahead instead of drawing 1e15 values
    assert 0.0 <= value <= 0.3 and value == profile.latency_s(1e12)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), spec=st.sampled_from(["steps:0-0.35:0.5", "frames:9-21:60@60"]))
def test_same_seed_same_realisation_different_seed_different(seed, spec):
    def realisation(rng_seed: int) -> list[float]:
        profile = parse_profile(spec)
        profile.reset(seeded(rng_seed))
        return [profile.latency_s(t) for t in np.arange(0.0, 60.0, 0.25)]

    assert realisation(seed) == realisation(seed)
    assert realisation(seed) != realisation(seed + 1)


def test_draws_do_not_consume_the_callers_generator():
    rng = seeded(5)
    profile = parse_profile("steps:0-0.3:0.1")
    profile.reset(rng)
    for t_s in np.arange(0.0, 10.0, 0.05):
        profile.latency_s(t_s)
    assert rng.random() == seeded(5).random()


def test_other_bit_generators_are_deterministic_too():
    def values(seed: int) -> list[float]:
        profile = parse_profile("steps:0-0.3:0.1")
        profile.reset(np.random.Generator(np.random.MT19937(seed)))
        return [profile.latency_s(t) for t in np.arange(0.0, 5.0, 0.1)]

    assert values(1) == values(1) != values(2)


def test_random_profile_needs_a_reset_first():
    for spec in ("steps:0-0.3:1", "frames:9-21:60@30"):
        with pytest.raises(RuntimeError, match="reset"):
            parse_profile(spec).latency_s(0.0)


@pytest.mark.parametrize("spec", ["const:0.2", "steps:0-0.3:1", "frames:9-21:60@30", "sine:0.2:0.1:1", "ramp:0-0.3:1"])
@pytest.mark.parametrize("t_s", [math.nan, math.inf, -math.inf])
def test_time_must_be_finite(spec, t_s):
    profile = parse_profile(spec)
    profile.reset(seeded(0))
    if spec.startswith("const"):
        assert profile.latency_s(t_s) == 0.2  # a constant does not look at the time
        return
    with pytest.raises(ValueError, match="finite"):
        profile.latency_s(t_s)


# -- spec grammar and bounds ---------------------------------------------------------------------


@pytest.mark.parametrize(("spec", "latency_s"), [
    ("none", 0.0), ("0", 0.0), ("0.25", 0.25), ("1e-1", 0.1), (".5", 0.5), ("const:10", 10.0), (0.3, 0.3), (0, 0.0),
    (np.float64(0.2), 0.2),
])
def test_accepted_constant_forms(spec, latency_s):
    profile = parse_profile(spec)
    assert profile.latency_s(1.0) == latency_s and profile.spec.startswith("const:")


BAD_SPECS = [
    # (spec, fragments the message must contain)
    ("", ["''", "empty", "none"]),
    ("   ", ["empty"]),
    ("x" * 5000, ["5000 characters", "4096"]),
    ("const:0.1\x00", ["control character"]),
    ("const:0.1\x1b[2J", ["control character"]),
    ("const:11", ["const:11", "11.0", "[0, 10] s"]),
    ("12", ["12", "[0, 10] s"]),
    ("const:1e999", ["1e999", "not finite"]),
    ("const:1_0", ["1_0", "not a plain"]),
    ("const:0x1", ["0x1", "not a plain"]),
    ("const:+0.1", ["+0.1", "not a plain"]),
    ("const:NaN", ["NaN", "not a plain"]),
    ("const:Infinity", ["Infinity"]),
    ("const:", ["const:"]),
    ("steps:0-0.3:1e-9", ["1e-09", "[0.001, 1e+06] s"]),
    ("steps:0-0.3:0.0009", ["0.0009", "0.001"]),
    ("steps:0-0.3:2e6", ["2000000.0", "1e+06"]),
    ("steps:0-11:1", ["range end", "11.0"]),
    ("steps:0.3-0.1:1", ["range end", "below"]),
    ("steps:0--0.1:1", ["-0.1"]),
    ("frames:9-21:60", ["60", "EVERY@RATE"]),
    ("frames:9-21:60@0", ["loop rate", "[1, 1000] Hz"]),
    ("frames:9-21:60@2000", ["loop rate", "2000"]),
    ("frames:21-9:60@30", ["below its start"]),
    ("frames:9.5-21:60@30", ["9.5", "whole number"]),
    ("frames:9-21:0@30", ["at least 1"]),
    ("frames:0-400:60@30", ["400 frames", "[0, 10] s"]),
    ("frames:9-21:1@2000", ["2000"]),
    ("frames:9-21:1234567890@30", ["1234567890", "9 digits"]),
    ("frames:9-21:60@nan", ["nan"]),
    ("sine:6:5:1", ["crest", "[0, 10] s"]),
    ("sine:0.1:0.2:1", ["amplitude", "exceeds mean"]),
    ("sine:0.2:0.1:0", ["period", "0.001"]),
    ("ramp:0-0.3:1e-4", ["duration", "0.001"]),
    ("ramp:0-20:1", ["ramp end", "[0, 10] s"]),
    ("trace:", ["expected one of"]),
    ("pulse:0.1", ["expected one of", "frames:LO-HI:EVERY@RATE"]),
]


@pytest.mark.parametrize(("spec", "fragments"), BAD_SPECS, ids=[repr(spec)[:30] for spec, _ in BAD_SPECS])
def test_bad_specs_are_refused_before_any_work(spec, fragments):
    with pytest.raises(ValueError) as excinfo:
        parse_profile(spec)
    message = str(excinfo.value)
    assert message.startswith("latency spec")
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    assert len(message) < 400  # a 5000-character spec is not echoed whole


@pytest.mark.parametrize("value", [True, None, [0.1], {"const": 0.1}, math.nan, -0.1, math.inf, 10.5])
def test_non_string_specs_are_refused(value):
    with pytest.raises(ValueError, match="latency"):
        parse_profile(value)


def test_spec_at_the_length_bound_is_parsed(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("t,latency_s\n0,0.1\n")
    padded = f"trace:{path}" + " " * (latency_profiles.MAX_SPEC_CHARS - len(f"trace:{path}"))
    assert len(padded) == latency_profiles.MAX_SPEC_CHARS
    assert parse_profile(padded).latency_s(0.0) == 0.1


# -- trace files: every defect names the file, the row and the value --------------------------------


def write_bytes(tmp_path, content: bytes, name: str = "trace.csv"):
    path = tmp_path / name
    path.write_bytes(content)
    return path


BAD_TRACES = [
    # (content, fragments besides the path)
    (b"t,latency_s\n0,0.1\n\x89PNG\r\n\x1a\n\x00\x00garbage", ["row 3", "0x89", "not UTF-8"]),
    (bytes(range(256)) * 4, ["row 2", "0x80", "not UTF-8"]),  # 0x0a, a newline, comes before 0x80
    (b"\xef\xbb\xbft,latency_s\n0,0.1\n", ["row 1", "byte-order mark"]),
    (b"t,latency_s\n0,0.1\n1,0.2\x00\n", ["row 3", "control character"]),
    (b"t,latency_s\n0,0.1\n1,nan\n", ["row 3", "'latency_s'", "'nan'", "not finite"]),
    (b"t,latency_s\n0,0.1\ninf,0.2\n", ["row 3", "'t'", "'inf'", "not finite"]),
    (b"t,latency_s\n-1,0.1\n0,0.2\n", ["row 2", "'t'", "'-1'", "negative"]),
    (b"t,latency_s\n0,0.1\n1,-0.2\n", ["row 3", "'latency_s'", "'-0.2'", "negative"]),
    (b"t,latency_s\n0,0.1\n2,0.2\n1,0.3\n", ["row 4", "'t'", "1.0", "does not increase", "previous 2.0"]),
    (b"t,latency_s\n0,0.1\n0,0.3\n", ["row 3", "does not increase"]),
    (b"t,latency_s\n0,0.1\n1,11\n", ["row 3", "'latency_s'", "11.0", "10 s"]),
    (b"t,latency_s\n0,0.1\n2e6,0.2\n", ["row 3", "'t'", "2000000.0", "1e+06 s"]),
    (b"t,latency_s\n0,0.1\n1,0x10\n", ["row 3", "'0x10'", "not a number"]),
    (b"t,latency_s\n0,0.1\n1,1_0\n", ["row 3", "'1_0'", "not a plain decimal"]),
    (b"t,latency_s\n0,0.1\n1,\n", ["row 3", "'latency_s'", "missing value"]),
    (b"t,latency_s\n0,0.1\n1\n", ["row 3", "'latency_s'", "missing value"]),
    (b"t,latency_s\n0,0.1\n\"1,0.2\n", ["row"]),
    (b"time,latency\n0,0.1\n", ["row 1", "missing columns", "'t'", "'latency_s'"]),
    (b"t,latency_s,t\n0,0.1,0\n", ["row 1", "more than once"]),
    (b"t,latency_s\n", ["no rows"]),
    (b"t,latency_s\n\n\n", ["no rows"]),
    (b"", ["empty"]),
]


@pytest.mark.parametrize(("content", "fragments"), BAD_TRACES, ids=[f"trace{i}" for i in range(len(BAD_TRACES))])
def test_bad_trace_names_file_row_and_value(tmp_path, content, fragments):
    path = write_bytes(tmp_path, content)
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    message = str(excinfo.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_trace_with_crlf_blank_lines_and_extra_columns_is_read(tmp_path):
    path = write_bytes(tmp_path, b"t, latency_s ,note\r\n0,0.1,start\r\n\r\n1.0,0.3,x\r\n2,2e-1,\r\n")
    profile = parse_profile(f"trace:{path}")
    assert [profile.latency_s(t) for t in (0.0, 0.5, 1.0, 3.0)] == pytest.approx([0.1, 0.2, 0.3, 0.2])


def test_trace_beyond_the_size_bound_is_refused_unread(tmp_path):
    path = tmp_path / "huge.csv"
    with open(path, "wb") as handle:
        handle.truncate(MAX_TRACE_BYTES + 1)  # sparse: no disk used, and it must not be read
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    assert str(path) in str(excinfo.value) and str(MAX_TRACE_BYTES + 1) in str(excinfo.value)


def test_trace_beyond_the_row_bound_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(latency_profiles, "MAX_TRACE_ROWS", 5)
    rows = "".join(f"{i},0.1\n" for i in range(6))
    path = write_bytes(tmp_path, f"t,latency_s\n{rows}".encode())
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    assert "row 7" in str(excinfo.value) and "5 data rows" in str(excinfo.value)
    write_bytes(tmp_path, f"t,latency_s\n{rows[:-6]}".encode())  # five rows: at the bound
    assert parse_profile(f"trace:{path}").max_latency_s == 0.1


@pytest.mark.parametrize("where", ["missing", "directory", "device"])
def test_trace_path_that_is_not_a_file(tmp_path, where):
    path = {"missing": tmp_path / "nope.csv", "directory": tmp_path, "device": "/dev/zero"}[where]
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    assert str(path) in str(excinfo.value)
    assert ("does not exist" if where == "missing" else "not a regular file") in str(excinfo.value)


def test_unreadable_trace_is_a_value_error(tmp_path, monkeypatch):
    path = write_bytes(tmp_path, b"t,latency_s\n0,0.1\n")

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")  # what a chmod 000 file gives a non-root user

    monkeypatch.setattr(latency_profiles, "open", refuse, raising=False)
    with pytest.raises(ValueError) as excinfo:
        parse_profile(f"trace:{path}")
    assert str(path) in str(excinfo.value) and "cannot be read (Permission denied)" in str(excinfo.value)


@settings(max_examples=40, deadline=None)
@given(base_s=st.floats(0.0, 0.5), jitter_s=st.floats(0.0, 0.1), period_s=st.floats(0.01, 1.0),
       times=st.lists(st.floats(0.0, 30.0), min_size=1, max_size=20), seed=st.integers(0, 2**31))
def test_a_jittered_profile_stays_within_its_jitter_and_is_one_realisation_per_seed(base_s, jitter_s, period_s,
                                                                                     times, seed):
    def profile():
        made = latency_profiles.JitteredProfile(f"const:{base_s!r}", jitter_s, period_s)
        made.reset(np.random.default_rng(seed))
        return made

    forward, backward = profile(), profile()
    ahead = [forward.latency_s(t) for t in sorted(times)]
    behind = [backward.latency_s(t) for t in sorted(times, reverse=True)][::-1]
    assert ahead == behind  # the draws do not depend on the order the times are asked in
    for latency_s in ahead:
        assert max(0.0, base_s - jitter_s) - 1e-12 <= latency_s <= base_s + jitter_s + 1e-12
    assert forward.max_latency_s == pytest.approx(base_s + jitter_s)
