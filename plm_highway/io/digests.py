"""What a result was made from, by content: the key of every reuse (sweep cells, estimate caches).

A result is reused only when everything it was made from is the same *content*: the bytes of a track
file or a latency trace (never its path: ``t.json`` in two working directories is two tracks), the
sha256 of every checkpoint file (a retrained model in the same directory is another model), the
settings with their types (``1`` and ``'1'`` differ) and the kit's version. A stored result carries the
digest of its own content too (:func:`content_digest`), so a result edited by hand is recognised and
made again rather than used.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path

from plm_highway._version import __version__
from plm_highway.errors import BadInput

DIGEST_KEY = "content_sha256"  # in a stored result: the sha256 of the rest of it (see content_digest)


def file_sha256(path: str | Path, what: str = "input file") -> str:
    """The sha256 of a file's bytes; BadInput naming the file when it cannot be read."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            return hashlib.file_digest(handle, "sha256").hexdigest()
    except OSError as exc:
        raise BadInput(f"{what} {str(path)!r}: cannot be read ({exc.strerror or exc})") from None


def files_sha256(paths: Iterable[str | Path], what: str = "input file") -> dict[str, str]:
    """``{file name: sha256}`` of each file (names only: where the files lie is not what they hold)."""
    return {Path(path).name: file_sha256(path, what) for path in paths}


def _canonical(value):
    """``value`` as typed JSON: keys sorted; text, integers, floats and booleans stay apart (``1``, ``1.0``,
    ``'1'`` and ``True`` are four values); NaN and infinities as JSON's null, the way a stored result reads back."""
    if isinstance(value, Mapping):
        return {str(key): _canonical(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(item) for item in value]
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:
        value = value.item()
    if isinstance(value, float):
        return None if not math.isfinite(value) else {"float": repr(value)}
    if isinstance(value, bool):
        return {"bool": value}
    if isinstance(value, int):
        return {"int": str(value)}
    if value is None or isinstance(value, str):
        return value
    return {type(value).__name__: str(value)}


def json_digest(value) -> str:
    """The sha256 of ``value`` in a canonical, typed JSON form (see :func:`_canonical`)."""
    text = json.dumps(_canonical(value), sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def content_digest(record: Mapping, *, ignore: Iterable[str] = ()) -> str:
    """The digest of a stored result without its own digest (and the keys in ``ignore``)."""
    skipped = {DIGEST_KEY, *ignore}
    return json_digest({key: value for key, value in record.items() if key not in skipped})


def set_aside(path: Path, why: str, then: str = "run again") -> Path:
    """Move a stored result that can no longer be used to ``NAME.edited`` (``-2``, ``-3``... when taken: a user's
    edit is kept, never overwritten), say so on stderr naming ``why``, and return where it went."""
    aside = candidate = Path(path).with_name(Path(path).name + ".edited")
    number = 1
    while os.path.lexists(candidate):
        number += 1
        candidate = aside.with_name(f"{aside.name}-{number}")
    os.rename(path, candidate)
    print(f"warning: {path}: {why}; moved to {candidate.name} and {then}", file=sys.stderr)
    return candidate


def source_sha256(*modules) -> str:
    """The digest of the source of ``modules`` (a package: every ``.py`` file directly in its folder; a module:
    its file), each file as its name and bytes, in the order given and sorted within a package: the code a result
    was made by, so that a result made by other code of that path is made again."""
    digest = hashlib.sha256()
    for module in modules:
        source = Path(module.__file__)
        files = sorted(source.parent.glob("*.py")) if source.name == "__init__.py" else [source]
        for path in files:
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def kit_version() -> str:
    return __version__
