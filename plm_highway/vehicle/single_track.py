"""Dynamic single-track ("bicycle") model with linear tires, as pure functions.

This is the physics a kinematic bicycle leaves out: the tires need a slip angle to produce lateral
force, so the car turns less than the kinematic geometry says (understeer) and the yaw rate follows
the steering through a speed-dependent transient rather than instantly.

States (body frame, reference point at the centre of gravity): lateral velocity ``vy`` [m/s] and
yaw rate ``r`` [rad/s]; input: front-wheel angle ``delta`` [rad]; the longitudinal speed ``u`` [m/s]
is given (as in a replay, the speed is an input). Axle forces ``Fy = C * alpha`` with

    alpha_f = delta - (vy + a r) / u         alpha_r = -(vy - b r) / u
    m (vy' + u r) = Fyf + Fyr                 Iz r' = a Fyf - b Fyr

Only the ratios ``C / m`` and ``Iz / m`` enter, so the model is written per unit mass
(``cf_per_kg = Cf / m``, ``k2_m2 = Iz / m``); this lets a recording without mass or inertia still
be fitted (with ``Iz / m`` assumed ``a * b``, the usual radius-of-gyration rule).
The steady state is ``r = u delta / (L + K u^2)`` with the understeer gradient
``K = (b / cf - a / cr) / L`` [rad / (m/s^2)].

Two integrators: :func:`single_track_rk4_step` for synthesising "real" data finely, and
:func:`single_track_tustin_step` for replays at the recording's sample rate (A-stable, so the fast
tire modes at low speed do not blow up; stiff intervals are sub-stepped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class SingleTrackParams:
    """A car for the dynamic single-track model; stiffnesses are per axle [N/rad]."""

    cg_to_front_m: float
    cg_to_rear_m: float
    mass_kg: float
    yaw_inertia_kgm2: float
    cornering_stiffness_front: float
    cornering_stiffness_rear: float

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m

    @property
    def understeer_gradient_rad_per_mps2(self) -> float:
        return understeer_gradient(
            self.cornering_stiffness_front / self.mass_kg,
            self.cornering_stiffness_rear / self.mass_kg,
            self.cg_to_front_m,
            self.cg_to_rear_m,
        )


# The seed paper's test car (Sensors 2025, 25, 6251, Table 2): a medium-sized sedan.
SEED_PAPER_VEHICLE = SingleTrackParams(
    cg_to_front_m=1.35,
    cg_to_rear_m=1.45,
    mass_kg=1850.0,
    yaw_inertia_kgm2=2800.0,
    cornering_stiffness_front=86_000.0,
    cornering_stiffness_rear=92_000.0,
)


def understeer_gradient(cf_per_kg: float, cr_per_kg: float, a_m: float, b_m: float) -> float:
    """K [rad/(m/s^2)]: extra steering per unit lateral acceleration beyond the kinematic angle."""
    return (b_m / cf_per_kg - a_m / cr_per_kg) / (a_m + b_m)


def front_stiffness_for_understeer(
    understeer_rad_per_mps2: float, cr_per_kg: float, a_m: float, b_m: float
) -> float:
    """The front ``Cf / m`` giving understeer gradient ``K`` with rear ``Cr / m`` fixed."""
    denominator = understeer_rad_per_mps2 * (a_m + b_m) + a_m / cr_per_kg
    if denominator <= 0:
        raise ValueError(f"understeer gradient {understeer_rad_per_mps2} is out of reach with Cr/m={cr_per_kg}")
    return b_m / denominator


@numba.njit(cache=True)
def single_track_matrices(u_mps, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2):
    """Continuous-time ``x' = A x + B delta`` for x = (vy, r) at longitudinal speed ``u``."""
    inv_u = 1.0 / u_mps
    inv_ku = inv_u / k2_m2
    a11 = -(cf_per_kg + cr_per_kg) * inv_u
    a12 = (b_m * cr_per_kg - a_m * cf_per_kg) * inv_u - u_mps
    a21 = (b_m * cr_per_kg - a_m * cf_per_kg) * inv_ku
    a22 = -(a_m * a_m * cf_per_kg + b_m * b_m * cr_per_kg) * inv_ku
    b1 = cf_per_kg
    b2 = a_m * cf_per_kg / k2_m2
    return a11, a12, a21, a22, b1, b2


@numba.njit(cache=True)
def single_track_steady_state(u_mps, delta_rad, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2):
    """(vy, r) in a steady turn; zero when the car is at its critical (oversteer) speed."""
    a11, a12, a21, a22, b1, b2 = single_track_matrices(u_mps, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    det = a11 * a22 - a12 * a21
    if abs(det) < 1e-12:
        return 0.0, 0.0
    # x = -A^-1 B delta
    vy = -(a22 * b1 - a12 * b2) / det * delta_rad
    r = -(-a21 * b1 + a11 * b2) / det * delta_rad
    return vy, r


@numba.njit(cache=True)
def _fastest_mode(a11, a12, a21, a22):
    """|lambda|max of a 2x2 matrix (the stiffness that limits the step)."""
    half_trace = 0.5 * (a11 + a22)
    det = a11 * a22 - a12 * a21
    disc = half_trace * half_trace - det
    if disc >= 0.0:
        return abs(half_trace) + math.sqrt(disc)
    return math.sqrt(max(det, 0.0))


@numba.njit(cache=True)
def _tustin_substep(h, p11, p12, p21, p22, pba1, pba2, q11, q12, q21, q22, pbb1, pbb2):
    """(I - h/2 A_b) x1 = (I + h/2 A_a) x0 + h/2 (B_a d_a + B_b d_b) as x1 = S x0 + Ga d_a + Gb d_b."""
    m11 = 1.0 - 0.5 * h * q11
    m12 = -0.5 * h * q12
    m21 = -0.5 * h * q21
    m22 = 1.0 - 0.5 * h * q22
    inv_det = 1.0 / (m11 * m22 - m12 * m21)
    i11, i12, i21, i22 = m22 * inv_det, -m12 * inv_det, -m21 * inv_det, m11 * inv_det
    n11 = 1.0 + 0.5 * h * p11
    n12 = 0.5 * h * p12
    n21 = 0.5 * h * p21
    n22 = 1.0 + 0.5 * h * p22
    s11 = i11 * n11 + i12 * n21
    s12 = i11 * n12 + i12 * n22
    s21 = i21 * n11 + i22 * n21
    s22 = i21 * n12 + i22 * n22
    ga1 = 0.5 * h * (i11 * pba1 + i12 * pba2)
    ga2 = 0.5 * h * (i21 * pba1 + i22 * pba2)
    gb1 = 0.5 * h * (i11 * pbb1 + i12 * pbb2)
    gb2 = 0.5 * h * (i21 * pbb1 + i22 * pbb2)
    return s11, s12, s21, s22, ga1, ga2, gb1, gb2


@numba.njit(cache=True)
def single_track_tustin_map(u0_mps, u1_mps, dt_s, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, u_min_mps):
    """One sample of the trapezoidal rule as an affine map: x1 = Phi x0 + Pa delta0 + Pb delta1.

    Steering and speed are interpolated linearly across the sample (first-order hold); intervals
    that are stiff against ``dt`` (low speed, very stiff tires) are sub-stepped so that
    dt * |lambda| <= 1.5: the trapezoidal rule is stable at any step but rings (amplification
    below zero) beyond 2; modes that fast have decayed within a step anyway. Returns (phi11, phi12, phi21, phi22, pa1, pa2,
    pb1, pb2).
    """
    ua = max(u0_mps, u_min_mps)
    ub = max(u1_mps, u_min_mps)
    p11, p12, p21, p22, pba1, pba2 = single_track_matrices(ua, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    q11, q12, q21, q22, pbb1, pbb2 = single_track_matrices(ub, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    # The stiffest end of the interval sets the sub-step (the modes scale like 1/u).
    if ua < ub:
        stiff = _fastest_mode(p11, p12, p21, p22)
    else:
        stiff = _fastest_mode(q11, q12, q21, q22)
    n_sub = min(max(math.ceil(dt_s * stiff / 1.5), 1), 200)
    if n_sub == 1:
        return _tustin_substep(dt_s, p11, p12, p21, p22, pba1, pba2, q11, q12, q21, q22, pbb1, pbb2)
    h = dt_s / n_sub
    f11, f12, f21, f22 = 1.0, 0.0, 0.0, 1.0
    pa1, pa2, pb1, pb2 = 0.0, 0.0, 0.0, 0.0
    for i in range(n_sub):
        f0 = i / n_sub
        f1 = (i + 1) / n_sub
        u_b = max(u0_mps + (u1_mps - u0_mps) * f1, u_min_mps)
        q11, q12, q21, q22, pbb1, pbb2 = single_track_matrices(u_b, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
        s11, s12, s21, s22, ga1, ga2, gb1, gb2 = _tustin_substep(h, p11, p12, p21, p22, pba1, pba2,
                                                                 q11, q12, q21, q22, pbb1, pbb2)
        # Compose: the sub-step's inputs are (1 - f) delta0 + f delta1.
        f11, f12, f21, f22 = s11 * f11 + s12 * f21, s11 * f12 + s12 * f22, s21 * f11 + s22 * f21, s21 * f12 + s22 * f22
        pa1, pa2 = (s11 * pa1 + s12 * pa2 + ga1 * (1.0 - f0) + gb1 * (1.0 - f1),
                    s21 * pa1 + s22 * pa2 + ga2 * (1.0 - f0) + gb2 * (1.0 - f1))
        pb1, pb2 = s11 * pb1 + s12 * pb2 + ga1 * f0 + gb1 * f1, s21 * pb1 + s22 * pb2 + ga2 * f0 + gb2 * f1
        p11, p12, p21, p22, pba1, pba2 = q11, q12, q21, q22, pbb1, pbb2
    return f11, f12, f21, f22, pa1, pa2, pb1, pb2


@numba.njit(cache=True)
def single_track_tustin_step(vy, r, u0_mps, u1_mps, delta0_rad, delta1_rad, dt_s,
                             cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, u_min_mps):
    """Advance (vy, r) over one sample with the trapezoidal rule (see :func:`single_track_tustin_map`)."""
    f11, f12, f21, f22, pa1, pa2, pb1, pb2 = single_track_tustin_map(u0_mps, u1_mps, dt_s, cf_per_kg, cr_per_kg,
                                                                     a_m, b_m, k2_m2, u_min_mps)
    return (f11 * vy + f12 * r + pa1 * delta0_rad + pb1 * delta1_rad,
            f21 * vy + f22 * r + pa2 * delta0_rad + pb2 * delta1_rad)


@numba.njit(cache=True)
def single_track_derivatives(vy, r, u_mps, delta_rad, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2):
    """Right-hand side with the exact slip-angle geometry (atan, cos delta): used to make "real" data."""
    alpha_f = delta_rad - math.atan2(vy + a_m * r, u_mps)
    alpha_r = -math.atan2(vy - b_m * r, u_mps)
    fyf = cf_per_kg * alpha_f  # per unit mass
    fyr = cr_per_kg * alpha_r
    vy_dot = fyf * math.cos(delta_rad) + fyr - u_mps * r
    r_dot = (a_m * fyf * math.cos(delta_rad) - b_m * fyr) / k2_m2
    return vy_dot, r_dot


@numba.njit(cache=True)
def single_track_rk4_step(vy, r, u0_mps, u1_mps, delta0_rad, delta1_rad, dt_s,
                          cf_per_kg, cr_per_kg, a_m, b_m, k2_m2):
    """Classical RK4 over one (small) step with inputs interpolated linearly."""
    u_h = 0.5 * (u0_mps + u1_mps)
    d_h = 0.5 * (delta0_rad + delta1_rad)
    k1v, k1r = single_track_derivatives(vy, r, u0_mps, delta0_rad, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    k2v, k2r = single_track_derivatives(vy + 0.5 * dt_s * k1v, r + 0.5 * dt_s * k1r, u_h, d_h,
                                        cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    k3v, k3r = single_track_derivatives(vy + 0.5 * dt_s * k2v, r + 0.5 * dt_s * k2r, u_h, d_h,
                                        cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    k4v, k4r = single_track_derivatives(vy + dt_s * k3v, r + dt_s * k3r, u1_mps, delta1_rad,
                                        cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    vy = vy + dt_s / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    r = r + dt_s / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r)
    return vy, r


@numba.njit(cache=True)
def single_track_rollout(steer_rad, speed_mps, dt_s, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2):
    """(vy, r) at each sample, replay-style (trapezoidal rule), starting from the steady state."""
    n = steer_rad.shape[0]
    vy_out = np.empty(n)
    r_out = np.empty(n)
    vy, r = single_track_steady_state(max(speed_mps[0], 0.5), steer_rad[0], cf_per_kg, cr_per_kg, a_m, b_m, k2_m2)
    vy_out[0] = vy
    r_out[0] = r
    for k in range(n - 1):
        vy, r = single_track_tustin_step(vy, r, speed_mps[k], speed_mps[k + 1], steer_rad[k], steer_rad[k + 1],
                                         dt_s, cf_per_kg, cr_per_kg, a_m, b_m, k2_m2, 0.5)
        vy_out[k + 1] = vy
        r_out[k + 1] = r
    return vy_out, r_out


def params_per_kg(params: SingleTrackParams) -> tuple[float, float, float]:
    """(Cf/m, Cr/m, Iz/m) of a car."""
    return (
        params.cornering_stiffness_front / params.mass_kg,
        params.cornering_stiffness_rear / params.mass_kg,
        params.yaw_inertia_kgm2 / params.mass_kg,
    )
