"""The paper's lane-coordinate vehicle model (Kim, Kang, Ahn, Sensors 2025, 25, 6251, Eqs. (9), (23), (24)).

State ``X = [d, dpsi, v_n, v, r, kappa]``:

- ``d`` [m]: lateral offset of the centre of gravity from the lane centre line, left positive;
- ``dpsi`` [rad]: heading of the car minus heading of the lane, counter-clockwise positive;
- ``v_n`` [m/s]: lateral velocity relative to the lane (``d' = v_n``);
- ``v`` [m/s], ``r`` [rad/s]: body lateral velocity and yaw rate of the dynamic single-track model;
- ``kappa`` [1/m]: lane curvature, positive turning left (the lane's yaw rate is ``r_d = u kappa``).

Input: the front-wheel angle ``delta`` [rad]; the longitudinal speed ``u`` [m/s] is a known parameter.
The ``(v, r)`` rows are the shared single-track model (:func:`plm_highway.vehicle.single_track.single_track_matrices`,
one implementation for the env, sim2real and this estimator). The lane rows are Eqs. (2)-(8):

    d'     = v_n
    dpsi'  = r - u kappa
    v_n'   = v' + (u - dpsi v)(r - u kappa)         (Eq. (4) for small dpsi, v' from the single-track rows)
    kappa' = 0

Measurements (Eq. (24)): the IMU gives ``[a_y, r]`` with ``a_y = v' + u r`` (linear in the state plus a
steering feed-through), the camera gives ``[d, dpsi, kappa]``. Both are linear in ``X``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from plm_highway.vehicle.single_track import SingleTrackParams, params_per_kg, single_track_matrices

STATE_NAMES = ("d_m", "dpsi_rad", "vn_mps", "v_mps", "r_radps", "kappa_1pm")
N_STATES = 6
D, DPSI, VN, V, R, KAPPA = range(N_STATES)

# The camera measures rows d, dpsi, kappa of the state (Eq. (24)).
H_CAMERA = np.zeros((3, N_STATES))
H_CAMERA[0, D] = H_CAMERA[1, DPSI] = H_CAMERA[2, KAPPA] = 1.0


class LinearRows(NamedTuple):
    """The single-track rows at one speed: ``[v', r'] = A [v, r] + B delta``."""

    a11: float
    a12: float
    a21: float
    a22: float
    b1: float
    b2: float


def single_track_rows(speed_mps: float, params: SingleTrackParams) -> LinearRows:
    """The shared single-track model's matrices for this car at this speed."""
    cf_per_kg, cr_per_kg, k2_m2 = params_per_kg(params)
    return LinearRows(*single_track_matrices(speed_mps, cf_per_kg, cr_per_kg, params.cg_to_front_m,
                                             params.cg_to_rear_m, k2_m2))


def lane_dynamics(x: np.ndarray, steer_rad: float, speed_mps: float, rows: LinearRows) -> np.ndarray:
    """``X' = f(X, delta)``, Eq. (23)."""
    d_m, dpsi, vn, v, r, kappa = x
    v_dot = rows.a11 * v + rows.a12 * r + rows.b1 * steer_rad
    r_dot = rows.a21 * v + rows.a22 * r + rows.b2 * steer_rad
    relative_yaw_rate = r - speed_mps * kappa
    vn_dot = v_dot + (speed_mps - dpsi * v) * relative_yaw_rate
    return np.array([vn, relative_yaw_rate, vn_dot, v_dot, r_dot, 0.0])


def lane_dynamics_jacobian(x: np.ndarray, speed_mps: float, rows: LinearRows) -> np.ndarray:
    """``df/dX`` at ``x`` (the steering enters linearly, so it does not appear)."""
    _, dpsi, _, v, r, kappa = x
    u = speed_mps
    jacobian = np.zeros((N_STATES, N_STATES))
    jacobian[D, VN] = 1.0
    jacobian[DPSI, R] = 1.0
    jacobian[DPSI, KAPPA] = -u
    jacobian[VN, DPSI] = -v * (r - u * kappa)
    jacobian[VN, V] = rows.a11 - dpsi * (r - u * kappa)
    jacobian[VN, R] = rows.a12 + u - dpsi * v
    jacobian[VN, KAPPA] = -u * (u - dpsi * v)
    jacobian[V, V], jacobian[V, R] = rows.a11, rows.a12
    jacobian[R, V], jacobian[R, R] = rows.a21, rows.a22
    return jacobian


def imu_model(speed_mps: float, rows: LinearRows) -> tuple[np.ndarray, np.ndarray]:
    """``(H, G)`` with ``[a_y, r] = H X + G delta`` (Eq. (24), IMU rows): ``a_y = v' + u r``."""
    h_imu = np.zeros((2, N_STATES))
    h_imu[0, V], h_imu[0, R] = rows.a11, rows.a12 + speed_mps
    h_imu[1, R] = 1.0
    return h_imu, np.array([rows.b1, 0.0])


def observability_matrix(f_matrix: np.ndarray, h_matrix: np.ndarray) -> np.ndarray:
    """``O = [H; H F; ...; H F^(n-1)]`` (Eq. (27))."""
    blocks = [h_matrix]
    for _ in range(f_matrix.shape[0] - 1):
        blocks.append(blocks[-1] @ f_matrix)
    return np.vstack(blocks)


def observability_rank(x: np.ndarray, speed_mps: float, params: SingleTrackParams, step_s: float,
                       with_camera: bool = True, with_imu: bool = True) -> int:
    """Rank of Eq. (27)'s matrix for the discrete model linearised at ``x`` (6 = fully observable)."""
    rows = single_track_rows(speed_mps, params)
    f_matrix = np.eye(N_STATES) + step_s * lane_dynamics_jacobian(np.asarray(x, float), speed_mps, rows)
    blocks = []
    if with_imu:
        blocks.append(imu_model(speed_mps, rows)[0])
    if with_camera:
        blocks.append(H_CAMERA)
    if not blocks:
        return 0
    return int(np.linalg.matrix_rank(observability_matrix(f_matrix, np.vstack(blocks))))
