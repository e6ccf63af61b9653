"""Generated blocks in Markdown: ``<!-- render: NAME -->`` ... ``<!-- /render -->``.

Every number README.md and the docs quote from a run sits in such a block. :func:`render_file` replaces each
block's body by what renderer ``NAME`` (:data:`~plm_highway.publish.renderers.RENDERERS`) makes of the committed
result files; ``plm-highway docs render`` does it for every Markdown file of the project, and ``--check`` only
says which blocks differ (the test suite runs it, so a number that no longer matches its results file fails CI).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from plm_highway.errors import BadInput

BLOCK = re.compile(r"(<!-- render: (?P<name>[a-z0-9-]+) -->\n)(?P<body>.*?)(<!-- /render -->)", re.DOTALL)
MARKDOWN_FILES = ("README.md", "docs/**/*.md", "plm_highway/**/README.md")  # a package README docs/ includes


@dataclass(frozen=True)
class Difference:
    path: Path
    name: str


class MissingResult(BadInput):
    """A block's committed result file is not in the repository (yet): the block is left as it is, and said so."""

    def __init__(self, relative: Path):
        super().__init__(f"{relative}: not committed; its blocks stay as they are until it is")
        self.relative = relative


@dataclass(frozen=True)
class Rendered:
    """What :func:`render_all` found: blocks that differ (and were rewritten unless checking), blocks left alone."""

    stale: list[Difference]
    missing: list[tuple[Difference, Path]]


def render_text(text: str, renderers: Mapping[str, Callable[[Path], str]], root: Path, source: str = "",
                missing: list[tuple[str, Path]] | None = None) -> str:
    """``text`` with every block's body rendered anew; an unknown block name is refused, naming it.

    A block whose result file is not committed (:class:`MissingResult`) keeps its body; it is appended to
    ``missing`` as (name, file) when a list is given, and refused otherwise.
    """

    def replace(match: re.Match) -> str:
        name = match.group("name")
        if name not in renderers:
            raise BadInput(f"{source}: block 'render: {name}' has no renderer (known: {sorted(renderers)})")
        try:
            body = renderers[name](root).rstrip("\n") + "\n"
        except MissingResult as exc:
            if missing is None:
                raise
            missing.append((name, exc.relative))
            return match.group(0)
        return match.group(1) + body + match.group(4)

    return BLOCK.sub(replace, text)


def markdown_files(root: Path) -> list[Path]:
    files: list[Path] = []
    for pattern in MARKDOWN_FILES:
        files.extend(sorted(p for p in root.glob(pattern) if "_build" not in p.parts))
    return files


def render_all(root: Path, renderers: Mapping[str, Callable[[Path], str]], check: bool = False) -> Rendered:
    """Render every block of the project's Markdown files; with ``check`` write nothing, only say what differs."""
    differences: list[Difference] = []
    missing: list[tuple[Difference, Path]] = []
    for path in markdown_files(root):
        text = path.read_text(encoding="utf-8")
        absent: list[tuple[str, Path]] = []
        rendered = render_text(text, renderers, root, str(path.relative_to(root)), absent)
        missing += [(Difference(path, name), relative) for name, relative in absent]
        if rendered == text:
            continue
        old = {m.group("name"): m.group("body") for m in BLOCK.finditer(text)}
        new = {m.group("name"): m.group("body") for m in BLOCK.finditer(rendered)}
        differences += [Difference(path, name) for name in new if old.get(name) != new[name]]
        if not check:
            tmp = path.with_name(f".{path.name}.render-tmp")
            tmp.write_text(rendered, encoding="utf-8")
            tmp.replace(path)
    return Rendered(differences, missing)
