"""Same seed, two processes: byte-identical datasets and checkpoints (collect, train bm, train tapm).

Each command runs twice, in separate processes started from sibling directories with the same
relative paths, so that the command lines recorded in the outputs are the same too. Nothing is
excluded from the comparison: no output records a wall time or anything else that legitimately
differs between runs (``data_dir`` is recorded resolved, and resolves to the same dataset).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow


def run_command(cwd: Path, *args: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-m", "plm_highway", *args], cwd=cwd, env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr


def file_bytes(directory: Path) -> dict[str, bytes]:
    return {str(path.relative_to(directory)): path.read_bytes() for path in sorted(directory.rglob("*"))
            if path.is_file()}


def test_collect_and_training_are_byte_identical_across_processes(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    for cwd in runs:
        cwd.mkdir()
        run_command(cwd, "collect", "--track", "test", "--out", "ds", "--episodes", "2", "--episode-seconds", "1",
                    "--seed", "3")
    datasets = [file_bytes(cwd / "ds") for cwd in runs]
    assert sorted(datasets[0]) == [".plm-highway-output.json", "frames.npy", "manifest.json", "steps.npz"]
    assert datasets[0] == datasets[1]

    common = ["--data", "../a/ds", "--epochs", "1", "--seed", "4", "--threads", "1", "--quiet"]
    for cwd in runs:
        run_command(cwd, "train", "bm", "--out", "bm", *common)
    checkpoints = [file_bytes(cwd / "bm") for cwd in runs]
    assert sorted(checkpoints[0]) == [".plm-highway-output.json", "model.json", "model.pt", "steering_balance.png"]
    assert checkpoints[0] == checkpoints[1]

    for cwd in runs:
        run_command(cwd, "train", "tapm", "--out", "tapm", "--bm", "../a/bm", *common)
    tapms = [file_bytes(cwd / "tapm") for cwd in runs]
    assert sorted(tapms[0]) == [".plm-highway-output.json", "model.json", "model.pt", "steering_balance.png"]
    assert tapms[0] == tapms[1]
