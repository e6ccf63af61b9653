"""Synthetic recordings from richer physics than the simulator, with a known answer.

A recording is made in four steps:

1. **Driver inputs** (:func:`driver_inputs`): a smooth speed profile within the car's speed range
   and a sequence of manoeuvres expressed as lateral-acceleration demands (straights, steady turns,
   weaves, single and double lane changes, left and right; everyday levels), plus a little
   band-limited steering noise, turned into a front-wheel command with the kinematic geometry the
   driver "knows". A :class:`Car` scales them: the seed paper's sedan drives 10-30 m/s, the 1:10
   scale car 0.8-4 m/s with half the lateral demand and its steering limit.
2. **Concealed effects** (:class:`ConcealedEffects`), set from the effect registry
   (``effects.EFFECTS[name].conceal``), on a fine time grid (10 sub-steps per sample), by the
   registry's concealment stages (``effects.concealed_*``): steering gain and offset, transport delay (optionally jittering per sample), a first-order servo with a
   rate limit; in the vehicle, tires with a friction peak and a road bank; at the sensors, a late
   gyro. Two effects outside the library (:data:`OUTSIDE_EFFECTS`) test the tool's honesty.
3. **Vehicle** (:data:`MODELS`, one table): the simulator's own step, a continuous kinematic
   bicycle, a dynamic single-track model (linear or magic-formula tires, optional bank), or
   CommonRoad's single-track and multi-body models (BMW 320i parameters, RK4).
4. **Measurement**: samples at the recording rate (optionally at jittered times, with rows
   dropped) with white Gaussian noise on every channel (:class:`NoiseLevels`); the steering column
   is the command, as a log of commands is.

:func:`make_recording` returns the :class:`Recording` and a ``truth`` dict (the answer key, written
by the CLI as ``<stem>.truth.json``; ``diagnose`` never reads it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, fields, replace

import numba
import numpy as np
from scipy.signal import lfilter

from plm_highway.sim2real.physics.effect_spec import ChainField
from plm_highway.sim2real.physics.effects import (
    CONCEALED_FIELDS,
    EFFECTS,
    concealed_calibration,
    concealed_delay,
    concealed_gyro_delay_s,
    concealed_road,
    concealed_servo,
    concealed_understeer,
    delay_jitters,
)
from plm_highway.sim2real.physics.records import plain_record
from plm_highway.sim2real.record.recording import (
    SIMULATOR_VEHICLE,
    Recording,
    VehicleGeometry,
    recording_from_arrays,
)
from plm_highway.vehicle.kinematic import (
    HIGHWAY_ENV_VEHICLE,
    KinematicState,
    kinematic_bicycle_rates,
    kinematic_bicycle_rollout,
)
from plm_highway.vehicle.single_track import (
    SEED_PAPER_VEHICLE,
    SingleTrackParams,
    front_stiffness_for_understeer,
    params_per_kg,
    single_track_rk4_step,
)
from plm_highway.vehicle.tires import (
    GRAVITY_MPS2,
    saturating_single_track_rk4_step,
    saturating_single_track_settled,
)

SUBSTEPS = 10
LEAD_IN_S = 2.0  # inputs start before the recording so a delayed command has a past
# RK4 steps for CommonRoad's models (the multi-body model's wheel and suspension modes need ~5 ms).
COMMONROAD_STEP_S = {"commonroad-st": 0.002, "commonroad-mb": 0.005}
MAX_SAMPLES = 400_000  # make-recording's size bound (duration x rate)

# Effects make-recording can conceal that the library does not have: a recording with them must
# never read as a match nor be named with a tight fit ("partly explained" or "unexplained" instead).
OUTSIDE_EFFECTS = {
    "steering_backlash": ("width_rad", 0.006, "free play in the steering: the wheels follow the command only "
                          "once it has moved by more than the play (a play operator)"),
}


@dataclass(frozen=True)
class NoiseLevels:
    """Standard deviations of the white measurement noise on each recorded channel."""

    yaw_rate_radps: float = 0.005
    heading_rad: float = 0.002
    position_m: float = 0.05
    speed_mps: float = 0.05
    lat_accel_mps2: float = 0.05

    def scaled(self, factor: float) -> NoiseLevels:
        return NoiseLevels(**{k: v * factor for k, v in asdict(self).items()})


# Physics between the log and the recording (neutral: none): the fields the registry's effects conceal
# (``effects.EFFECTS[name].conceal``), plus those of the effects outside the library.
ConcealedEffects = plain_record("ConcealedEffects", (*CONCEALED_FIELDS, ChainField("backlash_rad", 0.0)), __name__,
                                "Physics between the log and the recording (neutral: none). Set from the effect registry.")


# ----------------------------------------------------------------------------------------------
# Cars


@dataclass(frozen=True)
class Car:
    """A car for synthetic recordings and how its driver drives it."""

    name: str
    tires: SingleTrackParams
    speed_range_mps: tuple[float, float] = (10.0, 30.0)
    lat_accel_scale: float = 1.0  # of the everyday manoeuvre levels (1-3.5 m/s^2)
    max_lat_accel_mps2: float = 4.0
    lane_width_scale: float = 1.0  # of a 3-3.7 m lane change
    max_steer_rad: float = math.inf
    measurement_scale: float = 1.0  # of the position, speed and lateral-acceleration noise
    source: str = ""


# The F1TENTH 1:10 scale car (f1tenth_gym parameters): m 3.74 kg, Iz 0.04712 kg m^2, lf 0.15875 m,
# lr 0.17145 m; axle stiffness mu C_S m g l_other / L with mu 1.0489, C_Sf 4.718, C_Sr 5.4562 /rad.
_F1TENTH_L = 0.15875 + 0.17145
SMALL_CAR_TIRES = SingleTrackParams(
    cg_to_front_m=0.15875, cg_to_rear_m=0.17145, mass_kg=3.74, yaw_inertia_kgm2=0.04712,
    cornering_stiffness_front=1.0489 * 4.718 * 3.74 * GRAVITY_MPS2 * 0.17145 / _F1TENTH_L,
    cornering_stiffness_rear=1.0489 * 5.4562 * 3.74 * GRAVITY_MPS2 * 0.15875 / _F1TENTH_L,
)
CARS = {
    "sedan": Car("sedan", SEED_PAPER_VEHICLE, source="seed paper car (Sensors 2025, 25, 6251)"),
    "small": Car("small", SMALL_CAR_TIRES, speed_range_mps=(0.8, 4.0), lat_accel_scale=0.5, max_lat_accel_mps2=2.5,
                 lane_width_scale=0.15, max_steer_rad=0.4189, measurement_scale=0.1,
                 source="F1TENTH 1:10 scale car (f1tenth_gym)"),
}


def seed_paper_car(understeer_rad_per_mps2: float | None, car: SingleTrackParams = SEED_PAPER_VEHICLE
                   ) -> SingleTrackParams:
    """A car with its front stiffness changed to give the asked understeer (None: as it is)."""
    if understeer_rad_per_mps2 is None:
        return car
    cr = car.cornering_stiffness_rear / car.mass_kg
    cf = front_stiffness_for_understeer(understeer_rad_per_mps2, cr, car.cg_to_front_m, car.cg_to_rear_m)
    return replace(car, cornering_stiffness_front=cf * car.mass_kg)


# ----------------------------------------------------------------------------------------------
# 1. Driver inputs


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(math.pi * x)


def speed_profile(t_s: np.ndarray, rng: np.random.Generator, speed_range_mps: tuple[float, float] = (10.0, 30.0)
                  ) -> np.ndarray:
    """Smooth speed changes between targets in the range, at 0.5-1.5 m/s^2 (scaled with the range)."""
    lo, hi = speed_range_mps
    scale = (hi - lo) / 20.0
    speed = np.full(t_s.shape, rng.uniform(lo + 2 * scale, hi - 2 * scale))
    t = t_s[0] + rng.uniform(2.0, 8.0)
    current = speed[0]
    while t < t_s[-1]:
        target = rng.uniform(lo, hi)
        ramp_s = max(abs(target - current) / (scale * rng.uniform(0.5, 1.5)), 1.0)
        blend = _smoothstep((t_s - t) / ramp_s)
        speed = np.where(t_s >= t, current + (target - current) * blend, speed)
        current = target
        t += ramp_s + rng.uniform(4.0, 12.0)
    return speed


def lateral_demand(t_s: np.ndarray, rng: np.random.Generator, width_scale: float = 1.0) -> np.ndarray:
    """Signed lateral-acceleration demand [m/s^2] from a random sequence of manoeuvres."""
    demand = np.zeros_like(t_s)
    t = t_s[0] + rng.uniform(0.5, 2.0)
    while t < t_s[-1]:
        kind = rng.choice(["straight", "turn", "weave", "lane_change", "double_lane_change"],
                          p=[0.15, 0.3, 0.25, 0.18, 0.12])
        side = rng.choice([-1.0, 1.0])
        local = t_s - t
        if kind == "straight":
            length = rng.uniform(2.0, 5.0)
        elif kind == "turn":
            ramp, hold, level = rng.uniform(1.0, 2.5), rng.uniform(3.0, 8.0), rng.uniform(1.0, 3.5)
            length = 2 * ramp + hold
            shape = _smoothstep(local / ramp) - _smoothstep((local - ramp - hold) / ramp)
            demand += side * level * shape * ((local >= 0) & (local <= length))
        elif kind == "weave":
            freq, cycles, level = rng.uniform(0.15, 0.9), rng.integers(2, 5), rng.uniform(1.0, 3.0)
            length = cycles / freq
            inside = (local >= 0) & (local <= length)
            demand += side * level * np.sin(2 * math.pi * freq * local) * inside
        else:
            width, duration = width_scale * rng.uniform(3.0, 3.7), rng.uniform(3.0, 5.0)
            pulses = [(0.0, side)] if kind == "lane_change" else [(0.0, side), (duration + rng.uniform(1.0, 2.0), -side)]
            length = pulses[-1][0] + duration
            for start, sign in pulses:
                s = local - start
                inside = (s >= 0) & (s <= duration)
                demand += sign * width * 2 * math.pi / duration**2 * np.sin(2 * math.pi * s / duration) * inside
        t += length + rng.uniform(0.5, 2.0)
    return demand


def steering_noise(t_s: np.ndarray, rng: np.random.Generator, level_mps2: float) -> np.ndarray:
    """Band-limited (~0.3-2 Hz) driver corrections as a lateral-acceleration demand."""
    dt = t_s[1] - t_s[0]
    white = rng.standard_normal(t_s.shape)
    # Two first-order low passes at 2 Hz minus a slow component: a band pass, cheap and smooth.
    alpha = math.exp(-2 * math.pi * 2.0 * dt)
    lp = lfilter([1 - alpha], [1, -alpha], lfilter([1 - alpha], [1, -alpha], white))
    beta = math.exp(-2 * math.pi * 0.3 * dt)
    band = lp - lfilter([1 - beta], [1, -beta], lp)
    return level_mps2 * band / max(np.std(band), 1e-12)


def driver_inputs(t_s: np.ndarray, rng: np.random.Generator, wheelbase_m: float,
                  noise_mps2: float = 0.25, car: Car = CARS["sedan"]) -> tuple[np.ndarray, np.ndarray]:
    """(steering command [rad], speed [m/s]) on the time grid ``t_s``."""
    speed = speed_profile(t_s, rng, car.speed_range_mps)
    demand = car.lat_accel_scale * (lateral_demand(t_s, rng, car.lane_width_scale)
                                    + steering_noise(t_s, rng, noise_mps2))
    # Everyday driving stays below ~4 m/s^2 (a full-size car), where tires are close to linear.
    demand = np.clip(demand, -car.max_lat_accel_mps2, car.max_lat_accel_mps2)
    curvature = demand / speed**2
    steer = np.arctan(wheelbase_m * curvature)
    if math.isfinite(car.max_steer_rad):
        steer = np.clip(steer, -car.max_steer_rad, car.max_steer_rad)
    return steer, speed


# ----------------------------------------------------------------------------------------------
# 2. Effects on the command


def _play(command: np.ndarray, width_rad: float) -> np.ndarray:
    """Backlash (play operator): the output moves only when the input pushes it at an edge."""
    out = np.empty_like(command)
    half = 0.5 * width_rad
    y = command[0]
    for k, u in enumerate(command):
        y = min(max(y, u - half), u + half)
        out[k] = y
    return out


def apply_effects(t_s: np.ndarray, command_rad: np.ndarray, effects: ConcealedEffects,
                  jitter_rng: np.random.Generator | None = None, frame_s: float | None = None) -> np.ndarray:
    """The front-wheel angle the car actually gets, on a fine uniform grid ``t_s``.

    A jittering delay draws one delay per recording frame (``frame_s``) from ``jitter_rng``.
    """
    dt = t_s[1] - t_s[0]
    delta = concealed_calibration(effects, command_rad)
    delta = concealed_delay(t_s, delta, effects, jitter_rng, frame_s)
    if effects.backlash_rad > 0:  # outside the library: before the servo, as a worn steering column's play
        delta = _play(delta, effects.backlash_rad)
    return concealed_servo(delta, dt, effects)


# ----------------------------------------------------------------------------------------------
# 3. Vehicles on the fine grid: each returns (x, y, heading, yaw rate, speed, lateral accel)


def _cumtrapz(rate: np.ndarray, dt: float, start: float) -> np.ndarray:
    out = np.empty_like(rate)
    out[0] = start
    out[1:] = start + np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)
    return out


def _kinematic_fine(delta, speed, dt, geometry: VehicleGeometry, heading0):
    r, beta = kinematic_bicycle_rates(delta, speed, geometry.kinematic)
    heading = _cumtrapz(r, dt, heading0)
    course = heading + beta
    x = _cumtrapz(speed * np.cos(course), dt, 0.0)
    y = _cumtrapz(speed * np.sin(course), dt, 0.0)
    lat_accel = speed * np.gradient(course, dt)
    return x, y, heading, r, speed, lat_accel


@numba.njit(cache=True)
def _single_track_fine_states(delta, speed, dt, cf, cr, a, b, k2):
    n = delta.shape[0]
    vy = np.zeros(n)
    r = np.zeros(n)
    # Settle: start from the steady state by integrating the first input for a while.
    v, w = 0.0, 0.0
    for _ in range(4000):
        v, w = single_track_rk4_step(v, w, speed[0], speed[0], delta[0], delta[0], dt, cf, cr, a, b, k2)
    vy[0], r[0] = v, w
    for k in range(n - 1):
        v, w = single_track_rk4_step(v, w, speed[k], speed[k + 1], delta[k], delta[k + 1], dt, cf, cr, a, b, k2)
        vy[k + 1], r[k + 1] = v, w
    return vy, r


@numba.njit(cache=True)
def _saturating_fine_states(delta, speed, dt, cf, cr, a, b, k2, mu, bank):
    n = delta.shape[0]
    vy = np.zeros(n)
    r = np.zeros(n)
    v, w = saturating_single_track_settled(speed[0], delta[0], cf, cr, a, b, k2, mu, bank)
    vy[0], r[0] = v, w
    for k in range(n - 1):
        v, w = saturating_single_track_rk4_step(v, w, speed[k], speed[k + 1], delta[k], delta[k + 1], dt, cf, cr, a,
                                                b, k2, mu, bank)
        vy[k + 1], r[k + 1] = v, w
    return vy, r


def _single_track_fine(delta, speed, dt, car: SingleTrackParams, heading0, friction: float = math.inf,
                       bank_rad: float = 0.0):
    cf, cr, k2 = params_per_kg(car)
    a, b = car.cg_to_front_m, car.cg_to_rear_m
    if math.isfinite(friction) or bank_rad != 0.0:
        vy, r = _saturating_fine_states(delta, speed, dt, cf, cr, a, b, k2, friction,
                                        GRAVITY_MPS2 * math.sin(bank_rad))
    else:
        vy, r = _single_track_fine_states(delta, speed, dt, cf, cr, a, b, k2)
    heading = _cumtrapz(r, dt, heading0)
    vx_world = speed * np.cos(heading) - vy * np.sin(heading)
    vy_world = speed * np.sin(heading) + vy * np.cos(heading)
    x = _cumtrapz(vx_world, dt, 0.0)
    y = _cumtrapz(vy_world, dt, 0.0)
    lat_accel = np.gradient(vy, dt) + speed * r
    return x, y, heading, r, np.hypot(speed, vy), lat_accel


def _commonroad_fine(model: str, delta_target, speed_target, dt_fine, heading0, decimate: int):
    """CommonRoad ST or MB with a fast steering servo and a speed controller (RK4, python)."""
    # lazy: CommonRoad's vehicle models serve only the richer-physics cars
    from vehiclemodels.init_mb import init_mb
    from vehiclemodels.init_st import init_st
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
    from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st

    p = parameters_vehicle2()
    # Integrate on a coarser grid than the fine effect grid where the model is expensive, keeping
    # the step a divisor of the sub-step count so that samples fall on the grid.
    target_s = COMMONROAD_STEP_S[model]
    step = max(d for d in range(1, decimate + 1) if decimate % d == 0 and (d == 1 or d * dt_fine <= target_s))
    dt = dt_fine * step
    delta_t = delta_target[::step]
    speed_t = speed_target[::step]
    dyn = vehicle_dynamics_mb if model == "commonroad-mb" else vehicle_dynamics_st
    state = init_mb([0.0, 0.0, delta_t[0], speed_t[0], heading0, 0.0, 0.0], p) if model == "commonroad-mb" \
        else init_st([0.0, 0.0, delta_t[0], speed_t[0], heading0, 0.0, 0.0])
    x = np.array(state, float)
    n = delta_t.shape[0]
    out = np.empty((n, 5))  # x, y, heading, yaw rate, speed
    steer_time_constant_s = 0.01
    speed_gain = 2.0
    accel_ff = np.gradient(speed_t, dt)

    def f(xx, u):
        return np.asarray(dyn(xx, u, p), float)

    for k in range(n):
        if model == "commonroad-mb":
            speed = math.hypot(x[3], x[10])
        else:
            speed = x[3]
        out[k] = (x[0], x[1], x[4], x[5], speed)
        if k == n - 1:
            break
        u = [(delta_t[k] - x[2]) / steer_time_constant_s, accel_ff[k] + speed_gain * (speed_t[k] - speed)]
        k1 = f(x, u)
        k2 = f(x + 0.5 * dt * k1, u)
        k3 = f(x + 0.5 * dt * k2, u)
        k4 = f(x + dt * k3, u)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    course_rate = np.gradient(out[:, 2], dt)
    lat_accel = out[:, 4] * course_rate
    # Back onto the fine grid (samples fall on every ``step``-th fine point).
    fine_idx = np.arange(len(delta_target)) // step
    fine = tuple(a[np.minimum(fine_idx, n - 1)] for a in (out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4],
                                                           lat_accel))
    return fine


# ----------------------------------------------------------------------------------------------
# The table of vehicle models


@dataclass(frozen=True)
class VehicleModel:
    """How make-recording simulates a vehicle: on the fine grid (``fine``), or highway-env's own step."""

    name: str
    description: str
    has_tires: bool  # the effects of the "tires" group (and road_bank) need this
    takes_effects: bool = True
    fixed_car: str | None = None  # CommonRoad's models bring their own car
    fine: Callable | None = None  # (delta, speed, dt, car, geometry, heading0, concealed) -> 6 fine arrays


def _fine_kinematic(delta, speed, dt, car, geometry, heading0, concealed):
    return _kinematic_fine(delta, speed, dt, geometry, heading0)


def _fine_single_track(delta, speed, dt, car, geometry, heading0, concealed):
    return _single_track_fine(delta, speed, dt, car, heading0, *concealed_road(concealed))


def _fine_commonroad(name):
    def run(delta, speed, dt, car, geometry, heading0, concealed):
        return _commonroad_fine(name, delta, speed, dt, heading0, SUBSTEPS)
    return run


def _bmw_320i() -> VehicleGeometry:
    # lazy: CommonRoad's vehicle models serve only the richer-physics cars
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

    p = parameters_vehicle2()
    return VehicleGeometry(p.a, p.b, p.m, p.I_z, source="BMW 320i (vehiclemodels parameters_vehicle2)")


MODELS_TABLE: dict[str, VehicleModel] = {m.name: m for m in (
    VehicleModel("simulator", "highway-env's own step (forward Euler at the sample rate), exactly", False,
                 takes_effects=False),
    VehicleModel("kinematic", "a continuous-time kinematic bicycle", False, fine=_fine_kinematic),
    VehicleModel("single-track", "a dynamic single-track model (linear or magic-formula tires, optional bank)",
                 True, fine=_fine_single_track),
    VehicleModel("commonroad-st", "CommonRoad's single-track model (BMW 320i)", False, fixed_car="bmw",
                 fine=_fine_commonroad("commonroad-st")),
    VehicleModel("commonroad-mb", "CommonRoad's 29-state multi-body model (BMW 320i)", False, fixed_car="bmw",
                 fine=_fine_commonroad("commonroad-mb")),
)}
MODELS = ("auto", *MODELS_TABLE)


# ----------------------------------------------------------------------------------------------
# 4. Putting it together


def parse_effects(specs: Mapping[str, float | Mapping[str, float] | None]) -> ConcealedEffects:
    """Effect name -> value (the effect's first make-recording parameter), a mapping of its
    parameters, or None (defaults) into the concealed physics. Values outside
    ``EFFECTS[name].synth_bounds`` are refused naming the effect and parameter."""
    known = (*EFFECTS, *OUTSIDE_EFFECTS)
    unknown = sorted(set(specs) - set(known))
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(known)}")
    values: dict[str, float] = {}
    for name, spec in specs.items():
        if name in OUTSIDE_EFFECTS:
            key, default, _ = OUTSIDE_EFFECTS[name]
            value = default if spec is None else float(spec if not isinstance(spec, Mapping) else spec[key])
            if not (math.isfinite(value) and 0 < value < 0.5):
                raise ValueError(f"effect {name}: {key} = {value!r} must be in (0, 0.5)")
            values["backlash_rad"] = value
            continue
        effect = EFFECTS[name]
        given = {} if spec is None else (dict(spec) if isinstance(spec, Mapping) else {effect.primary_synth_key: spec})
        extra = sorted(set(given) - set(effect.synth_defaults))
        if extra:
            raise ValueError(f"effect {name}: unknown parameter(s) {', '.join(extra)}; known: "
                             f"{', '.join(effect.synth_defaults)}")
        for key, default in effect.synth_defaults.items():
            value = float(given.get(key, default))
            lo, hi = effect.synth_bounds[key]
            if key not in given and math.isnan(default):
                continue  # NaN default: the car's own value
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"effect {name}: {key} = {value!r} is outside {lo:g}-{hi:g}")
            field_name = effect.conceal[key].name
            if field_name in values and key not in given and values[field_name] != value:
                continue  # another effect set it explicitly (e.g. delay_jitter's mean delay)
            values[field_name] = value
    return ConcealedEffects(**values)


def _effect_groups(effects: Mapping) -> set[str]:
    return {EFFECTS[e].group for e in effects if e in EFFECTS and EFFECTS[e].group} | \
        {EFFECTS[e].needs_group for e in effects if e in EFFECTS and EFFECTS[e].needs_group}


def choose_model(model: str, effects: Mapping) -> VehicleModel:
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; known: {', '.join(MODELS)}")
    needs_tires = "tires" in _effect_groups(effects)
    if model == "auto":
        model = "single-track" if needs_tires else "kinematic"
    chosen = MODELS_TABLE[model]
    if needs_tires and not chosen.has_tires:
        raise ValueError(f"{', '.join(e for e in effects if e in EFFECTS and 'tires' in _effect_groups({e: 0}))} "
                         f"act(s) on the single-track model's tires; model {model!r} has its own (or none)")
    if not chosen.takes_effects and effects:
        raise ValueError("the 'simulator' model is highway-env's own step: it takes no effects (use 'kinematic')")
    return chosen


def _check_sampling(duration_s: float, sample_hz: float, timestamp_jitter: float, drop_fraction: float) -> None:
    if not (math.isfinite(duration_s) and duration_s >= 10):
        raise ValueError(f"duration must be at least 10 s, got {duration_s!r}")
    if not (math.isfinite(sample_hz) and 5.0 <= sample_hz <= 1000.0):
        raise ValueError(f"sample rate must be 5-1000 Hz, got {sample_hz!r}")
    if duration_s * sample_hz > MAX_SAMPLES:
        raise ValueError(f"{duration_s:g} s at {sample_hz:g} Hz is {duration_s * sample_hz:,.0f} samples; at most "
                         f"{MAX_SAMPLES:,}")
    if not (0.0 <= timestamp_jitter < 0.5):
        raise ValueError(f"timestamp jitter must be 0 to 0.5 of the interval, got {timestamp_jitter!r}")
    if not (0.0 <= drop_fraction <= 0.5):
        raise ValueError(f"drop fraction must be 0-0.5, got {drop_fraction!r}")


def make_recording(
    effects: Mapping[str, float | Mapping[str, float] | None] | None = None,
    *,
    rng: np.random.Generator,
    duration_s: float = 120.0,
    sample_hz: float = 50.0,
    model: str = "auto",
    noise: NoiseLevels | None = None,
    with_yaw_rate: bool = True,
    with_lat_accel: bool = True,
    car: str = "auto",
    timestamp_jitter: float = 0.0,
    drop_fraction: float = 0.0,
) -> tuple[Recording, dict]:
    """A recording with concealed physics, and its answer key.

    ``timestamp_jitter`` (fraction of the interval, uniform) and ``drop_fraction`` (rows removed at
    random) make the timestamps irregular: the returned recording is then the raw rows (not
    uniformly sampled; :func:`as_read` resamples it as ``read_recording`` would).
    """
    effects = dict(effects or {})
    _check_sampling(duration_s, sample_hz, timestamp_jitter, drop_fraction)
    concealed = parse_effects(effects)
    vehicle_model = choose_model(model, effects)
    if car not in ("auto", *CARS):
        raise ValueError(f"unknown car {car!r}; known: auto, {', '.join(CARS)}")
    if vehicle_model.fixed_car and car not in ("auto",):
        raise ValueError(f"model {vehicle_model.name!r} brings its own car (BMW 320i); leave --car at auto")
    chosen_car = CARS["sedan" if car == "auto" else car]
    noise = NoiseLevels() if noise is None else noise
    if chosen_car.measurement_scale != 1.0:  # a small car's pose and speed are measured to scale
        noise = replace(noise, position_m=noise.position_m * chosen_car.measurement_scale,
                        speed_mps=noise.speed_mps * chosen_car.measurement_scale,
                        lat_accel_mps2=noise.lat_accel_mps2 * chosen_car.measurement_scale)

    n = round(duration_s * sample_hz) + 1
    dt = 1.0 / sample_hz
    t_rec = np.arange(n) * dt
    heading0 = rng.uniform(-math.pi, math.pi)

    tires = seed_paper_car(concealed_understeer(concealed), chosen_car.tires)
    if vehicle_model.fixed_car:
        geometry = _bmw_320i()
    elif vehicle_model.has_tires:
        geometry = VehicleGeometry(tires.cg_to_front_m, tires.cg_to_rear_m, tires.mass_kg, tires.yaw_inertia_kgm2,
                                   source=chosen_car.source)
    elif car == "auto":
        geometry = SIMULATOR_VEHICLE
    else:
        geometry = VehicleGeometry(tires.cg_to_front_m, tires.cg_to_rear_m, source=chosen_car.source)

    if vehicle_model.fine is None:
        # Exactly highway-env: commands held over each step, forward Euler at the sample rate.
        command, speed = driver_inputs(t_rec, rng, geometry.wheelbase_m, car=chosen_car)
        xs, ys, hs = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, heading0), command[:-1], speed[:-1], dt,
                                               HIGHWAY_ENV_VEHICLE)
        r, _beta = kinematic_bicycle_rates(command, speed, HIGHWAY_ENV_VEHICLE)
        signals = {"x": xs, "y": ys, "heading": hs, "yaw_rate": r, "speed": speed, "lat_accel": speed * r,
                   "steer": command}
        t_sample = t_rec
    else:
        dt_fine = dt / SUBSTEPS
        n_lead = round(LEAD_IN_S / dt_fine)
        t_fine = (np.arange(n_lead + (n - 1) * SUBSTEPS + 1) - n_lead) * dt_fine
        command_fine, speed_fine = driver_inputs(t_fine, rng, geometry.wheelbase_m, car=chosen_car)
        jitter_rng = rng.spawn(1)[0] if delay_jitters(concealed) else None
        delta_fine = apply_effects(t_fine, command_fine, concealed, jitter_rng, dt)
        fine = vehicle_model.fine(delta_fine, speed_fine, dt_fine, tires, geometry, heading0, concealed)
        t_sample = t_rec
        if timestamp_jitter > 0 or drop_fraction > 0:
            sampling_rng = rng.spawn(1)[0]
            t_sample = t_rec + timestamp_jitter * dt * sampling_rng.uniform(-1.0, 1.0, n)
            t_sample[0], t_sample[-1] = t_rec[0], t_rec[-1]
            keep = sampling_rng.random(n) >= drop_fraction
            keep[0] = keep[-1] = True
            t_sample = t_sample[keep]

        def at(values: np.ndarray, late_s: float = 0.0) -> np.ndarray:
            return np.interp(t_sample - late_s, t_fine, values)

        x, y, heading, yaw_rate, speed_true, lat_accel = fine
        signals = {"x": at(x) - at(x)[0], "y": at(y) - at(y)[0], "heading": at(heading),
                   "yaw_rate": at(yaw_rate, concealed_gyro_delay_s(concealed)), "speed": at(speed_true),
                   "lat_accel": at(lat_accel), "steer": at(command_fine)}
        if t_sample is t_rec:  # on the grid exactly (bit for bit the samples, no interpolation)
            pick = np.arange(n_lead, len(t_fine), SUBSTEPS)
            for key, values in (("x", x), ("y", y), ("heading", heading), ("speed", speed_true),
                                ("lat_accel", lat_accel), ("steer", command_fine)):
                signals[key] = values[pick]
            signals["x"] = signals["x"] - signals["x"][0]
            signals["y"] = signals["y"] - signals["y"][0]
            if concealed_gyro_delay_s(concealed) == 0:
                signals["yaw_rate"] = yaw_rate[pick]
    m = len(t_sample)
    rec = Recording(
        t_s=t_sample,
        steer_rad=np.round(signals["steer"], 7),
        speed_mps=signals["speed"] + noise.speed_mps * rng.standard_normal(m),
        x_m=signals["x"] + noise.position_m * rng.standard_normal(m),
        y_m=signals["y"] + noise.position_m * rng.standard_normal(m),
        heading_rad=signals["heading"] + noise.heading_rad * rng.standard_normal(m),
        yaw_rate_radps=(signals["yaw_rate"] + noise.yaw_rate_radps * rng.standard_normal(m)) if with_yaw_rate
        else None,
        lat_accel_mps2=(signals["lat_accel"] + noise.lat_accel_mps2 * rng.standard_normal(m)) if with_lat_accel
        else None,
        vehicle=geometry,
        name="synthetic",
    )
    truth = {
        "model": vehicle_model.name,
        "car": "BMW 320i" if vehicle_model.fixed_car else chosen_car.name,
        "effects": truth_effects(effects, concealed, tires if vehicle_model.has_tires else None),
        "outside_library": sorted(e for e in effects if e in OUTSIDE_EFFECTS),
        "noise": asdict(noise),
        "vehicle": geometry.sidecar() if geometry != SIMULATOR_VEHICLE else "simulator",
        "duration_s": duration_s,
        "sample_hz": sample_hz,
        "timestamp_jitter": timestamp_jitter,
        "drop_fraction": drop_fraction,
    }
    return rec, truth


def as_read(recording: Recording) -> Recording:
    """The recording as ``read_recording`` sees it: irregular rows resampled (with warnings)."""
    if recording.is_uniform:
        return recording
    return recording_from_arrays(recording.columns(), vehicle=recording.vehicle, name=recording.name)


def truth_effects(specs: Mapping, concealed: ConcealedEffects, tires: SingleTrackParams | None
                  ) -> dict[str, dict[str, float]]:
    """The answer key: every effect asked, under its public names, and the car's tires when it has any."""
    fields_by_name = {f.name: getattr(concealed, f.name) for f in fields(concealed)}
    out: dict[str, dict[str, float]] = {}
    for name in EFFECTS:
        if name not in specs:
            continue
        effect = EFFECTS[name]
        reported = {key: fields_by_name[effect.conceal[key].name] for key in effect.synth_defaults}
        out[name] = {k: v for k, v in reported.items() if k in effect.public_keys and v is not None}
    if tires is not None:
        tire_values = {"understeer_gradient_rad_per_mps2": tires.understeer_gradient_rad_per_mps2,
                       "cornering_stiffness_front": tires.cornering_stiffness_front,
                       "cornering_stiffness_rear": tires.cornering_stiffness_rear}
        friction, _bank_rad = concealed_road(concealed)
        key = "tire_saturation" if math.isfinite(friction) else "tire_slip"
        out[key] = out.get(key, {}) | tire_values
    return {name: out[name] for name in EFFECTS if name in out}
