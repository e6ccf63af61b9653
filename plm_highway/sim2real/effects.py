"""The library of physics a kinematic-bicycle simulator leaves out, each a term added to its model.

The simulator (highway-env's kinematic bicycle) turns the commanded front-wheel angle into a yaw rate
instantly: ``r = v sin(beta) / lr`` with ``beta = atan(lr / L tan(delta))``. Each candidate effect
inserts one physical term into that chain:

=================== ======================================= =====================================
effect              term added                              parameters (fixed names)
=================== ======================================= =====================================
steering_gain       delta <- gain * delta                   ``gain``
steering_offset     delta <- delta + offset                 ``offset_rad``
transport_delay     delta(t) <- delta(t - delay)            ``delay_s``
actuator_lag        tau delta' = delta_cmd - delta          ``time_constant_s``
tire_slip           kinematic bicycle -> dynamic single-    ``understeer_gradient_rad_per_mps2``
                    track with linear tires                 (+ ``cornering_stiffness_front`` /
                                                            ``_rear`` [N/rad] when mass and
                                                            yaw inertia are known)
=================== ======================================= =====================================

Order of the chain: gain and offset (the steering system's calibration), then the delay (a pure
transport delay of the command), then the first-order actuator, then the vehicle. Gain, offset,
delay and lag are linear, so their order among themselves does not change the output.

All parameters at their neutral values (gain 1, offset 0, delay 0, lag 0, no tire slip) give the
simulator's model exactly: the plain model is one point of every candidate's family.

The numerical kernels are compiled with numba: :func:`simulate_yaw_rate` runs one parameter set
over a recording; :func:`candidate_statistics` runs a whole batch of candidate parameter sets in
parallel and returns, for each, the sums needed to solve gain and offset in closed form (they enter
the yaw rate linearly: exactly for the tire model, to first order for the kinematic one).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

from plm_highway.vehicle.single_track import (
    single_track_steady_state,
    single_track_tustin_map,
    understeer_gradient,
)

EFFECT_NAMES = ("transport_delay", "actuator_lag", "tire_slip", "steering_gain", "steering_offset")

# Parameter keys each effect reports (other tools read these names).
EFFECT_PARAM_KEYS = {
    "transport_delay": ("delay_s",),
    "actuator_lag": ("time_constant_s",),
    "tire_slip": ("understeer_gradient_rad_per_mps2", "cornering_stiffness_front", "cornering_stiffness_rear"),
    "steering_gain": ("gain",),
    "steering_offset": ("offset_rad",),
}

# Free parameters each effect adds to the fit (its complexity).
EFFECT_DOF = {"transport_delay": 1, "actuator_lag": 1, "tire_slip": 2, "steering_gain": 1, "steering_offset": 1}

EFFECT_FINGERPRINTS = {
    "transport_delay": "phase lag growing linearly with steering frequency, gain 1, independent of speed",
    "actuator_lag": "gain rolling off above 1/(2 pi tau), phase lag at most 90 deg",
    "tire_slip": "yaw gain u/(L + K u^2) falling with speed and lateral acceleration, speed-dependent lag",
    "steering_gain": "constant ratio between observed and expected yaw rate",
    "steering_offset": "constant yaw-rate error proportional to speed",
}

# Below this speed the tire model's axle slip angles divide by ~0; hold it there.
TIRE_MIN_SPEED_MPS = 0.5


@dataclass(frozen=True)
class EffectParams:
    """The simulator's model plus every effect; the defaults are the plain simulator.

    ``cf_per_kg``/``cr_per_kg`` are axle cornering stiffness per unit vehicle mass [N/rad/kg]; None
    means no tire slip (the kinematic bicycle).
    """

    delay_s: float = 0.0
    time_constant_s: float = 0.0
    gain: float = 1.0
    offset_rad: float = 0.0
    cf_per_kg: float | None = None
    cr_per_kg: float | None = None

    @property
    def has_tire_slip(self) -> bool:
        return self.cf_per_kg is not None

    def numba_args(self) -> tuple[float, float, float, float, float, float]:
        cf = 0.0 if self.cf_per_kg is None else float(self.cf_per_kg)
        cr = 0.0 if self.cr_per_kg is None else float(self.cr_per_kg)
        return float(self.delay_s), float(self.time_constant_s), float(self.gain), float(self.offset_rad), cf, cr


def effect_report(name: str, params: EffectParams, a_m: float, b_m: float, mass_kg: float | None,
                  inertia_known: bool) -> dict[str, float]:
    """An effect's parameters under their fixed public names."""
    if name == "transport_delay":
        return {"delay_s": params.delay_s}
    if name == "actuator_lag":
        return {"time_constant_s": params.time_constant_s}
    if name == "steering_gain":
        return {"gain": params.gain}
    if name == "steering_offset":
        return {"offset_rad": params.offset_rad}
    if name == "tire_slip":
        out = {"understeer_gradient_rad_per_mps2": understeer_gradient(params.cf_per_kg, params.cr_per_kg, a_m, b_m)}
        if inertia_known and mass_kg is not None:
            out["cornering_stiffness_front"] = params.cf_per_kg * mass_kg
            out["cornering_stiffness_rear"] = params.cr_per_kg * mass_kg
        return out
    raise KeyError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")


# ----------------------------------------------------------------------------------------------
# Kernels (numba). Arrays are per sample of the recording, uniformly spaced by dt.


@numba.njit(cache=True)
def _delayed(steer, delay_samples, out):
    """``steer`` delayed by a fractional number of samples (Catmull-Rom, C1 in the delay)."""
    n = steer.shape[0]
    for k in range(n):
        s = k - delay_samples
        if s <= 0.0:
            out[k] = steer[0]
            continue
        i = math.floor(s)
        f = s - i
        p0 = steer[max(i - 1, 0)]
        p1 = steer[i]
        p2 = steer[min(i + 1, n - 1)]
        p3 = steer[min(i + 2, n - 1)]
        out[k] = p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0)))


@numba.njit(cache=True)
def _lagged(u, dt, tau, out):
    """First-order actuator, exact for inputs linear between samples; starts settled."""
    n = u.shape[0]
    if tau < 1e-9:
        for k in range(n):
            out[k] = u[k]
        return
    alpha = math.exp(-dt / tau)
    c = tau / dt * (1.0 - alpha)
    out[0] = u[0]
    for k in range(1, n):
        out[k] = alpha * out[k - 1] + (1.0 - c) * u[k] + (c - alpha) * u[k - 1]


@numba.njit(cache=True)
def _kinematic_response(delta, speed, a_m, b_m, r_out, slip_out, drdd_out, with_slip):
    """Yaw rate, slip and d(yaw rate)/d(delta) of the kinematic bicycle (the simulator).

    ``r = v sin(beta) / lr`` with ``tan(beta) = lr/L tan(delta)``, written with one tangent and
    one square root (sin and cos of an arctangent are algebraic); the slip itself only on demand.
    """
    ratio = b_m / (a_m + b_m)
    for k in range(delta.shape[0]):
        t = math.tan(delta[k])
        ct = ratio * t
        inv_norm = 1.0 / math.sqrt(1.0 + ct * ct)  # cos(beta)
        r_out[k] = speed[k] * ct * inv_norm / b_m
        if with_slip:
            slip_out[k] = math.atan(ct)
        drdd_out[k] = speed[k] * inv_norm * ratio * (1.0 + t * t) * inv_norm * inv_norm / b_m


@numba.njit(cache=True)
def tire_maps(speed, dt, cf, cr, a_m, b_m, k2):
    """Per-sample affine maps of the tire model (see ``single_track_tustin_map``) and the settled
    start per unit steering: (maps [n-1, 8], start [2])."""
    n = speed.shape[0]
    maps = np.empty((n - 1, 8))
    for k in range(n - 1):
        m = single_track_tustin_map(speed[k], speed[k + 1], dt, cf, cr, a_m, b_m, k2, TIRE_MIN_SPEED_MPS)
        for j in range(8):
            maps[k, j] = m[j]
    start = np.empty(2)
    start[0], start[1] = single_track_steady_state(max(speed[0], TIRE_MIN_SPEED_MPS), 1.0, cf, cr, a_m, b_m, k2)
    return maps, start


@numba.njit(cache=True)
def _run_tire_maps(maps, start, delta, speed, r_out, slip_out, with_slip):
    """Yaw rate (and slip) of the tire model driven by ``delta`` through precomputed maps."""
    n = delta.shape[0]
    vy = start[0] * delta[0]
    r = start[1] * delta[0]
    r_out[0] = r
    if with_slip:
        slip_out[0] = math.atan2(vy, max(speed[0], TIRE_MIN_SPEED_MPS))
    for k in range(n - 1):
        m = maps[k]
        vy, r = (m[0] * vy + m[1] * r + m[4] * delta[k] + m[6] * delta[k + 1],
                 m[2] * vy + m[3] * r + m[5] * delta[k] + m[7] * delta[k + 1])
        r_out[k + 1] = r
        if with_slip:
            slip_out[k + 1] = math.atan2(vy, max(speed[k + 1], TIRE_MIN_SPEED_MPS))


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def simulate_yaw_rate(steer, speed, dt, delay_s, tau_s, gain, offset_rad, cf, cr, a_m, b_m, k2, with_slip=True):
    """Yaw rate [rad/s] and slip angle [rad] at each sample for one parameter set (cf = 0: kinematic).

    Without ``with_slip`` the slip array is left uninitialised (fits only need the yaw rate).
    """
    n = steer.shape[0]
    calibrated = gain * steer + offset_rad
    delayed = np.empty(n)
    _delayed(calibrated, delay_s / dt, delayed)
    delta = np.empty(n)
    _lagged(delayed, dt, tau_s, delta)
    r = np.empty(n)
    slip = np.empty(n)
    if cf > 0.0:
        maps, start = tire_maps(speed, dt, cf, cr, a_m, b_m, k2)
        _run_tire_maps(maps, start, delta, speed, r, slip, with_slip)
    else:
        drdd = np.empty(n)
        _kinematic_response(delta, speed, a_m, b_m, r, slip, drdd, with_slip)
    return r, slip


@numba.njit(cache=True, nogil=True)
def _tire_tables_into(speed, dt, cfs, crs, a_m, b_m, k2, taps, lo, first, last, maps_all, start_all, unit_all):
    """Rows ``first:last`` of the tire tables (see :func:`tire_tables`); releases the GIL."""
    n = speed.shape[0]
    ones = np.ones(n)
    for i in range(first, last):
        maps, start = tire_maps(speed, dt, cfs[i], crs[i], a_m, b_m, k2)
        maps_all[i] = maps
        start_all[i] = start
        r = np.empty(n)
        slip = np.empty(n)
        _run_tire_maps(maps, start, ones, speed, r, slip, False)
        out = np.empty(n)
        fir_filter(r, taps, lo, out)
        unit_all[i] = out


@numba.njit(cache=True, nogil=True)
def _candidate_statistics_into(steer, speed, dt, delays_s, taus_s, tire_index, maps_all, start_all, unit_all,
                               a_m, b_m, taps, lo, y, weight, first, last, stats):
    """Rows ``first:last`` of :func:`candidate_statistics`; releases the GIL."""
    n = steer.shape[0]
    for b in range(first, last):
        delayed = np.empty(n)
        _delayed(steer, delays_s[b] / dt, delayed)
        delta = np.empty(n)
        _lagged(delayed, dt, taus_s[b], delta)
        r = np.empty(n)
        slip = np.empty(n)
        pa = np.empty(n)
        pb = np.empty(n)
        ti = tire_index[b]
        if ti >= 0:
            _run_tire_maps(maps_all[ti], start_all[ti], delta, speed, r, slip, False)
        else:
            _kinematic_response(delta, speed, a_m, b_m, r, slip, pb, False)
            for k in range(n):
                pa[k] = delta[k] * pb[k]
        rf = np.empty(n)
        fir_filter(r, taps, lo, rf)
        if ti >= 0:
            paf = rf
            pbf = unit_all[ti]
        else:
            paf = np.empty(n)
            pbf = np.empty(n)
            fir_filter(pa, taps, lo, paf)
            fir_filter(pb, taps, lo, pbf)
        # One pass of the simulation serves every fold: a weight row per fold.
        for f in range(weight.shape[0]):
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            s3 = 0.0
            s4 = 0.0
            s5 = 0.0
            for k in range(n):
                w = weight[f, k]
                if w == 0.0:
                    continue
                e = y[k] - rf[k]
                s0 += w * e * e
                s1 += w * e * paf[k]
                s2 += w * e * pbf[k]
                s3 += w * paf[k] * paf[k]
                s4 += w * paf[k] * pbf[k]
                s5 += w * pbf[k] * pbf[k]
            stats[b, f, 0] = s0
            stats[b, f, 1] = s1
            stats[b, f, 2] = s2
            stats[b, f, 3] = s3
            stats[b, f, 4] = s4
            stats[b, f, 5] = s5


def _in_threads(fn, n_items: int, *args) -> None:
    """Run ``fn(*args, first, last, ...)`` over chunks of ``range(n_items)`` on all cores.

    The kernels release the GIL, so threads run them in parallel without numba's parallel
    compilation (which costs tens of seconds on a cold cache).
    """
    n_threads = max(1, min(os.cpu_count() or 1, n_items))
    bounds = np.linspace(0, n_items, n_threads + 1).astype(int)
    if n_threads == 1:
        fn(*args[0], 0, n_items, *args[1])
        return
    with ThreadPoolExecutor(n_threads) as pool:
        futures = [pool.submit(fn, *args[0], int(bounds[i]), int(bounds[i + 1]), *args[1]) for i in range(n_threads)]
        for f in futures:
            f.result()


def tire_tables(speed, dt, cfs, crs, a_m, b_m, k2, taps, lo):
    """Maps, settled starts and filtered unit-steering responses for a set of tire candidates."""
    n = speed.shape[0]
    n_tire = cfs.shape[0]
    maps_all = np.empty((n_tire, n - 1, 8))
    start_all = np.empty((n_tire, 2))
    unit_all = np.empty((n_tire, n))
    _in_threads(_tire_tables_into, n_tire, (speed, dt, cfs, crs, a_m, b_m, k2, taps, lo),
                (maps_all, start_all, unit_all))
    return maps_all, start_all, unit_all


def candidate_statistics(steer, speed, dt, delays_s, taus_s, tire_index, maps_all, start_all, unit_all,
                         a_m, b_m, taps, lo, y, weight):
    """For each candidate b and weight row f: sums [e.e, e.pa, e.pb, pa.pa, pa.pb, pb.pb] (shape B, F, 6).

    ``e`` is the measured signal minus the model's (gain 1, offset 0), ``pa`` and ``pb`` its
    sensitivities to the gain (minus one) and to the offset; all after the output filter ``taps``.
    The best gain/offset of a candidate then follow from a 2x2 solve. ``tire_index[b]`` < 0 means
    the kinematic bicycle, otherwise a row of the tables from :func:`tire_tables`. ``weight`` has a
    row per fold (train mask as 0/1), so one simulation serves all folds.
    """
    stats = np.zeros((delays_s.shape[0], weight.shape[0], 6))
    _in_threads(_candidate_statistics_into, delays_s.shape[0],
                (steer, speed, dt, delays_s, taus_s, tire_index, maps_all, start_all, unit_all, a_m, b_m, taps, lo,
                 y, weight), (stats,))
    return stats


def profiled_sse(stats: np.ndarray, gain_free: bool, offset_free: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares SSE of each candidate with the gain and/or offset solved; also (gain, offset)."""
    s0, s1, s2, s3, s4, s5 = (stats[:, i] for i in range(6))
    n = stats.shape[0]
    dgain = np.zeros(n)
    offset = np.zeros(n)
    tiny = 1e-300
    if gain_free and offset_free:
        det = s3 * s5 - s4 * s4
        ok = np.abs(det) > 1e-12 * np.maximum(s3 * s5, tiny)
        dgain = np.where(ok, (s5 * s1 - s4 * s2) / np.where(ok, det, 1.0), 0.0)
        offset = np.where(ok, (s3 * s2 - s4 * s1) / np.where(ok, det, 1.0), 0.0)
        sse = s0 - dgain * s1 - offset * s2
    elif gain_free:
        dgain = s1 / np.maximum(s3, tiny)
        sse = s0 - dgain * s1
    elif offset_free:
        offset = s2 / np.maximum(s5, tiny)
        sse = s0 - offset * s2
    else:
        sse = s0.copy()
    return np.maximum(sse, 0.0), 1.0 + dgain, offset
