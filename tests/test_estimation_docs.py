"""The README's and Lesson 5's numbers on the model-based side are the committed result files' numbers."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from plm_highway.estimation.table3 import readme_table

ROOT = Path(__file__).resolve().parents[1]


def _flat(text: str) -> str:
    """Markdown prose with its line breaks and runs of spaces as single spaces."""
    return re.sub(r"\s+", " ", text)


@pytest.fixture(scope="module")
def readme() -> str:
    return (ROOT / "README.md").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def table3() -> dict:
    return json.loads((ROOT / "figures/estimation/table3.json").read_text(encoding="utf-8"))


def _span(values) -> str:
    values = list(values)
    return f"{min(values):.2f}-{max(values):.2f}x"


def test_readme_table3_is_rendered_from_the_committed_result(readme, table3):
    assert readme_table(table3) in readme


def test_readme_table3_prose_quotes_the_committed_ratios(readme, table3):
    ratios = table3["rmse_over_paper"]
    compensated = ratios["ekf_dc"]
    text = _flat(readme)
    every = [r for by_state in compensated["realistic"].values() for r in by_state.values()]
    assert f"({_span(every)} its RMSE per state, " in text
    assert f"{_span(by_state['d'] for by_state in compensated['realistic'].values())} in d)" in text
    clean = [r for by_state in compensated["clean"].values() for r in by_state.values()]
    assert f"where the clean one gave {_span(clean)}" in text
    worst = [max(ratios["camera"][m][n].values()) for m in ("clean", "realistic") for n in ("2", "3", "4")]
    assert f"({_span(worst)} in its worst state; scenario 1: {_span(ratios['camera']['realistic']['1'].values())})" in text
    lag = ratios["camera_lag"]["clean"]
    assert f"already errs {_span(lag[n]['d'] for n in ('2', '3', '4'))} the paper's camera-only d RMSE" in text
    assert f"and {_span(lag[n]['dpsi'] for n in ('3', '4'))} its dpsi RMSE in the double lane changes" in text
    assert not any(table3["camera_row_near_paper"][m][n] for m in ("clean", "realistic") for n in ("2", "3", "4"))
