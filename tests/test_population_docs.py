"""The committed population study against what the docs say of it."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from plm_highway.population.ledger import RECORD_FORMAT, read_ledger
from plm_highway.population.plan import PopulationPlan

ROOT = Path(__file__).resolve().parent.parent
STUDY = ROOT / "figures" / "population"


def _records() -> dict[int, dict]:
    plan = PopulationPlan.from_dict(json.loads((STUDY / "population.json").read_text())["plan"])
    return read_ledger(STUDY, plan)


def test_every_committed_pair_record_is_whole_and_reads_back():
    records = _records()
    assert records, "the committed study has no pair record"
    for record in records.values():
        assert record["format"] == RECORD_FORMAT
        assert record["training"]["ok"]
        assert set(record["training"]["summary"]["stages"]) == {"collect", "bm_training", "tapm_training"}
        assert {row["seed"] for row in record["runs"]} == set(record["made_from"]["sim_seeds"])


def test_the_report_is_rendered_from_every_committed_pair():
    document = json.loads((STUDY / "population.json").read_text())
    assert document["pairs_driven"] == sorted(_records())


def test_pair_0_has_the_shipped_paper_pair_bit_for_bit():
    """What docs/population.md rests its claim on: training pairs one at a time, with the frozen BM in inference
    mode, learns exactly what the shipped paper pair learned (the same recipe and seeds)."""
    records = _records()
    if 0 not in records:
        pytest.fail("pair 0 has no committed record")
    shipped = {f"{model}/model.pt": hashlib.sha256(
        (ROOT / "plm_highway" / "checkpoints" / f"{model}_paper.pt").read_bytes()).hexdigest()
        for model in ("bm", "tapm")}
    assert records[0]["checkpoints"] == shipped
    assert "bit for bit" in (ROOT / "docs" / "population.md").read_text()
