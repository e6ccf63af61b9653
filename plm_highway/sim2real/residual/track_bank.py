"""A road bank that varies along the track: a lateral pull tied to places, not to times.

The library's ``road_bank`` is one cross slope for the whole run. A circuit is banked in its curves
and flat elsewhere; a car that passes the same places lap after lap then carries an error that
repeats with the place. The bank is a field over places along the track: anchors every
``spacing`` metres of the path (each sample belongs to its nearest anchor), one bank angle per
anchor, smooth between neighbouring anchors. It enters the single-track model as the lateral
acceleration ``g sin(bank)`` (a bank acts through the tires: a kinematic bicycle cannot crab), so
each anchor's bank moves every recorded channel linearly (its columns are the tire model's response
to that anchor's lateral pull), and the field is a penalised least-squares fit (graph-Laplacian
smoothness between neighbouring anchors, the penalty chosen on held-out visits). It is held out by
place: every visit to a place (a lap) alternates between the two folds, so the field fitted on one
half of the laps predicts the other half at the same places. It enters only when the error follows
the track position rather than the time, which is what tells a road from a sensor or a steering
fault; a recording that passes most places once cannot tell them apart and the field is not tried.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from plm_highway.sim2real.fit.polish import coordinates
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem, heldout_mask
from plm_highway.sim2real.fit.scoring import combined_score
from plm_highway.sim2real.physics.effects import EffectParams, coordinates_of, params_from
from plm_highway.sim2real.physics.replay import channel_prediction, model_outputs
from plm_highway.vehicle.single_track import single_track_matrices
from plm_highway.vehicle.tires import GRAVITY_MPS2

SPACING_S = 1.0  # anchors about one second of driving apart ...
SPACING_RANGE_M = (5.0, 40.0)  # ... within this range, and at least this many wheelbases
MIN_SPACING_WHEELBASES = 5.0
MIN_REVISITED = 0.5  # share of samples at places the car passes at least twice
VISIT_GAP_S = 5.0  # time away from a place that makes the next pass a new visit
PENALTY_GRID = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
FIELD_DOF = 2  # the penalty and the anchor spacing
REFIT_STEPS = 1
SETTLE_AFTER_PULL_S = 3.0  # the tire model's lateral modes die out well within this  # Gauss-Newton steps of the chain before the field fitted on every sample
CURVE_KAPPA = 0.004  # 1/m: a place counts as a curve above this curvature (radius under 250 m)


@dataclass
class BankField:
    anchors_xy: np.ndarray  # (M, 2)
    anchor_bank_rad: np.ndarray  # (M,) the bank at each anchor
    standard_error_rad: np.ndarray  # (M,)
    covariance: np.ndarray  # (M, M), of the bank values (neighbours are smoothed together)
    curvature: np.ndarray  # (M,) mean path curvature at each anchor [1/m]
    assignment: np.ndarray  # (n,) anchor of each sample (-1: none)
    spacing_m: float
    penalty: float

    def at_samples(self) -> np.ndarray:
        return np.where(self.assignment >= 0, self.anchor_bank_rad[np.maximum(self.assignment, 0)], 0.0)


@numba.njit(cache=True, nogil=True)
def lateral_pull_response(speed, dt, cf, cr, a, b, k2, u_min, accel, r_out, vy_out):
    """Yaw rate and lateral velocity of the linear single-track model (no steering) under a lateral
    acceleration series ``accel`` (trapezoidal rule, sub-stepped for the stiffest mode; from rest)."""
    n = speed.shape[0]
    vy = 0.0
    r = 0.0
    r_out[0] = 0.0
    vy_out[0] = 0.0
    for k in range(n - 1):
        ua = max(speed[k], u_min)
        ub = max(speed[k + 1], u_min)
        stiff = (cf + cr) / min(ua, ub) * (1.0 + max(a, b) ** 2 / k2)
        n_sub = min(max(math.ceil(dt * stiff / 1.5), 1), 200)
        h = dt / n_sub
        for i in range(n_sub):
            f0 = i / n_sub
            f1 = (i + 1) / n_sub
            u0 = ua + (ub - ua) * f0
            u1 = ua + (ub - ua) * f1
            p0 = accel[k] + (accel[k + 1] - accel[k]) * f0
            p1 = accel[k] + (accel[k + 1] - accel[k]) * f1
            a11, a12, a21, a22, _, _ = single_track_matrices(u0, cf, cr, a, b, k2)
            q11, q12, q21, q22, _, _ = single_track_matrices(u1, cf, cr, a, b, k2)
            rhs1 = vy + 0.5 * h * (a11 * vy + a12 * r + p0) + 0.5 * h * p1
            rhs2 = r + 0.5 * h * (a21 * vy + a22 * r)
            m11 = 1.0 - 0.5 * h * q11
            m12 = -0.5 * h * q12
            m21 = -0.5 * h * q21
            m22 = 1.0 - 0.5 * h * q22
            inv_det = 1.0 / (m11 * m22 - m12 * m21)
            vy = (m22 * rhs1 - m12 * rhs2) * inv_det
            r = (-m21 * rhs1 + m11 * rhs2) * inv_det
        r_out[k + 1] = r
        vy_out[k + 1] = vy


def anchors(x: np.ndarray, y: np.ndarray, usable: np.ndarray, spacing_m: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Anchors every ``spacing_m`` along the path (in the order first reached) and each sample's
    nearest anchor (-1 when farther than the spacing, or not usable)."""
    centres = np.empty((max(int(usable.sum()), 1), 2))
    m = 0
    for px, py in zip(x[usable], y[usable]):
        if m == 0 or np.min((centres[:m, 0] - px) ** 2 + (centres[:m, 1] - py) ** 2) > spacing_m**2:
            centres[m] = px, py
            m += 1
    centres = centres[:m]
    distance, index = cKDTree(centres).query(np.column_stack([x, y]))
    return centres, np.where((distance <= spacing_m) & usable, index, -1)


def _laplacian(centres: np.ndarray, spacing_m: float) -> np.ndarray:
    pairs = cKDTree(centres).query_pairs(1.6 * spacing_m, output_type="ndarray")
    m = len(centres)
    lap = np.zeros((m, m))
    for i, j in pairs:
        lap[i, j] -= 1.0
        lap[j, i] -= 1.0
        lap[i, i] += 1.0
        lap[j, j] += 1.0
    return lap


def tire_params(base: CandidateFit, ranking: list[CandidateFit]) -> EffectParams | None:
    """The chain a bank acts through: the base's, or the best-ranked candidate with tires."""
    if base.params.cf_per_kg is not None:
        return base.params
    for fit in ranking:
        if fit.params.cf_per_kg is not None:
            return fit.params
    return None


def _spacing(problem: FitProblem) -> float:
    rec = problem.recording
    lo, hi = SPACING_RANGE_M
    return float(np.clip(SPACING_S * problem.ctx.speed_median_mps, max(lo, MIN_SPACING_WHEELBASES
                                                                       * rec.vehicle.wheelbase_m), hi))


def compare(problem: FitProblem, base: CandidateFit, ranking: list[CandidateFit]
            ) -> tuple[FitProblem, CandidateFit, CandidateFit, BankField] | str:
    """(the problem held out by place, the chain and the chain with a bank field held out there, the
    field fitted on every sample); or why it was not tried."""
    rec = problem.recording
    tires = tire_params(base, ranking)
    if tires is None:
        return "no tire model in any candidate (a bank acts through the tires)"
    usable = problem.signal.usable
    spacing = _spacing(problem)
    centres, assignment = anchors(rec.x_m, rec.y_m, usable, spacing)
    visit, visits_at = _visits(assignment, rec.t_s, len(centres))
    assigned = assignment >= 0
    share = float(np.mean((visits_at[np.maximum(assignment, 0)] >= 2)[assigned])) if assigned.any() else 0.0
    if share < MIN_REVISITED:
        return (f"the car passes most places once (only {100 * share:.0f}% of the samples are at places it passes "
                "twice or more): a place cannot be told from a time")
    odd = visit % 2 == 1
    places = FitProblem(rec, problem.channels, [(~odd, odd), (odd, ~odd)])
    m = len(centres)
    # The chain's own coordinates are refitted with the field (linearised, not penalised): a bank the
    # library could not represent has pulled them (stiffer tires, a lag), and a field on a fixed chain
    # would take up their error instead.
    chain = _chain_columns(problem, base.effects, base.params)
    columns = [np.hstack([b, c]) for b, c in zip(_columns(problem, tires, assignment, m), chain)]
    penalty = np.zeros((columns[0].shape[1],) * 2)
    penalty[:m, :m] = _laplacian(centres, spacing) + 1e-3 * np.eye(m)
    preds = problem.predictions(base.params)
    per_fold = [(folds, *_normal(places, columns, preds, [train for train, _ in folds]))
                for folds in zip(*places.channel_folds)]
    before = _candidate(places, base, _held_out(rec.n, per_fold, preds, columns, None, m), base.dof)
    best = None
    for factor in PENALTY_GRID:
        fit = _candidate(places, base, _held_out(rec.n, per_fold, preds, columns, factor * penalty, m),
                         base.dof + FIELD_DOF)
        if best is None or fit.score < best[0].score:
            best = (fit, factor)
    fit, factor = best
    # On every sample: a second Gauss-Newton step from the chain the first one refitted.
    params = base.params
    for _ in range(REFIT_STEPS):
        beta = _all_data_solution(problem, params, columns, factor * penalty, m)
        params = _moved_chain(problem, base.effects, params, beta[m:])
        chain = _chain_columns(problem, base.effects, params)
        tires = params if params.cf_per_kg is not None else tires
        columns = [np.hstack([b, c]) for b, c in zip(_columns(problem, tires, assignment, m), chain)]
    field = _all_data_field(problem, params, columns, factor * penalty, centres, assignment, spacing, m)
    return places, before, fit, field


def _moved_chain(problem: FitProblem, effects: tuple[str, ...], params: EffectParams, step: np.ndarray
                 ) -> EffectParams:
    """The chain with its coordinates moved by ``step`` (in :func:`_chain_columns`' order), within bounds."""
    ctx = problem.ctx
    coords = [c for c in coordinates(effects, ctx) if not c.variance]
    values = coordinates_of(effects, params, ctx)
    for c, d in zip(coords, step):
        values[c.key] = float(np.clip(values[c.key] + d, c.lo, c.hi))
    return params_from(effects, values, ctx)


def _solve(gram: np.ndarray, rhs: np.ndarray, penalty: np.ndarray | None, m: int) -> np.ndarray:
    """Penalised least squares; without a penalty, the chain's coordinates alone (no field)."""
    scale = float(np.mean(np.diag(gram)[:m])) or 1.0
    if penalty is None:
        out = np.zeros(rhs.size)
        chain = gram[m:, m:] + 1e-9 * scale * np.eye(rhs.size - m)
        out[m:] = np.linalg.solve(chain, rhs[m:]) if rhs.size > m else 0.0
        return out
    return np.linalg.solve(gram + scale * (penalty + 1e-9 * np.eye(rhs.size)), rhs)


def _held_out(n, per_fold, preds, columns, penalty, m) -> list[np.ndarray]:
    oof = [np.full(n, np.nan) for _ in preds]
    for folds, gram, rhs in per_fold:
        beta = _solve(gram, rhs, penalty, m)
        for i, (pred, (_, test)) in enumerate(zip(preds, folds)):
            full = pred + columns[i] @ beta
            oof[i][test] = full[test]
    return oof


def _chain_columns(problem: FitProblem, effects: tuple[str, ...], params: EffectParams) -> list[np.ndarray]:
    """Per channel, (n, P): the channel's sensitivity to each of the chain's fitted coordinates."""
    ctx = problem.ctx
    coords = [c for c in coordinates(effects, ctx) if not c.variance]
    values = coordinates_of(effects, params, ctx)
    preds = problem.predictions(params)
    cols = [np.zeros((problem.recording.n, len(coords))) for _ in preds]
    for j, c in enumerate(coords):
        step = 1e-3 * c.scale
        moved = dict(values)
        moved[c.key] = values[c.key] + step if values[c.key] + step <= c.hi else values[c.key] - step
        shifted = problem.predictions(params_from(effects, moved, ctx))
        for i, (a, b) in enumerate(zip(shifted, preds)):
            cols[i][:, j] = (a - b) / (moved[c.key] - values[c.key])
    return cols


def _columns(problem: FitProblem, tires: EffectParams, assignment: np.ndarray, m: int) -> list[np.ndarray]:
    """Per channel, (n, M): what one radian of bank at each anchor adds to the channel (linearised)."""
    rec = problem.recording
    v = rec.vehicle
    base_out = model_outputs(rec, tires, with_slip=False)
    base_pred = [channel_prediction(c, rec, tires, base_out) for c in problem.channels]
    cols = [np.zeros((rec.n, m)) for _ in problem.channels]
    speed = np.ascontiguousarray(rec.speed_mps, float)
    settle = round(SETTLE_AFTER_PULL_S / rec.dt_s)
    for j in range(m):
        inside = assignment == j
        if not inside.any():
            continue
        # The pull acts on a few visits; its response dies out within seconds after each (from rest
        # at the start of each visit: the previous lap's has long settled).
        r = np.zeros(rec.n)
        vy = np.zeros(rec.n)
        edges = np.diff(np.concatenate([[0], inside.astype(int), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            stop = min(b + settle, rec.n)
            pull = np.where(inside[a:stop], GRAVITY_MPS2, 0.0)
            part_r, part_vy = np.empty(stop - a), np.empty(stop - a)
            lateral_pull_response(speed[a:stop], rec.dt_s, tires.cf_per_kg, tires.cr_per_kg, v.cg_to_front_m,
                                  v.cg_to_rear_m, v.yaw_inertia_per_kg_m2, rec.tire_min_speed_mps, pull, part_r,
                                  part_vy)
            r[a:stop] += part_r
            vy[a:stop] += part_vy
        outputs = (base_out[0] + r, base_out[1] + vy, base_out[2])
        for i, c in enumerate(problem.channels):
            cols[i][:, j] = channel_prediction(c, rec, tires, outputs) - base_pred[i]
    return cols


def _normal(problem: FitProblem, columns: list[np.ndarray], preds: list[np.ndarray], masks: list[np.ndarray]
            ) -> tuple[np.ndarray, np.ndarray]:
    m = columns[0].shape[1]
    gram, rhs = np.zeros((m, m)), np.zeros(m)
    for c, col, pred, mask, w in zip(problem.channels, columns, preds, masks, problem.weights):
        j = col[mask]
        gram += w * j.T @ j
        rhs += w * j.T @ (c.values - pred)[mask]
    return gram, rhs


def _visits(assignment: np.ndarray, t_s: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's visit number at its anchor (a new visit after VISIT_GAP_S away), and each
    anchor's number of visits."""
    visit = np.zeros(assignment.size, int)
    count = np.zeros(max(m, 1), int)
    last = np.full(max(m, 1), -math.inf)
    for k in np.flatnonzero(assignment >= 0):
        j = assignment[k]
        if t_s[k] - last[j] > VISIT_GAP_S:
            count[j] += 1
        last[j] = t_s[k]
        visit[k] = count[j] - 1
    return visit, count


def _candidate(problem: FitProblem, base: CandidateFit, oof: list[np.ndarray], dof: int) -> CandidateFit:
    oof = [np.array(o, float) for o in oof]
    fit = CandidateFit(base.effects, base.params, dof, math.nan, math.nan, oof=oof,
                       shapes=list(base.shapes) if base.shapes else [None] * len(oof))
    held = heldout_mask(problem, 0)
    fit.heldout_mse = float(np.mean((oof[0] - problem.signal.values)[held] ** 2))
    fit.channel_mse = {c.name: float(np.mean((oof[i] - c.values)[heldout_mask(problem, i)] ** 2))
                       for i, c in enumerate(problem.channels)}
    fit.raw_score = combined_score(problem, fit)
    fit.score = fit.raw_score * (1 + 0.01 * fit.dof)
    return fit


def _all_data_solution(problem: FitProblem, params: EffectParams, columns, penalty, m: int) -> np.ndarray:
    preds = problem.predictions(params)
    gram, rhs = _normal(problem, columns, preds, [c.usable for c in problem.channels])
    scale = float(np.mean(np.diag(gram)[:m])) or 1.0
    return np.linalg.solve(gram + scale * (penalty + 1e-9 * np.eye(rhs.size)), rhs)


def _all_data_field(problem: FitProblem, params: EffectParams, columns, penalty, centres, assignment, spacing,
                    m: int) -> BankField:
    rec = problem.recording
    preds = problem.predictions(params)
    masks = [c.usable for c in problem.channels]
    gram, rhs = _normal(problem, columns, preds, masks)
    scale = float(np.mean(np.diag(gram)[:m])) or 1.0
    system = gram + scale * (penalty + 1e-9 * np.eye(rhs.size))
    beta = np.linalg.solve(system, rhs)
    # Residual variance in the weighted metric, inflated for the primary channel's autocorrelation.
    sse, n_obs = 0.0, 0
    for c, col, pred, mask, w in zip(problem.channels, columns, preds, masks, problem.weights):
        e = (c.values - pred - col @ beta)[mask]
        sse += w * float(e @ e)
        n_obs += int(mask.sum())
    inverse = np.linalg.inv(system)
    cov = sse / max(n_obs - len(beta), 1) * n_obs * inverse @ gram @ inverse / n_obs
    primary = (problem.signal.values - preds[0] - columns[0] @ beta)[masks[0]]
    rho = float(np.clip(np.corrcoef(primary[1:], primary[:-1])[0, 1], 0.0, 0.99)) if primary.size > 3 else 0.0
    se = np.sqrt(np.maximum(np.diag(cov), 0.0) * (1 + rho) / (1 - rho))
    heading_rate = np.gradient(rec.heading_rad, rec.dt_s)
    kappa = heading_rate / np.maximum(rec.speed_mps, rec.speed_floor_mps)
    curvature = np.array([float(np.mean(kappa[assignment == j])) if np.any(assignment == j) else 0.0
                          for j in range(len(centres))])
    inflation = (1 + rho) / (1 - rho)
    return BankField(centres, beta[:m], se[:m], cov[:m, :m] * inflation, curvature, assignment, spacing,
                     float(penalty[0, 0]))


def describe(field: BankField) -> tuple[dict[str, float], dict[str, list[float]], str]:
    """Estimates, intervals and the sentence: the bank where the track curves left, right, and straight."""
    groups = {"left": field.curvature > CURVE_KAPPA, "right": field.curvature < -CURVE_KAPPA,
              "straight": np.abs(field.curvature) <= CURVE_KAPPA}
    estimates, ci, parts = {}, {}, []
    for name, sel in groups.items():
        if not sel.any():
            continue
        mean = float(np.mean(field.anchor_bank_rad[sel]))
        weights = sel / sel.sum()
        error = float(np.sqrt(max(weights @ field.covariance @ weights, 0.0)))
        estimates[f"bank_{name}_rad"] = mean
        ci[f"bank_{name}_rad"] = [mean - 1.96 * error, mean + 1.96 * error]
        where = {"left": "where the track curves left", "right": "where it curves right",
                 "straight": "on the straights"}[name]
        parts.append(f"{math.degrees(mean):+.1f} deg (+-{math.degrees(1.96 * error):.1f}) {where}")
    peak = int(np.argmax(np.abs(field.anchor_bank_rad)))
    estimates["max_abs_bank_rad"] = float(abs(field.anchor_bank_rad[peak]))
    ci["max_abs_bank_rad"] = [estimates["max_abs_bank_rad"] - 1.96 * float(field.standard_error_rad[peak]),
                              estimates["max_abs_bank_rad"] + 1.96 * float(field.standard_error_rad[peak])]
    estimates["anchors"] = float(len(field.anchor_bank_rad))
    estimates["spacing_m"] = field.spacing_m
    sentence = ("the car yaws as if the road were banked along the track (positive: falling to the left): "
                + ", ".join(parts) + f"; at most {math.degrees(estimates['max_abs_bank_rad']):.1f} deg "
                f"({len(field.anchor_bank_rad)} places {field.spacing_m:.0f} m apart)")
    return estimates, ci, sentence
