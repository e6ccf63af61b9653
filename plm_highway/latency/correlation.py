"""The baseline: an online lag estimate the way a deployed driver-assistance stack makes one.

openpilot's lateral-lag learner (``selfdrive/locationd/lagd.py``, public) estimates the lag between what the
controller asked for and what the car did. This module applies the same method, written here from its published
description, to the kit's question (how late is the camera?) and feeds it exactly what
:class:`~plm_highway.latency.estimate.LatencyEstimator` gets: the fast sensors and the lane the camera reported.

- **Signals.** The prompt signal is the car's lateral acceleration from its fast sensors, ``u r`` (speed times yaw
  rate); the late one is what the camera says of it, ``u`` times the rate of the lane-relative heading it reports
  (differenced between consecutive lane samples). Their difference, ``u^2 kappa`` of the road, changes slowly and
  the correlation removes each window's mean. Both are smoothed by one masked Gaussian moving average (5 samples,
  sigma 1): the same filter on both leaves the lag between them unchanged.
- **Validity.** A sample counts when the car is faster than ``min_speed_mps``, both lane samples behind the
  difference arrived, and ``recovery_s`` have passed since the last invalid sample.
- **Windows.** Every ``1 / update_hz`` the last ``window_s`` are correlated (masked normalised cross-correlation,
  Padfield, CVPR 2010) at lags ``0 .. max_lag_s``, provided ``min_valid_s`` of them are valid and a valid sample
  is new since the last accepted window. The window's lag is the correlation's peak (refined by a parabola); it is
  accepted when the peak is at least ``min_ncc`` and narrow: the run of lags around it whose correlation lies in
  the top ``1 - peak_fraction`` of the window's range is at most ``1 - min_confidence`` seconds wide.
- **Claims.** Accepted lags are averaged in blocks of ``block_size``; the last ``blocks_kept`` blocks are kept.
  The estimate is claimed ("estimated") only once ``blocks_needed`` blocks are complete and only while their
  means spread by at most ``max_block_spread_s`` (standard deviation; "invalid" otherwise), clamped to
  ``[min_lag_s, max_lag_s]``; until then the prior is what a consumer uses.

The published constants (:data:`PUBLISHED`) need ``min_valid_s + blocks_needed x block_size / update_hz`` =
150 s of valid driving before the first claim: it trades speed for never being confidently wrong.
:func:`time_scaled` divides every duration by a factor (the block size with it), for runs shorter than that.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.latency.estimate import FastSample, LaneSample

STATES = ("estimated", "invalid", "unestimated")
SMOOTHING_SAMPLES = 5  # the moving average both signals pass through: 5 samples, Gaussian weights of sigma 1 sample
SMOOTHING_SIGMA = 1.0
BORDER_SAMPLES = 5  # the peak's run of good lags is looked for this many samples beyond the lag range


@dataclass(frozen=True)
class CorrelationLagConfig:
    """The method's constants; the defaults are the published ones (module docstring)."""

    window_s: float = 60.0
    min_valid_s: float = 25.0
    recovery_s: float = 2.0
    min_speed_mps: float = 15.0
    min_ncc: float = 0.95
    peak_fraction: float = 0.9
    min_confidence: float = 0.7
    update_hz: float = 4.0
    block_size: int = 100
    blocks_needed: int = 5
    blocks_kept: int = 50
    max_block_spread_s: float = 0.1
    min_lag_s: float = 0.15
    max_lag_s: float = 1.0
    # What a consumer is told before a claim: the same prior as the kit's estimator, so that both start alike.
    prior_latency_s: float = 0.175
    # When the motion of a fast-sensor sample happens relative to its tick: the same calibration the kit's estimator
    # is given (LatencyEstimatorConfig.fast_sensor_shift_s), so that both are told the same about the car's sensors.
    fast_sensor_shift_s: float = 0.0

    def __post_init__(self):
        for name in ("window_s", "min_valid_s", "update_hz", "max_lag_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 1e6:
                raise BadInput(f"CorrelationLagConfig.{name}={value!r}: must be a positive number")
        for name in ("block_size", "blocks_needed", "blocks_kept"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise BadInput(f"CorrelationLagConfig.{name}={value!r}: must be a positive integer")
        if self.blocks_needed > self.blocks_kept:
            raise BadInput(f"CorrelationLagConfig: blocks_needed={self.blocks_needed} exceeds blocks_kept="
                           f"{self.blocks_kept}")
        if not 0 <= self.min_lag_s < self.max_lag_s:
            raise BadInput(f"CorrelationLagConfig: need 0 <= min_lag_s < max_lag_s, got {self.min_lag_s}, "
                           f"{self.max_lag_s}")
        if self.min_valid_s > self.window_s:
            raise BadInput(f"CorrelationLagConfig: min_valid_s={self.min_valid_s} exceeds window_s={self.window_s}")

    @property
    def first_claim_s(self) -> float:
        """The least valid driving before a claim can be made [s]."""
        return self.min_valid_s + self.blocks_needed * self.block_size / self.update_hz


PUBLISHED = CorrelationLagConfig()


def time_scaled(factor: float, config: CorrelationLagConfig = PUBLISHED) -> CorrelationLagConfig:
    """``config`` with every duration divided by ``factor`` (windows, recovery, and the block size, so that a block
    spans ``factor`` times less time); thresholds, lag range and update rate unchanged."""
    if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not 1 <= factor <= 1000:
        raise BadInput(f"time_scaled: factor={factor!r} must be a number in [1, 1000]")
    return replace(config, window_s=config.window_s / factor, min_valid_s=config.min_valid_s / factor,
                   recovery_s=config.recovery_s / factor, block_size=max(1, round(config.block_size / factor)))


class CorrelationEstimate(NamedTuple):
    """The baseline's answer at one tick: ``state`` in :data:`STATES`, ``latency_s`` the block mean (NaN before any
    accepted window), ``spread_s`` the block means' standard deviation, ``held_s`` what a consumer should use."""

    state: str
    latency_s: float
    spread_s: float
    held_s: float
    blocks: int

    @property
    def estimable(self) -> bool:
        return self.state == "estimated"


def masked_ncc(prompt: np.ndarray, late: np.ndarray, mask: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation of ``late`` against ``prompt`` shifted by 0..``max_lag`` samples, over the
    samples valid in both (``mask``); each lag's means and variances are those of its own overlap (Padfield's
    masked NCC, written directly: the windows are short). 0 where an overlap has no variance."""
    n = len(prompt)
    out = np.zeros(max_lag + 1)
    for lag in range(max_lag + 1):
        if lag >= n - 2:
            break
        a, b = prompt[:n - lag], late[lag:]
        valid = mask[:n - lag] & mask[lag:]
        if valid.sum() < 3:
            continue
        a, b = a[valid] - a[valid].mean(), b[valid] - b[valid].mean()
        denominator = math.sqrt(float(a @ a) * float(b @ b))
        out[lag] = float(a @ b) / denominator if denominator > 1e-300 else 0.0
    return np.clip(out, -1.0, 1.0)


def smoothed(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The masked Gaussian moving average (invalid samples carry no weight; NaN where none is near)."""
    pad = SMOOTHING_SAMPLES // 2
    offsets = np.arange(SMOOTHING_SAMPLES) - pad
    weights = np.exp(-0.5 * (offsets / SMOOTHING_SIGMA) ** 2)
    weights /= weights.sum()
    numerator = np.convolve(np.pad(np.where(mask, values, 0.0), pad, mode="edge"), weights, mode="valid")
    denominator = np.convolve(np.pad(mask.astype(float), pad, mode="edge"), weights, mode="valid")
    return np.divide(numerator, denominator, out=np.full(len(values), np.nan), where=denominator > 0)


def window_lag(prompt: np.ndarray, late: np.ndarray, mask: np.ndarray, dt_s: float,
               config: CorrelationLagConfig) -> tuple[float, float, float]:
    """(lag s, peak correlation, confidence) of one window (module docstring)."""
    max_lag = int(config.max_lag_s / dt_s)
    ncc = masked_ncc(prompt, late, mask, max_lag + BORDER_SAMPLES)
    roi = ncc[:max_lag + 1]
    best = int(np.argmax(roi))
    peak = float(roi[best])
    lag = float(best)
    if 0 < best < len(roi) - 1:
        left, centre, right = roi[best - 1], roi[best], roi[best + 1]
        curvature = 2.0 * centre - left - right
        if curvature > 0:
            lag += 0.5 * (right - left) / curvature
    threshold = float(roi.min()) + config.peak_fraction * float(roi.max() - roi.min())
    good = ncc >= threshold
    start, stop = best, best
    while start > 0 and good[start - 1]:
        start -= 1
    while stop < len(good) - 1 and good[stop + 1]:
        stop += 1
    confidence = float(np.clip(1.0 - (stop - start + 1) * dt_s, 0.0, 1.0))
    return lag * dt_s, peak, confidence


class CorrelationLagEstimator:
    """Online, tick by tick, with the interface of :class:`~plm_highway.latency.estimate.LatencyEstimator`:
    :meth:`update` takes the fast sensors and the lane sample that arrived at the tick (None when none did)."""

    def __init__(self, config: CorrelationLagConfig = PUBLISHED):
        self.config = config
        self.reset()

    def reset(self) -> None:
        self._times: deque[float] = deque()
        self._prompt: deque[float] = deque()
        self._late: deque[float] = deque()
        self._valid: deque[bool] = deque()
        self._previous_lane: tuple[float, float] | None = None  # (arrival s, heading rad) of the last lane sample
        self._last_invalid_s = -math.inf
        self._next_update_s = -math.inf
        self._new_valid = False
        self._blocks: deque[float] = deque(maxlen=self.config.blocks_kept)  # completed block means
        self._current: list[float] = []
        self.windows_accepted = 0
        self.last = CorrelationEstimate("unestimated", math.nan, math.nan, self.config.prior_latency_s, 0)

    def update(self, fast: FastSample, lane: LaneSample | None = None) -> CorrelationEstimate:
        config = self.config
        time_s = float(fast.time_s)
        if self._times and time_s <= self._times[-1]:
            raise BadInput(f"fast sensor time {time_s!r} s is not after the previous tick at {self._times[-1]!r} s")
        speed_mps = float(fast.speed_mps)
        prompt = speed_mps * float(fast.yaw_rate_radps)
        late, valid = math.nan, False
        lane_ok = lane is not None and math.isfinite(lane.heading_rad) and math.isfinite(lane.offset_m)
        if lane_ok:
            if self._previous_lane is not None:
                previous_s, previous_heading = self._previous_lane
                late = speed_mps * (float(lane.heading_rad) - previous_heading) / (time_s - previous_s)
                valid = True
            self._previous_lane = (time_s, float(lane.heading_rad))
        else:
            self._previous_lane = None  # a difference across a gap would mix two intervals
        if not (valid and speed_mps > config.min_speed_mps):
            self._last_invalid_s = time_s
            valid = False
        valid = valid and time_s - self._last_invalid_s >= config.recovery_s - 1e-9
        self._push(time_s, prompt, late, valid)
        if time_s >= self._next_update_s - 1e-9:
            self._next_update_s = time_s + 1.0 / config.update_hz
            self._estimate_window()
        self.last = self._claim()
        return self.last

    def _push(self, time_s: float, prompt: float, late: float, valid: bool) -> None:
        self._times.append(time_s)
        self._prompt.append(prompt)
        self._late.append(late if valid else 0.0)
        self._valid.append(valid)
        self._new_valid = self._new_valid or valid
        while self._times and self._times[0] <= time_s - self.config.window_s - 1e-9:
            for column in (self._times, self._prompt, self._late, self._valid):
                column.popleft()

    def _estimate_window(self) -> None:
        config = self.config
        times = np.asarray(self._times)
        if len(times) < 3:
            return
        dt_s = float(np.median(np.diff(times)))
        mask = np.asarray(self._valid, bool)
        if mask.sum() * dt_s < config.min_valid_s - 1e-9 or not self._new_valid:
            return
        prompt = smoothed(np.asarray(self._prompt), np.ones(len(times), bool))
        late = smoothed(np.asarray(self._late), mask)
        usable = mask & np.isfinite(late)
        lag_s, peak, confidence = window_lag(prompt, np.nan_to_num(late), usable, dt_s, config)
        # The camera's rate is a difference over the tick before: it describes the motion half a tick earlier.
        lag_s -= config.fast_sensor_shift_s + 0.5 * dt_s
        if peak < config.min_ncc or confidence < config.min_confidence:
            return
        self._new_valid = False
        self.windows_accepted += 1
        self._current.append(lag_s)
        if len(self._current) == config.block_size:
            self._blocks.append(float(np.mean(self._current)))
            self._current = []

    def _claim(self) -> CorrelationEstimate:
        config = self.config
        blocks = list(self._blocks)
        if not blocks:
            mean = float(np.mean(self._current)) if self._current else math.nan
            return CorrelationEstimate("unestimated", mean, math.nan, config.prior_latency_s, 0)
        mean, spread = float(np.mean(blocks)), float(np.std(blocks))
        if len(blocks) < config.blocks_needed:
            return CorrelationEstimate("unestimated", mean, spread, config.prior_latency_s, len(blocks))
        if spread > config.max_block_spread_s:
            return CorrelationEstimate("invalid", mean, spread, config.prior_latency_s, len(blocks))
        claimed = min(max(mean, config.min_lag_s), config.max_lag_s)
        return CorrelationEstimate("estimated", claimed, spread, claimed, len(blocks))
