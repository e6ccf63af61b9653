"""Synthetic recordings from richer physics than the simulator, with a known answer.

A recording is made in four steps:

1. **Driver inputs** (:func:`driver_inputs`): a smooth speed profile between 10 and 30 m/s and a
   sequence of manoeuvres expressed as lateral-acceleration demands (straights, steady turns,
   weaves, single and double lane changes, left and right; everyday levels, at most 4 m/s^2), plus
   a little band-limited steering noise, turned into a front-wheel command with the kinematic
   geometry the driver "knows".
2. **Concealed effects** on the command: steering gain and offset, transport delay, first-order
   actuator lag (:class:`ConcealedEffects`), evaluated on a fine time grid (10 sub-steps per sample).
3. **Vehicle**: the simulator's own model (stepped exactly as highway-env does), a continuous
   kinematic bicycle, a dynamic single-track model with linear tires (the seed paper's car:
   m 1850 kg, Iz 2800 kg m^2, a 1.35 m, b 1.45 m, Cf 86,000, Cr 92,000 N/rad), or CommonRoad's
   single-track (``commonroad-st``) and multi-body (``commonroad-mb``) models with the BMW 320i
   parameters, integrated with RK4 on a fine grid.
4. **Measurement**: samples at the recording rate with white Gaussian noise on every measured
   channel (:class:`NoiseLevels`); the steering column is the command, as a log of commands is.

:func:`make_recording` returns the :class:`Recording` and a ``truth`` dict (the answer key, written
by the CLI as ``<stem>.truth.json``; ``diagnose`` never reads it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace

import numba
import numpy as np
from scipy.signal import lfilter

from plm_highway.sim2real.effects import EFFECT_NAMES
from plm_highway.sim2real.recording import SIMULATOR_VEHICLE, Recording, VehicleGeometry
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

MODELS = ("auto", "simulator", "kinematic", "single-track", "commonroad-st", "commonroad-mb")

# What "--effect NAME" means without "=value", and which parameter the value sets.
DEFAULT_EFFECT_VALUES = {
    "transport_delay": 0.20,  # delay_s
    "actuator_lag": 0.15,  # time_constant_s
    "tire_slip": SEED_PAPER_VEHICLE.understeer_gradient_rad_per_mps2,  # understeer gradient
    "steering_gain": 0.90,  # gain
    "steering_offset": 0.006,  # offset_rad
}
EFFECT_VALUE_MEANING = {
    "transport_delay": "delay_s",
    "actuator_lag": "time_constant_s",
    "tire_slip": "understeer_gradient_rad_per_mps2",
    "steering_gain": "gain",
    "steering_offset": "offset_rad",
}

SPEED_RANGE_MPS = (10.0, 30.0)
MAX_LAT_ACCEL_MPS2 = 4.0
SUBSTEPS = 10
LEAD_IN_S = 2.0  # inputs start before the recording so a delayed command has a past
# RK4 steps for CommonRoad's models (the multi-body model's wheel and suspension modes need ~5 ms).
COMMONROAD_STEP_S = {"commonroad-st": 0.002, "commonroad-mb": 0.005}


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


@dataclass(frozen=True)
class ConcealedEffects:
    """Terms on the steering command between the log and the wheels (neutral: none)."""

    delay_s: float = 0.0
    time_constant_s: float = 0.0
    gain: float = 1.0
    offset_rad: float = 0.0


# ----------------------------------------------------------------------------------------------
# 1. Driver inputs


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(math.pi * x)


def speed_profile(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Smooth speed changes between targets in [10, 30] m/s, at 0.5-1.5 m/s^2."""
    lo, hi = SPEED_RANGE_MPS
    speed = np.full(t_s.shape, rng.uniform(lo + 2, hi - 2))
    t = t_s[0] + rng.uniform(2.0, 8.0)
    current = speed[0]
    while t < t_s[-1]:
        target = rng.uniform(lo, hi)
        ramp_s = max(abs(target - current) / rng.uniform(0.5, 1.5), 1.0)
        blend = _smoothstep((t_s - t) / ramp_s)
        speed = np.where(t_s >= t, current + (target - current) * blend, speed)
        current = target
        t += ramp_s + rng.uniform(4.0, 12.0)
    return speed


def lateral_demand(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
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
            width, duration = rng.uniform(3.0, 3.7), rng.uniform(3.0, 5.0)
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
                  noise_mps2: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """(steering command [rad], speed [m/s]) on the time grid ``t_s``."""
    speed = speed_profile(t_s, rng)
    demand = lateral_demand(t_s, rng) + steering_noise(t_s, rng, noise_mps2)
    # Everyday driving stays below ~4 m/s^2, where tires are close to linear.
    demand = np.clip(demand, -MAX_LAT_ACCEL_MPS2, MAX_LAT_ACCEL_MPS2)
    curvature = demand / speed**2
    return np.arctan(wheelbase_m * curvature), speed


# ----------------------------------------------------------------------------------------------
# 2. Effects on the command


def apply_effects(t_s: np.ndarray, command_rad: np.ndarray, effects: ConcealedEffects) -> np.ndarray:
    """The front-wheel angle the car actually gets, on a fine uniform grid."""
    dt = t_s[1] - t_s[0]
    delta = effects.gain * command_rad + effects.offset_rad
    if effects.delay_s > 0:
        delta = np.interp(t_s - effects.delay_s, t_s, delta)
    if effects.time_constant_s > 0:
        alpha = math.exp(-dt / effects.time_constant_s)
        c = effects.time_constant_s / dt * (1 - alpha)
        b, a = [1 - c, c - alpha], [1.0, -alpha]
        zi = np.array([c * delta[0]])  # settled start: output = input = delta[0]
        delta, _ = lfilter(b, a, delta, zi=zi)
    return delta


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


def _single_track_fine(delta, speed, dt, car: SingleTrackParams, heading0):
    cf, cr, k2 = params_per_kg(car)
    vy, r = _single_track_fine_states(delta, speed, dt, cf, cr, car.cg_to_front_m, car.cg_to_rear_m, k2)
    heading = _cumtrapz(r, dt, heading0)
    vx_world = speed * np.cos(heading) - vy * np.sin(heading)
    vy_world = speed * np.sin(heading) + vy * np.cos(heading)
    x = _cumtrapz(vx_world, dt, 0.0)
    y = _cumtrapz(vy_world, dt, 0.0)
    lat_accel = np.gradient(vy, dt) + speed * r
    return x, y, heading, r, np.hypot(speed, vy), lat_accel


def _commonroad_fine(model: str, delta_target, speed_target, dt_fine, heading0, decimate: int):
    """CommonRoad ST or MB with a fast steering servo and a speed controller (RK4, python)."""
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
    geometry = VehicleGeometry(cg_to_front_m=p.a, cg_to_rear_m=p.b, mass_kg=p.m, yaw_inertia_kgm2=p.I_z,
                               source=f"{model} (BMW 320i, vehiclemodels parameters_vehicle2)")
    return (out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4], lat_accel), geometry, step


# ----------------------------------------------------------------------------------------------
# 4. Putting it together


def parse_effects(specs: Mapping[str, float | None]) -> tuple[ConcealedEffects, float | None]:
    """Effect name -> value (None: the default) into the command terms and the understeer gradient."""
    unknown = sorted(set(specs) - set(EFFECT_NAMES))
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)}")
    values = {k: (DEFAULT_EFFECT_VALUES[k] if v is None else float(v)) for k, v in specs.items()}
    effects = ConcealedEffects(
        delay_s=values.get("transport_delay", 0.0),
        time_constant_s=values.get("actuator_lag", 0.0),
        gain=values.get("steering_gain", 1.0),
        offset_rad=values.get("steering_offset", 0.0),
    )
    if effects.delay_s < 0 or effects.time_constant_s < 0 or effects.gain <= 0:
        raise ValueError("transport_delay and actuator_lag must be >= 0 and steering_gain > 0")
    return effects, values.get("tire_slip")


def seed_paper_car(understeer_rad_per_mps2: float | None) -> SingleTrackParams:
    """The seed paper's car, with the front stiffness changed to give the asked understeer."""
    car = SEED_PAPER_VEHICLE
    if understeer_rad_per_mps2 is None:
        return car
    cr = car.cornering_stiffness_rear / car.mass_kg
    cf = front_stiffness_for_understeer(understeer_rad_per_mps2, cr, car.cg_to_front_m, car.cg_to_rear_m)
    return replace(car, cornering_stiffness_front=cf * car.mass_kg)


def make_recording(
    effects: Mapping[str, float | None] | None = None,
    *,
    rng: np.random.Generator,
    duration_s: float = 120.0,
    sample_hz: float = 50.0,
    model: str = "auto",
    noise: NoiseLevels | None = None,
    with_yaw_rate: bool = True,
    with_lat_accel: bool = True,
) -> tuple[Recording, dict]:
    """A recording with concealed physics, and its answer key."""
    effects = dict(effects or {})
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; known: {', '.join(MODELS)}")
    if duration_s < 10:
        raise ValueError("duration must be at least 10 s")
    command_effects, understeer = parse_effects(effects)
    if model == "auto":
        model = "single-track" if "tire_slip" in effects else "kinematic"
    if "tire_slip" in effects and model != "single-track":
        raise ValueError(f"tire_slip is the single-track model's; model {model!r} has its own tires")
    if model == "simulator" and command_effects != ConcealedEffects():
        raise ValueError("the 'simulator' model is highway-env's own step: it takes no effects (use 'kinematic')")
    noise = NoiseLevels() if noise is None else noise

    n = round(duration_s * sample_hz) + 1
    dt = 1.0 / sample_hz
    t_rec = np.arange(n) * dt
    heading0 = rng.uniform(-math.pi, math.pi)

    if model == "single-track":
        car = seed_paper_car(understeer)
        geometry = VehicleGeometry(car.cg_to_front_m, car.cg_to_rear_m, car.mass_kg, car.yaw_inertia_kgm2,
                                   source="seed paper car (Sensors 2025, 25, 6251)")
    elif model.startswith("commonroad"):
        from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

        p = parameters_vehicle2()
        geometry = VehicleGeometry(p.a, p.b, p.m, p.I_z, source="BMW 320i")
    else:
        geometry = SIMULATOR_VEHICLE

    if model == "simulator":
        # Exactly highway-env: commands held over each step, forward Euler at the sample rate.
        command, speed = driver_inputs(t_rec, rng, geometry.wheelbase_m)
        xs, ys, hs = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, heading0), command[:-1], speed[:-1], dt,
                                               HIGHWAY_ENV_VEHICLE)
        r, _beta = kinematic_bicycle_rates(command, speed, HIGHWAY_ENV_VEHICLE)
        x, y, heading, yaw_rate, speed_true = xs, ys, hs, r, speed
        lat_accel = speed * r
    else:
        dt_fine = dt / SUBSTEPS
        n_lead = round(LEAD_IN_S / dt_fine)
        t_fine = (np.arange(n_lead + (n - 1) * SUBSTEPS + 1) - n_lead) * dt_fine
        command_fine, speed_fine = driver_inputs(t_fine, rng, geometry.wheelbase_m)
        delta_fine = apply_effects(t_fine, command_fine, command_effects)
        if model == "kinematic":
            fine = _kinematic_fine(delta_fine, speed_fine, dt_fine, geometry, heading0)
            step = 1
        elif model == "single-track":
            fine = _single_track_fine(delta_fine, speed_fine, dt_fine, car, heading0)
            step = 1
        else:
            fine, geometry, step = _commonroad_fine(model, delta_fine, speed_fine, dt_fine, heading0, SUBSTEPS)
        pick = np.arange(n_lead, len(t_fine), SUBSTEPS)
        idx = pick // step
        x, y, heading, yaw_rate, speed_true, lat_accel = (a[idx] for a in fine)
        command = command_fine[pick]
        x = x - x[0]
        y = y - y[0]

    rec = Recording(
        t_s=t_rec,
        steer_rad=np.round(command, 7),
        speed_mps=speed_true + noise.speed_mps * rng.standard_normal(n),
        x_m=x + noise.position_m * rng.standard_normal(n),
        y_m=y + noise.position_m * rng.standard_normal(n),
        heading_rad=heading + noise.heading_rad * rng.standard_normal(n),
        yaw_rate_radps=(yaw_rate + noise.yaw_rate_radps * rng.standard_normal(n)) if with_yaw_rate else None,
        lat_accel_mps2=(lat_accel + noise.lat_accel_mps2 * rng.standard_normal(n)) if with_lat_accel else None,
        vehicle=geometry,
        name="synthetic",
    )
    truth = {
        "model": model,
        "effects": truth_effects(effects, command_effects, understeer if model == "single-track" else None),
        "noise": asdict(noise),
        "vehicle": geometry.sidecar() if geometry != SIMULATOR_VEHICLE else "simulator",
        "duration_s": duration_s,
        "sample_hz": sample_hz,
    }
    return rec, truth


def truth_effects(specs: Mapping[str, float | None], command: ConcealedEffects,
                  understeer: float | None) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    if "transport_delay" in specs:
        out["transport_delay"] = {"delay_s": command.delay_s}
    if "actuator_lag" in specs:
        out["actuator_lag"] = {"time_constant_s": command.time_constant_s}
    if "steering_gain" in specs:
        out["steering_gain"] = {"gain": command.gain}
    if "steering_offset" in specs:
        out["steering_offset"] = {"offset_rad": command.offset_rad}
    if "tire_slip" in specs:
        car = seed_paper_car(understeer)
        out["tire_slip"] = {"understeer_gradient_rad_per_mps2": car.understeer_gradient_rad_per_mps2,
                            "cornering_stiffness_front": car.cornering_stiffness_front,
                            "cornering_stiffness_rear": car.cornering_stiffness_rear}
    return out
