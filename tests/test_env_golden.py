"""Golden run: the env computes what it computed before it was optimised.

``tests/data/env_golden.json`` was recorded from the env *before* it was optimised
(commit f974516) by ``PYTHONPATH=. python tests/test_env_golden.py --record``. It holds, for a
few fixed seeded runs (expert policy plus a sine perturbation that also drives the action past its
clip, with and without a ``const:0.2`` latency, and a closed track at a 10 Hz policy rate):

- the pose of the car after every step, to full float precision;
- a SHA-256 prefix of every delivered frame and of every ``info`` (canonical JSON: floats exact);
- the full ``info`` every 50 steps and a few whole frames (PNG), so a failure says what changed.

The runs pin ``map_px_per_m: 10.0`` (the map resolution of the recording), so they stay comparable
when the default resolution changes; the frames at the default resolution are compared with these
within a documented mean absolute pixel tolerance in ``test_camera.py``.
If a change is *meant* to alter the result, regenerate the fixture in a commit of its own that says why.

Floats in ``info`` are compared to :data:`INFO_DECIMALS` decimals (the per-step digests) and to
:data:`INFO_TOLERANCE` (the samples), poses and frames exactly: the track's lane geometry is built by
highway-env with numpy, whose float64 transcendental functions are CPU-dispatched (on an AVX-512 Xeon
``np.arctan2`` differs from libm's ``atan2`` in the last bit where an AVX2 CPU agreed), so the lateral
offset and the heading error can move by 1e-15 between machines while nothing the car does changes.

Regenerations (each in its own commit):
1. The camera warps only the rows that see ground (the sky rows were overwritten anyway, and warping
   them took OpenCV's slow border path: ~3x the cost of the ground rows). OpenCV's fixed-point warp
   rounds a row-shifted homography slightly differently: 0.13% of the pixels of the 400 frames of
   ``expert_no_latency`` changed by one gray level (never more). Poses and ``info`` were unchanged.
   ``test_camera.py::test_ground_row_warp_matches_the_full_frame_warp`` keeps that bound.
2. The per-step ``info`` digests only, re-taken over ``info`` rounded to :data:`INFO_DECIMALS` decimals
   (they had hashed exact floats, which differ between CPUs in the last bit, see above); poses, frames
   and ``info`` samples are the original recording's, and the runs reproduced them (samples within
   :data:`INFO_TOLERANCE`) when the digests were re-taken.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
import sys
from pathlib import Path

import cv2
import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.expert import ExpertPolicy
from plm_highway.latency import LatencyWrapper

FIXTURE = Path(__file__).resolve().parent / "data" / "env_golden.json"
INFO_SAMPLE_EVERY = 50
INFO_DECIMALS = 9  # per-step info digests: floats rounded to 1e-9 (see the module docstring)
INFO_TOLERANCE = 1e-12  # info samples: relative and absolute
SQUARE_LOOP = {"name": "golden_loop", "lanes": 3, "lane_width_m": 4.0, "closed": True,
               "segments": [s for _ in range(4) for s in ({"type": "straight", "length_m": 100},
                                                          {"type": "arc", "radius_m": 50, "angle_deg": 90,
                                                           "direction": "left"})]}
RUNS = {
    "expert_no_latency": {
        "config": {"track": "test", "map_px_per_m": 10.0}, "latency": None, "steps": 400, "seed": 0,
        "options": {"start_arc_length_m": 90.0, "start_offset_m": 0.4, "start_heading_error_rad": 0.01},
        "frame_steps": [0, 133, 266, 399],
    },
    "expert_const_0.2": {
        "config": {"track": "test", "map_px_per_m": 10.0}, "latency": "const:0.2", "steps": 400, "seed": 0,
        "options": {"start_arc_length_m": 90.0, "start_offset_m": 0.4, "start_heading_error_rad": 0.01},
        "frame_steps": [],
    },
    "closed_loop_10hz": {
        "config": {"track": SQUARE_LOOP, "map_px_per_m": 10.0, "policy_frequency": 10}, "latency": None,
        "steps": 150, "seed": 3, "options": {"start_arc_length_m": 600.0, "start_offset_m": -0.3},
        "frame_steps": [],
    },
}


def perturbation(step: int) -> float:
    return 0.4 * math.sin(0.15 * step)


def canonical(value):
    """JSON-ready copy with every number as an exact Python float/int."""
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [canonical(v) for v in np.asarray(value).tolist()] if isinstance(value, np.ndarray) \
            else [canonical(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    return value


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def rounded(value):
    """``canonical(value)`` with every float rounded to :data:`INFO_DECIMALS` decimals (and -0.0 made 0.0)."""
    if isinstance(value, dict):
        return {key: rounded(v) for key, v in value.items()}
    if isinstance(value, list):
        return [rounded(v) for v in value]
    if isinstance(value, float):
        return round(value, INFO_DECIMALS) + 0.0
    return value


def info_digest(info: dict) -> str:
    return digest(json.dumps(rounded(canonical(info)), sort_keys=True).encode())


def assert_info_close(actual, expected, where: str) -> None:
    """Equal, except floats within :data:`INFO_TOLERANCE` (relative or absolute)."""
    if isinstance(expected, dict):
        assert sorted(actual) == sorted(expected), f"{where}: keys {sorted(actual)} vs {sorted(expected)}"
        for key in expected:
            assert_info_close(actual[key], expected[key], f"{where}[{key!r}]")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), f"{where}: {actual!r} vs {expected!r}"
        for k, (a, b) in enumerate(zip(actual, expected)):
            assert_info_close(a, b, f"{where}[{k}]")
    elif isinstance(expected, float):
        assert isinstance(actual, float) and math.isclose(actual, expected, rel_tol=INFO_TOLERANCE,
                                                          abs_tol=INFO_TOLERANCE), f"{where}: {actual!r} vs {expected!r}"
    else:
        assert type(actual) is type(expected) and actual == expected, f"{where}: {actual!r} vs {expected!r}"


def recorded_keys(samples: dict) -> dict:
    """The info keys the fixture recorded (nested dicts as nested key sets): keys added later do
    not change what was computed before, so they are left out of the comparison."""
    keys: dict = {}
    for sample in samples.values():
        for key, value in sample.items():
            keys[key] = recorded_keys({"sample": value}) if isinstance(value, dict) else None
    return keys


def restricted(info: dict, keys: dict | None) -> dict:
    """``info`` with only the recorded keys; the step's own extras (``_reward``...) need not be there."""
    if keys is None:
        return info
    missing = sorted(key for key in set(keys) - set(info) if not key.startswith("_"))
    assert not missing, f"info lost keys {missing}"
    return {key: restricted(info[key], sub) if isinstance(info[key], dict) else info[key]
            for key, sub in keys.items() if key in info}


def play(spec: dict, keys: dict | None = None) -> dict:
    """Run one golden configuration; return what the fixture records (``info`` limited to ``keys``)."""
    env = gymnasium.make(ENV_ID, config=spec["config"])
    if spec["latency"] is not None:
        env = LatencyWrapper(env, spec["latency"])
    expert = ExpertPolicy()
    obs, info = env.reset(seed=spec["seed"], options=spec["options"])
    record = {"pose": [], "frame": [], "info": [], "info_samples": {}, "frames_png": {}, "end": None}

    def keep(step: int, obs, info) -> None:
        info = restricted(info, keys)
        vehicle = env.unwrapped.vehicle
        record["pose"].append([float(vehicle.position[0]), float(vehicle.position[1]), float(vehicle.heading)])
        record["frame"].append(digest(str(obs.shape).encode() + obs.tobytes()))
        record["info"].append(info_digest(info))
        if step % INFO_SAMPLE_EVERY == 0:
            record["info_samples"][str(step)] = canonical(info)
        if step in spec["frame_steps"]:
            record["frames_png"][str(step)] = base64.b64encode(cv2.imencode(".png", obs)[1].tobytes()).decode()

    keep(0, obs, info)
    for step in range(1, spec["steps"] + 1):
        action = np.array([expert(obs, info) + perturbation(step)], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        info = {**info, "_reward": reward, "_terminated": terminated, "_truncated": truncated}
        keep(step, obs, info)
        if terminated or truncated:
            record["end"] = step
            break
    env.close()
    return record


def decode_png(text: str) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(base64.b64decode(text), np.uint8), cv2.IMREAD_UNCHANGED)


@pytest.fixture(scope="module")
def golden() -> dict:
    return json.loads(FIXTURE.read_text())


@pytest.mark.parametrize("name", list(RUNS))
def test_golden_run_is_unchanged(golden, name):
    expected = golden["runs"][name]
    actual = play(RUNS[name], keys=recorded_keys(expected["info_samples"]))
    assert actual["end"] == expected["end"]
    assert len(actual["pose"]) == len(expected["pose"])
    # Poses first: they say where a divergence started.
    for step, (got, want) in enumerate(zip(actual["pose"], expected["pose"])):
        assert got == want, f"{name}: pose at step {step} is {got}, was {want}"
    for step, want in expected["info_samples"].items():
        assert_info_close(actual["info_samples"][step], want, f"{name}: info at step {step}")
    for step, want in expected["frames_png"].items():
        frame = decode_png(actual["frames_png"][step])
        diff = np.abs(frame.astype(int) - decode_png(want).astype(int))
        assert diff.max() == 0, f"{name}: frame {step} differs (mean abs {diff.mean():.3f}, max {diff.max()})"
    first_bad_frame = next((i for i, (a, b) in enumerate(zip(actual["frame"], expected["frame"])) if a != b), None)
    assert first_bad_frame is None, f"{name}: frame at step {first_bad_frame} changed"
    first_bad_info = next((i for i, (a, b) in enumerate(zip(actual["info"], expected["info"])) if a != b), None)
    assert first_bad_info is None, f"{name}: info at step {first_bad_info} changed"


def test_golden_runs_exercise_what_they_claim(golden):
    """The fixture is not vacuous: the runs steer, clip, see the delay and wrap around the loop."""
    plain = golden["runs"]["expert_no_latency"]["info_samples"]
    steering = [sample["steering"] for sample in plain.values()]
    assert max(abs(s) for s in steering) > 0.3
    assert {sample["segment"] for sample in plain.values()} >= {"straight", "left", "right"}
    delayed = golden["runs"]["expert_const_0.2"]["info_samples"]["200"]
    assert delayed["observation_age_s"] == pytest.approx(0.2)
    assert delayed["observed_state"]["time_s"] == pytest.approx(delayed["time_s"] - 0.2)
    loop = golden["runs"]["closed_loop_10hz"]
    arc_lengths = [sample["arc_length_m"] for sample in loop["info_samples"].values()]
    assert min(arc_lengths) < 100 < 600 < max(arc_lengths)  # started at 600 m, wrapped past the start
    assert len(set(golden["runs"]["expert_no_latency"]["frame"])) > 390  # the frames change as the car moves


def write_fixture(text: str) -> None:
    """The fixture is the tests' own file: written whole (temporary file, then rename)."""
    FIXTURE.parent.mkdir(exist_ok=True)
    staging = FIXTURE.with_name(FIXTURE.name + ".tmp")
    staging.write_text(text + "\n")
    staging.replace(FIXTURE)


def retake_info_digests() -> None:
    """Regeneration 2: replace only the per-step info digests, after checking that the runs reproduce the
    recording's poses, frames and info samples."""
    fixture = json.loads(FIXTURE.read_text())
    for name, spec in RUNS.items():
        expected = fixture["runs"][name]
        actual = play(spec, keys=recorded_keys(expected["info_samples"]))
        assert actual["pose"] == expected["pose"] and actual["frame"] == expected["frame"], name
        for step, want in expected["info_samples"].items():
            assert_info_close(actual["info_samples"][step], want, f"{name}: info at step {step}")
        expected["info"] = actual["info"]
    write_fixture(json.dumps(fixture, separators=(",", ":")))
    print(f"re-took the info digests of {FIXTURE}")


def record() -> None:
    runs = {name: play(spec) for name, spec in RUNS.items()}
    text = json.dumps({"recorded_by": "tests/test_env_golden.py --record", "runs": runs}, separators=(",", ":"))
    write_fixture(text)
    print(f"wrote {FIXTURE} ({len(text) / 1024:.0f} KiB)")


if __name__ == "__main__":
    if sys.argv[1:] == ["--record"]:
        record()
    elif sys.argv[1:] == ["--retake-info-digests"]:
        retake_info_digests()
    else:
        raise SystemExit("usage: python tests/test_env_golden.py --record | --retake-info-digests")
