"""Writing files so that a crash or a bad input never leaves a half-written result behind."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(final_path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``final_path``; rename it into place only if the block succeeds.

    Works for files and directories: whatever the block creates at the yielded path replaces
    ``final_path`` in one ``os.replace`` (a directory is swapped via a second rename).
    """
    final_path = Path(final_path)
    final_path.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{final_path.name}.", suffix=".tmp", dir=final_path.parent))
    tmp_path = tmp_dir / final_path.name
    try:
        yield tmp_path
        if tmp_path.is_dir() and final_path.exists():
            backup = tmp_dir / (final_path.name + ".old")
            os.replace(final_path, backup)
        os.replace(tmp_path, final_path)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
