"""A grid of parameter sets simulated as one parallel batch, with the linear parameters in closed form.

A candidate's nonlinear parameters (delays, time constant, tires, rate limit, friction) are tried
on a grid; its linear parameters (gain, offset, bank) enter the signal linearly (or nearly), so at
every grid point the best values follow from a weighted Gram matrix of the residual and the
signal's sensitivities to them (:func:`grid_statistics`, then :func:`profile_linear`). One
simulation serves every cross-validation fold (a weight row per fold). Grid points are a
structured array of :data:`~plm_highway.sim2real.physics.chain.CHAIN_DTYPE`; a linear coordinate is a
direction in that space (:class:`LinearDirection`).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np

from plm_highway.sim2real.physics.chain import (
    CHAIN_DTYPE,
    CarParams,
    ChainOutputs,
    ChainParams,
    Drive,
    TireTable,
    _delayed,
    simulate_chain,
    tire_maps,
    unit_bank_response,
)
from plm_highway.sim2real.physics.filters import fir_filter


class GridChannel(NamedTuple):
    """The recorded channel a grid is scored on (``y``) and the FIR filter (``taps`` from offset
    ``lo``) through which it sees a model's yaw rate."""

    y: np.ndarray
    taps: np.ndarray
    lo: int


class LinearDirection(NamedTuple):
    """A linear coordinate: the chain parameter it moves and the finite-difference step there."""

    field: str
    step: float


class TireTables(NamedTuple):
    """Linear-tire tables shared by grid points: ``index[g]`` is point g's row (-1: none)."""

    index: np.ndarray  # (G,) int64
    maps: np.ndarray  # (T, n-1, 8)
    start: np.ndarray  # (T, 2)
    bank_r: np.ndarray  # (T, n) or (T, 0) without a bank
    bank_vy: np.ndarray


@numba.njit(cache=True, nogil=True)
def _chain_at(points, g):
    """Grid point ``g`` (a record of CHAIN_DTYPE) as :class:`ChainParams`."""
    q = points[g]
    return ChainParams(q.gain, q.offset_rad, q.delay_s, q.time_constant_s, q.max_rate_radps, q.cf_per_kg,
                       q.cr_per_kg, q.friction_coefficient, q.bank_accel_mps2, q.sensor_delay_s, q.jitter_s,
                       q.speed_gain_slope, q.speed_ref_mps, q.asymmetry, q.dead_band_rad, q.play_rad,
                       q.saturation_rad, q.gyro_bias_radps)


@numba.njit(cache=True, nogil=True)
def _moved(p, d):
    """``p`` moved by the record ``d`` (zero except along one linear coordinate)."""
    return ChainParams(p.gain + d.gain, p.offset_rad + d.offset_rad, p.delay_s + d.delay_s,
                       p.time_constant_s + d.time_constant_s, p.max_rate_radps + d.max_rate_radps,
                       p.cf_per_kg + d.cf_per_kg, p.cr_per_kg + d.cr_per_kg,
                       p.friction_coefficient + d.friction_coefficient, p.bank_accel_mps2 + d.bank_accel_mps2,
                       p.sensor_delay_s + d.sensor_delay_s, p.jitter_s + d.jitter_s,
                       p.speed_gain_slope + d.speed_gain_slope, p.speed_ref_mps + d.speed_ref_mps,
                       p.asymmetry + d.asymmetry, p.dead_band_rad + d.dead_band_rad, p.play_rad + d.play_rad,
                       p.saturation_rad + d.saturation_rad, p.gyro_bias_radps + d.gyro_bias_radps)


@numba.njit(cache=True, nogil=True)
def _channel(r, dt, sensor_delay_s, bias, taps, lo, out):
    """A model's yaw rate as a recorded rotation channel sees it: late by the sensor delay, filtered,
    plus the sensor's bias (the gyro's; zero for the other channels)."""
    if sensor_delay_s > 0.0:
        late = np.empty(r.shape[0])
        _delayed(r, sensor_delay_s / dt, late)
        fir_filter(late, taps, lo, out)
    else:
        fir_filter(r, taps, lo, out)
    if bias != 0.0:
        for k in range(out.shape[0]):
            out[k] += bias


@numba.njit(cache=True, nogil=True)
def _grid_into(drive, car, points, tires, channel, moves, step_sizes, weight, same_chain, first, last, gram):
    """Rows ``first:last`` of :func:`grid_statistics`; releases the GIL. ``same_chain[g]``: point g differs from
    point g-1 only in what acts on the channel (sensor delay, gyro bias), so its chain's yaw rate is the one
    simulated for g-1."""
    n = drive.steer.shape[0]
    n_lin = moves.shape[0]
    out = ChainOutputs(np.empty(n), np.empty(n), np.empty(n))
    columns = np.empty((n_lin + 1, n))
    pred = np.empty(n)
    r = np.empty(n)
    y, taps, lo = channel.y, channel.taps, channel.lo
    for g in range(first, last):
        p = _chain_at(points, g)
        ti = tires.index[g]
        if ti >= 0:
            tire = TireTable(tires.maps[ti], tires.start[ti], tires.bank_r[ti], tires.bank_vy[ti])
        else:
            tire = TireTable(np.zeros((0, 8)), np.zeros(0), np.zeros(0), np.zeros(0))
        if g == first or not same_chain[g]:
            simulate_chain(drive, p, car, tire, out, 0)
            for k in range(n):
                r[k] = out.r[k]
        _channel(r, drive.dt_s, p.sensor_delay_s, p.gyro_bias_radps, taps, lo, pred)
        for k in range(n):
            columns[0, k] = y[k] - pred[k]
        for j in range(n_lin):
            q = _moved(p, moves[j])
            simulate_chain(drive, q, car, tire, out, 0)
            other = np.empty(n)
            _channel(out.r, drive.dt_s, q.sensor_delay_s, q.gyro_bias_radps, taps, lo, other)
            for k in range(n):
                columns[j + 1, k] = (other[k] - pred[k]) / step_sizes[j]
        for f in range(weight.shape[0]):
            for i in range(n_lin + 1):
                for j in range(i, n_lin + 1):
                    acc = 0.0
                    for k in range(n):
                        w = weight[f, k]
                        if w != 0.0:
                            acc += w * columns[i, k] * columns[j, k]
                    gram[g, f, i, j] = acc
                    gram[g, f, j, i] = acc


def in_threads(fn, n_items: int, *args) -> None:
    """Run ``fn(*args[0], first, last, *args[1])`` over chunks of ``range(n_items)`` on all cores.

    The kernels release the GIL, so threads run them in parallel without numba's parallel
    compilation (which costs tens of seconds on a cold cache).
    """
    n_threads = max(1, min(os.cpu_count() or 1, n_items))
    if n_threads == 1:
        fn(*args[0], 0, n_items, *args[1])
        return
    # More chunks than threads: grid points differ in cost (sub-stepped tires at low speed).
    bounds = np.linspace(0, n_items, min(n_items, 4 * n_threads) + 1).astype(int)
    with ThreadPoolExecutor(n_threads) as pool:
        futures = [pool.submit(fn, *args[0], int(bounds[i]), int(bounds[i + 1]), *args[1])
                   for i in range(len(bounds) - 1)]
        for f in futures:
            f.result()


@numba.njit(cache=True, nogil=True)
def _tire_tables_into(drive, car, cfs, crs, with_bank, first, last, maps_all, start_all, bank_r_all, bank_vy_all):
    for i in range(first, last):
        maps, start = tire_maps(drive.speed, drive.dt_s, cfs[i], crs[i], car.a_m, car.b_m, car.k2_m2, car.u_min_mps)
        maps_all[i] = maps
        start_all[i] = start
        if with_bank:
            unit_bank_response(drive.speed, drive.dt_s, cfs[i], crs[i], car.a_m, car.b_m, car.k2_m2, car.u_min_mps,
                               bank_r_all[i], bank_vy_all[i])


def tire_tables(drive: Drive, car: CarParams, cfs: np.ndarray, crs: np.ndarray, with_bank: bool = False
                ) -> TireTables:
    """Maps, settled starts (and unit-bank responses) for a set of linear-tire candidates (index: 0..T-1)."""
    n = drive.speed.shape[0]
    n_tire = cfs.shape[0]
    maps_all = np.empty((n_tire, n - 1, 8))
    start_all = np.empty((n_tire, 2))
    bank_r_all = np.empty((n_tire, n if with_bank else 0))
    bank_vy_all = np.empty((n_tire, n if with_bank else 0))
    in_threads(_tire_tables_into, n_tire, (drive, car, cfs, crs, with_bank),
               (maps_all, start_all, bank_r_all, bank_vy_all))
    return TireTables(np.arange(n_tire, dtype=np.int64), maps_all, start_all, bank_r_all, bank_vy_all)


def grid_statistics(drive: Drive, car: CarParams, points: np.ndarray, channel: GridChannel, weight: np.ndarray,
                    linear: list[LinearDirection]) -> np.ndarray:
    """For each parameter set in ``points`` (structured, :data:`CHAIN_DTYPE`) and weight row f: the
    weighted Gram matrix of [e, s_1, ..., s_L], shape (G, F, L+1, L+1).

    ``e`` is the measured channel minus the model's, ``s_j`` the model channel's sensitivity to the
    linear coordinate ``linear[j]`` (forward difference of its step: exact for a linear model, the
    local linearisation otherwise). Each weight row is a fold's train mask, so one simulation
    serves all folds. Linear tires are precomputed once per distinct tire.
    """
    points = np.ascontiguousarray(points, CHAIN_DTYPE)
    n_points = points.shape[0]
    linear_tires = (points["cf_per_kg"] > 0) & ~np.isfinite(points["friction_coefficient"])
    tires = TireTables(np.full(n_points, -1, np.int64), np.zeros((1, 0, 8)), np.zeros((1, 0)), np.zeros((1, 0)),
                       np.zeros((1, 0)))
    if linear_tires.any():
        stiffness = np.column_stack([points["cf_per_kg"], points["cr_per_kg"]])[linear_tires]
        distinct, inverse = np.unique(stiffness, axis=0, return_inverse=True)
        with_bank = bool(np.any(points["bank_accel_mps2"] != 0) or any(d.field == "bank_accel_mps2" for d in linear))
        table = tire_tables(drive, car, np.ascontiguousarray(distinct[:, 0]), np.ascontiguousarray(distinct[:, 1]),
                            with_bank)
        index = np.full(n_points, -1, np.int64)
        index[linear_tires] = inverse.ravel()
        tires = table._replace(index=index)
    moves = np.zeros(len(linear), CHAIN_DTYPE)
    for j, d in enumerate(linear):
        moves[d.field][j] = d.step
    step_sizes = np.array([d.step for d in linear], float)
    # Points whose chains differ only in what acts on the channel alone are simulated once: ordered so that they
    # neighbour each other (each row is still computed from its own point; the rows go back to the points' order).
    order, same_chain = _chain_groups(points)
    sorted_tires = tires._replace(index=np.ascontiguousarray(tires.index[order]))
    gram = np.zeros((n_points, weight.shape[0], len(linear) + 1, len(linear) + 1))
    in_threads(_grid_into, n_points, (drive, car, np.ascontiguousarray(points[order]), sorted_tires, channel, moves,
                                      step_sizes, weight, same_chain), (gram,))
    out = np.empty_like(gram)
    out[order] = gram
    return out


CHANNEL_ONLY_FIELDS = ("sensor_delay_s", "gyro_bias_radps")  # simulate_chain reads neither: see _channel


def _chain_groups(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An order of ``points`` in which points with the same chain (every field but :data:`CHANNEL_ONLY_FIELDS`) are
    adjacent, first-seen chains first and each group in its points' order; and, in that order, whether a point's
    chain is its predecessor's."""
    chains = points.copy()
    for name in CHANNEL_ONLY_FIELDS:
        chains[name] = 0.0
    keys = chains.view(np.dtype((np.void, chains.dtype.itemsize)))
    _, first_of, group = np.unique(keys, return_index=True, return_inverse=True)
    group = group.ravel()
    order = np.lexsort((np.arange(len(points)), first_of[group]))
    same_chain = np.zeros(len(points), np.bool_)
    same_chain[1:] = group[order][1:] == group[order][:-1]
    return order, same_chain


def profile_linear(gram: np.ndarray, lo: np.ndarray, hi: np.ndarray, base: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares SSE of each grid point with its linear parameters solved (clipped to bounds);
    ``gram`` is (G, L+1, L+1) for one fold. Returns (sse [G], solved values [G, L])."""
    n_lin = gram.shape[-1] - 1
    if n_lin == 0:
        return np.maximum(gram[:, 0, 0], 0.0), np.zeros((gram.shape[0], 0))
    a = gram[:, 1:, 1:]
    rhs = gram[:, 1:, 0]
    scale = np.sqrt(np.maximum(np.einsum("gii->gi", a), 1e-300))
    a_n = a / scale[:, :, None] / scale[:, None, :] + 1e-12 * np.eye(n_lin)
    step = np.linalg.solve(a_n, (rhs / scale)[..., None])[..., 0] / scale
    values = np.clip(base + step, lo, hi)
    step = values - base
    sse = gram[:, 0, 0] - 2 * np.einsum("gi,gi->g", step, rhs) + np.einsum("gi,gij,gj->g", step, a, step)
    return np.maximum(sse, 0.0), values
