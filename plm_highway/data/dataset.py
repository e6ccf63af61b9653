"""The demonstration dataset written by ``plm-highway collect`` and read by training.

A dataset is a directory:

- ``manifest.json``: ``{"format": "plm_highway.dataset/1", "track", "speed_mps",
  "simulation_frequency", "policy_frequency", "seed", "camera": {...}, "counts": {"samples",
  "episodes"}, "collector": {...}}``.
- ``frames.npy``: uint8 array (N, H, W), the camera frame the expert's label belongs to
  (memory-mappable: training does not load it all at once).
- ``steps.npz``: one 1-D array of length N per column in :data:`STEP_COLUMNS`.

Rows are in time order within each episode. An *episode* is one continuous stretch of driving:
a perturbation that teleports the car starts a new episode, so a future-action look-up by time
never crosses a discontinuity. ``steering`` is the expert's normalised label for the frame
(positive turns left); ``executed_steering`` is what the car actually received. The shipped collector
perturbs by displacing the car at episode starts, so the two are equal in its datasets; the column
is kept for collectors that perturb the steering itself.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plm_highway.io import directory_kind, write_output

FORMAT = "plm_highway.dataset/1"
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
        return json.loads((path / "manifest.json").read_text(encoding="utf-8")).get("format") == FORMAT
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
    if frames.dtype != np.uint8 or frames.ndim != 3:
        raise ValueError(f"frames: expected uint8 (N, H, W), got {frames.dtype} {frames.shape}")
    columns = _validated_columns(steps, len(frames), source="steps")
    manifest = {**manifest, "format": FORMAT}
    manifest["counts"] = {"samples": int(len(frames)), "episodes": int(len(np.unique(columns["episode_id"])))}
    out_dir = Path(out_dir)
    with write_output(out_dir, DATASET, overwrite=overwrite) as tmp:
        np.save(tmp / "frames.npy", frames)
        np.savez(tmp / "steps.npz", **columns)
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return out_dir


def read_dataset(data_dir: str | Path, mmap: bool = True) -> Dataset:
    data_dir = Path(data_dir)
    manifest_path = data_dir / "manifest.json"
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{manifest_path}: no dataset manifest (run 'plm-highway collect' first)")
    manifest = json.loads(manifest_path.read_text())
    if manifest.get("format") != FORMAT:
        raise ValueError(f"{manifest_path}: field 'format' is {manifest.get('format')!r}, expected {FORMAT!r}")
    frames = np.load(data_dir / "frames.npy", mmap_mode="r" if mmap else None)
    with np.load(data_dir / "steps.npz") as npz:
        steps = _validated_columns(dict(npz), len(frames), source=str(data_dir / "steps.npz"))
    return Dataset(manifest=manifest, frames=frames, steps=steps)


def _validated_columns(steps: dict[str, np.ndarray], n_rows: int, source: str) -> dict[str, np.ndarray]:
    missing = sorted(set(STEP_COLUMNS) - set(steps))
    unknown = sorted(set(steps) - set(STEP_COLUMNS))
    if missing or unknown:
        raise ValueError(f"{source}: missing columns {missing}, unknown columns {unknown}")
    columns = {}
    for name, dtype in STEP_COLUMNS.items():
        values = np.asarray(steps[name]).astype(dtype, copy=False)
        if values.shape != (n_rows,):
            raise ValueError(f"{source}: column {name!r} has shape {values.shape}, expected ({n_rows},)")
        if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise ValueError(f"{source}: column {name!r} is not finite at row {row}")
        columns[name] = values
    return columns
