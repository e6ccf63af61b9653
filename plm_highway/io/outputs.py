"""Safe outputs: a command writes a new path, or replaces an earlier output of its own kind; nothing else.

The rules (README, "Reliability"):

- The target path must name something: an empty name, ``.``, ``..``, the current directory or one
  of its ancestors, the home directory, a filesystem root and symbolic links are refused.
- A missing target (or an empty directory where a directory goes) is created. An existing target is replaced only if it is an output of the same
  kind that plm-highway recognises (:class:`OutputKind`) **and** ``overwrite`` is set; a file where a
  directory goes (or the reverse), or anything not recognised, is refused, naming the path and what
  is there. Nothing is touched when a target is refused.
- Every output is staged in a temporary sibling ``.NAME.plm-highway-tmp-PID-XXXX`` and published in
  one rename (an existing directory is swapped in one ``renameat2(RENAME_EXCHANGE)`` on Linux), so a
  crash or SIGKILL at any moment leaves the previous output or the new one whole, never a mixture.
  Staging directories of crashed runs are removed by the next run that writes the same target (a
  live process holds a lock on its own staging directory, so only dead ones are removed).
- The check and the rename happen under an exclusive lock on the parent directory: of two processes
  writing one target, one publishes whole; the other then finds that output there and is refused
  (or, with ``overwrite``, replaces it whole).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from plm_highway.errors import OutputRefused

MARKER_NAME = ".plm-highway-output.json"  # inside every directory plm-highway writes
JSON_MARKER_KEY = "plm_highway_output"  # top-level key of every JSON object plm-highway writes
PNG_SOFTWARE = "plm-highway"  # the PNG "Software" text chunk of every figure plm-highway writes
TMP_INFIX = ".plm-highway-tmp-"
_STAGING_LOCK = ".lock"


@dataclass(frozen=True)
class OutputKind:
    """One kind of output a command writes, and how to recognise an earlier one at a path.

    ``recognisers`` are extra tests for outputs written before markers existed (a dataset's
    ``manifest.json``, a checkpoint's ``model.json``); the marker alone suffices otherwise.
    """

    name: str
    is_dir: bool
    describe: str  # what it is, for messages: "a dataset directory", "an evaluation JSON file"
    csv_header: tuple[str, ...] | None = None  # CSV files: recognised by this exact header row
    recognisers: tuple[Callable[[Path], bool], ...] = field(default=())

    def recognises(self, path: Path) -> bool:
        if self.is_dir != path.is_dir():
            return False
        if self.is_dir:
            if _marker_kind(path) == self.name:
                return True
        else:
            suffix = path.suffix.lower()
            if suffix == ".json" and _json_marker_kind(path) == self.name:
                return True
            if suffix == ".png" and _png_software(path) == PNG_SOFTWARE:
                return True
            if self.csv_header is not None and _first_line(path) == ",".join(self.csv_header):
                return True
        return any(recognise(path) for recognise in self.recognisers)


def directory_kind(name: str, describe: str, *recognisers: Callable[[Path], bool]) -> OutputKind:
    return OutputKind(name, True, describe, recognisers=tuple(recognisers))


def file_kind(name: str, describe: str, csv_header: Sequence[str] | None = None,
              *recognisers: Callable[[Path], bool]) -> OutputKind:
    header = None if csv_header is None else tuple(csv_header)
    return OutputKind(name, False, describe, csv_header=header, recognisers=tuple(recognisers))


# -- recognising ---------------------------------------------------------------------------------


def _marker_kind(directory: Path) -> str | None:
    try:
        data = json.loads((directory / MARKER_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data.get("kind") if isinstance(data, dict) else None


def _json_marker_kind(path: Path, max_bytes: int = 64 << 20) -> str | None:
    try:
        if path.stat().st_size > max_bytes:
            return None
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data.get(JSON_MARKER_KEY) if isinstance(data, dict) else None


def _first_line(path: Path, limit: int = 65536) -> str | None:
    try:
        with open(path, "rb") as handle:
            line = handle.readline(limit)
    except OSError:
        return None
    try:
        return line.decode("utf-8").rstrip("\r\n")
    except UnicodeDecodeError:
        return None


def _png_software(path: Path, max_chunks: int = 64) -> str | None:
    """The PNG's ``Software`` tEXt value, read from the chunks before the image data."""
    try:
        with open(path, "rb") as handle:
            if handle.read(8) != b"\x89PNG\r\n\x1a\n":
                return None
            for _ in range(max_chunks):
                header = handle.read(8)
                if len(header) < 8:
                    return None
                length, chunk_type = int.from_bytes(header[:4], "big"), header[4:]
                if chunk_type in (b"IDAT", b"IEND") or length > 1 << 20:
                    return None
                data = handle.read(length)
                handle.read(4)  # CRC
                if chunk_type == b"tEXt":
                    key, _, value = data.partition(b"\x00")
                    if key == b"Software":
                        return value.decode("latin-1")
    except OSError:
        return None
    return None


def describe_existing(path: Path) -> str:
    """What is at ``path``, in a few words, for a refusal message."""
    if path.is_symlink():
        return f"a symbolic link to {os.readlink(path)!r}"
    if path.is_dir():
        try:
            entries = sorted(entry.name for entry in path.iterdir())
        except OSError:
            return "a directory that cannot be listed"
        if not entries:
            return "an empty directory"
        shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
        kind = _marker_kind(path)
        written = f" (a plm-highway '{kind}' output)" if kind else ""
        return f"a directory with {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}{written}: {shown}"
    if path.is_file():
        return f"a file of {path.stat().st_size:,} bytes"
    return "something that is neither a file nor a directory"


# -- checking a target ----------------------------------------------------------------------------


def _protected_reason(path: Path) -> str | None:
    if path.name in ("", ".", ".."):
        return "it does not name a file or directory of its own"
    resolved = path.resolve()
    if resolved == Path(resolved.anchor):
        return "it is a filesystem root"
    with contextlib.suppress(RuntimeError, KeyError):
        if resolved == Path.home().resolve():
            return "it is your home directory"
    cwd = Path.cwd().resolve()
    if resolved == cwd or resolved in cwd.parents:
        return "it is the current directory or contains it"
    return None


def check_target(path: str | os.PathLike, kind: OutputKind, *, overwrite: bool = False) -> Path:
    """Refuse (:class:`OutputRefused`) unless ``path`` may receive an output of ``kind``; returns the path.

    Call it before long work starts, so a refusal costs nothing; publishing checks again.
    """
    text = os.fspath(path)
    if not text or not text.strip():
        raise OutputRefused(f"output path {text!r}: empty; give a file or directory name")
    target = Path(text)
    reason = _protected_reason(target)
    if reason is not None:
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: {reason}; choose a new path")
    if target.is_symlink():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: it is {describe_existing(target)}; "
                            "plm-highway does not write through links")
    if not target.exists():
        _check_parent(target, kind)
        return target
    there = describe_existing(target)
    if kind.is_dir and not target.is_dir():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: a directory goes there, but it is {there}")
    if not kind.is_dir and target.is_dir():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: a file goes there, but it is {there}")
    if kind.is_dir and not any(target.iterdir()):
        return target  # an empty directory holds nothing to lose (e.g. made with mkdir beforehand)
    if not kind.recognises(target):
        raise OutputRefused(f"refusing to replace {text!r}: it is {there}, not {kind.describe} that plm-highway "
                            "wrote; nothing was changed. Choose a new path, or move it away yourself")
    if not overwrite:
        raise OutputRefused(f"{text!r} already holds {kind.describe} (an earlier output); pass --overwrite to "
                            "replace it, or choose a new path")
    return target


def _check_parent(target: Path, kind: OutputKind) -> None:
    for ancestor in target.absolute().parents:
        if ancestor.exists():
            if not ancestor.is_dir():
                raise OutputRefused(f"cannot write {kind.describe} at {str(target)!r}: {str(ancestor)!r} is "
                                    f"{describe_existing(ancestor)}, not a directory")
            return


# -- staging and publishing -----------------------------------------------------------------------


@dataclass
class _Staged:
    target: Path
    kind: OutputKind
    overwrite: bool
    staging_dir: Path
    lock_fd: int

    @property
    def path(self) -> Path:
        return self.staging_dir / self.target.name


def _stage(target: Path, kind: OutputKind, overwrite: bool) -> _Staged:
    target = check_target(target, kind, overwrite=overwrite)
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(target)
    staging_dir = Path(tempfile.mkdtemp(prefix=f".{target.name}{TMP_INFIX}{os.getpid()}-", dir=parent))
    lock_fd = os.open(staging_dir / _STAGING_LOCK, os.O_CREAT | os.O_WRONLY, 0o600)
    fcntl.flock(lock_fd, fcntl.LOCK_EX)  # released when this process dies: marks the staging dir live
    staged = _Staged(target, kind, overwrite, staging_dir, lock_fd)
    if kind.is_dir:
        staged.path.mkdir()
        write_marker(staged.path, kind)
    return staged


def _discard(staged: _Staged) -> None:
    with contextlib.suppress(OSError):
        os.close(staged.lock_fd)
    shutil.rmtree(staged.staging_dir, ignore_errors=True)


def write_marker(directory: Path, kind: OutputKind) -> None:
    from plm_highway._version import __version__

    (directory / MARKER_NAME).write_text(json.dumps({"tool": "plm-highway", "version": __version__,
                                                     "kind": kind.name}) + "\n", encoding="utf-8")


def remove_stale_staging(target: Path) -> list[Path]:
    """Remove staging directories of ``target`` left by dead processes; returns what was removed."""
    removed = []
    parent = target.parent
    if not parent.is_dir():
        return removed
    prefix = f".{target.name}{TMP_INFIX}"
    for candidate in parent.iterdir():
        if not candidate.name.startswith(prefix) or not candidate.is_dir() or candidate.is_symlink():
            continue
        if _staging_is_live(candidate):
            continue
        previous = candidate / ".previous"
        if previous.exists() and not target.exists():  # a swap interrupted between its two renames
            os.rename(previous, target)
        shutil.rmtree(candidate, ignore_errors=True)
        removed.append(candidate)
    return removed


def _staging_is_live(staging_dir: Path) -> bool:
    try:
        fd = os.open(staging_dir / _STAGING_LOCK, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


@contextlib.contextmanager
def _parent_locks(targets: Sequence[Path]) -> Iterator[None]:
    """Exclusive locks on the targets' parent directories (each once, in a fixed order)."""
    fds = []
    try:
        for parent in sorted({t.parent.resolve() for t in targets}):
            fd = os.open(parent, os.O_RDONLY | os.O_DIRECTORY)
            fds.append(fd)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        for fd in fds:
            os.close(fd)


def _publish(staged: _Staged) -> None:
    """Move the staged output to its target (the caller holds the parent lock and has re-checked)."""
    source, target = staged.path, staged.target
    if not source.exists():
        raise RuntimeError(f"internal error: nothing was staged for {target}")
    if staged.kind.is_dir != source.is_dir():
        raise RuntimeError(f"internal error: staged {source} is not a {'directory' if staged.kind.is_dir else 'file'}")
    if target.exists():
        if not staged.kind.is_dir:
            os.replace(source, target)  # one atomic rename over an earlier file of this kind
        elif not _renameat2(source, target, _RENAME_EXCHANGE):
            # No atomic exchange here: move the earlier output aside first. A crash between the two
            # renames leaves it in the staging directory, and the next run puts it back.
            os.rename(target, staged.staging_dir / ".previous")
            os.rename(source, target)
    elif not _renameat2(source, target, _RENAME_NOREPLACE):
        os.rename(source, target)


_RENAME_NOREPLACE, _RENAME_EXCHANGE = 1, 2


def _renameat2(source: Path, target: Path, flags: int) -> bool:
    """Linux renameat2; False when the platform or filesystem does not offer it."""
    try:
        function = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    at_fdcwd = -100
    if function(at_fdcwd, os.fsencode(source), at_fdcwd, os.fsencode(target), flags) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), str(target))


@contextlib.contextmanager
def write_outputs(targets: Sequence[tuple[str | os.PathLike, OutputKind]], *, overwrite: bool = False
                  ) -> Iterator[list[Path]]:
    """Stage several outputs and publish them together when the block succeeds.

    Yields one temporary path per target (a directory already created, with its marker, for
    directory kinds). On an exception nothing is published and the staging is removed.
    """
    targets = [(Path(os.fspath(path)), kind) for path, kind in targets]
    resolved = [path.absolute() for path, _ in targets]
    if len(set(resolved)) != len(resolved):
        raise OutputRefused(f"two outputs of one command go to the same path: {[str(p) for p, _ in targets]}")
    staged: list[_Staged] = []
    try:
        for path, kind in targets:
            staged.append(_stage(path, kind, overwrite))
        yield [item.path for item in staged]
        with _parent_locks([item.target for item in staged]):
            for item in staged:  # all checks first: a refusal publishes nothing
                _recheck(item)
            for item in staged:
                _publish(item)
    finally:
        for item in staged:
            _discard(item)


def _recheck(staged: _Staged) -> None:
    try:
        check_target(staged.target, staged.kind, overwrite=staged.overwrite)
    except OutputRefused as exc:
        raise OutputRefused(f"{exc} (it appeared while this run was working; nothing was published)") from None


@contextlib.contextmanager
def write_output(path: str | os.PathLike, kind: OutputKind, *, overwrite: bool = False) -> Iterator[Path]:
    """Stage one output; publish it when the block succeeds. See :func:`write_outputs`."""
    with write_outputs([(path, kind)], overwrite=overwrite) as (staged,):
        yield staged
