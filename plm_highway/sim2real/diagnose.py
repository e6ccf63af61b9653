"""Diagnose a recording against the simulator: where it departs, which physics is missing, how much
the fitted term explains.

The steps, top to bottom (:func:`diagnose`):

1. Replay the recorded steering and speed through the simulator's model (yaw rate over the whole
   run; pose re-anchored every ``anchor_s``) and take residuals against the recording.
2. Estimate the measurement noise of the signal (high-frequency content of the residual).
3. Locate the mismatch in time (1-s RMS of the residual above twice the noise) and by operating
   condition (speed band, |lateral acceleration|, steering frequency, left/right/straight).
4. Fit every candidate effect and pair inside the model; pick one on held-out data with a
   complexity penalty (:mod:`plm_highway.sim2real.selection`).
5. Report held-out errors before and after (yaw rate, heading, position), the parameters with 95%
   intervals, the runner-up and margin, and a plain-language summary.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d

from plm_highway.sim2real.effects import EFFECT_NAMES, EffectParams
from plm_highway.sim2real.recording import Recording
from plm_highway.sim2real.replay import (
    ANCHOR_S,
    FitSignal,
    PoseReplay,
    filtered,
    fit_signal,
    model_yaw_rate,
    replay_pose,
    signal_noise_sigma,
    yaw_rate_lag_behind_heading,
)
from plm_highway.sim2real.selection import (
    CandidateFit,
    Selection,
    default_block_s,
    fit_candidates,
    make_problem,
    select,
)

WINDOW_RMS_S = 1.0
WINDOW_NOISE_FACTOR = 2.0
WINDOW_MIN_S = 0.5
WINDOW_MERGE_S = 1.0

SPEED_BANDS_MPS = (0.0, 10.0, 15.0, 20.0, 25.0, 30.0, math.inf)
LAT_ACCEL_BANDS_MPS2 = (0.0, 1.0, 2.0, 4.0, math.inf)
STEER_FREQ_BANDS_HZ = (0.0, 0.1, 0.3, 0.6, math.inf)
STRAIGHT_LAT_ACCEL_MPS2 = 0.5
CHANNEL_LAG_MIN_S = 0.06


@dataclass
class Diagnosis:
    recording: Recording
    signal: FitSignal
    noise_sigma: float
    selection: Selection
    block_s: float
    anchor_s: float
    heldout: np.ndarray
    before: np.ndarray  # the fit signal as the plain model predicts it
    after: np.ndarray  # ... as the chosen model predicts it (held-out samples: out of fold)
    best: np.ndarray  # ... as the best-scoring candidate predicts it (== after on a mismatch)
    pose_before: PoseReplay
    pose_after: PoseReplay
    windows: list[list[float]]
    conditions: dict
    fit: dict
    summary: str
    checks: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # caveats found by the diagnosis itself

    @property
    def verdict(self) -> str:
        return self.selection.verdict


# ----------------------------------------------------------------------------------------------
# Locating


def mismatch_windows(t_s: np.ndarray, residual: np.ndarray, usable: np.ndarray, noise_sigma: float,
                     rms_s: float = WINDOW_RMS_S, factor: float = WINDOW_NOISE_FACTOR,
                     min_s: float = WINDOW_MIN_S, merge_s: float = WINDOW_MERGE_S) -> list[list[float]]:
    """Stretches where the ``rms_s`` running RMS of the residual exceeds ``factor`` x the noise."""
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    size = max(1, round(rms_s / dt))
    w = usable.astype(float)
    mean_sq = uniform_filter1d(np.where(usable, residual, 0.0) ** 2, size) / np.maximum(uniform_filter1d(w, size),
                                                                                        1e-12)
    above = (np.sqrt(np.maximum(mean_sq, 0.0)) > factor * noise_sigma) & usable
    edges = np.diff(np.concatenate([[0], above.astype(int), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    windows: list[list[float]] = []
    for s, e in zip(starts, stops):
        t0, t1 = float(t_s[s]), float(t_s[e])
        if windows and t0 - windows[-1][1] <= merge_s:
            windows[-1][1] = t1
        else:
            windows.append([t0, t1])
    return [[round(a, 3), round(b, 3)] for a, b in windows if b - a >= min_s]


def steering_frequency_hz(t_s: np.ndarray, steer_rad: np.ndarray, window_s: float = 3.0,
                          smooth_s: float = 0.3, steady_rad: float = 0.002) -> np.ndarray:
    """Local dominant steering frequency: rms(steer rate) / (2 pi rms(steer - local mean)).

    Exact for a sinusoid. The steering is first smoothed over ``smooth_s`` so that sensor jitter
    does not read as fast steering, and stretches whose steering varies by less than
    ``steady_rad`` (held turns, straights) read as 0 Hz.
    """
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    steer = uniform_filter1d(steer_rad, max(1, round(smooth_s / dt)))
    size = max(3, round(window_s / dt))
    mean = uniform_filter1d(steer, size)
    spread = np.sqrt(np.maximum(uniform_filter1d((steer - mean) ** 2, size), 0.0))
    rate_rms = np.sqrt(uniform_filter1d(np.gradient(steer, dt) ** 2, size))
    freq = rate_rms / (2 * math.pi * np.maximum(spread, 1e-12))
    return np.where(spread < steady_rad, 0.0, freq)


def _band_rows(values: np.ndarray, bands: tuple[float, ...], before: np.ndarray, after: np.ndarray,
               usable: np.ndarray) -> list[dict]:
    rows = []
    total = max(int(usable.sum()), 1)
    for lo, hi in itertools.pairwise(bands):
        sel = usable & (values >= lo) & (values < hi)
        n = int(sel.sum())
        if n < 10:
            continue
        rows.append({"range": [lo, None if math.isinf(hi) else hi], "fraction": round(n / total, 4),
                     "rmse_before": float(np.sqrt(np.mean(before[sel] ** 2))),
                     "rmse_after": float(np.sqrt(np.mean(after[sel] ** 2))), "n": n})
    return rows


def operating_conditions(recording: Recording, signal: FitSignal, res_before: np.ndarray, res_after: np.ndarray
                         ) -> dict:
    """Residual RMS before and after, per speed band, |lateral acceleration|, steering frequency, side."""
    usable = signal.usable
    if recording.lat_accel_mps2 is not None:
        lat = recording.lat_accel_mps2
    else:
        lat = recording.speed_mps * signal.values
    freq = steering_frequency_hz(recording.t_s, recording.steer_rad)
    direction = []
    total = max(int(usable.sum()), 1)
    for label, sel in (("left", lat > STRAIGHT_LAT_ACCEL_MPS2), ("right", lat < -STRAIGHT_LAT_ACCEL_MPS2),
                       ("straight", np.abs(lat) <= STRAIGHT_LAT_ACCEL_MPS2)):
        sel = sel & usable
        n = int(sel.sum())
        if n < 10:
            continue
        direction.append({"side": label, "fraction": round(n / total, 4),
                          "rmse_before": float(np.sqrt(np.mean(res_before[sel] ** 2))),
                          "rmse_after": float(np.sqrt(np.mean(res_after[sel] ** 2))), "n": n})
    return {
        "speed_mps": _band_rows(recording.speed_mps, SPEED_BANDS_MPS, res_before, res_after, usable),
        "abs_lat_accel_mps2": _band_rows(np.abs(lat), LAT_ACCEL_BANDS_MPS2, res_before, res_after, usable),
        "steer_freq_hz": _band_rows(freq, STEER_FREQ_BANDS_HZ, res_before, res_after, usable),
        "direction": direction,
        "lat_accel_source": "recorded" if recording.lat_accel_mps2 is not None else "speed x yaw rate",
    }


# ----------------------------------------------------------------------------------------------
# Words


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


def _pm(ci: list[float]) -> float:
    return 0.5 * (ci[1] - ci[0])


def effect_sentence(name: str, params: dict, ci: dict) -> str:
    if name == "transport_delay":
        return f"the car steers late by {params['delay_s']:.3f} s +- {_pm(ci['delay_s']):.3f} s (transport delay)"
    if name == "actuator_lag":
        return (f"the steering follows the command like a first-order actuator with time constant "
                f"{params['time_constant_s']:.3f} s +- {_pm(ci['time_constant_s']):.3f} s")
    if name == "tire_slip":
        k = params["understeer_gradient_rad_per_mps2"]
        text = (f"the tires slip: understeer gradient {k:.5f} +- {_pm(ci['understeer_gradient_rad_per_mps2']):.5f} "
                f"rad/(m/s^2) ({math.degrees(k) * 9.81:.2f} deg/g)")
        if "cornering_stiffness_front" in params:
            text += (f", cornering stiffness front {params['cornering_stiffness_front']:,.0f} "
                     f"+- {_pm(ci['cornering_stiffness_front']):,.0f} N/rad, rear "
                     f"{params['cornering_stiffness_rear']:,.0f} +- {_pm(ci['cornering_stiffness_rear']):,.0f} N/rad")
        return text
    if name == "steering_gain":
        return (f"the wheels turn {params['gain']:.3f} +- {_pm(ci['gain']):.3f} times the commanded angle "
                "(steering gain)")
    if name == "steering_offset":
        side = "left" if params["offset_rad"] > 0 else "right"
        return (f"the steering is offset by {params['offset_rad']:+.4f} +- {_pm(ci['offset_rad']):.4f} rad "
                f"({math.degrees(params['offset_rad']):+.2f} deg): commanded straight, the car pulls {side}")
    raise KeyError(name)


# What drive would tell two effects apart, when a recording cannot (fingerprints in effects.py).
SEPARATING_MANOEUVRES = {
    frozenset({"transport_delay", "actuator_lag"}): ("quick steering (above ~1 Hz) separates them: a delay keeps "
                                                     "the yaw-rate amplitude, a lag cuts it"),
    frozenset({"tire_slip", "transport_delay"}): ("steady turns at very different speeds separate them: only tire "
                                                  "slip changes the steady yaw rate with speed"),
    frozenset({"tire_slip", "actuator_lag"}): ("steady turns at very different speeds separate them: only tire slip "
                                               "changes the steady yaw rate with speed"),
    frozenset({"tire_slip", "steering_gain"}): ("the same turn at 10 and at 30 m/s separates them: a gain error is "
                                                "the same at every speed, understeer grows with speed"),
    frozenset({"steering_offset", "steering_gain"}): ("driving straight separates them: only an offset turns the car "
                                                      "with the wheel centred"),
}
TIE_MARGIN = 0.02


def tie_text(winner: tuple[str, ...], runner_up: tuple[str, ...], margin: float) -> str:
    """A remark when the runner-up is practically as good as the winner."""
    if margin >= TIE_MARGIN:
        return ""
    text = "; practically tied: this recording cannot tell them apart"
    swapped = frozenset(set(winner) ^ set(runner_up))
    if swapped in SEPARATING_MANOEUVRES:
        text += f" ({SEPARATING_MANOEUVRES[swapped]})"
    return text


def summary_text(d: Diagnosis) -> str:
    sel = d.selection
    fit = d.fit
    unit = "rad/s"
    if sel.verdict == "match":
        lines = [(f"No significant mismatch: the simulator's model reproduces '{d.recording.name}' within its "
                 f"measurement noise (held-out {fit['signal'].replace('_', ' ')} RMSE {fit['rmse_before']:.4f} {unit}, "
                 f"noise {fit['noise_sigma']:.4f} {unit})."),
                 (f"Best alternative: {sel.best.name if sel.best.effects else sel.runner_up.name} "
                 f"(held-out RMSE {(sel.best if sel.best.effects else sel.runner_up).heldout_rmse:.4f} {unit}); "
                 f"{sel.reason}.")]
        return "\n".join(lines)
    effects = sel.winner.effects
    sentences = [effect_sentence(e, sel.winner.estimates[e], sel.winner.ci95[e]) for e in effects]
    name = " + ".join(e.replace("_", " ") for e in effects)
    article = "a " if len(effects) == 1 else ""
    lines = [
        f"'{d.recording.name}' departs from the simulator: {where_text(d.conditions, d.windows, d.recording.duration_s, fit['noise_sigma'], fit['signal'].replace('_', ' '))}.",
        "Missing physics: " + "; ".join(sentences) + ".",
        (f"On held-out data {article}{name} explains {100 * fit['explained_fraction']:.0f}% of the "
        f"{fit['signal'].replace('_', ' ')} error above the noise: RMSE {fit['rmse_before']:.4f} -> "
        f"{fit['rmse_after']:.4f} {unit} ({100 * (fit['rmse_after'] / fit['rmse_before'] - 1):+.0f}%; noise "
        f"{fit['noise_sigma']:.4f}); heading {fit['heading_rmse_before_rad']:.4f} -> "
        f"{fit['heading_rmse_after_rad']:.4f} rad, position {fit['position_rmse_before_m']:.3f} -> "
        f"{fit['position_rmse_after_m']:.3f} m (re-anchored every {d.anchor_s:g} s)."),
        (f"Runner-up: {sel.runner_up.name} (held-out RMSE {sel.runner_up.heldout_rmse:.4f} {unit}; penalised score "
         f"{100 * sel.margin:.1f}% worse){tie_text(sel.winner.effects, sel.runner_up.effects, sel.margin)}."),
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# The diagnosis


def _rmse(values: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values[mask] ** 2))) if mask.any() else math.nan


def _chosen_model_outputs(recording: Recording, signal: FitSignal, problem, fit: CandidateFit, anchor_s: float
                          ) -> tuple[np.ndarray, PoseReplay]:
    """The chosen model's fit signal and re-anchored pose, held-out samples from the fold model that
    did not see them, all other samples from the model refitted on everything."""
    r_all, slip_all = model_yaw_rate(recording, fit.params)
    signal_out = filtered(signal, r_all)
    pose = replay_pose(recording, r_all, slip_all, anchor_s)
    heading_err, position_err = pose.heading_error_rad.copy(), pose.position_error_m.copy()
    x, y, h = pose.x_m.copy(), pose.y_m.copy(), pose.heading_rad.copy()
    for params, (_, test) in zip(fit.fold_params, problem.folds):
        r_fold, slip_fold = model_yaw_rate(recording, params)
        pose_fold = replay_pose(recording, r_fold, slip_fold, anchor_s)
        signal_out[test] = filtered(signal, r_fold)[test]
        heading_err[test] = pose_fold.heading_error_rad[test]
        position_err[test] = pose_fold.position_error_m[test]
        x[test], y[test], h[test] = pose_fold.x_m[test], pose_fold.y_m[test], pose_fold.heading_rad[test]
    return signal_out, PoseReplay(x, y, h, heading_err, position_err)


def channel_notes(recording: Recording, signal: FitSignal) -> tuple[dict, list[str]]:
    """Consistency of the recording's own channels: does the yaw rate agree with the heading?"""
    checks: dict = {}
    notes: list[str] = []
    lag = yaw_rate_lag_behind_heading(recording)
    if lag is not None:
        checks["yaw_rate_lag_behind_heading"] = lag
        if abs(lag["lag_s"]) >= max(2 * recording.dt_s, CHANNEL_LAG_MIN_S) and \
                lag["rmse_at_lag"] < 0.9 * lag["rmse_at_zero"]:
            late = "late" if lag["lag_s"] > 0 else "early"
            hint = ("the heading's derivative (--signal heading)" if signal.name == "yaw_rate"
                    else "the yaw rate (--signal yaw_rate)")
            notes.append(f"the recorded yaw_rate runs {abs(lag['lag_s']):.2f} s {late} against the derivative of "
                         f"the recorded heading: one of the two channels is filtered or delayed, so a delay "
                         f"fitted to {signal.name.replace('_', ' ')} may be in the measurement rather than the "
                         f"steering; compare with a diagnosis on {hint}")
    return checks, notes


def diagnose(recording: Recording, *, block_s: float | None = None, anchor_s: float = ANCHOR_S,
             split: str = "blocks", signal_name: str = "auto",
             candidates: list[tuple[str, ...]] | None = None) -> Diagnosis:
    """Run the whole diagnosis on a recording (see the module docstring)."""
    signal = fit_signal(recording, signal_name)
    checks, notes = channel_notes(recording, signal)
    # 1. Plain replay and residuals.
    r_plain, slip_plain = model_yaw_rate(recording, EffectParams())
    before = filtered(signal, r_plain)
    res_before = signal.values - before
    pose_before = replay_pose(recording, r_plain, slip_plain, anchor_s)
    # 2. Noise.
    noise = signal_noise_sigma(recording, signal, res_before)
    # 4. Candidates (before 3, whose "after" columns need the fit).
    block_s = default_block_s(recording.duration_s) if block_s is None else block_s
    problem = make_problem(recording, signal, block_s, split)
    fits = fit_candidates(problem, candidates)
    selection = select(problem, fits, noise)
    after, pose_after = _chosen_model_outputs(recording, signal, problem, selection.winner, anchor_s)
    if selection.best is selection.winner:
        best = after
    else:
        best, _ = _chosen_model_outputs(recording, signal, problem, selection.best, anchor_s)
    res_after = signal.values - after
    # 3. Where.
    windows = mismatch_windows(recording.t_s, res_before, signal.usable, noise)
    conditions = operating_conditions(recording, signal, res_before, res_after)
    # 5. Before/after on held-out data.
    heldout = problem.heldout
    mse_before, mse_after = selection.plain.heldout_mse, selection.winner.heldout_mse
    excess = mse_before - noise**2
    explained = (mse_before - mse_after) / excess if excess > 0 else 0.0
    fit = {
        "signal": signal.name,
        "rmse_before": math.sqrt(mse_before),
        "rmse_after": math.sqrt(mse_after),
        "noise_sigma": noise,
        "heldout": True,
        "explained_fraction": float(np.clip(explained, 0.0, 1.0)),
        "heading_rmse_before_rad": _rmse(pose_before.heading_error_rad, heldout),
        "heading_rmse_after_rad": _rmse(pose_after.heading_error_rad, heldout),
        "position_rmse_before_m": _rmse(pose_before.position_error_m, heldout),
        "position_rmse_after_m": _rmse(pose_after.position_error_m, heldout),
        "anchor_s": anchor_s,
        "split": split,
        "block_s": block_s,
        "heldout_fraction": float(heldout.sum() / max(signal.usable.sum(), 1)),
        "t_statistic": selection.t_statistic,
    }
    d = Diagnosis(recording, signal, noise, selection, block_s, anchor_s, heldout, before, after, best,
                  pose_before, pose_after, windows, conditions, fit, summary="", checks=checks, notes=notes)
    d.summary = summary_text(d)
    if notes:
        d.summary += "\nCaveat: " + "; ".join(notes) + "."
    return d


def _candidate_json(c: CandidateFit) -> dict:
    return {"name": c.name, "effects": list(c.effects), "params": c.estimates, "ci": c.ci95,
            "rmse_heldout": c.heldout_rmse, "rmse_train": math.sqrt(c.train_mse), "dof": c.dof, "score": c.score}


def to_json(d: Diagnosis) -> dict:
    """The diagnosis as the documented JSON (effect names and parameter keys are fixed)."""
    sel = d.selection
    winner = sel.winner
    effects = [{"name": e, "params": winner.estimates[e], "ci": winner.ci95[e]} for e in winner.effects]
    runner = _candidate_json(sel.runner_up)
    runner["margin"] = sel.margin
    rec = d.recording
    return {
        "verdict": sel.verdict,
        "effects": effects,
        "runner_up": runner,
        "fit": d.fit,
        "windows": d.windows,
        "conditions": d.conditions,
        "reason": sel.reason,
        "summary": d.summary,
        "candidates": [_candidate_json(c) for c in sel.ranking],
        "recording": {"name": rec.name, "duration_s": rec.duration_s, "sample_hz": 1.0 / rec.dt_s,
                      "vehicle": rec.vehicle.sidecar() | {"source": rec.vehicle.source},
                      "yaw_inertia_assumed": not rec.vehicle.inertia_known},
        "checks": d.checks,
        "warnings": list(rec.warnings) + list(d.notes),
        "effect_names": list(EFFECT_NAMES),
    }
