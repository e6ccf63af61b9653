"""A diagnosis rendered: its printed summary (where the recording departs, the physics named, how much of the
error it explains, the runner-up, what is left) and its documented JSON. The pipeline is
:mod:`plm_highway.sim2real.diagnose`; this module computes nothing it does not state."""

from __future__ import annotations

import math

from plm_highway.io import json_safe
from plm_highway.sim2real.diagnosis import (
    EXCITATION_NOISE_FACTOR,
    PARTLY_EXPLAINED_BELOW,
    SIGNAL_CHANGE,
    STRUCTURE_MATTERS_BELOW,
    Diagnosis,
)
from plm_highway.sim2real.fit.problem import CandidateFit
from plm_highway.sim2real.fit.selection import Selection
from plm_highway.sim2real.physics.effects import EFFECT_NAMES, SPECS, separating_text
from plm_highway.sim2real.physics.replay import FitSignal
from plm_highway.sim2real.residual.discovery import Discovery, removed_words


def _band_label(row: dict, unit: str) -> str:
    lo, hi = row["range"]
    return f"> {lo:g} {unit}" if hi is None else f"{lo:g}-{hi:g} {unit}"


def where_text(conditions: dict, windows: list[list[float]], duration_s: float, noise: float,
               signal: str = "yaw rate") -> str:
    covered = sum(b - a for a, b in windows)
    parts = [(f"the {signal} error exceeds twice the noise in {len(windows)} stretch(es) covering "
             f"{100 * covered / max(duration_s, 1e-9):.0f}% of the run")]
    contrasts = []
    for key, unit, name in (("speed_mps", "m/s", "at speeds"), ("abs_lat_accel_mps2", "m/s^2", "at |lateral accel|"),
                            ("steer_freq_hz", "Hz", "with steering at")):
        rows = [r for r in conditions[key] if r["fraction"] >= 0.03]
        if len(rows) < 2:
            continue
        worst = max(rows, key=lambda r: r["rmse_before"])
        best = min(rows, key=lambda r: r["rmse_before"])
        ratio = worst["rmse_before"] / max(best["rmse_before"], 1e-12)
        contrasts.append((ratio, (f"{name} {_band_label(worst, unit)} ({worst['rmse_before'] / max(noise, 1e-12):.1f}x "
                                 f"noise vs {best['rmse_before'] / max(noise, 1e-12):.1f}x at "
                                 f"{_band_label(best, unit)})")))
    sides = {r["side"]: r for r in conditions["direction"]}
    if "left" in sides and "right" in sides:
        left, right = sides["left"]["rmse_before"], sides["right"]["rmse_before"]
        if max(left, right) > 1.3 * min(left, right):
            contrasts.append((max(left, right) / max(min(left, right), 1e-12),
                              (f"in {'left' if left > right else 'right'} turns "
                              f"({max(left, right) / max(noise, 1e-12):.1f}x noise vs "
                              f"{min(left, right) / max(noise, 1e-12):.1f}x)")))
    contrasts.sort(reverse=True)
    strong = [text for ratio, text in contrasts if ratio > 1.3][:2]
    if strong:
        parts.append("it is largest " + " and ".join(strong))
    return "; ".join(parts)


def effect_sentence(name: str, params: dict, ci: dict) -> str:
    return SPECS[name].sentence(params, ci)


def tie_text(winner: tuple[str, ...], runner_up: tuple[str, ...]) -> str:
    """What drive would separate two explanations a recording cannot tell apart."""
    hints = [separating_text(a, b) for a in set(winner) - set(runner_up) for b in set(runner_up) - set(winner)]
    hints = [h for h in dict.fromkeys(hints) if h]
    return f" ({'; '.join(hints)})" if hints else ""


def runner_up_text(sel: Selection, unit: str) -> str:
    """Winner against runner-up with the margin's sign and its bootstrap spread."""
    r, w = sel.runner_up, sel.winner
    lo, hi = sel.margin_ci
    spread = f"95% {100 * lo:+.1f} to {100 * hi:+.1f}%" if math.isfinite(lo) else "no spread"
    head = f"Runner-up: {r.name} (held-out RMSE {r.heldout_rmse:.4f} {unit})"
    if math.isfinite(lo) and lo <= 0 <= hi:
        return (f"{head}: penalised score {100 * sel.margin:+.1f}% against {w.name} ({spread}), inside the bootstrap "
                f"spread: this recording cannot tell them apart{tie_text(w.effects, r.effects)}.")
    if sel.margin >= 0:
        return f"{head}: penalised score {100 * sel.margin:.1f}% worse ({spread})."
    why = (f"it does not beat the plain model consistently enough ({sel.reason})" if not w.effects
           else f"its extra term does not improve consistently on {w.name}")
    return f"{head}: scores {100 * -sel.margin:.1f}% better than {w.name} ({spread}) but is not chosen: {why}."


def _change(before: float, after: float) -> float:
    return after / before - 1.0 if before > 0 and math.isfinite(before) and math.isfinite(after) else math.nan


def signals_text(fit: dict) -> tuple[str, list[str], list[str]]:
    """Held-out error change of every signal; which improve and which worsen."""
    parts, better, worse = [], [], []
    rows = [(name, c["rmse_before"], c["rmse_after"], c["unit"]) for name, c in fit["channels"].items()]
    rows += [("re-anchored heading", fit["heading_rmse_before_rad"], fit["heading_rmse_after_rad"], "rad"),
             ("re-anchored position", fit["position_rmse_before_m"], fit["position_rmse_after_m"], "m")]
    for name, before, after, unit in rows:
        change = _change(before, after)
        if not math.isfinite(change):
            continue
        label = name.replace("_", " ")
        parts.append(f"{label} {before:.4g} -> {after:.4g} {unit} ({100 * change:+.0f}%)")
        if change < -SIGNAL_CHANGE:
            better.append(label)
        elif change > SIGNAL_CHANGE:
            worse.append(f"{label} ({100 * change:+.0f}%)")
    return "; ".join(parts), better, worse


def scored_text(data: dict) -> str:
    return (f"{data['scored_s']:.1f} s ({100 * data['scored_fraction']:.0f}%) of the {data['duration_s']:.1f} s "
            "recording are scored")


def summary_text(d: Diagnosis) -> str:
    sel = d.selection
    fit = d.fit
    unit = d.signal.unit
    label = d.signal.label
    lines = []
    if d.data.get("low_confidence_reasons"):
        lines.append(f"Low confidence: only {scored_text(d.data)} ({'; '.join(d.data['low_confidence_reasons'])}).")
    if d.data.get("unchecked_consistency"):
        lines.append("Low confidence: the recording could not be checked against itself for "
                     + "; ".join(d.data["unchecked_consistency"])
                     + ", so a flipped sign or a wrong unit in those channels would read as physics.")
    if d.verdict == "unexcited":
        lines.append(f"Unexcited: '{d.recording.name}' cannot show steering-path physics: the steering moves the "
                     f"model's {label} by {d.data['model_signal_rms']:.4g} {unit} RMS and the car's {label} varies by "
                     f"{d.data['recorded_signal_rms']:.4g} {unit}, both within {EXCITATION_NOISE_FACTOR:g} x the noise "
                     f"({fit['noise_sigma']:.4g}). Record turns, weaves or lane changes.")
        return "\n".join(lines)
    if d.verdict in ("match", "inconclusive"):
        if d.verdict == "match":
            lines.append(f"No significant mismatch: the simulator's model reproduces '{d.recording.name}' within its "
                         f"measurement noise (held-out {label} RMSE {fit['rmse_before']:.4f} {unit}, noise "
                         f"{fit['noise_sigma']:.4f} {unit}; "
                         + ("the replay reproduces the recording to the digits it was written with)."
                            if d.data.get("reproduced") else "residual white)."))
        else:
            lines.append(f"Inconclusive: no candidate beats the simulator's model on '{d.recording.name}', but "
                         f"{d.data['inconclusive_because']}, so this is not a match (held-out {label} RMSE "
                         f"{fit['rmse_before']:.4f} {unit}, noise estimate {fit['noise_sigma']:.4f}).")
        alt = sel.best if sel.best.effects else sel.runner_up
        lines.append(f"Best alternative: {alt.name} (held-out RMSE {alt.heldout_rmse:.4f} {unit}); {sel.reason}.")
        return "\n".join(lines)
    if d.verdict == "unexplained":
        left = d.residual
        lines.append(f"Unexplained: '{d.recording.name}' departs from the simulator "
                     f"({where_text(d.conditions, d.windows, d.recording.duration_s, fit['noise_sigma'], label)}), "
                     f"but nothing in the library explains it: held-out {label} RMSE {fit['rmse_before']:.4f} {unit} "
                     f"is {fit['rmse_before'] / max(fit['noise_sigma'], 1e-12):.1f}x the noise "
                     f"({fit['noise_sigma']:.4f}) and not white{_correlates(left)}.")
        if d.data.get("steering_flat"):
            lines.append(f"The recorded steering barely varies (std {d.data['steer_std_rad']:.2g} rad) while the car "
                         "turns: check the steer column (and --steer-scale for simulator logs).")
        alt = sel.best if sel.best.effects else sel.runner_up
        lines.append(f"Best alternative: {alt.name} (held-out RMSE {alt.heldout_rmse:.4f} {unit}); {sel.reason}.")
        return "\n".join(lines)
    effects = sel.winner.effects
    sentences = [effect_sentence(e, sel.winner.estimates[e], sel.winner.ci95[e]) for e in effects]
    name = " + ".join(e.replace("_", " ") for e in effects)
    article = "a " if len(effects) == 1 else ""
    lines += [
        f"'{d.recording.name}' departs from the simulator: "
        f"{where_text(d.conditions, d.windows, d.recording.duration_s, fit['noise_sigma'], label)}.",
        "Missing physics: " + "; ".join(sentences) + ".",
        (f"On held-out data {article}{name} explains {100 * fit['explained_fraction']:.0f}% of the {label} error "
         f"above the noise: RMSE {fit['rmse_before']:.4f} -> {fit['rmse_after']:.4f} {unit} "
         f"({100 * (fit['rmse_after'] / fit['rmse_before'] - 1):+.0f}%; noise {fit['noise_sigma']:.4f}); "
         f"heading {fit['heading_rmse_before_rad']:.4f} -> {fit['heading_rmse_after_rad']:.4f} rad, position "
         f"{fit['position_rmse_before_m']:.3f} -> {fit['position_rmse_after_m']:.3f} m (re-anchored every "
         f"{d.anchor_s:g} s)."),
    ]
    text, better, worse = signals_text(fit)
    if len(fit["channels"]) > 1:
        lines.append(f"Every signal, held out: {text}.")
    if worse and better:
        lines.append(f"Mixed: the fit improves {', '.join(better)} but worsens {', '.join(worse)}; the recorded signals "
                     "disagree about this physics (a sensor issue, or physics outside the library).")
    lines.append(runner_up_text(sel, unit))
    if d.verdict == "mismatch" and d.data.get("structure_within_accuracy"):
        lines.append(f"What is left is not quite white noise ({d.residual['rmse'] / max(fit['noise_sigma'], 1e-12):.2f}x "
                     f"the noise, Ljung-Box p = {d.residual['whiteness']['p_value']:.2g}) but is under "
                     f"{100 * (1 - STRUCTURE_MATTERS_BELOW):.0f}% of the error above the noise: within the replay's "
                     "accuracy.")
    if d.verdict == "partly explained" and d.data.get("position_worse"):
        lines.append(f"Partly explained: {name} fits the {label} but moves the car the wrong way (re-anchored position "
                     f"{fit['position_rmse_before_m']:.3f} -> {fit['position_rmse_after_m']:.3f} m): a yaw-plane term "
                     "standing in for physics it cannot represent (road bank or grade, a sensor mounted askew, "
                     "something outside the library); do not read its parameters as the car's.")
    elif d.verdict == "partly explained":
        left = d.residual
        why = (f"only {100 * fit['explained_fraction']:.0f}% of the error above the noise is explained"
               if fit["explained_fraction"] < PARTLY_EXPLAINED_BELOW else
               f"the remaining {label} error is {left['rmse'] / max(fit['noise_sigma'], 1e-12):.1f}x the noise")
        white = left["whiteness"]
        lines.append(f"Partly explained: {why} and what is left is not white noise (Ljung-Box p = "
                     f"{white['p_value']:.2g}){_correlates(left)}; physics outside the library remains"
                     + (" (or, close to the noise, the interpolation of the irregular rows' steering onto the "
                        "uniform grid the model runs on)." if d.recording.raw is not None else "."))
    return "\n".join(lines)


def discovery_text(disc: Discovery, signal: FitSignal) -> str:
    """Residual discovery in words: what entered (and what it gains held out), what is doubtful, what not."""
    unit = signal.unit
    lines = []
    for f in disc.named:
        lines.append(f"Discovered outside the library: {f.sentence}. Held out on {f.validation}, it removes "
                     f"{100 * f.removed_fraction:.0f}% of the {signal.label} error above the noise left by "
                     f"{disc.base.name if f is disc.found[0] else 'the model before it'}: RMSE "
                     f"{math.sqrt(f.mse_before):.4f} -> {math.sqrt(f.mse_after):.4f} {unit} (t = {f.t_statistic:.1f}).")
    for f in disc.doubtful:
        lines.append(f"Doubtful, not named: {f.sentence} ({'; '.join(f.doubts)}); held out it "
                     f"{removed_words(f.removed_fraction, would=True)} of the {signal.label} error above the noise.")
    if not disc.named:
        tried = sorted(disc.tried, key=lambda t: t.score_ratio)
        best = f"; the best, {tried[0].name.replace('_', ' ')}: {tried[0].why}" if tried else ""
        lines.append(f"Residual discovery: no {'plausible ' if disc.doubtful else ''}term outside the library "
                     f"improves held-out data clearly ({len(tried)} tried{best}).")
    if disc.not_tried:
        lines.append("Not tried: " + "; ".join(f"{k.replace('_', ' ')} ({v})" for k, v in disc.not_tried.items())
                     + ".")
    return "\n".join(lines)


def discovery_json(disc: Discovery) -> dict:
    def found(f):
        return {"name": f.name, "sentence": f.sentence, "params": f.estimates, "ci": f.ci95,
                "validation": f.validation, "rmse_before": math.sqrt(f.mse_before), "rmse_after": math.sqrt(f.mse_after),
                "removed_fraction": f.removed_fraction, "t_statistic": f.t_statistic, "plausible": f.plausible,
                "doubts": f.doubts}
    return {"base": disc.base.name, "found": [found(f) for f in disc.named],
            "doubtful": [found(f) for f in disc.doubtful],
            "tried": [{"name": t.name, "score_ratio": t.score_ratio, "entered": t.entered, "why": t.why}
                      for t in disc.tried],
            "not_tried": disc.not_tried, "noise_sigma": disc.noise_sigma}


def _correlates(residual: dict) -> str:
    named = [c for c in residual["correlations"] if c["significant"]][:3]
    if not named:
        return ""
    return "; it correlates with " + ", ".join(f"{c['with']} (rho = {c['rho']:+.2f})" for c in named)


# ----------------------------------------------------------------------------------------------
# The diagnosis


def _candidate_json(c: CandidateFit) -> dict:
    return {"name": c.name, "effects": list(c.effects), "params": c.estimates, "ci": c.ci95,
            "rmse_heldout": c.heldout_rmse, "rmse_train": math.sqrt(c.train_mse), "dof": c.dof, "score": c.score,
            "rmse_heldout_by_signal": {k: math.sqrt(v) for k, v in c.channel_mse.items()}}


def to_json(d: Diagnosis) -> dict:
    """The diagnosis as the documented JSON (effect names and parameter keys are fixed; no NaN)."""
    rec = d.recording
    recording = {"name": rec.name, "duration_s": rec.duration_s, "sample_hz": 1.0 / rec.dt_s,
                 "vehicle": rec.vehicle.sidecar() | {"source": rec.vehicle.source},
                 "yaw_inertia_assumed": not rec.vehicle.inertia_known}
    if d.verdict == "inconsistent":
        return json_safe({"verdict": d.verdict, "confidence": d.confidence, "effects": [],
                          "consistency": d.consistency.to_json(), "summary": d.summary, "recording": recording,
                          "warnings": list(rec.warnings) + list(d.notes), "effect_names": list(EFFECT_NAMES)})
    sel = d.selection
    winner = sel.winner
    named = (d.library_verdict or d.verdict) in ("mismatch", "partly explained")
    effects = [{"name": e, "params": winner.estimates[e], "ci": winner.ci95[e]} for e in winner.effects] if named \
        else []
    runner = _candidate_json(sel.runner_up)
    runner["margin"] = sel.margin
    runner["margin_ci95"] = list(sel.margin_ci)
    return json_safe({
        "verdict": d.verdict,
        "library_verdict": d.library_verdict or d.verdict,
        "confidence": d.confidence,
        "effects": effects,
        "discovery": discovery_json(d.discovery) if d.discovery is not None else None,
        "runner_up": runner,
        "fit": d.fit,
        "residual": d.residual,
        "data": d.data,
        "windows": d.windows,
        "conditions": d.conditions,
        "reason": sel.reason,
        "summary": d.summary,
        "candidates": [_candidate_json(c) for c in sel.ranking],
        "recording": recording,
        "checks": d.checks,
        "consistency": d.consistency.to_json() if d.consistency is not None else None,
        "warnings": list(rec.warnings) + list(d.notes),
        "effect_names": list(EFFECT_NAMES),
    })
