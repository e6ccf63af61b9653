"""A grid of parameter sets simulated as one parallel batch, with the linear parameters in closed form.

A candidate's nonlinear parameters (delays, time constant, tires, rate limit, friction) are tried
on a grid; its linear parameters (gain, offset, bank) enter the signal linearly (or nearly), so at
every grid point the best values follow from a weighted Gram matrix of the residual and the
signal's sensitivities to them (:func:`grid_statistics`, then :func:`profile_linear`). One
simulation serves every cross-validation fold (a weight row per fold). Grid points are a
structured array of :data:`~plm_highway.sim2real.physics.effects.CHAIN_DTYPE` (its fields are the
registry's); a linear coordinate is a direction in that space (:class:`LinearDirection`). Nothing
here names a parameter: the kernels of :mod:`~plm_highway.sim2real.physics.chain` read them.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np
from numba.np.unsafe.ndarray import to_fixed_tuple

from plm_highway.sim2real.physics.chain import (
    CarParams,
    ChainOutputs,
    Drive,
    TireTable,
    gyro_channel,
    linear_tire_points,
    simulate_chain,
    tire_maps,
    unit_bank_response,
)
from plm_highway.sim2real.physics.effects import CHAIN_DTYPE, CHAIN_FIELDS, GYRO_ONLY_NEUTRAL, ChainParams

# Fields per parameter set: a compile-time constant of the kernels below. Their cached machine code is
# keyed on the grid's structured dtype, so a changed set of fields compiles them afresh.
N_CHAIN_FIELDS = len(CHAIN_FIELDS)


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
    """Grid point ``g`` (a record of CHAIN_DTYPE: all fields float64) as :class:`ChainParams`."""
    values = points.view(np.float64)
    return ChainParams(*to_fixed_tuple(values[g * N_CHAIN_FIELDS:(g + 1) * N_CHAIN_FIELDS], N_CHAIN_FIELDS))


@numba.njit(cache=True, nogil=True)
def _moved(points, g, moves, j):
    """Grid point ``g`` moved by ``moves[j]`` (zero except along one linear coordinate)."""
    values = points.view(np.float64)
    move = moves.view(np.float64)
    row = values[g * N_CHAIN_FIELDS:(g + 1) * N_CHAIN_FIELDS] + move[j * N_CHAIN_FIELDS:(j + 1) * N_CHAIN_FIELDS]
    return ChainParams(*to_fixed_tuple(row, N_CHAIN_FIELDS))


@numba.njit(cache=True, nogil=True)
def _grid_into(drive, car, points, tires, channel, moves, step_sizes, weight, same_chain, first, last, gram):
    """Rows ``first:last`` of :func:`grid_statistics`; releases the GIL. ``same_chain[g]``: point g differs from
    point g-1 only in what acts on the gyro alone (:data:`GYRO_ONLY_NEUTRAL`), so its chain's yaw rate is the one
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
        gyro_channel(r, drive.dt_s, p, taps, lo, pred)
        for k in range(n):
            columns[0, k] = y[k] - pred[k]
        for j in range(n_lin):
            q = _moved(points, g, moves, j)
            simulate_chain(drive, q, car, tire, out, 0)
            other = np.empty(n)
            gyro_channel(out.r, drive.dt_s, q, taps, lo, other)
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
    linear_tires, stiffness, with_bank = linear_tire_points(points, [d.field for d in linear])
    tires = TireTables(np.full(n_points, -1, np.int64), np.zeros((1, 0, 8)), np.zeros((1, 0)), np.zeros((1, 0)),
                       np.zeros((1, 0)))
    if linear_tires.any():
        distinct, inverse = np.unique(stiffness, axis=0, return_inverse=True)
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


def _chain_groups(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An order of ``points`` in which points with the same chain (every field but the gyro's alone) are
    adjacent, first-seen chains first and each group in its points' order; and, in that order, whether a point's
    chain is its predecessor's."""
    chains = points.copy()
    for name, neutral in GYRO_ONLY_NEUTRAL.items():
        chains[name] = neutral
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
