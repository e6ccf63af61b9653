"""The simulator's vehicle model: highway-env's kinematic bicycle, as pure functions.

highway-env 1.12.1 ``Vehicle.step`` (``highway_env/vehicle/kinematics.py``) integrates, at the
simulation frequency and with forward Euler,

    beta     = atan(lr / L * tan(delta))          slip angle of the velocity at the reference point
    x'       = v * cos(heading + beta)
    y'       = v * sin(heading + beta)
    heading' = v * sin(beta) / lr

with the reference point halfway along the car (lr = L / 2 = LENGTH / 2 = 2.5 m, so
``lr / L = 1/2``), the steering applied instantly, and the heading *before* the update used for
the position step. World frame: x right, y up, so a positive steering angle raises the heading
(turns left).

Written in the style of CommonRoad's vehicle models: one pure function per model, the parameters as
data (:class:`KinematicBicycleParams`). Other geometries (a recording's sidecar wheelbase and
centre-of-gravity position) use the same equations with their own ``lf`` and ``lr``; the highway-env
vehicle is :data:`HIGHWAY_ENV_VEHICLE`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


@dataclass(frozen=True)
class KinematicBicycleParams:
    """Geometry of a kinematic bicycle; the reference point is the centre of gravity."""

    cg_to_front_m: float = 2.5
    cg_to_rear_m: float = 2.5

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m

    @property
    def half_length_m(self) -> float:
        """highway-env's ``LENGTH / 2`` when the car is the simulator's own (lf = lr)."""
        return self.cg_to_rear_m


# highway-env's Vehicle: LENGTH = 5 m, reference point at the middle.
HIGHWAY_ENV_VEHICLE = KinematicBicycleParams(cg_to_front_m=2.5, cg_to_rear_m=2.5)


class KinematicState(NamedTuple):
    x_m: float
    y_m: float
    heading_rad: float


def kinematic_bicycle_step(
    state: KinematicState, steer_rad: float, speed_mps: float, dt_s: float, params: KinematicBicycleParams
) -> KinematicState:
    """One forward-Euler step, operation for operation as highway-env's ``Vehicle.step``."""
    return KinematicState(*kinematic_bicycle_pose_step(
        state.x_m, state.y_m, state.heading_rad, steer_rad, speed_mps, dt_s,
        params.cg_to_rear_m / params.wheelbase_m, params.cg_to_rear_m,
    ))


def kinematic_bicycle_pose_step(
    x_m: float, y_m: float, heading_rad: float, steer_rad: float, speed_mps: float, dt_s: float,
    rear_fraction: float, cg_to_rear_m: float,
) -> tuple[float, float, float]:
    """:func:`kinematic_bicycle_step` on bare floats (``rear_fraction = lr / L``)."""
    return kinematic_bicycle_update(x_m, y_m, heading_rad, steer_rad, speed_mps, steer_rad, speed_mps, dt_s,
                                    rear_fraction, cg_to_rear_m)[:3]


def kinematic_bicycle_update(
    x_m: float, y_m: float, heading_rad: float, steer_rad: float, speed_mps: float, steer_end_rad: float,
    speed_end_mps: float, dt_s: float, rear_fraction: float, cg_to_rear_m: float,
) -> tuple[float, float, float, float, float]:
    """The one implementation of the step: pose after ``dt_s`` (inputs at the start of the step, as
    highway-env), then the body lateral velocity and yaw rate with the inputs at its end.

    Returns (x_m, y_m, heading_rad, lateral_velocity_mps, yaw_rate_radps). Scalar ``math`` rather
    than numpy: the same IEEE operations (numpy's float64 sin/cos/tan/arctan give libm's results on
    this project's platforms), without the cost of numpy on scalars.
    """
    beta = math.atan(rear_fraction * math.tan(steer_rad))
    sin_beta = math.sin(beta)
    yaw_rate_radps = speed_mps * sin_beta / cg_to_rear_m
    # The position uses the heading before this step's update, as highway-env does.
    x_m = x_m + speed_mps * math.cos(heading_rad + beta) * dt_s
    y_m = y_m + speed_mps * math.sin(heading_rad + beta) * dt_s
    heading_rad = heading_rad + yaw_rate_radps * dt_s
    if steer_end_rad != steer_rad or speed_end_mps != speed_mps:
        sin_beta = math.sin(math.atan(rear_fraction * math.tan(steer_end_rad)))
        yaw_rate_radps = speed_end_mps * sin_beta / cg_to_rear_m
    return x_m, y_m, heading_rad, speed_end_mps * sin_beta, yaw_rate_radps


def kinematic_bicycle_rates(
    steer_rad: np.ndarray, speed_mps: np.ndarray, params: KinematicBicycleParams
) -> tuple[np.ndarray, np.ndarray]:
    """Yaw rate [rad/s] and slip angle [rad] of the kinematic bicycle, elementwise.

    With the speed given (the simulator's speed is an input here, as in a replay), the yaw rate is
    an algebraic function of the current steering angle: no state is needed.
    Arrays broadcast, so a batch of geometries can be given as arrays inside ``params``.
    """
    steer_rad = np.asarray(steer_rad, dtype=float)
    lr = np.asarray(params.cg_to_rear_m, dtype=float)
    wheelbase = np.asarray(params.cg_to_front_m, dtype=float) + lr
    slip_rad = np.arctan(lr / wheelbase * np.tan(steer_rad))
    yaw_rate_radps = np.asarray(speed_mps, dtype=float) * np.sin(slip_rad) / lr
    return yaw_rate_radps, slip_rad


def integrate_pose_euler(
    x0_m: np.ndarray | float,
    y0_m: np.ndarray | float,
    heading0_rad: np.ndarray | float,
    yaw_rate_radps: np.ndarray,
    slip_rad: np.ndarray,
    speed_mps: np.ndarray,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward-Euler pose from per-step yaw rate, slip and speed; time is the last axis.

    Returns arrays one longer than the inputs along time (the initial pose first). The running sums
    add the increments in the same order as a step-by-step loop, so the result is bit-for-bit the
    loop's (no cumulative-sum reassociation).
    """
    yaw_rate_radps, slip_rad, speed_mps = np.broadcast_arrays(
        np.asarray(yaw_rate_radps, float), np.asarray(slip_rad, float), np.asarray(speed_mps, float)
    )
    lead = yaw_rate_radps.shape[:-1]
    heading0 = np.broadcast_to(np.asarray(heading0_rad, float), lead)[..., None]
    heading_rad = np.cumsum(np.concatenate([heading0, yaw_rate_radps * dt_s], axis=-1), axis=-1)
    course_rad = heading_rad[..., :-1] + slip_rad
    x0 = np.broadcast_to(np.asarray(x0_m, float), lead)[..., None]
    y0 = np.broadcast_to(np.asarray(y0_m, float), lead)[..., None]
    x_m = np.cumsum(np.concatenate([x0, speed_mps * np.cos(course_rad) * dt_s], axis=-1), axis=-1)
    y_m = np.cumsum(np.concatenate([y0, speed_mps * np.sin(course_rad) * dt_s], axis=-1), axis=-1)
    return x_m, y_m, heading_rad


def kinematic_bicycle_rollout(
    initial: KinematicState,
    steer_rad: np.ndarray,
    speed_mps: np.ndarray,
    dt_s: float,
    params: KinematicBicycleParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll the simulator's model over a steering sequence: (x, y, heading), each ``T + 1`` long.

    Time is the last axis; leading axes are a batch (e.g. candidate steering sequences, or a batch
    of geometries given as arrays in ``params`` with shape ``(B, 1)``).
    """
    steer_rad = np.asarray(steer_rad, float)
    yaw_rate, slip = kinematic_bicycle_rates(steer_rad, speed_mps, params)
    # The speed term must be multiplied in the same order as highway-env: v * sin(beta) / lr * dt.
    return integrate_pose_euler(initial.x_m, initial.y_m, initial.heading_rad, yaw_rate, slip, speed_mps, dt_s)
