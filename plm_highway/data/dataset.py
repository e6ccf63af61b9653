"""The demonstration dataset written by ``plm-highway collect`` and read by training.

A dataset is a directory:

- ``manifest.json``: ``{"format": "plm_highway.dataset/1", "track", "speed_mps",
  "simulation_frequency", "policy_frequency", "seed", "camera": {...}, "counts": {"samples",
  "episodes"}, "collector": {...}}``. UTF-8 JSON (a byte-order mark is accepted), at most
  :data:`MAX_MANIFEST_BYTES`. ``format`` and ``counts`` are required; ``counts`` must agree with
  the arrays.
- ``frames.npy``: uint8 array (N, H, W), the camera frame the expert's label belongs to
  (memory-mappable: training does not load it all at once). Its header is checked against the
  file size before it is mapped, so a truncated file is named as such.
- ``steps.npz``: one 1-D array of length N per column in :data:`STEP_COLUMNS` (no pickled objects).

A dataset has 1 to :data:`MAX_SAMPLES` rows; frames are at most :data:`MAX_FRAME_SIDE_PX` px a side.

Rows are in time order within each episode. An *episode* is one continuous stretch of driving:
a perturbation that teleports the car starts a new episode, so a future-action look-up by time
never crosses a discontinuity. ``steering`` is the expert's normalised label for the frame
(positive turns left); ``executed_steering`` is what the car actually received. The shipped collector
perturbs by displacing the car at episode starts, so the two are equal in its datasets; the column
is kept for collectors that perturb the steering itself.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import JsonLimits, directory_kind, load_json, parse_json, read_bounded, write_output
from plm_highway.io.digests import DIGEST_KEY, content_digest

FORMAT = "plm_highway.dataset/1"
MAX_MANIFEST_BYTES = 4 * 1024 * 1024
MANIFEST_LIMITS = JsonLimits(max_bytes=MAX_MANIFEST_BYTES, max_depth=16, max_nodes=200_000, max_int_digits=30)
MAX_SAMPLES = 10_000_000
MAX_FRAME_SIDE_PX = 4096
STEP_COLUMNS: dict[str, type] = {
    "episode_id": np.int32,
    "t_s": np.float64,
    "speed_mps": np.float32,
    "steering": np.float32,
    "executed_steering": np.float32,
    "x_m": np.float64,
    "y_m": np.float64,
    "heading_rad": np.float64,
    "lateral_offset_m": np.float32,
    "perturbed": np.bool_,
}


def _has_dataset_manifest(path: Path) -> bool:
    """Datasets written before output markers existed: a manifest of this format."""
    try:
        return load_json(path / "manifest.json", MANIFEST_LIMITS).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


DATASET = directory_kind("dataset", "a plm-highway dataset directory", _has_dataset_manifest)


@dataclass
class Dataset:
    manifest: dict
    frames: np.ndarray  # (N, H, W) uint8, possibly a read-only memory map
    steps: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.frames)


def write_dataset(out_dir: str | Path, frames: np.ndarray, steps: dict[str, np.ndarray], manifest: dict,
                  overwrite: bool = False) -> Path:
    """Validate and write a dataset atomically (see :mod:`plm_highway.io.outputs`); returns the directory."""
    frames = np.asarray(frames)
    _check_frames(frames.dtype, frames.shape, "frames")
    columns = _validated_columns(steps, len(frames), source="steps")
    manifest = {key: value for key, value in manifest.items() if key != DIGEST_KEY}
    manifest = {**manifest, "format": FORMAT}
    manifest["counts"] = {"samples": int(len(frames)), "episodes": int(len(np.unique(columns["episode_id"])))}
    manifest = json.loads(json.dumps(manifest))  # as it reads back, so its digest is the one a reader computes
    manifest[DIGEST_KEY] = content_digest(manifest)
    out_dir = Path(out_dir)
    with write_output(out_dir, DATASET, overwrite=overwrite) as tmp:
        np.save(tmp / "frames.npy", frames)
        np.savez(tmp / "steps.npz", **columns)
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return out_dir


def read_dataset(data_dir: str | Path, mmap: bool = True) -> Dataset:
    """The dataset at ``data_dir``, checked (see the module docstring); ValueError names the culprit."""
    data_dir = Path(data_dir)
    manifest_path = data_dir / "manifest.json"
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{manifest_path}: no dataset manifest (run 'plm-highway collect' first)")
    manifest = _read_manifest(manifest_path)
    frames = _load_frames(data_dir / "frames.npy", mmap)
    steps_path = data_dir / "steps.npz"
    if not steps_path.is_file():
        raise FileNotFoundError(f"{steps_path}: dataset file not found")
    try:
        with np.load(steps_path, allow_pickle=False) as npz:
            steps = {name: npz[name] for name in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise BadInput(f"{steps_path}: not a readable .npz of step columns ({exc})") from exc
    steps = _validated_columns(steps, len(frames), source=str(steps_path))
    _check_counts(manifest_path, manifest, frames, steps)
    _check_against_manifest(manifest_path, manifest, frames, steps)
    _check_digest(manifest_path, manifest)
    return Dataset(manifest=manifest, frames=frames, steps=steps)


def _check_digest(path: Path, manifest: dict) -> None:
    """A setting the data cannot show (a camera pitch within its range) is still the collector's: the manifest
    carries the digest of its content, so an edit by hand is refused rather than trained on."""
    if manifest.get(DIGEST_KEY) != content_digest(manifest):
        why = "has no content digest" if DIGEST_KEY not in manifest else "was edited after plm-highway wrote it"
        raise BadInput(f"{path}: {why} ({DIGEST_KEY} does not match its fields); its settings may not describe "
                       "the frames, so it is not trained on: collect the dataset again")


def _read_manifest(path: Path) -> dict:
    size_bytes = path.stat().st_size
    if size_bytes > MAX_MANIFEST_BYTES:
        raise BadInput(f"{path}: {size_bytes} bytes, a dataset manifest is at most {MAX_MANIFEST_BYTES}")
    manifest = parse_json(read_bounded(path, MAX_MANIFEST_BYTES, "dataset manifest"), str(path), MANIFEST_LIMITS)
    if not isinstance(manifest, dict):
        raise BadInput(f"{path}: expected a JSON object, found {type(manifest).__name__}")
    if manifest.get("format") != FORMAT:
        raise BadInput(f"{path}: field 'format' is {manifest.get('format')!r}, expected {FORMAT!r}")
    counts = manifest.get("counts")
    if not isinstance(counts, dict) or not all(
        isinstance(counts.get(name), int) and not isinstance(counts.get(name), bool)
        for name in ("samples", "episodes")
    ):
        raise BadInput(f"{path}: field 'counts' must be an object with integer 'samples' and 'episodes', "
                         f"got {counts!r}")
    return manifest


def _check_counts(path: Path, manifest: dict, frames: np.ndarray, steps: dict[str, np.ndarray]) -> None:
    counts = manifest["counts"]
    if counts["samples"] != len(frames):
        raise BadInput(f"{path}: counts.samples is {counts['samples']}, but frames.npy holds {len(frames)} frames")
    n_episodes = len(np.unique(steps["episode_id"]))
    if counts["episodes"] != n_episodes:
        raise BadInput(f"{path}: counts.episodes is {counts['episodes']}, but steps.npz holds {n_episodes}")


def _check_frames(dtype: np.dtype, shape: tuple, source: str) -> None:
    if dtype != np.uint8 or len(shape) != 3:
        raise BadInput(f"{source}: expected uint8 (N, H, W), got {dtype} {shape}")
    n, height, width = shape
    if not 1 <= n <= MAX_SAMPLES:
        raise BadInput(f"{source}: a dataset has 1 to {MAX_SAMPLES} samples, got {n}")
    if not (1 <= height <= MAX_FRAME_SIDE_PX and 1 <= width <= MAX_FRAME_SIDE_PX):
        raise BadInput(f"{source}: frames must be 1 to {MAX_FRAME_SIDE_PX} px a side, got {height}x{width}")


def _load_frames(path: Path, mmap: bool) -> np.ndarray:
    """frames.npy, its header checked against the file size first (a truncated file is named as such)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: dataset file not found")
    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                           (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read_header is None:
                raise BadInput(f"unsupported .npy format version {version}")
            shape, fortran_order, dtype = read_header(handle)
            header_bytes = handle.tell()
    except (ValueError, EOFError, OSError) as exc:
        raise BadInput(f"{path}: not a .npy array file ({exc})") from exc
    _check_frames(dtype, shape, str(path))
    if fortran_order:
        raise BadInput(f"{path}: expected a C-ordered array, found Fortran order")
    expected_bytes = header_bytes + int(np.prod(shape)) * dtype.itemsize
    size_bytes = path.stat().st_size
    if size_bytes != expected_bytes:
        kind = "truncated" if size_bytes < expected_bytes else "longer than its header says"
        raise BadInput(
            f"{path}: {kind}: {size_bytes} bytes, its header ({shape[0]} frames of {shape[1]}x{shape[2]} px) "
            f"needs {expected_bytes}"
        )
    return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)


# Label and setting ranges: what a collector can have written. A value outside is an edited or foreign file.
LABEL_RANGES = {"steering": (-1.0, 1.0), "executed_steering": (-1.0, 1.0), "speed_mps": (0.0, 100.0)}
MANIFEST_RANGES = {"speed_mps": (0.1, 100.0), "max_steering_rad": (0.01, 1.5), "camera.pitch_deg": (-45.0, 45.0),
                   "camera.fov_deg": (1.0, 179.0), "camera.mount_height_m": (0.05, 20.0)}
SPEED_AGREEMENT = 0.05  # the recorded speeds' median within 5% of a constant manifest speed


def _check_against_manifest(path: Path, manifest: dict, frames: np.ndarray, steps: dict[str, np.ndarray]) -> None:
    """The manifest's settings in their ranges, and agreeing with what the data holds where the data shows them:
    the frame size against the camera's, the recorded speed against a constant manifest speed."""
    for dotted, (low, high) in MANIFEST_RANGES.items():
        node = manifest
        for part in dotted.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node is None or isinstance(node, dict):
            continue  # absent, or a schedule (speed): nothing to compare
        if isinstance(node, bool) or not isinstance(node, (int, float)) or not low <= node <= high:
            raise BadInput(f"{path}: field {dotted!r} = {node!r} is outside [{low:g}, {high:g}]")
    camera = manifest.get("camera") if isinstance(manifest.get("camera"), dict) else {}
    size = (camera.get("height_px"), camera.get("width_px"))
    if all(isinstance(v, int) and not isinstance(v, bool) for v in size) and frames.ndim == 3 \
            and tuple(frames.shape[1:]) != size:
        raise BadInput(f"{path}: camera is {size[0]}x{size[1]} px but frames.npy holds {frames.shape[1]}x"
                       f"{frames.shape[2]} frames; the manifest does not describe this data")
    speed = manifest.get("speed_mps")
    if isinstance(speed, (int, float)) and not isinstance(speed, bool) and len(steps["speed_mps"]):
        recorded = float(np.median(steps["speed_mps"]))
        if abs(recorded - speed) > SPEED_AGREEMENT * speed:
            raise BadInput(f"{path}: field 'speed_mps' = {speed:g} m/s but the recorded speeds' median is "
                           f"{recorded:.3g} m/s (steps.npz); the manifest does not describe this data")


def _validated_columns(steps: dict[str, np.ndarray], n_rows: int, source: str) -> dict[str, np.ndarray]:
    missing = sorted(set(STEP_COLUMNS) - set(steps))
    unknown = sorted(set(steps) - set(STEP_COLUMNS))
    if missing or unknown:
        raise BadInput(f"{source}: missing columns {missing}, unknown columns {unknown}")
    columns = {}
    for name, dtype in STEP_COLUMNS.items():
        values = np.asarray(steps[name]).astype(dtype, copy=False)
        if values.shape != (n_rows,):
            raise BadInput(f"{source}: column {name!r} has shape {values.shape}, expected ({n_rows},)")
        if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise BadInput(f"{source}: column {name!r} is not finite at row {row}")
        if name in LABEL_RANGES:
            low, high = LABEL_RANGES[name]
            outside = np.flatnonzero((values < low) | (values > high))
            if len(outside):
                row = int(outside[0])
                raise BadInput(f"{source}: column {name!r} = {float(values[row]):g} at row {row} is outside "
                               f"[{low:g}, {high:g}] ({len(outside)} row(s) outside)")
        columns[name] = values
    return columns
