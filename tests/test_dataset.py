"""The demonstration dataset: round trip, validation, atomic writes, and what the collector records."""

from __future__ import annotations

import json
import math
import re
import zipfile

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway import cli
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
    (out / "notes.txt").write_text("the user's, not plm-highway's")
    with pytest.raises(ValueError, match="--overwrite"):
        write_dataset(out, make_frames(6), make_steps(6, episodes=2), {"version": 2})
    assert read_dataset(out).manifest["version"] == 1
    write_dataset(out, make_frames(6), make_steps(6, episodes=2), {"version": 2}, overwrite=True)
    data = read_dataset(out)
    assert len(data) == 6 and data.manifest["version"] == 2
    assert data.manifest["counts"] == {"samples": 6, "episodes": 2}
    # Only what plm-highway wrote is replaced: the user's file in the directory stays as it was.
    assert listing(tmp_path) == ["ds", "ds/.plm-highway-output.json", "ds/frames.npy", "ds/manifest.json",
                                 "ds/notes.txt", "ds/steps.npz"]
    assert (out / "notes.txt").read_text() == "the user's, not plm-highway's"


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


# One line per bad collect argument: (arguments, message). Each exits 2 before an episode runs and writes nothing.
BAD_COLLECT_ARGUMENTS = [
    pytest.param(["--episodes", "0"], r"--episodes: must lie in \[1, 100000\], got 0", id="episodes-0"),
    pytest.param(["--episodes", "-3"], r"--episodes: must lie in \[1, 100000\], got -3", id="episodes-negative"),
    pytest.param(["--episodes", "1000000"], r"--episodes: must lie in \[1, 100000\]", id="episodes-huge"),
    pytest.param(["--episode-seconds", "0"], r"--episode-seconds: must be a finite number in \(0, 3600\], got 0",
                 id="seconds-0"),
    pytest.param(["--episode-seconds", "-1"], r"--episode-seconds: .*got -1", id="seconds-negative"),
    pytest.param(["--episode-seconds", "nan"], r"--episode-seconds: .*got nan", id="seconds-nan"),
    pytest.param(["--episode-seconds", "1e9"], r"--episode-seconds: .*got 1e\+?0?9|--episode-seconds: .*1000000000",
                 id="seconds-huge"),
    pytest.param(["--speed-mps", "0"], r"--speed-mps: must be a finite number in \(0, 70\], got 0", id="speed-0"),
    pytest.param(["--speed-mps", "-10"], r"--speed-mps: .*got -10", id="speed-negative"),
    pytest.param(["--speed-mps", "nan"], r"--speed-mps: .*got nan", id="speed-nan"),
    pytest.param(["--speed-mps", "1000"], r"--speed-mps: .*got 1000", id="speed-huge"),
    pytest.param(["--max-offset-m", "50"], r"--max-offset-m 50 would start the car off the road of track 'test': "
                 r"at most 6 m", id="offset-off-road"),
    pytest.param(["--max-offset-m", "-1"], r"--max-offset-m: must be a finite number in \[0, inf\), got -1",
                 id="offset-negative"),
    pytest.param(["--max-offset-m", "nan"], r"--max-offset-m: .*got nan", id="offset-nan"),
    pytest.param(["--max-heading-error-deg", "90"], r"--max-heading-error-deg: .*\[0, 45\], got 90", id="heading"),
    pytest.param(["--displaced-fraction", "1.5"], r"--displaced-fraction: .*\[0, 1\], got 1.5", id="fraction"),
    pytest.param(["--displaced-fraction", "nan"], r"--displaced-fraction: .*got nan", id="fraction-nan"),
    pytest.param(["--seed", "-1"], r"--seed: must lie in \[0, 9223372036854775807\], got -1", id="seed-negative"),
    pytest.param(["--episodes", "100000", "--episode-seconds", "60"], r"frames of 66x200 px exceed the 8 GiB",
                 id="too-many-frames"),
]


@pytest.mark.parametrize(("arguments", "message"), BAD_COLLECT_ARGUMENTS)
def test_collect_refuses_bad_arguments_on_the_command_line(tmp_path, capsys, arguments, message):
    out = tmp_path / "ds"
    code = cli.main(["collect", "--track", "test", "--out", str(out), "--episodes", "1", "--episode-seconds", "1",
                     *arguments])
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT, err
    assert re.search(message, err), err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # no dataset, no temporary directory


# -- bad dataset directories -------------------------------------------------------------------------


def rewrite_manifest(change):
    def mutate(path):
        manifest = json.loads((path / "manifest.json").read_text())
        change(manifest)
        (path / "manifest.json").write_text(json.dumps(manifest))

    return mutate


def write_file(name: str, data: bytes):
    def mutate(path):
        (path / name).write_bytes(data)

    return mutate


def truncate(name: str, keep_fraction: float = 0.5):
    def mutate(path):
        data = (path / name).read_bytes()
        (path / name).write_bytes(data[: int(len(data) * keep_fraction)])

    return mutate


def remove(name: str):
    def mutate(path):
        (path / name).unlink()

    return mutate


def replace_frames(make):
    def mutate(path):
        frames = np.load(path / "frames.npy")
        np.save(path / "frames.npy", make(frames), allow_pickle=True)

    return mutate


def replace_steps(change):
    def mutate(path):
        with np.load(path / "steps.npz") as npz:
            steps = {name: npz[name] for name in npz.files}
        change(steps)
        np.savez(path / "steps.npz", **steps)

    return mutate


def append_bytes(name: str, data: bytes):
    def mutate(path):
        with open(path / name, "ab") as handle:
            handle.write(data)

    return mutate


def huge_header(path):
    """A valid .npy header claiming 10**9 frames, with almost no data behind it."""
    frames = np.load(path / "frames.npy")
    with open(path / "frames.npy", "wb") as handle:
        np.lib.format.write_array_header_1_0(
            handle, {"descr": "|u1", "fortran_order": False, "shape": (10**9, *frames.shape[1:])})
        handle.write(b"\0" * 100)


def empty_dataset(path):
    frames = np.load(path / "frames.npy")
    np.save(path / "frames.npy", frames[:0])
    with np.load(path / "steps.npz") as npz:
        np.savez(path / "steps.npz", **{name: npz[name][:0] for name in npz.files})
    rewrite_manifest(lambda m: m.update(counts={"samples": 0, "episodes": 0}))(path)


def steps_with_an_object_column(path):
    with np.load(path / "steps.npz") as npz:
        steps = {name: npz[name] for name in npz.files}
    steps["x_m"] = np.array([{"x": 1}] * len(steps["x_m"]), dtype=object)
    np.savez(path / "steps.npz", **steps)


def _drop(manifest, key):
    del manifest[key]


# One line per bad dataset directory: (what is done to a valid dataset, exception, message).
BAD_DATASETS = [
    pytest.param(truncate("frames.npy"), ValueError, r"frames.npy: truncated: \d+ bytes, its header \(\d+ frames "
                 r"of \d+x\d+ px\) needs \d+", id="frames-truncated"),
    pytest.param(truncate("frames.npy", 0.001), ValueError, r"frames.npy: (not a .npy array file|truncated)",
                 id="frames-header-cut"),
    pytest.param(append_bytes("frames.npy", b"extra"), ValueError, r"frames.npy: longer than its header says",
                 id="frames-too-long"),
    pytest.param(write_file("frames.npy", b"hello, not numpy"), ValueError, r"frames.npy: not a .npy array file",
                 id="frames-garbage"),
    pytest.param(replace_frames(lambda f: f.astype(np.float32)), ValueError,
                 r"frames.npy: expected uint8 \(N, H, W\), got float32", id="frames-float"),
    pytest.param(replace_frames(lambda f: f.reshape(len(f), -1)), ValueError, r"frames.npy: expected uint8 \(N, H, W\)",
                 id="frames-2d"),
    pytest.param(replace_frames(lambda f: np.array([None] * len(f), dtype=object)), ValueError,
                 r"frames.npy: expected uint8 \(N, H, W\), got object", id="frames-pickled-objects"),
    pytest.param(huge_header, ValueError, r"frames.npy: a dataset has 1 to 10000000 samples, got 1000000000",
                 id="frames-huge-header"),
    pytest.param(remove("frames.npy"), FileNotFoundError, r"frames.npy: dataset file not found", id="frames-missing"),
    pytest.param(remove("manifest.json"), FileNotFoundError, r"manifest.json: no dataset manifest",
                 id="manifest-missing"),
    pytest.param(write_file("manifest.json", b"{not json"), ValueError, r"manifest.json: not valid JSON",
                 id="manifest-not-json"),
    pytest.param(write_file("manifest.json", b"[]"), ValueError, r"manifest.json: expected a JSON object, found list",
                 id="manifest-list"),
    pytest.param(write_file("manifest.json", b"\xff\xfe\x00{"), ValueError, r"manifest.json: not UTF-8 text",
                 id="manifest-binary"),
    pytest.param(write_file("manifest.json", b" " * (5 * 1024 * 1024)), ValueError,
                 r"manifest.json: \d+ bytes, a dataset manifest is at most 4194304", id="manifest-huge"),
    pytest.param(rewrite_manifest(lambda m: _drop(m, "format")), ValueError, r"manifest.json: field 'format' is None",
                 id="manifest-no-format"),
    pytest.param(rewrite_manifest(lambda m: _drop(m, "counts")), ValueError,
                 r"manifest.json: field 'counts' must be an object with integer 'samples' and 'episodes', got None",
                 id="manifest-no-counts"),
    pytest.param(rewrite_manifest(lambda m: m.update(counts={"samples": "12", "episodes": 3})), ValueError,
                 r"field 'counts' must be an object", id="manifest-str-count"),
    pytest.param(rewrite_manifest(lambda m: m["counts"].update(samples=m["counts"]["samples"] + 1)), ValueError,
                 r"manifest.json: counts.samples is \d+, but frames.npy holds \d+ frames", id="counts-samples"),
    pytest.param(rewrite_manifest(lambda m: m["counts"].update(episodes=99)), ValueError,
                 r"manifest.json: counts.episodes is 99, but steps.npz holds \d+", id="counts-episodes"),
    pytest.param(remove("steps.npz"), FileNotFoundError, r"steps.npz: dataset file not found", id="steps-missing"),
    pytest.param(truncate("steps.npz"), ValueError, r"steps.npz: not a readable .npz of step columns",
                 id="steps-truncated"),
    pytest.param(steps_with_an_object_column, ValueError, r"steps.npz: not a readable .npz .*allow_pickle",
                 id="steps-pickled-objects"),
    pytest.param(replace_steps(lambda s: s.update(x_m=s["x_m"][:-1])), ValueError,
                 r"steps.npz: column 'x_m' has shape \(\d+,\), expected \(\d+,\)", id="steps-rows-mismatch"),
    pytest.param(replace_steps(lambda s: s.pop("t_s")), ValueError, r"steps.npz: missing columns \['t_s'\]",
                 id="steps-missing-column"),
    pytest.param(replace_steps(lambda s: s["y_m"].__setitem__(2, np.inf)), ValueError,
                 r"steps.npz: column 'y_m' is not finite at row 2", id="steps-inf"),
    pytest.param(empty_dataset, ValueError, r"frames.npy: a dataset has 1 to 10000000 samples, got 0", id="empty"),
]


@pytest.mark.parametrize(("mutate", "exception", "message"), BAD_DATASETS)
def test_bad_dataset_directories_are_refused_naming_the_file(tmp_path, mutate, exception, message):
    out = write_dataset(tmp_path / "ds", make_frames(), make_steps(), {})
    mutate(out)
    with pytest.raises(exception, match=message):
        read_dataset(out)


@pytest.fixture(scope="module")
def camera_size_dataset(tmp_path_factory):
    from plm_highway.training.synthetic import make_synthetic_dataset

    return make_synthetic_dataset(tmp_path_factory.mktemp("camera") / "ds", n_episodes=6, steps_per_episode=20)


@pytest.mark.parametrize(("mutate", "exception", "message"), BAD_DATASETS)
def test_bad_dataset_directories_exit_2_in_training_and_leave_nothing(tmp_path, capsys, camera_size_dataset,
                                                                      mutate, exception, message):
    import shutil

    data = tmp_path / "data"
    shutil.copytree(camera_size_dataset, data)
    mutate(data)
    out = tmp_path / "bm"
    code = cli.main(["train", "bm", "--data", str(data), "--out", str(out), "--quiet", "--threads", "1"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT, err
    assert re.search(message, err), err
    assert "Traceback" not in err and not out.exists()


def test_a_manifest_with_a_byte_order_mark_is_read(tmp_path):
    out = write_dataset(tmp_path / "ds", make_frames(), make_steps(), {"track": "test"})
    (out / "manifest.json").write_bytes(b"\xef\xbb\xbf" + (out / "manifest.json").read_bytes())
    assert read_dataset(out).manifest["track"] == "test"


def test_an_empty_dataset_is_not_written(tmp_path):
    with pytest.raises(ValueError, match=r"frames: a dataset has 1 to 10000000 samples, got 0"):
        write_dataset(tmp_path / "ds", make_frames(0), make_steps(0, episodes=1), {})
    assert listing(tmp_path) == []


def test_npz_files_are_zip_archives_without_timestamps(tmp_path):
    # The determinism of collect's output rests on this: np.savez writes no wall-clock time.
    out = write_dataset(tmp_path / "ds", make_frames(), make_steps(), {})
    with zipfile.ZipFile(out / "steps.npz") as archive:
        assert {info.date_time for info in archive.infolist()} == {(1980, 1, 1, 0, 0, 0)}
