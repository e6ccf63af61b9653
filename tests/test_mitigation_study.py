"""The mitigation study's verdicts, intervals and records, on hand-made rows (no driving)."""

from __future__ import annotations

import json

import pytest

from plm_highway.errors import BadInput
from plm_highway.population import mitigations as study

SETTINGS = ("const:0.25", "const:0.3", "steps:0.0-0.35:1.0")


def rows_of(part: str, offsets: dict[str, float], maes: dict[str, float], off_road: dict[str, int], seeds=(0, 1, 2)):
    """Rows for every policy, setting and seed: offsets and MAEs scaled a little per seed (so intervals exist);
    ``off_road[policy]`` of the seeds left the road."""
    rows = []
    for setting in SETTINGS:
        for policy in study.POLICIES:
            for k, seed in enumerate(seeds):
                scale = 1.0 + 0.05 * k
                rows.append({"part": part, "seed": seed, "policy": policy, "setting": setting,
                             "steering_mae_paper": maes[policy] * scale, "offset_rms_m": offsets[policy] * scale,
                             "offset_max_m": 2 * offsets[policy] * scale, "frechet_m": offsets[policy],
                             "left_road": k < off_road.get(policy, 0)})
    return rows


def records(offsets, maes, off_road, pairs=4):
    return [{"part": f"pair-{p:02d}", "rows": rows_of(f"pair-{p:02d}", {k: v * (1 + 0.1 * p) for k, v in offsets.items()},
                                                         maes, off_road),
             "gains": {"bm": {"offset_gain_per_m": -0.2, "heading_gain_per_rad": -2.0},
                       "bm-warp@0.25": {"offset_gain_per_m": -0.2, "heading_gain_per_rad": -3.0}}}
            for p in range(pairs)]


OFFSETS = {"bm": 5.0, "plm": 2.0, "ekf": 0.2, "bm-warp": 0.22, "bm-smith": 3.0}
MAES = {"bm": 0.5, "plm": 0.1, "ekf": 0.05, "bm-warp": 0.01, "bm-smith": 0.2}


def test_a_design_on_the_road_with_a_lower_offset_and_mae_is_recommended_and_meets_the_aim():
    summary = study.summarise(records(OFFSETS, MAES, {"plm": 1, "bm": 3, "bm-smith": 1}))
    entry = summary["population"]
    assert entry["units"] == 4 and entry["unit"] == "pair"
    warp, smith = entry["verdicts"]["bm-warp"], entry["verdicts"]["bm-smith"]
    assert warp["recommended"] and warp["aim_met"]  # 0.22 / 0.2 = 1.1x the EKF's, under 1.2
    assert not smith["recommended"] and not smith["aim_met"]
    assert not smith["settings"]["const:0.25"]["on_road"]
    assert not smith["settings"]["const:0.25"]["offset_lower_than_plm"]
    at = entry["settings"]["const:0.25"]
    assert at["plm"]["left_road"] == 4 and at["plm"]["runs"] == 12
    assert at["bm-warp"]["offset_rms_over_ekf"]["mean"] == pytest.approx(1.1)
    # every interval of a positive quantity stays positive; the paired difference is negative for the warp
    for policy, s in at.items():
        assert s["offset_rms_m"]["ci_low"] > 0, policy
    assert at["bm-warp"]["offset_rms_m_minus_plm"]["ci_high"] < 0
    assert entry["gains"]["bm-warp@0.25"] == {"offset_gain_per_m": 1.0, "heading_gain_per_rad": 1.5}


def test_a_design_further_than_the_ratio_from_the_ekf_misses_the_aim_but_can_still_be_recommended():
    offsets = dict(OFFSETS, **{"bm-warp": 0.3})  # 1.5x the EKF's
    entry = study.summarise(records(offsets, MAES, {}))["population"]
    assert entry["verdicts"]["bm-warp"]["recommended"]
    assert not entry["verdicts"]["bm-warp"]["aim_met"]
    assert not entry["verdicts"]["bm-warp"]["settings"]["const:0.3"]["offset_within_ekf_ratio"]


def test_a_higher_mae_than_plm_net_is_not_recommended():
    maes = dict(MAES, **{"bm-warp": 0.2})
    entry = study.summarise(records(OFFSETS, maes, {}))["population"]
    assert not entry["verdicts"]["bm-warp"]["recommended"]
    assert not entry["verdicts"]["bm-warp"]["settings"]["const:0.25"]["mae_not_higher_than_plm"]


def test_with_too_few_pairs_no_interval_is_printed():
    summary = study.summarise(records(OFFSETS, MAES, {}, pairs=2))
    at = summary["population"]["settings"]["const:0.25"]
    assert at["plm"]["offset_rms_m"]["ci_low"] is None
    assert not summary["population"]["verdicts"]["bm-warp"]["recommended"]  # no interval: not shown lower
    text = study.report_text({"summary": summary, "reference_checks": {}})
    assert "too few for an interval" in text


def test_the_report_and_the_sentences_name_every_design_and_verdict(tmp_path):
    parts = records(OFFSETS, MAES, {"plm": 2})
    for record in parts:
        record.update({"format": study.PART_FORMAT, "made_from": {"x": 1}})
        study.write_part(tmp_path, record)
    summary = study.render(tmp_path, study.committed_parts(tmp_path))
    report = (tmp_path / "report.md").read_text()
    assert "BM + view warp: recommended" in report and "BM + Smith correction: not recommended" in report
    sentences = study.outcome_sentences(json.loads((tmp_path / "mitigations.json").read_text()))
    assert len(sentences) == 1
    assert "`bm-warp` left the road in 0 of 36 runs" in sentences[0]
    assert "PLM-Net left the road in 24 of 36 runs" in sentences[0]
    header = (tmp_path / "results.csv").read_text().splitlines()[0]
    assert header.split(",") == list(study.RESULT_COLUMNS)
    assert summary["parts"] == [f"pair-{p:02d}" for p in range(4)]


def test_an_edited_part_is_refused_and_a_stale_one_driven_again(tmp_path):
    part = study.shipped_part([0], ["const:0.25"], max_steps=5)
    record = {"format": study.PART_FORMAT, "part": "shipped", "made_from": part.made_from(), "rows": [], "gains": {}}
    path = study.write_part(tmp_path, record)
    assert study.read_part(tmp_path, part)["part"] == "shipped"
    other = study.shipped_part([0, 1], ["const:0.25"], max_steps=5)
    assert study.read_part(tmp_path, other) is None  # other seeds: made again
    data = json.loads(path.read_text())
    data["rows"] = [{"offset_rms_m": 0.0}]
    path.write_text(json.dumps(data))
    with pytest.raises(BadInput, match="changed after plm-highway wrote it"):
        study.read_part(tmp_path, part)


def test_report_only_without_parts_says_what_to_run(tmp_path):
    with pytest.raises(BadInput, match="no committed mitigation parts"):
        study.committed_parts(tmp_path)
