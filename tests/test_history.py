"""The project speaks of itself alone: no work history (issue or stop numbers, sessions, scratch scripts) in what
it ships. That history belongs in commit messages."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("README.md", "environment.md", "docs", "figures", "plm_highway", "tests", "lessons", "solutions", ".ci")
SUFFIXES = {".py", ".md", ".ipynb", ".json", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".csv", ""}
# "stop 66 m before the road's end" is a distance, not a work-history stop.
HISTORY = re.compile(r"\bissues? #?\d+(\.\d+)?\b|\bstops? #?\d+\b(?!\s*(m|s|steps?|%)\b)|\b(this|earlier|previous|last) "
                     r"session\b|/tmp script|\bthis stop\b|on a slower day", re.IGNORECASE)


def shipped_files():
    for name in SHIPPED:
        path = ROOT / name
        candidates = [path] if path.is_file() else sorted(path.rglob("*")) if path.is_dir() else []
        for file in candidates:
            if file.is_file() and file.suffix in SUFFIXES and "__pycache__" not in file.parts:
                yield file


def history_hits(text: str) -> list[str]:
    return [m.group(0) for m in HISTORY.finditer(text)]


def test_nothing_shipped_speaks_of_the_work_history():
    me = Path(__file__).resolve()
    hits = []
    for file in shipped_files():
        if file == me:
            continue
        text = file.read_text(encoding="utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), 1):
            for hit in history_hits(line):
                hits.append(f"{file.relative_to(ROOT)}:{number}: {hit!r} in {line.strip()[:100]!r}")
    assert not hits, "work history in shipped files (it belongs in commit messages):\n" + "\n".join(hits)


@pytest.mark.parametrize("line", ["see issue 9.3", "Issue 14 target", "issues #12", "as in stop 28",
                                  "measured this session", "a /tmp script", "on a slower day", "STOP 3 said"])
def test_the_pattern_catches_history(line):
    assert history_hits(line)


@pytest.mark.parametrize("line", ["runs stop 66 m before the road's end", "stop 5 s after", "the car stops 3 steps later",
                                  "an issue with the camera", "the session's kernel", "stop at the end"])
def test_the_pattern_spares_ordinary_prose(line):
    assert not history_hits(line)
