"""Same seed, two processes: byte-identical evaluate JSON and logs, reproduce and sim2real reports.

Datasets and checkpoints are covered by tests/test_model_determinism.py. The commands run twice, once
in each of two separate processes started from sibling directories with the same relative paths (so
the recorded command lines agree); a process runs them one after the other, as ``plm-highway`` would
(``cli.main``), which spares three interpreters' imports per side. Every output of one process is
compared with the other's. Excluded from the comparison, and only these: ``elapsed_s`` in the
sim2real diagnosis JSON (wall time of the run). Nothing else legitimately differs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
VOLATILE_JSON_FIELDS = {"elapsed_s"}

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
                            capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stderr


def comparable(path: Path) -> dict[str, object]:
    out = {}
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        data = file.read_bytes()
        if file.suffix == ".json":
            document = json.loads(data)
            if isinstance(document, dict) and VOLATILE_JSON_FIELDS & set(document):
                data = {k: v for k, v in document.items() if k not in VOLATILE_JSON_FIELDS}
        out[str(file.relative_to(path))] = data
    return out


@pytest.mark.timeout(1800)
def test_evaluate_reproduce_and_diagnose_outputs_are_byte_identical_across_processes(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    for cwd in runs:
        cwd.mkdir()
        run_commands(cwd,
                     ["evaluate", "--policy", "plm", "--latency", "steps:0.0-0.35:1.0", "--seed", "5",
                      "--max-steps", "120", "--out", "eval", "--json", "eval.json"],
                     ["reproduce", "--settings", "const:0.1", "--generalise", "--max-steps", "40", "--seed", "5",
                      "--workers", "0", "--no-progress", "--out", "rep"],
                     ["sim2real", "make-recording", "--effect", "actuator_lag", "--duration-s", "40", "--seed", "5",
                      "--out", "rec/r.csv"],
                     ["sim2real", "diagnose", "rec/r.csv", "--quiet", "--json", "diag.json", "--report", "diag"])
    a, b = runs
    assert (a / "eval.json").read_bytes() == (b / "eval.json").read_bytes()
    evaluation = comparable(a / "eval")
    assert {"result.json", "reference.csv", "baseline.csv", "mitigated.csv", "steps.csv"} <= set(evaluation)
    assert evaluation == comparable(b / "eval")
    report = comparable(a / "rep")
    assert "report.md" in report and any(name.endswith(".png") for name in report)
    assert report == comparable(b / "rep")
    assert comparable(a / "rec") == comparable(b / "rec")
    diagnosis = comparable(a / "diag")
    assert diagnosis and diagnosis == comparable(b / "diag")
    documents = [json.loads((cwd / "diag.json").read_bytes()) for cwd in runs]
    assert all("elapsed_s" in document for document in documents)
    assert [{k: v for k, v in d.items() if k != "elapsed_s"} for d in documents][0] == \
        [{k: v for k, v in d.items() if k != "elapsed_s"} for d in documents][1]
