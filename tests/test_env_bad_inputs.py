"""Bad inputs to the env, its tracks and the bounded loader: each is refused before any work
with a BadInput that names the field or file, the value and the accepted range."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.errors import BadInput
from plm_highway.latency import LatencyWrapper
from plm_highway.road.track import MAX_SEGMENTS, MAX_TRACK_FILE_BYTES, load_track, parse_track

NAN, INF = float("nan"), float("inf")
STRAIGHT = {"name": "straight", "lanes": 3, "lane_width_m": 4.0, "segments": [{"type": "straight", "length_m": 300}]}


def straight(length_m) -> dict:
    return {"type": "straight", "length_m": length_m}


def arc(radius_m, angle_deg, direction: str = "left") -> dict:
    return {"type": "arc", "radius_m": radius_m, "angle_deg": angle_deg, "direction": direction}


def spec(*segments, **top) -> dict:
    return {"name": "t", "lanes": 3, "lane_width_m": 4.0, "segments": list(segments), **top}


def make(track=STRAIGHT, **config):
    return gymnasium.make(ENV_ID, config={"track": track, **config})


def refused(fragments, call, *args, **kwargs) -> str:
    with pytest.raises(BadInput) as excinfo:
        call(*args, **kwargs)
    message = str(excinfo.value)
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    return message


# -- track specs -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("raw", "fragments"), [
    # A full circle on an open track: the following straight runs over the first one.
    (spec(straight(50), arc(60, 360), straight(50)), ["overlaps itself", "(segment 0)", "(segment 1)", "a closed loop needs"]),
    (spec(arc(60, 360)), ["overlaps itself"]),
    (spec(straight(100), arc(30, 180), straight(100), arc(30, 180), straight(100)), ["overlaps itself"]),
    (spec(straight(10), name=42), ["'name'", "string", "42"]),
    (spec(straight(10), name=""), ["'name'", "1 to 100"]),
    (spec(straight(10), name=["x"]), ["'name'"]),
    (spec(straight(1e300)), ["segment 0", "length_m", "(0, 10000]", "1e+300"]),
    (spec(straight(10), arc(1e300, 90)), ["segment 1", "radius_m", "50000"]),
    (spec(straight(10), arc(50, NAN)), ["segment 1", "angle_deg", "nan"]),
    (spec(straight(10), arc(50, INF)), ["segment 1", "angle_deg"]),
    (spec(straight(10), lane_width_m=NAN), ["lane_width_m", "[2, 8]"]),
    (spec(straight(10), lane_width_m=100), ["lane_width_m", "[2, 8]"]),
    (spec(straight(9_000), straight(9_000), straight(9_000)), ["total length", "27,000", "20,000"]),
    (spec(*[straight(0.01)] * (MAX_SEGMENTS + 1)), ["1,001 segments", "1,000"]),
])
def test_bad_track_specs_are_refused(raw, fragments):
    message = refused(fragments, parse_track, raw, source="unit")
    assert message.startswith("unit")


def test_300k_segments_are_refused_without_building_them():
    # 300k one-centimetre segments once ran for minutes; the count is checked first.
    refused(["300,000 segments"], parse_track, spec(*[straight(0.01)] * 300_000))


def test_a_long_arc_that_does_not_come_back_is_accepted():
    track = parse_track(spec(straight(20), arc(60, 270), straight(20)))
    assert track.length_m == pytest.approx(40 + 60 * 1.5 * np.pi)


# -- track files -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("content", "fragments"), [
    (bytes(range(256)) * 4, ["not UTF-8 text", "byte 0x80 at offset 128"]),
    (b"\xef\xbb\xbf" + json.dumps(STRAIGHT).encode(), ["byte-order mark", "without BOM"]),
    (b"[" * 100_000 + b"]" * 100_000, ["nested 100000 deep", "at most 16"]),
    (json.dumps(spec(straight(1e300))).encode(), ["segment 0", "length_m", "(0, 10000]"]),
    (b"{\"name\": \"t\", \"segments\": [", ["not valid JSON"]),
    (b" " * (MAX_TRACK_FILE_BYTES + 1), ["larger than a track file may be", "1,048,576"]),
])
def test_bad_track_files_are_refused_naming_the_file(tmp_path, content, fragments):
    path = tmp_path / "track.json"
    path.write_bytes(content)
    message = refused(fragments, load_track, path)
    assert message.startswith(str(path))


def test_the_command_line_refuses_a_binary_track_file_with_exit_2(tmp_path):
    path = tmp_path / "garbage.json"
    path.write_bytes(os.urandom(64) + b"\xff")
    env = {**os.environ, "MPLBACKEND": "Agg", "SDL_VIDEODRIVER": "offscreen"}
    result = subprocess.run([sys.executable, "-m", "plm_highway", "demo", "zigzag", "--track", str(path),
                             "--policy", "expert", "--out", str(tmp_path / "z.png")],
                            capture_output=True, text=True, timeout=300, check=False, env=env)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and str(path) in result.stderr and "UTF-8" in result.stderr
    assert not (tmp_path / "z.png").exists()


# -- env config -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("config", "fragments"), [
    ({"max_steering_rad": NAN}, ["'max_steering_rad'", "nan", "(0, 1]"]),
    ({"max_steering_rad": 0}, ["'max_steering_rad'", "(0, 1]"]),
    ({"steering_time_constant_s": -1}, ["'steering_time_constant_s'", "[0, 5]"]),
    ({"start_offset_m": NAN}, ["'start_offset_m'", "nan"]),
    ({"start_offset_m": 50}, ["'start_offset_m'", "50"]),
    ({"start_heading_error_rad": INF}, ["'start_heading_error_rad'", "inf"]),
    ({"start_arc_length_m": 1e6}, ["'start_arc_length_m'", "[0, 300]"]),
    ({"start_lane": 5}, ["'start_lane'", "5", "from 0 to 2", "3 lanes"]),
    ({"start_lane": -1}, ["'start_lane'", "from 0 to 2"]),
    ({"start_lane": "1"}, ["'start_lane'", "'1'"]),
    ({"start_lane": True}, ["'start_lane'"]),
    ({"map_px_per_m": 0}, ["'map_px_per_m'", "[1, 40]"]),
    ({"map_px_per_m": NAN}, ["'map_px_per_m'", "nan"]),
    ({"speed_mps": 0}, ["speed", "(0, 70]"]),
    ({"speed_mps": -10}, ["speed", "(0, 70]"]),
    ({"speed_mps": NAN}, ["speed", "nan"]),
    ({"policy_frequency": 0}, ["'policy_frequency'", "1 to 1000"]),
    ({"duration_s": NAN}, ["'duration_s'", "nan"]),
    ({"curvature_preview_s": -0.5}, ["'curvature_preview_s'", "[0, 10]"]),
    ({"camera": {"mount_height_m": NAN}}, ["mount_height_m", "nan", "[0.1, 10]"]),
    ({"camera": {"mount_height_m": 0}}, ["mount_height_m", "[0.1, 10]"]),
    ({"camera": {"width_px": 200.5}}, ["width_px", "an integer"]),
    ({"camera": {"pitch_deg": -30, "fov_deg": 10}}, ["sees no ground"]),
    ({"camera": "wide"}, ["camera config", "dict"]),
    ({"vehicle_model": "dynamic", "vehicle_params": {"cg_to_front_m": 1e-9}}, ["'cg_to_front_m'", "[0.1, 10]"]),
    ({"vehicle_model": "dynamic", "vehicle_params": {"mass_kg": NAN}}, ["'mass_kg'", "nan"]),
    ({"vehicle_model": 3}, ["vehicle_model", "['dynamic', 'kinematic', 'saturating']"]),
    ({"speed": 20}, ["unknown keys", "'speed'"]),
    ({"track": {**STRAIGHT, "name": 7}}, ["'name'", "string"]),
    ({"track": spec(straight(50), arc(60, 360), straight(50))}, ["overlaps itself"]),
    # A closed circle of 1.5 km radius: its ground map would be 625 million pixels (14.5 GB at the peak before).
    ({"track": spec(arc(1500, 360), closed=True)}, ["ground map", "80,000,000 px"]),
])
def test_bad_env_configs_are_refused_before_the_first_step(config, fragments):
    def make_and_reset():
        env = gymnasium.make(ENV_ID, config={"track": STRAIGHT, **config})
        env.reset(seed=0)

    refused(fragments, make_and_reset)


@pytest.mark.parametrize(("options", "fragments"), [
    ({"start_offset_m": NAN}, ["reset options", "'start_offset_m'", "nan"]),
    ({"start_arc_length_m": -1}, ["reset options", "'start_arc_length_m'"]),
    ({"start_lane": 1}, ["reset options", "unknown keys", "start_lane"]),
])
def test_bad_reset_options_are_refused(options, fragments):
    env = make()
    refused(fragments, env.reset, seed=0, options=options)


# -- actions ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(("action", "fragments"), [
    (np.array([NAN], np.float32), ["must be finite", "nan"]),
    (np.array([INF]), ["must be finite", "inf"]),
    (np.array([-INF], np.float32), ["must be finite"]),
    (np.array([0.1, 0.2], np.float32), ["shape (1,)", "got shape (2,)"]),
    (np.array([[0.1]], np.float32), ["got shape (1, 1)"]),
    (np.array([], np.float32), ["got shape (0,)"]),
    (np.float32(0.1), ["got shape ()"]),
    (np.array(["0.1"]), ["dtype <U3"]),
    ([None], ["dtype object"]),
    (np.array([0], np.uint8), ["integer array of dtype uint8", "float32"]),
    (np.array([1], np.int64), ["integer array of dtype int64"]),
])
@pytest.mark.parametrize("wrapped", [False, True])
def test_bad_actions_are_refused(action, fragments, wrapped):
    env = make()
    if wrapped:
        env = LatencyWrapper(env, "const:0.1")
    env.reset(seed=0)
    refused(["action", *fragments], env.step, action)


def test_a_refused_action_leaves_the_env_where_it_was():
    env = make()
    _, info = env.reset(seed=0)
    with pytest.raises(BadInput):
        env.step(np.array([NAN], np.float32))
    _, _, _, _, after = env.step(np.array([0.0], np.float32))
    reference = make()
    reference.reset(seed=0)
    _, _, _, _, expected = reference.step(np.array([0.0], np.float32))
    assert after["arc_length_m"] == expected["arc_length_m"] and after["time"] == expected["time"]
    assert after["lateral_offset_m"] == expected["lateral_offset_m"]


def test_float_arrays_and_lists_of_python_numbers_of_the_right_shape_are_accepted():
    env = make()
    env.reset(seed=0)
    for action in ([0], np.array([0.05]), np.array([0.05], np.float32), [0.05], (-2.0,), (1,)):
        _, _, terminated, _, info = env.step(action)
        assert not terminated and np.isfinite(info["lateral_offset_m"])


# -- misuse that highway-env would otherwise answer with OverflowError/TypeError/AttributeError, or ignore --

HUGE = 10**400  # an integer no float holds


@pytest.mark.parametrize(("config", "fragments"), [
    ({"observation": {"type": "Kinematics"}}, ["'observation'", "Kinematics", "does not use it"]),
    ({"action": {"type": "DiscreteMetaAction"}}, ["'action'", "DiscreteMetaAction"]),
    ({"manual_control": True}, ["'manual_control'", "True"]),
    ({"render_agent": "x"}, ["'render_agent'"]),
    ({"real_time_rendering": 1e308}, ["'real_time_rendering'"]),
    ({"centering_position": [1e308, 0.5]}, ["'centering_position'"]),
    ({"other_vehicles_type": "os.system"}, ["'other_vehicles_type'"]),
    ({"offscreen_rendering": "yes"}, ["'offscreen_rendering'", "true or false"]),
    ({"speed_mps": HUGE}, ["speed", "(0, 70]"]),
    ({"speed_mps": [[0, 10], [HUGE, 12]]}, ["speed_mps", "[1]"]),
    ({"duration_s": HUGE}, ["'duration_s'", "characters)"]),
    ({"max_steering_rad": HUGE}, ["'max_steering_rad'", "(0, 1]"]),
    ({"start_offset_m": HUGE}, ["'start_offset_m'"]),
    ({"start_lane": HUGE}, ["'start_lane'", "characters)"]),
    ({"track": 5}, ["config['track']", "a path to a track JSON file"]),
    ({"track": ["test"]}, ["config['track']"]),
])
def test_env_misuse_is_refused_naming_the_setting(config, fragments):
    def make_and_reset():
        env = gymnasium.make(ENV_ID, config={"track": STRAIGHT, **config})
        env.reset(seed=0)

    refused(fragments, make_and_reset)


@pytest.mark.parametrize(("call", "fragments"), [
    (lambda: gymnasium.make(ENV_ID, config=[1]), ["config", "dict", "list"]),
    (lambda: make().reset(seed=0, options=[1]), ["reset options", "dict", "list"]),
    (lambda: make().reset(seed=0, options={"config": 5}), ["options['config']", "int"]),
    (lambda: make().reset(seed=0, options={"start_offset_m": HUGE}), ["reset options", "'start_offset_m'"]),
    (lambda: LatencyWrapper(make(), HUGE), ["latency", "too large"]),
])
def test_misused_calls_are_refused_naming_the_argument(call, fragments):
    refused(fragments, call)


def test_the_default_fixed_settings_are_still_accepted():
    env = make(observation={"type": "DashCamera"}, manual_control=False, offscreen_rendering=True)
    frame, _ = env.reset(seed=0)
    assert frame.shape == (66, 200)


# -- the bounded loader: linear time, explicit limits, each refusal naming file, field and limit ---------


@pytest.mark.timeout(10)
def test_a_megabyte_of_escaped_quotes_is_read_in_linear_time(tmp_path):
    from plm_highway.io.bounded import json_depth

    text = '{"name": "' + '\\"' * 500_000 + '", "x": [[1]]}'
    assert json_depth(text)[0] == 3  # the object, the list, the list in it
    unterminated = '["' + '\\"' * 500_000
    assert json_depth(unterminated)[0] == 1
    path = tmp_path / "t.json"
    path.write_text(unterminated)
    refused([str(path), "not valid JSON"], load_track, path)


def _reference_depth(value) -> int:
    if isinstance(value, dict):
        return 1 + max((_reference_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_reference_depth(v) for v in value), default=0)
    return 0


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(alphabet='ab"\\[]{}\n', max_size=6),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text('ab"\\[{', max_size=3), children,
                                                                      max_size=3),
    max_leaves=12)


@given(JSON_VALUES)
def test_the_linear_depth_scan_agrees_with_the_documents_structure(value):
    from plm_highway.io.bounded import json_depth, parse_json

    text = json.dumps(value)
    assert json_depth(text)[0] == _reference_depth(value)
    assert parse_json(text, "doc") == value


@given(st.lists(st.sampled_from(["a", "b", "c"]), min_size=2, max_size=5))
def test_a_key_given_twice_is_always_named(keys):
    from plm_highway.io.bounded import parse_json

    text = "{" + ", ".join(f'"{key}": {i}' for i, key in enumerate(keys)) + "}"
    if len(set(keys)) == len(keys):
        assert parse_json(text, "doc") == {key: i for i, key in enumerate(keys)}
        return
    first_repeat = next(key for i, key in enumerate(keys) if key in keys[:i])
    refused(["doc", f"key {first_repeat!r}", "more than once"], parse_json, text, "doc")


@pytest.mark.timeout(10)
@pytest.mark.parametrize(("text", "fragments"), [
    ("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{n}: &{n} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n" for p, n in zip("abcdefgh", "bcdefghi")),
     ["grid.yaml", "after expansion", "node limit"]),
    ("a: &a '" + "x" * 100_000 + "'\nb: [" + ", ".join(["*a"] * 60) + "]\n", ["grid.yaml", "expansion limit"]),
    ("a: &a [*a]\n", ["grid.yaml"]),
    ("a: " + "[" * 5000 + "]" * 5000 + "\n", ["grid.yaml", "nested more than 16 deep"]),
    ("a:\n  b: " + "9" * 5000 + "\n", ["grid.yaml", "'a.b'", "5,000 digits"]),
    ("a: 1\nb: 2\na: 3\n", ["grid.yaml", "'a'", "more than once"]),
    ("a: !!python/name:os.system\n", ["grid.yaml", "not valid YAML"]),
])
def test_bad_yaml_is_refused_in_bounded_time(text, fragments):
    from plm_highway.io.bounded import JsonLimits, parse_yaml

    refused(fragments, parse_yaml, text, "grid.yaml",
            JsonLimits(max_depth=16, max_nodes=200_000, max_int_digits=20, max_expanded_chars=4 << 20))


def test_yaml_aliases_within_the_limits_are_read():
    from plm_highway.io.bounded import parse_yaml

    assert parse_yaml("a: &a [1, 2]\nb: *a\n", "g") == {"a": [1, 2], "b": [1, 2]}


@given(labels=st.lists(st.text("aA_-/. t", min_size=1, max_size=6), min_size=1, max_size=6, unique=True))
def test_file_names_stay_distinct_whatever_the_labels(labels):
    from plm_highway.io import unique_file_names

    names = unique_file_names(labels, suffix=".png")
    assert len({name.lower() for name in names}) == len(names)
    assert all(set(name) <= set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789.+-") for name in names)
