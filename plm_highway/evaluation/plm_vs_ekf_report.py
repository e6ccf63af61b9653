"""The learned-vs-model-based comparison as files: a JSON result, or a report directory (both conditions in one)."""

from __future__ import annotations

import os
from pathlib import Path

from plm_highway.evaluation.outcomes import OUTCOMES
from plm_highway.evaluation.plm_vs_ekf import CompareResult, markdown, plot_comparison, setting_name
from plm_highway.io import directory_kind, file_kind, json_text, load_json, write_csv_into, write_outputs

COMPARE_JSON = file_kind("estimation-compare", "a PLM-Net vs EKF comparison JSON file")
COMPARE_REPORT = directory_kind("estimation-compare-report", "a plm-highway PLM-Net vs EKF comparison directory")
DEFAULT_OUT = Path("figures/estimation/compare")
CSV_COLUMNS = ("conditions", "policy", "latency", "bias_s", "seed", *OUTCOMES)


def comparison_data(results: list[CompareResult]) -> dict:
    """The JSON of one or more conditions' comparisons: ``{"reports": [CompareResult.to_dict(), ...]}``."""
    return {"reports": [result.to_dict() for result in results]}


def publish_comparison(results: list[CompareResult], json_path: str | os.PathLike | None,
                       out_dir: str | os.PathLike | None, *, overwrite: bool = False) -> list[Path]:
    """The JSON and/or a directory (compare.json, compare.md, runs.csv, compare.png), published together."""
    targets = [(path, kind) for path, kind in ((json_path, COMPARE_JSON), (out_dir, COMPARE_REPORT)) if path is not None]
    if not targets:
        return []
    data = comparison_data(results)
    text = json_text(data, COMPARE_JSON)
    with write_outputs(targets, overwrite=overwrite) as staged:
        for (_, kind), path in zip(targets, staged):
            if kind is COMPARE_JSON:
                path.write_text(text, encoding="utf-8")
                continue
            (path / "compare.json").write_text(text, encoding="utf-8")
            (path / "compare.md").write_text(markdown(data["reports"]) + "\n", encoding="utf-8")
            write_csv_into(path / "runs.csv", list(CSV_COLUMNS),
                           [[result.config.conditions, r.policy, r.latency, r.bias_s, r.seed,
                             *(r.outcomes[m] for m in OUTCOMES)] for result in results for r in result.rows])
            plot_comparison(data["reports"], path / "compare.png")
    return [Path(path) for path, _ in targets]


# ---------------------------------------------------------------------------------------------
# who wins where, rendered from the committed result (README, Lesson 5)
# ---------------------------------------------------------------------------------------------


def committed_comparison(path: str | os.PathLike | None = None) -> dict:
    """The comparison committed with the kit (``figures/estimation/compare/compare.json`` of this checkout)."""
    checkout = Path(__file__).resolve().parents[2]  # plm_highway/evaluation/ -> the checkout
    path = checkout / DEFAULT_OUT / "compare.json" if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no comparison there; make one with 'plm-highway estimate compare --out "
                                f"{path.parent}'")
    return load_json(path, what="comparison result")


def _mean(entry: dict, policy: str, metric: str) -> float | None:
    summary = entry["policies"].get(policy)
    return None if summary is None else summary[metric]["mean"]


def _winner(entry: dict, pair: str, metric: str, names: tuple[str, str]) -> str:
    """The better side of a paired ``first - second`` interval (lower is better), or ``no clear difference``."""
    difference = entry["paired"].get(pair, {}).get(metric)
    if difference is None or difference["low"] is None:
        return "n/a"
    if difference["high"] < 0:
        return f"{names[0]} better"
    if difference["low"] > 0:
        return f"{names[1]} better"
    return "no clear difference"


def _off_road(entry: dict, policy: str) -> str:
    summary = entry["policies"].get(policy)
    if summary is None:
        return "n/a"
    left = summary["left_road"]
    return f"{round(left['mean'] * left['n'])}/{left['n']}"


def who_wins_lines(data: dict) -> list[str]:
    """One plain sentence per conditions and latency setting: which answer steers closer to the reference and
    which keeps closer to the lane centre (paired 95 % intervals), what delay compensation buys the EKF, and who
    left the road; then a count over the settings with latency."""

    lines, tally = [], {}
    for report in data["reports"]:
        conditions = report["config"]["conditions"]
        for entry in report["settings"]:
            setting = setting_name(entry["latency"], entry["bias_s"])
            parts = [f"steering MAE PLM-Net {_mean(entry, 'plm', 'steering_mae_paper'):.3f}, EKF "
                     f"{_mean(entry, 'ekf', 'steering_mae_paper'):.3f} "
                     f"({_winner(entry, 'ekf-plm', 'steering_mae_paper', ('EKF', 'PLM-Net'))})",
                     f"offset RMS PLM-Net {_mean(entry, 'plm', 'offset_rms_m'):.3f} m, EKF "
                     f"{_mean(entry, 'ekf', 'offset_rms_m'):.3f} m "
                     f"({_winner(entry, 'ekf-plm', 'offset_rms_m', ('EKF', 'PLM-Net'))})"]
            if "ekf-ekf_nc" in entry["paired"]:
                parts.append(f"the EKF without delay compensation {_mean(entry, 'ekf_nc', 'offset_rms_m'):.3f} m "
                             f"({_winner(entry, 'ekf-ekf_nc', 'offset_rms_m', ('compensation', 'no compensation'))})")
            if "bm" in entry["policies"] and entry["latency"] != "const:0":
                parts.append(f"the Base Model {_mean(entry, 'bm', 'offset_rms_m'):.3f} m")
            off = ", ".join(f"{name} {_off_road(entry, policy)}" for policy, name in
                            (("bm", "Base Model"), ("plm", "PLM-Net"), ("ekf", "EKF")) if policy in entry["policies"])
            lines.append(f"- {conditions}, {setting}: " + "; ".join(parts) + f"; left the road: {off}.")
            if entry["latency"] != "const:0" and entry["bias_s"] == 0.0:
                counts = tally.setdefault(conditions, {"settings": 0, "steering": {}, "offset": {}})
                counts["settings"] += 1
                for key, metric in (("steering", "steering_mae_paper"), ("offset", "offset_rms_m")):
                    winner = _winner(entry, "ekf-plm", metric, ("EKF", "PLM-Net"))
                    counts[key][winner] = counts[key].get(winner, 0) + 1
    for conditions, counts in tally.items():
        lines.append(f"- {conditions}, over the {counts['settings']} settings with latency: steering MAE "
                     + _tally(counts["steering"]) + "; offset RMS " + _tally(counts["offset"]) + ".")
    return lines


def _tally(counts: dict) -> str:
    order = ("PLM-Net better", "EKF better", "no clear difference", "n/a")
    return ", ".join(f"{label} in {counts[label]}" for label in order if counts.get(label))


def readme_table(data: dict) -> str:
    """Means over seeds per conditions and setting (steering MAE in the paper's unit, offset RMS [m]), the
    paired winner EKF vs PLM-Net on each, and the runs that left the road."""

    lines = ["| conditions | setting | steering MAE: BM / PLM-Net / EKF, no comp. / EKF | offset RMS [m]: BM / PLM-Net / "
             "EKF, no comp. / EKF | better (paired): steering / offset | left the road: BM / PLM-Net / EKF |",
             "|---|---|---|---|---|---|"]
    for report in data["reports"]:
        for entry in report["settings"]:
            if entry["bias_s"] != 0.0:
                continue

            def row(metric, digits=3, entry=entry):
                return " / ".join("-" if _mean(entry, p, metric) is None else f"{_mean(entry, p, metric):.{digits}f}"
                                  for p in ("bm", "plm", "ekf_nc", "ekf"))

            winners = " / ".join(_winner(entry, "ekf-plm", m, ("EKF", "PLM-Net")).replace(" better", "")
                                 for m in ("steering_mae_paper", "offset_rms_m"))
            off = " / ".join(_off_road(entry, p) for p in ("bm", "plm", "ekf"))
            lines.append(f"| {report['config']['conditions']} | {setting_name(entry['latency'])} | "
                         f"{row('steering_mae_paper')} | {row('offset_rms_m')} | {winners} | {off} |")
    return "\n".join(lines)
