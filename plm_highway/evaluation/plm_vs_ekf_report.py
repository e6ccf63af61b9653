"""The learned-vs-model-based comparison as files: a JSON result, or a report directory."""

from __future__ import annotations

import os
from pathlib import Path

from plm_highway.evaluation.plm_vs_ekf import RUN_METRICS, CompareResult, markdown, plot_comparison
from plm_highway.io import directory_kind, file_kind, json_text, write_csv_into, write_outputs

COMPARE_JSON = file_kind("estimation-compare", "a PLM-Net vs EKF comparison JSON file")
COMPARE_REPORT = directory_kind("estimation-compare-report", "a plm-highway PLM-Net vs EKF comparison directory")
DEFAULT_OUT = Path("figures/estimation/compare")


def publish_comparison(result: CompareResult, json_path: str | os.PathLike | None,
                       out_dir: str | os.PathLike | None, *, overwrite: bool = False) -> list[Path]:
    """The JSON and/or a directory (compare.json, compare.md, runs.csv, compare.png), published together."""
    targets = [(path, kind) for path, kind in ((json_path, COMPARE_JSON), (out_dir, COMPARE_REPORT)) if path is not None]
    if not targets:
        return []
    data = result.to_dict()
    text = json_text(data, COMPARE_JSON)
    with write_outputs(targets, overwrite=overwrite) as staged:
        for (_, kind), path in zip(targets, staged):
            if kind is COMPARE_JSON:
                path.write_text(text, encoding="utf-8")
                continue
            (path / "compare.json").write_text(text, encoding="utf-8")
            (path / "compare.md").write_text(markdown(data) + "\n", encoding="utf-8")
            write_csv_into(path / "runs.csv", ["policy", "latency", "bias_s", "seed", *RUN_METRICS],
                           [[r.policy, r.latency, r.bias_s, r.seed, *(r.metrics[m] for m in RUN_METRICS)]
                            for r in result.rows])
            plot_comparison(data, path / "compare.png")
    return [Path(path) for path, _ in targets]
