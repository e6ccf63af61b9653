"""Which effect (or pair of effects) explains the mismatch: fit each inside the model, judge held out.

1. **Split** the recording into alternating blocks in time and use them for 2-fold
   cross-validation: fit on the even blocks and predict the odd ones, then the other way round.
   Every usable sample gets an out-of-fold prediction, both folds see every kind of driving, and no
   fit is scored on samples it saw. (``split="halves"``: fit on the first half, score the second.)
2. **Candidates**: the plain model, every effect of the registry alone (``effects.EFFECTS``; an
   effect that needs tires brings ``tire_slip``, one that needs a recorded channel is tried only
   with it), then pairs by forward selection: each of the best ``LEAD_SINGLES`` singles with every
   single that beats the plain model, and every pair among the best ``TOP_SINGLES``; then, around
   the best ``NEIGHBOURHOOD`` candidates, each effect swapped for its refinement or its simpler
   version (``tire_slip`` <-> ``tire_saturation``, ``transport_delay`` <-> ``delay_jitter``).
3. **Fit** each candidate on each fold's train blocks. Its nonlinear parameters (delays, time
   constant, tires, rate limit, friction) go on the registry's grids, simulated as one parallel
   batch on the primary channel that serves both folds; its linear parameters (gain, offset, bank)
   are solved in closed form at every grid point. A grid larger than ``MAX_GRID_POINTS`` is seeded
   with each effect's best single-effect grid points. The best grid points are then polished with
   ``scipy.optimize.least_squares`` (trust-region reflective, bounded) on **all recorded
   channels** (yaw rate, heading rate, lateral velocity from positions), each weighted by the
   inverse of the plain model's mean-square error on it, so that each channel counts as much as
   the others whatever its unit. Fitting the effect *inside* the model is what keeps a tire-slip
   recording (an apparent ~0.1 s lag to input-output cross-correlation) from being called a
   transport delay: a delay shifts the yaw rate, tire slip also scales it with speed.
4. **Judge** on held-out samples: per channel the mean-square error (for an effect that shapes the
   error variance, ``delay_jitter``, its Gaussian likelihood written as an equivalent mean-square
   error), combined as the geometric mean over channels (the determinant criterion of system
   identification: a change counts by its ratio on every channel), times ``1 + 0.01 p`` for ``p``
   fitted parameters. A pair must also be *clearly* better than its simpler version (step 5's
   test), or the simpler one is kept.
5. **Decide**: a mismatch needs the winner to beat the plain model clearly, either consistently
   across held-out stretches (t statistic of the per-second log ratio of the two scores above 3) or
   in total (95% block-bootstrap interval of the score ratio above 1: effects that show only in
   some manoeuvres), and by more than a tenth of the primary channel's noise variance.

The winner and the runner-up are refitted on all usable samples; 95% intervals from the
least-squares Jacobian with the residual variance inflated for autocorrelation (AR(1) effective
sample size), derived quantities by the delta method; the jitter from a block bootstrap of its
variance regression.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares, nnls

from plm_highway.sim2real.effects import (
    BANK,
    DELAY,
    EFFECTS,
    GAIN,
    N_SLOTS,
    OFFSET,
    SENSOR,
    EffectParams,
    FitContext,
    coordinates_of,
    effect_report,
    grid_statistics,
    params_from,
    profile_linear,
)
from plm_highway.sim2real.recording import Recording
from plm_highway.sim2real.replay import (
    FitSignal,
    channel_prediction,
    model_outputs,
    recorded_channels,
)
from plm_highway.vehicle.tires import GRAVITY_MPS2

PENALTY_PER_PARAMETER = 0.01
T_STAT_THRESHOLD = 3.0
T_BLOCK_S = 1.0
NOISE_FRACTION = 0.1  # the improvement must exceed this fraction of the noise variance
SPLITS = ("blocks", "halves")
MAX_GRID_POINTS = 1200
SEED_POINTS = 6
TOP_SINGLES = 4
LEAD_SINGLES = 2
NEIGHBOURHOOD = 3
RUNNER_UP_CONTENDERS = 3
N_POLISH = 2
MAX_POLISH_EVALUATIONS = 40
# Grid fits scoring within this factor of the best are polished (a finer delay or stiffness than
# the grid's moves a score by a few per cent, well under this).
POLISH_WITHIN = 1.3
BOOTSTRAP_RESAMPLES = 1000
BOOTSTRAP_DECISION_RESAMPLES = 400
MIN_BLOCKS = 4  # alternating blocks the recording must hold (two per fold)

# Linear coordinates: the chain slot each sets, its finite-difference step there, and bounds there.
LINEAR_SLOTS = {
    "gain": (GAIN, 1e-3, (0.2, 5.0)),
    "offset_rad": (OFFSET, 1e-4, (-0.2, 0.2)),
    "bank_rad": (BANK, 1e-3, (GRAVITY_MPS2 * math.sin(-0.3), GRAVITY_MPS2 * math.sin(0.3))),
}
VARIANCE_PARAMETERS = {"jitter_s"}
JITTER_ITERATIONS = 2
JITTER_MAX_S = 0.5


def default_block_s(duration_s: float, dt_s: float = 0.02) -> float:
    """duration/16 within 2.5-8 s, and at least 25 samples."""
    return float(max(np.clip(duration_s / 16.0, 2.5, 8.0), 25 * dt_s))


def check_block_s(block_s: float, usable_duration_s: float) -> None:
    """Refuse blocks too long for cross-validation: the recording must hold ``MIN_BLOCKS`` of them."""
    if not (math.isfinite(block_s) and block_s > 0):
        raise ValueError(f"--block-s must be a positive number of seconds (got {block_s!r})")
    if MIN_BLOCKS * block_s > usable_duration_s:
        raise ValueError(f"--block-s {block_s:g} s is too long: the {usable_duration_s:.1f} s recording holds fewer "
                         f"than {MIN_BLOCKS} alternating blocks (two per fold); use at most "
                         f"{usable_duration_s / MIN_BLOCKS:.1f} s")


def make_folds(t_s: np.ndarray, usable: np.ndarray, split: str = "blocks", block_s: float = 8.0
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, held-out) mask pairs; held-out masks are disjoint."""
    if split == "blocks":
        block = np.floor((t_s - t_s[0]) / block_s).astype(int)
        even = block % 2 == 0
        return [(even & usable, ~even & usable), (~even & usable, even & usable)]
    if split == "halves":
        first = t_s < t_s[0] + 0.5 * (t_s[-1] - t_s[0])
        return [(first & usable, ~first & usable)]
    raise ValueError(f"unknown split {split!r}; known: {', '.join(SPLITS)}")


def expand(effects: tuple[str, ...]) -> tuple[str, ...]:
    """Add what effects need (road_bank -> tire_slip), in registry order."""
    chosen = set(effects)
    for name in effects:
        need = EFFECTS[name].needs_group
        if need and not any(EFFECTS[e].group == need for e in chosen):
            chosen.add(next(e for e in EFFECTS if EFFECTS[e].group == need))
    return tuple(e for e in EFFECTS if e in chosen)


def compatible(effects: tuple[str, ...]) -> bool:
    groups = [EFFECTS[e].group for e in effects if EFFECTS[e].group]
    return len(groups) == len(set(groups))


def available_effects(channels: list[FitSignal]) -> list[str]:
    names = {c.name for c in channels}
    out = []
    for name, effect in EFFECTS.items():
        if effect.needs_channel and (effect.needs_channel not in names or len(channels) < 2):
            continue  # a late gyro only shows against another channel
        out.append(name)
    return out


def singles(available: list[str]) -> list[tuple[str, ...]]:
    out = []
    for name in available:
        c = expand((name,))
        if c not in out:
            out.append(c)
    return out


def pairs_of(single_candidates: list[tuple[str, ...]], lead: int | None = None) -> list[tuple[str, ...]]:
    """Compatible pairs of the candidates; with ``lead``, only pairs containing one of the first
    ``lead`` candidates (forward selection from the best singles)."""
    out = []
    for i, j in itertools.combinations(range(len(single_candidates)), 2):
        if lead is not None and i >= lead:
            continue
        a, b = single_candidates[i], single_candidates[j]
        c = expand(tuple(set(a) | set(b)))
        if compatible(c) and c not in out and c not in single_candidates:
            out.append(c)
    return out


def all_candidates(available: list[str] | None = None) -> list[tuple[str, ...]]:
    """The plain model, each effect alone, and each compatible pair, in a fixed order."""
    s = singles(list(EFFECTS) if available is None else available)
    return [()] + s + pairs_of(s)


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
    return FitContext(
        a_m=v.cg_to_front_m, b_m=v.cg_to_rear_m, k2_m2=v.yaw_inertia_per_kg_m2, dt_s=recording.dt_s,
        mass_kg=v.mass_kg, inertia_known=v.inertia_known, u_min_mps=recording.tire_min_speed_mps,
        steer_rate_median_radps=float(np.median(rate)) if rate.size else 0.05,
        steer_rate_max_radps=float(np.percentile(rate, 99.5)) if rate.size else 0.5,
        max_lat_accel_mps2=float(np.percentile(lat, 99.5)) if lat.size else 4.0,
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
        return [channel_prediction(c, self.recording, params, out) for c in self.channels]

    def predictions_at(self, params: EffectParams, indices: list[np.ndarray]) -> list[np.ndarray]:
        out = model_outputs(self.recording, params, with_slip=False)
        return [channel_prediction(c, self.recording, params, out, idx) for c, idx in zip(self.channels, indices)]

    def predict(self, params: EffectParams) -> np.ndarray:
        """The primary channel as the model with ``params`` predicts it."""
        return channel_prediction(self.signal, self.recording, params)

    def grid_gram(self, points: np.ndarray, linear_slots: list[int], steps: list[float]) -> np.ndarray:
        """Grid statistics on the primary channel (see ``effects.grid_statistics``)."""
        weight = np.ascontiguousarray(np.array([train for train, _ in self.folds], dtype=float))
        c = self.signal
        if not c.late:  # a sensor delay acts on the gyro only
            points = points.copy()
            points[:, SENSOR] = 0.0
        return grid_statistics(self.steer, self.speed, self.dt, points, self.ctx.a_m, self.ctx.b_m, self.ctx.k2_m2,
                               self.ctx.u_min_mps, np.ascontiguousarray(c.taps, float), c.lo, self.y, weight,
                               linear_slots, steps)


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


# ----------------------------------------------------------------------------------------------
# Coordinates


@dataclass(frozen=True)
class Coordinate:
    key: str  # "effect.parameter"
    effect: str
    name: str
    scale: float
    lo: float
    hi: float
    linear: bool
    variance: bool


def coordinates(effects: tuple[str, ...], ctx: FitContext) -> list[Coordinate]:
    out = []
    for e in effects:
        for p in EFFECTS[e].parameters:
            lo, hi = p.bounds_for(ctx)
            out.append(Coordinate(f"{e}.{p.name}", e, p.name, p.scale, lo, hi, p.linear,
                                  p.name in VARIANCE_PARAMETERS))
    return out


def _neutral_value(c: Coordinate) -> float:
    return 1.0 if c.name == "gain" else 0.0


def _slot_params(slots: np.ndarray, jitter_s: float = 0.0) -> EffectParams:
    cf = float(slots[5])
    return EffectParams(gain=float(slots[GAIN]), offset_rad=float(slots[OFFSET]), delay_s=float(slots[DELAY]),
                        time_constant_s=float(slots[3]), max_rate_radps=float(slots[4]),
                        cf_per_kg=cf if cf > 0 else None, cr_per_kg=float(slots[6]) if cf > 0 else None,
                        friction_coefficient=float(slots[7]), bank_accel_mps2=float(slots[BANK]),
                        sensor_delay_s=float(slots[9]), jitter_s=float(slots[10]) if len(slots) > 10 else jitter_s)


# ----------------------------------------------------------------------------------------------
# Grids


@dataclass
class FitCache:
    """Grid statistics shared between candidates, and each effect's best grid rows alone."""

    grams: dict = field(default_factory=dict)
    top_rows: dict[str, np.ndarray] = field(default_factory=dict)


def _effect_grid(effect: str, ctx: FitContext) -> np.ndarray:
    return EFFECTS[effect].grid(ctx)


def _candidate_grid(effects: tuple[str, ...], ctx: FitContext, cache: FitCache) -> list[np.ndarray]:
    """Grid rows per effect (nonlinear coordinates), combined as a product or, when too large,
    seeded: each effect's full grid against the others' best single-effect rows."""
    grids = {e: _effect_grid(e, ctx) for e in effects}
    nonlinear = [e for e in effects if grids[e].shape[1] > 0]
    size = int(np.prod([grids[e].shape[0] for e in nonlinear])) if nonlinear else 1
    if size <= MAX_GRID_POINTS or len(nonlinear) < 2 or any(e not in cache.top_rows for e in nonlinear):
        return [_product([grids[e] for e in effects])]
    blocks = []
    for e in nonlinear:
        axes = [grids[o] if o == e else (cache.top_rows[o] if o in nonlinear else grids[o]) for o in effects]
        blocks.append(_product(axes))
    return blocks


def _product(axes: list[np.ndarray]) -> np.ndarray:
    rows = [np.zeros(0)]
    for axis in axes:
        rows = [np.concatenate([r, a]) for r in rows for a in (axis if axis.shape[1] else np.zeros((1, 0)))]
    return np.array(rows)


def _slots_of_rows(effects: tuple[str, ...], coords: list[Coordinate], rows: np.ndarray, ctx: FitContext
                   ) -> np.ndarray:
    nonlinear = [c for c in coords if not c.linear]
    out = np.empty((rows.shape[0], N_SLOTS))
    for i, row in enumerate(rows):
        values = {c.key: float(v) for c, v in zip(nonlinear, row)}
        values |= {c.key: _neutral_value(c) for c in coords if c.linear}
        out[i] = params_from(effects, values, ctx).slots()
    return out


def _polish_starts(sse: np.ndarray, rows: np.ndarray, scales: np.ndarray) -> list[int]:
    """The best grid point, plus up to ``N_POLISH - 1`` runners-up from other basins.

    A runner-up is polished only if its grid error is within 20% of the best and some nonlinear
    coordinate is more than one typical scale away from every start already taken.
    """
    order = np.argsort(sse)
    starts = [int(order[0])]
    for idx in order[1:]:
        if len(starts) >= N_POLISH or sse[idx] > 1.2 * sse[order[0]]:
            break
        if rows.shape[1] == 0:
            break
        far = all(np.any(np.abs(rows[idx] - rows[j]) > scales) for j in starts)
        if far:
            starts.append(int(idx))
    return starts


# ----------------------------------------------------------------------------------------------
# Polishing (scipy.optimize.least_squares)


@dataclass
class Polished:
    values: dict[str, float]  # coordinates
    cost: float  # weighted sum of squares
    jacobian: np.ndarray  # of the weighted residual, in coordinate units
    residual: np.ndarray  # weighted, stacked over channels
    primary_residual: np.ndarray  # unweighted primary-channel residual on its mask
    keys: list[str]


def polish(problem: FitProblem, effects: tuple[str, ...], start: dict[str, float], masks: list[np.ndarray]
           ) -> Polished:
    """Least squares over every mean coordinate on all channels (``masks`` per channel)."""
    coords = [c for c in coordinates(effects, problem.ctx) if not c.variance]
    fixed = {c.key: start.get(c.key, 0.0) for c in coordinates(effects, problem.ctx) if c.variance}
    scale = np.array([c.scale for c in coords])
    lo = np.array([c.lo for c in coords])
    hi = np.array([c.hi for c in coords])
    x0 = np.clip(np.array([start[c.key] for c in coords], float), lo, hi)
    sqrt_w = [math.sqrt(w) for w in problem.weights]
    indices = [np.flatnonzero(m) for m in masks]
    ys = [c.values[i] for c, i in zip(problem.channels, indices)]

    def params(z: np.ndarray) -> EffectParams:
        return params_from(effects, dict(zip([c.key for c in coords], z * scale)) | fixed, problem.ctx)

    def residual(z: np.ndarray) -> np.ndarray:
        preds = problem.predictions_at(params(z), indices)
        return np.concatenate([sw * (p - y) for sw, p, y in zip(sqrt_w, preds, ys)])

    result = least_squares(residual, x0 / scale, bounds=(lo / scale, hi / scale), method="trf", diff_step=1e-4,
                           ftol=1e-7, xtol=1e-6, gtol=1e-12, max_nfev=MAX_POLISH_EVALUATIONS)
    values = dict(zip([c.key for c in coords], result.x * scale)) | fixed
    n_primary = int(masks[0].sum())
    primary = result.fun[:n_primary] / sqrt_w[0]
    return Polished(values, float(result.fun @ result.fun), result.jac / scale, result.fun, primary,
                    [c.key for c in coords])


# ----------------------------------------------------------------------------------------------
# Variance (delay jitter)


def _delay_sensitivity(problem: FitProblem, params: EffectParams, step_s: float = 1e-3) -> np.ndarray:
    """d(primary channel)/d(delay): the yaw-rate scatter per second of delay jitter."""
    base = problem.predict(params)
    return (problem.predict(replace(params, delay_s=params.delay_s + step_s)) - base) / step_s


def fit_jitter(residual: np.ndarray, sensitivity: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(noise variance, jitter variance) from ``residual^2 ~ s0 + j^2 sensitivity^2`` (non-negative LS)."""
    e2 = residual[mask] ** 2
    g2 = sensitivity[mask] ** 2
    if e2.size < 10:
        return float(np.mean(e2)) if e2.size else 1.0, 0.0
    scale_e, scale_g = max(float(np.mean(e2)), 1e-300), max(float(np.mean(g2)), 1e-300)
    design = np.column_stack([np.ones_like(g2), g2 / scale_g])
    coef, _ = nnls(design, e2 / scale_e)
    s0 = max(coef[0] * scale_e, 1e-6 * scale_e)
    return float(s0), float(coef[1] * scale_e / scale_g)


# ----------------------------------------------------------------------------------------------
# Fitting candidates


def _candidate_dof(effects: tuple[str, ...]) -> int:
    return sum(EFFECTS[e].dof for e in effects)


def _fold_starts(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], blocks, grams,
                 fold: int) -> list[EffectParams]:
    """The best grid points (linear terms profiled in closed form) on one fold's train blocks."""
    linear = [c for c in coords if c.linear and not c.variance]
    lo = np.array([LINEAR_SLOTS[c.name][2][0] for c in linear])
    hi = np.array([LINEAR_SLOTS[c.name][2][1] for c in linear])
    parts = []
    for (rows, slots), gram in zip(blocks, grams):
        base = slots[:, [LINEAR_SLOTS[c.name][0] for c in linear]] if linear else np.zeros((len(rows), 0))
        sse, solved = profile_linear(gram[:, fold], lo, hi, base)
        parts.append((sse, rows, slots, solved))
    sse_all, rows_all, slots_all, solved_all = (np.concatenate([p[i] for p in parts]) for i in range(4))
    scales = np.array([c.scale for c in coords if not c.linear])
    starts = []
    for idx in _polish_starts(sse_all, rows_all, scales):
        slots = slots_all[idx].copy()
        for j, c in enumerate(linear):
            slots[LINEAR_SLOTS[c.name][0]] = solved_all[idx, j]
        starts.append(params_from(effects, coordinates_of(effects, _slot_params(slots), problem.ctx), problem.ctx))
    return starts


def _polish_fold(problem: FitProblem, effects: tuple[str, ...], starts: list[EffectParams], fold: int
                 ) -> EffectParams:
    """Polish each start on one fold's train masks (all channels); keep the best."""
    masks = [folds[fold][0] for folds in problem.channel_folds]
    best = None
    for start in starts:
        result = polish(problem, effects, coordinates_of(effects, start, problem.ctx), masks)
        if best is None or result.cost < best.cost:
            best = result
    return params_from(effects, best.values, problem.ctx)


def _grid_blocks(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], cache: FitCache):
    linear = [c for c in coords if c.linear and not c.variance]
    linear_slots = [LINEAR_SLOTS[c.name][0] for c in linear]
    steps = [LINEAR_SLOTS[c.name][1] for c in linear]
    blocks, grams = [], []
    for rows in _candidate_grid(effects, problem.ctx, cache):
        slots = _slots_of_rows(effects, coords, rows, problem.ctx)
        key = (slots.tobytes(), tuple(linear_slots))
        if key not in cache.grams:
            cache.grams[key] = problem.grid_gram(slots, linear_slots, steps)
        blocks.append((rows, slots))
        grams.append(cache.grams[key])
    return blocks, grams


def _remember_top_rows(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], blocks, grams,
                       cache: FitCache) -> None:
    """A single effect's best grid rows (summed over folds): seeds for large pair grids."""
    own = [e for e in effects if e not in cache.top_rows and _effect_grid(e, problem.ctx).shape[1] > 0]
    if not own or len(blocks) != 1:
        return
    (rows, slots), gram = blocks[0], grams[0]
    linear = [c for c in coords if c.linear and not c.variance]
    lo = np.array([LINEAR_SLOTS[c.name][2][0] for c in linear])
    hi = np.array([LINEAR_SLOTS[c.name][2][1] for c in linear])
    base = slots[:, [LINEAR_SLOTS[c.name][0] for c in linear]] if linear else np.zeros((len(rows), 0))
    total = sum(profile_linear(gram[:, f], lo, hi, base)[0] for f in range(gram.shape[1]))
    order = np.argsort(total)
    column = 0
    for e in effects:
        width = _effect_grid(e, problem.ctx).shape[1]
        if e in own:
            chosen = []
            for idx in order:
                row = rows[idx, column:column + width]
                if not any(np.allclose(row, c) for c in chosen):
                    chosen.append(row)
                if len(chosen) >= SEED_POINTS:
                    break
            cache.top_rows[e] = np.array(chosen)
        column += width


def fit_candidate(problem: FitProblem, effects: tuple[str, ...], cache: FitCache | None = None,
                  polished: bool = True) -> CandidateFit:
    """Fit one candidate on each fold's train blocks and predict its held-out blocks.

    ``polished=False`` stops at the best grid point (linear terms solved); :func:`polish_candidate`
    finishes it later (the screening of candidates that cannot win uses grid fits).
    """
    cache = FitCache() if cache is None else cache
    if not effects:
        plain = _scored(problem, effects, [EffectParams() for _ in problem.time_folds], [], True)
        plain.grid_score = plain.score
        return plain
    coords = coordinates(effects, problem.ctx)
    blocks, grams = _grid_blocks(problem, effects, coords, cache)
    _remember_top_rows(problem, effects, coords, blocks, grams, cache)
    starts = [_fold_starts(problem, effects, coords, blocks, grams, f) for f in range(len(problem.time_folds))]
    grid_fit = _scored(problem, effects, [s[0] for s in starts], starts, False)
    grid_fit.grid_score = grid_fit.score
    return grid_fit if not polished else polish_candidate(problem, grid_fit)


def polish_candidate(problem: FitProblem, fit: CandidateFit) -> CandidateFit:
    """A grid fit polished (returns ``fit`` itself when it already is)."""
    if fit.polished:
        return fit
    params = [_polish_fold(problem, fit.effects, s, f) for f, s in enumerate(fit.starts)]
    polished = _scored(problem, fit.effects, params, fit.starts, True)
    polished.grid_score = fit.grid_score
    return polished


def _scored(problem: FitProblem, effects: tuple[str, ...], fold_params: list[EffectParams], starts: list,
            polished: bool) -> CandidateFit:
    """Held-out predictions (and the jitter's variance model) of per-fold parameters, and scores."""
    n_channels = len(problem.channels)
    oof = [np.full(problem.recording.n, np.nan) for _ in range(n_channels)]
    shapes: list[np.ndarray | None] = [None] * n_channels
    variance = any(EFFECTS[e].varies_noise for e in effects)
    train_sse, train_n = 0.0, 0
    for f, params in enumerate(fold_params):
        preds = problem.predictions(params) if effects else problem.plain_predictions
        train0, test0 = problem.folds[f]
        if variance:
            # The jitter shows in the scatter: regress it, then refit the mean (which it smooths).
            for _ in range(JITTER_ITERATIONS if polished else 1):
                sens = _delay_sensitivity(problem, params)
                s0, j2 = fit_jitter(problem.y - preds[0], sens, train0)
                params = replace(params, jitter_s=min(math.sqrt(j2), JITTER_MAX_S))
                if polished:
                    params = _polish_fold(problem, effects, [params], f)
                preds = problem.predictions(params)
            sens = _delay_sensitivity(problem, params)
            s0, j2 = fit_jitter(problem.y - preds[0], sens, train0)
            fold_params[f] = params = replace(params, jitter_s=min(math.sqrt(j2), JITTER_MAX_S))
            shape = (s0 + j2 * sens**2) / s0
            if shapes[0] is None:
                shapes[0] = np.ones(problem.recording.n)
            shapes[0][test0] = shape[test0]
        for i, pred in enumerate(preds):
            test = problem.channel_folds[i][f][1]
            oof[i][test] = pred[test]
        train_sse += float(np.sum((preds[0] - problem.y)[train0] ** 2))
        train_n += int(train0.sum())
    err = oof[0] - problem.y
    held = problem.heldout
    fit = CandidateFit(effects, fold_params[0], _candidate_dof(effects), train_sse / max(train_n, 1),
                       float(np.sum(err[held] ** 2)) / max(int(held.sum()), 1), fold_params=fold_params, oof=oof,
                       shapes=shapes, polished=polished, starts=starts)
    fit.channel_mse = {c.name: _mse(oof[i], c.values, _heldout_mask(problem, i))
                       for i, c in enumerate(problem.channels)}
    fit.raw_score = combined_score(problem, fit)
    fit.score = fit.raw_score * (1.0 + PENALTY_PER_PARAMETER * fit.dof)
    if effects:  # until refitted: the mean of the folds' estimates, without intervals
        per_fold = [_public(problem, effects, p) for p in fold_params]
        for (e, k) in per_fold[0]:
            fit.estimates.setdefault(e, {})[k] = float(np.mean([pf[(e, k)] for pf in per_fold]))
    return fit


def _heldout_mask(problem: FitProblem, channel: int) -> np.ndarray:
    mask = np.zeros(problem.recording.n, bool)
    for _, test in problem.channel_folds[channel]:
        mask |= test
    return mask


def _mse(pred: np.ndarray, values: np.ndarray, mask: np.ndarray) -> float:
    return float(np.mean((pred - values)[mask] ** 2)) if mask.any() else math.nan


def _equivalent_mse(err2: np.ndarray, shape: np.ndarray | None) -> float:
    """Gaussian likelihood with error variance proportional to ``shape`` (scale profiled out), as the
    mean-square error of a constant-variance model with the same likelihood. Constant shape: the MSE."""
    if err2.size == 0:
        return math.nan
    if shape is None:
        return float(np.mean(err2))
    return float(np.mean(err2 / shape) * np.exp(np.mean(np.log(shape))))


def combined_score(problem: FitProblem, fit: CandidateFit) -> float:
    """Geometric mean over channels of the held-out (likelihood-equivalent) mean-square errors."""
    logs = []
    for i, c in enumerate(problem.channels):
        mask = _heldout_mask(problem, i)
        if not mask.any():
            continue
        err2 = (fit.oof[i] - c.values)[mask] ** 2
        shape = fit.shapes[i][mask] if fit.shapes[i] is not None else None
        logs.append(math.log(max(_equivalent_mse(err2, shape), 1e-300)))
    return math.exp(float(np.mean(logs))) if logs else math.nan


def _public(problem: FitProblem, effects: tuple[str, ...], params: EffectParams) -> dict[tuple[str, str], float]:
    out = {}
    for e in effects:
        for k, val in effect_report(e, params, problem.ctx).items():
            out[(e, k)] = float(val)
    return out


def _leads_first(ranked: list[tuple[str, ...]]) -> list[tuple[str, ...]]:
    """The ranked singles with the best ``LEAD_SINGLES`` of *different* physics first: a single that
    shares an effect with a better one, or refines it (tire_saturation and tire_slip), is a variant
    of the same explanation, not a second one."""
    leads: list[tuple[str, ...]] = []
    for c in ranked:
        if len(leads) < LEAD_SINGLES and not any(_with_refined(c) & _with_refined(lead) for lead in leads):
            leads.append(c)
    return leads + [c for c in ranked if c not in leads]


def _polish_promising(problem: FitProblem, fits: list[CandidateFit]) -> list[CandidateFit]:
    """Polish every grid fit whose grid-level score is within ``POLISH_WITHIN`` of the best grid-level
    score: the others cannot win (polishing gains about as much for every candidate near the right
    physics) and keep their grid estimates."""
    best = min(f.grid_score for f in fits)
    todo = [i for i, f in enumerate(fits) if f.grid_score <= POLISH_WITHIN * best and not f.polished]
    out = list(fits)
    # The simulations and the optimiser's linear algebra release the GIL: polish on all cores.
    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, len(todo)))) as pool:
        for i, fit in zip(todo, pool.map(lambda i: polish_candidate(problem, fits[i]), todo)):
            out[i] = fit
    return out


def fit_candidates(problem: FitProblem, candidates: list[tuple[str, ...]] | None = None) -> list[CandidateFit]:
    """The plain model, every single effect, then pairs of the singles that beat the plain model
    (or exactly ``candidates``, all polished)."""
    cache = FitCache()
    if candidates is not None:
        ordered = sorted(candidates, key=len)  # singles first: they seed pair grids
        return [fit_candidate(problem, c, cache) for c in ordered]
    available = available_effects(problem.channels)
    plain = fit_candidate(problem, (), cache)
    fits = _polish_promising(problem, [plain] + [fit_candidate(problem, c, cache, polished=False)
                                                  for c in singles(available)])
    helpful = [f.effects for f in sorted(fits[1:], key=lambda f: f.score) if f.score < plain.score]
    # Forward selection: the best singles with every helpful single, and the best few among themselves
    # (effects that explain the same thing crowd the top; a second, different effect ranks lower).
    chosen = pairs_of(_leads_first(helpful), lead=LEAD_SINGLES) + pairs_of(helpful[:TOP_SINGLES])
    if helpful:
        # Forward selection's second step proper: the best single with every other effect, helpful alone
        # or not. An effect can hide behind a larger one: a 15% steering gain beside a steering offset does
        # not beat the plain model on its own, yet the pair explains everything.
        chosen += pairs_of([helpful[0]] + [c for c in singles(available) if c != helpful[0]], lead=1)
    pairs = [fit_candidate(problem, c, cache, polished=False) for c in dict.fromkeys(chosen)
             if all(f.effects != c for f in fits)]
    fits = _polish_promising(problem, fits + pairs)
    # Around the best few: each effect swapped for its refinement or its simpler version
    # (tire_slip <-> tire_saturation, transport_delay <-> delay_jitter), and every simpler
    # candidate polished, so that the final choice compares like with like.
    for _ in range(2):
        top = sorted(fits, key=lambda f: f.score)[:NEIGHBOURHOOD]
        wanted = [c for f in top for c in _neighbours(f.effects)] + _simpler(top[0].effects)
        known = {f.effects: i for i, f in enumerate(fits)}
        new = [fit_candidate(problem, c, cache) for c in dict.fromkeys(wanted) if c not in known]
        fits = [polish_candidate(problem, f) if f.effects in wanted else f for f in fits] + new
        if not new:
            break
    return fits


def _neighbours(effects: tuple[str, ...]) -> list[tuple[str, ...]]:
    """The candidate with one effect replaced by an effect that refines it."""
    out = []
    for e in effects:
        for other, spec in EFFECTS.items():
            if spec.refines == e:
                c = expand(tuple(other if x == e else x for x in effects))
                if compatible(c):
                    out.append(c)
    return out


# ----------------------------------------------------------------------------------------------
# Refitting on everything, with intervals


def _autocorrelation_inflation(residual: np.ndarray) -> float:
    """n / n_eff for AR(1)-like residuals (>= 1)."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    if denom <= 0 or r.size < 3:
        return 1.0
    rho = float(np.clip(np.dot(r[1:], r[:-1]) / denom, 0.0, 0.99))
    return (1 + rho) / (1 - rho)


def _uncertainty(problem: FitProblem, effects: tuple[str, ...], result: Polished) -> tuple[dict, dict]:
    """Public estimates and 95% intervals per effect, from the Jacobian (delta method for derived)."""
    n, p = result.residual.size, len(result.keys)
    s2 = result.cost / max(n - p, 1) * _autocorrelation_inflation(result.primary_residual)
    cov = s2 * np.linalg.pinv(result.jacobian.T @ result.jacobian)
    centre = _public(problem, effects, params_from(effects, result.values, problem.ctx))
    keys = list(centre)
    grads = np.zeros((len(keys), p))
    scales = {c.key: c.scale for c in coordinates(effects, problem.ctx)}
    for j, key in enumerate(result.keys):
        h = 1e-4 * scales[key]
        shifted_values = dict(result.values)
        shifted_values[key] += h
        shifted = _public(problem, effects, params_from(effects, shifted_values, problem.ctx))
        grads[:, j] = [(shifted[k] - centre[k]) / h for k in keys]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", grads, cov, grads), 0.0))
    estimates: dict[str, dict[str, float]] = {}
    ci: dict[str, dict[str, list[float]]] = {}
    for (e, k), s in zip(keys, sd):
        estimates.setdefault(e, {})[k] = centre[(e, k)]
        ci.setdefault(e, {})[k] = [centre[(e, k)] - 1.96 * float(s), centre[(e, k)] + 1.96 * float(s)]
    return estimates, ci


def _jitter_interval(problem: FitProblem, params: EffectParams, mask: np.ndarray, rng: np.random.Generator
                     ) -> tuple[float, list[float]]:
    residual = problem.y - problem.predict(params)
    sens = _delay_sensitivity(problem, params)
    _, j2 = fit_jitter(residual, sens, mask)
    block = np.floor((problem.recording.t_s - problem.recording.t_s[0]) / T_BLOCK_S).astype(int)
    ids = np.unique(block[mask])
    draws = []
    for _ in range(200):
        pick = rng.choice(ids, size=ids.size)
        counts = np.bincount(pick, minlength=block.max() + 1)
        weights = counts[block] * mask
        idx = np.repeat(np.arange(len(mask)), weights)
        draws.append(math.sqrt(fit_jitter(residual[idx], sens[idx], np.ones(idx.size, bool))[1]))
    return math.sqrt(j2), [float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))]


def refit(problem: FitProblem, fit: CandidateFit, rng: np.random.Generator | None = None) -> CandidateFit:
    """Refit a candidate on all usable samples (from its best fold solution), with 95% intervals."""
    if not fit.effects or fit.refitted:
        return fit
    rng = np.random.default_rng(0) if rng is None else rng
    masks = [c.usable for c in problem.channels]
    best = None
    for start in fit.fold_params:
        result = polish(problem, fit.effects, coordinates_of(fit.effects, start, problem.ctx), masks)
        if best is None or result.cost < best.cost:
            best = result
    fit.params = params_from(fit.effects, best.values, problem.ctx)
    fit.estimates, fit.ci95 = _uncertainty(problem, fit.effects, best)
    for e in fit.effects:
        if EFFECTS[e].varies_noise:
            jitter, interval = _jitter_interval(problem, fit.params, masks[0], rng)
            fit.params = replace(fit.params, jitter_s=jitter)
            fit.estimates[e]["jitter_s"] = jitter
            fit.ci95[e]["jitter_s"] = interval
    fit.refitted = True
    return fit


def out_of_fold_prediction(problem: FitProblem, fit: CandidateFit) -> np.ndarray:
    """The candidate's prediction of each held-out sample (primary channel) by the fold model that
    did not see it."""
    return fit.oof[0]


# ----------------------------------------------------------------------------------------------
# Comparing candidates block by block


def _block_index(problem: FitProblem, block_s: float = T_BLOCK_S) -> np.ndarray:
    t = problem.recording.t_s
    return np.floor((t - t[0]) / block_s).astype(int)


def block_scores(problem: FitProblem, fit: CandidateFit, block_s: float = T_BLOCK_S
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per block and channel: sums of e^2/shape, of log shape, and counts (held-out samples)."""
    block = _block_index(problem, block_s)
    n_blocks = int(block.max()) + 1
    n_ch = len(problem.channels)
    e_sum = np.zeros((n_blocks, n_ch))
    log_sum = np.zeros((n_blocks, n_ch))
    count = np.zeros((n_blocks, n_ch))
    for i, c in enumerate(problem.channels):
        mask = _heldout_mask(problem, i)
        err2 = (fit.oof[i] - c.values)[mask] ** 2
        shape = fit.shapes[i][mask] if fit.shapes[i] is not None else np.ones(err2.size)
        b = block[mask]
        e_sum[:, i] = np.bincount(b, weights=err2 / shape, minlength=n_blocks)
        log_sum[:, i] = np.bincount(b, weights=np.log(shape), minlength=n_blocks)
        count[:, i] = np.bincount(b, minlength=n_blocks)
    return e_sum, log_sum, count


def _combined_from_sums(e_sum: np.ndarray, log_sum: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Geometric mean over channels (with samples) of each row's equivalent mean-square error."""
    with np.errstate(divide="ignore", invalid="ignore"):
        eq = np.where(count > 0, e_sum / np.maximum(count, 1) * np.exp(log_sum / np.maximum(count, 1)), np.nan)
        logs = np.log(np.maximum(eq, 1e-300))
    present = count > 0
    return np.exp(np.where(present, logs, 0.0).sum(axis=1) / np.maximum(present.sum(axis=1), 1))


def paired_t_statistic(err_plain: np.ndarray, err_model: np.ndarray, mask: np.ndarray, t_s: np.ndarray,
                       block_s: float = 1.0) -> float:
    """t statistic of the log ratio of the two models' mean-square errors over ``block_s`` blocks.

    The log ratio, not the difference: squared errors are heavy-tailed (a few hard manoeuvres carry
    most of them), and a difference test would call a 99% improvement "inconsistent" because of the
    spread of those few blocks. Under no improvement the log ratios scatter around zero.
    """
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)[mask]
    if block.size == 0:
        return 0.0
    counts = np.bincount(block)
    keep = counts > 0
    mse_plain = np.bincount(block, weights=err_plain[mask] ** 2)[keep] / counts[keep]
    mse_model = np.bincount(block, weights=err_model[mask] ** 2)[keep] / counts[keep]
    return _t_of_log_ratios(np.log(np.maximum(mse_plain, 1e-300)) - np.log(np.maximum(mse_model, 1e-300)))


def _t_of_log_ratios(log_ratio: np.ndarray) -> float:
    log_ratio = log_ratio[np.isfinite(log_ratio)]
    if log_ratio.size < 3:
        return 0.0
    sd = log_ratio.std(ddof=1)
    if sd == 0:
        return math.inf if log_ratio.mean() > 0 else 0.0
    return float(log_ratio.mean() / (sd / math.sqrt(log_ratio.size)))


def consistency_t(problem: FitProblem, worse: CandidateFit, better: CandidateFit) -> float:
    """t statistic of the per-second log ratio of the two candidates' combined held-out scores
    (positive: ``better`` is better). With one channel and constant variance this is
    :func:`paired_t_statistic`."""
    a = block_scores(problem, worse)
    b = block_scores(problem, better)
    has = (a[2].sum(axis=1) > 0) & (b[2].sum(axis=1) > 0)
    sa = _combined_from_sums(*[x[has] for x in a])
    sb = _combined_from_sums(*[x[has] for x in b])
    return _t_of_log_ratios(np.log(np.maximum(sa, 1e-300)) - np.log(np.maximum(sb, 1e-300)))


def bootstrap_ratio(problem: FitProblem, a: CandidateFit, b: CandidateFit, rng: np.random.Generator,
                    resamples: int = BOOTSTRAP_RESAMPLES) -> tuple[float, float, float]:
    """Held-out combined score of ``b`` over ``a`` (penalties included), with a 95% block-bootstrap
    interval over 1-s blocks: (ratio, low, high). Above 1: ``a`` is better."""
    sa, sb = block_scores(problem, a), block_scores(problem, b)
    n_blocks = sa[0].shape[0]
    keep = np.flatnonzero(sa[2].sum(axis=1) > 0)
    penalty = (1 + PENALTY_PER_PARAMETER * b.dof) / (1 + PENALTY_PER_PARAMETER * a.dof)

    def ratio(weights: np.ndarray) -> float:
        wa = [np.tensordot(weights, x, axes=1)[None, :] for x in sa]
        wb = [np.tensordot(weights, x, axes=1)[None, :] for x in sb]
        return float(_combined_from_sums(*wb)[0] / max(_combined_from_sums(*wa)[0], 1e-300)) * penalty

    full = ratio(np.ones(n_blocks))
    if keep.size < 3:
        return full, full, full
    draws = np.empty(resamples)
    for i in range(resamples):
        weights = np.bincount(rng.choice(keep, size=keep.size), minlength=n_blocks).astype(float)
        draws[i] = ratio(weights)
    return full, float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))


# ----------------------------------------------------------------------------------------------
# Deciding


@dataclass
class Selection:
    verdict: str  # "match" or "mismatch" (diagnose refines it)
    winner: CandidateFit  # the chosen model (the plain model when no candidate is chosen)
    best: CandidateFit  # the best-scoring candidate (may be non-plain even on a "match")
    runner_up: CandidateFit
    plain: CandidateFit
    t_statistic: float
    margin: float  # runner-up score / winner score - 1 (negative: the runner-up scores better)
    ranking: list[CandidateFit]
    reason: str
    margin_ci: tuple[float, float] = (math.nan, math.nan)  # 95% block bootstrap of the margin
    skipped: list[str] = field(default_factory=list)


def _with_refined(effects: tuple[str, ...]) -> set[str]:
    """The effects and the simpler effects they contain (delay_jitter contains transport_delay)."""
    return set(effects) | {EFFECTS[e].refines for e in effects if EFFECTS[e].refines}


def _is_superset(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    return set(b) <= _with_refined(a)


def _simpler(effects: tuple[str, ...]) -> list[tuple[str, ...]]:
    """Candidates one step simpler: a term dropped, or a refinement replaced by its simpler effect."""
    out = [expand(tuple(e for e in effects if e != drop)) for drop in effects if len(effects) >= 2]
    for e in effects:
        if EFFECTS[e].refines:
            out.append(expand(tuple(EFFECTS[e].refines if x == e else x for x in effects)))
    return [c for c in dict.fromkeys(out) if c != effects]


def clearly_better(problem: FitProblem, simpler: CandidateFit, richer: CandidateFit, rng: np.random.Generator
                   ) -> tuple[bool, float]:
    """Is ``richer`` better on held-out data beyond chance? Either consistently (the per-second log
    ratio's t statistic at least ``T_STAT_THRESHOLD``) or in total (the 95% block-bootstrap interval
    of the penalised score ratio above 1: an effect that shows only in some manoeuvres, such as a
    friction limit or a rate limit, wins big in few seconds). Returns (verdict, t statistic)."""
    t_stat = consistency_t(problem, simpler, richer)
    if t_stat >= T_STAT_THRESHOLD:
        return True, t_stat
    _, low, _ = bootstrap_ratio(problem, richer, simpler, rng, BOOTSTRAP_DECISION_RESAMPLES)
    return low > 1.0, t_stat


def _simplest_sufficient(problem: FitProblem, best: CandidateFit, fits: list[CandidateFit],
                         rng: np.random.Generator) -> CandidateFit:
    """Drop a term (or a refinement) while the richer candidate is not clearly better than the
    simpler one. The penalty is small so that a real second effect is not missed; this test keeps
    a term that only fits noise out."""
    by_effects = {f.effects: f for f in fits}
    while best.effects:
        subsets = [by_effects[c] for c in _simpler(best.effects) if c in by_effects]
        if not subsets:
            break
        simpler = min(subsets, key=lambda f: f.score)
        if clearly_better(problem, simpler, best, rng)[0]:
            break
        best = simpler
    return best


def select(problem: FitProblem, fits: list[CandidateFit], noise_sigma: float,
           rng: np.random.Generator | None = None) -> Selection:
    rng = np.random.default_rng(0) if rng is None else rng
    ranking = sorted(fits, key=lambda f: f.score)
    plain = next(f for f in fits if not f.effects)
    best = _simplest_sufficient(problem, ranking[0], fits, rng)
    better, t_stat = clearly_better(problem, plain, best, rng) if best.effects else (False, 0.0)
    improvement = plain.heldout_mse - best.heldout_mse
    if not best.effects:
        verdict, reason = "match", "no candidate beats the plain model on held-out data after the complexity penalty"
    elif not better:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out error inconsistently "
                                    f"(t = {t_stat:.1f} < {T_STAT_THRESHOLD:g}, and its total gain is within the "
                                    "bootstrap spread)")
    elif improvement < NOISE_FRACTION * noise_sigma**2 and best.raw_score > (1 - NOISE_FRACTION) * plain.raw_score:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out mean-square error by "
                                    f"less than {NOISE_FRACTION:g} of the noise variance")
    else:
        verdict, reason = "mismatch", (f"{best.name} beats the plain model on held-out data "
                                       f"(t = {t_stat:.1f}, {100 * (1 - best.raw_score / plain.raw_score):.0f}% "
                                       "lower combined mean-square error)")
    winner = best if verdict == "mismatch" else plain
    # The runner-up is the best *alternative* explanation: neither the winner plus a term (a superset
    # fits at least as well, by construction) nor, when there is another, the winner minus one.
    others = [f for f in ranking if f.effects and f is not winner and not _is_superset(f.effects, winner.effects)
              and not _is_superset(winner.effects, f.effects)]
    others = others or [f for f in ranking if f.effects and f is not winner
                        and not _is_superset(f.effects, winner.effects)]
    if not others:
        others = [f for f in ranking if f.effects and f is not winner] or [plain]
    # Compare polished with polished: a screened-out grid fit's score is pessimistic.
    contenders = [polish_candidate(problem, f) for f in others[:RUNNER_UP_CONTENDERS]]
    runner_up = min(contenders, key=lambda f: f.score)
    ranking = sorted([f for f in ranking if f not in others[:RUNNER_UP_CONTENDERS]] + contenders,
                     key=lambda f: f.score)
    for f in {id(winner): winner, id(runner_up): runner_up, id(best): best}.values():
        refit(problem, f, rng)
    margin = runner_up.score / winner.score - 1.0 if winner.score > 0 else math.inf
    ratio, lo, hi = bootstrap_ratio(problem, winner, runner_up, rng)
    return Selection(verdict, winner, best, runner_up, plain, t_stat, margin, ranking, reason,
                     margin_ci=(lo - 1.0, hi - 1.0))


def make_problem(recording: Recording, signal: FitSignal | str = "auto", block_s: float | None = None,
                 split: str = "blocks") -> FitProblem:
    channels = recorded_channels(recording, signal) if isinstance(signal, str) else [signal]
    block_s = default_block_s(recording.duration_s, recording.dt_s) if block_s is None else block_s
    time_folds = make_folds(recording.t_s, np.ones(recording.n, bool), split, block_s)
    return FitProblem(recording, channels, time_folds)
