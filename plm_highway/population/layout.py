"""Where a population's work directory keeps each piece (one place, read by the run and by the report)."""

from __future__ import annotations

from pathlib import Path

from plm_highway.population.driving import read_traces as decode
from plm_highway.population.plan import pair_name


def runs_path(work: Path, pair: int, seed: int, remedy: str = "") -> Path:
    """The rows of one pair's runs under one seed (the traces beside it, ``.npz``)."""
    return work / "runs" / f"{pair_name(pair)}-seed-{seed}{'-' + remedy if remedy else ''}.json"


def remedy_dir(work: Path, pair: int, remedy: str) -> Path:
    return work / "pairs" / pair_name(pair) / f"remedy-{remedy}"


def read_traces(work: Path, pair: int, seed: int) -> dict:
    """The traces of one pair's runs under one seed (:func:`~plm_highway.population.driving.read_traces`)."""
    return decode(runs_path(work, pair, seed).with_suffix(".npz").read_bytes())
