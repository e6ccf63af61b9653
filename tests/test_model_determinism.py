"""Same seed, two processes: byte-identical datasets and checkpoints (collect, train bm, train tapm).

The commands run twice, once in each of two separate processes started from sibling directories with
the same relative paths, so that the command lines recorded in the outputs are the same too; a process
runs collect, train bm and train tapm one after the other, as ``plm-highway`` would (``cli.main``),
which spares two interpreters' imports per side. Nothing is excluded from the comparison: no output
records a wall time or anything else that legitimately differs between runs (``data_dir`` is recorded
resolved, and resolves to the same dataset).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow


# Runs each command line of argv[1] (JSON) through plm-highway's entry point, in order; stops at the first failure.
SEQUENCE = """import json, sys
from plm_highway.cli import main
for argv in json.loads(sys.argv[1]):
    code = main(argv)
    if code:
        sys.exit(f"plm-highway {' '.join(argv)}: exit {code}")
"""


def run_commands(cwd: Path, *commands: list[str]) -> None:
    """``commands`` one after the other in one new process started in ``cwd``."""
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-c", SEQUENCE, json.dumps(commands)], cwd=cwd, env=env,
                            capture_output=True, text=True, timeout=1200)
    assert result.returncode == 0, result.stderr


def file_bytes(directory: Path) -> dict[str, bytes]:
    return {str(path.relative_to(directory)): path.read_bytes() for path in sorted(directory.rglob("*"))
            if path.is_file()}


def test_collect_and_training_are_byte_identical_across_processes(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    # Both sides train on a's dataset and BM, so that the paths the checkpoints record resolve to the same files
    # (side a finishes before side b starts).
    common = ["--data", "../a/ds", "--epochs", "1", "--seed", "4", "--threads", "1", "--quiet"]
    for cwd in runs:
        cwd.mkdir()
        run_commands(cwd,
                     ["collect", "--track", "test", "--out", "ds", "--episodes", "2", "--episode-seconds", "1",
                      "--seed", "3"],
                     ["train", "bm", "--out", "bm", *common],
                     ["train", "tapm", "--out", "tapm", "--bm", "../a/bm", *common])
    datasets = [file_bytes(cwd / "ds") for cwd in runs]
    assert sorted(datasets[0]) == [".plm-highway-output.json", "frames.npy", "manifest.json", "steps.npz"]
    assert datasets[0] == datasets[1]

    checkpoints = [file_bytes(cwd / "bm") for cwd in runs]
    assert sorted(checkpoints[0]) == [".plm-highway-output.json", "model.json", "model.pt", "steering_balance.png"]
    assert checkpoints[0] == checkpoints[1]

    tapms = [file_bytes(cwd / "tapm") for cwd in runs]
    assert sorted(tapms[0]) == [".plm-highway-output.json", "model.json", "model.pt", "steering_balance.png"]
    assert tapms[0] == tapms[1]
