"""The fault battery: SIGKILL, foreign content, two writers at once, and what --overwrite may touch.

For each writing command (collect, train bm, evaluate --json, evaluate --out, reproduce, sim2real
diagnose --report):

- a first run publishes an output; the same command with ``--overwrite`` is then killed with
  SIGKILL at several points: as soon as its staging directory appears (mid-write), after a seeded
  random number of progress updates (commands that show progress), and after seeded random
  fractions of the first run's wall time. After every kill the target is the first
  run's output byte for byte, or (a kill after publishing) the new output whole;
- a run that completes afterwards (a fresh ``python -m plm_highway``) removes the staging
  directories the killed runs left, and writes the first run's output again;
- a foreign directory and a foreign file at the target survive every command byte-identical, and
  the command refuses before any work (the refusal is all it prints);
- two processes writing one new target at once: one publishes whole, the other exits 2 cleanly.

Every other run is a process of its own forked from one interpreter that imported the library
beforehand (tests/command_server.py): a SIGKILL ends it as it ends any process, and the random
kill points fall in the command's own work, not in the seconds a fresh interpreter spends importing
torch and the simulator, when nothing is written yet.

The commands are deterministic under their seed, so the new output of an ``--overwrite`` run is
byte-identical to the first one except for the fields listed in ``VOLATILE`` (wall times).

Then, in-process and only in ``tmp_path``: ``--overwrite`` keeps every file the earlier output's
manifest does not list (and says so), refuses one where the new output writes, never replaces an
input of the run, never touches a name that merely looks like a staging directory; a sweep's grid,
table and figures publish as one set; output names stay unique; training gives the same bytes under
any CPU affinity.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

REPO_ROOT = Path(__file__).resolve().parent.parent
TMP_INFIX = ".plm-highway-tmp-"
pytestmark = pytest.mark.slow

# Fields that legitimately differ between two runs of one command (documented in docs/reliability.md).
VOLATILE = {"elapsed_s"}

KILL_SEED = 8  # the random kill points are drawn from this seed
RANDOM_KILLS = 2  # kills at random fractions of a run's wall time, besides the staging and progress points


def env() -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO_ROOT), "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}


# What the commands below import, the command server imports once (torch's optimiser pulls in its compiler's
# configuration at the first step).
SERVER_MODULES = ["plm_highway.data.collect", "plm_highway.data.dataset", "plm_highway.training.train",
                  "plm_highway.evaluation.evaluate", "plm_highway.evaluation.reproduce", "plm_highway.rollout.policies",
                  "plm_highway.sim2real.workflow", "plm_highway.sim2real.diagnose", "plm_highway.sim2real.report",
                  "torch._inductor.config", *(f"plm_highway.cli.{name}" for name in
                                              ("collect", "train", "evaluate", "reproduce", "sim2real"))]


class CommandServer:
    """tests/command_server.py: each command a process of its own, forked from an interpreter that imported the
    library once (a fresh ``python -m plm_highway`` spends seconds on imports before it does anything)."""

    def __init__(self, stderr_dir: Path):
        self.stderr_dir = stderr_dir
        self.process = subprocess.Popen([sys.executable, str(REPO_ROOT / "tests" / "command_server.py"),
                                         *SERVER_MODULES], env=env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, bufsize=1)
        ready = self.process.stdout.readline()
        assert ready and json.loads(ready) == {"ready": True}, "the command server did not start"
        self._lock = threading.Lock()
        self._started: queue.Queue[int] = queue.Queue()
        self._exits: dict[int, int] = {}
        self._gone = False  # the server's stdout closed: it reports nothing more
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.process.stdout:
            message = json.loads(line)
            if "pid" in message:
                self._started.put(message["pid"])
            else:
                with self._changed:
                    self._exits[message["exited"]] = message["code"]
                    self._changed.notify_all()
        with self._changed:
            self._gone = True
            self._changed.notify_all()

    def start(self, cwd: Path, argv: list[str], stderr: Path) -> int:
        with self._lock:
            self.process.stdin.write(json.dumps({"cwd": str(cwd), "argv": argv, "stderr": str(stderr)}) + "\n")
            self.process.stdin.flush()
            return self._started.get(timeout=60)

    def exit_code(self, pid: int, timeout: float | None) -> int | None:
        """The command's exit status (negative: the signal that ended it), or None while it runs."""
        with self._changed:
            self._changed.wait_for(lambda: pid in self._exits or self._gone, timeout=timeout)
            if pid not in self._exits and self._gone:
                raise RuntimeError(f"the command server ended before reporting process {pid}")
            return self._exits.get(pid)

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=60)


class Running:
    """A command in a process of its own (forked by the command server), its stderr in a file whose progress
    updates are counted (tqdm redraws end in a carriage return, log lines in a newline)."""

    _numbers = itertools.count()

    def __init__(self, server: CommandServer, cwd: Path, argv: list[str]):
        self.server = server
        self.stderr_path = server.stderr_dir / f"stderr-{next(self._numbers)}.txt"
        self.stderr_path.touch()
        self.pid = server.start(cwd, argv, self.stderr_path)

    @property
    def updates(self) -> int:
        data = self.stderr_path.read_bytes()
        return data.count(b"\r") + data.count(b"\n")

    def poll(self) -> int | None:
        return self.server.exit_code(self.pid, timeout=0)

    def kill(self) -> None:
        if self.poll() is None:  # not reported as ended: a child of the server, not yet reaped, so still this command
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)

    def wait(self, timeout: float = 600) -> tuple[int, str]:
        code = self.server.exit_code(self.pid, timeout)
        if code is None:
            self.kill()
            raise TimeoutError(f"{self.pid} ran past {timeout} s")
        return code, self.stderr_path.read_bytes().decode("utf-8", "replace")


def run(cwd: Path, argv: list[str], timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m plm_highway ARGV`` from the start, imports and all."""
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
    "reproduce": (["reproduce", "--settings", "const:0.1", "--seeds", "1", "--generalise", "--max-steps", "40",
                   "--workers", "0", "--out", "target"], "target"),
    "diagnose": (["sim2real", "diagnose", "rec/r.csv", "--quiet", "--report", "target"], "target"),
}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    server = CommandServer(tmp_path_factory.mktemp("fault_stderr"))
    yield server
    server.close()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, server) -> Path:
    """A dataset and a recording the commands read (shared, read-only)."""
    root = tmp_path_factory.mktemp("fault_inputs")
    for argv in (["collect", "--track", "test", "--episodes", "2", "--episode-seconds", "2", "--out", "ds"],
                 ["sim2real", "make-recording", "--effect", "transport_delay", "--duration-s", "40", "--out", "rec/r.csv"]):
        code, stderr = Running(server, root, argv).wait()
        assert code == 0, stderr
    return root


def workdir(tmp_path: Path, inputs: Path) -> Path:
    work = tmp_path / "work"
    work.mkdir()
    for name in ("ds", "rec"):
        (work / name).symlink_to(inputs / name)
    return work


def kill_when(running: Running, ready, deadline_s: float) -> bool:
    """SIGKILL the command as soon as ``ready()``; whether the SIGKILL ended it (False: it ended first, or the
    deadline passed and it was killed then)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end and running.poll() is None:
        if ready():
            running.kill()
            return running.wait()[0] == -signal.SIGKILL
        time.sleep(0.005)
    running.kill()
    running.wait()
    return False


@pytest.mark.timeout(1200)
@pytest.mark.parametrize("command", list(COMMANDS))
def test_sigkill_leaves_the_previous_output_or_the_new_one_whole(command, server, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    target = work / relative
    argv = [*argv, "--overwrite"]  # every run alike, so the recorded command lines agree too
    started = time.monotonic()
    first = Running(server, work, argv)
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
        process = Running(server, work, argv)
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

    # A fresh interpreter (its own hash seed, nothing imported beforehand) writes the same output again.
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
def test_foreign_content_at_the_target_survives(command, as_dir, server, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    target = _foreign(work, relative, as_dir)
    before = tree(target)
    for extra in ([], ["--overwrite"]):
        code, stderr = Running(server, work, [*argv, *extra]).wait()
        assert code == 2, stderr
        assert "Traceback" not in stderr and relative in stderr
        # Refused before any work: the refusal is all the command printed (no progress, no log line).
        assert stderr.startswith(f"plm-highway {argv[0]}") and stderr.count("\n") == 1 and "\r" not in stderr, stderr
        assert tree(target) == before
        assert staging_dirs(target) == []


@pytest.mark.timeout(600)
@pytest.mark.parametrize("command", ["evaluate-json", "collect"])
def test_two_writers_of_one_target_one_wins_whole(command, server, inputs, tmp_path):
    argv, relative = COMMANDS[command]
    work = workdir(tmp_path, inputs)
    processes = [Running(server, work, argv) for _ in range(2)]
    results = [p.wait() for p in processes]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    loser = next(stderr for code, stderr in results if code == 2)
    assert "Traceback" not in loser and relative in loser
    # A loser that started while the other was writing is told who is writing there, not advised to replace a
    # result it has never seen; on a loaded machine it may start only after the winner published, and is then
    # refused as any command whose output already exists.
    assert ("another plm-highway" in loser and "--overwrite" not in loser) or "already holds" in loser, loser
    alone = tmp_path / "alone"
    alone.mkdir()
    for name in ("ds", "rec"):
        (alone / name).symlink_to(inputs / name)
    assert run(alone, argv).returncode == 0
    assert without_volatile(tree(work / relative)) == without_volatile(tree(alone / relative))
    assert staging_dirs(work / relative) == []


# -- --overwrite replaces only what plm-highway wrote (the manifest), in-process and in tmp_path only ------


def files_with_meta(root: Path) -> dict[str, tuple]:
    """Every entry under ``root`` (hidden ones too): bytes (or link target), permission bits and mtime."""
    state = {}
    for path in sorted(root.rglob("*")):
        rel = str(path.relative_to(root))
        info = path.lstat()
        if path.is_symlink():
            state[rel] = ("link", os.readlink(path))
        elif path.is_dir():
            state[rel] = ("dir", oct(info.st_mode & 0o7777))
        else:
            state[rel] = (path.read_bytes(), oct(info.st_mode & 0o7777), info.st_mtime_ns)
    return state


def kit_output(target: Path, files: dict[str, bytes], *, overwrite: bool = False, **options) -> None:
    from plm_highway.io import write_output
    from plm_highway.io.outputs import directory_kind

    with write_output(target, directory_kind("test-output", "a test output"), overwrite=overwrite, **options) as tmp:
        for relative, data in files.items():
            (tmp / relative).parent.mkdir(parents=True, exist_ok=True)
            (tmp / relative).write_bytes(data)


def cli(argv: list[str]) -> tuple[int, str]:
    import io

    from plm_highway.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, err.getvalue()


TRACK_JSON = json.dumps({"name": "t", "lanes": 3, "lane_width_m": 4.0,
                         "segments": [{"type": "straight", "length_m": 200}]})


def test_overwrite_keeps_user_files_and_the_runs_own_track(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["evaluate", "--policy", "expert", "--max-steps", "3", "--out", "D"]
    assert cli(argv)[0] == 0
    (tmp_path / "D" / "NOTES.txt").write_text("my notes")
    (tmp_path / "D" / "t.json").write_text(TRACK_JSON)
    os.chmod(tmp_path / "D" / "NOTES.txt", 0o600)
    (tmp_path / "D" / "mine" / "deep").mkdir(parents=True)
    (tmp_path / "D" / "mine" / "deep" / "x.bin").write_bytes(os.urandom(64))
    (tmp_path / "D" / "link").symlink_to("NOTES.txt")
    before = files_with_meta(tmp_path / "D")
    code, err = cli(["evaluate", "--policy", "expert", "--max-steps", "3", "--track", "D/t.json", "--out", "D",
                     "--overwrite"])
    assert code == 0, err
    after = files_with_meta(tmp_path / "D")
    for rel in ("NOTES.txt", "t.json", "mine/deep/x.bin", "link"):
        assert after[rel] == before[rel], rel
    assert "warning" in err and "NOTES.txt" in err and "t.json" in err and "mine/deep/x.bin" in err
    assert json.loads((tmp_path / "D" / "result.json").read_text())["track"] != before  # the new result is there


@pytest.mark.parametrize("how", ["changed-kit-file", "new-path-collision", "dir-where-file-goes"])
def test_a_user_file_where_the_new_output_writes_is_refused_and_nothing_changes(tmp_path, how):
    from plm_highway.errors import OutputRefused

    target = tmp_path / "out"
    kit_output(target, {"a.txt": b"kit a", "sub/b.txt": b"kit b"})
    if how == "changed-kit-file":
        (target / "a.txt").write_bytes(b"edited by the user")
        culprit = "a.txt"
    elif how == "new-path-collision":
        (target / "c.txt").write_bytes(b"user c")
        culprit = "c.txt"
    else:
        (target / "c.txt").mkdir()
        (target / "c.txt" / "inner").write_text("user")
        culprit = "c.txt/inner"
    before = files_with_meta(tmp_path)
    with pytest.raises(OutputRefused, match=culprit.replace(".", r"\.")):
        kit_output(target, {"a.txt": b"new a", "c.txt": b"new c"}, overwrite=True)
    assert files_with_meta(tmp_path) == before


def test_a_kit_file_that_is_an_input_of_the_run_is_never_replaced(tmp_path):
    from plm_highway.errors import OutputRefused
    from plm_highway.io import protected_inputs

    target = tmp_path / "out"
    kit_output(target, {"grid.json": b"{}", "other.txt": b"x"})
    before = files_with_meta(tmp_path)
    with protected_inputs([target / "grid.json"]), pytest.raises(OutputRefused, match=r"grid\.json.*input of this run"):
        kit_output(target, {"grid.json": b"{\"new\": 1}"}, overwrite=True)
    assert files_with_meta(tmp_path) == before
    # Not rewritten by the new output: carried instead of removed with the earlier output.
    with protected_inputs([target / "grid.json"]):
        kit_output(target, {"other.txt": b"y"}, overwrite=True)
    assert (target / "grid.json").read_bytes() == b"{}" and (target / "other.txt").read_bytes() == b"y"


def test_a_directory_input_protects_what_lies_inside_the_output_not_around_it(tmp_path):
    from plm_highway.errors import OutputRefused
    from plm_highway.io import protected_inputs

    target = tmp_path / "out"
    kit_output(target, {"model.pt": b"bm weights", "model.json": b"{}", "sub/data.bin": b"read"})
    before = files_with_meta(tmp_path)
    with protected_inputs([target]), pytest.raises(OutputRefused, match=r"out'?: it is an input of this run"):
        kit_output(target, {"model.pt": b"tapm weights"}, overwrite=True)  # train tapm --bm C --out C
    assert files_with_meta(tmp_path) == before
    with protected_inputs([target / "sub"]), pytest.raises(OutputRefused, match=r"sub/data\.bin.*input of this run"):
        kit_output(target, {"sub/data.bin": b"replaced"}, overwrite=True)  # --checkpoints R/ck --out R
    assert files_with_meta(tmp_path) == before
    with protected_inputs([tmp_path]):  # --checkpoints . --out out: the output lies inside the input
        kit_output(target, {"model.pt": b"new"}, overwrite=True)
    assert (target / "model.pt").read_bytes() == b"new" and not (target / "model.json").exists()


def test_the_command_line_protects_every_input_it_names(tmp_path, monkeypatch):
    from plm_highway.cli import build_parser, input_paths

    monkeypatch.chdir(tmp_path)
    for name in ("t.json", "a,b.csv", "c.csv"):
        (tmp_path / name).write_text("x")
    argv = ["evaluate", "--track", "t.json", "--latency", "trace:a,b.csv", "--out", "D", "--json", "c.csv"]
    args = build_parser(argv).parse_args(argv)
    assert sorted(input_paths(args)) == ["a,b.csv", "t.json"]


def test_outputs_written_before_manifests_keep_everything_not_recognisably_the_kits(tmp_path):
    from plm_highway.io import MARKER_NAME

    target = tmp_path / "old"
    target.mkdir()
    (target / MARKER_NAME).write_text(json.dumps({"tool": "plm-highway", "version": "0.0", "kind": "test-output"}))
    (target / "a.txt").write_text("written by an old plm-highway")
    (target / "notes.txt").write_text("the user's")
    kit_output(target, {"a.txt": b"new"}, overwrite=True)
    assert (target / "a.txt").read_bytes() == b"new" and (target / "notes.txt").read_text() == "the user's"
    manifest = json.loads((target / MARKER_NAME).read_text())
    assert sorted(manifest["files"]) == ["a.txt"]  # the user's file stays theirs


def test_a_second_overwrite_still_knows_which_files_are_the_users(tmp_path):
    target = tmp_path / "out"
    kit_output(target, {"a.txt": b"1", "old-only.txt": b"1"})
    (target / "mine.txt").write_text("mine")
    kit_output(target, {"a.txt": b"2"}, overwrite=True)
    assert not (target / "old-only.txt").exists()  # the kit's own earlier file goes
    kit_output(target, {"a.txt": b"3"}, overwrite=True)
    assert (target / "mine.txt").read_text() == "mine" and (target / "a.txt").read_bytes() == b"3"


STAGING_LOOKALIKES = {
    "no-lock": {},
    "garbage-lock": {".lock": b"\x00garbage"},
    "forged-claim": {".lock": json.dumps({"tool": "plm-highway staging directory", "staging": "x", "target": "out",
                                          "device": 1, "inode": 2}).encode()},
}


@pytest.mark.parametrize("lock", list(STAGING_LOOKALIKES))
@pytest.mark.parametrize("exists", [True, False], ids=["target-exists", "target-absent"])
def test_names_that_look_like_staging_are_never_removed_or_renamed_into_place(tmp_path, lock, exists):
    target = tmp_path / "out"
    if exists:
        kit_output(target, {"a.txt": b"1"})
    lookalike = tmp_path / f".out{TMP_INFIX}999999-abcd"
    lookalike.mkdir()
    (lookalike / ".previous").mkdir()
    (lookalike / ".previous" / "thesis.tex").write_text("my thesis")
    for name, data in STAGING_LOOKALIKES[lock].items():
        (lookalike / name).write_bytes(data)
    (tmp_path / f".out{TMP_INFIX}1-file").write_text("a file with a staging-like name")
    before = {k: v for k, v in files_with_meta(tmp_path).items() if k.startswith(".")}
    kit_output(target, {"a.txt": b"2"}, overwrite=exists)
    assert {k: v for k, v in files_with_meta(tmp_path).items() if k.startswith(".")} == before
    assert (target / "a.txt").read_bytes() == b"2"


def test_a_dead_runs_own_staging_is_still_cleaned(tmp_path):
    from plm_highway.io.outputs import _stage, remove_stale_staging

    target = tmp_path / "out"
    staged = _stage(target, OutputKindForTests.DIR, False, None, ())
    os.close(staged.lock_fd)  # as if the process died: its lock is released
    assert remove_stale_staging(target) == [staged.staging_dir] and not staged.staging_dir.exists()


class OutputKindForTests:
    from plm_highway.io.outputs import directory_kind, file_kind

    DIR = directory_kind("test-output", "a test output")
    FILE = file_kind("test-file", "a test JSON file")


def test_replacing_keeps_the_permission_bits(tmp_path):
    from plm_highway.io import write_json

    path = tmp_path / "r.json"
    write_json(path, {"a": 1}, OutputKindForTests.FILE)
    os.chmod(path, 0o640)
    write_json(path, {"a": 2}, OutputKindForTests.FILE, overwrite=True)
    assert path.stat().st_mode & 0o777 == 0o640 and json.loads(path.read_text())["a"] == 2
    target = tmp_path / "d"
    kit_output(target, {"x": b"1"})
    os.chmod(target, 0o750)
    kit_output(target, {"x": b"2"}, overwrite=True)
    assert target.stat().st_mode & 0o777 == 0o750


def test_a_target_that_appears_meanwhile_is_refused_without_advising_overwrite(tmp_path):
    from plm_highway.errors import OutputRefused
    from plm_highway.io import write_json, write_output

    path = tmp_path / "r.json"
    with pytest.raises(OutputRefused) as refusal:
        with write_output(path, OutputKindForTests.FILE, overwrite=True) as tmp:
            tmp.write_text("{}")
            write_json(path, {"other": "process"}, OutputKindForTests.FILE)  # another writer wins meanwhile
    message = str(refusal.value)
    assert "--overwrite" not in message and "another plm-highway wrote" in message
    assert "while this run was working" in message
    assert json.loads(path.read_text())["other"] == "process"


def test_a_failed_or_refused_run_leaves_no_directories_it_made(tmp_path):
    from plm_highway.io import write_output

    with pytest.raises(KeyboardInterrupt):
        with write_output(tmp_path / "a" / "b" / "c.json", OutputKindForTests.FILE):
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_json_to_a_name_ending_in_a_slash_writes_no_file_named_like_the_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = cli(["evaluate", "--policy", "expert", "--max-steps", "1", "--json", "res/"])
    assert code == 2 and "res/" in err and "directory" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


NAMES = st.sampled_from(["a", "b", "c", "d.txt", "e.json", "sub"])
RELATIVE = st.lists(NAMES, min_size=1, max_size=3).map("/".join)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kit=st.dictionaries(RELATIVE, st.binary(max_size=8), max_size=5),
       user=st.dictionaries(RELATIVE, st.binary(max_size=8), max_size=5),
       new=st.dictionaries(RELATIVE, st.binary(max_size=8), max_size=5))
def test_overwrite_never_removes_or_changes_a_file_not_in_the_manifest(tmp_path_factory, kit, user, new):
    """Whatever the earlier output, the user's additions and the new output: either the user's files are all
    there byte for byte afterwards (and the new output whole), or the overwrite is refused and nothing changed."""
    from plm_highway.errors import OutputRefused

    root = tmp_path_factory.mktemp("prop")
    target = root / "out"
    try:
        kit_output(target, kit)
    except (OSError, FileExistsError, NotADirectoryError, IsADirectoryError):
        return  # paths that cannot coexist (a file and a directory of one name): not an output
    added = {}
    for relative, data in user.items():
        path = target / relative
        try:
            if path.exists() or any((target / a).is_file() for a in _ancestors(relative)):
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
            added[relative] = data
        except OSError:
            continue
    before = files_with_meta(root)
    try:
        kit_output(target, new, overwrite=True)
    except OutputRefused:
        assert files_with_meta(root) == before
        return
    except (OSError, FileExistsError, NotADirectoryError, IsADirectoryError):
        return
    for relative, data in added.items():
        assert (target / relative).read_bytes() == data, relative
    for relative, data in new.items():
        assert (target / relative).read_bytes() == data, relative
    for relative in kit:
        if relative not in new and relative not in added and not any(r.startswith(relative + "/") for r in added):
            assert not (target / relative).is_file(), f"the earlier output's {relative} was kept"


def _ancestors(relative: str) -> list[str]:
    parts = relative.split("/")
    return ["/".join(parts[:i]) for i in range(1, len(parts))]


# -- a sweep's grid, table and figures publish as one set; output names are unique ----------------------

SWEEP_GRID_SMALL = dict(latencies=("const:0.1",), tracks=("test",), seeds=(0,), policies=("expert",), max_steps=8)


def sweep_set(out: Path) -> dict:
    return {name: tree(out / name) for name in ("grid.json", "results.csv", "figures")}


def test_an_interrupted_resume_with_a_changed_grid_leaves_the_previous_set_whole(tmp_path, monkeypatch):
    from plm_highway.sweep import SweepGrid, run_sweep
    from plm_highway.sweep import runner as sweep_runner

    out = tmp_path / "sweep"
    run_sweep(SweepGrid(**SWEEP_GRID_SMALL), out, workers=0, progress=False)
    previous = sweep_set(out)
    assert all(previous.values())

    def interrupted(job):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_runner, "run_chunk", interrupted)
    changed = SweepGrid(**{**SWEEP_GRID_SMALL, "latencies": ("const:0.1", "const:0.2")})
    with pytest.raises(KeyboardInterrupt):
        run_sweep(changed, out, workers=0, progress=False)
    assert sweep_set(out) == previous
    monkeypatch.undo()
    summary = run_sweep(changed, out, workers=0, progress=False)
    assert summary["resumed"] == 2 and json.loads((out / "grid.json").read_text())["latencies"] == ["const:0.1",
                                                                                                  "const:0.2"]
    assert len((out / "results.csv").read_text().splitlines()) == 1 + 3


def test_a_sweep_resume_keeps_the_users_files_and_its_cells(tmp_path):
    from plm_highway.sweep import SweepGrid, run_sweep

    out = tmp_path / "sweep"
    run_sweep(SweepGrid(**SWEEP_GRID_SMALL), out, workers=0, progress=False)
    (out / "analysis.ipynb").write_text("{}")
    (out / "figures" / "my_plot.png").write_bytes(b"\x89PNG\r\n\x1a\nmine")
    cells = tree(out / "cells")
    run_sweep(SweepGrid(**{**SWEEP_GRID_SMALL, "seeds": (0, 1)}), out, workers=0, progress=False)
    assert (out / "analysis.ipynb").read_text() == "{}"
    assert (out / "figures" / "my_plot.png").read_bytes() == b"\x89PNG\r\n\x1a\nmine"
    assert set(cells) < set(tree(out / "cells")) and all(tree(out / "cells")[k] == v for k, v in cells.items())


def test_two_tracks_with_one_file_name_get_two_figures(tmp_path):
    from plm_highway.sweep import SweepGrid
    from plm_highway.sweep.table import figure_names

    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "t.json").write_text(TRACK_JSON)
    grid = SweepGrid(latencies=("const:0.1",), tracks=(str(tmp_path / "a" / "t.json"), str(tmp_path / "b" / "t.json")),
                     policies=("expert",), conditions={"x_y": {}, "x-y": {}})
    names = [name for _, _, name in figure_names(grid)]
    assert len({name.lower() for name in names}) == 4, names


def test_settings_that_round_alike_get_distinct_figure_names():
    from plm_highway.evaluation.protocol import setting_tag

    tags = [setting_tag(spec) for spec in ("const:0.199", "const:0.201", "const:0.2", "const:0.20")]
    assert tags[0] != tags[1] != tags[2] and tags[2] == tags[3] == "0.20s"


def test_two_figures_of_one_output_with_one_name_are_refused(tmp_path):
    from plm_highway.io import pyplot, save_figure_into

    fig = pyplot().figure()
    save_figure_into(fig, tmp_path / "f.png")
    with pytest.raises(RuntimeError, match="both named 'f.png'"):
        save_figure_into(fig, tmp_path / "f.png")
    pyplot().close(fig)


# -- one training command, one result: the thread count does not follow the CPU affinity -----------------


@pytest.mark.timeout(1200)
def test_training_writes_the_same_bytes_whatever_the_cpu_affinity(inputs, tmp_path):
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        pytest.skip("needs a machine with two CPUs to compare one CPU with two")
    argv = ["train", "bm", "--data", "ds", "--epochs", "1", "--max-samples", "200", "--seed", "3", "--quiet",
            "--out", "ck"]
    results = []
    for allowed in ({cpus[0]}, set(cpus)):
        work = tmp_path / f"cpus{len(allowed)}"
        work.mkdir()
        (work / "ds").symlink_to(inputs / "ds")
        done = subprocess.run([sys.executable, "-m", "plm_highway", *argv], cwd=work, env=env(), capture_output=True,
                              text=True, timeout=1100, preexec_fn=lambda allowed=allowed: os.sched_setaffinity(0, allowed))
        assert done.returncode == 0, done.stderr
        results.append(tree(work / "ck"))
    assert results[0] == results[1]
    assert json.loads(results[0]["model.json"])["training"]["threads"] == 2
