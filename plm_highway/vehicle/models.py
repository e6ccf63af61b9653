"""Vehicle models as data: one table from a name to a pure step function and its parameters.

In the style of CommonRoad's vehicle models: each model is pure functions of a state, inputs and a
frozen parameter dataclass (units in the field names), with a default parameter set. The env picks
its ego model here by name (config ``vehicle_model``); sim2real and the lane-coordinate estimator
can take the same entries, so each model has one implementation.

Every model shares one state, :class:`VehicleState` (pose of the reference point, body-frame lateral
velocity and yaw rate), so the env, the sensors and an estimator read any model the same way.
Inputs over one step of ``dt_s``: the front-wheel angle and the longitudinal speed at the start
and at the end of the step (speed is an input: the models are lateral).

=============  ================================================================================
``kinematic``  highway-env's kinematic bicycle (the simulator's own model, bit for bit; forward
               Euler with the inputs at the start of the step). Lateral velocity and yaw rate are
               algebraic: ``v sin(beta)`` and ``v sin(beta) / lr`` with ``tan(beta) = lr/L tan(delta)``.
               Default parameters: highway-env's 5 m car, reference point in the middle.
``dynamic``    Single-track model with linear tires in the form of the seed paper's Equation (1)
               (Sensors 2025, 25, 6251): ``m (vy' + u r) = Cf alpha_f + Cr alpha_r``,
               ``Iz r' = a Cf alpha_f - b Cr alpha_r``, ``alpha_f = delta - (vy + a r)/u``,
               ``alpha_r = -(vy - b r)/u``; (vy, r) by the trapezoidal rule
               (:func:`~plm_highway.vehicle.single_track.single_track_tustin_step`, A-stable), the
               pose by the midpoint rule. Default parameters: the paper's Table 2 car.
``saturating`` The same equations with magic-formula axle forces that peak at ``friction_coefficient``
               times the axle load (:mod:`plm_highway.vehicle.tires`, the physics of sim2real's
               ``tire_saturation``); RK4 sub-steps. Default parameters: the Table 2 car on a dry
               road (1.0); :func:`kinematic_car_with_friction` puts the kinematic car on stiff tires.
=============  ================================================================================

Adding a model is one :class:`VehicleModel` entry in :data:`VEHICLE_MODELS` plus its tests.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

from plm_highway.errors import BadInput
from plm_highway.vehicle.kinematic import HIGHWAY_ENV_VEHICLE, KinematicBicycleParams, kinematic_bicycle_update
from plm_highway.vehicle.single_track import (
    SEED_PAPER_VEHICLE,
    SingleTrackParams,
    params_per_kg,
    single_track_matrices,
    single_track_tustin_step,
)
from plm_highway.vehicle.tires import (
    saturating_axle_forces,
    saturating_single_track_derivatives,
    saturating_single_track_pose_step,
    saturating_single_track_settled,
)

# Plausible range of each parameter field of the models' dataclasses (closed intervals, units in the
# names): a car, from a go-kart to a truck. Outside them the integrators' step sizes lose meaning
# (a 1e-9 m wheelbase turns a 0.05 s step into thousands of revolutions).
PARAM_RANGES: dict[str, tuple[float, float]] = {
    "cg_to_front_m": (0.1, 10.0),
    "cg_to_rear_m": (0.1, 10.0),
    "mass_kg": (50.0, 60_000.0),
    "yaw_inertia_kgm2": (10.0, 1e6),
    "cornering_stiffness_front": (1_000.0, 2e6),  # N/rad per axle
    "cornering_stiffness_rear": (1_000.0, 2e6),
    "friction_coefficient": (0.05, 3.0),  # peak lateral force over axle load: ice to racing slicks
}

# Below this speed the tire model's slip angles are not defined; the integrator holds it here.
TIRE_MIN_SPEED_MPS = 0.5


class VehicleState(NamedTuple):
    x_m: float
    y_m: float
    heading_rad: float
    lateral_velocity_mps: float  # body frame, at the reference point, left positive
    yaw_rate_radps: float


class Sensors(NamedTuple):
    """What a car's IMU would read at the reference point (no noise, no bias)."""

    yaw_rate_radps: float
    lateral_acceleration_mps2: float  # body frame, left positive
    slip_angle_rad: float  # direction of travel minus heading


StepFunction = Callable[[VehicleState, float, float, float, float, float, Any], VehicleState]


@dataclass(frozen=True)
class VehicleModel:
    name: str
    description: str
    default_params: Any  # a frozen dataclass, units in its field names
    step: StepFunction  # (state, steer_start_rad, steer_end_rad, speed_start_mps, speed_end_mps, dt_s, params)
    # (state, steer_rad, speed_mps, params); the state may be any object with VehicleState's attributes
    sensors: Callable[[VehicleState, float, float, Any], Sensors]
    derivatives: Callable[[VehicleState, float, float, Any], VehicleState]  # d(state)/dt, same inputs
    # (x_m, y_m, heading_rad, steer_rad, speed_mps, params) -> the pose with its lateral motion settled
    settled: Callable[..., VehicleState]

    def initial_state(self, x_m: float, y_m: float, heading_rad: float, steer_rad: float = 0.0,
                      speed_mps: float = 0.0, params: Any = None) -> VehicleState:
        """A pose with the lateral motion settled for the given steering and speed."""
        return self.settled(x_m, y_m, heading_rad, steer_rad, speed_mps, self.default_params if params is None else params)


# -- kinematic bicycle ---------------------------------------------------------------------------------


def kinematic_slip_rad(steer_rad: float, params: KinematicBicycleParams) -> float:
    return math.atan(params.cg_to_rear_m / params.wheelbase_m * math.tan(steer_rad))


def kinematic_step(state: VehicleState, steer_start_rad: float, steer_end_rad: float, speed_start_mps: float,
                   speed_end_mps: float, dt_s: float, params: KinematicBicycleParams) -> VehicleState:
    """highway-env's ``Vehicle.step`` (inputs at the start of the step); rates settle with the end inputs."""
    lr_m = params.cg_to_rear_m
    return VehicleState(*kinematic_bicycle_update(state[0], state[1], state[2], steer_start_rad, speed_start_mps,
                                                  steer_end_rad, speed_end_mps, dt_s, lr_m / (params.cg_to_front_m + lr_m),
                                                  lr_m))


def _kinematic_settled(x_m, y_m, heading_rad, steer_rad, speed_mps, params: KinematicBicycleParams) -> VehicleState:
    slip_rad = kinematic_slip_rad(steer_rad, params)
    return VehicleState(x_m, y_m, heading_rad, speed_mps * math.sin(slip_rad),
                        speed_mps * math.sin(slip_rad) / params.cg_to_rear_m)


def kinematic_sensors(state: VehicleState, steer_rad: float, speed_mps: float,
                      params: KinematicBicycleParams) -> Sensors:
    lr_m = params.cg_to_rear_m
    slip_rad = math.atan(lr_m / (params.cg_to_front_m + lr_m) * math.tan(steer_rad))
    yaw_rate_radps = speed_mps * math.sin(slip_rad) / lr_m
    # The path's curvature times v^2 (the slip angle's own rate, nonzero only while steering moves, is left out).
    return Sensors(yaw_rate_radps, speed_mps * yaw_rate_radps, slip_rad)


def kinematic_derivatives(state: VehicleState, steer_rad: float, speed_mps: float,
                          params: KinematicBicycleParams) -> VehicleState:
    slip_rad = kinematic_slip_rad(steer_rad, params)
    course_rad = state.heading_rad + slip_rad
    return VehicleState(speed_mps * math.cos(course_rad), speed_mps * math.sin(course_rad),
                        speed_mps * math.sin(slip_rad) / params.cg_to_rear_m, 0.0, 0.0)


# -- dynamic single track --------------------------------------------------------------------------------


def dynamic_step(state: VehicleState, steer_start_rad: float, steer_end_rad: float, speed_start_mps: float,
                 speed_end_mps: float, dt_s: float, params: SingleTrackParams) -> VehicleState:
    """Equation (1) over one step: (vy, r) by the trapezoidal rule with the inputs interpolated
    linearly across the step, the pose by the midpoint rule."""
    cf, cr, k2 = params_per_kg(params)
    vy0, r0 = state.lateral_velocity_mps, state.yaw_rate_radps
    vy1, r1 = single_track_tustin_step(vy0, r0, speed_start_mps, speed_end_mps, steer_start_rad, steer_end_rad,
                                       dt_s, cf, cr, params.cg_to_front_m, params.cg_to_rear_m, k2, TIRE_MIN_SPEED_MPS)
    heading_rad = state.heading_rad + 0.5 * dt_s * (r0 + r1)
    mid_heading_rad = 0.5 * (state.heading_rad + heading_rad)
    mid_speed_mps, mid_lateral_mps = 0.5 * (speed_start_mps + speed_end_mps), 0.5 * (vy0 + vy1)
    c, s = math.cos(mid_heading_rad), math.sin(mid_heading_rad)
    return VehicleState(state.x_m + dt_s * (mid_speed_mps * c - mid_lateral_mps * s),
                        state.y_m + dt_s * (mid_speed_mps * s + mid_lateral_mps * c),
                        heading_rad, float(vy1), float(r1))


def _lateral_accelerations(state: VehicleState, steer_rad: float, speed_mps: float, params: SingleTrackParams):
    """(vy', r') of Equation (1) and the body lateral acceleration (Fyf + Fyr) / m."""
    cf, cr, k2 = params_per_kg(params)
    a_m, b_m = params.cg_to_front_m, params.cg_to_rear_m
    u_mps = max(speed_mps, TIRE_MIN_SPEED_MPS)
    vy, r = state.lateral_velocity_mps, state.yaw_rate_radps
    front_per_kg = cf * (steer_rad - (vy + a_m * r) / u_mps)
    rear_per_kg = cr * -(vy - b_m * r) / u_mps
    lateral_acceleration = front_per_kg + rear_per_kg
    return lateral_acceleration - u_mps * r, (a_m * front_per_kg - b_m * rear_per_kg) / k2, lateral_acceleration


def dynamic_sensors(state: VehicleState, steer_rad: float, speed_mps: float, params: SingleTrackParams) -> Sensors:
    _, _, lateral_acceleration = _lateral_accelerations(state, steer_rad, speed_mps, params)
    return Sensors(state.yaw_rate_radps, lateral_acceleration,
                   math.atan2(state.lateral_velocity_mps, max(speed_mps, TIRE_MIN_SPEED_MPS)))


def dynamic_derivatives(state: VehicleState, steer_rad: float, speed_mps: float,
                        params: SingleTrackParams) -> VehicleState:
    vy_dot, r_dot, _ = _lateral_accelerations(state, steer_rad, speed_mps, params)
    c, s = math.cos(state.heading_rad), math.sin(state.heading_rad)
    vy = state.lateral_velocity_mps
    return VehicleState(speed_mps * c - vy * s, speed_mps * s + vy * c, state.yaw_rate_radps, vy_dot, r_dot)


def dynamic_steady_state(steer_rad: float, speed_mps: float, params: SingleTrackParams) -> tuple[float, float]:
    """(vy, r) of a steady turn: ``-A^-1 B delta`` of Equation (1)."""
    cf, cr, k2 = params_per_kg(params)
    a11, a12, a21, a22, b1, b2 = single_track_matrices(max(speed_mps, TIRE_MIN_SPEED_MPS), cf, cr,
                                                       params.cg_to_front_m, params.cg_to_rear_m, k2)
    det = a11 * a22 - a12 * a21
    return (-(a22 * b1 - a12 * b2) / det * steer_rad, -(-a21 * b1 + a11 * b2) / det * steer_rad)


def _dynamic_settled(x_m, y_m, heading_rad, steer_rad, speed_mps, params: SingleTrackParams) -> VehicleState:
    vy, r = dynamic_steady_state(steer_rad, speed_mps, params)
    return VehicleState(x_m, y_m, heading_rad, vy, r)


# -- dynamic single track with saturating tires ---------------------------------------------------------


@dataclass(frozen=True)
class TireSingleTrackParams(SingleTrackParams):
    """A single-track car whose axle forces saturate at ``friction_coefficient`` times the axle load."""

    friction_coefficient: float = 1.0  # dry asphalt


SEED_PAPER_VEHICLE_DRY = TireSingleTrackParams(**dataclasses.asdict(SEED_PAPER_VEHICLE))

# Tires this stiff (cornering stiffness per axle over the car's mass [1/s^2 per rad]) make the single-track car's
# lateral modes settle within about 6 ms at 16.7 m/s, so below the friction limit it steers close to a kinematic
# bicycle of the same geometry (whose wheels cannot slip at all).
STIFF_TIRE_PER_KG = 1400.0
CAR_DEMO_MASS_KG = 1356.0  # OSRF car_demo's Prius chassis (the PLM-Net papers' simulated car)


def kinematic_car_with_friction(friction_coefficient: float,
                                geometry: KinematicBicycleParams = HIGHWAY_ENV_VEHICLE) -> TireSingleTrackParams:
    """The kinematic bicycle ``geometry`` with stiff tires that saturate at ``friction_coefficient`` g: close to the
    kinematic car below the friction limit, and unable to turn harder beyond it. The yaw inertia m a b makes the
    axles independent (a dumbbell), as in the kinematic model. Close, not identical: its RK4 sub-steps lag less
    than highway-env's forward Euler (the inputs at the start of each 1/30 s step), which matters to a closed
    loop near its stability limit."""
    a_m, b_m = geometry.cg_to_front_m, geometry.cg_to_rear_m
    return TireSingleTrackParams(cg_to_front_m=a_m, cg_to_rear_m=b_m, mass_kg=CAR_DEMO_MASS_KG,
                                 yaw_inertia_kgm2=CAR_DEMO_MASS_KG * a_m * b_m,
                                 cornering_stiffness_front=STIFF_TIRE_PER_KG * CAR_DEMO_MASS_KG,
                                 cornering_stiffness_rear=STIFF_TIRE_PER_KG * CAR_DEMO_MASS_KG,
                                 friction_coefficient=float(friction_coefficient))


def _tire_args(params: TireSingleTrackParams) -> tuple[float, ...]:
    cf, cr, k2 = params_per_kg(params)
    return cf, cr, params.cg_to_front_m, params.cg_to_rear_m, k2, params.friction_coefficient


def saturating_step(state: VehicleState, steer_start_rad: float, steer_end_rad: float, speed_start_mps: float,
                    speed_end_mps: float, dt_s: float, params: TireSingleTrackParams) -> VehicleState:
    """Magic-formula tires (:mod:`plm_highway.vehicle.tires`) over one step: RK4 sub-steps of at most 10 ms."""
    return VehicleState(*saturating_single_track_pose_step(
        state[0], state[1], state[2], state[3], state[4], speed_start_mps, speed_end_mps, steer_start_rad,
        steer_end_rad, dt_s, *_tire_args(params), 0.0, TIRE_MIN_SPEED_MPS))


def saturating_sensors(state: VehicleState, steer_rad: float, speed_mps: float,
                       params: TireSingleTrackParams) -> Sensors:
    cf, cr, a_m, b_m, _, mu = _tire_args(params)
    u_mps = max(speed_mps, TIRE_MIN_SPEED_MPS)
    vy, r = state.lateral_velocity_mps, state.yaw_rate_radps
    front_per_kg, rear_per_kg = saturating_axle_forces(vy, r, u_mps, steer_rad, cf, cr, a_m, b_m, mu)
    return Sensors(r, front_per_kg * math.cos(steer_rad) + rear_per_kg, math.atan2(vy, u_mps))


def saturating_derivatives(state: VehicleState, steer_rad: float, speed_mps: float,
                           params: TireSingleTrackParams) -> VehicleState:
    vy_dot, r_dot = saturating_single_track_derivatives(state.lateral_velocity_mps, state.yaw_rate_radps,
                                                        max(speed_mps, TIRE_MIN_SPEED_MPS), steer_rad,
                                                        *_tire_args(params), 0.0)
    c, s = math.cos(state.heading_rad), math.sin(state.heading_rad)
    vy = state.lateral_velocity_mps
    return VehicleState(speed_mps * c - vy * s, speed_mps * s + vy * c, state.yaw_rate_radps, vy_dot, r_dot)


def _saturating_settled(x_m, y_m, heading_rad, steer_rad, speed_mps, params: TireSingleTrackParams) -> VehicleState:
    vy, r = saturating_single_track_settled(max(speed_mps, TIRE_MIN_SPEED_MPS), steer_rad, *_tire_args(params), 0.0)
    return VehicleState(x_m, y_m, heading_rad, vy, r)


# -- the table ------------------------------------------------------------------------------------------

VEHICLE_MODELS: dict[str, VehicleModel] = {
    "kinematic": VehicleModel(
        "kinematic", "highway-env's kinematic bicycle (the simulator's model; steering acts instantly)",
        HIGHWAY_ENV_VEHICLE, kinematic_step, kinematic_sensors, kinematic_derivatives, _kinematic_settled,
    ),
    "dynamic": VehicleModel(
        "dynamic", "single-track model with linear tires, seed paper Eq. (1); Table 2 car by default",
        SEED_PAPER_VEHICLE, dynamic_step, dynamic_sensors, dynamic_derivatives, _dynamic_settled,
    ),
    "saturating": VehicleModel(
        "saturating", "single-track model with magic-formula tires that saturate at mu times the axle load",
        SEED_PAPER_VEHICLE_DRY, saturating_step, saturating_sensors, saturating_derivatives, _saturating_settled,
    ),
}


def checked_params(model: VehicleModel, overrides: dict, where: str = "vehicle_params") -> Any:
    """``model``'s default parameters with ``overrides`` (field name -> number in :data:`PARAM_RANGES`)."""
    defaults = model.default_params
    if not isinstance(overrides, dict):
        raise BadInput(f"{where}: must be a dict of parameter overrides, got {overrides!r}")
    fields = sorted(defaults.__dataclass_fields__)
    for name, value in overrides.items():
        if name not in fields:
            raise BadInput(f"{where}: {name!r} is not a parameter of the {model.name} model; allowed {fields}")
        low, high = PARAM_RANGES[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:  # NaN: False
            raise BadInput(f"{where}[{name!r}] = {value!r}: must be a number in [{low:g}, {high:g}]")
    return dataclasses.replace(defaults, **{name: float(value) for name, value in overrides.items()})


def vehicle_model(name: str) -> VehicleModel:
    """The table entry for ``name``; a clear error listing the known names otherwise."""
    if not isinstance(name, str) or name not in VEHICLE_MODELS:
        raise BadInput(f"vehicle_model {name!r} is not one of {sorted(VEHICLE_MODELS)}")
    return VEHICLE_MODELS[name]
