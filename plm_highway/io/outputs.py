"""Safe outputs: a command writes a new path, or replaces what it wrote there earlier; nothing else.

The rules (README, "Reliability"):

- The target path must name something: an empty name, ``.``, ``..``, the current directory or one
  of its ancestors, the home directory, a filesystem root and symbolic links are refused; so is a
  file target written with a trailing ``/`` (it names a directory).
- A missing target (or an empty directory where a directory goes) is created. An existing target is
  replaced only if it is an output of the same kind that plm-highway recognises (:class:`OutputKind`)
  **and** ``overwrite`` is set; a file where a directory goes (or the reverse), or anything not
  recognised, is refused, naming the path and what is there. Nothing is touched when a target is
  refused. A file target that is an input of the running command is never replaced.
- **Only what plm-highway wrote is replaced.** Every directory output carries a manifest of the files
  it wrote, with their sizes and sha256 (:mod:`plm_highway.io.manifest`). When a directory output is
  replaced, everything inside it that the manifest does not list, or that changed since it was
  written, is kept: carried into the new output as it was (hard links, so modes, times and contents
  stay; a copy where links are impossible) and named in a warning on stderr. A kept file whose path
  the new output would write is refused instead (exit 2, naming it; nothing changes), and so is a
  file plm-highway wrote that is an input of the running command (:func:`protected_inputs`): it is
  never replaced, only carried. Directory outputs written before manifests existed list no files:
  there, only the files at the paths the new output writes (and marker files) count as
  plm-highway's; everything else is kept. ``update`` (a resumed sweep) keeps plm-highway's other
  files too and replaces only the named parts of the output (its grid, table and figures) as one set.
- Every output is staged in a temporary sibling ``.NAME.plm-highway-tmp-PID-XXXX`` and published in
  one rename (an existing directory is swapped in one ``renameat2(RENAME_EXCHANGE)`` on Linux), so a
  crash or SIGKILL at any moment leaves the previous output or the new one whole, never a mixture.
  A staging directory is plm-highway's only when its lock file says so and names that very directory
  (its device and inode); a file or folder whose name merely looks like one is never touched. (A
  staging directory takes its name only once it is claimed; a run killed in the microseconds before
  that leaves an empty ``.NAME.plm-highway-new-PID-XXXX``, which is never removed automatically.)
  Staging directories of crashed runs are removed by the next run that writes the same target (a
  live process holds a lock on its own staging directory, so only dead ones are removed). Parent
  directories a refused or failed run created are removed again.
- The check and the rename happen under an exclusive lock on the parent directory: of two processes
  writing one new target, one publishes whole; the other finds that output there and is refused
  (whatever ``overwrite`` says: it did not see that output when it started).
- A replaced output keeps the permission bits of the one it replaces.
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import errno
import fcntl
import json
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path

from plm_highway.errors import BadInput, OutputRefused
from plm_highway.io.bounded import JsonLimits, load_json
from plm_highway.io.manifest import (
    MARKER_NAME,
    ancestors,
    file_record,
    marker_problem,
    marker_text,
    read_marker,
    record_matches,
    walk,
)

JSON_MARKER_KEY = "plm_highway_output"  # top-level key of every JSON object plm-highway writes
PNG_SOFTWARE = "plm-highway"  # the PNG "Software" text chunk of every figure plm-highway writes
TMP_INFIX = ".plm-highway-tmp-"
_NEW_INFIX = ".plm-highway-new-"  # a staging directory until it is claimed (see _new_staging_dir)
_STAGING_LOCK = ".lock"
_STAGING_TOOL = "plm-highway staging directory"
_PREVIOUS = ".previous"
_PREVIOUS_CLAIM = ".previous.json"
_MAX_NAME_IN_STAGING = 100  # characters of the target's name in its staging directory's name
_MAX_NAMED = 10  # paths named in one warning or refusal


@dataclass(frozen=True)
class OutputKind:
    """One kind of output a command writes, and how to recognise an earlier one at a path.

    ``recognisers`` are extra tests for outputs written before markers existed (a dataset's
    ``manifest.json``, a checkpoint's ``model.json``); the marker alone suffices otherwise.
    ``owned`` (directory kinds): files added inside the directory after it was published (a sweep's
    cells), as (relative glob, file kind): such a file counts as plm-highway's when that kind
    recognises it, though the manifest does not list it.
    """

    name: str
    is_dir: bool
    describe: str  # what it is, for messages: "a dataset directory", "an evaluation JSON file"
    csv_header: tuple[str, ...] | None = None  # CSV files: recognised by this exact header row
    recognisers: tuple[Callable[[Path], bool], ...] = field(default=())
    owned: tuple[tuple[str, OutputKind], ...] = field(default=())

    def recognises(self, path: Path) -> bool:
        if self.is_dir != path.is_dir():
            return False
        if self.is_dir:
            marker = read_marker(path)
            if marker is not None and marker.kind == self.name:
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

    def owns_added(self, relative: str, path: Path) -> bool:
        return any(fnmatchcase(relative, pattern) and kind.recognises(path) for pattern, kind in self.owned)


def directory_kind(name: str, describe: str, *recognisers: Callable[[Path], bool],
                   owned: Sequence[tuple[str, OutputKind]] = ()) -> OutputKind:
    return OutputKind(name, True, describe, recognisers=tuple(recognisers), owned=tuple(owned))


def file_kind(name: str, describe: str, csv_header: Sequence[str] | None = None,
              *recognisers: Callable[[Path], bool]) -> OutputKind:
    header = None if csv_header is None else tuple(csv_header)
    return OutputKind(name, False, describe, csv_header=header, recognisers=tuple(recognisers))


# -- recognising ---------------------------------------------------------------------------------


def _json_marker_kind(path: Path, max_bytes: int = 64 << 20) -> str | None:
    try:
        data = load_json(path, JsonLimits(max_bytes=max_bytes, max_nodes=20_000_000))
    except (OSError, BadInput):
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
        marker = read_marker(path)
        written = f" (a plm-highway '{marker.kind}' output)" if marker is not None and marker.kind else ""
        return f"a directory with {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}{written}: {shown}"
    if path.is_file():
        return f"a file of {path.stat().st_size:,} bytes"
    return "something that is neither a file nor a directory"


# -- the inputs of the running command -------------------------------------------------------------


@dataclass(frozen=True)
class _Input:
    path: Path  # resolved
    is_dir: bool
    inode: tuple[int, int] | None  # files: (device, inode), so a hard link or another spelling is found too


_PROTECTED: contextvars.ContextVar[tuple[_Input, ...]] = contextvars.ContextVar("plm_highway_inputs", default=())


def _as_input(path: str | os.PathLike) -> _Input | None:
    try:
        resolved = Path(os.fspath(path)).resolve()
        info = resolved.stat()
    except (OSError, RuntimeError, ValueError):
        return None
    is_dir = stat.S_ISDIR(info.st_mode)
    return _Input(resolved, is_dir, None if is_dir else (info.st_dev, info.st_ino))


@contextlib.contextmanager
def protected_inputs(paths: Iterable[str | os.PathLike]) -> Iterator[None]:
    """While the block runs, no output replaces or removes these files (or the files under these
    directories): the inputs of the running command. Paths that do not exist are ignored."""
    entries = tuple(entry for entry in (_as_input(path) for path in paths) if entry is not None)
    token = _PROTECTED.set(_PROTECTED.get() + entries)
    try:
        yield
    finally:
        _PROTECTED.reset(token)


def input_named(path: Path, extra: Sequence[_Input] = (), output: Path | None = None) -> Path | None:
    """The protected input that ``path`` is (or lies under), or None.

    A file input protects that file (any spelling, any hard link). A directory input protects the files
    under it only inside ``output``, the directory output being replaced, when the input lies at or
    below it (``--bm C --out C``, ``--checkpoints R/ck --out R``): an output written inside an input
    directory (``--checkpoints . --out rep``) replaces nothing that was read.
    """
    inputs = (*_PROTECTED.get(), *extra)
    if not inputs:
        return None
    try:
        resolved = path.resolve()
        info = path.lstat()
        root = output.resolve() if output is not None else None
    except (OSError, RuntimeError):
        return None
    inode = (info.st_dev, info.st_ino)
    for entry in inputs:
        if entry.is_dir:
            if root is not None and (entry.path == root or root in entry.path.parents) and \
                    (resolved == entry.path or entry.path in resolved.parents):
                return entry.path
        elif entry.inode == inode or resolved == entry.path:
            return entry.path
    return None


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


def check_target(path: str | os.PathLike, kind: OutputKind, *, overwrite: bool = False,
                 protect: Sequence[str | os.PathLike] = ()) -> Path:
    """Refuse (:class:`OutputRefused`) unless ``path`` may receive an output of ``kind``; returns the path.

    Call it before long work starts, so a refusal costs nothing; publishing checks again.
    """
    text = os.fspath(path)
    if not text or not text.strip():
        raise OutputRefused(f"output path {text!r}: empty; give a file or directory name")
    if not kind.is_dir and text.endswith((os.sep, "/")):
        raise OutputRefused(f"output path {text!r}: ends with '/', so it names a directory, but {kind.describe} is "
                            "a file; give a file name")
    target = Path(text)
    reason = _protected_reason(target)
    if reason is not None:
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: {reason}; choose a new path")
    if target.is_symlink():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: it is {describe_existing(target)}; "
                            "plm-highway does not write through links")
    if not target.exists():
        _check_parent(target, kind)
        if _live_writer(target):
            raise OutputRefused(_another_writer(text))
        _SEEN_ABSENT.add(_identity(target))
        return target
    there = describe_existing(target)
    if kind.is_dir and not target.is_dir():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: a directory goes there, but it is {there}")
    if not kind.is_dir and target.is_dir():
        raise OutputRefused(f"refusing to write {kind.describe} at {text!r}: a file goes there, but it is {there}")
    source = input_named(target, _inputs_of(protect)) if not kind.is_dir else _directory_input(target, protect)
    if source is not None:
        raise OutputRefused(f"refusing to replace {text!r}: it is an input of this run ({str(source)!r}); "
                            "nothing was changed. Write the output to another path")
    if kind.is_dir and not any(target.iterdir()):
        return target  # an empty directory holds nothing to lose (e.g. made with mkdir beforehand)
    if kind.is_dir and (problem := marker_problem(target)) is not None:
        raise OutputRefused(f"refusing to replace {text!r}: its marker cannot be trusted ({problem}); nothing was "
                            "changed. Move the directory away yourself, or choose a new path")
    if not kind.recognises(target):
        raise OutputRefused(f"refusing to replace {text!r}: it is {there}, not {kind.describe} that plm-highway "
                            "wrote; nothing was changed. Choose a new path, or move it away yourself")
    if not overwrite:
        if _live_writer(target) or (_identity(target) in _SEEN_ABSENT and _identity(target) not in _PUBLISHED_HERE):
            raise OutputRefused(_another_writer(text) + " (it was not there when this run started)")
        raise OutputRefused(f"{text!r} already holds {kind.describe} (an earlier output); pass --overwrite to "
                            "replace it, or choose a new path")
    return target


# Targets this process found absent, and those it published: a target found absent and now there, that this process
# did not publish, was written by another plm-highway meanwhile (its author is named, not --overwrite advised).
_SEEN_ABSENT: set[str] = set()
_OWN_STAGING: set[Path] = set()  # this process's staging directories (live, but not another writer)
_PUBLISHED_HERE: set[str] = set()


def _identity(target: Path) -> str:
    with contextlib.suppress(OSError, RuntimeError):
        return str(target.resolve())
    return str(target.absolute())


def _another_writer(text: str) -> str:
    return (f"another plm-highway is writing {text!r}; wait for it to finish or choose another path; nothing was "
            "changed")


def _live_writer(target: Path) -> bool:
    """Whether a live plm-highway process holds a staging directory for ``target`` (it is being written now)."""
    parent = target.parent
    prefix = _staging_prefix(target)
    with contextlib.suppress(OSError):
        for candidate in parent.iterdir():
            if (candidate.name.startswith(prefix) and candidate not in _OWN_STAGING and _is_claimed(candidate, target)
                    and _staging_is_live(candidate)):
                return True
    return False


def _directory_input(target: Path, protect: Sequence[str | os.PathLike]) -> Path | None:
    """The input directory that ``target`` is itself (``train tapm --bm C --out C``), or None."""
    with contextlib.suppress(OSError, RuntimeError):
        resolved = target.resolve()
        for entry in (*_PROTECTED.get(), *_inputs_of(protect)):
            if entry.is_dir and entry.path == resolved:
                return entry.path
    return None


def _inputs_of(paths: Sequence[str | os.PathLike]) -> tuple[_Input, ...]:
    return tuple(entry for entry in (_as_input(path) for path in paths) if entry is not None)


def _check_parent(target: Path, kind: OutputKind) -> None:
    for ancestor in target.absolute().parents:
        if ancestor.exists():
            if not ancestor.is_dir():
                raise OutputRefused(f"cannot write {kind.describe} at {str(target)!r}: {str(ancestor)!r} is "
                                    f"{describe_existing(ancestor)}, not a directory")
            return


# -- staging directories: created, claimed, recognised --------------------------------------------------


@dataclass
class _Staged:
    target: Path
    kind: OutputKind
    overwrite: bool
    update: tuple[str, ...] | None  # see write_outputs
    staging_dir: Path
    lock_fd: int
    existed: bool  # whether the target was there when staging began
    created_parents: list[Path]
    published: bool = False

    @property
    def path(self) -> Path:
        return self.staging_dir / self.target.name


def _staging_prefix(target: Path) -> str:
    return f".{target.name[:_MAX_NAME_IN_STAGING]}{TMP_INFIX}"


def _make_parents(parent: Path) -> list[Path]:
    """Create ``parent`` and its missing ancestors; returns those created (outermost first)."""
    missing = []
    for directory in (parent, *parent.parents):
        if directory.exists():
            break
        missing.append(directory)
    missing.reverse()
    created = []
    for directory in missing:
        try:
            directory.mkdir()
        except FileExistsError:
            continue
        created.append(directory)
    return created


def _remove_created(created: list[Path]) -> None:
    for directory in reversed(created):
        with contextlib.suppress(OSError):
            directory.rmdir()  # only when still empty: a concurrent writer's content stays


def _new_staging_dir(target: Path) -> tuple[Path, int]:
    """A staging directory for ``target``, locked, and claimed before it takes its staging name.

    It is made under a name of its own (``...plm-highway-new-...``), its lock file records that
    plm-highway made it for ``target`` (its final name, device and inode), and only then is it renamed
    to ``.NAME.plm-highway-tmp-PID-XXXX``: a directory under a staging name is always claimed, so a run
    killed at any moment leaves nothing that the next run could not recognise as its own.
    """
    suffix_start = len(f".{target.name[:_MAX_NAME_IN_STAGING]}{_NEW_INFIX}")
    fresh = Path(tempfile.mkdtemp(prefix=f".{target.name[:_MAX_NAME_IN_STAGING]}{_NEW_INFIX}{os.getpid()}-",
                                  dir=target.parent))
    staging_dir = target.parent / f"{_staging_prefix(target)}{fresh.name[suffix_start:]}"
    fd = -1
    try:
        info = fresh.lstat()
        fd = os.open(fresh / _STAGING_LOCK, os.O_CREAT | os.O_EXCL | os.O_RDWR, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)  # released when this process dies: marks the staging dir live
        claim = {"tool": _STAGING_TOOL, "staging": staging_dir.name, "target": target.name,
                 "device": info.st_dev, "inode": info.st_ino, "pid": os.getpid()}
        os.write(fd, json.dumps(claim).encode("utf-8"))
        if not _renameat2(fresh, staging_dir, _RENAME_NOREPLACE):
            if os.path.lexists(staging_dir):
                raise FileExistsError(errno.EEXIST, "staging name taken", str(staging_dir))
            os.rename(fresh, staging_dir)
    except BaseException:
        if fd >= 0:
            os.close(fd)
        shutil.rmtree(fresh, ignore_errors=True)
        raise
    _OWN_STAGING.add(staging_dir)
    return staging_dir, fd


def _is_claimed(candidate: Path, target: Path) -> bool:
    """Whether ``candidate`` is verifiably a staging directory plm-highway made for ``target``."""
    try:
        info = candidate.lstat()
        if not stat.S_ISDIR(info.st_mode):
            return False
        lock = candidate / _STAGING_LOCK
        lock_info = lock.lstat()
        if not stat.S_ISREG(lock_info.st_mode) or lock_info.st_size > 4096:
            return False
        claim = json.loads(lock.read_bytes().decode("utf-8"))
    except (OSError, ValueError):
        return False
    return (isinstance(claim, dict) and claim.get("tool") == _STAGING_TOOL and claim.get("staging") == candidate.name
            and claim.get("target") == target.name and claim.get("device") == info.st_dev
            and claim.get("inode") == info.st_ino)


def _staging_is_live(staging_dir: Path) -> bool:
    try:
        fd = os.open(staging_dir / _STAGING_LOCK, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def remove_stale_staging(target: Path) -> list[Path]:
    """Remove the staging directories of ``target`` that dead plm-highway processes left; returns them.

    Only directories whose lock file claims them for ``target`` (naming their own device and inode)
    are considered; anything else with a similar name is left alone.
    """
    removed = []
    parent = target.parent
    if not parent.is_dir():
        return removed
    prefix = _staging_prefix(target)
    for candidate in sorted(parent.iterdir()):
        if not candidate.name.startswith(prefix) or not _is_claimed(candidate, target):
            continue
        if _staging_is_live(candidate):
            continue
        _restore_previous(candidate, target)
        shutil.rmtree(candidate, ignore_errors=True)
        removed.append(candidate)
    return removed


def _restore_previous(staging_dir: Path, target: Path) -> None:
    """Put back an earlier output moved aside by a swap that a crash cut between its two renames."""
    previous = staging_dir / _PREVIOUS
    try:
        with open(staging_dir / _PREVIOUS_CLAIM, "rb") as handle:
            claim = json.loads(handle.read(4096).decode("utf-8"))
        info = previous.lstat()
    except (OSError, ValueError):
        return
    if (isinstance(claim, dict) and claim.get("device") == info.st_dev and claim.get("inode") == info.st_ino
            and not os.path.lexists(target)):
        os.rename(previous, target)


def _stage(target: Path, kind: OutputKind, overwrite: bool, update: tuple[str, ...] | None,
           protect: tuple[_Input, ...]) -> _Staged:
    target = check_target(target, kind, overwrite=overwrite or update is not None, protect=[p.path for p in protect])
    existed = os.path.lexists(target)
    created = _make_parents(target.parent)
    try:
        remove_stale_staging(target)
        staging_dir, lock_fd = _new_staging_dir(target)
    except BaseException:
        _remove_created(created)
        raise
    staged = _Staged(target, kind, overwrite, update, staging_dir, lock_fd, existed, created)
    if kind.is_dir:
        staged.path.mkdir()
        (staged.path / MARKER_NAME).write_text(marker_text(kind.name), encoding="utf-8")
    return staged


def _discard(staged: _Staged) -> None:
    _OWN_STAGING.discard(staged.staging_dir)
    with contextlib.suppress(OSError):
        os.close(staged.lock_fd)
    shutil.rmtree(staged.staging_dir, ignore_errors=True)


def write_marker(directory: Path, kind: OutputKind) -> None:
    (directory / MARKER_NAME).write_text(marker_text(kind.name), encoding="utf-8")


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


# -- what an earlier directory output holds, and what stays ---------------------------------------------


@dataclass
class _Plan:
    """What happens to an earlier directory output's entries when the staged one replaces it."""

    carry: list[tuple[str, Path, os.stat_result]] = field(default_factory=list)  # into the new output, as they are
    kit_records: dict[str, dict] = field(default_factory=dict)  # carried files that plm-highway wrote
    kit_dirs: set[str] = field(default_factory=set)
    kept: list[str] = field(default_factory=list)  # for the warning: not plm-highway's, or changed since
    kept_inputs: list[str] = field(default_factory=list)  # plm-highway's, but inputs of this run
    old_kit_dirs: frozenset[str] = frozenset()  # directories the earlier manifest lists
    made_dirs: set[str] = field(default_factory=set)  # directories made in the staged output to carry entries


def _plan(staged: _Staged, protect: tuple[_Input, ...]) -> _Plan:
    """Classify every entry of the earlier output; refuse (nothing changed yet) what cannot stay."""
    plan = _Plan()
    old = staged.target
    if not staged.kind.is_dir or not old.is_dir():
        return plan
    manifest = read_marker(old)
    files = manifest.files if manifest is not None else None
    if files is not None:
        plan.old_kit_dirs = manifest.dirs
    new_files, new_dirs = set(), set()
    for relative, _, info in walk(staged.path):
        (new_dirs if stat.S_ISDIR(info.st_mode) else new_files).add(relative)
    new_files.discard(MARKER_NAME)

    def keeps(relative: str) -> bool:
        """Whether an earlier file of plm-highway's stays (``update``: all but those the new output replaces)."""
        if staged.update is None:
            return False
        return not any(relative == prefix or relative.startswith(prefix + "/") for prefix in staged.update)

    def collides(relative: str, is_dir: bool) -> bool:
        if relative in new_files or any(a in new_files for a in ancestors(relative)):
            return True
        return not is_dir and relative in new_dirs

    refusals = []
    entries = list(walk(old))
    children = {a for relative, _, _ in entries for a in ancestors(relative)}
    for relative, path, info in entries:
        is_dir = stat.S_ISDIR(info.st_mode)
        if relative == MARKER_NAME:
            continue
        if is_dir:
            if relative in children:
                continue  # a directory with content: its entries decide
            kit_dir = (relative in manifest.dirs) if files is not None else (relative in new_dirs)
            if kit_dir and not keeps(relative):
                continue
            if collides(relative, True):
                if not kit_dir:
                    refusals.append(f"{relative}/ (an empty directory where the new output writes a file)")
                continue
            plan.carry.append((relative, path, info))
            (plan.kit_dirs.add(relative) if kit_dir else plan.kept.append(f"{relative}/"))
            continue
        record = files.get(relative) if files is not None else None
        if files is not None:
            if record is not None:
                owner = "kit" if record_matches(path, info, record) else "changed"
            else:
                owner = "kit" if staged.kind.owns_added(relative, path) else "user"
        else:
            legacy_kit = relative in new_files or Path(relative).name == MARKER_NAME
            owner = "kit" if legacy_kit or staged.kind.owns_added(relative, path) else "user"
        if not (stat.S_ISREG(info.st_mode) or stat.S_ISLNK(info.st_mode)):
            if owner != "kit":
                refusals.append(f"{relative} (a special file that cannot be carried into the new output)")
            continue
        if owner == "kit":
            source = input_named(path, protect, old)
            if source is not None:
                if collides(relative, False):
                    refusals.append(f"{relative} (an input of this run, which the new output would replace)")
                    continue
                plan.kept_inputs.append(relative)
            elif relative in new_files or not keeps(relative):
                continue  # replaced by the new output, or dropped with the earlier one
            plan.carry.append((relative, path, info))
            plan.kit_records[relative] = record if record is not None else file_record(path)
            continue
        if collides(relative, False):
            why = "changed since plm-highway wrote it" if owner == "changed" else "not written by plm-highway"
            refusals.append(f"{relative} ({why}; the new output writes that path)")
            continue
        plan.carry.append((relative, path, info))
        plan.kept.append(relative + (" (changed since plm-highway wrote it)" if owner == "changed" else ""))
    if refusals:
        shown = "; ".join(refusals[:_MAX_NAMED]) + (f"; and {len(refusals) - _MAX_NAMED} more"
                                                     if len(refusals) > _MAX_NAMED else "")
        raise OutputRefused(f"refusing to replace {str(old)!r}: it holds what plm-highway must not replace: {shown}. "
                            "Nothing was changed; move those away (or write to a new path) and run again")
    return plan


def _carry(staged: _Staged, plan: _Plan) -> None:
    """Put the entries that stay into the staged output, exactly as they are (only staging changes)."""
    made: list[tuple[Path, os.stat_result]] = []

    def ensure_dir(relative: str, source: Path) -> None:
        destination = staged.path / relative
        if not destination.exists():
            destination.mkdir()
            made.append((destination, source.lstat()))
            plan.made_dirs.add(relative)

    for relative, source, info in plan.carry:
        for ancestor in ancestors(relative):
            ensure_dir(ancestor, staged.target / ancestor)
        destination = staged.path / relative
        if stat.S_ISDIR(info.st_mode):
            ensure_dir(relative, source)
        elif stat.S_ISLNK(info.st_mode):
            os.symlink(os.readlink(source), destination)
            with contextlib.suppress(OSError, NotImplementedError):
                os.utime(destination, ns=(info.st_atime_ns, info.st_mtime_ns), follow_symlinks=False)
        else:
            try:
                os.link(source, destination)  # the same file: contents, mode and times unchanged
            except OSError:
                shutil.copy2(source, destination)  # no hard links here (another filesystem, or not allowed)
    for directory, info in reversed(made):  # deepest first: filling a directory changes its times
        os.chmod(directory, stat.S_IMODE(info.st_mode))
        os.utime(directory, ns=(info.st_atime_ns, info.st_mtime_ns))


def _seal(staged: _Staged, plan: _Plan) -> None:
    """Write the manifest: what this output wrote, plus what it carries of plm-highway's earlier files."""
    carried = {relative for relative, _, _ in plan.carry}
    files, dirs = {}, set(plan.kit_dirs)
    for relative, path, info in walk(staged.path):
        if relative == MARKER_NAME or (relative in carried and relative not in plan.kit_records):
            continue
        if stat.S_ISDIR(info.st_mode):
            if relative not in carried and (relative not in plan.made_dirs or relative in plan.old_kit_dirs):
                dirs.add(relative)
        else:
            files[relative] = plan.kit_records.get(relative) or file_record(path)
    (staged.path / MARKER_NAME).write_text(marker_text(staged.kind.name, files, dirs), encoding="utf-8")


def _keep_mode(previous: Path, replacement: Path) -> None:
    with contextlib.suppress(OSError):
        os.chmod(replacement, stat.S_IMODE(previous.stat().st_mode))


def _publish(staged: _Staged) -> None:
    """Move the staged output to its target (the caller holds the parent lock and has re-checked)."""
    source, target = staged.path, staged.target
    if not source.exists():
        raise RuntimeError(f"internal error: nothing was staged for {target}")
    if staged.kind.is_dir != source.is_dir():
        raise RuntimeError(f"internal error: staged {source} is not a {'directory' if staged.kind.is_dir else 'file'}")
    if target.exists():
        _keep_mode(target, source)
        if not staged.kind.is_dir:
            os.replace(source, target)  # one atomic rename over an earlier file of this kind
        elif not _renameat2(source, target, _RENAME_EXCHANGE):
            # No atomic exchange here: move the earlier output aside first, recording which directory
            # that is. A crash between the two renames leaves it in the staging directory, and the next
            # run puts it back.
            info = target.lstat()
            (staged.staging_dir / _PREVIOUS_CLAIM).write_text(
                json.dumps({"device": info.st_dev, "inode": info.st_ino}), encoding="utf-8")
            os.rename(target, staged.staging_dir / _PREVIOUS)
            os.rename(source, target)
    elif not _renameat2(source, target, _RENAME_NOREPLACE):
        os.rename(source, target)
    staged.published = True
    _PUBLISHED_HERE.add(_identity(target))


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


def _warn(staged: _Staged, plan: _Plan) -> None:
    for entries, why in ((plan.kept, "that plm-highway did not write (or that changed since)"),
                         (plan.kept_inputs, "that plm-highway wrote but that are inputs of this run")):
        if entries:
            shown = ", ".join(entries[:_MAX_NAMED]) + (f", and {len(entries) - _MAX_NAMED} more"
                                                       if len(entries) > _MAX_NAMED else "")
            print(f"warning: {staged.target}: kept {len(entries)} entr{'y' if len(entries) == 1 else 'ies'} {why}, "
                  f"as they were: {shown}", file=sys.stderr)


@contextlib.contextmanager
def write_outputs(targets: Sequence[tuple[str | os.PathLike, OutputKind]], *, overwrite: bool = False,
                  update: Sequence[str] | None = None, protect: Sequence[str | os.PathLike] = ()
                  ) -> Iterator[list[Path]]:
    """Stage several outputs and publish them together when the block succeeds.

    Yields one temporary path per target (a directory already created, with its marker, for
    directory kinds). On an exception nothing is published and the staging is removed.
    ``update``: relative paths (files or directories) inside earlier directory outputs of this kind that
    the new output replaces as a whole (a sweep's ``grid.json``, ``results.csv``, ``figures``); every
    other file plm-highway wrote there stays. None: the new output replaces all of plm-highway's files.
    ``protect``: input paths besides those of :func:`protected_inputs`.
    """
    targets = [(Path(os.fspath(path)), kind) for path, kind in targets]
    resolved = [path.absolute() for path, _ in targets]
    if len(set(resolved)) != len(resolved):
        raise OutputRefused(f"two outputs of one command go to the same path: {[str(p) for p, _ in targets]}")
    extra = _inputs_of(protect)
    update = None if update is None else tuple(str(part).strip("/") for part in update)
    staged: list[_Staged] = []
    try:
        for path, kind in targets:
            staged.append(_stage(path, kind, overwrite, update, extra))
        try:
            yield [item.path for item in staged]
        except OSError as exc:
            raise _naming_output(exc, targets) from None
        with _parent_locks([item.target for item in staged]):
            for item in staged:  # all checks first: a refusal publishes nothing
                _recheck(item, extra)
            plans = [_plan(item, extra) for item in staged]
            try:
                for item, plan in zip(staged, plans):
                    if item.kind.is_dir:
                        _carry(item, plan)
                        _seal(item, plan)
                for item in staged:
                    _publish(item)
            except OSError as exc:
                raise _naming_output(exc, targets) from None
        for item, plan in zip(staged, plans):
            _warn(item, plan)
    finally:
        for item in staged:
            _discard(item)
        for item in reversed(staged):  # parents that a run which published nothing created go again
            if not item.published:
                _remove_created(item.created_parents)


def _naming_output(exc: OSError, targets) -> OSError:
    """``exc`` with the output it happened to named: a full disk (``ENOSPC``) or a quota raised by a write or a
    close carries no path of its own."""
    if exc.filename is not None:
        return exc
    names = ", ".join(repr(str(path)) for path, _ in targets)
    error = type(exc)(exc.errno, f"{exc.strerror or exc} (writing {names}; nothing was published)",
                      str(targets[0][0]) if len(targets) == 1 else names)
    return error


def _recheck(staged: _Staged, extra: tuple[_Input, ...]) -> None:
    if not staged.existed and os.path.lexists(staged.target):
        who = "another plm-highway" if staged.kind.recognises(staged.target) else "another program"
        raise OutputRefused(f"{who} wrote {str(staged.target)!r} while this run was working; nothing was published. "
                            "Wait for it to finish or choose another path")
    try:
        check_target(staged.target, staged.kind, overwrite=staged.overwrite or staged.update is not None,
                     protect=[p.path for p in extra])
    except OutputRefused as exc:
        raise OutputRefused(f"{exc} (it changed while this run was working; nothing was published)") from None


@contextlib.contextmanager
def write_output(path: str | os.PathLike, kind: OutputKind, *, overwrite: bool = False,
                 update: Sequence[str] | None = None, protect: Sequence[str | os.PathLike] = ()) -> Iterator[Path]:
    """Stage one output; publish it when the block succeeds. See :func:`write_outputs`."""
    with write_outputs([(path, kind)], overwrite=overwrite, update=update, protect=protect) as (staged,):
        yield staged
