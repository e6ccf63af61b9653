"""A fit problem (a recording, its recorded channels, the folds) and a candidate's fit on it.

:class:`FitProblem` holds everything a candidate fit needs: the recording's inputs, its channels
(primary first, each with the filter that makes a model comparable and the weight that makes every
channel count equally), the folds in time and per channel. :class:`CandidateFit` is one candidate
fitted on each fold's train blocks with its out-of-fold predictions and scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.fit.folds import default_block_s, make_folds
from plm_highway.sim2real.fit.grid import GridChannel, LinearDirection, grid_statistics
from plm_highway.sim2real.physics.chain import CarParams, Drive
from plm_highway.sim2real.physics.effect_spec import STEER_QUANTILES, FitContext
from plm_highway.sim2real.physics.effects import GYRO_ONLY_NEUTRAL, EffectParams
from plm_highway.sim2real.physics.replay import FitSignal, channel_prediction, model_outputs, recorded_channels
from plm_highway.sim2real.record.recording import Recording


def fit_context(recording: Recording) -> FitContext:
    v = recording.vehicle
    usable = recording.usable_mask
    rate = np.abs(np.gradient(recording.steer_rad, recording.dt_s))[usable]
    if recording.lat_accel_mps2 is not None:
        lat = np.abs(recording.lat_accel_mps2[usable])
    elif recording.yaw_rate_radps is not None:
        lat = np.abs(recording.speed_mps * recording.yaw_rate_radps)[usable]
    else:
        lat = np.abs(recording.speed_mps * np.gradient(recording.heading_rad, recording.dt_s))[usable]
    steer = np.abs(recording.steer_rad[usable])
    return FitContext(
        a_m=v.cg_to_front_m, b_m=v.cg_to_rear_m, k2_m2=v.yaw_inertia_per_kg_m2, dt_s=recording.dt_s,
        mass_kg=v.mass_kg, inertia_known=v.inertia_known, u_min_mps=recording.tire_min_speed_mps,
        steer_rate_median_radps=float(np.median(rate)) if rate.size else 0.05,
        steer_rate_max_radps=float(np.percentile(rate, 99.5)) if rate.size else 0.5,
        max_lat_accel_mps2=float(np.percentile(lat, 99.5)) if lat.size else 4.0,
        steer_quantiles_rad=tuple(float(q) for q in np.quantile(steer, STEER_QUANTILES)) if steer.size else (),
        speed_median_mps=float(np.median(recording.speed_mps[usable])) if usable.any() else 0.0,
    )


@dataclass
class FitProblem:
    """Everything a candidate fit needs: the recording, its channels (primary first), the folds."""

    recording: Recording
    channels: list[FitSignal]
    time_folds: list[tuple[np.ndarray, np.ndarray]]  # (train, held-out) in time, before channel masks

    def __post_init__(self):
        rec = self.recording
        self.signal = self.channels[0]
        self.ctx = fit_context(rec)
        self.steer = np.ascontiguousarray(rec.steer_rad, float)
        self.speed = np.ascontiguousarray(rec.speed_mps, float)
        self.dt = rec.dt_s
        self.y = np.ascontiguousarray(self.signal.values, float)
        self.channel_folds = [[(train & c.usable, test & c.usable) for train, test in self.time_folds]
                              for c in self.channels]
        self.folds = self.channel_folds[0]
        self.heldout = np.zeros(rec.n, bool)
        for _, test in self.folds:
            self.heldout |= test
        self.fit_mask = self.signal.usable
        plain = self.predictions(EffectParams())
        self.plain_predictions = plain
        # Each channel counts equally: weight by the inverse of the plain model's mean-square error.
        self.weights = []
        for c, pred in zip(self.channels, plain):
            err = (pred - c.values)[c.usable]
            floor = max((1e-3 * c.noise_sigma) ** 2 if math.isfinite(c.noise_sigma) else 0.0, 1e-30)
            mse = max(float(np.mean(err**2)) if err.size else 1.0, floor)
            self.weights.append(1.0 / (mse * max(err.size, 1)))

    def outputs(self, params: EffectParams):
        return model_outputs(self.recording, params)

    def predictions(self, params: EffectParams) -> list[np.ndarray]:
        out = model_outputs(self.recording, params, with_slip=False)
        return [channel_prediction(c, self.recording, params, out, turns=self._turns(i))
                for i, c in enumerate(self.channels)]

    def predictions_at(self, params: EffectParams, indices: list[np.ndarray]) -> list[np.ndarray]:
        out = model_outputs(self.recording, params, with_slip=False)
        return [channel_prediction(c, self.recording, params, out, idx, turns=self._turns(i))
                for i, (c, idx) in enumerate(zip(self.channels, indices))]

    def _turns(self, channel: int) -> dict:
        """Channel ``channel``'s kept heading turns (see ``replay.channel_prediction``)."""
        turns = self.__dict__.setdefault("_turns_by_channel", {})
        return turns.setdefault(channel, {})

    def predict(self, params: EffectParams) -> np.ndarray:
        """The primary channel as the model with ``params`` predicts it."""
        return channel_prediction(self.signal, self.recording, params)

    def grid_gram(self, points: np.ndarray, linear: list[LinearDirection]) -> np.ndarray:
        """Grid statistics on the primary channel (see ``grid.grid_statistics``)."""
        weight = np.ascontiguousarray(np.array([train for train, _ in self.folds], dtype=float))
        c = self.signal
        if not c.late:  # what acts on the gyro alone leaves the other channels as they are
            points = points.copy()
            for name, neutral in GYRO_ONLY_NEUTRAL.items():
                points[name] = neutral
        ctx = self.ctx
        return grid_statistics(Drive(self.steer, self.speed, self.dt), CarParams(ctx.a_m, ctx.b_m, ctx.k2_m2,
                                                                                 ctx.u_min_mps),
                               points, GridChannel(self.y, np.ascontiguousarray(c.taps, float), c.lo), weight, linear)


@dataclass
class CandidateFit:
    effects: tuple[str, ...]
    params: EffectParams  # fitted on all usable samples (winner, runner-up) or on the first fold
    dof: int
    train_mse: float  # primary channel, mean over folds
    heldout_mse: float  # primary channel, out-of-fold
    fold_params: list[EffectParams] = field(default_factory=list)
    score: float = math.nan
    estimates: dict[str, dict[str, float]] = field(default_factory=dict)  # public names
    ci95: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    refitted: bool = False
    oof: list[np.ndarray] = field(default_factory=list)  # out-of-fold prediction per channel
    shapes: list[np.ndarray | None] = field(default_factory=list)  # error-variance shape per channel
    channel_mse: dict[str, float] = field(default_factory=dict)  # held-out per channel
    raw_score: float = math.nan  # before the complexity penalty
    polished: bool = True  # False: the best grid point (a screened-out candidate)
    starts: list = field(default_factory=list)  # per fold, the grid points polishing starts from
    grid_score: float = math.nan  # the score at the best grid point (before polishing)

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "plain"

    @property
    def heldout_rmse(self) -> float:
        return math.sqrt(self.heldout_mse)


def heldout_mask(problem: FitProblem, channel: int) -> np.ndarray:
    mask = np.zeros(problem.recording.n, bool)
    for _, test in problem.channel_folds[channel]:
        mask |= test
    return mask


def make_problem(recording: Recording, signal: FitSignal | str = "auto", block_s: float | None = None,
                 split: str = "blocks") -> FitProblem:
    channels = recorded_channels(recording, signal) if isinstance(signal, str) else [signal]
    block_s = default_block_s(recording.duration_s, recording.dt_s) if block_s is None else block_s
    time_folds = make_folds(recording.t_s, np.ones(recording.n, bool), split, block_s)
    return FitProblem(recording, channels, time_folds)
