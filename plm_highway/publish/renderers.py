"""What each generated block shows, and from which committed result file (paths relative to the project root).

A renderer takes the project root and returns Markdown. It reads committed files only, never runs anything, so
``plm-highway docs render --check`` is fast and its answer depends on the repository alone.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from plm_highway.errors import BadInput

POPULATION = Path("figures/population/population.json")


def _json(root: Path, relative: Path) -> dict:
    path = root / relative
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise BadInput(f"{relative}: the committed result file a generated block needs is unreadable ({exc})") from None


def population_headline(root: Path) -> str:
    """The population study's result in both metrics, with the number of pairs (README's results box)."""
    from plm_highway.population.report import headline

    lines = headline(_json(root, POPULATION))
    return "\n".join(f"> {line}" for line in lines) + f"\n>\n> From [{POPULATION.parent}/report.md]({POPULATION.parent}/report.md)."


RENDERERS: dict[str, Callable[[Path], str]] = {
    "population-headline": population_headline,
}
