"""A population's report: results.csv (one row per pair x setting x seed x run), pairs.csv (per pair and setting),
population.json (the plan, each pair's training, every statistic), report.md and the figures, published together.

Everything in report.md is computed here from the rows; :func:`render_report` renders it again from
``population.json`` and ``results.csv`` alone, so a test can check that the committed report and its results agree.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from plm_highway.errors import BadInput
from plm_highway.evaluation.outcomes import OUTCOMES
from plm_highway.evaluation.protocol import setting_label, setting_tag
from plm_highway.io import (
    directory_kind,
    format_cell,
    json_text,
    pyplot,
    save_figure_into,
    write_csv_into,
    write_output,
)
from plm_highway.metrics.intervals import MIN_INTERVAL_VALUES, interval_text, too_few
from plm_highway.population import analysis
from plm_highway.population.drift import drift_summary
from plm_highway.population.ledger import made_from
from plm_highway.population.plan import PopulationPlan, pair_name
from plm_highway.population.recipe import Recipe
from plm_highway.population.remedies import REMEDIES

POPULATION_REPORT = directory_kind("population-report", "a plm-highway population report directory")
RESULT_COLUMNS = ("pair", "data_seed", "bm_seed", "tapm_seed", "seed", "role", "remedy", "setting", "latency_driven",
                  *OUTCOMES)
PAIR_COLUMNS = ("pair", "setting", "seeds", "bm_steering_mae_paper", "plm_steering_mae_paper", "mae_reduction_pct",
                "bm_steering_mae_paper_common", "plm_steering_mae_paper_common", "mae_common_reduction_pct",
                "ref_offset_rms_m", "bm_offset_rms_m", "plm_offset_rms_m", "offset_rms_reduction_pct",
                "bm_offset_max_m", "plm_offset_max_m", "bm_frechet_m", "plm_frechet_m", "bm_left_road_seeds",
                "plm_left_road_seeds")
ROLE_ORDER = {"reference": 0, "baseline": 1, "mitigated": 2}
# What a rendering of the report replaces (the committed pair records under pairs/ are not among them).
REPORT_FILES = ("results.csv", "pairs.csv", "population.json", "report.md", "errors.png", "reductions.png",
                "offset_rms.png", "drift.png")


def source_text(plan: dict) -> str:
    """What PLM-Net was told of the latency, where it is not the conditions' own (``--latency-source``)."""
    source = plan.get("latency_source", "")
    return f" (PLM-Net told the {source} latency)" if source else ""


def result_rows(state) -> list[dict]:
    """Every run's row, with its pair's seeds, in a stable order."""
    seeds_of = {s.pair: s for s in state.plan.pairs}
    settings = list(state.plan.settings)
    remedies = ["", *state.plan.remedies]
    chunks = [*state.runs.values(), *(rows for (remedy, _, _), rows in state.remedy_runs.items()
                                       if remedy in remedies)]
    rows = []
    for chunk in chunks:
        for row in chunk:
            pair_seeds = seeds_of[row["pair"]]
            if row.get("remedy") and row["role"] == "reference":
                continue  # the remedy's chunk drives the reference again only to judge against it: the same run
            rows.append({**row, "remedy": row.get("remedy", ""), "data_seed": pair_seeds.data_seed,
                         "bm_seed": pair_seeds.bm_seed, "tapm_seed": pair_seeds.tapm_seed})
    rows.sort(key=lambda r: (r["pair"], settings.index(r["setting"]), ROLE_ORDER[r["role"]],
                             remedies.index(r["remedy"]), r["seed"]))
    return rows


def analyse(plan: PopulationPlan, trainings: dict, all_rows: list[dict]) -> dict:
    """Every statistic the report states, as plain data (what population.json holds besides the plan)."""
    rows = [r for r in all_rows if not r.get("remedy")]
    summaries = analysis.pair_summaries(rows, plan.settings)
    constant = [s for s in plan.latency_settings if s.startswith("const:")]
    per_setting = {}
    for setting in plan.settings:
        at = [s for s in summaries if s["setting"] == setting]
        per_setting[setting] = {
            "label": setting_label(setting),
            **{f"{key}": _spread(at, key) for key in (
                "bm_steering_mae_paper", "plm_steering_mae_paper", "mae_reduction_pct", "mae_common_reduction_pct",
                "ref_offset_rms_m", "bm_offset_rms_m", "plm_offset_rms_m", "offset_rms_reduction_pct",
                "bm_offset_max_m", "plm_offset_max_m", "bm_frechet_m", "plm_frechet_m")},
            "bm_left_road": sum(s["bm_left_road_seeds"] for s in at),
            "plm_left_road": sum(s["plm_left_road_seeds"] for s in at),
            "runs_per_policy": sum(s["seeds"] for s in at),
            "shares": analysis.shares(summaries, setting),
            "variance": {
                "plm_offset_rms_m": analysis.variance_split(rows, summaries, setting, "mitigated", "offset_rms_m"),
                "bm_steering_mae_paper": analysis.variance_split(rows, summaries, setting, "baseline",
                                                                 "steering_mae_paper")}
            if setting != "const:0" else None,
        }
    return {
        "pairs_planned": len(plan.pairs),
        "pairs_trained": sorted(p for p, t in trainings.items() if t.get("ok")),
        "pairs_failed": {str(p): t.get("error", "").splitlines()[0] if t.get("error") else "failed"
                         for p, t in trainings.items() if not t.get("ok")},
        "pairs_driven": sorted({r["pair"] for r in rows}),
        "per_setting": per_setting,
        "verdicts": [v for s in plan.latency_settings if (v := analysis.verdict(s, summaries)) is not None],
        "error_fit": analysis.error_fit(summaries, constant),
        "pair_summaries": summaries,
        "remedies": {remedy: analysis.remedy_comparison(all_rows, remedy, plan.settings, summaries)
                     for remedy in plan.remedies},
    }


def _spread(summaries: list[dict], key: str) -> dict | None:
    value = analysis.spread((s[key] for s in summaries), scale=analysis.scale_of(key))
    return None if value is None else value.as_dict()


def publish_report(state, options) -> dict:
    """Write the report directory ``options.out`` in one publication; returns the analysis."""
    rows = _as_written(result_rows(state))
    if not rows:
        raise BadInput("population: no pair was trained and driven, so there is nothing to report (see the "
                       f"training records under {options.work}/pairs)")
    numbers = analyse(state.plan, state.trainings, rows)
    numbers["drift"] = drift_numbers(state)
    document = {"plan": state.plan.as_dict(), "made_from": made_from(state.plan), "command": options.command,
                "trainings": {str(p): t for p, t in sorted(state.trainings.items())},
                "stages": {str(p): s for p, s in sorted(state.stages.items())}, **numbers}
    # The report's own files are replaced as a whole; the committed pair records (pairs/) stay.
    with write_output(options.out, POPULATION_REPORT, update=REPORT_FILES) as staged:
        write_csv_into(staged / "results.csv", RESULT_COLUMNS, [[r.get(c) for c in RESULT_COLUMNS] for r in rows])
        write_csv_into(staged / "pairs.csv", PAIR_COLUMNS,
                       [[s.get(c) for c in PAIR_COLUMNS] for s in numbers["pair_summaries"]])
        (staged / "population.json").write_text(json_text(document), encoding="utf-8")
        figures = save_figures(state.plan, numbers, staged)
        if numbers["drift"] is not None:
            figures.append(save_drift_figure(state.plan, numbers["drift"], staged))
        (staged / "report.md").write_text(render_report(document, figures), encoding="utf-8")
    return {"out": str(options.out), **numbers}


def drift_numbers(state) -> dict | None:
    """:func:`~plm_highway.population.drift.drift_summary` from every driven run's offset bands and posed gains."""
    if not state.bands:
        return None
    bands: dict[tuple[int, str], list[dict]] = {}
    for (pair, _seed), by_label in sorted(state.bands.items()):
        for label, value in by_label.items():
            bands.setdefault((pair, label), []).append(value)
    return drift_summary(bands, state.feedback, state.plan.latency_settings)


# -------------------------------------------------------------------------------------------------
# figures
# -------------------------------------------------------------------------------------------------


def save_drift_figure(plan: PopulationPlan, drift: dict, directory: Path) -> str:
    plt = pyplot()
    settings = list(drift["settings"])
    labels = [setting_label(s) for s in settings]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    x = range(len(settings))
    for who, colour, name in (("ref", "tab:blue", "reference BM (no latency)"), ("bm", "tab:green", "BM with latency"),
                              ("plm", "tab:red", "PLM-Net with latency")):
        axes[0].plot(x, [drift["settings"][s][f"{who}_slow_rms_m"] for s in settings], "o-", color=colour,
                     label=f"{name}: slow (< {drift['cutoff_hz']:g} Hz)")
        axes[0].plot(x, [drift["settings"][s][f"{who}_fast_rms_m"] for s in settings], "s--", color=colour,
                     label=f"{name}: fast (weave)")
    axes[0].set_xticks(list(x), labels, rotation=20)
    axes[0].set_ylabel("lateral-offset RMS [m] (mean over pairs)")
    axes[0].set_title("Where the offset lies: slow drift vs fast weave")
    axes[0].legend(fontsize=7)
    axes[0].grid(alpha=0.3)
    constant = [s for s in settings if not math.isnan(drift["settings"][s].get("plm_over_bm_offset_gain_per_m",
                                                                                math.nan))]
    xc = range(len(constant))
    axes[1].plot(xc, [drift["settings"][s]["plm_over_bm_offset_gain_per_m"] for s in constant], "o-",
                 color="tab:red", label="offset gain, PLM-Net / BM")
    axes[1].plot(xc, [drift["settings"][s]["plm_over_bm_heading_gain_per_rad"] for s in constant], "s--",
                 color="tab:purple", label="heading gain, PLM-Net / BM")
    axes[1].axhline(1.0, color="grey", linewidth=0.8)
    axes[1].set_xticks(list(xc), [setting_label(s) for s in constant], rotation=20)
    axes[1].set_ylabel("posed feedback gain, PLM-Net over its BM (mean over pairs)")
    axes[1].set_title("How hard PLM-Net answers the lane, told each latency")
    axes[1].legend(fontsize=8)
    axes[1].grid(alpha=0.3)
    return _save(fig, directory, "drift.png", plt)



def save_figures(plan: PopulationPlan, numbers: dict, directory: Path) -> list[str]:
    summaries = numbers["pair_summaries"]
    latency_settings = list(plan.latency_settings)
    names = []
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7.5, 6))
    markers = "osD^v<>ph*"
    for k, setting in enumerate(latency_settings):
        at = [s for s in summaries if s["setting"] == setting]
        ax.scatter([s["bm_steering_mae_paper"] for s in at], [s["plm_steering_mae_paper"] for s in at],
                   marker=markers[k % len(markers)], color=f"C{k}", label=f"pairs, {setting_label(setting)}")
        numbers_paper = analysis.paper_numbers(setting)
        if numbers_paper is not None:
            ax.scatter([numbers_paper["bm_mae"]], [numbers_paper["plm_mae"]], marker=markers[k % len(markers)],
                       s=160, facecolors="none", edgecolors="black", linewidths=1.6)
    ax.scatter([], [], marker="o", s=160, facecolors="none", edgecolors="black", label="the paper (hollow)")
    top = max([s["bm_steering_mae_paper"] for s in summaries if math.isfinite(s["bm_steering_mae_paper"])] + [0.4])
    ax.plot([0, top], [0, top], color="grey", linestyle=":", label="no mitigation (PLM-Net = BM)")
    ax.set_xlabel("BM with latency: steering MAE vs reference, whole track (paper unit)")
    ax.set_ylabel("PLM-Net: steering MAE vs reference, whole track (paper unit)")
    ax.set_title(f"PLM-Net against BM error, one point per trained pair ({len(numbers['pairs_driven'])} pairs)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    names.append(_save(fig, directory, "errors.png", plt))

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    labels = [setting_label(s) for s in latency_settings]
    for ax, key, title in ((axes[0], "mae_reduction_pct", "steering MAE reduction, whole track"),
                           (axes[1], "offset_rms_reduction_pct", "lateral-offset RMS reduction")):
        data = [[s[key] for s in summaries if s["setting"] == setting and math.isfinite(s[key])]
                for setting in latency_settings]
        ax.boxplot([d if d else [math.nan] for d in data], tick_labels=labels, showmeans=True)
        for k, values in enumerate(data):
            ax.scatter([k + 1] * len(values), values, color="C0", alpha=0.6, s=14, zorder=3)
            numbers_paper = analysis.paper_numbers(latency_settings[k])
            if key == "mae_reduction_pct" and numbers_paper is not None:
                ax.scatter([k + 1], [numbers_paper["reduction_pct"]], marker="*", s=140, color="black", zorder=4,
                           label="the paper" if k == 0 else None)
        ax.axhline(0, color="grey", linewidth=0.8)
        ax.set_ylabel("reduction by PLM-Net [%] (per pair)")
        ax.set_title(title)
        ax.tick_params(axis="x", labelrotation=20)
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=8)
    names.append(_save(fig, directory, "reductions.png", plt))

    fig, ax = plt.subplots(figsize=(9, 5))
    settings = list(plan.settings)
    for who, colour, offset in (("ref", "tab:blue", -0.2), ("bm", "tab:green", 0.0), ("plm", "tab:red", 0.2)):
        for k, setting in enumerate(settings):
            values = [s[f"{who}_offset_rms_m"] for s in summaries if s["setting"] == setting]
            ax.scatter([k + offset] * len(values), values, color=colour, s=16, alpha=0.7,
                       label={"ref": "reference BM (no latency)", "bm": "BM with latency",
                              "plm": "PLM-Net with latency"}[who] if k == 0 else None)
    ax.set_xticks(range(len(settings)), [setting_label(s) for s in settings], rotation=20)
    ax.set_ylabel("lateral-offset RMS over the whole track [m] (per pair)")
    ax.set_title("Lane keeping by latency: each point one trained pair (mean over simulator seeds)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    names.append(_save(fig, directory, "offset_rms.png", plt))
    return names


def _save(fig, directory: Path, name: str, plt) -> str:
    fig.tight_layout()
    save_figure_into(fig, directory / name)
    plt.close(fig)
    return name


# -------------------------------------------------------------------------------------------------
# report.md
# -------------------------------------------------------------------------------------------------


def _f(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def _ci(spread: dict | None, digits: int = 3, unit: str = "", short: bool = True) -> str:
    if spread is None:
        return "n/a"
    return interval_text(spread["mean"], spread["ci_low"], spread["ci_high"], spread["n"],
                         lambda value: _f(value, digits), unit, "pairs", short)


def _bare(spread: dict | None, digits: int = 3, unit: str = "") -> str:
    """The centre alone, or with its interval when there is one (the headline says once when there is none)."""
    if spread is None or spread["ci_low"] is None:
        return f"{_f(_mean(spread), digits)}{unit}"
    return _ci(spread, digits, unit)


def _pi(spread: dict | None, digits: int = 1) -> str:
    if spread is None:
        return "n/a"
    if spread["pi_low"] is None:
        return "no PI"
    return f"[{_f(spread['pi_low'], digits)}, {_f(spread['pi_high'], digits)}]"


def headline(document: dict) -> list[str]:
    """Three lines: the population's result in both metrics at the paper's headline latency, with the pair count,
    the conditions and the recipe."""
    per = document["per_setting"]
    setting = "const:0.25" if "const:0.25" in per else next(s for s in per if s != "const:0")
    entry = per[setting]
    n = len(document["pairs_driven"])
    shares = entry["shares"]
    plan = document["plan"]
    statistics = ("95% CIs over pairs" if n >= MIN_INTERVAL_VALUES
                  else f"{too_few('pairs')} (the 95% CIs need at least {MIN_INTERVAL_VALUES})")
    return [
        f"{n} independently trained BM/PLM-Net pairs (recipe `{plan['recipe']['name']}`), {plan['conditions']} "
        f"conditions{source_text(plan)}, {entry['label']} latency, whole test track, {len(plan['sim_seeds'])} simulator seeds each; "
        f"means over pairs, {statistics}:",
        f"steering MAE reduction {_bare(entry['mae_reduction_pct'], 1, '%')} (PLM-Net lower "
        f"in {shares['lower_mae']} of {shares['pairs']} pairs; the paper: "
        f"{_paper_reduction(setting)});",
        f"lateral-offset RMS {_bare(entry['plm_offset_rms_m'], 3, ' m')} with PLM-Net against "
        f"{_bare(entry['bm_offset_rms_m'], 3, ' m')} without (reference BM without latency "
        f"{_bare(entry['ref_offset_rms_m'], 3, ' m')}); PLM-Net lower in {shares['lower_offset_rms']} of "
        f"{shares['pairs']} pairs.",
    ]


def _paper_reduction(setting: str) -> str:
    numbers = analysis.paper_numbers(setting)
    return "not reported" if numbers is None else f"{numbers['reduction_pct']:.1f}%"


def render_report(document: dict, figures: list[str]) -> str:
    """report.md from population.json's content (nothing else)."""
    plan = document["plan"]
    recipe = plan["recipe"]
    per = document["per_setting"]
    lines = ["# PLM-Net across a population of trained pairs", ""]
    lines += ["**Result.** " + " ".join(headline(document)), ""]
    lines += ["## What was run", ""]
    quick = f" **Shrunk for a quick run ({recipe['overrides']}): not the recipe's numbers.**" if recipe["overrides"] else ""
    lines += [
        f"- Recipe `{recipe['name']}` for the `{plan['conditions']}` conditions, every pair the same, seeds aside "
        f"(pair k: data seed 1+k, BM and TAPM training seed k; pair 0 is the shipped pair's recipe and seeds).{quick}",
        f"  - data: `{_command(recipe, 'collect')}`",
        f"  - BM: `{_command(recipe, 'bm')}`",
        f"  - TAPM: `{_command(recipe, 'tapm')}`",
        f"- Pairs: {document['pairs_planned']} planned, {len(document['pairs_trained'])} trained, "
        f"{len(document['pairs_failed'])} failed"
        + ("" if not document["pairs_failed"] else " (" + "; ".join(
            f"{pair_name(int(p))}: {why}" for p, why in document["pairs_failed"].items()) + ")")
        + f", {len(document['pairs_driven'])} driven. No pair was dropped or chosen by its outcome.",
        f"- Closed loop: track `{plan['track']}`, settings {', '.join(setting_label(s) for s in plan['settings'])}, "
        f"simulator seeds {plan['sim_seeds']}"
        + (f", at most {plan['max_steps']} steps" if plan["max_steps"] else ", the whole scored track") + ".",
        f"- Command: `{document.get('command') or 'n/a'}`",
        "",
        "Every outcome is over the **whole scored track**: the steering MAE against the same pair's BM without latency "
        "(paper unit, 1 = 450 deg of steering wheel), each step missed after leaving the road counted as a full-scale "
        "error; the lateral offset from the lane centre with missed steps held at the offset the car left with; the "
        "Frechet distance to the reference's path. The common-span MAE (judged only until a run leaves the road, as "
        "the reproduction report does) is secondary. Statistics are over pairs (seeds averaged within a pair): means "
        "with 95% CIs on the quantity's scale (errors on the log scale, never below 0; reductions through the ratio "
        "PLM-Net / BM on the log scale, never above 100%), and the 95% prediction interval (PI) for "
        f"one new pair made with this recipe. With fewer than {MIN_INTERVAL_VALUES} pairs there are too few pairs for an "
        "interval: the tables then say \"no interval\" and \"no PI\".",
        "",
    ]
    lines += ["## Steering and lane keeping by latency", "",
              "| setting | BM MAE | PLM-Net MAE | MAE reduction % | PI for a new pair | common-span reduction % | "
              "offset RMS ref / BM / PLM-Net [m] | offset max BM / PLM-Net [m] | Frechet BM / PLM-Net [m] | "
              "left the road BM / PLM-Net (runs) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for e in per.values():
        lines.append(
            f"| {e['label']} | {_ci(e['bm_steering_mae_paper'])} | {_ci(e['plm_steering_mae_paper'])} | "
            f"{_ci(e['mae_reduction_pct'], 1)} | {_pi(e['mae_reduction_pct'])} | {_ci(e['mae_common_reduction_pct'], 1)} | "
            f"{_f(_mean(e['ref_offset_rms_m']))} / {_ci(e['bm_offset_rms_m'])} / {_ci(e['plm_offset_rms_m'])} | "
            f"{_f(_mean(e['bm_offset_max_m']), 2)} / {_f(_mean(e['plm_offset_max_m']), 2)} | "
            f"{_f(_mean(e['bm_frechet_m']), 2)} / {_f(_mean(e['plm_frechet_m']), 2)} | "
            f"{e['bm_left_road']} / {e['plm_left_road']} of {e['runs_per_policy']} |")
    lines += ["", "At 0 s the BM is its own reference (MAE 0) and PLM-Net's row shows what mitigation costs when nothing "
              "is late.", ""]
    lines += ["## Does PLM-Net lower the error, pair by pair?", "",
              "| setting | pairs | PLM-Net lowers the steering MAE | PLM-Net lowers the offset RMS | offset RMS "
              "reduction % (PI) | between-pair / within-pair SD of PLM-Net's offset RMS [m] |",
              "|---|---|---|---|---|---|"]
    for setting, e in per.items():
        if setting == "const:0":
            continue
        s, v = e["shares"], e["variance"]["plm_offset_rms_m"]
        lines.append(f"| {e['label']} | {s['pairs']} | {s['lower_mae']} | {s['lower_offset_rms']} | "
                     f"{_ci(e['offset_rms_reduction_pct'], 1)} {_pi(e['offset_rms_reduction_pct'])} | "
                     f"{_f(v['between_pairs_sd'])} / {_f(v['within_pair_sd'])} |")
    lines += ["", "## The paper's MAE reductions", "",
              f"A pair is comparable at a setting when its BM's whole-track MAE lies within "
              f"{analysis.COMPARABLE_BM_RATIO[0]}-{analysis.COMPARABLE_BM_RATIO[1]}x the paper's BM MAE there and its BM "
              f"stayed on the road in every seed. *reproduced*: the paper's reduction lies inside the comparable pairs' "
              f"95% prediction interval; *not testable*: fewer than {analysis.MIN_COMPARABLE_PAIRS} comparable pairs; "
              "otherwise ours lie above or below it.", "",
              "| setting | the paper: BM MAE / PLM-Net MAE / reduction | our BMs' MAE / the paper's, per pair | "
              "comparable pairs | their reduction % (PI) | verdict |", "|---|---|---|---|---|---|"]
    for v in document["verdicts"]:
        p = v["paper"]
        ratios = ", ".join(f"{r:.2f}" for r in v["bm_ratio_to_paper"])
        lines.append(f"| {setting_label(v['setting'])} | {p['bm_mae']:.4f} / {p['plm_mae']:.4f} / "
                     f"{p['reduction_pct']:.1f}% | {ratios} | {v['comparable_pairs']} of {v['pairs']} | "
                     f"{_ci(v['reduction'], 1)} {_pi(v['reduction'])} | **{v['verdict']}** |")
    fit = document["error_fit"]
    if fit is not None:
        lines += ["", f"PLM-Net's whole-track MAE against the BM's, least squares over pairs and constant latencies "
                  f"({fit['points']} points): slope {fit['slope']:.3f} +- {fit['slope_se']:.3f}, intercept "
                  f"{fit['intercept']:.4f} +- {fit['intercept_se']:.4f}, r = {fit['r']:.2f} (errors are standard "
                  "errors). A slope below 1 means mitigation removes a share of the BM's error that does not shrink as "
                  "the BM gets worse; it is the number to compare, not a reduction whose denominator is the BM's "
                  "error."]
    lines += drift_section(document.get("drift"))
    lines += remedy_section(document.get("remedies", {}))
    lines += ["", "## Figures", ""]
    captions = {"errors.png": "PLM-Net's error against its BM's error, one point per pair and latency; hollow: the "
                              "paper's five points",
                "reductions.png": "Reductions per pair: steering MAE (stars: the paper) and lateral-offset RMS",
                "offset_rms.png": "Lateral-offset RMS per pair by latency: reference, BM, PLM-Net",
                "drift.png": "Why the drift: lateral-offset and heading feedback of the reference BM and of PLM-Net"}
    for name in figures:
        lines += [f"![{captions.get(name, name)}]({name})", ""]
    lines += ["## Per pair", "", "| pair | setting | BM MAE | PLM-Net MAE | reduction % | offset RMS ref / BM / PLM-Net "
              "[m] | left the road BM / PLM-Net (seeds) |", "|---|---|---|---|---|---|---|"]
    for s in document["pair_summaries"]:
        lines.append(f"| {pair_name(s['pair'])} | {setting_label(s['setting'])} | {_f(s['bm_steering_mae_paper'], 4)} | "
                     f"{_f(s['plm_steering_mae_paper'], 4)} | {_f(s['mae_reduction_pct'], 1)} | "
                     f"{_f(s['ref_offset_rms_m'])} / {_f(s['bm_offset_rms_m'])} / {_f(s['plm_offset_rms_m'])} | "
                     f"{s['bm_left_road_seeds']} / {s['plm_left_road_seeds']} |")
    trainings = document.get("trainings", {})
    if trainings:
        lines += trainings_section(plan, trainings, document.get("stages", {}))
    return "\n".join(lines) + "\n"


TRAINING_STAGES = (("collect", "collect"), ("bm_training", "BM"), ("tapm_training", "TAPM"))


def trainings_section(plan: dict, trainings: dict, stages: dict) -> list[str]:
    """Each pair's seeds, validation losses and where its time went: wall minutes per stage (CPU minutes of the
    training in brackets) and the 1-minute load average over the training."""
    lines = ["", "## Trainings", "",
             "Wall minutes per stage; training total with its CPU minutes in brackets (2 threads at full use give "
             "twice the wall time); the load is the 1-minute load average from the start to the end of the "
             "training. Driving is every run of the pair on the stated workers.", "",
             "| pair | data seed | BM / TAPM seed | BM val. loss | TAPM val. loss | collect | BM | TAPM | training "
             "(CPU) | load | driving (workers) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    seeds_of = {p["pair"]: p for p in plan["pairs"]}
    for pair_text, t in trainings.items():
        seeds = seeds_of[int(pair_text)]
        summary = t.get("summary", {})
        status = "" if t.get("ok") else " (failed)"
        times = summary.get("stages", {})
        cells = [_minutes(times.get(stage, {}).get("wall_s")) for stage, _ in TRAINING_STAGES]
        cpu_s = sum(times[stage]["cpu_s"] for stage, _ in TRAINING_STAGES if stage in times) if times else None
        loads = [times[stage][key] for stage, _ in TRAINING_STAGES if stage in times
                 for key in ("load_start", "load_end") if times[stage].get(key) is not None]
        load = f"{min(loads):.1f}-{max(loads):.1f}" if loads else "n/a"
        driving = stages.get(pair_text, {})
        drive_s = driving.get("driving", {}).get("wall_s")
        # under a second: the runs were on record from an earlier, interrupted run (nothing was timed)
        drive = (f"{_minutes(drive_s)} ({driving.get('workers', 'n/a')})" if drive_s is not None
                 and drive_s >= UNTIMED_DRIVE_S else "n/a")
        lines.append(f"| {pair_name(int(pair_text))}{status} | {seeds['data_seed']} | {seeds['bm_seed']} / "
                     f"{seeds['tapm_seed']} | {_f(summary.get('bm_best_val_loss'), 4)} | "
                     f"{_f(summary.get('tapm_best_val_loss'), 4)} | {' | '.join(cells)} | "
                     f"{_minutes(summary.get('seconds'))} ({_minutes(cpu_s)}) | {load} | {drive} |")
    return lines


UNTIMED_DRIVE_S = 1.0  # a pair's driving "took" less: its runs were all on record, nothing was driven or timed


def _minutes(seconds) -> str:
    return "n/a" if seconds is None else f"{seconds / 60:.1f}"


def remedy_section(remedies: dict) -> list[str]:
    lines = []
    for name, result in remedies.items():
        lines += ["", f"## Remedy `{name}`", "", f"{REMEDIES[name]}. Each pair keeps its BM; the remedy's TAPM is "
                  "trained with the pair's recipe and seed. Differences are paired: the remedy's PLM-Net minus the "
                  "pair's own, per pair (seed means), mean and 95% CI over pairs.", "",
                  "| setting | pairs | PLM-Net MAE: own / remedy | difference | offset RMS [m]: own / remedy | "
                  "difference [m] | left the road own / remedy (runs) |", "|---|---|---|---|---|---|---|"]
        for setting, e in result["settings"].items():
            lines.append(f"| {setting_label(setting)} | {e['pairs']} | {_f(e['own_mae'], 4)} / "
                         f"{_f(e['remedy_mae'], 4)} | {_ci(e['mae_difference'], 4)} | {_f(e['own_offset_rms_m'])} / "
                         f"{_f(e['remedy_offset_rms_m'])} | {_ci(e['offset_rms_difference_m'])} | "
                         f"{e['own_left_road']} / {e['remedy_left_road']} |")
        lines += ["", f"**Decision: {result['decision']}** ({result['decision_rule']})."]
    return lines


def drift_section(drift: dict | None) -> list[str]:
    if drift is None:
        return []
    lines = ["", "## Why the car drifts while the steering follows", "",
             f"The lateral offset of every run split at {drift['cutoff_hz']:g} Hz (zero-phase low-pass): the slow part "
             "(swings longer than 4 s) and the fast part (the weave a late camera causes). Posed gains: the car placed "
             "on the longest straight at offsets of -1..1 m or heading errors of -0.04..0.04 rad, each policy steering "
             "from that one frame; PLM-Net's slope over its own BM's (means over pairs, range in brackets).", "",
             "| setting | slow offset RMS ref / BM / PLM-Net [m] | fast offset RMS ref / BM / PLM-Net [m] | "
             "offset gain PLM-Net / BM | heading gain PLM-Net / BM |", "|---|---|---|---|---|"]
    for setting, e in drift["settings"].items():
        gains = "n/a | n/a"
        if e.get("plm_over_bm_offset_gain_per_m_range"):
            low, high = e["plm_over_bm_offset_gain_per_m_range"]
            h_low, h_high = e["plm_over_bm_heading_gain_per_rad_range"]
            gains = (f"{_f(e['plm_over_bm_offset_gain_per_m'], 2)} [{_f(low, 2)}, {_f(high, 2)}] | "
                     f"{_f(e['plm_over_bm_heading_gain_per_rad'], 2)} [{_f(h_low, 2)}, {_f(h_high, 2)}]")
        lines.append(f"| {setting_label(setting)} | {_f(e['ref_slow_rms_m'])} / {_f(e['bm_slow_rms_m'])} / "
                     f"{_f(e['plm_slow_rms_m'])} | {_f(e['ref_fast_rms_m'])} / {_f(e['bm_fast_rms_m'])} / "
                     f"{_f(e['plm_fast_rms_m'])} | {gains} |")
    fit = drift.get("gain_explains_drift")
    if fit is not None:
        lines += ["", f"Across pairs and constant latencies ({fit['points']} points), log(PLM-Net's slow offset RMS "
                  f"over the reference's) against log(BM offset gain over PLM-Net's): slope {fit['slope']:.2f}, "
                  f"r = {fit['r']:.2f}. A slope near 1 with a high r means the slow drift grows as the offset gain "
                  "shrinks, as a loop held by its offset gain alone would."]
    return lines


def _mean(spread: dict | None) -> float | None:
    return None if spread is None else spread["mean"]


def _command(recipe: dict, which: str) -> str:
    r = Recipe.from_dict(recipe)
    return r.collect_command(1) if which == "collect" else r.train_command(which, 0)


def _as_written(rows: list[dict]) -> list[dict]:
    """``rows`` as results.csv will hold them (floats to its digits), so that population.json's statistics are
    exactly those a reader recomputes from the published results.csv."""
    return [{key: (_parse(format_cell(value)) if isinstance(value, float) and key in RESULT_COLUMNS else value)
             for key, value in row.items()} for row in rows]


def read_results(path: Path) -> list[dict]:
    """results.csv back as rows (numbers as floats, booleans as bool, empty as None)."""
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        return [{key: _parse(value) for key, value in row.items()} for row in reader]


def _parse(text: str):
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        number = float(text)
    except ValueError:
        return text
    return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() else number


__all__ = ["POPULATION_REPORT", "RESULT_COLUMNS", "analyse", "headline", "publish_report", "read_results",
           "render_report", "result_rows", "setting_tag"]
