"""Start ``plm-highway`` commands as processes of their own without paying the interpreter's imports each time.

``python tests/command_server.py MODULE...`` imports the command line and the given library modules once, then
reads requests from stdin, one JSON object a line: ``{"cwd": DIR, "argv": [...], "stderr": FILE}``. For each it
forks a child that runs ``plm_highway.cli.main(argv)`` in ``DIR`` exactly as ``python -m plm_highway`` would after
its imports (stdin and stdout on /dev/null, stderr appended to ``FILE``; its exit status is main's), and answers
``{"pid": PID}`` at once and ``{"exited": PID, "code": CODE}`` when the child has ended (a negative code: the
signal that ended it). Each child is a real process: it can be sent SIGKILL at any moment, and it holds its own
locks. At EOF on stdin the server kills the children still running, reaps them and exits.

Used where a test starts one command many times (tests/test_faults.py): a fresh ``python -m plm_highway`` spends
seconds importing torch, the simulator and plotting before the command does anything.
"""

from __future__ import annotations

import importlib
import json
import os
import select
import signal
import sys
import warnings

_MAIN = None


def _child(request: dict) -> None:
    """In the forked child: become the command, never return."""
    code = 1
    try:
        os.chdir(request["cwd"])
        null = os.open(os.devnull, os.O_RDWR)
        err = os.open(request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        os.dup2(null, 0)
        os.dup2(null, 1)
        os.dup2(err, 2)
        os.close(null)
        os.close(err)
        # sys.stdin, sys.stdout and sys.stderr stay the interpreter's own objects, now on the new descriptors: buffered
        # as in a fresh process (stderr line by line, and tqdm flushes each redraw).
        sys.argv = [str(os.path.join(os.path.dirname(sys.modules["plm_highway"].__file__), "__main__.py")),
                    *request["argv"]]
        try:
            code = _MAIN(list(request["argv"]))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        import atexit

        atexit._run_exitfuncs()
    except BaseException:
        import traceback

        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(code if isinstance(code, int) else 1)


def _say(message: dict) -> None:
    sys.__stdout__.write(json.dumps(message) + "\n")
    sys.__stdout__.flush()


def _reap(children: set[int]) -> None:
    while children:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            children.clear()
            return
        if pid == 0:
            return
        children.discard(pid)
        _say({"exited": pid, "code": os.waitstatus_to_exitcode(status)})


def serve(modules: list[str]) -> None:
    global _MAIN
    warnings.simplefilter("ignore", DeprecationWarning)  # os.fork with the BLAS pool's idle threads alive
    from plm_highway.cli import main

    _MAIN = main
    for name in modules:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            pass  # only a head start: a child imports what it needs
    _say({"ready": True})
    children: set[int] = set()
    stdin = sys.stdin.buffer
    pending = b""
    while True:
        readable, _, _ = select.select([stdin], [], [], 0.005)
        if readable:
            chunk = os.read(stdin.fileno(), 65536)
            if not chunk:
                break
            pending += chunk
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                request = json.loads(line)
                pid = os.fork()
                if pid == 0:
                    _child(request)
                children.add(pid)
                _say({"pid": pid})
        _reap(children)
    for pid in list(children):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    while children:
        pid, status = os.waitpid(-1, 0)
        children.discard(pid)


if __name__ == "__main__":
    serve(sys.argv[1:])
