"""What plm-highway wrote inside a directory output: the manifest kept in its marker file.

Every directory output holds ``.plm-highway-output.json``::

    {"tool": "plm-highway", "version": "...", "kind": "evaluation-run",
     "files": {"result.json": {"bytes": 1234, "sha256": "..."}, "runs/bm.csv": {...}},
     "dirs": ["runs"]}

``files`` lists every file the command wrote (relative POSIX paths, the marker itself excluded) with
its size and sha256; ``dirs`` the directories it made. When an output is replaced, only what the
manifest lists, unchanged since it was written, counts as plm-highway's (see
:mod:`plm_highway.io.outputs`). A marker without ``files`` comes from a version before manifests:
:func:`read_marker` returns ``files=None`` and the caller decides conservatively.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from plm_highway._version import __version__
from plm_highway.errors import BadInput
from plm_highway.io.bounded import JsonLimits, parse_json

MARKER_NAME = ".plm-highway-output.json"  # inside every directory plm-highway writes
MAX_MARKER_BYTES = 64 << 20  # a sweep of 100,000 cells lists about 15 MB


@dataclass(frozen=True)
class Manifest:
    kind: str | None
    files: dict[str, dict] | None  # None: a marker written before manifests existed (or one that was damaged)
    dirs: frozenset[str]


def read_marker(directory: Path) -> Manifest | None:
    """The marker of a directory output, or None when there is none (or it is not plm-highway's)."""
    path = directory / MARKER_NAME
    try:
        info = path.lstat()
        if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_MARKER_BYTES:
            return None
        data = parse_json(path.read_bytes(), str(path), JsonLimits(max_bytes=MAX_MARKER_BYTES, max_depth=8,
                                                                  max_nodes=10_000_000))
    except (OSError, BadInput):
        return None
    if not isinstance(data, dict) or data.get("tool", "plm-highway") != "plm-highway":
        return None
    kind = data.get("kind") if isinstance(data.get("kind"), str) else None
    files = data.get("files")
    dirs = data.get("dirs", [])
    valid = (isinstance(files, dict) and all(isinstance(v, dict) for v in files.values())
             and isinstance(dirs, list) and all(isinstance(d, str) for d in dirs))
    if not valid:
        return Manifest(kind, None, frozenset())
    return Manifest(kind, files, frozenset(dirs))


def marker_problem(directory: Path) -> str | None:
    """Why the marker of ``directory`` cannot be trusted (a key given twice, not JSON, too large), or None when
    it reads (or there is none). A damaged marker never counts as plm-highway's: replacing the directory on its
    word is refused."""
    path = directory / MARKER_NAME
    try:
        info = path.lstat()
    except OSError:
        return None
    if not stat.S_ISREG(info.st_mode):
        return f"{MARKER_NAME} is not a regular file"
    if info.st_size > MAX_MARKER_BYTES:
        return f"{MARKER_NAME} is {info.st_size:,} bytes, more than a marker holds ({MAX_MARKER_BYTES:,})"
    try:
        parse_json(path.read_bytes(), str(path), JsonLimits(max_bytes=MAX_MARKER_BYTES, max_depth=8,
                                                            max_nodes=10_000_000))
    except BadInput as exc:
        return str(exc)
    except OSError as exc:
        return f"{path}: cannot be read ({exc.strerror or exc})"
    return None


def marker_text(kind: str, files: dict[str, dict] | None = None, dirs=()) -> str:
    document = {"tool": "plm-highway", "version": __version__, "kind": kind}
    if files is not None:
        document["files"] = {name: files[name] for name in sorted(files)}
        document["dirs"] = sorted(dirs)
    return json.dumps(document, indent=None if files else 2, separators=(",", ":") if files else None) + "\n"


def file_record(path: Path) -> dict:
    """What identifies a file plm-highway wrote: its size and sha256 (a link: its target)."""
    info = path.lstat()
    if stat.S_ISLNK(info.st_mode):
        return {"link": os.readlink(path)}
    with open(path, "rb") as handle:
        digest = hashlib.file_digest(handle, "sha256").hexdigest()
    return {"bytes": info.st_size, "sha256": digest}


def record_matches(path: Path, info: os.stat_result, record: dict) -> bool:
    """Whether ``path`` is still exactly what the manifest recorded (size first: cheap)."""
    if stat.S_ISLNK(info.st_mode):
        return record.get("link") == os.readlink(path)
    if not stat.S_ISREG(info.st_mode) or record.get("bytes") != info.st_size:
        return False
    try:
        return file_record(path).get("sha256") == record.get("sha256")
    except OSError:
        return False


def walk(root: Path) -> Iterator[tuple[str, Path, os.stat_result]]:
    """Every entry below ``root`` (relative POSIX path, path, lstat), parents before children, sorted;
    links are listed, never followed."""
    stack = [("", root)]
    while stack:
        prefix, directory = stack.pop()
        with os.scandir(directory) as entries:
            found = sorted(entries, key=lambda entry: entry.name)
        children = []
        for entry in found:
            relative = f"{prefix}{entry.name}"
            path = Path(entry.path)
            info = path.lstat()
            yield relative, path, info
            if stat.S_ISDIR(info.st_mode):
                children.append((f"{relative}/", path))
        stack.extend(reversed(children))


def ancestors(relative: str) -> list[str]:
    """``a/b/c`` -> ``["a", "a/b"]``."""
    parts = relative.split("/")
    return ["/".join(parts[:i]) for i in range(1, len(parts))]
