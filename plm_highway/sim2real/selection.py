"""Which effect (or pair of effects) explains the mismatch: fit each inside the model, judge held out.

1. **Split** the recording into alternating blocks in time (train, held-out, train, ...), so both
   halves see every kind of driving and a fit cannot memorise the samples it is scored on.
2. **Fit** every candidate on the train blocks: the plain model, each effect alone and every pair.
   The parameters that enter nonlinearly (delay, time constant, tire stiffnesses) go on a grid,
   simulated as one parallel batch; gain and offset enter linearly and are solved in closed form at
   each grid point. The best grid points are then polished jointly by nonlinear least squares.
   Fitting the effect *inside* the model is what keeps a tire-slip recording (an apparent ~0.1 s
   lag to input-output cross-correlation) from being called a transport delay: a delay shifts the
   yaw rate, tire slip also scales it with speed, and only the right term fits both.
3. **Judge** on the held-out blocks: mean-square error of the fit signal, times ``1 + 0.02 p`` for
   ``p`` fitted parameters (each parameter must earn a 2% reduction).
4. **Decide**: a mismatch is reported only if the winner is not the plain model, its improvement
   over the plain model is consistent across held-out stretches (paired t statistic over 1-s blocks
   above 3), and the improvement exceeds a tenth of the measurement-noise variance. Otherwise the
   simulator matches the recording within its noise.

Uncertainty: from the least-squares Jacobian at the solution, with the residual variance inflated
for autocorrelation (effective sample size from the lag-1 correlation); 95% intervals.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

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

PENALTY_PER_PARAMETER = 0.02
T_STAT_THRESHOLD = 3.0
NOISE_FRACTION = 0.1  # the improvement must exceed this fraction of the noise variance

DELAY_GRID_S = np.round(np.arange(0.0, 0.601, 0.02), 3)
LAG_GRID_S = np.array([0.02, 0.04, 0.06, 0.08, 0.10, 0.13, 0.16, 0.20, 0.25, 0.30, 0.40, 0.50, 0.60])
UNDERSTEER_GRID = np.array([-0.001, 0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006, 0.009, 0.014, 0.02])
REAR_STIFFNESS_GRID_PER_KG = np.array([25.0, 70.0, 200.0])
N_POLISH = 3

BOUNDS = {
    "delay_s": (0.0, 0.8),
    "time_constant_s": (0.0, 0.8),
    "understeer": (-0.003, 0.05),
    "log_cr": (math.log(5.0), math.log(3000.0)),
    "gain": (0.2, 5.0),
    "offset_rad": (-0.2, 0.2),
}
SCALES = {"delay_s": 0.05, "time_constant_s": 0.05, "understeer": 0.001, "log_cr": 1.0, "gain": 0.1,
          "offset_rad": 0.005}


def all_candidates() -> list[tuple[str, ...]]:
    """The plain model, each effect alone, and each pair, in a fixed order."""
    singles = [(name,) for name in EFFECT_NAMES]
    pairs = list(itertools.combinations(EFFECT_NAMES, 2))
    return [()] + singles + pairs


def block_split(t_s: np.ndarray, block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Alternating blocks: (train mask, held-out mask)."""
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)
    train = block % 2 == 0
    return train, ~train


def default_block_s(duration_s: float) -> float:
    return float(np.clip(duration_s / 16.0, 2.5, 8.0))


@dataclass
class FitProblem:
    """Everything a candidate fit needs, as contiguous arrays for the kernels."""

    recording: Recording
    signal: FitSignal
    train: np.ndarray  # usable & train block
    heldout: np.ndarray  # usable & held-out block

    def __post_init__(self):
        v = self.recording.vehicle
        self.steer = np.ascontiguousarray(self.recording.steer_rad, float)
        self.speed = np.ascontiguousarray(self.recording.speed_mps, float)
        self.dt = self.recording.dt_s
        self.a = v.cg_to_front_m
        self.b = v.cg_to_rear_m
        self.k2 = v.yaw_inertia_per_kg_m2
        self.y = np.ascontiguousarray(self.signal.values, float)

    def predict(self, params: EffectParams) -> np.ndarray:
        r, _ = model_yaw_rate(self.recording, params)
        return filtered(self.signal, r)

    def batch_statistics(self, delays, taus, cfs, crs, weight: np.ndarray) -> np.ndarray:
        """Closed-form statistics for a batch of candidates (see ``effects.candidate_statistics``)."""
        tires, tire_index = np.unique(np.column_stack([cfs, crs]), axis=0, return_inverse=True)
        tire_index = tire_index.ravel().astype(np.int64)
        if tires[0, 0] > 0:
            maps, starts, units = tire_tables(self.speed, self.dt, np.ascontiguousarray(tires[:, 0]),
                                              np.ascontiguousarray(tires[:, 1]), self.a, self.b, self.k2,
                                              self.signal.taps, self.signal.lo)
        else:
            tire_index[:] = -1
            maps, starts, units = np.zeros((1, 1, 8)), np.zeros((1, 2)), np.zeros((1, 1))
        return candidate_statistics(
            self.steer, self.speed, self.dt, np.ascontiguousarray(delays, float), np.ascontiguousarray(taus, float),
            tire_index, maps, starts, units, self.a, self.b, self.signal.taps, self.signal.lo, self.y,
            weight.astype(float),
        )


@dataclass
class CandidateFit:
    effects: tuple[str, ...]
    params: EffectParams
    dof: int
    train_mse: float
    heldout_mse: float
    score: float = math.nan
    estimates: dict[str, dict[str, float]] = field(default_factory=dict)  # public names
    ci95: dict[str, dict[str, list[float]]] = field(default_factory=dict)

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
    if denominator <= b / 1e5:
        return 1e5
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
    x = np.array(out, float)
    lo = np.array([BOUNDS[n][0] for n in names])
    hi = np.array([BOUNDS[n][1] for n in names])
    return np.clip(x, lo + 1e-9, hi - 1e-9)


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
                if 1.0 < cf < 5e4:
                    tires.append((cf, cr))
        tires = np.array(tires)
    else:
        tires = np.zeros((1, 2))
    d, t, i = np.meshgrid(delays, taus, np.arange(len(tires)), indexing="ij")
    return d.ravel(), t.ravel(), tires[i.ravel(), 0], tires[i.ravel(), 1]


def _nonlinear_key(effects: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(e for e in effects if e in ("transport_delay", "actuator_lag", "tire_slip"))


# ----------------------------------------------------------------------------------------------
# Fitting


def _residual_fn(problem: FitProblem, names: list[str], mask: np.ndarray):
    y = problem.y[mask]

    def residual(x: np.ndarray) -> np.ndarray:
        params = _params_from_vector(names, x, problem.a, problem.b)
        return problem.predict(params)[mask] - y

    return residual


def _polish(problem: FitProblem, effects: tuple[str, ...], start: EffectParams):
    names = _free_names(effects)
    residual = _residual_fn(problem, names, problem.train)
    x0 = _vector_from_params(names, start, problem.a, problem.b)
    lo = np.array([BOUNDS[n][0] for n in names])
    hi = np.array([BOUNDS[n][1] for n in names])
    scale = np.array([SCALES[n] for n in names])
    result = least_squares(residual, x0, bounds=(lo, hi), x_scale=scale, diff_step=1e-4, max_nfev=60,
                           xtol=1e-8, ftol=1e-10)
    return result, names


def _autocorrelation_inflation(residual: np.ndarray) -> float:
    """n / n_eff for AR(1)-like residuals (>= 1)."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    if denom <= 0 or r.size < 3:
        return 1.0
    rho = float(np.clip(np.dot(r[1:], r[:-1]) / denom, 0.0, 0.99))
    return (1 + rho) / (1 - rho)


def _uncertainty(problem: FitProblem, effects: tuple[str, ...], names: list[str], result) -> tuple[dict, dict]:
    """Public estimates and 95% intervals per effect, from the Jacobian (delta method for derived)."""
    params = _params_from_vector(names, result.x, problem.a, problem.b)
    n, p = result.fun.size, len(names)
    jac = result.jac
    s2 = float(np.dot(result.fun, result.fun)) / max(n - p, 1) * _autocorrelation_inflation(result.fun)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    v = problem.recording.vehicle
    estimates, ci = {}, {}

    def public(x: np.ndarray) -> dict[str, float]:
        pp = _params_from_vector(names, x, problem.a, problem.b)
        flat = {}
        for e in effects:
            for k, val in effect_report(e, pp, problem.a, problem.b, v.mass_kg, v.inertia_known).items():
                flat[(e, k)] = val
        return flat

    centre = public(result.x)
    keys = list(centre)
    # Numerical gradient of each public quantity w.r.t. the free vector (identity for most).
    grads = np.zeros((len(keys), p))
    for j in range(p):
        h = 1e-6 * max(1.0, abs(result.x[j]))
        xp = result.x.copy()
        xp[j] += h
        shifted = public(xp)
        grads[:, j] = [(shifted[k] - centre[k]) / h for k in keys]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", grads, cov, grads), 0.0))
    for (e, k), value, s in zip(keys, (centre[k] for k in keys), sd):
        estimates.setdefault(e, {})[k] = float(value)
        ci.setdefault(e, {})[k] = [float(value - 1.96 * s), float(value + 1.96 * s)]
    return estimates, ci, params


def fit_candidates(problem: FitProblem, candidates: list[tuple[str, ...]] | None = None) -> list[CandidateFit]:
    """Fit every candidate on the train blocks and score it on the held-out blocks."""
    candidates = all_candidates() if candidates is None else candidates
    weight = problem.train.astype(float)
    grid_cache: dict[tuple[str, ...], tuple] = {}
    fits: list[CandidateFit] = []
    n_train = max(int(problem.train.sum()), 1)
    n_held = max(int(problem.heldout.sum()), 1)
    for effects in candidates:
        dof = sum(EFFECT_DOF[e] for e in effects)
        if not effects:
            pred = problem.predict(EffectParams())
            err = pred - problem.y
            fits.append(CandidateFit((), EffectParams(), 0, float(np.sum(err[problem.train] ** 2)) / n_train,
                                     float(np.sum(err[problem.heldout] ** 2)) / n_held))
            continue
        key = _nonlinear_key(effects)
        if key not in grid_cache:
            grid = _grid(key, problem.a, problem.b)
            grid_cache[key] = (grid, problem.batch_statistics(*grid, weight))
        (delays, taus, cfs, crs), stats = grid_cache[key]
        sse, gains, offsets = profiled_sse(stats, "steering_gain" in effects, "steering_offset" in effects)
        best_polished = None
        order = np.argsort(sse)
        for idx in order[:N_POLISH]:
            start = EffectParams(
                delay_s=float(delays[idx]), time_constant_s=float(taus[idx]),
                gain=float(np.clip(gains[idx], *BOUNDS["gain"])),
                offset_rad=float(np.clip(offsets[idx], *BOUNDS["offset_rad"])),
                cf_per_kg=float(cfs[idx]) if cfs[idx] > 0 else None,
                cr_per_kg=float(crs[idx]) if crs[idx] > 0 else None,
            )
            result, names = _polish(problem, effects, start)
            if best_polished is None or result.cost < best_polished[0].cost:
                best_polished = (result, names)
        result, names = best_polished
        estimates, ci, params = _uncertainty(problem, effects, names, result)
        err = problem.predict(params) - problem.y
        fits.append(CandidateFit(effects, params, dof, float(np.sum(err[problem.train] ** 2)) / n_train,
                                 float(np.sum(err[problem.heldout] ** 2)) / n_held, estimates=estimates, ci95=ci))
    for f in fits:
        f.score = f.heldout_mse * (1.0 + PENALTY_PER_PARAMETER * f.dof)
    return fits


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
    """t statistic of the mean squared-error reduction, over ``block_s`` blocks of ``mask`` samples."""
    gain = err_plain**2 - err_model**2
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)[mask]
    values = gain[mask]
    if values.size == 0:
        return 0.0
    sums = np.bincount(block, weights=values)
    counts = np.bincount(block)
    means = sums[counts > 0] / counts[counts > 0]
    if means.size < 3:
        return 0.0
    sd = means.std(ddof=1)
    if sd == 0:
        return math.inf if means.mean() > 0 else 0.0
    return float(means.mean() / (sd / math.sqrt(means.size)))


def _is_superset(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    return set(b) <= set(a)


def select(problem: FitProblem, fits: list[CandidateFit], noise_sigma: float) -> Selection:
    ranking = sorted(fits, key=lambda f: f.score)
    plain = next(f for f in fits if not f.effects)
    best = ranking[0]
    if best.effects:
        others = [f for f in ranking if f is not best and not _is_superset(f.effects, best.effects)]
    else:
        others = [f for f in ranking if f.effects]
    err_plain = problem.predict(plain.params) - problem.y
    t_stat = 0.0
    if best.effects:
        err_best = problem.predict(best.params) - problem.y
        t_stat = paired_t_statistic(err_plain, err_best, problem.heldout, problem.recording.t_s)
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
    if verdict == "match":
        others = [f for f in ranking if f.effects]
    runner_up = others[0]
    margin = runner_up.score / winner.score - 1.0 if winner.score > 0 else math.inf
    return Selection(verdict, winner, best, runner_up, plain, t_stat, margin, ranking, reason)


def make_problem(recording: Recording, signal: FitSignal, block_s: float | None = None) -> FitProblem:
    block_s = default_block_s(recording.duration_s) if block_s is None else block_s
    train, heldout = block_split(recording.t_s, block_s)
    return FitProblem(recording, signal, train & signal.usable, heldout & signal.usable)
