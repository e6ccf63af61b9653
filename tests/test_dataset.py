"""The demonstration dataset: round trip, validation, atomic writes, and what the collector records."""

from __future__ import annotations

import json
import math

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.data import dataset as dataset_module
from plm_highway.data.collect import RECOVERY_WINDOW_S, collect
from plm_highway.data.dataset import FORMAT, STEP_COLUMNS, read_dataset, write_dataset
from plm_highway.envs import ENV_ID
from plm_highway.expert import expert_steering
from plm_highway.road.geometry import reference_pose_at, sample_reference
from plm_highway.road.track import load_track

N_ROWS = 12


def make_steps(n: int = N_ROWS, episodes: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    per = n // episodes
    return {
        "episode_id": np.repeat(np.arange(episodes), per).astype(np.int32),
        "t_s": np.tile(np.arange(per) * 0.05, episodes),
        "speed_mps": np.full(n, 16.7, np.float32),
        "steering": rng.uniform(-1, 1, n).astype(np.float32),
        "executed_steering": rng.uniform(-1, 1, n).astype(np.float32),
        "x_m": rng.normal(size=n) * 100,
        "y_m": rng.normal(size=n) * 100,
        "heading_rad": rng.uniform(-math.pi, math.pi, n),
        "lateral_offset_m": rng.normal(size=n).astype(np.float32),
        "perturbed": rng.random(n) < 0.5,
    }


def make_frames(n: int = N_ROWS) -> np.ndarray:
    return np.random.default_rng(1).integers(0, 256, size=(n, 8, 10), dtype=np.uint8)


def listing(path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*"))


# -- round trip ------------------------------------------------------------------------------------


def test_write_read_round_trip(tmp_path):
    frames, steps = make_frames(), make_steps()
    out = write_dataset(tmp_path / "ds", frames, steps, {"track": "test", "seed": 3})
    assert out == tmp_path / "ds"
    assert listing(out) == [".plm-highway-output.json", "frames.npy", "manifest.json", "steps.npz"]
    data = read_dataset(out)
    assert len(data) == N_ROWS
    assert isinstance(data.frames, np.memmap)  # not loaded into memory
    assert data.frames.dtype == np.uint8 and data.frames.shape == (N_ROWS, 8, 10)
    assert np.array_equal(data.frames, frames)
    assert set(data.steps) == set(STEP_COLUMNS)
    for name, dtype in STEP_COLUMNS.items():
        assert data.steps[name].dtype == np.dtype(dtype), name
        assert np.array_equal(data.steps[name], steps[name]), name
    assert data.manifest["format"] == FORMAT
    assert data.manifest["counts"] == {"samples": N_ROWS, "episodes": 3}
    assert data.manifest["track"] == "test" and data.manifest["seed"] == 3
    assert json.loads((out / "manifest.json").read_text()) == data.manifest
    in_memory = read_dataset(out, mmap=False)
    assert not isinstance(in_memory.frames, np.memmap)
    assert np.array_equal(in_memory.frames, frames)


def test_columns_are_cast_to_their_dtypes(tmp_path):
    steps = make_steps()
    steps["episode_id"] = steps["episode_id"].astype(np.int64)
    steps["speed_mps"] = steps["speed_mps"].astype(np.float64)
    data = read_dataset(write_dataset(tmp_path / "ds", make_frames(), steps, {}))
    assert data.steps["episode_id"].dtype == np.int32
    assert data.steps["speed_mps"].dtype == np.float32


# -- validation ------------------------------------------------------------------------------------


def _without(steps: dict, name: str) -> dict:
    return {k: v for k, v in steps.items() if k != name}


@pytest.mark.parametrize(
    ("mutate", "fragments"),
    [
        (lambda s: _without(s, "t_s"), ["missing", "t_s"]),
        (lambda s: {**s, "colour": np.zeros(N_ROWS)}, ["unknown", "colour"]),
        (lambda s: {**s, "x_m": s["x_m"][:-1]}, ["'x_m'", "shape", f"({N_ROWS},)"]),
        (lambda s: {**s, "steering": np.zeros((N_ROWS, 2), np.float32)}, ["'steering'", "shape"]),
        (lambda s: {**s, "y_m": np.where(np.arange(N_ROWS) == 5, np.nan, s["y_m"])}, ["'y_m'", "row 5"]),
        (lambda s: {**s, "lateral_offset_m": np.where(np.arange(N_ROWS) == 7, np.inf, 0.0)},
         ["'lateral_offset_m'", "row 7"]),
    ],
)
def test_bad_columns_are_rejected_and_nothing_is_written(tmp_path, mutate, fragments):
    with pytest.raises(ValueError) as excinfo:
        write_dataset(tmp_path / "ds", make_frames(), mutate(make_steps()), {})
    for fragment in fragments:
        assert fragment in str(excinfo.value), (fragment, str(excinfo.value))
    assert listing(tmp_path) == []  # no directory, no temporary files


@pytest.mark.parametrize("frames", [np.zeros((N_ROWS, 8, 10), np.float32), np.zeros((N_ROWS, 80), np.uint8),
                                    np.zeros((N_ROWS, 8, 10, 3), np.uint8)])
def test_bad_frames_are_rejected(tmp_path, frames):
    with pytest.raises(ValueError, match="frames"):
        write_dataset(tmp_path / "ds", frames, make_steps(), {})
    assert listing(tmp_path) == []


def test_frames_and_rows_must_agree(tmp_path):
    with pytest.raises(ValueError, match=r"\(11,\)"):
        write_dataset(tmp_path / "ds", make_frames(11), make_steps(), {})
    assert listing(tmp_path) == []


def test_read_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="manifest"):
        read_dataset(tmp_path / "nothing")
    out = write_dataset(tmp_path / "ds", make_frames(), make_steps(), {})
    manifest = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**manifest, "format": "other/9"}))
    with pytest.raises(ValueError, match="format"):
        read_dataset(out)


def test_read_validates_columns(tmp_path):
    out = write_dataset(tmp_path / "ds", make_frames(), make_steps(), {})
    steps = make_steps()
    steps["x_m"][2] = np.nan
    np.savez(out / "steps.npz", **steps)
    with pytest.raises(ValueError) as excinfo:
        read_dataset(out)
    assert "'x_m'" in str(excinfo.value) and "row 2" in str(excinfo.value)


# -- atomicity -------------------------------------------------------------------------------------


def test_rewriting_replaces_the_dataset_only_with_overwrite(tmp_path):
    out = tmp_path / "ds"
    write_dataset(out, make_frames(), make_steps(), {"version": 1})
    (out / "stale.txt").write_text("left over from the first write")
    with pytest.raises(ValueError, match="--overwrite"):
        write_dataset(out, make_frames(6), make_steps(6, episodes=2), {"version": 2})
    assert read_dataset(out).manifest["version"] == 1
    write_dataset(out, make_frames(6), make_steps(6, episodes=2), {"version": 2}, overwrite=True)
    data = read_dataset(out)
    assert len(data) == 6 and data.manifest["version"] == 2
    assert data.manifest["counts"] == {"samples": 6, "episodes": 2}
    assert listing(tmp_path) == ["ds", "ds/.plm-highway-output.json", "ds/frames.npy", "ds/manifest.json",
                                 "ds/steps.npz"]


def test_failed_rewrite_keeps_the_old_dataset(tmp_path):
    out = tmp_path / "ds"
    write_dataset(out, make_frames(), make_steps(), {"version": 1})
    before = listing(tmp_path)
    with pytest.raises(ValueError):
        write_dataset(out, make_frames(), _without(make_steps(), "steering"), {"version": 2}, overwrite=True)
    assert listing(tmp_path) == before
    assert read_dataset(out).manifest["version"] == 1


def test_crash_during_the_write_leaves_nothing_behind(tmp_path, monkeypatch):
    out = tmp_path / "ds"
    write_dataset(out, make_frames(), make_steps(), {"version": 1})
    before = listing(tmp_path)

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(dataset_module.np, "savez", crash)
    with pytest.raises(OSError, match="disk full"):
        write_dataset(out, make_frames(6), make_steps(6, episodes=2), {"version": 2}, overwrite=True)
    with pytest.raises(OSError):
        write_dataset(tmp_path / "new", make_frames(), make_steps(), {})
    monkeypatch.undo()
    assert listing(tmp_path) == before  # no half-written dataset, no temporary directory
    assert read_dataset(out).manifest["version"] == 1


# -- the collector ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def collected():
    # Seed 0 draws: episode 0 displaced, episode 1 centred, episode 2 displaced.
    return collect("test", episodes=3, episode_seconds=2.5, seed=0, progress=False)


def _start_options(track, x_m: float, y_m: float, heading_rad: float) -> dict:
    """Recover the reset options from the first recorded pose, by projecting onto the reference line."""
    ref = sample_reference(track, spacing_m=0.1)
    s_m = float(ref.s_m[np.argmin(np.hypot(ref.x_m - x_m, ref.y_m - y_m))])
    for _ in range(20):
        px, py, h = reference_pose_at(track, s_m)
        s_m += (x_m - px) * math.cos(h) + (y_m - py) * math.sin(h)
    px, py, h = reference_pose_at(track, s_m)
    return {"start_arc_length_m": s_m, "start_offset_m": -(x_m - px) * math.sin(h) + (y_m - py) * math.cos(h),
            "start_heading_error_rad": heading_rad - h}


def test_collect_rows_and_episodes(collected):
    frames, steps, manifest = collected
    n = len(frames)
    assert frames.dtype == np.uint8 and frames.shape == (n, 66, 200)
    assert n == 3 * 50  # 2.5 s at 20 Hz, no episode cut short
    assert set(steps) == set(STEP_COLUMNS) and all(len(v) == n for v in steps.values())
    episode_id = steps["episode_id"]
    assert np.array_equal(episode_id, np.sort(episode_id))
    assert np.array_equal(np.unique(episode_id), np.arange(3))
    for e in range(3):
        t = steps["t_s"][episode_id == e]
        assert t[0] == 0.0
        assert np.allclose(np.diff(t), 0.05)
    assert np.all(np.abs(steps["steering"]) <= 1.0)
    assert np.array_equal(steps["executed_steering"], steps["steering"])  # the car executes the label
    assert np.allclose(steps["speed_mps"], 16.7)
    assert manifest["track"] == "test" and manifest["policy_frequency"] == 20
    assert manifest["camera"]["height_px"] == 66 and manifest["collector"]["episodes"] == 3


def test_collect_perturbs_only_early_in_displaced_episodes(collected):
    _, steps, _ = collected
    episode_id, t, perturbed = steps["episode_id"], steps["t_s"], steps["perturbed"]
    kinds = []
    for e in range(3):
        rows = episode_id == e
        displaced = abs(steps["lateral_offset_m"][rows][0]) > 1e-6
        kinds.append(displaced)
        if displaced:
            assert np.array_equal(perturbed[rows], t[rows] < RECOVERY_WINDOW_S - 1e-9)
        else:
            assert not perturbed[rows].any()
    assert kinds == [True, False, True]
    assert not perturbed[t >= RECOVERY_WINDOW_S].any()


def test_collect_labels_are_the_expert_on_the_true_state(collected):
    frames, steps, _ = collected
    track = load_track("test")
    env = gymnasium.make(ENV_ID, config={"track": "test"})
    for e in range(3):
        rows = np.flatnonzero(steps["episode_id"] == e)
        first = rows[0]
        options = _start_options(track, steps["x_m"][first], steps["y_m"][first], steps["heading_rad"][first])
        obs, info = env.reset(seed=0, options=options)
        for row in rows:
            # Replaying the executed actions retraces the recorded poses ...
            assert (info["x_m"], info["y_m"]) == pytest.approx((steps["x_m"][row], steps["y_m"][row]), abs=1e-6)
            assert info["heading_rad"] == pytest.approx(steps["heading_rad"][row], abs=1e-9)
            # ... and each label is the expert's action for that row's state.
            assert steps["steering"][row] == pytest.approx(expert_steering(info), abs=1e-5)
            assert np.mean(np.abs(frames[row].astype(int) - obs.astype(int))) < 0.5
            obs, _, _, _, info = env.step(np.array([steps["executed_steering"][row]], dtype=np.float32))


def test_collect_episodes_are_never_cut_short_by_the_end_of_the_track(tmp_path):
    short = {"name": "short", "lanes": 3, "lane_width_m": 4.0, "segments": [
        {"type": "straight", "length_m": 100},
        {"type": "arc", "radius_m": 80, "angle_deg": 60, "direction": "left"},
        {"type": "straight", "length_m": 30},
    ]}
    path = tmp_path / "short.json"
    path.write_text(json.dumps(short))
    # 214 m of road and 4 s episodes (67 m): starts must stay in the first 147 m.
    _, steps, _ = collect(str(path), episodes=8, episode_seconds=4.0, seed=0, progress=False)
    counts = np.bincount(steps["episode_id"])
    assert counts.tolist() == [80] * 8
    with pytest.raises(ValueError, match="shorter than one episode"):
        collect(str(path), episodes=1, episode_seconds=20.0, progress=False)


@pytest.mark.parametrize(("kwargs", "fragment"), [({"episodes": 0}, "episodes"), ({"episode_seconds": 0}, "episode-seconds"),
                                                  ({"displaced_fraction": 1.5}, "displaced-fraction")])
def test_collect_rejects_bad_arguments(kwargs, fragment):
    with pytest.raises(ValueError, match=fragment):
        collect("test", **{"episodes": 1, "episode_seconds": 1.0, "progress": False, **kwargs})
