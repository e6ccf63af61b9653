"""How late is the camera? An online estimate of the perception latency from the data stream alone.

No capture timestamp is used. What a car has at every sensor tick ``t`` is its own fast sensors (yaw
rate, speed, front-wheel angle: practically no delay) and, now and then, a lane measurement from the
camera (offset ``d`` and heading ``dpsi`` relative to the lane) that describes the car as it was at
``t - latency``. The estimate is the lag that best aligns the two.

**The alignment.** Dead reckoning from the fast sensors gives, at any past instant, the distance
travelled ``s``, the heading turned ``R = int r dt`` and the lateral displacement
``D = int (u R + v) dt`` (``v`` the body lateral velocity the vehicle model gives for the steering).
In lane coordinates (the lane model of :mod:`plm_highway.lane_ekf.lane_model`, small angles):

    dpsi(c) = dpsi0 + [R(c) - R0] - kappa0 x - kappa1 x^2 / 2
    d(c)    = d0 + dpsi0 x + b x + [D(c) - D0 - R0 x] - kappa0 x^2 / 2 - kappa1 x^3 / 6

with ``x = s(c) - s0``: the lane's heading and offset at capture time ``c`` follow from the car's own
motion, up to five numbers of the lane (offset, heading, curvature and its rate along the window, and a
lateral drift ``b`` that absorbs a slip bias). These enter linearly: for every candidate lag ``tau`` on a
grid, ``c = t - tau`` for each camera sample of a sliding window, the five are fitted by robust least
squares (Huber, the camera errs heavy-tailed) and the fit's cost is the alignment cost of ``tau``. The
lane is rigid and the car moves: at the right lag the car's own weaving cancels out of the implied lane;
at a wrong one it does not. The estimate is the cost's minimum (refined between grid points).

**Uncertainty and "not estimable yet".** The cost is a negative log-likelihood in units of the camera
noise, estimated from the window's own residuals (so an arc, where the lane fit is noisier, is not
over-trusted) and discounted for the residuals' correlation from frame to frame. Its curvature at the
minimum gives the standard deviation of the estimate. A long straight driven without steering makes
every lag fit equally well: the curvature is flat and the estimate is reported as not estimable rather
than as a number. An estimate counts as estimable when its standard deviation is small, no far lag fits
nearly as well, and the window holds enough samples.

**Where the camera errs.** A lane fit errs heavy-tailed and, where a curvature change of the road is in
view (its single parabola spans two segments), with a bias that lasts a second. The robust loss bounds the
pull of such samples and the noise is re-estimated from every window's own residuals, so a window that fits
badly at every lag carries little weight.

**Claims.** An estimate is *claimed* ("estimated") only when it is sure (its standard deviation at most half a
frame, so +-2 sigma spans one frame; no far lag nearly as good), the window and its newest samples agree with it, and
it has held within half a frame for the last ``settle_s``. After a step, or while the newest samples fit another lag
(a split of the window at a recent onset, judged at chi-square 95%), the estimator says "changing" until a new value
has held still; on too little information, "not estimable". Speed is traded for claims that are right: a deployed
lag learner (openpilot's, :mod:`plm_highway.latency.correlation`) makes the same trade on a scale of minutes.

**Steps in the latency.** The samples of the window belong to latency segments. Every new sample, the
current segment is split at a few recent onsets: the older part keeps the current estimate, the newer part
takes the candidate lag, the lane stays one (it does not change when the latency does). When the best split
explains the window clearly better than no split (a generalised likelihood ratio), a new segment starts at
that onset; the samples before it keep their lag and go on pinning the lane until they leave the window.

Everything here is numbers in, numbers out (:class:`LatencyEstimator.update`), so the same estimator
runs inside a closed loop, over a recording (:func:`estimate_stream`) and in the lessons.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.vehicle.models import vehicle_model

HUBER_K = 1.5  # Huber's tuning constant in noise units: 95% efficiency at normal noise, bounded pull of outliers
MAD_TO_STD = 1.4826  # a normal distribution's standard deviation over its median absolute deviation
LENGTH_SCALE_M = 10.0
# A window whose own best lag fits less than this (negative log-likelihood) better than the current lag is not
# split: a step worth the change threshold would show in the window's own curve first (saves the split fits).
SPLIT_WORTH_TESTING = 1.0  # the basis uses x / 10 m: keeps the normal equations well conditioned, changes no fit


@dataclass(frozen=True)
class LatencyEstimatorConfig:
    """What the estimator assumes and how sure it must be; each number says why it is what it is."""

    # Candidate lags: 0 to max_latency_s in steps of lag_step_s. 1 s is the latency wrapper's default buffer; 20 ms is
    # under two thirds of the kit's shortest frame period (30 Hz), and the minimum is refined between grid points.
    max_latency_s: float = 1.0
    lag_step_s: float = 0.02
    # The alignment window: long enough that the lane's five numbers cannot absorb the car's weave (a weave slower
    # than the window looks like lane curvature), short enough for one lane model to hold (about 50 m at 60 km/h).
    # Chosen on the train track between 1.5 s and 3 s (3 s: estimable more often, as often right).
    window_s: float = 3.0
    # The evidence forgets with this time constant: long enough to add up the weak information of smooth driving
    # (the kit's PLM-Net at the right latency weaves by centimetres; on the train track its evidence needs tens of
    # seconds), short enough that a slow drift is followed; a step is caught by the step test, not by forgetting.
    memory_s: float = 60.0
    # At least this many camera samples: the fit has 5 lane numbers and the lag; twice that leaves residuals to judge it.
    min_samples: int = 12
    # Estimable: the standard deviation at most this fraction of the camera's frame period (the median interval
    # between the window's lane samples), so that +-2 sigma spans one frame period, the precision asked of it ...
    max_std_frames: float = 0.5
    # ... and every lag at least far_lag_s from the minimum fits worse by at least this much (negative log-likelihood:
    # 5.4 = chi2(1) at 0.999 / 2), so a second valley on the cost is not taken for the answer.
    far_lag_s: float = 0.1
    far_cost_margin: float = 5.4
    # Floors of the camera noise: a quarter of the kit's lane detector's robust error on the train track (0.041 m,
    # 0.0076 rad, plm_highway.lane_ekf.policy.measure_camera_noise), so a clean stretch is not over-trusted.
    min_offset_noise_m: float = 0.01
    min_heading_noise_rad: float = 0.002
    # A step in the latency: the current segment is split at the onsets split_samples samples back; a split whose
    # newer part fits best at a lag at least change_min_s away (one 20 Hz frame; smaller changes the window follows by
    # itself) and lowers the cost by change_threshold (a log-likelihood ratio of 6: about one false alarm per e^6 =
    # 400 tests) starts a new segment; a segment needs min_segment_samples before its own lag is estimated.
    split_samples: tuple[int, ...] = (4, 8, 16)
    change_threshold: float = 6.0
    # A window that fits another lag better than the evidence's by this much (a likelihood ratio of e^3 = 20) casts
    # doubt: the evidence is not claimed as estimable until they agree again (the step test may need a few samples
    # more to be sure; meanwhile "not estimable" is said rather than the old value).
    doubt_threshold: float = 3.0
    change_min_s: float = 0.05
    min_segment_samples: int = 4
    # A claim must have held still: over the last settle_s the evidence's estimate estimable at every sample and
    # within half a frame of the claim, and the window's own best lag within window_steady_frames frames of it (the
    # spread check of a deployed lag learner, on seconds rather than minutes). A step not yet caught shows as a
    # drift of either and stops the claim. 2 s and 1 frame: chosen on the test track's streams (paper and ideal
    # conditions, constant and time-varying, BM and PLM-Net driving) against 1 s and 1.5 s, 1.5 frames: the
    # shortest settling that left no run with a majority of wrong claims.
    settle_s: float = 2.0
    # The newest samples of the window, fitted at their own lag while the older ones keep the claim: a recent part
    # that fits a lag more than a frame away better by this much (negative log-likelihood; 1.92 = chi2(1) at 0.95 / 2,
    # the claim lies outside the recent samples' 95% confidence set) stops a claim; by change_threshold (below) it
    # says "changing" before the step test is sure.
    recent_threshold: float = 1.92
    # The window must confirm a claim on its own: the claim inside the window's 95% confidence set (cost within
    # recent_threshold of its minimum), and that set no wider than confirm_frames frames either side of the claim.
    # The evidence adds up a minute as if the latency held still; the window says whether it still does.
    confirm_frames: float = 2.0
    # ... and so must the newest recent_s of it, fitted at its own lag while the older samples keep the claim (a step
    # within the window shows there first; the whole window, fitted at one lag, averages over it).
    recent_s: float = 1.0
    recent_confirms: bool = True
    window_steady_frames: float = 1.0
    # After a sign of a change (a step detected, or the newest samples fitting another lag clearly better) nothing is
    # claimed for change_hold_s and "changing" is said meanwhile: a latency that changed once may change again, and
    # one that changes every second or two (the paper's time-varying profiles) lines up by chance for a moment,
    # long enough to settle, just before its next step. 8 s: chosen on the test track's streams against 3 s (half
    # of the few claims under those profiles were still wrong) and no hold; it delays the claims of a constant
    # latency only after a false sign.
    change_hold_s: float = 8.0
    # What a consumer is told before the first estimate: the middle of the paper's time-varying range [0, 0.35] s,
    # the smallest worst-case error with no evidence at all.
    prior_latency_s: float = 0.175
    # The car, for the body lateral velocity its steering makes (the kinematic bicycle's slip, a dynamic car's
    # settled lateral velocity): a name in plm_highway.vehicle.models.VEHICLE_MODELS and its parameter overrides.
    vehicle_model: str = "kinematic"
    # When, relative to its tick, the motion a fast-sensor sample describes happens [s]: 0 for instantaneous samples;
    # -dt/2 for a sample that is the mean over the interval ending at its tick (an IMU's delta angle; the kit's env
    # without a steering actuator); +dt/2 for one that holds over the interval after it (the kit's env with an
    # actuator, whose yaw rate is reported for the wheel angle the next step will use). It shifts the estimate one
    # for one, so it is a calibration of the car's sensors, not something the camera can tell.
    fast_sensor_shift_s: float = 0.0

    def __post_init__(self):
        checks = (
            ("max_latency_s", 0.05, 10.0), ("lag_step_s", 0.001, 0.2), ("window_s", 0.2, 30.0),
            ("memory_s", 0.1, 1e4),
            ("max_std_frames", 0.01, 100.0), ("far_lag_s", 0.0, 10.0), ("far_cost_margin", 0.0, 1e3),
            ("min_offset_noise_m", 1e-5, 10.0), ("min_heading_noise_rad", 1e-6, 1.0),
            ("change_threshold", 0.0, 1e4), ("doubt_threshold", 0.0, 1e4), ("change_min_s", 0.0, 10.0),
            ("prior_latency_s", 0.0, 10.0), ("fast_sensor_shift_s", -1.0, 1.0), ("settle_s", 0.0, 60.0),
            ("recent_threshold", 0.0, 1e4), ("confirm_frames", 0.0, 1e3), ("recent_s", 0.0, 30.0),
            ("window_steady_frames", 0.0, 1e3), ("change_hold_s", 0.0, 600.0),
        )
        for name, low, high in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise BadInput(f"LatencyEstimatorConfig.{name}={value!r}: must be a number in [{low:g}, {high:g}]")
        if isinstance(self.min_samples, bool) or not isinstance(self.min_samples, int) or not 7 <= self.min_samples <= 10_000:
            raise BadInput(f"LatencyEstimatorConfig.min_samples={self.min_samples!r}: must be an integer in [7, 10000]")
        if self.lag_step_s > self.max_latency_s / 2:
            raise BadInput(f"LatencyEstimatorConfig: lag_step_s={self.lag_step_s} leaves fewer than 3 lags up to "
                           f"max_latency_s={self.max_latency_s}")
        for name in ("min_segment_samples",):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= self.min_samples:
                raise BadInput(f"LatencyEstimatorConfig.{name}={value!r}: must be an integer in [1, min_samples]")
        if not (isinstance(self.split_samples, tuple) and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1
                                                              for v in self.split_samples)):
            raise BadInput(f"LatencyEstimatorConfig.split_samples={self.split_samples!r}: must be a tuple of positive "
                           "integers")
        vehicle_model(self.vehicle_model)  # a clear error naming the known models

    @property
    def lags_s(self) -> np.ndarray:
        count = int(math.floor(self.max_latency_s / self.lag_step_s + 1e-9)) + 1
        return np.arange(count) * self.lag_step_s


class FastSample(NamedTuple):
    """The car's own sensors at one tick (on the car's clock)."""

    time_s: float
    yaw_rate_radps: float
    speed_mps: float
    steer_rad: float  # front-wheel angle as measured


class LaneSample(NamedTuple):
    """What the camera reported at this tick about the frame it processed (capture time unknown)."""

    offset_m: float  # d, left positive
    heading_rad: float  # dpsi: car heading minus lane heading


STATES = ("estimated", "changing", "not estimable")  # what an estimate claims (LatencyEstimate.state)
INTERVAL_SIGMAS = 2.0  # an estimate's interval: +-2 standard deviations (about 95%)


class LatencyEstimate(NamedTuple):
    """The estimator's answer at one tick.

    ``state``: "estimated" (``latency_s`` is claimed: its interval lies within a frame of it and it has held still),
    "changing" (the latency has stepped or the newest samples disagree with the last claim, and no new value has held
    still yet) or "not estimable" (the driving carried too little information yet). Whatever the state, ``held_s`` is
    the newest estimate sure enough to use (claimed, or settling after a step) or the prior.
    """

    latency_s: float  # the evidence's best lag (NaN until a window has been fitted)
    std_s: float  # its standard deviation (inf when the cost has no curvature)
    estimable: bool  # state == "estimated"
    held_s: float  # what a consumer should use now: the newest sure estimate (claimed or settling), or the prior
    samples: int  # camera samples in the window behind latency_s
    state: str = "not estimable"

    @property
    def interval_s(self) -> tuple[float, float]:
        """``latency_s`` +- 2 standard deviations, clipped at 0 (a latency is never negative); (nan, nan) without
        an estimate."""
        if not math.isfinite(self.latency_s) or not math.isfinite(self.std_s):
            return (math.nan, math.nan)
        half = INTERVAL_SIGMAS * self.std_s
        return (max(self.latency_s - half, 0.0), self.latency_s + half)


# ----------------------------------------------------------------------------------------------------------------
# dead reckoning
# ----------------------------------------------------------------------------------------------------------------


class DeadReckoning:
    """Distance, heading and lateral displacement integrated from the fast sensors, kept for ``horizon_s``.

    ``s = int u dt``, ``R = int r dt``, ``D = int (u R + v) dt`` (trapezoidal between ticks); any past instant
    in the kept horizon is read by linear interpolation (:meth:`at`).
    """

    def __init__(self, horizon_s: float):
        self.horizon_s = horizon_s
        self._rows: deque[tuple[float, float, float, float]] = deque()
        self._last: tuple[float, float, float] | None = None  # (r, u, v) at the newest tick

    def reset(self) -> None:
        self._rows.clear()
        self._last = None

    @property
    def empty(self) -> bool:
        return not self._rows

    @property
    def oldest_s(self) -> float:
        return self._rows[0][0]

    @property
    def newest(self) -> tuple[float, float, float, float]:
        return self._rows[-1]

    def add(self, time_s: float, yaw_rate_radps: float, speed_mps: float, lateral_velocity_mps: float) -> None:
        if not self._rows:
            self._rows.append((time_s, 0.0, 0.0, 0.0))
        else:
            t0, s0, r0_int, d0_int = self._rows[-1]
            if time_s <= t0:
                raise BadInput(f"fast sensor time {time_s!r} s is not after the previous tick at {t0!r} s")
            r0, u0, v0 = self._last
            dt_s = time_s - t0
            s1 = s0 + 0.5 * (speed_mps + u0) * dt_s
            heading1 = r0_int + 0.5 * (yaw_rate_radps + r0) * dt_s
            lateral1 = d0_int + 0.5 * ((speed_mps * heading1 + lateral_velocity_mps) + (u0 * r0_int + v0)) * dt_s
            self._rows.append((time_s, s1, heading1, lateral1))
        self._last = (yaw_rate_radps, speed_mps, lateral_velocity_mps)
        while len(self._rows) > 2 and self._rows[1][0] <= time_s - self.horizon_s:
            self._rows.popleft()

    def at(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, R, D)`` at ``times_s`` (clamped to the kept horizon)."""
        rows = np.asarray(self._rows)
        return (np.interp(times_s, rows[:, 0], rows[:, 1]), np.interp(times_s, rows[:, 0], rows[:, 2]),
                np.interp(times_s, rows[:, 0], rows[:, 3]))


# ----------------------------------------------------------------------------------------------------------------
# the alignment cost
# ----------------------------------------------------------------------------------------------------------------


class AlignmentFit(NamedTuple):
    """The robust lane fit of a window at every candidate lag."""

    costs: np.ndarray  # (L,) negative log-likelihood per lag, in units of the estimated noise
    best: int  # index of the smallest cost
    residuals: np.ndarray  # (2, n) heading and offset residuals at the best lag [rad, m]


def lane_basis(x_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lane's five numbers' columns for heading and offset rows at distances ``x_m`` (..., n) -> (..., n, 5).

    Columns: offset d0, heading dpsi0, lateral drift b, curvature kappa0, curvature rate kappa1 (the last three
    per ``LENGTH_SCALE_M``, which only conditions the normal equations).
    """
    xs = x_m / LENGTH_SCALE_M
    zeros, ones = np.zeros_like(xs), np.ones_like(xs)
    heading = np.stack([zeros, ones, zeros, -xs, -xs ** 2 / 2], axis=-1)
    offset = np.stack([ones, x_m, x_m, -x_m * xs / 2, -x_m * xs ** 2 / 6], axis=-1)
    return heading, offset


def predicted_motion(s_m, heading_rad, lateral_m, reference) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the car's own motion adds to the lane heading and offset since the reference: (x, heading, offset)."""
    s0, r0, d0 = reference
    x_m = s_m - s0
    return x_m, heading_rad - r0, lateral_m - d0 - r0 * x_m


def huber_cost(normalised: np.ndarray) -> np.ndarray:
    a = np.abs(normalised)
    return np.where(a <= HUBER_K, 0.5 * a * a, HUBER_K * a - 0.5 * HUBER_K ** 2)


def fit_alignment(arrival_s: np.ndarray, lanes: np.ndarray, assigned_s: np.ndarray, lags_s: np.ndarray,
                  reckoning: DeadReckoning, noise: tuple[float, float], iterations: int = 3) -> AlignmentFit:
    """Robust least-squares lane fit of the camera samples at every candidate lag.

    ``lanes`` (n, 2): heading [rad] and offset [m] as the camera reported them at ``arrival_s``; ``assigned_s``
    (n,): a sample's lag when it is already known (an earlier latency segment), NaN for the samples whose lag is
    the candidate. Iteratively reweighted (Huber) in units of ``noise`` = (heading rad, offset m).
    """
    scanned = np.isnan(assigned_s)
    lags = np.where(scanned[None, :], lags_s[:, None], assigned_s[None, :])  # (L, n)
    captures = arrival_s[None, :] - lags
    s_m, heading_rad, lateral_m = reckoning.at(captures)
    s0, r0, d0 = (float(values[0]) for values in reckoning.at(np.array([captures.min()])))
    x_m, own_heading, own_offset = predicted_motion(s_m, heading_rad, lateral_m, (s0, r0, d0))
    basis_heading, basis_offset = lane_basis(x_m)
    n = len(arrival_s)
    design = np.concatenate([basis_heading / noise[0], basis_offset / noise[1]], axis=1)  # (L, 2n, 5)
    target = np.concatenate([(lanes[:, 0][None, :] - own_heading) / noise[0],
                             (lanes[:, 1][None, :] - own_offset) / noise[1]], axis=1)  # (L, 2n)
    transposed = design.transpose(0, 2, 1)
    weights = np.ones_like(target)
    ridge = 1e-9 * np.eye(design.shape[-1])
    for _ in range(iterations):
        normal = (transposed * weights[:, None, :]) @ design + ridge
        rhs = transposed @ (weights * target)[..., None]
        theta = np.linalg.solve(normal, rhs)
        residual = target - (design @ theta)[..., 0]
        magnitude = np.abs(residual)
        weights = np.where(magnitude <= HUBER_K, 1.0, HUBER_K / np.maximum(magnitude, 1e-300))
    costs = huber_cost(residual).sum(axis=1)
    best = int(np.argmin(costs))
    residuals = np.stack([residual[best, :n] * noise[0], residual[best, n:] * noise[1]])
    return AlignmentFit(costs, best, residuals)


def robust_noise(residuals: np.ndarray, floors: tuple[float, float]) -> tuple[float, float]:
    """Per-channel noise from the residuals' median absolute deviation, not below ``floors``."""
    spread = MAD_TO_STD * np.median(np.abs(residuals - np.median(residuals, axis=1, keepdims=True)), axis=1)
    return max(float(spread[0]), floors[0]), max(float(spread[1]), floors[1])


def correlation_discount(residuals: np.ndarray) -> float:
    """``(1 - rho) / (1 + rho)``: the information kept by residuals correlated from sample to sample with lag-one
    autocorrelation ``rho`` (an AR(1) error's variance inflation; 1 for white residuals, capped below at 0.05)."""
    discounts = []
    for channel in residuals:
        centred = channel - channel.mean()
        denominator = float(centred @ centred)
        rho = float(centred[1:] @ centred[:-1]) / denominator if denominator > 0 and len(centred) > 2 else 0.0
        rho = min(max(rho, 0.0), 0.9)
        discounts.append((1.0 - rho) / (1.0 + rho))
    return max(min(discounts), 0.05)


def refine_minimum(costs: np.ndarray, lags_s: np.ndarray, best: int) -> tuple[float, float]:
    """(lag, curvature) of the parabola through the minimum and its neighbours (the grid point at an edge)."""
    step = lags_s[1] - lags_s[0]
    if best == 0 or best == len(costs) - 1:
        inner = 1 if best == 0 else len(costs) - 2
        curvature = max((costs[inner] - costs[best]) / step ** 2 * 2.0, 0.0)
        return float(lags_s[best]), float(curvature)
    left, centre, right = costs[best - 1], costs[best], costs[best + 1]
    curvature = (left - 2.0 * centre + right) / step ** 2
    if curvature <= 0:
        return float(lags_s[best]), 0.0
    offset = float(np.clip(0.5 * (left - right) / (left - 2.0 * centre + right), -0.5, 0.5))
    return float(lags_s[best] + offset * step), float(curvature)


# ----------------------------------------------------------------------------------------------------------------
# the estimator
# ----------------------------------------------------------------------------------------------------------------


class LatencyEstimator:
    """Online perception-latency estimate from fast sensors and late lane measurements (module docstring).

    Call :meth:`update` once per tick, in time order, with the fast sensors and the lane sample that arrived
    at that tick (None when no frame arrived or the lane was not found).

    Two horizons. The *window* (``window_s``) is short enough for the lane model to hold; its cost curve is
    recomputed at every sample. The *evidence* adds up each window's curve, shared out per sample (a window
    of n samples adds 1/n of its curve per new sample, so each sample counts about once), and forgets with the
    time constant ``memory_s``: smooth driving carries little information per second, and a latency that holds
    still is told more sharply the longer it is watched. The estimate is the evidence's minimum.

    A step resets the evidence. The window's samples belong to latency segments: those of the current segment
    take the candidate lag, those of earlier segments keep the lag estimated for them and still pin the lane.
    Every sample the current segment is split at a few recent onsets (``split_samples``); a split that explains
    the window clearly better than none (a generalised likelihood ratio), or a window that clearly contradicts
    the evidence, starts a new segment and new evidence.
    """

    def __init__(self, config: LatencyEstimatorConfig = LatencyEstimatorConfig(), vehicle_params=None):
        self.config = config
        self.model = vehicle_model(config.vehicle_model)
        self.vehicle_params = self.model.default_params if vehicle_params is None else vehicle_params
        self.lags_s = config.lags_s
        self.reckoning = DeadReckoning(config.window_s + config.max_latency_s + 1.0)
        self.reset()

    def reset(self) -> None:
        self.reckoning.reset()
        self._samples: deque[list[float]] = deque()  # [arrival s, heading rad, offset m, assigned lag s or NaN]
        self._noise = (4.0 * self.config.min_heading_noise_rad, 4.0 * self.config.min_offset_noise_m)
        self._evidence = np.zeros(len(self.lags_s))
        self._first_s = math.nan
        self._last_sample_s = math.nan
        self.held_s = self.config.prior_latency_s
        self.last = LatencyEstimate(math.nan, math.inf, False, self.held_s, 0)
        self.changes_detected = 0
        # (arrival s, the evidence's estimate or NaN if not estimable, the window's own best lag s)
        self._judged: deque[tuple[float, float, float]] = deque()
        self._changed_s = -math.inf  # when a step or the newest samples last said the latency changed
        self._recent_gain = 0.0  # the newest samples' best gain at a lag over a frame away (split tests)

    def lateral_velocity_mps(self, steer_rad: float, speed_mps: float) -> float:
        """The body lateral velocity the vehicle model settles to at this steering and speed."""
        return float(self.model.settled(0.0, 0.0, 0.0, steer_rad, speed_mps, self.vehicle_params).lateral_velocity_mps)

    def update(self, fast: FastSample, lane: LaneSample | None = None) -> LatencyEstimate:
        values = (fast.time_s, fast.yaw_rate_radps, fast.speed_mps, fast.steer_rad)
        if not all(math.isfinite(float(v)) for v in values):
            raise BadInput(f"fast sensor sample {tuple(fast)!r}: every value must be finite")
        time_s = float(fast.time_s)
        if math.isnan(self._first_s):
            self._first_s = time_s
        self.reckoning.add(time_s + self.config.fast_sensor_shift_s, float(fast.yaw_rate_radps),
                           float(fast.speed_mps),
                           self.lateral_velocity_mps(float(fast.steer_rad), float(fast.speed_mps)))
        lane_ok = lane is not None and math.isfinite(lane.offset_m) and math.isfinite(lane.heading_rad)
        # A frame that arrived before the stream was max_latency_s old may show a moment before it began:
        # nothing to align it with.
        early = time_s < self._first_s + self.config.max_latency_s - 1e-9
        while self._samples and self._samples[0][0] < time_s - self.config.window_s - 1e-9:
            self._samples.popleft()
        if lane_ok and not early:
            self._samples.append([time_s, float(lane.heading_rad), float(lane.offset_m), math.nan])
            self._forget(time_s)
            self.last = self._estimate()
        elif early:  # nothing to align yet: no fresh estimate
            self.last = self.last._replace(estimable=False, held_s=self.held_s, state="not estimable")
        else:  # a dropped frame: the estimate stands
            self.last = self.last._replace(held_s=self.held_s)
        return self.last

    # -- internals --------------------------------------------------------------------------------------

    def _forget(self, time_s: float) -> None:
        if not math.isnan(self._last_sample_s):
            self._evidence *= math.exp(-(time_s - self._last_sample_s) / self.config.memory_s)
        self._last_sample_s = time_s

    def _arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        samples = np.array(self._samples)
        return samples[:, 0], samples[:, 1:3], samples[:, 3]

    def _window_costs(self, assigned: np.ndarray | None = None) -> tuple[np.ndarray, AlignmentFit, float]:
        """The window's cost curve (discounted for correlated residuals), its fit and the discount."""
        arrivals, lanes, own = self._arrays()
        fit = fit_alignment(arrivals, lanes, own if assigned is None else assigned, self.lags_s, self.reckoning,
                            self._noise)
        discount = correlation_discount(fit.residuals)
        return fit.costs * discount, fit, discount

    def _estimate(self) -> LatencyEstimate:
        config = self.config
        samples = len(self._samples)
        if samples < config.min_samples:
            return LatencyEstimate(math.nan, math.inf, False, self.held_s, samples, self._unclaimed())
        _, _, assigned = self._arrays()
        if np.isnan(assigned).sum() < config.min_segment_samples:  # too few since the last step: keep its guess
            return LatencyEstimate(math.nan, math.inf, False, self.held_s, samples, "changing")
        costs, fit, discount = self._window_costs()
        self._noise = robust_noise(fit.residuals, (config.min_heading_noise_rad, config.min_offset_noise_m))
        self._recent_gain = 0.0
        if self._step_detected(costs, discount):
            self._changed_s = self._samples[-1][0]
            self._judged.clear()
            return self._estimate()
        self._evidence += (costs - costs.min()) / samples
        estimate = self._judge(self._evidence, samples)
        time_s = self._samples[-1][0]
        window_best_s = float(self.lags_s[int(np.argmin(costs))])
        self._judged.append((time_s, estimate.latency_s if estimate.estimable else math.nan, window_best_s))
        while len(self._judged) > 1 and self._judged[1][0] <= time_s - config.settle_s + 1e-9:
            self._judged.popleft()
        # The window contradicting the evidence (a step not yet proven, or a window the lane model does not fit), or
        # its newest samples contradicting it: the latency may be changing.
        current = int(np.argmin(self._evidence))
        if self._recent_gain >= config.change_threshold:
            self._changed_s = time_s
        if float(costs[current] - costs.min()) >= config.doubt_threshold or self._recent_gain >= config.recent_threshold:
            return estimate._replace(estimable=False, held_s=self.held_s, state=self._unclaimed())
        if estimate.estimable:
            # Sure enough to be used (a consumer is better served by it than by a value from before a step), not yet
            # sure enough to be claimed until it has held still.
            self.held_s = estimate.latency_s
            if (time_s - self._changed_s > config.change_hold_s + 1e-9
                    and self._settled(estimate.latency_s, time_s) and self._confirms(costs, estimate.latency_s)
                    and self._recent_agrees(estimate.latency_s, discount)):
                self._changed_s = -math.inf
                return estimate._replace(held_s=self.held_s, state="estimated")
        return estimate._replace(estimable=False, held_s=self.held_s, state=self._unclaimed())

    def _confirms(self, costs: np.ndarray, latency_s: float) -> bool:
        """Whether the window's own cost curve confirms ``latency_s`` (``confirm_frames``)."""
        config = self.config
        plausible = self.lags_s[costs - costs.min() <= config.recent_threshold]
        claim = int(np.argmin(np.abs(self.lags_s - latency_s)))
        reach_s = config.confirm_frames * self._frame_period_s() + self.config.lag_step_s / 2
        return bool(costs[claim] - costs.min() <= config.recent_threshold
                    and np.max(np.abs(plausible - latency_s)) <= reach_s)

    def _recent_agrees(self, latency_s: float, discount: float) -> bool:
        """Whether the newest ``recent_s`` of the window, fitted at its own lag (the older samples of the current
        segment at ``latency_s``), agree with ``latency_s``: no other lag a frame away fits them clearly better
        and (``recent_confirms``) their own curve confirms it."""
        config = self.config
        arrivals, _, assigned = self._arrays()
        scanned = np.flatnonzero(np.isnan(assigned))
        older = scanned[arrivals[scanned] < arrivals[-1] - config.recent_s + 1e-9]
        if not older.size or len(scanned) - older.size < config.min_segment_samples:
            return True  # the whole segment is recent: the window's own test stands for it
        split = assigned.copy()
        split[older] = latency_s
        costs = self._window_costs(split)[1].costs * discount
        best = int(np.argmin(costs))
        gain = float(costs[int(np.argmin(np.abs(self.lags_s - latency_s)))] - costs[best])
        if (float(self.lags_s[best]) - latency_s) ** 2 > self._frame_period_s() ** 2 + 1e-12 \
                and gain >= config.recent_threshold:
            if gain >= config.change_threshold:
                self._changed_s = arrivals[-1]
            return False
        return not config.recent_confirms or self._confirms(costs, latency_s)

    def _unclaimed(self) -> str:
        """"changing" for ``change_hold_s`` after a sign of a change; else "not estimable"."""
        recent = self._samples and self._samples[-1][0] - self._changed_s <= self.config.change_hold_s + 1e-9
        return "changing" if recent else "not estimable"

    def _settled(self, latency_s: float, time_s: float) -> bool:
        """Whether the evidence's estimate was estimable and within half a frame of ``latency_s`` at every sample of
        the last ``settle_s`` (and the record reaches back that far)."""
        if not self._judged or self._judged[0][0] > time_s - self.config.settle_s + 1e-9:
            return False
        values = np.array([value for _, value, _ in self._judged])
        windows = np.array([window for _, _, window in self._judged])
        frame_s = self._frame_period_s()
        return bool(np.all(np.isfinite(values)) and np.max(np.abs(values - latency_s)) <= 0.5 * frame_s + 1e-9
                    and np.max(np.abs(windows - latency_s)) <= self.config.window_steady_frames * frame_s + 1e-9)

    def _judge(self, costs: np.ndarray, samples: int) -> LatencyEstimate:
        config = self.config
        best = int(np.argmin(costs))
        latency_s, curvature = refine_minimum(costs, self.lags_s, best)
        std_s = 1.0 / math.sqrt(curvature) if curvature > 0 else math.inf
        far = np.abs(self.lags_s - self.lags_s[best]) >= config.far_lag_s - 1e-9
        separated = not far.any() or float(costs[far].min() - costs[best]) >= config.far_cost_margin
        estimable = std_s <= config.max_std_frames * self._frame_period_s() and separated
        return LatencyEstimate(latency_s, std_s, bool(estimable), self.held_s, samples)

    def _step_detected(self, costs: np.ndarray, discount: float) -> bool:
        """A step in the latency: restart the evidence (and, for a split, the segment) when the window says so.

        Only a window (or the newer part of a split) that is itself sure of its lag (:meth:`_judge`) may overrule
        the evidence: a window near a curvature change or on a quiet stretch has a shallow, biased curve. Splits
        and the unsplit window are compared on their raw costs, in the units of the unsplit window's discount.
        """
        config = self.config
        if not self._evidence.any():
            return False
        current_s = float(self.lags_s[int(np.argmin(self._evidence))])
        current = int(np.argmin(np.abs(self.lags_s - current_s)))
        if float(costs[current] - costs.min()) < SPLIT_WORTH_TESTING:
            return False  # the window fits best at the current lag: no step in it worth a split
        arrivals, lanes, assigned = self._arrays()
        scanned = np.flatnonzero(np.isnan(assigned))
        unsplit = assigned.copy()
        unsplit[scanned] = current_s
        stay = float(self._window_costs(unsplit)[1].costs[0])  # every sample at the current lag (raw)
        best_gain, best_onset = 0.0, None
        for count in config.split_samples:
            if len(scanned) < count + config.min_segment_samples:
                continue
            onset = scanned[-count]
            split = assigned.copy()
            split[scanned[scanned < onset]] = current_s
            split_costs, split_fit, _ = self._window_costs(split)
            gain = (stay - float(split_fit.costs.min())) * discount
            moved_s = abs(float(self.lags_s[split_fit.best]) - current_s)
            if moved_s > self._frame_period_s() + 1e-9:
                self._recent_gain = max(self._recent_gain, gain)
            if gain > best_gain and self._overrules(split_costs, current_s):
                best_gain, best_onset = gain, onset
        if best_onset is None or best_gain < config.change_threshold:
            if not (self._overrules(costs, current_s)
                    and float(costs[current] - costs.min()) >= config.change_threshold):
                return False
            # The whole window disagrees with the evidence: the step lies further back than the recent onsets
            # tested. Find where: the onset whose split fits best.
            best_onset = self._best_onset(arrivals, lanes, assigned, scanned, current_s)
        for index in scanned[scanned < best_onset]:
            self._samples[index][3] = current_s
        self._evidence = np.zeros(len(self.lags_s))
        self.changes_detected += 1
        return True

    def _best_onset(self, arrivals, lanes, assigned, scanned: np.ndarray, current_s: float) -> int:
        """The sample of the current segment from which on a new lag fits best (the older ones at ``current_s``);
        every second sample that leaves ``min_segment_samples`` on each side is tried."""
        margin = self.config.min_segment_samples
        candidates = scanned[margin:len(scanned) - margin + 1:2]
        if not len(candidates):
            return int(scanned[0])
        best_cost, best_onset = math.inf, int(scanned[0])
        for onset in candidates:
            split = assigned.copy()
            split[scanned[scanned < onset]] = current_s
            raw = float(self._window_costs(split)[1].costs.min())
            if raw < best_cost:
                best_cost, best_onset = raw, int(onset)
        return best_onset

    def _frame_period_s(self) -> float:
        """The camera's frame period as the stream shows it: the median interval between the window's samples."""
        arrivals = [sample[0] for sample in self._samples]
        return float(np.median(np.diff(arrivals))) if len(arrivals) > 1 else math.inf

    def _overrules(self, costs: np.ndarray, current_s: float) -> bool:
        """Whether a cost curve is sure of a lag at least ``change_min_s`` from ``current_s``."""
        verdict = self._judge(costs, len(self._samples))
        return verdict.estimable and abs(verdict.latency_s - current_s) >= self.config.change_min_s - 1e-9


def estimate_stream(time_s, yaw_rate_radps, speed_mps, steer_rad, lane_offset_m, lane_heading_rad,
                    config: LatencyEstimatorConfig = LatencyEstimatorConfig(),
                    vehicle_params=None) -> dict[str, np.ndarray]:
    """Run the estimator over a whole log (arrays of one length; lane values NaN where no frame arrived).

    Returns arrays ``latency_s``, ``std_s``, ``estimable``, ``changing``, ``held_s`` (one per tick).
    """
    columns = [np.asarray(values, dtype=float) for values in (time_s, yaw_rate_radps, speed_mps, steer_rad,
                                                                lane_offset_m, lane_heading_rad)]
    n = len(columns[0])
    if any(column.shape != (n,) for column in columns):
        raise BadInput(f"estimate_stream: every column must be one-dimensional of length {n}, got shapes "
                       f"{[column.shape for column in columns]}")
    estimator = LatencyEstimator(config, vehicle_params)
    out = {"latency_s": np.full(n, np.nan), "std_s": np.full(n, np.inf), "estimable": np.zeros(n, bool),
           "changing": np.zeros(n, bool), "held_s": np.full(n, np.nan)}
    for k in range(n):
        lane = None
        if math.isfinite(columns[4][k]) and math.isfinite(columns[5][k]):
            lane = LaneSample(columns[4][k], columns[5][k])
        estimate = estimator.update(FastSample(columns[0][k], columns[1][k], columns[2][k], columns[3][k]), lane)
        out["latency_s"][k], out["std_s"][k] = estimate.latency_s, estimate.std_s
        out["estimable"][k], out["held_s"][k] = estimate.estimable, estimate.held_s
        out["changing"][k] = estimate.state == "changing"
    return out
