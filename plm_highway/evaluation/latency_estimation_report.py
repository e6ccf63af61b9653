"""The latency-estimation report: ``results.json`` and, rendered from it alone, ``report.md`` and its figures.

:func:`render_markdown` takes the results dict (:meth:`~plm_highway.evaluation.latency_estimation.Results.as_json`)
and nothing else, so a report can be checked against its results file (``tests/test_latency_estimation.py``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from plm_highway.io import directory_kind, json_text, pyplot, save_figure_into, write_output
from plm_highway.metrics.intervals import MIN_INTERVAL_VALUES, interval_text, too_few

LATENCY_REPORT = directory_kind("latency-estimation-report", "a plm-highway latency-estimation report directory")
FIGURES = ("traces.png", "mitigation.png")
ROLE_LABELS = {"estimated": "PLM-Net told the estimate", "baseline": "Base Model (unmitigated)",
               "reference": "Base Model, no latency", "true": "PLM-Net told the true latency"}
VARIANT_LABELS = {"dropped": "20% of lane measurements dropped", "jitter": "latency jittering +-10 ms per frame",
                  "drift": "the car's clock 1% fast", "recording": "a recording without capture timestamps",
                  "probe": "a steering probe"}


def _kept(fraction) -> str:
    """The share of the true latency's MAE reduction kept with the estimate ("-" where there was none to keep)."""
    return "-" if fraction is None or not math.isfinite(fraction) else f"{100 * fraction:.0f}%"


def _mean(interval, scale: float = 1.0, digits: int = 2, unit: str = "") -> str:
    """``mean unit [low, high]`` (the interval as summarised: not symmetric off the linear scale), or without an
    interval (fewer than 3 seeds) ``mean unit (n=2, no interval)``; "-" where there is no mean."""
    if not interval or interval.get("mean") is None or not math.isfinite(interval["mean"]):
        return "-"
    low, high = (None if interval.get(end) is None else interval[end] * scale for end in ("low", "high"))
    return interval_text(interval["mean"] * scale, low, high, interval.get("n", 0),
                         lambda value: f"{value:.{digits}f}", unit, short=True)


def _pct(interval) -> str:
    return _mean(interval, 100.0, 0, "%")


def _setting(setting: str) -> str:
    return setting.replace("const:", "") + (" s" if setting.startswith("const:") else "")


def estimation_rows(results: dict, role: str, variant: str = "", constants: bool = True) -> list[str]:
    rows = []
    for e in results["estimation"]:
        if e["role"] != role or e["variant"] != variant or e["setting"].startswith("const:") != constants:
            continue
        n = len(e["seeds"])
        lock = _mean(e["lock_s"], 1.0, 1, " s") if e["locked"] == n else \
            f"{_mean(e['lock_s'], 1.0, 1, ' s')} ({e['locked']} of {n} locked)"
        row = [e["conditions"], e["track"], _setting(e["setting"]), f"{1000 * e['frame_s']:.0f} ms", lock,
               f"{e['locked_within_budget']} of {n}", _pct(e["estimable_fraction"]),
               _pct(e["wrong_when_estimable_fraction"]), _pct(e["within_after_first_fraction"]),
               _mean(e["median_error_after_first_s"], 1000.0, 0, " ms")]
        if not constants and "steps" in e:
            row += [_pct(e["steps"]["recovered_within_budget_fraction"]), _pct(e["steps"]["within_fraction"])]
        rows.append("| " + " | ".join(row) + " |")
    return rows


def _claims(summary: dict) -> str:
    """``wrong of claims (share)`` pooled over a group's runs, or "no claim"."""
    if not summary or not summary.get("claims"):
        return "no claim"
    return f"{summary['wrong_claims']} of {summary['claims']} ({100 * summary['wrong_claims_fraction']:.1f}%)"


def _first_claim(summary: dict) -> str:
    if not summary or not summary.get("claimed_runs"):
        return "never"
    text = _mean(summary["first_claim_s"], 1.0, 1, " s")
    return text if summary["claimed_runs"] == summary["runs"] else \
        f"{text}, {summary['claimed_runs']} of {summary['runs']} runs claimed"


def steps_text(steps: dict | None) -> str:
    """A claim-step count as "handled of judged (unseen)"; "-" where no step was judged."""
    if not steps or not steps["steps_judged"]:
        return "-"
    unseen = steps.get("unanswered_not_estimable", 0)
    return f"{steps['handled']} of {steps['steps_judged']}" + (f" ({unseen} unseen)" if unseen else "")


def _steps(summary: dict) -> str:
    return steps_text((summary or {}).get("claim_steps"))


def claims_rows(results: dict) -> list[str]:
    """One row per group of runs: the estimator's claims beside the baseline's, on the same runs."""
    rows = []
    for e in results["estimation"]:
        scaled, published = (e.get("baselines", {}).get(name, {}) for name in ("scaled", "published"))
        label = ROLE_LABELS[e["role"]] + (f", {VARIANT_LABELS[e['variant']]}" if e["variant"] else "")
        rows.append("| " + " | ".join([
            e["conditions"], e["track"], f"`{e['setting']}`", label, _first_claim(e), _claims(e),
            _pct(e.get("changing_fraction")), _steps(e), _first_claim(scaled), _claims(scaled), _steps(scaled),
            _claims(published)]) + " |")
    return rows


def render_markdown(results: dict) -> str:
    """The report, from the results dict alone."""
    suite = results["suite"]
    met = sum(target["met"] for target in results["targets"])
    lines = [
        "# Perception latency estimated from the stream",
        "",
        "The latency estimator (`plm_highway/latency/estimate.py`) finds how late the camera is from the data "
        "stream alone: it aligns the lane offset and heading the late camera reports "
        "(`plm_highway/lane_ekf/lane_camera.py`, on the frame the car got) with what the car's own fast sensors "
        "(yaw rate, speed, wheel angle) and the lane model say at candidate lags, with no capture timestamp. It "
        "answers with an estimate, its standard deviation, and \"not estimable yet\" when the driving carried too "
        "little information. PLM-Net interpolates by the estimate; the EKF re-stamps each camera measurement by it.",
        "",
        f"Made by `{results['command']}`. Conditions {', '.join(suite['conditions'])}; tracks "
        f"{', '.join(suite['tracks'])}; seeds {', '.join(str(s) for s in suite['seeds'])}; "
        + (f"each run the scored track's first {suite['duration_s']:g} s; " if suite.get("duration_s") else
           "each run the whole scored track; ")
        + "the tolerance is one "
        "frame period of the loop (50 ms at the ideal conditions' 20 Hz, 33 ms at the paper conditions' 30 Hz); the "
        "truth is the age of the frame the car got. Numbers are means over seeds [a 95% Student-t interval]: "
        "times, errors, MAEs and RMSs on the log scale (never below 0), MAE reductions on the scale of the ratio "
        "mitigated / baseline (never above 100%), shares on the linear scale within 0-100%; with fewer than "
        f"{MIN_INTERVAL_VALUES} seeds, {too_few()} (no interval). PLM-Net and the Base Model are "
        + (f"the checkpoints in `{results['checkpoints']}`" if results.get("checkpoints", "shipped") != "shipped"
           else "the shipped checkpoints of each conditions' preset")
        + ": one trained BM/TAPM pair per preset, so the intervals are over simulator seeds, not over trainings "
        "(`plm-highway population` judges PLM-Net across pairs).",
        "",
        f"## Targets: {met} of {len(results['targets'])} met",
        "",
        "| target | met | measured |",
        "|---|---|---|",
    ]
    lines += [f"| {t['target']} | {'met' if t['met'] else '**missed**'} | {t['detail']} |" for t in results["targets"]]
    rules = results.get("claim_rules", {})
    lines += ["", "## Claims, beside a deployed method's", "",
              "A *claim* is a tick at which the estimator says \"estimated\": its interval (+-2 standard deviations) "
              "lies within a frame of the estimate, no far lag fits nearly as well, the estimate has held within half "
              f"a frame for the last {rules.get('settle_s', math.nan):g} s, and neither the window nor its newest "
              "samples contradict it. Otherwise it says \"changing\" (the latency has just stepped, or the newest samples disagree with the last claim) "
              "or \"not estimable\" (too little information), and a consumer keeps the last claimed value or the "
              "prior. *Wrong*: more than a frame off the true age. Claims are pooled over the seeds' runs. *Steps "
              "handled*: of the steps of two frames or more followed by at least 1 s of the new latency, those after "
              "which no wrong claim was made from 1 s on and the new value was claimed within 5 s or \"changing\" "
              f"said until then; steps in a run's first {rules.get('step_blind_s', 0.0):g} s are not judged (the "
              "camera's first frames grow from age 0 to the latency while the estimators wait for a history as long as their largest lag). "
              "*Unseen*: of the steps not handled, those met with \"not estimable\" at every tick from the step to "
              "the 5 s budget: no claim to withdraw, and too little information in the driving to see the latency "
              "move (still counted as not handled).", "",
              "The baseline is openpilot's online lateral-lag method (`plm_highway/latency/correlation.py`, written "
              "from its published description: masked normalised cross-correlation of the car's lateral acceleration "
              "from its fast sensors with the one implied by the camera's lane heading, validity gating, block "
              "averaging, a spread check), fed the stream each run's estimator got. With its published durations "
              "(60 s window, 25 s of valid samples, 5 blocks of 100 window estimates at 4 Hz) it cannot claim before "
              "150 s of valid driving, five times a run; *scaled*: every duration divided by "
              f"{results.get('baseline_time_scale', 10):g}, so that it may claim from 15 s on.", "",
              "| conditions | track | latency | runs | first claim | wrong claims | changing | steps handled | "
              "baseline, scaled: first claim | wrong claims | steps handled | baseline, published: wrong claims |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|",
              *claims_rows(results)]
    header = ("| conditions | track | latency | frame | time to lock | locked within 2 s | estimable | wrong when "
              "estimable | within a frame after the first estimate | median error after it |")
    rule = "|---|---|---|---|---|---|---|---|---|---|"
    lines += ["", "## Constant latencies", "",
              "Time to lock: from the run's start to the first estimate that is estimable and within one frame of the "
              "truth (the estimator waits for one second of history first). *Wrong when estimable*: the share of the "
              "estimable ticks whose estimate was more than a frame off.", "",
              "### PLM-Net driven by the estimate (the closed loop the estimate serves)", "", header, rule,
              *estimation_rows(results, "estimated"),
              "", "### The unmitigated Base Model (a car that weaves under latency)", "", header, rule,
              *estimation_rows(results, "baseline")]
    lines += ["", "## Time-varying latencies", "",
              "After each change of the true latency by at least half a frame: the share of changes after which the "
              "estimate PLM-Net used was back within a frame within 1 s, and the share of all ticks within a frame.",
              "", header + " recovered within 1 s | within a frame |", rule + "---|---|",
              *estimation_rows(results, "estimated", constants=False),
              "", "The unmitigated Base Model under the same profiles:", "", header + " recovered within 1 s | "
              "within a frame |", rule + "---|---|", *estimation_rows(results, "baseline", constants=False)]
    lines += ["", "## Not estimable instead of wrong", ""]
    synthetic = results.get("synthetic", {})
    if synthetic:
        quiet, weave = synthetic.get("straight_without_steering"), synthetic.get("straight_with_weave")
        lines.append(f"A synthetic minute on a straight (`plm_highway/latency/synthetic.py`, 20 Hz, latency 0.25 s, "
                     f"lane noise 0.02 m and 0.003 rad): without steering the estimate was estimable on "
                     f"{100 * quiet['estimable_fraction']:.1f}% of {quiet['ticks']} ticks ({quiet['wrong_when_estimable']}"
                     f" wrong); with a 0.02 rad weave at 0.5 Hz on {100 * weave['estimable_fraction']:.0f}% "
                     f"({weave['wrong_when_estimable']} wrong), ending at {weave['final_held_s']:.3f} s.")
    quiet_rows = [e for e in results["estimation"] if e["quiet_ticks"] and not e["variant"]]
    ticks = sum(e["quiet_ticks"] for e in quiet_rows)
    if ticks:
        claimed = sum(e["estimable_when_quiet_fraction"] * e["quiet_ticks"] for e in quiet_rows) / ticks
        wrong = sum(e["wrong_when_quiet_fraction"] * e["quiet_ticks"] for e in quiet_rows) / ticks
        lines.append("")
        lines.append(f"In the closed-loop runs, {ticks} ticks came after 3 s in which the car's yaw rate varied by less "
                     f"than 0.003 rad/s (standard deviation): an estimate was claimed on {100 * claimed:.1f}% of them, "
                     f"a wrong one (more than a frame off) on {100 * wrong:.1f}%.")
    lines += ["", "## Robustness", "",
              f"Setting `{suite['robustness_setting']}` on the `{suite['robustness_track']}` track, PLM-Net driven by "
              "the estimate. *A steering probe*: a known excitation of "
              f"{1000 * results.get('probe', {}).get('probe_rad', math.nan):.0f} mrad at the front wheels (two tones, "
              f"{' s and '.join(f'{p:g}' for p in results.get('probe', {}).get('probe_periods_s', ()))} s) added to "
              "PLM-Net's commands, so that the car moves relative to its lane; also driven under "
              f"{', '.join(f'`{s}`' for s in suite.get('probe_settings', ()))}; the offset RMS beside it is the price "
              "(the same runs without the probe and with PLM-Net told the true latency are in the tables above and "
              "below).", "", "| conditions | variant | time to lock | locked within 2 s | estimable | wrong when "
              "estimable | within a frame after the first estimate | median error after it | more |",
              "|---|---|---|---|---|---|---|---|---|"]
    for e in results["estimation"]:
        if not e["variant"]:
            continue
        n = len(e["seeds"])
        more = ""
        if "stamped_error_final_s" in e and e["stamped_error_final_s"]:
            more = (f"a capture timestamp on a camera clock drifting 1% would be "
                    f"{_mean(e['stamped_error_final_s'], 1000.0, 0, ' ms')} off by the run's end")
        if e.get("steps"):
            more = f"within a frame {_pct(e['steps']['within_fraction'])} of the ticks"
        if e.get("recording"):
            agree = min(r["agrees_with_online_fraction"] for r in e["recording"])
            largest_s = max(r.get("max_difference_from_online_s", math.nan) for r in e["recording"])
            more = (f"read back from the file and estimated offline: within 1 ms of the online estimate on "
                    f"{100 * agree:.0f}% of the ticks (worst seed; largest difference {1e6 * largest_s:.0f} us)")
        if e["variant"] == "probe":
            more = "; ".join(part for part in (more, f"offset RMS {_mean(e.get('offset_rms_m'), 1, 3, ' m')}") if part)
        label = VARIANT_LABELS[e["variant"]]
        if e["setting"] != suite["robustness_setting"]:
            label += f", `{e['setting']}`"
        lines.append(f"| {e['conditions']} | {label} | {_mean(e['lock_s'], 1.0, 1, ' s')} | "
                     f"{e['locked_within_budget']} of {n} | {_pct(e['estimable_fraction'])} | "
                     f"{_pct(e['wrong_when_estimable_fraction'])} | {_pct(e['within_after_first_fraction'])} | "
                     f"{_mean(e['median_error_after_first_s'], 1000.0, 0, ' ms')} | {more} |")
    lines += ["", "## Mitigation with the estimate against mitigation with the true latency", "",
              "Steering MAE against the Base Model without latency (normalised steering, over the steps both runs "
              "reached); the reduction is from the unmitigated Base Model's; *true*: PLM-Net told the conditions' own "
              "latency (ideal: the frame's measured age; paper: the requested latency, as the original).", "",
              "| conditions | track | latency | BM MAE | PLM-Net MAE, true | PLM-Net MAE, estimate | reduction, true | "
              "reduction, estimate | kept | offset RMS true / estimate [m] | ratio | left the road true / estimate |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in results["mitigation"]:
        n = len(m["per_seed"])
        lines.append(f"| {m['conditions']} | {m['track']} | {_setting(m['setting'])} | {_mean(m['mae_baseline'], 1, 4)} | "
                     f"{_mean(m['mae_true'], 1, 4)} | {_mean(m['mae_estimated'], 1, 4)} | "
                     f"{_mean(m['reduction_true_pct'], 1, 1, '%')} | {_mean(m['reduction_estimated_pct'], 1, 1, '%')} | "
                     f"{_kept(m['kept_reduction_fraction'])} | {_mean(m['offset_rms_true_m'], 1, 3)} / "
                     f"{_mean(m['offset_rms_estimated_m'], 1, 3)} | {m['offset_rms_ratio']:.2f} | "
                     f"{m['left_road_true']} / {m['left_road_estimated']} of {n} |")
    if results.get("ekf"):
        lines += ["", "## The EKF re-stamping by the estimate (seed paper 004's Table 3 scenarios)", "",
                  "The delay-compensated lane EKF of `plm-highway estimate table3`, fed the same sensor data twice: "
                  "each camera measurement re-stamped at its known capture time, and at its arrival minus the latency "
                  "estimated from the stream (window 6 s: this camera delivers about 3 measurements a second). RMSE of "
                  "d [m], mean over the seeds:", "",
                  "| camera delay | scenario | known stamps | estimated latency | ratio | first estimable [s] | after it: "
                  "known / estimated | latency used / true [s] |",
                  "|---|---|---|---|---|---|---|---|"]
        for delay in sorted({row["delay"] for row in results["ekf"]}):
            for scenario in sorted({row["scenario"] for row in results["ekf"]}):
                rows = [row for row in results["ekf"] if row["delay"] == delay and row["scenario"] == scenario]
                known = sum(row["d_rmse_known_m"] for row in rows) / len(rows)
                estimated = sum(row["d_rmse_estimated_m"] for row in rows) / len(rows)
                used = sum(row["mean_used_latency_s"] for row in rows) / len(rows)
                true = sum(row["mean_true_delay_s"] for row in rows) / len(rows)
                first = [row["first_estimable_s"] for row in rows if math.isfinite(row["first_estimable_s"])]
                after = [row for row in rows if math.isfinite(row["d_rmse_estimated_after_lock_m"])]
                after_text = (f"{sum(r['d_rmse_known_after_lock_m'] for r in after) / len(after):.4f} / "
                              f"{sum(r['d_rmse_estimated_after_lock_m'] for r in after) / len(after):.4f}"
                              if after else "-")
                first_text = f"{sum(first) / len(first):.1f} ({len(first)} of {len(rows)})" if first else "never"
                lines.append(f"| `{delay}` | {scenario} | {known:.4f} | {estimated:.4f} | {estimated / known:.2f} | "
                             f"{first_text} | {after_text} | {used:.3f} / {true:.3f} |")
    tie_in = results.get("sim2real", {})
    if tie_in:
        lines += ["", "## sim2real: the camera's delay beside the vehicle's", "",
                  "`plm-highway sim2real diagnose` replays a recording's steering and finds the physics the simulator "
                  "leaves out, delays included (`plm_highway/sim2real/`); where the recording also carries what the "
                  "camera reported about the lane (columns `lane_offset`, `lane_heading`), its report now adds the "
                  "perception delay the latency estimator finds (`plm_highway/sim2real/perception_delay.py`).", ""]
        for key in ("real", "simulated"):
            if key not in tie_in:
                continue
            entry = tie_in[key]
            found = entry["perception_delay"]
            delays = ", ".join(f"{name} {value:.3f} s" for name, value in entry["diagnosis_delays_s"].items()) or "none"
            camera = (f"{found['latency_s']:.3f} s ± {found['std_s']:.3f} s"
                      + ("" if found.get("claimed", True) else " (its newest sure estimate, never claimed)")
                      if found.get("estimated") else f"not estimated: {found['reason']}")
            lines.append(f"- **{entry['recording']}** ({'real' if key == 'real' else 'simulated'}): diagnosis "
                         f"`{entry['verdict']}`, its delays: {delays}; the camera's perception delay: {camera}.")
            if key == "simulated":
                truth = entry["true_vehicle_delays"]
                lines.append(f"  The truth: the camera {entry['true_camera_latency_s']:.3f} s late; on the vehicle "
                             f"side {truth['processing_delay_s']:.3f} s of processing and a "
                             f"{truth['steering_time_constant_s']:g} s steering actuator.")
    lines += ["", "## Figures", "", "![estimate against the true latency](traces.png)", "",
              "![mitigation with the estimate and with the true latency](mitigation.png)", ""]
    return "\n".join(lines) + "\n"


def traces_figure(results: dict, plt):
    traces = results["traces"]
    wanted = [t for t in traces if t["spec"]["role"] == "estimated" and not t["spec"]["variant"]
              and t["spec"]["track"] == results["suite"]["tracks"][0]
              and t["spec"]["latency"] in ("const:0.05", "const:0.25", *results["suite"]["profiles"])]
    wanted.sort(key=lambda t: (t["spec"]["conditions"], t["spec"]["latency"]))
    if not wanted:
        fig, ax = plt.subplots(figsize=(8, 2))
        ax.text(0.5, 0.5, "no traces", ha="center")
        return fig
    fig, axes = plt.subplots(len(wanted), 1, figsize=(11, 2.2 * len(wanted)), sharex=False, squeeze=False)
    for ax, trace in zip(axes[:, 0], wanted):
        t = trace["t_s"]
        ax.plot(t, trace["observation_age_s"], color="black", lw=1.5, label="true age of the frame")
        ax.plot(t, trace["latency_estimate_s"], color="tab:blue", lw=1.0, label="estimate PLM-Net used")
        estimable = [v > 0.5 for v in trace["latency_estimable"]]
        ax.plot([x for x, e in zip(t, estimable) if e],
                [v for v, e in zip(trace["latency_estimate_s"], estimable) if e], ".", color="tab:green", ms=2,
                label="estimable")
        spec = trace["spec"]
        ax.set_title(f"{spec['conditions']}, {spec['track']} track, {spec['latency']}, seed {spec['seed']}", fontsize=9)
        ax.set_ylabel("latency [s]")
        ax.set_ylim(-0.02, max(0.8, max(trace["observation_age_s"]) + 0.05))
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    return fig


def mitigation_figure(results: dict, plt):
    rows = results["mitigation"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    labels = [f"{m['conditions']}\n{m['track']}\n{_setting(m['setting'])}" for m in rows]
    x = range(len(rows))
    for ax, (key_true, key_est, ylabel) in zip(axes, (("reduction_true_pct", "reduction_estimated_pct",
                                                        "steering-MAE reduction [%]"),
                                                       ("offset_rms_true_m", "offset_rms_estimated_m",
                                                        "lateral offset RMS [m]"))):
        ax.bar([i - 0.2 for i in x], [m[key_true]["mean"] for m in rows], 0.4, label="told the true latency")
        ax.bar([i + 0.2 for i in x], [m[key_est]["mean"] for m in rows], 0.4, label="told the estimate")
        ax.set_xticks(list(x))
        ax.set_xticklabels(labels, fontsize=7)
        ax.set_ylabel(ylabel)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def write_latency_report(results: dict, out: str | os.PathLike, overwrite: bool = False) -> list[Path]:
    """``results.json``, ``report.md`` (from the results alone) and the figures, published together."""

    plt = pyplot()
    with write_output(out, LATENCY_REPORT, overwrite=overwrite) as staged:
        (staged / "results.json").write_text(json_text(results), encoding="utf-8")
        (staged / "report.md").write_text(render_markdown(results), encoding="utf-8")
        for name, make in zip(FIGURES, (traces_figure, mitigation_figure)):
            fig = make(results, plt)
            try:
                save_figure_into(fig, staged / name, dpi=110)
            finally:
                plt.close(fig)
    return [Path(out) / name for name in ("results.json", "report.md", *FIGURES)]
