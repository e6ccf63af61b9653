"""The docs' and Lesson 5's numbers on the model-based side are the committed result files' numbers."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from plm_highway.lane_ekf.table3 import readme_table

ROOT = Path(__file__).resolve().parents[1]


def _flat(text: str) -> str:
    """Markdown prose with its line breaks and runs of spaces as single spaces."""
    return re.sub(r"\s+", " ", text)


@pytest.fixture(scope="module")
def readme() -> str:
    return (ROOT / "docs" / "ekf.md").read_text(encoding="utf-8")


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


@pytest.fixture(scope="module")
def comparison() -> dict:
    from plm_highway.evaluation.plm_vs_ekf_report import committed_comparison

    return committed_comparison()


def test_committed_comparison_is_the_full_one(comparison):
    # both conditions, five seeds, the whole scored track, no latency plus the paper's five latency settings
    reports = comparison["reports"]
    assert [r["config"]["conditions"] for r in reports] == ["ideal", "paper"]
    for report in reports:
        assert report["seeds"] == [0, 1, 2, 3, 4] and report["config"]["max_steps"] is None
        assert [e["latency"] for e in report["settings"]] == [
            "const:0", "const:0.15", "const:0.2", "const:0.25", "const:0.3", "steps:0.0-0.35:1.0"]


def test_readme_comparison_is_rendered_from_the_committed_result(readme, comparison):
    from plm_highway.evaluation.plm_vs_ekf_report import readme_table, who_wins_lines

    assert readme_table(comparison) in readme
    assert "\n".join(who_wins_lines(comparison)) in readme


def test_readme_lane_keeper_without_latency_quotes_the_committed_offsets(readme, comparison):
    text = _flat(readme)
    for report in comparison["reports"]:
        no_latency = report["settings"][0]["policies"]
        bm, ekf = no_latency["bm"]["offset_rms_m"]["mean"], no_latency["ekf"]["offset_rms_m"]["mean"]
        assert f"{ekf:.3f} m against the reference Base Model's {bm:.3f} m ({ekf / bm:.2f}x)" in text


def test_readme_realistic_measurement_quotes_the_noise_model_and_the_clean_accuracy(readme, table3):
    from plm_highway.lane_ekf.table3 import REALISTIC_LANE_NOISE

    text = _flat(readme)
    std, tau = REALISTIC_LANE_NOISE.std, REALISTIC_LANE_NOISE.correlation_time_s
    assert (f"standard deviation {std[0]:.3f} m, {math.degrees(std[1]):.2f} deg and {std[2]:.4f} 1/m, frame-to-frame "
            f"correlation time {min(tau):.2f}-{max(tau):.2f} s") in text
    clean = [s["camera_accuracy_rmse"]["d_m"]["mean"] for s in table3["measurements"]["clean"]["scenarios"]]
    assert f"at capture it errs by {min(clean):.2f}-{max(clean):.2f} m" in text
