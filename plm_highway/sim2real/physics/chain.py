"""The model chain: the simulator's kinematic bicycle plus every physical term the effect library can add.

The simulator (highway-env's kinematic bicycle) turns the commanded front-wheel angle into a yaw
rate instantly: ``r = v sin(beta) / lr`` with ``beta = atan(lr / L tan(delta))``. The chain inserts
the terms a real car adds, in a fixed order,

    command -> calibration (gain, offset) -> steering map (speed-dependent ratio, left/right asymmetry,
            dead band, backlash, end stops) -> transport delay (optionally jittering) -> servo
            (first-order lag, rate limit) -> vehicle (kinematic | linear tires | saturating tires; road
            bank) -> sensors (a late or biased gyro: applied per recorded channel, see ``replay``)

with its parameters named by the registry: each entry of :mod:`.effects` and :mod:`.terms` declares
the fields it sets, and the records are built from those declarations (``effects.EffectParams``,
``None`` tires: the kinematic bicycle; for the numba kernels ``effects.ChainParams``, plain floats
under the same names). The kernels here read the fields by name. All parameters at their neutral
values give the simulator's model exactly. The kernels release the GIL, so a grid of parameter sets
runs on all cores in threads (:mod:`.grid`).

The steering map acts on the calibrated command before the delay: the gain changes by
``speed_gain_slope`` per m/s away from ``speed_ref_mps``, left commands are ``1 + asymmetry`` and
right ones ``1 - asymmetry`` times as effective, ``dead_band_rad`` either side of the centre does
nothing, ``play_rad`` is the total free play (backlash) the command crosses on reversing, and
``saturation_rad`` is where the wheels stop. ``cf_per_kg``/``cr_per_kg``: axle cornering stiffness
per unit mass [N/rad/kg] (0: no tires); ``friction_coefficient`` inf: linear tires. ``jitter_s`` is
the standard deviation of a jittering delay: the expected response is the delayed command smoothed
by a Gaussian of that width. The sensor delay and ``gyro_bias_radps`` act on the recorded gyro
only (:func:`gyro_channel`, :func:`gyro_view`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from plm_highway.sim2real.physics.filters import fir_filter
from plm_highway.vehicle.single_track import single_track_steady_state, single_track_tustin_map
from plm_highway.vehicle.tires import saturating_single_track_replay

# Default speed below which the tire models hold the speed (their slip angles divide by it); a
# recording's own floor comes from its speed distribution and wheelbase (recording.speed_floor_mps).
TIRE_MIN_SPEED_MPS = 0.5


class Drive(NamedTuple):
    """What the car was asked to do: the recorded command [rad] and speed [m/s] on a uniform grid."""

    steer: np.ndarray
    speed: np.ndarray
    dt_s: float


class CarParams(NamedTuple):
    """The car as the chain needs it: axle distances, yaw inertia per unit mass, tire speed floor."""

    a_m: float
    b_m: float
    k2_m2: float
    u_min_mps: float = TIRE_MIN_SPEED_MPS


class TireTable(NamedTuple):
    """Precomputed for one linear tire: per-sample affine maps [n-1, 8], the settled start per unit
    steering [2], and the yaw rate and lateral velocity under a unit lateral acceleration [n] (for a
    bank). Empty arrays: the chain computes what it needs itself."""

    maps: np.ndarray
    start: np.ndarray
    bank_r: np.ndarray
    bank_vy: np.ndarray


class ChainOutputs(NamedTuple):
    """Per-sample outputs the chain writes: yaw rate [rad/s], lateral velocity [m/s], slip angle [rad]."""

    r: np.ndarray
    vy: np.ndarray
    slip: np.ndarray


# ----------------------------------------------------------------------------------------------
# Kernels (numba). Arrays are per sample of the recording, uniformly spaced by dt.


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def _jittered(steer, delay_samples, jitter_samples, out):
    """The expected command under a delay jittering with std ``jitter_samples`` around
    ``delay_samples``: the delayed command smoothed by a Gaussian (3 standard deviations)."""
    if jitter_samples < 0.05:
        _delayed(steer, delay_samples, out)
        return
    n = steer.shape[0]
    half = int(math.ceil(3.0 * jitter_samples))
    weights = np.empty(2 * half + 1)
    for m in range(-half, half + 1):
        weights[m + half] = math.exp(-0.5 * (m / jitter_samples) ** 2)
    weights /= weights.sum()
    shifted = np.empty(n)
    for k in range(n):
        out[k] = 0.0
    for m in range(-half, half + 1):
        _delayed(steer, max(delay_samples + m, 0.0), shifted)
        w = weights[m + half]
        for k in range(n):
            out[k] += w * shifted[k]


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def _servo(u, dt, tau, max_rate, out):
    """The steering servo: first-order lag (time constant ``tau``) whose output moves at most
    ``max_rate`` [rad/s]; without a finite rate it is :func:`_lagged` exactly."""
    if not math.isfinite(max_rate):
        _lagged(u, dt, tau, out)
        return
    n = u.shape[0]
    step = max_rate * dt
    out[0] = u[0]
    if tau < 1e-9:
        for k in range(1, n):
            out[k] = out[k - 1] + min(max(u[k] - out[k - 1], -step), step)
        return
    alpha = math.exp(-dt / tau)
    c = tau / dt * (1.0 - alpha)
    for k in range(1, n):
        target = alpha * out[k - 1] + (1.0 - c) * u[k] + (c - alpha) * u[k - 1]
        out[k] = out[k - 1] + min(max(target - out[k - 1], -step), step)


@numba.njit(cache=True, nogil=True)
def _maps_steering(p):
    """Does ``p`` have a steering map (any term away from neutral)?"""
    return (p.speed_gain_slope != 0.0 or p.asymmetry != 0.0 or p.dead_band_rad > 0.0 or p.play_rad > 0.0
            or math.isfinite(p.saturation_rad))


@numba.njit(cache=True, nogil=True)
def steering_map(u, speed, p, out):
    """The steering map of ``p`` applied to the calibrated command ``u`` (see the module's text):
    speed-dependent ratio, asymmetry, dead band, backlash (a play operator, starting centred on the
    first command), then the end stops."""
    half_play = 0.5 * p.play_rad
    held = u[0]
    for k in range(u.shape[0]):
        x = u[k]
        if p.speed_gain_slope != 0.0:
            x *= 1.0 + p.speed_gain_slope * (speed[k] - p.speed_ref_mps)
        if p.asymmetry != 0.0:
            x += p.asymmetry * abs(x)
        if p.dead_band_rad > 0.0:
            x -= min(max(x, -p.dead_band_rad), p.dead_band_rad)
        if half_play > 0.0:
            if k == 0:
                held = x
            held = min(max(held, x - half_play), x + half_play)
            x = held
        out[k] = min(max(x, -p.saturation_rad), p.saturation_rad)


@numba.njit(cache=True, nogil=True)
def _kinematic(delta, speed, a_m, b_m, r_out, vy_out, slip_out, need):
    """Yaw rate, lateral velocity and (``need`` >= 2) slip of the kinematic bicycle (the simulator).

    ``r = v sin(beta) / lr`` with ``tan(beta) = lr/L tan(delta)``, written with one tangent and
    one square root (sin and cos of an arctangent are algebraic).
    """
    ratio = b_m / (a_m + b_m)
    for k in range(delta.shape[0]):
        ct = ratio * math.tan(delta[k])
        sin_beta = ct / math.sqrt(1.0 + ct * ct)
        r_out[k] = speed[k] * sin_beta / b_m
        vy_out[k] = speed[k] * sin_beta
        if need >= 2:
            slip_out[k] = math.atan(ct)


@numba.njit(cache=True, nogil=True)
def tire_maps(speed, dt, cf, cr, a_m, b_m, k2, u_min=TIRE_MIN_SPEED_MPS):
    """Per-sample affine maps of the linear tire model (see ``single_track_tustin_map``) and the
    settled start per unit steering: (maps [n-1, 8], start [2])."""
    n = speed.shape[0]
    maps = np.empty((n - 1, 8))
    for k in range(n - 1):
        m = single_track_tustin_map(speed[k], speed[k + 1], dt, cf, cr, a_m, b_m, k2, u_min)
        for j in range(8):
            maps[k, j] = m[j]
    start = np.empty(2)
    start[0], start[1] = single_track_steady_state(max(speed[0], u_min), 1.0, cf, cr, a_m, b_m, k2)
    return maps, start


@numba.njit(cache=True, nogil=True)
def _run_tire_maps(maps, start, delta, speed, u_min, r_out, vy_out, slip_out, need):
    """Yaw rate, lateral velocity and (``need`` >= 2) slip of the linear tire model driven by ``delta``."""
    n = delta.shape[0]
    vy = start[0] * delta[0]
    r = start[1] * delta[0]
    r_out[0] = r
    vy_out[0] = vy
    for k in range(n - 1):
        m = maps[k]
        vy, r = (m[0] * vy + m[1] * r + m[4] * delta[k] + m[6] * delta[k + 1],
                 m[2] * vy + m[3] * r + m[5] * delta[k] + m[7] * delta[k + 1])
        r_out[k + 1] = r
        vy_out[k + 1] = vy
    if need >= 2:
        for k in range(n):
            slip_out[k] = math.atan2(vy_out[k], max(speed[k], u_min))


@numba.njit(cache=True, nogil=True)
def unit_bank_response(speed, dt, cf, cr, a_m, b_m, k2, u_min, r_out, vy_out):
    """Yaw rate and lateral velocity of the linear tire model under a unit lateral acceleration."""
    zero = np.zeros(speed.shape[0])
    saturating_single_track_replay(zero, speed, dt, cf, cr, a_m, b_m, k2, math.inf, 1.0, u_min, r_out, vy_out)


@numba.njit(cache=True, nogil=True)
def simulate_chain(drive, p, car, tire, out, need=2):
    """The simulator's model plus the effects in ``p`` (:class:`ChainParams`) driven by ``drive``
    (:class:`Drive`) on ``car`` (:class:`CarParams`): writes yaw rate, lateral velocity and
    (``need`` >= 2; fits skip it) slip into ``out`` (:class:`ChainOutputs`).

    ``tire`` (:class:`TireTable`) may hold the linear tire's maps and unit-bank response
    precomputed for ``p``'s tires; empty arrays make the chain compute them. The sensor delay is not
    applied here (it acts on one recorded channel only, see ``replay.FitSignal``).
    """
    steer, speed, dt = drive.steer, drive.speed, drive.dt_s
    a_m, b_m, k2, u_min = car.a_m, car.b_m, car.k2_m2, car.u_min_mps
    r, vy, slip = out.r, out.vy, out.slip
    n = steer.shape[0]
    calibrated = p.gain * steer + p.offset_rad
    if _maps_steering(p):
        mapped = np.empty(n)
        steering_map(calibrated, speed, p, mapped)
        calibrated = mapped
    delayed = np.empty(n)
    _jittered(calibrated, p.delay_s / dt, p.jitter_s / dt, delayed)
    delta = np.empty(n)
    _servo(delayed, dt, p.time_constant_s, p.max_rate_radps, delta)
    if p.cf_per_kg <= 0.0:
        _kinematic(delta, speed, a_m, b_m, r, vy, slip, need)
        return
    if math.isfinite(p.friction_coefficient):
        saturating_single_track_replay(delta, speed, dt, p.cf_per_kg, p.cr_per_kg, a_m, b_m, k2,
                                       p.friction_coefficient, p.bank_accel_mps2, u_min, r, vy)
    else:
        maps, start = tire.maps, tire.start
        if maps.shape[0] != n - 1:
            maps, start = tire_maps(speed, dt, p.cf_per_kg, p.cr_per_kg, a_m, b_m, k2, u_min)
        _run_tire_maps(maps, start, delta, speed, u_min, r, vy, slip, 0)
        if p.bank_accel_mps2 != 0.0:
            bank_r, bank_vy = tire.bank_r, tire.bank_vy
            if bank_r.shape[0] != n:
                bank_r = np.empty(n)
                bank_vy = np.empty(n)
                unit_bank_response(speed, dt, p.cf_per_kg, p.cr_per_kg, a_m, b_m, k2, u_min, bank_r, bank_vy)
            for k in range(n):
                r[k] += p.bank_accel_mps2 * bank_r[k]
                vy[k] += p.bank_accel_mps2 * bank_vy[k]
    if need >= 2:
        for k in range(n):
            slip[k] = math.atan2(vy[k], max(speed[k], u_min))


NO_TIRE_TABLE = TireTable(np.zeros((0, 8)), np.zeros(0), np.zeros(0), np.zeros(0))


def simulate(steer: np.ndarray, speed: np.ndarray, dt: float, params, a_m: float, b_m: float,
             k2: float, u_min: float = TIRE_MIN_SPEED_MPS, with_slip: bool = True
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw rate [rad/s], lateral velocity [m/s], slip angle [rad]) at each sample for one parameter
    set (an ``effects.EffectParams``; the slip left unset without ``with_slip``)."""
    steer = np.ascontiguousarray(steer, float)
    speed = np.ascontiguousarray(speed, float)
    n = steer.shape[0]
    out = ChainOutputs(np.empty(n), np.empty(n), np.empty(n))
    simulate_chain(Drive(steer, speed, float(dt)), params.chain(), CarParams(float(a_m), float(b_m), float(k2),
                                                                             float(u_min)),
                   NO_TIRE_TABLE, out, 2 if with_slip else 1)
    return out.r, out.vy, out.slip


def calibrated(params, steer: np.ndarray) -> np.ndarray:
    """The command after the calibration (gain, offset), as :func:`simulate_chain` computes it."""
    return params.gain * steer + params.offset_rad


def command_change(params, wheel_change_rad: float) -> float:
    """The command change that moves the calibrated angle by ``wheel_change_rad``."""
    return wheel_change_rad / params.gain


# ----------------------------------------------------------------------------------------------
# The recorded gyro: a sensor delay and a bias act on that channel only, after the chain.


@numba.njit(cache=True, nogil=True)
def gyro_channel(r, dt, p, taps, lo, out):
    """A model's yaw rate as a recorded rotation channel sees it: late by ``p``'s sensor delay,
    filtered (``taps`` from offset ``lo``), plus its gyro bias (a caller gives neutral values for
    the channels other than the gyro)."""
    if p.sensor_delay_s > 0.0:
        late = np.empty(r.shape[0])
        _delayed(r, p.sensor_delay_s / dt, late)
        fir_filter(late, taps, lo, out)
    else:
        fir_filter(r, taps, lo, out)
    if p.gyro_bias_radps != 0.0:
        for k in range(out.shape[0]):
            out[k] += p.gyro_bias_radps


def gyro_view(r: np.ndarray, dt: float, params) -> tuple[np.ndarray, float]:
    """The model's yaw rate as the gyro reads it before its filter (late by the sensor delay), and
    the bias the gyro adds after it."""
    if params.sensor_delay_s > 0:
        late = np.empty(len(r))
        _delayed(np.ascontiguousarray(r, float), params.sensor_delay_s / dt, late)
        r = late
    return r, params.gyro_bias_radps


def linear_tire_points(points: np.ndarray, moved_fields: list[str]) -> tuple[np.ndarray, np.ndarray, bool]:
    """Which points of a grid (a structured array of chain parameters) have linear tires, their
    (front, rear) stiffness [N/rad/kg] (K, 2), and whether any point, or a linear move along
    ``moved_fields``, needs the tires' response to a bank (their tables are then computed with it)."""
    mask = (points["cf_per_kg"] > 0) & ~np.isfinite(points["friction_coefficient"])
    stiffness = np.column_stack([points["cf_per_kg"], points["cr_per_kg"]])[mask]
    with_bank = bool(np.any(points["bank_accel_mps2"] != 0) or "bank_accel_mps2" in moved_fields)
    return mask, stiffness, with_bank
