"""Figures and a text summary of a diagnosis, written into a report directory.

``overlay.png``     a held-out excerpt: recorded vs plain vs fitted signal, residuals, heading error
``residuals.png``   the whole run: residual before/after with the mismatch windows shaded
``conditions.png``  residual RMS before/after by speed, |lateral acceleration|, steering frequency, side
``candidates.png``  held-out RMSE of every candidate against the noise level
``summary.md``      the plain-language summary and the numbers

``discovered_<term>.png``  each term residual discovery found (named or doubtful): its shape against
                    what the data say on their own (binned estimates with standard errors)

A recording that contradicts itself (verdict ``inconsistent``) gets ``consistency.png`` instead of
the four figures: each pair of channels that should agree, over the whole run.

Every file is written to a temporary name in the same directory and renamed into place.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from plm_highway.io import directory_kind, file_kind, json_text, save_figure_into, write_output, write_outputs
from plm_highway.sim2real.diagnosis import Diagnosis
from plm_highway.sim2real.record.consistency import channel_rates
from plm_highway.sim2real.rendering import to_json
from plm_highway.sim2real.residual.discovery import removed_words
from plm_highway.sim2real.residual.shapes import shape_data

NAMED = ("mismatch", "partly explained")

FIGURES = ("overlay.png", "residuals.png", "conditions.png", "candidates.png")


def _pyplot():
    # lazy: matplotlib only when a figure is drawn
    import matplotlib

    if os.environ.get("MPLBACKEND") is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 10, "axes.titlesize": 11, "axes.labelsize": 10, "legend.fontsize": 9})
    return plt


SIM2REAL_REPORT = directory_kind("sim2real-report", "a plm-highway sim2real report directory")


def _save(fig, path: Path) -> None:
    save_figure_into(fig, path, dpi=120, bbox_inches="tight")


def _excerpt(d: Diagnosis, length_s: float = 20.0) -> slice:
    """The held-out stretch of ``length_s`` where the chosen model gains most over the plain one
    (on a match: where the plain model is worst). Gains, not raw errors, so that a glitch in the
    recording that no model explains does not take the picture."""
    t = d.recording.t_s
    n = len(t)
    width = max(2, min(n, round(length_s / d.recording.dt_s)))
    before = np.nan_to_num(d.signal.values - d.before)
    after = np.nan_to_num(d.signal.values - d.after)
    sq_error_drop = before**2 - after**2 if d.library_verdict in NAMED else before**2
    csum = np.concatenate([[0.0], np.cumsum(np.where(d.heldout, sq_error_drop, 0.0))])
    scores = csum[width:] - csum[:-width]
    start = int(np.argmax(scores)) if scores.size else 0
    return slice(start, min(start + width, n))


def _label(d: Diagnosis) -> tuple[str, str]:
    if d.signal.name == "yaw_rate":
        return "yaw rate [rad/s]", "recorded yaw rate"
    return f"heading rate [{d.signal.unit}]", "recorded heading rate (smoothed derivative)"


def overlay_figure(d: Diagnosis, plt):
    sl = _excerpt(d)
    t = d.recording.t_s[sl]
    ylabel, rec_label = _label(d)
    after_name = d.selection.winner.name if d.library_verdict in NAMED else d.selection.best.name
    after = d.after if d.library_verdict in NAMED else d.best
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    ax = axes[0]
    ax.plot(t, d.signal.values[sl], color="0.3", lw=1.0, label=rec_label)
    ax.plot(t, d.before[sl], color="tab:red", lw=1.2, label="simulator (plain kinematic bicycle)")
    ax.plot(t, after[sl], color="tab:blue", lw=1.2, ls="--", label=f"simulator + {after_name}")
    ax.set_ylabel(ylabel)
    what = "the fitted term matters most" if d.library_verdict in NAMED else "the simulator is worst"
    ax.set_title(f"{d.recording.name} ({d.verdict}): held-out excerpt where {what}")
    ax.legend(loc="upper right")
    ax = axes[1]
    ax.plot(t, (d.signal.values - d.before)[sl], color="tab:red", lw=1.0, label="residual, plain")
    ax.plot(t, (d.signal.values - after)[sl], color="tab:blue", lw=1.0, label=f"residual, + {after_name}")
    ax.axhspan(-2 * d.noise_sigma, 2 * d.noise_sigma, color="0.85", label="+-2 x noise")
    ax.set_ylabel(f"recorded - model [{d.signal.unit}]")
    ax.legend(loc="upper right")
    ax = axes[2]
    ax.plot(t, d.pose_before.heading_error_rad[sl], color="tab:red", lw=1.0, label="plain")
    ax.plot(t, d.pose_after.heading_error_rad[sl], color="tab:blue", lw=1.0,
            label=f"+ {d.selection.winner.name}" if d.library_verdict in NAMED else "chosen model (plain)")
    ax.set_ylabel(f"heading error [rad]\n(re-anchored every {d.anchor_s:g} s)")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def residuals_figure(d: Diagnosis, plt):
    t = d.recording.t_s
    usable = d.signal.usable
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), gridspec_kw={"height_ratios": [2, 1]})
    ax = axes[0]
    for i, (a, b) in enumerate(d.windows):
        ax.axvspan(a, b, color="gold", alpha=0.35, lw=0, label="mismatch window (1-s RMS > 2 x noise)" if i == 0
                   else None)
    ax.plot(t[usable], (d.signal.values - d.before)[usable], color="tab:red", lw=0.6, label="plain")
    ax.plot(t[usable], (d.signal.values - d.after)[usable], color="tab:blue", lw=0.6,
            label=f"+ {d.selection.winner.name}" if d.library_verdict in NAMED else "chosen model (plain)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"recorded - model [{d.signal.unit}]")
    ax.set_title("Residuals over the whole run")
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3)
    ax = axes[1]
    held = d.heldout
    lim = float(np.percentile(np.abs(d.signal.values - d.before)[usable], 99.5)) or 1.0
    bins = np.linspace(-lim, lim, 61)
    ax.hist((d.signal.values - d.before)[held], bins=bins, color="tab:red", alpha=0.5, label="plain (held out)")
    ax.hist((d.signal.values - d.after)[held], bins=bins, color="tab:blue", alpha=0.5, label="chosen (held out)")
    ax.set_xlabel(f"residual [{d.signal.unit}]")
    ax.set_ylabel("samples")
    ax.legend(loc="upper right")
    fig.tight_layout()
    return fig


def conditions_figure(d: Diagnosis, plt):
    groups = (("speed_mps", "speed [m/s]"), ("abs_lat_accel_mps2", "|lateral accel| [m/s^2]"),
              ("steer_freq_hz", "steering frequency [Hz]"), ("direction", "side"))
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.8), sharey=True)
    for ax, (key, title) in zip(axes, groups):
        rows = d.conditions[key]
        if key == "direction":
            labels = [r["side"] for r in rows]
        else:
            labels = [f">{r['range'][0]:g}" if r["range"][1] is None else f"{r['range'][0]:g}-{r['range'][1]:g}"
                      for r in rows]
        x = np.arange(len(rows))
        ax.bar(x - 0.2, [r["rmse_before"] for r in rows], 0.4, color="tab:red", label="plain")
        ax.bar(x + 0.2, [r["rmse_after"] for r in rows], 0.4, color="tab:blue", label="chosen model")
        ax.axhline(d.noise_sigma, color="0.3", ls=":", label="noise")
        ax.set_xticks(x, labels, rotation=30)
        ax.set_xlabel(title)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_ylabel(f"residual RMS [{d.signal.unit}]")
    axes[0].legend(loc="upper left")
    fig.suptitle("Where the simulator departs from the recording (all usable samples)")
    fig.tight_layout()
    return fig


def candidates_figure(d: Diagnosis, plt):
    ranking = d.selection.ranking
    fig, ax = plt.subplots(figsize=(8, 0.32 * len(ranking) + 1.5))
    names = [c.name + ("" if c.polished else " (grid)") for c in ranking][::-1]
    values = [c.heldout_rmse for c in ranking][::-1]
    colors = ["tab:blue" if c is d.selection.winner else ("tab:orange" if c is d.selection.runner_up else "0.6")
              for c in ranking][::-1]
    ax.barh(names, values, color=colors)
    ax.axvline(d.noise_sigma, color="0.2", ls=":", label=f"noise {d.noise_sigma:.4f}")
    ax.set_xlabel(f"held-out {d.signal.label} RMSE [{d.signal.unit}] (chosen: blue, runner-up: orange; "
                  "(grid): screened out unpolished)")
    ax.set_title("Candidates, best penalised score at the top")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    return fig


def consistency_figure(d: Diagnosis, plt):
    """Each relation the consistency checks measure, over time: what one channel says against another."""
    rec = d.recording
    rates = channel_rates(rec, d.consistency.window_s)  # the window the checks compared over
    checks = {c.name: c for c in d.consistency.checks}
    t = rec.t_s
    v = rec.vehicle
    steered = rates.through_filter(rec.speed_mps * np.sin(np.arctan(v.cg_to_rear_m / v.wheelbase_m
                                                                    * np.tan(rec.steer_rad))) / v.cg_to_rear_m, rec.dt_s)
    gyro = rates.through_filter(rec.yaw_rate_radps, rec.dt_s) if rec.yaw_rate_radps is not None else None
    lat = rates.through_filter(rec.lat_accel_mps2, rec.dt_s) if rec.lat_accel_mps2 is not None else None
    panels = [
        ("speed_vs_position", "speed [m/s]", [(rec.speed_mps, "speed column"),
                                             (rates.speed_from_position, "|d(x, y)/dt| from the positions")]),
        ("yaw_rate_vs_heading", "yaw rate [rad/s]", [(gyro, "yaw_rate column"),
                                                     (rates.heading_rate, "d(heading)/dt")]),
        ("heading_vs_course", "turn rate [rad/s]", [(rates.heading_rate, "d(heading)/dt"),
                                                    (rates.course_rate, "d(course)/dt from the positions")]),
        ("steer_vs_turning", "turn rate [rad/s]", [(rates.heading_rate, "d(heading)/dt"),
                                                   (steered, "the simulator's yaw rate from the steering")]),
    ]
    if rec.lat_accel_mps2 is not None:
        panels.append(("lat_accel_vs_turning", "lateral accel [m/s^2]",
                       [(lat, "lat_accel column"),
                        (rates.speed_from_position * rates.heading_rate, "|d(x, y)/dt| x d(heading)/dt")]))
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 2.3 * len(panels)), sharex=True)
    for ax, (name, ylabel, series) in zip(axes, panels):
        check = checks[name]
        for (values, label), color in zip(series, ("tab:red", "tab:blue")):
            if values is not None:
                ax.plot(t, np.where(rates.valid, values, np.nan), color=color, lw=0.8, label=label)
        ax.set_ylabel(ylabel)
        ax.set_title(f"{name.replace('_', ' ')}: {check.status} ({check.text})", fontsize=9)
        ax.legend(loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time as recorded [s]")
    fig.suptitle(f"{rec.name}: the recording against itself (turn rates over {d.consistency.window_s:g}-s windows)")
    fig.tight_layout()
    return fig


def discovery_figure(d: Diagnosis, found, plt):
    """A discovered term's shape against the data's own binned estimate (see :mod:`.shapes`)."""
    data = shape_data(d.problem, found)
    status = "discovered" if found.plausible else "doubtful"
    title = f"{d.recording.name}: {found.name.replace('_', ' ')} ({status}; held out it " \
            f"{removed_words(found.removed_fraction, would=not found.plausible)} of the error left above the noise)"
    if data["kind"] == "time":
        fig, (ax, hist) = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [3, 1]})
        t, delay, error, seen = data["t_s"], data["track_delay_s"], data["error_s"], data["visible"]
        width = min(30.0, t[-1] - t[0])
        density = np.convolve(seen.astype(float), np.ones(max(1, round(width / d.recording.dt_s))), mode="valid")
        start = t[int(np.argmax(density))] if density.size else t[0]
        sel = (t >= start) & (t <= start + width)
        shown = np.where(seen, delay, np.nan)
        ax.fill_between(t[sel], (shown - 1.96 * error)[sel], (shown + 1.96 * error)[sel], color="tab:blue", alpha=0.2,
                        lw=0, label="95% band")
        ax.plot(t[sel], delay[sel], color="0.75", lw=0.8, label="delay track (held where unseen)")
        ax.plot(t[sel], shown[sel], color="tab:blue", lw=1.2, label="delay track (where the steering shows it)")
        ax.axhline(data["base_delay_s"], color="tab:red", ls="--", lw=1.0, label="the library's constant delay")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("delay [s]")
        ax.legend(loc="upper right")
        ax.grid(alpha=0.3)
        hist.hist(delay[seen], bins=30, color="tab:blue", alpha=0.7, orientation="horizontal")
        hist.set_xlabel("samples")
        hist.set_ylabel("delay [s]")
    elif data["kind"] == "place":
        fig, (ax, plan) = plt.subplots(1, 2, figsize=(13, 4.5), gridspec_kw={"width_ratios": [3, 2]})
        bank = np.degrees(data["anchor_bank_rad"])
        error = np.degrees(1.96 * data["error_rad"])
        order = np.arange(bank.size)
        ax.errorbar(order * data["spacing_m"], bank, yerr=error, fmt="o", ms=3, color="tab:blue", ecolor="0.6",
                    label="bank at each place (95%)")
        curve = np.sign(data["curvature"]) * (np.abs(data["curvature"]) > 0.004)
        ax.fill_between(order * data["spacing_m"], np.where(curve > 0, bank.max(), np.nan), np.where(curve > 0,
                        bank.min(), np.nan), color="tab:green", alpha=0.15, lw=0, label="the track curves left")
        ax.set_xlabel("place along the track, in the order first reached [m]")
        ax.set_ylabel("bank [deg] (positive: falls to the left)")
        ax.legend(loc="upper right")
        ax.grid(alpha=0.3)
        plan.plot(data["x_m"], data["y_m"], color="0.8", lw=0.5)
        dots = plan.scatter(data["anchors_xy"][:, 0], data["anchors_xy"][:, 1], c=bank, cmap="coolwarm", s=25,
                            vmin=-max(abs(bank).max(), 1e-3), vmax=max(abs(bank).max(), 1e-3))
        fig.colorbar(dots, ax=plan, label="bank [deg]")
        plan.set_aspect("equal")
        plan.set_xlabel("x [m]")
        plan.set_ylabel("y [m]")
    else:
        fig, ax = plt.subplots(figsize=(9, 4.5))
        style = "." if found.name == "steering_backlash" else "-"
        ax.plot(data["curve_x"], data["curve_y"], style, color="tab:blue", lw=1.5, ms=1.5, label="discovered shape")
        ax.errorbar(data["x"], data["y"], yerr=2 * data["y_error"], fmt="o", color="tab:red", capsize=3,
                    label="the data, binned (+-2 s.e.)")
        ax.axhline(0.0, color="0.3", lw=0.8)
        if found.name == "steering_backlash":  # the play is crossed early: show a few plays' travel
            ax.set_xlim(0.0, min(float(np.max(data["curve_x"])), 6 * found.estimates["play_rad"]))
        ax.set_xlabel(data["xlabel"])
        ax.set_ylabel(data["ylabel"])
        ax.legend(loc="best")
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


DIAGNOSIS_JSON = file_kind("sim2real-diagnosis", "a sim2real diagnosis JSON file")


def write_report(d: Diagnosis, directory: str | os.PathLike, overwrite: bool = False) -> list[Path]:
    """Write the figures, summary and JSON as one report directory; returns the paths written."""
    with write_output(directory, SIM2REAL_REPORT, overwrite=overwrite) as staged:
        names = _write_report_files(d, staged)
    return [Path(directory) / name for name in names]


def publish_diagnosis(d: Diagnosis, data: dict, json_path=None, report_dir=None, overwrite: bool = False,
                      extra_lines: list[str] | tuple[str, ...] = ()) -> None:
    """The diagnosis JSON and/or the report directory, published together (``extra_lines``: more of the summary)."""
    targets = [(p, k) for p, k in ((json_path, DIAGNOSIS_JSON), (report_dir, SIM2REAL_REPORT)) if p]
    with write_outputs(targets, overwrite=overwrite) as staged:
        for (_, kind), path in zip(targets, staged):
            if kind is DIAGNOSIS_JSON:
                path.write_text(json_text(data, DIAGNOSIS_JSON, indent=1), encoding="utf-8")
            else:
                _write_report_files(d, path, extra_lines)


def _write_report_files(d: Diagnosis, directory: Path, extra_lines: list[str] | tuple[str, ...] = ()) -> list[str]:
    plt = _pyplot()
    if d.verdict == "inconsistent":
        fig = consistency_figure(d, plt)
        try:
            _save(fig, directory / "consistency.png")
        finally:
            plt.close(fig)
        lines = [f"# sim2real diagnosis: {d.recording.name}", "", d.summary, "", "## Consistency checks", "",
                 "| check | channels | status | measured |", "|---|---|---|---|"]
        lines += [f"| {c.name} | {', '.join(c.channels)} | {c.status} | {c.text} |" for c in d.consistency.checks]
        (directory / "summary.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
        (directory / "diagnosis.json").write_text(json_text(to_json(d), indent=1), encoding="utf-8")
        return ["consistency.png", "summary.md", "diagnosis.json"]
    written = []
    for name, make in zip(FIGURES, (overlay_figure, residuals_figure, conditions_figure, candidates_figure)):
        fig = make(d, plt)
        try:
            _save(fig, directory / name)
        finally:
            plt.close(fig)
        written.append(name)
    for found in d.discovery.found if d.discovery is not None else []:
        name = f"discovered_{found.name}.png"
        fig = discovery_figure(d, found, plt)
        try:
            _save(fig, directory / name)
        finally:
            plt.close(fig)
        written.append(name)
    data = to_json(d)
    lines = [f"# sim2real diagnosis: {d.recording.name}", "", d.summary, "", "## Numbers (held-out)", "",
             "| quantity | plain | chosen |", "|---|---|---|"]
    fit = d.fit
    lines += [f"| {name} RMSE [{c['unit']}] | {c['rmse_before']:.5f} | {c['rmse_after']:.5f} |"
              for name, c in fit["channels"].items()]
    lines += [f"| re-anchored heading RMSE [rad] | {fit['heading_rmse_before_rad']:.5f} | "
              f"{fit['heading_rmse_after_rad']:.5f} |",
              f"| re-anchored position RMSE [m] | {fit['position_rmse_before_m']:.4f} | "
              f"{fit['position_rmse_after_m']:.4f} |",
              "", f"Noise level: {fit['noise_sigma']:.5f} {d.signal.unit}. Verdict: **{d.verdict}** "
              f"(confidence {d.confidence}; {d.selection.reason}).",
              f"Scored: {d.data['scored_s']:.1f} s of {d.data['duration_s']:.1f} s "
              f"({100 * d.data['scored_fraction']:.0f}%); speed floor {d.data['speed_floor_mps']:.3g} m/s.", ""]
    if d.residual:
        white = d.residual["whiteness"]
        lines += ["## What is left", "",
                  f"Residual RMS {d.residual['rmse']:.5f} (excess variance over the noise "
                  f"{100 * d.residual['excess_variance_ratio']:.0f}%); Ljung-Box over {white['lags']} lags: "
                  f"p = {white['p_value']:.3g}.", "", "| correlates with | rho | 99% level |", "|---|---|---|"]
        lines += [f"| {c['with']} | {c['rho']:+.3f} | {c['significance']:.3f} |" for c in d.residual["correlations"]]
        lines.append("")
    if d.discovery is not None:
        disc = d.discovery
        lines += ["## Residual discovery", "", f"After the library's best chain ({disc.base.name}); library verdict "
                  f"**{d.library_verdict}**.", ""]
        lines += [f"- {'discovered' if f.plausible else 'doubtful'}: {f.sentence} (held out: {f.validation}; removes "
                  f"{100 * f.removed_fraction:.0f}% of the error above the noise; t = {f.t_statistic:.1f})"
                  + (f"; doubts: {'; '.join(f.doubts)}" if f.doubts else "") + f"; figure discovered_{f.name}.png"
                  for f in disc.found]
        lines += ["", "| term tried | held-out score change | entered | why |", "|---|---|---|---|"]
        lines += [f"| {t.name} | {100 * (t.score_ratio - 1):+.1f}% | {'yes' if t.entered else 'no'} | {t.why} |"
                  for t in disc.tried]
        lines += [f"| {k} | - | not tried | {v} |" for k, v in disc.not_tried.items()] + [""]
    if d.consistency is not None:
        lines += ["## The recording against itself", "", "| check | status | measured |", "|---|---|---|"]
        lines += [f"| {c.name} | {c.status} | {c.text} |" for c in d.consistency.checks]
        lines.append("")
    if d.recording.warnings or d.notes:
        lines += ["## Warnings", ""] + [f"- {w}" for w in list(d.recording.warnings) + d.notes] + [""]
    lines += ["## Candidates", "", "| candidate | held-out RMSE | parameters |", "|---|---|---|"]
    for c in d.selection.ranking:
        params = "; ".join(f"{k}={v:.5g}" for e in c.estimates.values() for k, v in e.items())
        lines.append(f"| {c.name} | {c.heldout_rmse:.5f} | {params} |")
    lines += ["", *extra_lines]
    (directory / "summary.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (directory / "diagnosis.json").write_text(json_text(data, indent=1), encoding="utf-8")
    return written + ["summary.md", "diagnosis.json"]
