"""Replaying a recording's commands and speed through the simulator's model (plus effects), and
the recorded signals the replay is compared with.

**Channels.** Every recorded signal is compared as a rate, so that the comparison does not drift:

=================== =========== ===================================================================
channel             unit        measured as / model seen through
=================== =========== ===================================================================
``yaw_rate``        rad/s       the recorded gyro; the model's yaw rate (late by a sensor delay)
``heading_rate``    rad/s       Savitzky-Golay derivative of the unwrapped heading; the model's yaw
                                rate integrated to a heading and differentiated by the same filter
``lateral_velocity`` m/s        velocity from the positions' Savitzky-Golay derivative, projected
                                on the car's lateral axis (recorded heading); the model's ``v sin
                                beta`` (kinematic) or ``vy`` (tires) through the same filter, each
                                velocity in the window along the recorded heading it had
=================== =========== ===================================================================

The heading and the position are integrals of the yaw rate and the velocity; which rule the
recording's own integration follows matters at the half-sample level: the simulator steps with
forward Euler (its logs), a continuous-time car does not. When a yaw rate is recorded the rule
(forward Euler or trapezoidal) is the one under which the recorded yaw rate best reproduces the
recorded heading; without one, forward Euler (the simulator's).

**Heading and position** errors are also reported re-anchored: every ``anchor_s`` seconds
(default 2 s) the replay restarts from the recorded pose and integrates with highway-env's forward
Euler, so errors measure what the model gets wrong within a few seconds, not the drift of minutes.

**Noise.** The white measurement noise of the gyro is estimated from the third differences of a
model's residual (median absolute deviation): smooth model errors cancel in them, white noise does
not. The filtered channels take their noise from the heading's and positions' own third
differences through the filter. An estimate from too few samples is marked as not measured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs

from plm_highway.sim2real.physics.chain import gyro_view, simulate
from plm_highway.sim2real.physics.effects import EffectParams
from plm_highway.sim2real.physics.filters import fir_filter, fir_filter_at, lateral_fir_at, lateral_fir_at_turned
from plm_highway.sim2real.record.recording import HEADING_DERIVATIVE_WINDOW_S, Recording
from plm_highway.vehicle.kinematic import integrate_pose_euler

ANCHOR_S = 2.0
# Samples at the start where settled-start assumptions of the effect states may still be wrong.
SETTLE_S = 1.0
# Third differences needed before a noise level counts as measured.
MIN_NOISE_SAMPLES = 200
CONVENTIONS = ("euler", "trapezoidal")


@dataclass(frozen=True)
class FitSignal:
    """A recorded channel the models are scored on, and the filter that makes a model comparable."""

    name: str  # "yaw_rate", "heading_rate" or "lateral_velocity"
    values: np.ndarray
    taps: np.ndarray  # FIR applied to a model output: out[k] = sum_j taps[j] * x[k + lo + j]
    lo: int
    usable: np.ndarray  # samples that may be scored
    source: str = "yaw_rate"  # which model output: "yaw_rate" or "lateral_velocity"
    late: bool = False  # a sensor delay acts on this channel (the gyro)
    unit: str = "rad/s"
    noise_sigma: float = math.nan
    noise_measured: bool = False

    @property
    def label(self) -> str:
        return self.name.replace("_", " ")


Channel = FitSignal


def heading_rate_taps(window_samples: int, dt_s: float, convention: str = "euler"
                      ) -> tuple[np.ndarray, np.ndarray, int]:
    """Savitzky-Golay derivative taps for an integrated signal, and the equivalent taps on its rate.

    Forward Euler, ``h[n] = h[0] + dt sum_{i<n} r[i]``: the derivative filter ``sum_j c_j h[k+j]``
    equals ``sum_m w_m r[k+m]`` with ``w_m = dt sum_{j>m} c_j``. Trapezoidal: the mean of the Euler
    taps and the same taps one sample later. Returns (taps c for offsets -W..W, rate taps w,
    offset of w's first tap).
    """
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown convention {convention!r}; known: {', '.join(CONVENTIONS)}")
    half = window_samples // 2
    c = savgol_coeffs(2 * half + 1, polyorder=2, deriv=1, delta=dt_s, use="dot")
    offsets = np.arange(-half, half + 1)
    m = np.arange(-half - 1, half)
    w = np.array([dt_s * c[offsets > mm].sum() for mm in m])
    if convention == "euler":
        return c, w, int(m[0])
    w_trap = 0.5 * (np.concatenate([w, [0.0]]) + np.concatenate([[0.0], w]))
    return c, w_trap, int(m[0])


SIGNALS = ("auto", "yaw_rate", "heading")


def _window(recording: Recording) -> int:
    return max(5, round(HEADING_DERIVATIVE_WINDOW_S / recording.dt_s) | 1)


def _settled_usable(recording: Recording) -> np.ndarray:
    usable = recording.usable_mask.copy()
    usable[:round(SETTLE_S / recording.dt_s)] = False
    return usable


def _filtered_usable(usable: np.ndarray, half: int) -> np.ndarray:
    """Usable where the whole filter window is: glitches and gaps spoil every output that sees them."""
    bad = ~usable
    spread = np.convolve(bad.astype(float), np.ones(2 * half + 3), mode="same") > 0
    out = usable & ~spread
    out[:half + 1] = False
    out[-half - 1:] = False
    return out


def noise_estimate(residual: np.ndarray, usable: np.ndarray) -> tuple[float, int]:
    """(std of white noise in ``residual`` from its third differences (robust, MAD), number of
    third differences used); NaN when there are none."""
    d3 = np.diff(residual, n=3)
    ok = usable[3:] & usable[2:-1] & usable[1:-2] & usable[:-3]
    d3 = d3[ok]
    if d3.size == 0:
        return math.nan, 0
    mad = np.median(np.abs(d3 - np.median(d3)))
    return float(1.4826 * mad / math.sqrt(20.0)), int(d3.size)


def noise_sigma(residual: np.ndarray, usable: np.ndarray) -> float:
    """Std of white measurement noise in ``residual`` from its third differences (robust, MAD).

    With fewer than 10 usable third differences this falls back to the plain standard deviation (an
    upper bound); :func:`noise_estimate` says how many were used.
    """
    sigma, count = noise_estimate(residual, usable)
    if count < 10:
        return float(np.std(residual[usable])) if usable.any() else math.nan
    return sigma


def heading_convention(recording: Recording) -> str:
    """The integration rule under which the recorded yaw rate best reproduces the recorded heading."""
    if recording.yaw_rate_radps is None:
        return "euler"
    window = _window(recording)
    c, _, _ = heading_rate_taps(window, recording.dt_s)
    usable = _filtered_usable(_settled_usable(recording), window // 2)
    measured = np.convolve(recording.heading_rad, c[::-1], mode="same")
    errors = []
    for convention in CONVENTIONS:
        _, w, lo = heading_rate_taps(window, recording.dt_s, convention)
        model = _fir(recording.yaw_rate_radps, w, lo)
        errors.append(float(np.mean((measured - model)[usable] ** 2)) if usable.any() else 0.0)
    return CONVENTIONS[int(np.argmin(errors))]


def _fir(x: np.ndarray, taps: np.ndarray, lo: int) -> np.ndarray:
    out = np.empty(len(x))
    fir_filter(np.ascontiguousarray(x, float), np.ascontiguousarray(taps, float), int(lo), out)
    return out


def _heading_channel(recording: Recording, convention: str) -> FitSignal:
    window = _window(recording)
    c, w, lo = heading_rate_taps(window, recording.dt_s, convention)
    values = np.convolve(recording.heading_rad, c[::-1], mode="same")
    usable = _filtered_usable(_settled_usable(recording), window // 2)
    sigma_heading, count = noise_estimate(recording.heading_rad, recording.usable_mask)
    sigma = sigma_heading * float(np.sqrt(np.sum(c**2)))
    return FitSignal("heading_rate", values, w, lo, usable, noise_sigma=sigma,
                     noise_measured=count >= MIN_NOISE_SAMPLES)


def _lateral_channel(recording: Recording, convention: str) -> FitSignal:
    """The car's lateral velocity from its positions (see the module docstring)."""
    window = _window(recording)
    c, w, lo = heading_rate_taps(window, recording.dt_s, convention)
    heading = recording.heading_rad
    x_rate = np.convolve(recording.x_m, c[::-1], mode="same")
    y_rate = np.convolve(recording.y_m, c[::-1], mode="same")
    projected = -np.sin(heading) * x_rate + np.cos(heading) * y_rate
    # The window averages velocities along headings that turn within it; subtract the part a plain
    # rotation gives, known from the recorded heading (the model's channel does the same, see
    # effects.lateral_fir_at), so that what is left is about sum_m w_m v sin(beta) at k + m.
    n = recording.n
    turn = np.zeros(n)
    for j, tap in enumerate(w):
        idx = np.clip(np.arange(n) + lo + j, 0, n - 1)
        turn += tap * recording.speed_mps[idx] * np.sin(heading[idx] - heading)
    values = projected - turn
    usable = _filtered_usable(_settled_usable(recording), window // 2 + 1)
    sigma_x, count_x = noise_estimate(recording.x_m, recording.usable_mask)
    sigma_y, _ = noise_estimate(recording.y_m, recording.usable_mask)
    sigma_h, _ = noise_estimate(heading, recording.usable_mask)
    speed_rms = float(np.sqrt(np.mean(recording.speed_mps[usable] ** 2))) if usable.any() else 0.0
    sigma = math.sqrt(0.5 * (sigma_x**2 + sigma_y**2) * float(np.sum(c**2))
                      + (speed_rms * sigma_h) ** 2 * float(np.sum(w**2)))
    return FitSignal("lateral_velocity", values, w, lo, usable, source="lateral_velocity", unit="m/s",
                     noise_sigma=sigma, noise_measured=count_x >= MIN_NOISE_SAMPLES)


def _stride(channel: FitSignal, window: int) -> FitSignal:
    """Filtered channels are smooth over their window: score every few samples (independent
    information is one per ~window/5 samples; the rest only costs time)."""
    stride = max(1, window // 5)
    if stride == 1:
        return channel
    usable = channel.usable.copy()
    usable[np.arange(len(usable)) % stride != 0] = False
    return FitSignal(channel.name, channel.values, channel.taps, channel.lo, usable, channel.source, channel.late,
                     channel.unit, channel.noise_sigma, channel.noise_measured)


def fit_signal(recording: Recording, prefer: str = "auto") -> FitSignal:
    """The primary channel: the recorded yaw rate (``auto`` when present, or ``yaw_rate``) or the
    heading's derivative."""
    return recorded_channels(recording, prefer)[0]


def recorded_channels(recording: Recording, prefer: str = "auto") -> list[FitSignal]:
    """The channels a diagnosis fits and scores, primary first.

    ``auto``: every recorded signal (yaw rate when recorded, heading, position); ``yaw_rate`` or
    ``heading``: that one alone (the heading's derivative for ``heading``).
    """
    if prefer not in SIGNALS:
        raise ValueError(f"unknown signal {prefer!r}; known: {', '.join(SIGNALS)}")
    if prefer == "yaw_rate" and recording.yaw_rate_radps is None:
        raise ValueError(f"{recording.name}: no yaw_rate column to fit; use the heading")
    convention = heading_convention(recording)
    window = _window(recording)
    heading = _heading_channel(recording, convention)
    if prefer == "heading":
        return [heading]
    channels = []
    if recording.yaw_rate_radps is not None:
        gyro = FitSignal("yaw_rate", recording.yaw_rate_radps, np.ones(1), 0, _settled_usable(recording), late=True)
        if prefer == "yaw_rate":
            return [gyro]
        channels.append(gyro)
        channels.append(_stride(heading, window))
    else:
        channels.append(heading)
    channels.append(_stride(_lateral_channel(recording, convention), window))
    return channels


def filtered(signal: FitSignal, yaw_rate_radps: np.ndarray) -> np.ndarray:
    """A model output (yaw rate, or lateral velocity for that channel) as the channel sees it."""
    if signal.taps.shape[0] == 1 and signal.lo == 0:
        return yaw_rate_radps * signal.taps[0]
    return _fir(yaw_rate_radps, signal.taps, signal.lo)


def model_outputs(recording: Recording, params: EffectParams, with_slip: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw rate, lateral velocity, slip angle) of the simulator's model with ``params``, per sample
    (the slip left unset without ``with_slip``: fits do not need it)."""
    v = recording.vehicle
    return simulate(recording.steer_rad, recording.speed_mps, recording.dt_s, params, v.cg_to_front_m,
                    v.cg_to_rear_m, v.yaw_inertia_per_kg_m2, recording.tire_min_speed_mps, with_slip)


def model_yaw_rate(recording: Recording, params: EffectParams, with_slip: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(yaw rate, slip angle) of the simulator's model with ``params``, at each sample."""
    r, _, slip = model_outputs(recording, params)
    return r, slip


def channel_prediction(signal: FitSignal, recording: Recording, params: EffectParams,
                       outputs: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                       index: np.ndarray | None = None, turns: dict | None = None) -> np.ndarray:
    """What ``signal`` would record if the car were the model with ``params`` (only at ``index``
    when given: fits read filtered channels at a few samples).

    ``turns``: where a caller predicts this lateral-velocity ``signal`` of this ``recording`` many times (a fit),
    a dict it keeps for them: the heading's turns within the filter window are computed once per index there (the
    same numbers either way)."""
    r, vy, _ = model_outputs(recording, params, with_slip=False) if outputs is None else outputs
    if signal.source == "lateral_velocity":
        index = np.arange(recording.n) if index is None else np.ascontiguousarray(index, np.int64)
        out = np.empty(index.shape[0])
        inputs = (np.ascontiguousarray(vy, float), np.ascontiguousarray(recording.speed_mps, float),
                  np.ascontiguousarray(recording.heading_rad, float), np.ascontiguousarray(signal.taps, float),
                  int(signal.lo), index, out)
        if turns is None:
            lateral_fir_at(*inputs)
            return out
        key = index.tobytes()
        known = turns.get(key)
        if known is None:
            shape = (index.shape[0], signal.taps.shape[0])
            tables = (np.empty(shape), np.empty(shape))
            lateral_fir_at_turned(*inputs, *tables, False)
            turns[key] = tables
        else:
            lateral_fir_at_turned(*inputs, *known, True)
        return out
    source, bias = gyro_view(r, recording.dt_s, params) if signal.late else (r, 0.0)
    if index is None:
        out = filtered(signal, source)
    elif signal.taps.shape[0] == 1 and signal.lo == 0:
        out = source[index] * signal.taps[0]
    else:
        out = np.empty(index.shape[0])
        fir_filter_at(np.ascontiguousarray(source, float), np.ascontiguousarray(signal.taps, float),
                      int(signal.lo), index, out)
    return out + bias if bias != 0.0 else out


def heading_noise_to_signal(recording: Recording, signal: FitSignal) -> float:
    """For a heading-derived signal: the heading's white noise through the derivative filter."""
    return _heading_channel(recording, heading_convention(recording)).noise_sigma


def yaw_rate_lag_behind_heading(recording: Recording, max_lag_s: float = 0.5) -> dict | None:
    """How late the recorded yaw rate is against the derivative of the recorded heading.

    Both channels describe the same rotation; a lag between them is in the measurements (a filtered
    or delayed gyro, or a lagging pose estimate), and a delay fitted to one channel includes it.
    Returns {"lag_s", "rmse_at_zero", "rmse_at_lag"} (positive lag: the yaw rate is late), or None
    without a yaw-rate column.
    """
    if recording.yaw_rate_radps is None:
        return None
    heading = recorded_channels(recording, prefer="heading")[0]
    rate = filtered(heading, np.ascontiguousarray(recording.yaw_rate_radps, float))
    n_max = max(1, min(round(max_lag_s / recording.dt_s), recording.n // 4))
    lags = np.arange(-n_max, n_max + 1)
    core = heading.usable.copy()
    core[:n_max] = False
    core[len(core) - n_max:] = False
    idx = np.flatnonzero(core)
    if idx.size == 0:
        return None
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
