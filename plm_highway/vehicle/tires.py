"""Dynamic single-track model with saturating tires and a lateral disturbance (road bank), as pure functions.

:mod:`plm_highway.vehicle.single_track` has linear tires: axle force ``C alpha`` without limit. Real
tires reach a friction peak. Here each axle force follows Pacejka's magic formula without the
curvature term,

    F = D sin(C atan(B alpha)),   D = mu Fz,   B = c / (C D),

so that the slope at zero slip is the linear model's cornering stiffness ``c``, the force peaks at
``mu Fz`` (at ``B alpha = tan(pi / 2C)``) and falls to ``sin(C pi / 2) mu Fz`` beyond. The shape
factor is fixed at ``C = 1.3``, the usual value for lateral force. The axle loads are static
(``Fz_front = m g b / L``, ``Fz_rear = m g a / L``; no load transfer in a single-track model).

A **road bank** (cross slope) adds the lateral component of gravity, ``a_bank = g sin(bank)``
[m/s^2], to the lateral-velocity equation; positive pulls the car to the left. A kinematic
bicycle cannot feel it (its wheels cannot slip sideways); here the car crabs downhill with a side
slip set by the tires.

Everything is written per unit mass, as in :mod:`plm_highway.vehicle.single_track` (``cf_per_kg``,
``cr_per_kg``, ``k2_m2 = Iz / m``); ``mu = inf`` gives linear tires with the exact slip geometry
(the same right-hand side as ``single_track_derivatives``).

Two integrators: :func:`saturating_single_track_rk4_step` for synthesising data on a fine grid, and
:func:`saturating_single_track_replay` for replays at a recording's sample rate (small-angle slip geometry, as the linear replay of
:mod:`plm_highway.vehicle.single_track`; linearly implicit trapezoidal rule, a one-stage Rosenbrock method with gamma = 1/2: exact trapezoidal rule for the
linear model, A-stable; stiff intervals at low speed are sub-stepped).
"""

from __future__ import annotations

import math

import numba
import numpy as np

GRAVITY_MPS2 = 9.81
MAGIC_FORMULA_SHAPE = 1.3


@numba.njit(cache=True, nogil=True)
def axle_force(alpha_rad, stiffness_per_kg, peak_per_kg):
    """Lateral axle force per unit vehicle mass and its slope d F / d alpha (magic formula).

    ``peak_per_kg = inf`` gives the linear tire ``c alpha``.
    """
    if not math.isfinite(peak_per_kg):
        return stiffness_per_kg * alpha_rad, stiffness_per_kg
    b_factor = stiffness_per_kg / (MAGIC_FORMULA_SHAPE * peak_per_kg)
    x = b_factor * alpha_rad
    angle = MAGIC_FORMULA_SHAPE * math.atan(x)
    force = peak_per_kg * math.sin(angle)
    slope = peak_per_kg * MAGIC_FORMULA_SHAPE * math.cos(angle) * b_factor / (1.0 + x * x)
    return force, slope


@numba.njit(cache=True, nogil=True)
def axle_peaks_per_kg(mu, a_m, b_m):
    """Peak lateral force per unit vehicle mass of the front and rear axle (static loads)."""
    wheelbase = a_m + b_m
    return mu * GRAVITY_MPS2 * b_m / wheelbase, mu * GRAVITY_MPS2 * a_m / wheelbase


@numba.njit(cache=True, nogil=True)
def saturating_axle_forces(vy, r, u_mps, delta_rad, cf_per_kg, cr_per_kg, a_m, b_m, mu):
    """Front and rear axle forces per unit mass (magic formula, exact slip geometry)."""
    peak_f, peak_r = axle_peaks_per_kg(mu, a_m, b_m)
    fyf, _ = axle_force(delta_rad - math.atan2(vy + a_m * r, u_mps), cf_per_kg, peak_f)
    fyr, _ = axle_force(-math.atan2(vy - b_m * r, u_mps), cr_per_kg, peak_r)
    return fyf, fyr


@numba.njit(cache=True, nogil=True)
def saturating_single_track_derivatives(vy, r, u_mps, delta_rad, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, mu,
                                        bank_accel_mps2):
    """(vy', r') with magic-formula axle forces, exact slip geometry and a lateral disturbance."""
    fyf, fyr = saturating_axle_forces(vy, r, u_mps, delta_rad, cf_per_kg, cr_per_kg, a_m, b_m, mu)
    cos_delta = math.cos(delta_rad)
    vy_dot = fyf * cos_delta + fyr - u_mps * r + bank_accel_mps2
    r_dot = (a_m * fyf * cos_delta - b_m * fyr) / k2_m2
    return vy_dot, r_dot


@numba.njit(cache=True, nogil=True)
def _derivatives_and_jacobian(vy, r, u, delta, cf, cr, a, b, k2, mu, bank):
    """Right-hand side and its Jacobian in (vy, r) with small-angle slip geometry (for replays)."""
    peak_f, peak_r = axle_peaks_per_kg(mu, a, b)
    alpha_f = delta - (vy + a * r) / u
    alpha_r = -(vy - b * r) / u
    fyf, dff = axle_force(alpha_f, cf, peak_f)
    fyr, dfr = axle_force(alpha_r, cr, peak_r)
    f1 = fyf + fyr - u * r + bank
    f2 = (a * fyf - b * fyr) / k2
    inv_u = 1.0 / u
    j11 = -(dff + dfr) * inv_u
    j12 = (b * dfr - a * dff) * inv_u - u
    j21 = (b * dfr - a * dff) * inv_u / k2
    j22 = -(a * a * dff + b * b * dfr) * inv_u / k2
    return f1, f2, j11, j12, j21, j22


@numba.njit(cache=True, nogil=True)
def saturating_single_track_rk4_step(vy, r, u0_mps, u1_mps, delta0_rad, delta1_rad, dt_s, cf_per_kg, cr_per_kg,
                                     a_m, b_m, k2_m2, mu, bank_accel_mps2):
    """Classical RK4 over one small step, inputs interpolated linearly (for synthesis)."""
    u_h = 0.5 * (u0_mps + u1_mps)
    d_h = 0.5 * (delta0_rad + delta1_rad)
    k1v, k1r = saturating_single_track_derivatives(vy, r, u0_mps, delta0_rad, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2,
                                                   mu, bank_accel_mps2)
    k2v, k2r = saturating_single_track_derivatives(vy + 0.5 * dt_s * k1v, r + 0.5 * dt_s * k1r, u_h, d_h, cf_per_kg,
                                                   cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2)
    k3v, k3r = saturating_single_track_derivatives(vy + 0.5 * dt_s * k2v, r + 0.5 * dt_s * k2r, u_h, d_h, cf_per_kg,
                                                   cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2)
    k4v, k4r = saturating_single_track_derivatives(vy + dt_s * k3v, r + dt_s * k3r, u1_mps, delta1_rad, cf_per_kg,
                                                   cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2)
    return (vy + dt_s / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v),
            r + dt_s / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r))


@numba.njit(cache=True, nogil=True)
def saturating_single_track_settled(u_mps, delta_rad, cf, cr, a, b, k2, mu, bank):
    """(vy, r) of the steady state for constant inputs (Newton from rest); (0, 0) if there is none
    (beyond the friction limit, or at an oversteering car's critical speed)."""
    vy, r = 0.0, 0.0
    for _ in range(30):
        f1, f2, j11, j12, j21, j22 = _derivatives_and_jacobian(vy, r, u_mps, delta_rad, cf, cr, a, b, k2, mu, bank)
        det = j11 * j22 - j12 * j21
        if abs(det) < 1e-12:
            return 0.0, 0.0
        dvy = (j22 * f1 - j12 * f2) / det
        dr = (-j21 * f1 + j11 * f2) / det
        vy -= dvy
        r -= dr
        if abs(dvy) + abs(dr) < 1e-12 * (1.0 + abs(vy) + abs(r)):
            break
    if not (math.isfinite(vy) and math.isfinite(r)):
        return 0.0, 0.0
    return vy, r


@numba.njit(cache=True, nogil=True)
def saturating_single_track_replay(delta, speed, dt_s, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2,
                                   u_min_mps, r_out, vy_out):
    """Yaw rate and lateral velocity at each sample, from a settled start (see the module docstring).

    Speed and steering are interpolated linearly across each sample; the speed is held at
    ``u_min_mps`` or above (the slip angles divide by it).
    """
    n = delta.shape[0]
    u0 = max(speed[0], u_min_mps)
    vy, r = saturating_single_track_settled(u0, delta[0], cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2)
    r_out[0] = r
    vy_out[0] = vy
    for k in range(n - 1):
        ua = max(speed[k], u_min_mps)
        ub = max(speed[k + 1], u_min_mps)
        # The stiffest mode (|lambda| ~ (cf + cr) / u) sets the sub-step: h |lambda| <= 1.5.
        stiff = (cf_per_kg + cr_per_kg) / min(ua, ub) * (1.0 + max(a_m, b_m) ** 2 / k2_m2)
        n_sub = min(max(math.ceil(dt_s * stiff / 1.5), 1), 200)
        h = dt_s / n_sub
        for i in range(n_sub):
            f = (i + 0.5) / n_sub
            u = ua + (ub - ua) * f
            d = delta[k] + (delta[k + 1] - delta[k]) * f
            f1, f2, j11, j12, j21, j22 = _derivatives_and_jacobian(vy, r, u, d, cf_per_kg, cr_per_kg, a_m, b_m,
                                                                   k2_m2, mu, bank_accel_mps2)
            m11 = 1.0 - 0.5 * h * j11
            m12 = -0.5 * h * j12
            m21 = -0.5 * h * j21
            m22 = 1.0 - 0.5 * h * j22
            inv_det = 1.0 / (m11 * m22 - m12 * m21)
            vy += h * (m22 * f1 - m12 * f2) * inv_det
            r += h * (-m21 * f1 + m11 * f2) * inv_det
        r_out[k + 1] = r
        vy_out[k + 1] = vy


def saturating_single_track_rollout(delta: np.ndarray, speed: np.ndarray, dt_s: float, cf_per_kg: float,
                                    cr_per_kg: float, a_m: float, b_m: float, k2_m2: float, mu: float = math.inf,
                                    bank_accel_mps2: float = 0.0, u_min_mps: float = 0.5
                                    ) -> tuple[np.ndarray, np.ndarray]:
    """(yaw rate, lateral velocity) replay-style; convenience wrapper of the kernel."""
    delta = np.ascontiguousarray(delta, float)
    speed = np.ascontiguousarray(speed, float)
    r = np.empty_like(delta)
    vy = np.empty_like(delta)
    saturating_single_track_replay(delta, speed, float(dt_s), float(cf_per_kg), float(cr_per_kg), float(a_m),
                                   float(b_m), float(k2_m2), float(mu), float(bank_accel_mps2), float(u_min_mps),
                                   r, vy)
    return r, vy


@numba.njit(cache=True, nogil=True)
def saturating_single_track_pose_step(x_m, y_m, heading_rad, vy, r, u0_mps, u1_mps, delta0_rad, delta1_rad, dt_s,
                                      cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, mu, bank_accel_mps2, u_min_mps):
    """Pose and (vy, r) over one simulation step: RK4 sub-steps for (vy, r) (the inputs interpolated linearly),
    the pose by the midpoint rule within each sub-step. A sub-step is at most 10 ms, and short enough for the
    stiffest lateral mode (|lambda| ~ (cf + cr) / u): h |lambda| <= 1.5, inside RK4's stability limit of 2.78."""
    stiff = (cf_per_kg + cr_per_kg) / max(min(u0_mps, u1_mps), u_min_mps) * (1.0 + max(a_m, b_m) ** 2 / k2_m2)
    n_sub = min(max(math.ceil(dt_s / 0.01), math.ceil(dt_s * stiff / 1.5), 1), 1000)
    h = dt_s / n_sub
    for i in range(n_sub):
        f0 = i / n_sub
        f1 = (i + 1) / n_sub
        speed_a = u0_mps + (u1_mps - u0_mps) * f0
        speed_b = u0_mps + (u1_mps - u0_mps) * f1
        # The slip angles divide by the speed: the tire forces see at least u_min_mps, the pose the true speed.
        ua = max(speed_a, u_min_mps)
        ub = max(speed_b, u_min_mps)
        da = delta0_rad + (delta1_rad - delta0_rad) * f0
        db = delta0_rad + (delta1_rad - delta0_rad) * f1
        vy1, r1 = saturating_single_track_rk4_step(vy, r, ua, ub, da, db, h, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2,
                                                   mu, bank_accel_mps2)
        new_heading = heading_rad + 0.5 * h * (r + r1)
        mid_heading = 0.5 * (heading_rad + new_heading)
        mid_u = 0.5 * (speed_a + speed_b)
        mid_vy = 0.5 * (vy + vy1)
        c = math.cos(mid_heading)
        s = math.sin(mid_heading)
        x_m += h * (mid_u * c - mid_vy * s)
        y_m += h * (mid_u * s + mid_vy * c)
        heading_rad, vy, r = new_heading, vy1, r1
    return x_m, y_m, heading_rad, vy, r
