"""Table 3 results as files: a JSON result, or a report directory with the table and the figures."""

from __future__ import annotations

import os
from pathlib import Path

from plm_highway.io import directory_kind, file_kind, json_text, write_outputs
from plm_highway.lane_ekf.figures import plot_scenario_run
from plm_highway.lane_ekf.table3 import ScenarioRun, Table3Report

TABLE3_JSON = file_kind("estimation-table3", "a Table 3 result JSON file")
TABLE3_REPORT = directory_kind("estimation-table3-report", "a plm-highway Table 3 report directory")


def figure_name(run: ScenarioRun, measurement: str = "clean") -> str:
    suffix = "" if measurement == "clean" else f"_{measurement}"
    return f"scenario{run.scenario.number}_{run.scenario.key}{suffix}.png"


def publish_table3(result: Table3Report, runs: dict[str, list[ScenarioRun]], json_path: str | os.PathLike | None,
                   out_dir: str | os.PathLike | None, *, overwrite: bool = False) -> list[Path]:
    """Write the JSON result and/or a directory (table3.json, table3.md, one figure per scenario and lane
    measurement at the first seed; ``runs``: measurement -> its runs). Both are published together, or neither.
    """
    targets = [(path, kind) for path, kind in ((json_path, TABLE3_JSON), (out_dir, TABLE3_REPORT)) if path is not None]
    if not targets:
        return []
    text = json_text(result.to_dict(), TABLE3_JSON)
    with write_outputs(targets, overwrite=overwrite) as staged:
        for (_, kind), path in zip(targets, staged):
            if kind is TABLE3_JSON:
                path.write_text(text, encoding="utf-8")
                continue
            (path / "table3.json").write_text(text, encoding="utf-8")
            (path / "table3.md").write_text(result.markdown() + "\n", encoding="utf-8")
            for measurement, measured in runs.items():
                for run in measured:
                    if run.seed == result.seeds[0]:
                        plot_scenario_run(run, path / figure_name(run, measurement), measurement)
    return [Path(path) for path, _ in targets]
