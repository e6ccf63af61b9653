"""Replaying a recording's commands and speed through the simulator's model (plus effects).

What is compared, and how drift is kept out of it:

* **Yaw rate** is the primary signal. It depends on the steering history and the speed, not on
  where the car is, so the model's yaw rate is computed over the whole recording from the recorded
  inputs; the internal states of the effects (actuator, lateral velocity) start settled and run
  on the input history, which is the best estimate of them a replay has. When the recording has no
  ``yaw_rate`` column the signal is the derivative of the unwrapped heading (Savitzky-Golay), and
  the model's yaw rate goes through the *same* filter (after Euler integration to a heading, as the
  simulator does), so smoothing and edge effects cancel.
* **Heading and position** are re-anchored: every ``anchor_s`` seconds (default 2 s) the replay
  restarts from the recorded pose and integrates the model with highway-env's forward Euler. Errors
  then measure what the model gets wrong within a few seconds, not the accumulated drift of minutes.

The measurement noise of the signal is estimated from the high-frequency content of the plain
model's residual (third differences, median absolute deviation): smooth model errors cancel in the
differences, white noise does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs

from plm_highway.sim2real.effects import EffectParams, fir_filter, simulate_yaw_rate
from plm_highway.sim2real.recording import Recording
from plm_highway.vehicle.kinematic import integrate_pose_euler

ANCHOR_S = 2.0
HEADING_DERIVATIVE_WINDOW_S = 0.5
# Samples at the start where settled-start assumptions of the effect states may still be wrong.
SETTLE_S = 1.0


@dataclass(frozen=True)
class FitSignal:
    """The measured signal the models are scored on, and the filter that makes a model comparable."""

    name: str  # "yaw_rate" (recorded) or "heading_rate" (derivative of the recorded heading)
    values: np.ndarray
    taps: np.ndarray  # FIR applied to a model's yaw rate: out[k] = sum_j taps[j] * r[k + lo + j]
    lo: int
    usable: np.ndarray  # samples that may be scored


def heading_rate_taps(window_samples: int, dt_s: float) -> tuple[np.ndarray, int, np.ndarray]:
    """Savitzky-Golay derivative taps for the heading, and the equivalent taps on the yaw rate.

    With the simulator's Euler heading ``h[n] = h[0] + dt * sum_{i<n} r[i]``, the derivative filter
    ``sum_j c_j h[k+j]`` equals ``sum_m w_m r[k+m]`` with ``w_m = dt * sum_{j>m} c_j``.
    Returns (heading taps c for offsets -W..W, yaw-rate taps w, offset of w's first tap).
    """
    half = window_samples // 2
    c = savgol_coeffs(2 * half + 1, polyorder=2, deriv=1, delta=dt_s, use="dot")
    offsets = np.arange(-half, half + 1)
    m = np.arange(-half - 1, half)
    w = np.array([dt_s * c[offsets > mm].sum() for mm in m])
    return c, w, int(m[0])


SIGNALS = ("auto", "yaw_rate", "heading")


def fit_signal(recording: Recording, prefer: str = "auto") -> FitSignal:
    """The recorded yaw rate (``auto`` when present, or ``yaw_rate``) or the heading's derivative."""
    if prefer not in SIGNALS:
        raise ValueError(f"unknown signal {prefer!r}; known: {', '.join(SIGNALS)}")
    if prefer == "yaw_rate" and recording.yaw_rate_radps is None:
        raise ValueError(f"{recording.name}: no yaw_rate column to fit; use the heading")
    usable = recording.usable_mask.copy()
    settle = round(SETTLE_S / recording.dt_s)
    usable[:settle] = False
    if recording.yaw_rate_radps is not None and prefer != "heading":
        return FitSignal("yaw_rate", recording.yaw_rate_radps, np.ones(1), 0, usable)
    window = max(5, round(HEADING_DERIVATIVE_WINDOW_S / recording.dt_s) | 1)
    c, w, lo = heading_rate_taps(window, recording.dt_s)
    values = np.convolve(recording.heading_rad, c[::-1], mode="same")
    half = window // 2
    usable[:half + 1] = False
    usable[-half - 1:] = False
    return FitSignal("heading_rate", values, w, lo, usable)


def filtered(signal: FitSignal, yaw_rate_radps: np.ndarray) -> np.ndarray:
    """A model's yaw rate as the fit signal sees it."""
    if signal.taps.shape[0] == 1 and signal.lo == 0:
        return yaw_rate_radps * signal.taps[0]
    out = np.empty_like(yaw_rate_radps)
    fir_filter(np.ascontiguousarray(yaw_rate_radps, dtype=float), signal.taps, signal.lo, out)
    return out


def model_yaw_rate(recording: Recording, params: EffectParams, with_slip: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(yaw rate, slip angle) of the simulator's model with ``params``, at each sample.

    Without ``with_slip`` only the yaw rate is meaningful (cheaper, for fits).
    """
    v = recording.vehicle
    return simulate_yaw_rate(
        np.ascontiguousarray(recording.steer_rad, float), np.ascontiguousarray(recording.speed_mps, float),
        recording.dt_s, *params.numba_args(), v.cg_to_front_m, v.cg_to_rear_m, v.yaw_inertia_per_kg_m2, with_slip,
    )


def noise_sigma(residual: np.ndarray, usable: np.ndarray) -> float:
    """Std of white measurement noise in ``residual`` from its third differences (robust, MAD)."""
    d3 = np.diff(residual, n=3)
    ok = usable[3:] & usable[2:-1] & usable[1:-2] & usable[:-3]
    d3 = d3[ok]
    if d3.size < 10:
        return float(np.std(residual[usable]))
    mad = np.median(np.abs(d3 - np.median(d3)))
    return float(1.4826 * mad / math.sqrt(20.0))


def heading_noise_to_signal(recording: Recording, signal: FitSignal) -> float:
    """For a heading-derived signal: the heading's white noise through the derivative filter."""
    sigma_heading = noise_sigma(recording.heading_rad, recording.usable_mask)
    c, _, _ = heading_rate_taps(len(signal.taps), recording.dt_s)
    return float(sigma_heading * np.sqrt(np.sum(c**2)))


def signal_noise_sigma(recording: Recording, signal: FitSignal, plain_residual: np.ndarray) -> float:
    if signal.name == "yaw_rate":
        return noise_sigma(plain_residual, signal.usable)
    return heading_noise_to_signal(recording, signal)


def yaw_rate_lag_behind_heading(recording: Recording, max_lag_s: float = 0.5) -> dict | None:
    """How late the recorded yaw rate is against the derivative of the recorded heading.

    Both channels describe the same rotation; a lag between them is in the measurements (a filtered
    or delayed gyro, or a lagging pose estimate), and a delay fitted to one channel includes it.
    Returns {"lag_s", "rmse_at_zero", "rmse_at_lag"} (positive lag: the yaw rate is late), or None
    without a yaw-rate column.
    """
    if recording.yaw_rate_radps is None:
        return None
    heading = fit_signal(recording, prefer="heading")
    rate = filtered(heading, np.ascontiguousarray(recording.yaw_rate_radps, float))
    n_max = round(max_lag_s / recording.dt_s)
    lags = np.arange(-n_max, n_max + 1)
    core = heading.usable.copy()
    core[:n_max] = False
    core[len(core) - n_max:] = False
    idx = np.flatnonzero(core)
    rmse = np.array([np.sqrt(np.mean((heading.values[idx] - rate[idx + lag]) ** 2)) for lag in lags])
    i = int(np.argmin(rmse))
    lag = float(lags[i])
    if 0 < i < len(lags) - 1:  # parabolic refinement between samples
        a, b, c = rmse[i - 1] ** 2, rmse[i] ** 2, rmse[i + 1] ** 2
        denom = a - 2 * b + c
        if denom > 0:
            lag += 0.5 * (a - c) / denom
    return {"lag_s": lag * recording.dt_s, "rmse_at_zero": float(rmse[n_max]), "rmse_at_lag": float(rmse[i])}


@dataclass(frozen=True)
class PoseReplay:
    """Re-anchored replay: the model's pose, restarted from the recording every ``anchor_s``."""

    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    heading_error_rad: np.ndarray
    position_error_m: np.ndarray


def replay_pose(recording: Recording, yaw_rate_radps: np.ndarray, slip_rad: np.ndarray,
                anchor_s: float = ANCHOR_S) -> PoseReplay:
    """Integrate the model with the simulator's Euler step, re-anchored to the recorded pose."""
    n = recording.n
    per_segment = max(2, round(anchor_s / recording.dt_s))
    starts = np.arange(0, n, per_segment)
    x = np.empty(n)
    y = np.empty(n)
    h = np.empty(n)
    for s in starts:
        e = min(s + per_segment, n)
        xs, ys, hs = integrate_pose_euler(recording.x_m[s], recording.y_m[s], recording.heading_rad[s],
                                          yaw_rate_radps[s:e - 1], slip_rad[s:e - 1],
                                          recording.speed_mps[s:e - 1], recording.dt_s)
        x[s:e], y[s:e], h[s:e] = xs, ys, hs
    heading_error = np.angle(np.exp(1j * (recording.heading_rad - h)))
    position_error = np.hypot(recording.x_m - x, recording.y_m - y)
    return PoseReplay(x, y, h, heading_error, position_error)


def plain_replay(recording: Recording, anchor_s: float = ANCHOR_S) -> PoseReplay:
    """The simulator's model, as is, replaying the recording (step 2a of a diagnosis)."""
    r, slip = model_yaw_rate(recording, EffectParams())
    return replay_pose(recording, r, slip, anchor_s)
