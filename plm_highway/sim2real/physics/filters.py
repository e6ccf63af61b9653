"""How a recorded channel sees a model output: finite-impulse-response filters read at every sample
or at a few (numba kernels; indices are clamped at the ends of the recording).

A rotation channel (the gyro, or the heading's Savitzky-Golay derivative) is a FIR filter of the
model's yaw rate; the lateral velocity taken from positions is a FIR filter of velocities that turn
with the car within the window (:func:`lateral_fir_at`). ``replay`` builds the taps.
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True, nogil=True)
def fir_filter(x, taps, lo, out):
    """out[k] = sum_j taps[j] * x[k + lo + j], indices clamped at the ends."""
    n = x.shape[0]
    m = taps.shape[0]
    if m == 1 and lo == 0:
        for k in range(n):
            out[k] = taps[0] * x[k]
        return
    for k in range(n):
        acc = 0.0
        for j in range(m):
            i = min(max(k + lo + j, 0), n - 1)
            acc += taps[j] * x[i]
        out[k] = acc


@numba.njit(cache=True, nogil=True)
def fir_filter_at(x, taps, lo, index, out):
    """out[i] = sum_j taps[j] * x[index[i] + lo + j] (indices clamped): a filter read at a few samples."""
    n = x.shape[0]
    m = taps.shape[0]
    for i in range(index.shape[0]):
        k = index[i]
        acc = 0.0
        for j in range(m):
            acc += taps[j] * x[min(max(k + lo + j, 0), n - 1)]
        out[i] = acc


@numba.njit(cache=True, nogil=True)
def lateral_fir_at_turned(vy, speed, heading, taps, lo, index, out, cos_turn, sin_turn, known):
    """:func:`lateral_fir_at` with the turns' cosines and sines (which depend on the recorded heading only) kept:
    ``cos_turn``/``sin_turn`` [len(index), len(taps)] are filled here when not ``known``, read when ``known``. The
    arithmetic is lateral_fir_at's, term by term, so the output is the same to the bit; the trigonometry, most of
    the cost, is done once per heading and index instead of once per model."""
    n = vy.shape[0]
    m = taps.shape[0]
    for i in range(index.shape[0]):
        k = index[i]
        acc = 0.0
        for j in range(m):
            s = min(max(k + lo + j, 0), n - 1)
            if known:
                cos_dh = cos_turn[i, j]
                sin_dh = sin_turn[i, j]
            else:
                dh = heading[s] - heading[k]
                cos_dh = math.cos(dh)
                sin_dh = math.sin(dh)
                cos_turn[i, j] = cos_dh
                sin_turn[i, j] = sin_dh
            v = speed[s]
            along = math.sqrt(max(v * v - vy[s] * vy[s], 0.0))
            acc += taps[j] * (vy[s] * cos_dh + (along - v) * sin_dh)
        out[i] = acc


@numba.njit(cache=True, nogil=True)
def lateral_fir_at(vy, speed, heading, taps, lo, index, out):
    """What a lateral velocity taken from positions reads when the car's is ``vy``: the velocities
    in the filter window, each along the heading it had, projected on the car's lateral axis at the
    sample, minus the part a plain rotation of ``speed`` gives (the measurement subtracts it too):
    out[i] = sum_j taps[j] (vy cos(dh) + (sqrt(v^2 - vy^2) - v) sin(dh)) at k + lo + j, dh the turn."""
    n = vy.shape[0]
    m = taps.shape[0]
    for i in range(index.shape[0]):
        k = index[i]
        acc = 0.0
        for j in range(m):
            s = min(max(k + lo + j, 0), n - 1)
            dh = heading[s] - heading[k]
            v = speed[s]
            along = math.sqrt(max(v * v - vy[s] * vy[s], 0.0))
            acc += taps[j] * (vy[s] * math.cos(dh) + (along - v) * math.sin(dh))
        out[i] = acc
