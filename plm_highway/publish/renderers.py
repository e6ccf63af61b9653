"""What each generated block shows, and from which committed result file (paths relative to the project root).

A renderer takes the project root and returns Markdown. It reads committed files only, never runs anything, so
``plm-highway docs render --check`` is fast and its answer depends on the repository alone.
"""

from __future__ import annotations

import csv
import io
import statistics
from collections.abc import Callable
from pathlib import Path

from plm_highway.bench.models import format_closed_loop_table, format_runs
from plm_highway.errors import BadInput
from plm_highway.evaluation.latency_estimation_report import steps_text
from plm_highway.evaluation.plm_vs_ekf_report import readme_table as comparison_table
from plm_highway.evaluation.plm_vs_ekf_report import who_wins_lines
from plm_highway.io import load_json
from plm_highway.lane_ekf.table3 import readme_table
from plm_highway.population.mitigations import aim_table, outcome_sentences
from plm_highway.population.report import UNTIMED_DRIVE_S, headline
from plm_highway.publish.blocks import MissingResult
from plm_highway.sim2real.benchmark import CASE_SETS, markdown_table

POPULATION = Path("figures/population/population.json")
REPRODUCE_IDEAL = Path("figures/reproduce/results.json")
TABLE3 = Path("figures/estimation/table3.json")
COMPARISON = Path("figures/estimation/compare/compare.json")
# The bench models target is judged on the median of these three runs with the shipped weights.
BENCH_MODELS_SHIPPED = tuple(Path(f"figures/bench/models-cpu-{n}.json") for n in (1, 2, 3))
BENCH_MODELS_RANDOM = (Path("figures/bench/models-cpu-random.json"),)
BENCH_MODELS_CLOSED_LOOP = Path("figures/bench/models-cpu-closed-loop.json")
SIM2REAL_BENCH = Path("figures/bench/sim2real.json")
MITIGATIONS = Path("figures/mitigations/mitigations.json")
LATENCY_ESTIMATION = Path("figures/latency-estimation/results.json")
# The sim2real page's worked examples: ``plm-highway sim2real diagnose ... --json`` on the recordings its commands make.
SIM2REAL_EXAMPLES = {"sim2real-worked-example": Path("figures/sim2real/worked-example/rec-diagnosis.json"),
                     "sim2real-small-car": Path("figures/sim2real/worked-example/small-diagnosis.json"),
                     # the real race car, on the yaw rate and on the heading (the recording is not shipped)
                     "sim2real-real-car": Path("figures/sim2real/iac_putnam_run4_2/diagnosis.json"),
                     "sim2real-real-car-heading": Path("figures/sim2real/iac_putnam_run4_2_heading/diagnosis.json")}


def _json(root: Path, relative: Path) -> dict:
    path = root / relative
    if not path.exists():
        raise MissingResult(relative)
    try:
        return load_json(path, what="committed result file")
    except (OSError, BadInput) as exc:
        raise BadInput(f"{relative}: the committed result file a generated block needs is unreadable ({exc})") from None


def population_headline(root: Path) -> str:
    """The population study's result in both metrics, with the number of pairs (README's results box)."""
    lines = headline(_json(root, POPULATION))
    return "\n".join(f"> {line}" for line in lines) + f"\n>\n> From [{POPULATION.parent}/report.md]({POPULATION.parent}/report.md)."


def quickstart_shipped_pair(root: Path) -> str:
    """What the Quick start's evaluation measures, from the committed reproduction with the same shipped pair under
    the same ideal conditions: the steering MAE reduction beside the lane keeping, at 0.25 s."""
    result = _json(root, REPRODUCE_IDEAL)
    shipped = {role: f"plm_highway/checkpoints/{role}_default.pt" for role in ("bm", "tapm")}
    if result["conditions"] != "ideal" or {r: c["path"] for r, c in result["checkpoints"].items()} != shipped:
        raise BadInput(f"{REPRODUCE_IDEAL}: not the shipped pair under ideal conditions, which the Quick start runs")
    setting = result["settings"]["const:0.25"]
    seeds = setting["per_seed"]

    def mean_over_seeds(run: str) -> float:
        return sum(seed["runs"][run]["lateral_offset_rms_m"] for seed in seeds) / len(seeds)

    baseline, mitigated = mean_over_seeds("baseline"), mean_over_seeds("mitigated")
    return (f"With the shipped pair under ideal conditions at 0.25 s, the committed reproduction "
            f"([figures/reproduce/report.md](figures/reproduce/report.md), {len(seeds)} seeds, the first "
            f"{result['steps_scored']} steps) has PLM-Net lowering the steering MAE by "
            f"{setting['steering']['mae_reduction_pct']['mean']:.1f}% but the lateral-offset RMS only from "
            f"{baseline:.3f} m to {mitigated:.3f} m ({100 * (1 - mitigated / baseline):.0f}% lower; means over the seeds).")


def population_status(root: Path) -> str:
    """How far the committed population run got, what each pair's training and driving cost (per stage, with the
    load), and the remedies' decisions."""
    document = _json(root, POPULATION)
    plan = document["plan"]
    trainings = document["trainings"]
    stages_of = document.get("stages", {})
    per_pair, training_minutes = [], []
    for pair, record in sorted(trainings.items(), key=lambda item: int(item[0])):
        summary = record.get("summary", {})
        if summary.get("seconds") is None:
            continue
        training_minutes.append(summary["seconds"] / 60)
        times = summary.get("stages", {})
        split = ", ".join(f"{label} {times[stage]['wall_s'] / 60:.1f}" for stage, label in
                          (("collect", "collect"), ("bm_training", "BM"), ("tapm_training", "TAPM")) if stage in times)
        loads = [times[s][k] for s in times for k in ("load_start", "load_end") if times[s].get(k) is not None]
        drive = stages_of.get(pair, {}).get("driving", {}).get("wall_s")
        text = f"pair {pair}: {summary['seconds'] / 60:.1f} min"
        if split:
            text += f" ({split}; load {min(loads):.1f}-{max(loads):.1f})" if loads else f" ({split})"
        if drive is not None and drive >= UNTIMED_DRIVE_S:
            text += f", driving {drive / 60:.1f} min on {stages_of[pair].get('workers')} workers"
        elif drive is not None:
            text += ", driving not timed (its runs were on record from an interrupted run)"
        per_pair.append(text)
    lines = [f"- Pairs: {document['pairs_planned']} planned, {len(document['pairs_trained'])} trained, "
             f"{len(document['pairs_failed'])} failed, {len(document['pairs_driven'])} driven "
             f"({plan['conditions']} conditions, {len(plan['sim_seeds'])} simulator seeds per pair and setting).",
             f"- Training one pair with recipe `{plan['recipe']['name']}` on {plan['recipe']['threads']} CPU threads "
             f"(wall minutes, median {statistics.median(training_minutes):.1f}): " + "; ".join(per_pair) + "."
             if training_minutes else "- No pair has a training time on record."]
    for name, remedy in sorted(document.get("remedies", {}).items()):
        lines.append(f"- Remedy `{name}`: **{remedy['decision']}** ({remedy['decision_rule']}).")
    return "\n".join(lines)


def mitigations_outcome(root: Path) -> str:
    """The plug-in mitigations' outcome in one sentence per group (README)."""
    return "\n".join(f"> {line}" for line in outcome_sentences(_json(root, MITIGATIONS))) + (
        f"\n>\n> From [{MITIGATIONS.parent}/report.md]({MITIGATIONS.parent}/report.md).")


def mitigations_table(root: Path) -> str:
    """The designs beside the BM, PLM-Net and the EKF lane keeper at the aim's settings, per group (docs)."""
    return aim_table(_json(root, MITIGATIONS))


def latency_claims(root: Path) -> str:
    """The latency estimator's claims beside the openpilot-style baseline's, per conditions and latency (pooled over
    tracks and seeds), for the driving the estimate serves (PLM-Net told it) and a weaving car (the BM)."""
    results = _json(root, LATENCY_ESTIMATION)
    roles = {"estimated": "PLM-Net told the estimate", "baseline": "Base Model"}
    groups: dict[tuple, list[dict]] = {}
    for entry in results["estimation"]:
        if entry["variant"] or entry["role"] not in roles:
            continue
        groups.setdefault((entry["conditions"], entry["role"], entry["setting"]), []).append(entry)

    def pooled(entries: list[dict]) -> tuple[int, int, int, int]:
        claims = sum(e.get("claims", 0) for e in entries)
        wrong = sum(e.get("wrong_claims", 0) for e in entries)
        runs = sum(e.get("runs", len(e["seeds"])) for e in entries)
        return claims, wrong, sum(e.get("claimed_runs", 0) for e in entries), runs

    def share(claims: int, wrong: int) -> str:
        return f"{wrong} of {claims} ({100 * wrong / claims:.1f}%)" if claims else "no claim"

    lines = ["| conditions | driving | latency | runs claimed | wrong claims | steps handled | baseline (scaled): runs "
             "claimed | wrong claims |", "|---|---|---|---|---|---|---|---|"]
    for (conditions, role, setting), entries in sorted(groups.items()):
        claims, wrong, claimed_runs, runs = pooled(entries)
        base = [e["baselines"]["scaled"] for e in entries if "scaled" in e.get("baselines", {})]
        b_claims, b_wrong, b_runs, b_total = pooled([{**b, "seeds": []} for b in base])
        steps = [e["claim_steps"] for e in entries if e.get("claim_steps")]
        pooled_steps = {name: sum(s.get(name, 0) for s in steps)
                        for name in ("handled", "steps_judged", "unanswered_not_estimable")}
        lines.append(f"| {conditions} | {roles[role]} | `{setting}` | {claimed_runs} of {runs} | "
                     f"{share(claims, wrong)} | {steps_text(pooled_steps)} | {b_runs} of {b_total} | {share(b_claims, b_wrong)} |")
    return "\n".join(lines)


def estimation_table3(root: Path) -> str:
    """The EKF paper's Table 3 in simulation beside the paper's RMSE (``plm-highway estimate table3``)."""
    return readme_table(_json(root, TABLE3))


def plm_vs_ekf_table(root: Path) -> str:
    """PLM-Net, the Base Model and the EKF lane keeper per setting (``plm-highway estimate compare``)."""
    return comparison_table(_json(root, COMPARISON))


def plm_vs_ekf_who_wins(root: Path) -> str:
    """Who wins where, setting by setting, from the same comparison (Lesson 5 prints these lines too)."""
    return "\n".join(who_wins_lines(_json(root, COMPARISON)))


def _bench_models_runs(files: tuple[Path, ...]) -> Callable[[Path], str]:
    def render(root: Path) -> str:
        return "\n".join(["```text", *format_runs([_json(root, path) for path in files]), "```"])

    render.__doc__ = f"``plm-highway bench models`` runs side by side: {', '.join(str(p) for p in files)}."
    return render


def bench_models_closed_loop(root: Path) -> str:
    """PLM-Net's closed-loop steering MAE with the exact, int8 and reference forms (``bench models --closed-loop``)."""
    return "\n".join(format_closed_loop_table(_json(root, BENCH_MODELS_CLOSED_LOOP)))


CALIBRATIONS = {
    "the shipped paper conditions": Path("figures/bm-calibration.json"),
    "tires saturating at 0.9 g (`--friction-coefficient 0.9`)": Path("figures/bm-calibration-friction.json"),
    "the original's speed logic (`--speed-logic original-braking`)": Path("figures/bm-calibration-original-braking.json"),
    "latencies read as loop frames (`--reading loop-frames`)": Path("figures/bm-calibration-loop-frames.json"),
}
CALIBRATION_LEVERS = Path("figures/bm-calibration-levers.csv")


def bm_calibration(root: Path) -> str:
    """The BM's steering MAE over the paper's at each latency, per committed ``plm-highway calibrate`` run."""
    lines = ["| variant | 0.15 s | 0.20 s | 0.25 s | 0.30 s | penalised at 0.25 / 0.30 s | rule 2 |",
             "|---|---|---|---|---|---|---|"]
    for label, relative in CALIBRATIONS.items():
        result = _json(root, relative)
        ratios = result["rules"]["paper"]["ours_over_paper"]
        penalised = result["rules"]["paper_penalised"]["ours_over_paper"]
        rows = list(result["per_latency"].values())
        cells = [f"{ratio:.2f}x ({sum(row['left_road'])} of {len(row['left_road'])})"
                 for ratio, row in zip(ratios.values(), rows)]
        late = list(penalised.values())[-2:]
        verdict = "met" if result["rules"]["paper"]["met"] else "missed"
        lines.append(f"| {label} | {' | '.join(cells)} | {late[0]:.2f} / {late[1]:.2f}x | {verdict} |")
    shipped = _json(root, CALIBRATIONS["the shipped paper conditions"])
    rise = shipped["rules"]["rise"]
    lines += ["", f"Rule 1 on the shipped paper conditions, {rise['rule']}: **{'met' if rise['met'] else 'missed'}** "
              f"({rise['factor']:.0f}x)."]
    return "\n".join(lines)


def bm_calibration_levers(root: Path) -> str:
    """The levers tried on the BM calibration, as recorded when each was measured (``CALIBRATION_LEVERS``)."""
    path = root / CALIBRATION_LEVERS
    if not path.exists():
        raise MissingResult(CALIBRATION_LEVERS)
    try:
        rows = list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))))
    except (OSError, ValueError) as exc:
        raise BadInput(f"{CALIBRATION_LEVERS}: the committed result file a generated block needs is unreadable "
                       f"({exc})") from None
    columns = ["lever", "variant", "at_0.15_s", "at_0.20_s", "at_0.25_s", "at_0.30_s", "outcome"]
    if not rows or list(rows[0]) != columns:
        raise BadInput(f"{CALIBRATION_LEVERS}: expected the columns {columns}")
    lines = ["| lever | variant | 0.15 s | 0.20 s | 0.25 s | 0.30 s | outcome |", "|---|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row[c] for c in columns) + " |" for row in rows]
    return "\n".join(lines)


def _sim2real_example(relative: Path) -> Callable[[Path], str]:
    def render(root: Path) -> str:
        diagnosis = _json(root, relative)
        return "\n".join(["```text", diagnosis["summary"], f"verdict: {diagnosis['verdict']}", "```"])

    render.__doc__ = f"A ``sim2real diagnose`` summary and verdict, as the command printed them: {relative}."
    return render


def sim2real_bench(root: Path) -> str:
    """The sim2real battery as ``plm-highway bench sim2real`` measured it: recovery per case set, the match rate on
    the simulator's own model, and the timing of a 10-minute recording."""
    result = _json(root, SIM2REAL_BENCH)
    lines = [f"`{result['command']}` ({result['seeds']} seeds per case, 120-s recordings at 50 Hz unless the case "
             f"says otherwise; load average {result['load_average_at_start']:.1f} on {result['cpus']} CPUs):"]
    for name in CASE_SETS:
        if name in result:
            lines += ["", f"*{name}*:", "", markdown_table(result[name]["summary"])]
    if "match" in result:
        counts = result["match"]
        total = sum(counts.values())
        lines += ["", f"*match*: the simulator's own model plus noise, {total} seeds: "
                      f"{', '.join(f'{verdict} {count}' for verdict, count in counts.items())}."]
    if "timing" in result:
        timing = result["timing"]["this_tree"]
        lines += ["", f"*timing*: a {(timing['samples'] - 1) / 50:.0f}-s recording at 50 Hz ({timing['samples']:,} samples) "
                      f"diagnosed in {timing['wall_s']:.1f} s wall, {timing['cpu_s']:.1f} s CPU (verdict "
                      f"{timing['verdict']}: {' + '.join(timing['named'])})."]
    return "\n".join(lines)


RENDERERS: dict[str, Callable[[Path], str]] = {
    "population-headline": population_headline,
    "population-status": population_status,
    "mitigations-outcome": mitigations_outcome,
    "mitigations-table": mitigations_table,
    "quickstart-shipped-pair": quickstart_shipped_pair,
    "estimation-table3": estimation_table3,
    "latency-claims": latency_claims,
    "plm-vs-ekf-table": plm_vs_ekf_table,
    "plm-vs-ekf-who-wins": plm_vs_ekf_who_wins,
    "bench-models-shipped": _bench_models_runs(BENCH_MODELS_SHIPPED),
    "bench-models-random": _bench_models_runs(BENCH_MODELS_RANDOM),
    "bench-models-closed-loop": bench_models_closed_loop,
    "bm-calibration": bm_calibration,
    "bm-calibration-levers": bm_calibration_levers,
    **{name: _sim2real_example(path) for name, path in SIM2REAL_EXAMPLES.items()},
    "sim2real-bench": sim2real_bench,
}
