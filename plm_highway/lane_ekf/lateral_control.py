"""A discrete LQR lane keeper on the lane-coordinate error model, with curvature feedforward.

The plant is the linearisation of the estimator's own lane model (:mod:`plm_highway.lane_ekf.lane_model`,
the seed paper's Eq. (9) for small heading errors) with the state ``x = [d, dpsi, v, r]``:

    d'    = u dpsi + v                      (v_n, the offset's rate)
    dpsi' = r - u kappa                     (the heading error's rate)
    [v', r'] = A_st [v, r] + B_st delta     (the shared single-track rows, per unit mass)

for a car given as :class:`~plm_highway.vehicle.single_track.SingleTrackParams` at speed ``u``. The
pipeline between the controller and the tyres is part of the plant, as the conditions set it:

- a first-order steering actuator ``delta' = (delta_cmd - delta) / T`` adds the wheel angle ``delta`` as
  a state (``T = 0``: the wheels follow the command at once);
- ``N`` loop steps of processing delay (the command reaches the actuator ``N`` steps after it was
  computed) add the ``N`` commands still in flight as states (a shift register).

The continuous part is discretised at the loop period with a zero-order hold (the env holds a command
over its step); the gain is the infinite-horizon discrete LQR gain from
:func:`scipy.linalg.solve_discrete_are`. Weights follow **Bryson's rule**: each penalised quantity is
divided by the largest value one accepts, ``Q = C' diag(1 / tol^2) C`` over the offset, its rate, the
heading error and its rate, ``R = 1 / delta_tol^2``; the tolerances are stated in
:class:`BrysonTolerances` and were not tuned on the test track.

Curvature enters as a disturbance (``-u kappa`` in ``dpsi'``). The feedforward is the steering that, with
the feedback in place, leaves **no steady offset** on a curve of constant curvature: from the
closed loop's steady state ``x_ss = (I - A_cl)^-1 (B u_ff + E kappa)``, ``u_ff = -kappa [C_d (I - A_cl)^-1 E] /
[C_d (I - A_cl)^-1 B]``, at the curvature the caller gives. The EKF lane keeper gives its own estimate,
which comes from a lane fit over the road 6-25 m ahead (:mod:`plm_highway.lane_ekf.lane_camera`): at a
curve's start it rises before the car gets there, a preview of the order of the processing delay and
actuator lag it has to cover, but not computed from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from plm_highway.lane_ekf.lane_model import single_track_rows
from plm_highway.vehicle.kinematic import KinematicBicycleParams
from plm_highway.vehicle.single_track import SingleTrackParams

N_ERROR_STATES = 4  # d, dpsi, v, r
# What Bryson's rule penalises, in this order: offset, its rate (v_n), heading error, its rate.
PENALISED = ("offset_m", "lateral_speed_mps", "heading_rad", "heading_rate_radps")

# A kinematic bicycle (wheels that cannot slip) as a single-track car: tyres this stiff per unit mass
# [N/rad per kg] settle the lateral modes within ~10 ms at 16.7 m/s, so the linear model's steady state is the
# kinematic one (r = u delta / L, v = lr r). The same stiffness the estimator gives highway-env's car.
KINEMATIC_STIFFNESS_PER_KG = 1000.0
KINEMATIC_MASS_KG = 1500.0


def single_track_equivalent(params) -> SingleTrackParams:
    """The linear single-track car of a vehicle-table parameter set (:mod:`plm_highway.vehicle.models`).

    A kinematic bicycle (:class:`~plm_highway.vehicle.kinematic.KinematicBicycleParams`) becomes its
    geometry on stiff tyres with the yaw inertia ``m a b`` (independent axles, as the kinematic model);
    a single-track car (linear or saturating tyres) is its own linear part.
    """
    if isinstance(params, SingleTrackParams):
        return SingleTrackParams(params.cg_to_front_m, params.cg_to_rear_m, params.mass_kg, params.yaw_inertia_kgm2,
                                 params.cornering_stiffness_front, params.cornering_stiffness_rear)
    if isinstance(params, KinematicBicycleParams):
        a_m, b_m = params.cg_to_front_m, params.cg_to_rear_m
        stiffness = KINEMATIC_STIFFNESS_PER_KG * KINEMATIC_MASS_KG
        return SingleTrackParams(a_m, b_m, KINEMATIC_MASS_KG, KINEMATIC_MASS_KG * a_m * b_m, stiffness, stiffness)
    raise TypeError(f"single_track_equivalent: expected vehicle-table parameters, got {type(params).__name__}")


@dataclass(frozen=True)
class LoopTiming:
    """The control loop and what lies between the controller's command and the tyres (the conditions')."""

    loop_period_s: float = 0.05
    actuator_time_constant_s: float = 0.0  # first-order steering actuator; 0 = the wheels follow at once
    processing_delay_steps: int = 0  # loop steps between a command and the actuator receiving it

    def __post_init__(self):
        if not (math.isfinite(self.loop_period_s) and 0.001 <= self.loop_period_s <= 1.0):
            raise ValueError(f"LoopTiming.loop_period_s={self.loop_period_s!r} must be in [0.001, 1] s")
        if not (math.isfinite(self.actuator_time_constant_s) and 0.0 <= self.actuator_time_constant_s <= 2.0):
            raise ValueError(f"LoopTiming.actuator_time_constant_s={self.actuator_time_constant_s!r} must be in [0, 2] s")
        if isinstance(self.processing_delay_steps, bool) or not isinstance(self.processing_delay_steps, int) \
                or not 0 <= self.processing_delay_steps <= 20:
            raise ValueError(f"LoopTiming.processing_delay_steps={self.processing_delay_steps!r} must be an integer "
                             "in [0, 20]")


@dataclass(frozen=True)
class BrysonTolerances:
    """The largest excursion accepted in each penalised quantity (Bryson's rule: weight = 1 / tolerance^2).

    Stated, not tuned: a tenth of a metre of offset (the order a lane-centring assist holds; a quarter of
    the margin between a 2 m wide car and the lines of a 4 m lane would be 0.5 m), the lateral speed that
    covers it in a fifth of a second, a heading error of about one degree and its rate that covers it in
    the same time; and the steering: the steering range itself.
    """

    offset_m: float = 0.1
    lateral_speed_mps: float = 0.5
    heading_rad: float = 0.02
    heading_rate_radps: float = 0.1
    steering_fraction: float = 1.0  # of the car's max steering angle

    def __post_init__(self):
        for name in (*PENALISED, "steering_fraction"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"BrysonTolerances.{name}={value!r} must be a positive number")


@dataclass(frozen=True)
class LanePlant:
    """The discrete lane-error plant ``x+ = A x + B u + E kappa`` with its augmented states (see module docstring).

    ``x = [d, dpsi, v, r, (delta), (u_{k-N}, ..., u_{k-1})]``; ``C`` maps ``x`` to the penalised quantities
    (:data:`PENALISED`).
    """

    a: np.ndarray
    b: np.ndarray
    e: np.ndarray
    c: np.ndarray
    speed_mps: float
    timing: LoopTiming

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    @property
    def has_actuator_state(self) -> bool:
        return self.timing.actuator_time_constant_s > 0


def continuous_error_model(vehicle: SingleTrackParams, speed_mps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, E)`` of ``x' = A x + B delta + E kappa`` for ``x = [d, dpsi, v, r]`` (module docstring)."""
    if not (math.isfinite(speed_mps) and speed_mps > 0.5):
        raise ValueError(f"continuous_error_model: speed_mps={speed_mps!r} must exceed 0.5 m/s")
    rows = single_track_rows(speed_mps, vehicle)
    a = np.array([[0.0, speed_mps, 1.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, 0.0, rows.a11, rows.a12],
                  [0.0, 0.0, rows.a21, rows.a22]])
    b = np.array([0.0, 0.0, rows.b1, rows.b2])
    e = np.array([0.0, -speed_mps, 0.0, 0.0])
    return a, b, e


def zero_order_hold(a: np.ndarray, inputs: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of ``x' = A x + G w`` with ``w`` held over ``period_s``: ``(e^{A h}, int e^{A s} ds G)``."""
    n, m = a.shape[0], inputs.shape[1]
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = inputs
    phi = expm(block * period_s)
    return phi[:n, :n], phi[:n, n:]


def lane_plant(vehicle: SingleTrackParams, speed_mps: float, timing: LoopTiming = LoopTiming()) -> LanePlant:
    """The discrete plant of ``vehicle`` at ``speed_mps`` with the actuator and processing delay of ``timing``."""
    a_c, b_c, e_c = continuous_error_model(vehicle, speed_mps)
    n = N_ERROR_STATES
    c_rows = np.zeros((len(PENALISED), n))
    c_rows[0, 0] = 1.0  # d
    c_rows[1, 1], c_rows[1, 2] = speed_mps, 1.0  # v_n = u dpsi + v
    c_rows[2, 1] = 1.0  # dpsi
    c_rows[3, 3] = 1.0  # dpsi' = r (- u kappa, a disturbance)
    if timing.actuator_time_constant_s > 0:
        tau = timing.actuator_time_constant_s
        a_c = np.block([[a_c, b_c[:, None]], [np.zeros((1, n)), np.array([[-1.0 / tau]])]])
        e_c = np.append(e_c, 0.0)
        b_c = np.append(np.zeros(n), 1.0 / tau)
        c_rows = np.hstack([c_rows, np.zeros((len(PENALISED), 1))])
    a_d, g_d = zero_order_hold(a_c, np.column_stack([b_c, e_c]), timing.loop_period_s)
    b_d, e_d = g_d[:, 0], g_d[:, 1]
    delay = timing.processing_delay_steps
    if delay:
        # Shift register of the commands in flight: the oldest, u_{k-N}, drives the plant now.
        n_plant = a_d.shape[0]
        a_aug = np.zeros((n_plant + delay, n_plant + delay))
        a_aug[:n_plant, :n_plant] = a_d
        a_aug[:n_plant, n_plant] = b_d
        for i in range(delay - 1):
            a_aug[n_plant + i, n_plant + i + 1] = 1.0
        b_aug = np.zeros(n_plant + delay)
        b_aug[-1] = 1.0
        a_d, b_d = a_aug, b_aug
        e_d = np.append(e_d, np.zeros(delay))
        c_rows = np.hstack([c_rows, np.zeros((len(PENALISED), delay))])
    return LanePlant(a_d, b_d, e_d, c_rows, float(speed_mps), timing)


def dlqr(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Infinite-horizon discrete LQR: ``(K, P)`` with ``u = -K x`` minimising ``sum x'Qx + u'Ru``.

    ``P`` solves the discrete algebraic Riccati equation ``P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q``.
    """
    a, b = np.atleast_2d(a), np.asarray(b, float)
    b = b.reshape(a.shape[0], -1)
    q, r = np.atleast_2d(q), np.atleast_2d(r)
    p = solve_discrete_are(a, b, q, r)
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    return k, p


@dataclass(frozen=True)
class LaneKeepingGains:
    """Feedback ``K`` (on the plant's state) and the curvature feedforward gain, for one speed."""

    feedback: np.ndarray
    feedforward_rad_per_1pm: float
    plant: LanePlant
    closed_loop_poles: np.ndarray


def lqr_gains(vehicle: SingleTrackParams, speed_mps: float, timing: LoopTiming = LoopTiming(),
              max_steering_rad: float = 0.2, tolerances: BrysonTolerances = BrysonTolerances()) -> LaneKeepingGains:
    """The LQR gain and curvature feedforward of ``vehicle`` at ``speed_mps`` (module docstring)."""
    if not (math.isfinite(max_steering_rad) and max_steering_rad > 0):
        raise ValueError(f"lqr_gains: max_steering_rad={max_steering_rad!r} must be positive")
    plant = lane_plant(vehicle, speed_mps, timing)
    weights = np.array([1.0 / getattr(tolerances, name) ** 2 for name in PENALISED])
    q = plant.c.T @ np.diag(weights) @ plant.c
    r = np.array([[1.0 / (tolerances.steering_fraction * max_steering_rad) ** 2]])
    k, _ = dlqr(plant.a, plant.b, q, r)
    k = k.ravel()
    closed = plant.a - np.outer(plant.b, k)
    # No steady offset on a constant curve: d_ss = 0 with u = -K x + u_ff.
    inverse = np.linalg.inv(np.eye(plant.n_states) - closed)
    offset_row = plant.c[0] @ inverse
    feedforward = -float(offset_row @ plant.e) / float(offset_row @ plant.b)
    return LaneKeepingGains(k, feedforward, plant, np.linalg.eigvals(closed))


class LqrLaneController:
    """``steering [rad] = -K x + k_ff kappa`` with the gains scheduled on speed (recomputed when it moves by 0.5 m/s).

    :meth:`command` takes the lane state ``[d, dpsi, v, r]`` now, the wheel angle the actuator holds (used
    when the plant has an actuator state), and the curvature for the feedforward; it remembers its own
    commands in flight for the processing delay. Call :meth:`reset` at the start of an episode.
    """

    SPEED_STEP_MPS = 0.5

    def __init__(self, vehicle: SingleTrackParams, timing: LoopTiming = LoopTiming(), max_steering_rad: float = 0.2,
                 tolerances: BrysonTolerances = BrysonTolerances()):
        self.vehicle = vehicle
        self.timing = timing
        self.max_steering_rad = float(max_steering_rad)
        self.tolerances = tolerances
        self._gains: dict[float, LaneKeepingGains] = {}
        self.reset()

    def reset(self) -> None:
        self.in_flight_rad = [0.0] * self.timing.processing_delay_steps  # oldest first

    def gains(self, speed_mps: float) -> LaneKeepingGains:
        key = max(1.0, round(speed_mps / self.SPEED_STEP_MPS) * self.SPEED_STEP_MPS)
        if key not in self._gains:
            self._gains[key] = lqr_gains(self.vehicle, key, self.timing, self.max_steering_rad, self.tolerances)
        return self._gains[key]

    def command(self, lane_state: np.ndarray, speed_mps: float, curvature_1pm: float,
                wheel_angle_rad: float = 0.0) -> float:
        """The front-wheel angle command [rad], clipped to the car's range."""
        gains = self.gains(speed_mps)
        parts = [np.asarray(lane_state, float)[:N_ERROR_STATES]]
        if gains.plant.has_actuator_state:
            parts.append([wheel_angle_rad])
        parts.append(self.in_flight_rad)
        x = np.concatenate(parts)
        steer_rad = float(-gains.feedback @ x + gains.feedforward_rad_per_1pm * curvature_1pm)
        steer_rad = min(max(steer_rad, -self.max_steering_rad), self.max_steering_rad)
        if self.in_flight_rad:
            self.in_flight_rad = self.in_flight_rad[1:] + [steer_rad]
        return steer_rad
