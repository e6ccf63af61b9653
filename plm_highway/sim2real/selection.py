"""Which effect (or pair of effects) explains the mismatch: fit each inside the model, judge held out.

1. **Split** the recording into alternating blocks in time and use them for 2-fold
   cross-validation: fit on the even blocks and predict the odd ones, then the other way round.
   Every usable sample gets an out-of-fold prediction, both folds see every kind of driving, and no
   fit is scored on samples it saw. (``split="halves"``: fit on the first half, score the second.)
2. **Fit** every candidate on each fold's train blocks: the plain model, each effect alone and every
   pair. The parameters that enter nonlinearly (delay, time constant, tire stiffnesses) go on a
   grid, simulated as one parallel batch that serves both folds; gain and offset enter linearly and
   are solved in closed form at each grid point. The best grid points are then polished jointly by
   bounded Levenberg-Marquardt. Fitting the effect *inside* the model is what keeps a tire-slip
   recording (an apparent ~0.1 s lag to input-output cross-correlation) from being called a
   transport delay: a delay shifts the yaw rate, tire slip also scales it with speed, and only the
   right term fits both.
3. **Judge** on held-out samples: out-of-fold mean-square error of the fit signal, times
   ``1 + 0.01 p`` for ``p`` fitted parameters (each parameter must earn a 1% reduction). A pair
   that wins must also beat its better single effect *consistently* (the block-wise test of step
   4), or the single effect is kept: small enough a penalty not to miss a real second effect, and
   no second term that only fits noise.
4. **Decide**: a mismatch is reported only if the winner is not the plain model, its improvement
   over the plain model is consistent across held-out stretches (t statistic of the log ratio of
   the two models' mean-square errors over 1-s blocks above 3), and the improvement exceeds a tenth
   of the measurement-noise variance. Otherwise the
   simulator matches the recording within its noise.

The winner and the runner-up are then refitted on all usable samples; their parameters come with
95% intervals from the least-squares Jacobian, with the residual variance inflated for
autocorrelation (effective sample size from the lag-1 correlation).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.effects import (
    EFFECT_DOF,
    EFFECT_NAMES,
    EffectParams,
    candidate_statistics,
    effect_report,
    profiled_sse,
    tire_tables,
)
from plm_highway.sim2real.recording import Recording
from plm_highway.sim2real.replay import FitSignal, filtered, model_yaw_rate
from plm_highway.vehicle.single_track import understeer_gradient

PENALTY_PER_PARAMETER = 0.01
T_STAT_THRESHOLD = 3.0
NOISE_FRACTION = 0.1  # the improvement must exceed this fraction of the noise variance
SPLITS = ("blocks", "halves")

DELAY_GRID_S = np.round(np.arange(0.0, 0.601, 0.02), 3)
LAG_GRID_S = np.array([0.02, 0.04, 0.06, 0.08, 0.10, 0.13, 0.16, 0.20, 0.25, 0.30, 0.40, 0.50, 0.60])
UNDERSTEER_GRID = np.array([-0.001, 0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006, 0.009, 0.014, 0.02])
REAR_STIFFNESS_GRID_PER_KG = np.array([25.0, 70.0, 200.0])
N_POLISH = 3
# Axle cornering stiffness per unit mass [N/rad/kg]: road cars ~30-80, race cars a few hundred.
# Far stiffer tires are the kinematic bicycle already, and only make the tire model numerically stiff.
MAX_STIFFNESS_PER_KG = 1000.0

BOUNDS = {
    "delay_s": (0.0, 0.8),
    "time_constant_s": (0.0, 0.8),
    "understeer": (-0.003, 0.05),
    "log_cr": (math.log(5.0), math.log(MAX_STIFFNESS_PER_KG)),
    "gain": (0.2, 5.0),
    "offset_rad": (-0.2, 0.2),
}
# Typical scale of each free parameter: finite-difference steps and damping are relative to it.
SCALES = {"delay_s": 0.05, "time_constant_s": 0.05, "understeer": 0.001, "log_cr": 1.0, "gain": 0.1,
          "offset_rad": 0.005}


def all_candidates() -> list[tuple[str, ...]]:
    """The plain model, each effect alone, and each pair, in a fixed order."""
    singles = [(name,) for name in EFFECT_NAMES]
    pairs = list(itertools.combinations(EFFECT_NAMES, 2))
    return [()] + singles + pairs


def default_block_s(duration_s: float) -> float:
    return float(np.clip(duration_s / 16.0, 2.5, 8.0))


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


@dataclass
class FitProblem:
    """Everything a candidate fit needs, as contiguous arrays for the kernels."""

    recording: Recording
    signal: FitSignal
    folds: list[tuple[np.ndarray, np.ndarray]]

    def __post_init__(self):
        v = self.recording.vehicle
        self.steer = np.ascontiguousarray(self.recording.steer_rad, float)
        self.speed = np.ascontiguousarray(self.recording.speed_mps, float)
        self.dt = self.recording.dt_s
        self.a = v.cg_to_front_m
        self.b = v.cg_to_rear_m
        self.k2 = v.yaw_inertia_per_kg_m2
        self.y = np.ascontiguousarray(self.signal.values, float)
        self.heldout = np.zeros(self.recording.n, bool)
        for _, test in self.folds:
            self.heldout |= test
        self.fit_mask = self.signal.usable

    def predict(self, params: EffectParams) -> np.ndarray:
        r, _ = model_yaw_rate(self.recording, params, with_slip=False)
        return filtered(self.signal, r)

    def batch_statistics(self, delays, taus, cfs, crs) -> np.ndarray:
        """Closed-form statistics per candidate and fold (see ``effects.candidate_statistics``)."""
        tires, tire_index = np.unique(np.column_stack([cfs, crs]), axis=0, return_inverse=True)
        tire_index = tire_index.ravel().astype(np.int64)
        if tires[0, 0] > 0:
            maps, starts, units = tire_tables(self.speed, self.dt, np.ascontiguousarray(tires[:, 0]),
                                              np.ascontiguousarray(tires[:, 1]), self.a, self.b, self.k2,
                                              self.signal.taps, self.signal.lo)
        else:
            tire_index[:] = -1
            maps, starts, units = np.zeros((1, 1, 8)), np.zeros((1, 2)), np.zeros((1, 1))
        weight = np.ascontiguousarray(np.array([train for train, _ in self.folds], dtype=float))
        return candidate_statistics(
            self.steer, self.speed, self.dt, np.ascontiguousarray(delays, float), np.ascontiguousarray(taus, float),
            tire_index, maps, starts, units, self.a, self.b, self.signal.taps, self.signal.lo, self.y, weight,
        )


@dataclass
class CandidateFit:
    effects: tuple[str, ...]
    params: EffectParams  # fitted on all usable samples (winner, runner-up) or on the first fold
    dof: int
    train_mse: float
    heldout_mse: float  # out-of-fold
    fold_params: list[EffectParams] = field(default_factory=list)
    score: float = math.nan
    estimates: dict[str, dict[str, float]] = field(default_factory=dict)  # public names
    ci95: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    refitted: bool = False

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "plain"

    @property
    def heldout_rmse(self) -> float:
        return math.sqrt(self.heldout_mse)


# ----------------------------------------------------------------------------------------------
# Parameter vectors


def _free_names(effects: tuple[str, ...]) -> list[str]:
    names = []
    for e in EFFECT_NAMES:  # fixed order
        if e not in effects:
            continue
        names += {"transport_delay": ["delay_s"], "actuator_lag": ["time_constant_s"],
                  "tire_slip": ["understeer", "log_cr"], "steering_gain": ["gain"],
                  "steering_offset": ["offset_rad"]}[e]
    return names


def _front_from(understeer: float, cr: float, a: float, b: float) -> float:
    denominator = understeer * (a + b) + a / cr
    if denominator <= b / MAX_STIFFNESS_PER_KG:
        return MAX_STIFFNESS_PER_KG
    return max(b / denominator, 1.0)


def _params_from_vector(names: list[str], x: np.ndarray, a: float, b: float) -> EffectParams:
    values = dict(zip(names, x))
    kwargs = {k: float(values[k]) for k in ("delay_s", "time_constant_s", "gain", "offset_rad") if k in values}
    if "understeer" in values:
        cr = math.exp(values["log_cr"])
        kwargs["cf_per_kg"] = _front_from(values["understeer"], cr, a, b)
        kwargs["cr_per_kg"] = cr
    return EffectParams(**kwargs)


def _vector_from_params(names: list[str], p: EffectParams, a: float, b: float) -> np.ndarray:
    out = []
    for n in names:
        if n == "understeer":
            out.append(understeer_gradient(p.cf_per_kg, p.cr_per_kg, a, b))
        elif n == "log_cr":
            out.append(math.log(p.cr_per_kg))
        else:
            out.append(getattr(p, n))
    lo, hi = _bounds(names)
    return np.clip(np.array(out, float), lo, hi)


def _bounds(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([BOUNDS[n][0] for n in names]), np.array([BOUNDS[n][1] for n in names])


# ----------------------------------------------------------------------------------------------
# Bounded Levenberg-Marquardt (few parameters, many residuals)


@dataclass
class LeastSquaresResult:
    x: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float
    evaluations: int


def _jacobian(fun, x: np.ndarray, r: np.ndarray, lo: np.ndarray, hi: np.ndarray, scale: np.ndarray) -> np.ndarray:
    jac = np.empty((r.size, x.size))
    for j in range(x.size):
        h = 1e-4 * scale[j]
        if x[j] + h > hi[j]:  # step inward at an upper bound
            h = -h
        xp = x.copy()
        xp[j] += h
        jac[:, j] = (fun(xp) - r) / h
    return jac


def bounded_least_squares(fun, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, scale: np.ndarray,
                          max_iterations: int = 25, rtol: float = 1e-7) -> LeastSquaresResult:
    """Minimise ``|fun(x)|^2`` within [lo, hi] by Levenberg-Marquardt with clipped steps.

    With a handful of parameters the normal equations are tiny; forward-difference Jacobians cost
    ``p`` evaluations. Steps leaving the box are clipped onto it.
    """
    x = np.clip(np.asarray(x0, float), lo, hi)
    r = fun(x)
    cost = float(r @ r)
    evaluations = 1
    damping = 1e-3
    jac = _jacobian(fun, x, r, lo, hi, scale)
    evaluations += x.size
    for _ in range(max_iterations):
        g = jac.T @ r
        h = jac.T @ jac
        diag = np.maximum(np.diag(h), 1e-12 * max(np.max(np.diag(h)), 1e-300))
        improved = False
        while damping < 1e10:
            step = np.linalg.solve(h + damping * np.diag(diag), -g)
            x_new = np.clip(x + step, lo, hi)
            r_new = fun(x_new)
            evaluations += 1
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                improved = True
                break
            damping *= 4.0
        if not improved:
            break
        converged = (cost - cost_new) <= rtol * cost or np.all(np.abs(x_new - x) <= 1e-6 * scale)
        x, r, cost = x_new, r_new, cost_new
        damping = max(damping / 3.0, 1e-9)
        jac = _jacobian(fun, x, r, lo, hi, scale)
        evaluations += x.size
        if converged:
            break
    return LeastSquaresResult(x, r, jac, cost, evaluations)


# ----------------------------------------------------------------------------------------------
# Grids


def _grid(effects: tuple[str, ...], a: float, b: float) -> tuple[np.ndarray, ...]:
    """Candidate (delay, tau, cf, cr) arrays for the nonlinear parameters of ``effects``."""
    delays = DELAY_GRID_S if "transport_delay" in effects else np.zeros(1)
    taus = LAG_GRID_S if "actuator_lag" in effects else np.zeros(1)
    if "tire_slip" in effects:
        tires = []
        for k in UNDERSTEER_GRID:
            for cr in REAR_STIFFNESS_GRID_PER_KG:
                cf = _front_from(k, cr, a, b)
                if 1.0 < cf < MAX_STIFFNESS_PER_KG:
                    tires.append((cf, cr))
        tires = np.array(tires)
    else:
        tires = np.zeros((1, 2))
    d, t, i = np.meshgrid(delays, taus, np.arange(len(tires)), indexing="ij")
    return d.ravel(), t.ravel(), tires[i.ravel(), 0], tires[i.ravel(), 1]


def _nonlinear_key(effects: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(e for e in effects if e in ("transport_delay", "actuator_lag", "tire_slip"))


def _polish_starts(sse: np.ndarray, delays, taus, cfs, crs) -> list[int]:
    """The best grid point, plus up to ``N_POLISH - 1`` runners-up from other basins.

    A runner-up is polished only if its grid error is within 20% of the best and its nonlinear
    parameters are far from every start already taken (delay/lag by > 0.05 s, or stiffness by > 2x);
    neighbours of the best would only converge to the same optimum.
    """
    order = np.argsort(sse)
    starts = [int(order[0])]
    for idx in order[1:]:
        if len(starts) >= N_POLISH or sse[idx] > 1.2 * sse[order[0]]:
            break
        far = all(abs(delays[idx] - delays[j]) > 0.05 or abs(taus[idx] - taus[j]) > 0.05
                  or (cfs[j] > 0 and not 0.5 < cfs[idx] / cfs[j] < 2.0)
                  or (crs[j] > 0 and not 0.5 < crs[idx] / crs[j] < 2.0) for j in starts)
        if far:
            starts.append(int(idx))
    return starts


# ----------------------------------------------------------------------------------------------
# Fitting


def _polish(problem: FitProblem, effects: tuple[str, ...], start: EffectParams, mask: np.ndarray
            ) -> tuple[LeastSquaresResult, list[str]]:
    names = _free_names(effects)
    y = problem.y[mask]

    def residual(x: np.ndarray) -> np.ndarray:
        return problem.predict(_params_from_vector(names, x, problem.a, problem.b))[mask] - y

    lo, hi = _bounds(names)
    scale = np.array([SCALES[n] for n in names])
    x0 = _vector_from_params(names, start, problem.a, problem.b)
    return bounded_least_squares(residual, x0, lo, hi, scale), names


def _autocorrelation_inflation(residual: np.ndarray) -> float:
    """n / n_eff for AR(1)-like residuals (>= 1)."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    if denom <= 0 or r.size < 3:
        return 1.0
    rho = float(np.clip(np.dot(r[1:], r[:-1]) / denom, 0.0, 0.99))
    return (1 + rho) / (1 - rho)


def _public(problem: FitProblem, effects: tuple[str, ...], params: EffectParams) -> dict[tuple[str, str], float]:
    v = problem.recording.vehicle
    out = {}
    for e in effects:
        for k, val in effect_report(e, params, problem.a, problem.b, v.mass_kg, v.inertia_known).items():
            out[(e, k)] = float(val)
    return out


def _uncertainty(problem: FitProblem, effects: tuple[str, ...], names: list[str], result: LeastSquaresResult
                 ) -> tuple[dict, dict]:
    """Public estimates and 95% intervals per effect, from the Jacobian (delta method for derived)."""
    n, p = result.residual.size, len(names)
    s2 = result.cost / max(n - p, 1) * _autocorrelation_inflation(result.residual)
    cov = s2 * np.linalg.pinv(result.jacobian.T @ result.jacobian)
    centre = _public(problem, effects, _params_from_vector(names, result.x, problem.a, problem.b))
    keys = list(centre)
    grads = np.zeros((len(keys), p))
    for j in range(p):
        h = 1e-6 * max(1.0, abs(result.x[j]))
        xp = result.x.copy()
        xp[j] += h
        shifted = _public(problem, effects, _params_from_vector(names, xp, problem.a, problem.b))
        grads[:, j] = [(shifted[k] - centre[k]) / h for k in keys]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", grads, cov, grads), 0.0))
    estimates: dict[str, dict[str, float]] = {}
    ci: dict[str, dict[str, list[float]]] = {}
    for (e, k), s in zip(keys, sd):
        estimates.setdefault(e, {})[k] = centre[(e, k)]
        ci.setdefault(e, {})[k] = [centre[(e, k)] - 1.96 * float(s), centre[(e, k)] + 1.96 * float(s)]
    return estimates, ci


def _fit_fold(problem: FitProblem, effects: tuple[str, ...], grid, fold_stats: np.ndarray, train: np.ndarray
              ) -> tuple[EffectParams, float]:
    """Grid, then polish the best starts, on one fold's train mask: (params, train cost)."""
    delays, taus, cfs, crs = grid
    sse, gains, offsets = profiled_sse(fold_stats, "steering_gain" in effects, "steering_offset" in effects)
    best = None
    for idx in _polish_starts(sse, delays, taus, cfs, crs):
        start = EffectParams(
            delay_s=float(delays[idx]), time_constant_s=float(taus[idx]),
            gain=float(np.clip(gains[idx], *BOUNDS["gain"])),
            offset_rad=float(np.clip(offsets[idx], *BOUNDS["offset_rad"])),
            cf_per_kg=float(cfs[idx]) if cfs[idx] > 0 else None,
            cr_per_kg=float(crs[idx]) if crs[idx] > 0 else None,
        )
        result, names = _polish(problem, effects, start, train)
        if best is None or result.cost < best[0].cost:
            best = (result, names)
    result, names = best
    return _params_from_vector(names, result.x, problem.a, problem.b), result.cost


def fit_candidates(problem: FitProblem, candidates: list[tuple[str, ...]] | None = None) -> list[CandidateFit]:
    """Fit every candidate on each fold's train blocks; score out-of-fold; rank by penalised score."""
    candidates = all_candidates() if candidates is None else candidates
    grid_cache: dict[tuple[str, ...], tuple] = {}
    n_train = sum(max(int(train.sum()), 1) for train, _ in problem.folds)
    n_held = max(int(problem.heldout.sum()), 1)
    fits: list[CandidateFit] = []
    for effects in candidates:
        dof = sum(EFFECT_DOF[e] for e in effects)
        oof = np.zeros(problem.recording.n)
        fold_params: list[EffectParams] = []
        train_sse = 0.0
        if not effects:
            pred = problem.predict(EffectParams())
            for train, test in problem.folds:
                oof[test] = pred[test]
                train_sse += float(np.sum((pred - problem.y)[train] ** 2))
                fold_params.append(EffectParams())
        else:
            key = _nonlinear_key(effects)
            if key not in grid_cache:
                grid = _grid(key, problem.a, problem.b)
                grid_cache[key] = (grid, problem.batch_statistics(*grid))
            grid, stats = grid_cache[key]
            for f, (train, test) in enumerate(problem.folds):
                params, cost = _fit_fold(problem, effects, grid, stats[:, f, :], train)
                oof[test] = problem.predict(params)[test]
                train_sse += cost
                fold_params.append(params)
        err = oof - problem.y
        fits.append(CandidateFit(effects, fold_params[0], dof, train_sse / n_train,
                                 float(np.sum(err[problem.heldout] ** 2)) / n_held, fold_params=fold_params))
    for f in fits:
        f.score = f.heldout_mse * (1.0 + PENALTY_PER_PARAMETER * f.dof)
        if f.effects:  # until refitted: the mean of the folds' estimates, without intervals
            per_fold = [_public(problem, f.effects, p) for p in f.fold_params]
            for (e, k) in per_fold[0]:
                f.estimates.setdefault(e, {})[k] = float(np.mean([pf[(e, k)] for pf in per_fold]))
    return fits


def refit(problem: FitProblem, fit: CandidateFit) -> CandidateFit:
    """Refit a candidate on all usable samples (from its best fold solution), with 95% intervals."""
    if not fit.effects or fit.refitted:
        return fit
    mask = problem.fit_mask
    best = None
    for start in fit.fold_params:
        result, names = _polish(problem, fit.effects, start, mask)
        if best is None or result.cost < best[0].cost:
            best = (result, names)
    result, names = best
    fit.params = _params_from_vector(names, result.x, problem.a, problem.b)
    fit.estimates, fit.ci95 = _uncertainty(problem, fit.effects, names, result)
    fit.refitted = True
    return fit


def out_of_fold_prediction(problem: FitProblem, fit: CandidateFit) -> np.ndarray:
    """The candidate's prediction of each held-out sample by the fold model that did not see it."""
    oof = np.full(problem.recording.n, np.nan)
    for params, (_, test) in zip(fit.fold_params, problem.folds):
        oof[test] = problem.predict(params)[test]
    return oof


# ----------------------------------------------------------------------------------------------
# Deciding


@dataclass
class Selection:
    verdict: str  # "match" or "mismatch"
    winner: CandidateFit  # the chosen model (the plain model when the verdict is "match")
    best: CandidateFit  # the best-scoring candidate (may be non-plain even on a "match")
    runner_up: CandidateFit
    plain: CandidateFit
    t_statistic: float
    margin: float  # runner-up score / winner score - 1
    ranking: list[CandidateFit]
    reason: str


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
    tiny = 1e-300
    log_ratio = np.log(np.maximum(mse_plain, tiny)) - np.log(np.maximum(mse_model, tiny))
    if log_ratio.size < 3:
        return 0.0
    sd = log_ratio.std(ddof=1)
    if sd == 0:
        return math.inf if log_ratio.mean() > 0 else 0.0
    return float(log_ratio.mean() / (sd / math.sqrt(log_ratio.size)))


def _is_superset(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    return set(b) <= set(a)


def _simplest_sufficient(problem: FitProblem, best: CandidateFit, fits: list[CandidateFit]) -> CandidateFit:
    """Drop a term from a pair while the pair is not *consistently* better than its best single.

    The penalty is small so that a real second effect is not missed; this test keeps a term that
    only fits noise out (same block-wise test as against the plain model).
    """
    by_effects = {f.effects: f for f in fits}
    while len(best.effects) >= 2:
        subsets = [by_effects.get(tuple(e for e in best.effects if e != drop)) for drop in best.effects]
        subsets = [f for f in subsets if f is not None]
        if not subsets:
            break
        simpler = min(subsets, key=lambda f: f.score)
        t_stat = paired_t_statistic(out_of_fold_prediction(problem, simpler) - problem.y,
                                    out_of_fold_prediction(problem, best) - problem.y,
                                    problem.heldout, problem.recording.t_s)
        if t_stat >= T_STAT_THRESHOLD:
            break
        best = simpler
    return best


def select(problem: FitProblem, fits: list[CandidateFit], noise_sigma: float) -> Selection:
    ranking = sorted(fits, key=lambda f: f.score)
    plain = next(f for f in fits if not f.effects)
    best = _simplest_sufficient(problem, ranking[0], fits)
    t_stat = 0.0
    if best.effects:
        err_plain = problem.predict(plain.params) - problem.y
        err_best = out_of_fold_prediction(problem, best) - problem.y
        t_stat = paired_t_statistic(err_plain, np.nan_to_num(err_best), problem.heldout, problem.recording.t_s)
    improvement = plain.heldout_mse - best.heldout_mse
    if not best.effects:
        verdict, reason = "match", "no candidate beats the plain model on held-out data after the complexity penalty"
    elif t_stat < T_STAT_THRESHOLD:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out error inconsistently "
                                    f"(t = {t_stat:.1f} < {T_STAT_THRESHOLD:g})")
    elif improvement < NOISE_FRACTION * noise_sigma**2:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out mean-square error by "
                                    f"less than {NOISE_FRACTION:g} of the noise variance")
    else:
        verdict, reason = "mismatch", (f"{best.name} beats the plain model on held-out data "
                                       f"(t = {t_stat:.1f}, {100 * (1 - best.heldout_mse / plain.heldout_mse):.0f}% "
                                       "lower mean-square error)")
    winner = best if verdict == "mismatch" else plain
    # The runner-up is the best *alternative* explanation: another non-plain candidate that does
    # not merely add a term to the winner (a superset fits at least as well, by construction).
    others = [f for f in ranking if f.effects and f is not winner and not _is_superset(f.effects, winner.effects)]
    if not others:
        others = [f for f in ranking if f.effects and f is not winner]
    runner_up = others[0]
    for f in {id(winner): winner, id(runner_up): runner_up, id(best): best}.values():
        refit(problem, f)
    margin = runner_up.score / winner.score - 1.0 if winner.score > 0 else math.inf
    return Selection(verdict, winner, best, runner_up, plain, t_stat, margin, ranking, reason)


def make_problem(recording: Recording, signal: FitSignal, block_s: float | None = None, split: str = "blocks"
                 ) -> FitProblem:
    block_s = default_block_s(recording.duration_s) if block_s is None else block_s
    return FitProblem(recording, signal, make_folds(recording.t_s, signal.usable, split, block_s))
