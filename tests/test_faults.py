"""The fault battery (issue 8 item 4, issue 17 item 8): SIGKILL, foreign content, two writers at once.

For each writing command (collect, train bm, evaluate --json, evaluate --out, reproduce, sim2real
diagnose --report):

- a first run publishes an output; the same command with ``--overwrite`` is then killed with
  SIGKILL at several points: as soon as its staging directory appears (mid-write), after a seeded
  random number of progress updates (commands that show progress), and after seeded random
  fractions of the first run's wall time. After every kill the target is the first
  run's output byte for byte, or (a kill after publishing) the new output whole;
- a run that completes afterwards removes the staging directories the killed runs left;
- a foreign directory and a foreign file at the target survive every command byte-identical;
- two processes writing one new target at once: one publishes whole, the other exits 2 cleanly.

The commands are deterministic under their seed, so the new output of an ``--overwrite`` run is
byte-identical to the first one except for the fields listed in ``VOLATILE`` (wall times).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
TMP_INFIX = ".plm-highway-tmp-"
pytestmark = pytest.mark.slow

# Fields that legitimately differ between two runs of one command (documented in README "Reliability").
VOLATILE = {"elapsed_s"}

KILL_SEED = 8  # the random kill points are drawn from this seed
RANDOM_KILLS = 2  # kills at random fractions of a run's wall time, besides the staging and progress points


def env() -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO_ROOT), "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}


class Running:
    """A command in a subprocess whose stderr is drained by a thread that counts progress updates
    (tqdm redraws end in a carriage return, log lines in a newline)."""

    def __init__(self, cwd: Path, argv: list[str]):
        self.process = subprocess.Popen([sys.executable, "-m", "plm_highway", *argv], cwd=cwd, env=env(),
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.updates = 0
        self.stderr = b""
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()

    def _drain(self) -> None:
        while chunk := self.process.stderr.read1(4096):
            self.stderr += chunk
            self.updates += chunk.count(b"\r") + chunk.count(b"\n")

    def wait(self, timeout: float = 600) -> tuple[int, str]:
        code = self.process.wait(timeout=timeout)
        self._reader.join(timeout=10)
        return code, self.stderr.decode("utf-8", "replace")


def run(cwd: Path, argv: list[str], timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "plm_highway", *argv], cwd=cwd, env=env(), capture_output=True,
                          text=True, timeout=timeout)


def tree(path: Path) -> dict[str, bytes] | bytes | None:
    """The bytes at ``path`` (a file), or every file under it (a directory), or None if absent."""
    if path.is_file():
        return path.read_bytes()
    if not path.is_dir():
        return None
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def without_volatile(content):
    """JSON documents with the VOLATILE fields dropped (so two complete runs compare equal)."""
    if isinstance(content, dict):
        return {name: without_volatile(data) for name, data in content.items()}
    if isinstance(content, bytes):
        try:
            data = json.loads(content)
        except (UnicodeDecodeError, ValueError):
            return content
        if isinstance(data, dict):
            return {key: value for key, value in data.items() if key not in VOLATILE}
    return content


def staging_dirs(target: Path) -> list[Path]:
    return sorted(p for p in target.parent.iterdir() if p.name.startswith(f".{target.name}{TMP_INFIX}"))


# command id -> (argv writing TARGET, the target's relative path, setup needing fixtures)
COMMANDS = {
    "collect": (["collect", "--track", "test", "--episodes", "2", "--episode-seconds", "2", "--seed", "1",
                 "--out", "target"], "target"),
    "train": (["train", "bm", "--data", "ds", "--epochs", "2", "--seed", "1", "--threads", "1", "--out", "target"],
              "target"),
    "evaluate-json": (["evaluate", "--policy", "expert", "--max-steps", "150", "--latency", "const:0.1",
                       "--json", "target.json"], "target.json"),
    "evaluate-out": (["evaluate", "--policy", "expert", "--max-steps", "150", "--latency", "const:0.1",
                      "--out", "target"], "target"),
    "reproduce": (["reproduce", "--settings", "const:0.1", "--generalise", "--max-steps", "40",
                   "--out", "target"], "target"),
    "diagnose": (["sim2real", "diagnose", "rec/r.csv", "--quiet", "--report", "target"], "target"),
}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A dataset and a recording the commands read (shared, read-only)."""
    root = tmp_path_factory.mktemp("fault_inputs")
    result = run(root, ["collect", "--track", "test", "--episodes", "2", "--episode-seconds", "2", "--out", "ds"])
    assert result.returncode == 0, result.stderr
    result = run(root, ["sim2real", "make-recording", "--effect", "transport_delay", "--duration-s", "40",
                        "--out", "rec/r.csv"])
    assert result.returncode == 0, result.stderr
    return root


def workdir(tmp_path: Path, inputs: Path) -> Path:
    work = tmp_path / "work"
    work.mkdir()
    for name in ("ds", "rec"):
        (work / name).symlink_to(inputs / name)
    return work


def kill_when(running: Running, ready, deadline_s: float) -> bool:
    """SIGKILL the command as soon as ``ready()``; False if it ended (or the deadline passed) first."""
    process = running.process
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if process.poll() is not None:
            running.wait()
            return False
        if ready():
            process.send_signal(signal.SIGKILL)
            running.wait()
            return True
        time.sleep(0.005)
    process.kill()
    running.wait()
    return False


@pytest.mark.timeout(1200)
@pytest.mark.parametrize("command", list(COMMANDS))
def test_sigkill_leaves_the_previous_output_or_the_new_one_whole(command, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    target = work / relative
    argv = [*argv, "--overwrite"]  # every run alike, so the recorded command lines agree too
    started = time.monotonic()
    first = Running(work, argv)
    code, stderr = first.wait()
    first_wall_s = time.monotonic() - started
    assert code == 0, stderr
    previous = tree(target)
    assert previous, f"{command} wrote nothing at {relative}"

    # Kill points: as the staging directory appears (mid-write); after a seeded random number of the
    # first run's progress updates (commands that show progress); at seeded random fractions of its wall time.
    rng = np.random.default_rng([KILL_SEED, len(command)])
    points: list[tuple[str, float | int | None]] = [("staging", None)]
    if first.updates >= 2:
        points.append(("updates", int(rng.integers(1, first.updates))))
    points += [("fraction", float(f)) for f in rng.uniform(0.2, 1.0, RANDOM_KILLS)]
    kills = 0
    for kind, at in points:
        name = f"{kind} {at}"
        process = Running(work, argv)
        begin = time.monotonic()
        if kind == "staging":
            def ready():
                return bool(staging_dirs(target))
        elif kind == "updates":
            def ready(process=process, at=at):
                return process.updates >= at
        else:
            def ready(begin=begin, at=at):
                return time.monotonic() - begin >= at * first_wall_s
        killed = kill_when(process, ready, deadline_s=10 * first_wall_s + 60)
        kills += killed
        now = tree(target)
        assert now == previous or without_volatile(now) == without_volatile(previous), (
            f"{command}: after a SIGKILL ({name}) the target is neither the previous output nor a whole new one")
    assert kills >= 1, f"{command}: no kill landed before the command finished"

    completed = run(work, argv)
    assert completed.returncode == 0, completed.stderr
    assert without_volatile(tree(target)) == without_volatile(previous)
    assert staging_dirs(target) == [], "the next run did not clean the killed runs' staging directories"


def _foreign(work: Path, relative: str, as_dir: bool) -> Path:
    target = work / relative
    if as_dir:
        target.mkdir()
        (target / "thesis.tex").write_text("\\documentclass{article} my thesis")
        (target / "data").mkdir()
        (target / "data" / "raw.bin").write_bytes(os.urandom(1000))
    else:
        target.write_bytes(b"{\"not\": \"plm-highway's\"}\n" + os.urandom(100))
    return target


@pytest.mark.timeout(600)
@pytest.mark.parametrize("as_dir", [True, False], ids=["foreign-directory", "foreign-file"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_foreign_content_at_the_target_survives(command, as_dir, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    target = _foreign(work, relative, as_dir)
    before = tree(target)
    for extra in ([], ["--overwrite"]):
        result = run(work, [*argv, *extra])
        assert result.returncode == 2, result.stderr
        assert "Traceback" not in result.stderr and relative in result.stderr
        assert tree(target) == before
        assert staging_dirs(target) == []


@pytest.mark.timeout(600)
@pytest.mark.parametrize("command", ["evaluate-json", "collect"])
def test_two_writers_of_one_target_one_wins_whole(command, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    processes = [Running(work, argv) for _ in range(2)]
    results = [p.wait() for p in processes]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    loser = next(stderr for code, stderr in results if code == 2)
    assert "Traceback" not in loser and relative in loser
    alone = tmp_path / "alone"
    alone.mkdir()
    for name in ("ds", "rec"):
        (alone / name).symlink_to(inputs / name)
    assert run(alone, argv).returncode == 0
    assert without_volatile(tree(work / relative)) == without_volatile(tree(alone / relative))
    assert staging_dirs(work / relative) == []
