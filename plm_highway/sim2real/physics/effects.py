"""The library of physics a kinematic-bicycle simulator leaves out: one registry.

Each candidate effect inserts one physical term into the model chain (:mod:`.chain`),

    command -> calibration (gain, offset) -> transport delay -> servo (first-order lag, rate limit)
            -> vehicle (kinematic | linear tires | saturating tires; road bank) -> sensors (late gyro)

and every effect is one entry of :data:`EFFECTS`: its parameters (units, bounds, the values tried
before polishing), the chain parameters (:class:`~plm_highway.sim2real.physics.chain.EffectParams` fields)
it sets, the public parameter names it reports, its fingerprint, how ``make-recording`` conceals
it, and its sentence in a summary. ``selection``, ``diagnose`` and ``synth`` read only this table,
and the parameter records are built from it (:data:`ChainParams`, :data:`EffectParams`,
:data:`CHAIN_DTYPE`, and make-recording's concealed fields): adding an effect that the chain can
already express touches one entry; a new kind of physics also adds its term to the kernels
(:func:`~plm_highway.sim2real.physics.chain.simulate_chain`), which read the fields by name, and its
concealment stage (the ``concealed_*`` functions at the end, which make-recording composes). Tools that
move a parameter reach it here too: the delay helpers (:func:`later_by`, :func:`delay_estimates`) and
the variance coordinate's :class:`~.effect_spec.Scatter` (:func:`scatter_of`).

=================== ============================================= ============================================
effect              term                                          parameters (public names)
=================== ============================================= ============================================
transport_delay     delta(t) <- delta(t - delay)                  ``delay_s``
actuator_lag        tau delta' = delta_cmd - delta                ``time_constant_s``
tire_slip           kinematic -> single-track, linear tires       ``understeer_gradient_rad_per_mps2`` (+
                                                                  ``cornering_stiffness_front/_rear`` [N/rad])
steering_gain       delta <- gain delta                           ``gain``
steering_offset     delta <- delta + offset                       ``offset_rad``
steering_rate_limit |delta'| <= max_rate                          ``max_rate_radps``
tire_saturation     magic-formula tires with a friction peak      ``friction_coefficient`` (+ tire_slip's)
sensor_delay        recorded yaw_rate(t) <- yaw rate(t - delay)   ``delay_s`` (the gyro only)
road_bank           vy' += g sin(bank) (with tire slip)           ``bank_rad``
delay_jitter        delta(t) <- delta(t - delay - jitter(t))      ``delay_s``, ``jitter_s`` (std)
=================== ============================================= ============================================

All parameters at their neutral values give the simulator's model exactly: the plain model is one
point of every candidate's family.
"""

from __future__ import annotations

import math
from collections import ChainMap
from dataclasses import replace

import numpy as np

from plm_highway.sim2real.physics.chain import _servo, simulate
from plm_highway.sim2real.physics.effect_spec import ChainField, ChainMove, Effect, FitContext, Parameter, Scatter, pm
from plm_highway.sim2real.physics.records import (
    fit_record,
    kernel_record,
    merged_fields,
    structured_dtype,
)
from plm_highway.sim2real.physics.terms import TERMS
from plm_highway.vehicle.single_track import understeer_gradient
from plm_highway.vehicle.tires import GRAVITY_MPS2

# Axle cornering stiffness per unit mass [N/rad/kg]: road cars ~30-80, race cars a few hundred.
MAX_STIFFNESS_PER_KG = 1000.0


def front_stiffness_from(understeer: float, cr: float, a: float, b: float) -> float:
    """Front ``Cf/m`` for understeer gradient K and rear ``Cr/m`` (clipped to a physical range)."""
    denominator = understeer * (a + b) + a / cr
    if denominator <= b / MAX_STIFFNESS_PER_KG:
        return MAX_STIFFNESS_PER_KG
    return max(b / denominator, 1.0)


# Chain fields more than one effect sets. Absent tires (None) are the kinematic bicycle.
DELAY = ChainField("delay_s", 0.0)
# The delay's jitter (its standard deviation): a variance coordinate, fitted from the scatter it leaves.
JITTER = ChainField("jitter_s", 0.0)
# The public name every delay is reported under: the steering's, its jitter's mean and the gyro's.
DELAY_KEY = "delay_s"
TIRES = (ChainField("cf_per_kg", 0.0, absent_unless="cf_per_kg"), ChainField("cr_per_kg", 0.0, absent_unless="cf_per_kg"))
FRICTION = ChainField("friction_coefficient", math.inf)  # inf: linear tires
# make-recording's tires: the understeer gradient it gives the car (None: the car's own tires).
CONCEALED_UNDERSTEER = ChainField("understeer_rad_per_mps2", None)

UNDERSTEER_GRID = (-0.001, 0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006, 0.009, 0.014, 0.02)
REAR_STIFFNESS_GRID_PER_KG = (25.0, 70.0, 200.0)


def _tire_grid(ctx: FitContext, understeer=UNDERSTEER_GRID, rear=REAR_STIFFNESS_GRID_PER_KG) -> np.ndarray:
    points = []
    for k in understeer:
        for cr in rear:
            cf = front_stiffness_from(k, cr, ctx.a_m, ctx.b_m)
            if 1.0 < cf < MAX_STIFFNESS_PER_KG:
                points.append((k, math.log(cr)))
    return np.array(points)


def _tire_set(v: dict, ctx: FitContext) -> dict:
    cr = math.exp(v["log_cr"])
    return {"cf_per_kg": front_stiffness_from(v["understeer"], cr, ctx.a_m, ctx.b_m), "cr_per_kg": cr}


def _tire_read(p, ctx: FitContext) -> dict:
    return {"understeer": understeer_gradient(p.cf_per_kg, p.cr_per_kg, ctx.a_m, ctx.b_m),
            "log_cr": math.log(p.cr_per_kg)}


def _tire_report(p, ctx: FitContext) -> dict:
    out = {"understeer_gradient_rad_per_mps2": understeer_gradient(p.cf_per_kg, p.cr_per_kg, ctx.a_m, ctx.b_m)}
    if ctx.inertia_known and ctx.mass_kg is not None:
        out["cornering_stiffness_front"] = p.cf_per_kg * ctx.mass_kg
        out["cornering_stiffness_rear"] = p.cr_per_kg * ctx.mass_kg
    return out


def _tire_sentence(params: dict, ci: dict) -> str:
    k = params["understeer_gradient_rad_per_mps2"]
    text = (f"the tires slip: understeer gradient {k:.5f} +- {pm(ci['understeer_gradient_rad_per_mps2']):.5f} "
            f"rad/(m/s^2) ({math.degrees(k) * GRAVITY_MPS2:.2f} deg/g)")
    if "cornering_stiffness_front" in params:
        text += (f", cornering stiffness front {params['cornering_stiffness_front']:,.0f} "
                 f"+- {pm(ci['cornering_stiffness_front']):,.0f} N/rad, rear "
                 f"{params['cornering_stiffness_rear']:,.0f} +- {pm(ci['cornering_stiffness_rear']):,.0f} N/rad")
    return text


UNDERSTEER = Parameter("understeer", "rad/(m/s^2)", (-0.003, 0.05), 0.001)
LOG_CR = Parameter("log_cr", "log(N/rad/kg)", (math.log(5.0), math.log(MAX_STIFFNESS_PER_KG)), 1.0)
DELAY_GRID_S = tuple(np.round(np.arange(0.0, 0.601, 0.02), 3))
LAG_GRID_S = (0.02, 0.04, 0.06, 0.08, 0.10, 0.13, 0.16, 0.20, 0.25, 0.30, 0.40, 0.50, 0.60)


def _rate_grid(ctx: FitContext) -> np.ndarray:
    """Rate limits between the median and the largest commanded steering rates: a limit above every
    commanded rate changes nothing, one far below the median is a different car."""
    lo = max(ctx.steer_rate_median_radps, 1e-4)
    hi = max(ctx.steer_rate_max_radps, 1.5 * lo)
    return np.geomspace(lo, hi, 8)


def _rate_bounds(ctx: FitContext) -> tuple[float, float]:
    lo = max(ctx.steer_rate_median_radps, 1e-4)
    return math.log(0.3 * lo), math.log(3.0 * max(ctx.steer_rate_max_radps, 1.5 * lo))


def _friction_floor(ctx: FitContext) -> float:
    """The car reached this lateral acceleration: its friction coefficient is at least this (in g)."""
    return max(ctx.max_lat_accel_mps2 / GRAVITY_MPS2, 0.02)


def _saturation_grid(ctx: FitContext) -> np.ndarray:
    tires = _tire_grid(ctx, understeer=(0.0, 0.001, 0.002, 0.004, 0.009), rear=(25.0, 70.0))
    mus = _friction_floor(ctx) * np.array([1.05, 1.2, 1.45, 1.9, 2.8])
    return np.array([(k, c, m) for k, c in tires for m in mus])


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect(
        name="transport_delay", term="delta(t) <- delta(t - delay)",
        parameters=(Parameter("delay_s", "s", (0.0, 0.8), 0.05, grid=DELAY_GRID_S),),
        public_keys=("delay_s",),
        fingerprint="phase lag growing linearly with steering frequency, gain 1, independent of speed; "
                    "the heading and the position lag as much as the yaw rate",
        concealed="the steering command is shifted by the delay (fine grid, linear interpolation)",
        synth_defaults={"delay_s": 0.20}, synth_bounds={"delay_s": (0.0, 1.0)},
        conceal={"delay_s": DELAY}, chain_fields=(DELAY,),
        set_params=lambda v, ctx: {"delay_s": v["delay_s"]},
        read_params=lambda p, ctx: {"delay_s": p.delay_s},
        report=lambda p, ctx: {"delay_s": p.delay_s},
        sentence=lambda p, ci: f"the car steers late by {p['delay_s']:.3f} s +- {pm(ci['delay_s']):.3f} s "
                               "(transport delay)",
        group="delay", tolerances={"delay_s": (0.010, 0.10)},
        separated_from={
            "actuator_lag": "quick steering (above ~1 Hz) separates them: a delay keeps the yaw-rate amplitude, "
                            "a lag cuts it",
            "tire_slip": "steady turns at very different speeds separate them: only tire slip changes the steady "
                         "yaw rate with speed",
            "sensor_delay": "a recorded heading separates them: a late car turns its heading late too, a late gyro "
                            "does not",
        },
    ),
    Effect(
        name="actuator_lag", term="tau delta' = delta_cmd - delta",
        parameters=(Parameter("time_constant_s", "s", (0.0, 0.8), 0.05, grid=LAG_GRID_S),),
        public_keys=("time_constant_s",),
        fingerprint="gain rolling off above 1/(2 pi tau), phase lag at most 90 deg",
        tolerances={"time_constant_s": (0.0, 0.20)},
        concealed="a first-order servo between the command and the wheels (exact for a piecewise-linear input)",
        synth_defaults={"time_constant_s": 0.15}, synth_bounds={"time_constant_s": (0.0, 2.0)},
        conceal={"time_constant_s": ChainField("time_constant_s", 0.0)},
        chain_fields=(ChainField("time_constant_s", 0.0),),
        set_params=lambda v, ctx: {"time_constant_s": v["time_constant_s"]},
        read_params=lambda p, ctx: {"time_constant_s": p.time_constant_s},
        report=lambda p, ctx: {"time_constant_s": p.time_constant_s},
        sentence=lambda p, ci: (f"the steering follows the command like a first-order actuator with time constant "
                                f"{p['time_constant_s']:.3f} s +- {pm(ci['time_constant_s']):.3f} s"),
        separated_from={
            "tire_slip": "steady turns at very different speeds separate them: only tire slip changes the steady "
                         "yaw rate with speed",
            "steering_rate_limit": "small quick corrections separate them: a lag slows every change, a rate limit "
                                   "only the large fast ones",
        },
    ),
    Effect(
        name="tire_slip", term="kinematic bicycle -> dynamic single-track with linear tires",
        parameters=(UNDERSTEER, LOG_CR),
        public_keys=("understeer_gradient_rad_per_mps2", "cornering_stiffness_front", "cornering_stiffness_rear"),
        fingerprint="steady yaw gain u/(L + K u^2) falling with speed and lateral acceleration, speed-dependent lag",
        concealed="the car is a dynamic single-track model (RK4 on the fine grid, exact slip angles); the value "
                  "sets the understeer gradient through the front cornering stiffness (default NaN: the car's "
                  "own tires)",
        synth_defaults={"understeer_gradient_rad_per_mps2": math.nan},
        synth_bounds={"understeer_gradient_rad_per_mps2": (-0.002, 0.02)},
        conceal={"understeer_gradient_rad_per_mps2": CONCEALED_UNDERSTEER}, chain_fields=TIRES,
        set_params=_tire_set, read_params=_tire_read, report=_tire_report, sentence=_tire_sentence,
        group="tires", joint_grid=_tire_grid, tolerances={"understeer_gradient_rad_per_mps2": (0.0, 0.20)},
        separated_from={"steering_gain": "the same turn at 10 and at 30 m/s separates them: a gain error is the same "
                                         "at every speed, understeer grows with speed"},
    ),
    Effect(
        name="steering_gain", term="delta <- gain delta",
        parameters=(Parameter("gain", "1", (0.2, 5.0), 0.1, linear=True, move=ChainMove("gain", 1e-3, (0.2, 5.0)),
                              neutral=1.0),),
        public_keys=("gain",),
        fingerprint="constant ratio between observed and expected yaw rate", tolerances={"gain": (0.0, 0.03)},
        concealed="the command is multiplied by the gain before the wheels",
        synth_defaults={"gain": 0.90}, synth_bounds={"gain": (0.2, 5.0)},
        conceal={"gain": ChainField("gain", 1.0)}, chain_fields=(ChainField("gain", 1.0),),
        set_params=lambda v, ctx: {"gain": v["gain"]},
        read_params=lambda p, ctx: {"gain": p.gain},
        report=lambda p, ctx: {"gain": p.gain},
        sentence=lambda p, ci: (f"the wheels turn {p['gain']:.3f} +- {pm(ci['gain']):.3f} times the commanded "
                                "angle (steering gain)"),
        separated_from={"steering_offset": "driving straight separates them: only an offset turns the car with the "
                                           "wheel centred"},
    ),
    Effect(
        name="steering_offset", term="delta <- delta + offset",
        parameters=(Parameter("offset_rad", "rad", (-0.2, 0.2), 0.005, linear=True,
                              move=ChainMove("offset_rad", 1e-4, (-0.2, 0.2))),),
        public_keys=("offset_rad",),
        fingerprint="constant yaw-rate error proportional to speed", tolerances={"offset_rad": (0.002, 0.0)},
        concealed="a constant is added to the command before the wheels",
        synth_defaults={"offset_rad": 0.006}, synth_bounds={"offset_rad": (-0.2, 0.2)},
        conceal={"offset_rad": ChainField("offset_rad", 0.0)}, chain_fields=(ChainField("offset_rad", 0.0),),
        set_params=lambda v, ctx: {"offset_rad": v["offset_rad"]},
        read_params=lambda p, ctx: {"offset_rad": p.offset_rad},
        report=lambda p, ctx: {"offset_rad": p.offset_rad},
        sentence=lambda p, ci: (f"the steering is offset by {p['offset_rad']:+.4f} +- {pm(ci['offset_rad']):.4f} "
                                f"rad ({math.degrees(p['offset_rad']):+.2f} deg): commanded straight, the car pulls "
                                f"{'left' if p['offset_rad'] > 0 else 'right'}"),
        separated_from={"road_bank": "a recorded position separates them: on a bank the car crabs sideways (course "
                                     "and heading differ), with an offset it does not"},
    ),
    Effect(
        name="steering_rate_limit", term="|delta'| <= max_rate (after the servo)",
        parameters=(Parameter("log_rate", "log(rad/s)", _rate_bounds, 0.1, grid=lambda ctx: np.log(_rate_grid(ctx))),),
        public_keys=("max_rate_radps",), tolerances={"max_rate_radps": (0.0, 0.15)},
        fingerprint="the wheels fall behind only when the command changes faster than the limit: the error sits "
                    "at the peaks of the steering rate and grows with amplitude x frequency; slow or small "
                    "corrections pass unchanged (a delay or a lag would shift them too)",
        concealed="the front-wheel angle moves at most max_rate towards the command (fine grid)",
        synth_defaults={"max_rate_radps": 0.12}, synth_bounds={"max_rate_radps": (1e-3, 50.0)},
        conceal={"max_rate_radps": ChainField("max_rate_radps", math.inf)},
        chain_fields=(ChainField("max_rate_radps", math.inf),),
        set_params=lambda v, ctx: {"max_rate_radps": math.exp(v["log_rate"])},
        read_params=lambda p, ctx: {"log_rate": math.log(p.max_rate_radps)},
        report=lambda p, ctx: {"max_rate_radps": p.max_rate_radps},
        sentence=lambda p, ci: (f"the wheels cannot turn faster than {p['max_rate_radps']:.3f} rad/s "
                                f"(95% {ci['max_rate_radps'][0]:.3f}-{ci['max_rate_radps'][1]:.3f}; "
                                f"{math.degrees(p['max_rate_radps']):.1f} deg/s at the wheels): steering rate limit"),
        separated_from={"transport_delay": "small quick corrections separate them: a delay shifts every change, a "
                                           "rate limit only the large fast ones"},
    ),
    Effect(
        name="tire_saturation", term="single-track with magic-formula tires: F = mu Fz sin(1.3 atan(B alpha))",
        parameters=(UNDERSTEER, LOG_CR,
                    Parameter("friction_coefficient", "1", lambda ctx: (0.95 * _friction_floor(ctx), 5.0), 0.05)),
        public_keys=("friction_coefficient", "understeer_gradient_rad_per_mps2", "cornering_stiffness_front",
                     "cornering_stiffness_rear"),
        fingerprint="like tire slip at low lateral acceleration, but the yaw gain collapses as |lateral "
                    "acceleration| nears mu g: the error grows faster than linearly with lateral acceleration, "
                    "the same on both sides",
        concealed="the car is a single-track model with magic-formula tires (shape 1.3, static axle loads); "
                  "the value is the friction coefficient (default 0.4, a wet road: everyday manoeuvres reach "
                  "the limit), the linear part the car's own tires",
        synth_defaults={"friction_coefficient": 0.4, "understeer_gradient_rad_per_mps2": math.nan},
        synth_bounds={"friction_coefficient": (0.05, 3.0), "understeer_gradient_rad_per_mps2": (-0.002, 0.02)},
        conceal={"friction_coefficient": FRICTION, "understeer_gradient_rad_per_mps2": CONCEALED_UNDERSTEER},
        chain_fields=(*TIRES, FRICTION),
        set_params=lambda v, ctx: _tire_set(v, ctx) | {"friction_coefficient": v["friction_coefficient"]},
        read_params=lambda p, ctx: _tire_read(p, ctx) | {"friction_coefficient": p.friction_coefficient},
        report=lambda p, ctx: {"friction_coefficient": p.friction_coefficient} | _tire_report(p, ctx),
        sentence=lambda p, ci: (f"the tires saturate: friction coefficient {p['friction_coefficient']:.3f} +- "
                                f"{pm(ci['friction_coefficient']):.3f} (peak lateral acceleration "
                                f"{p['friction_coefficient'] * GRAVITY_MPS2:.1f} m/s^2); "
                                + _tire_sentence(p, ci).replace("the tires slip: ", "linear part: ")),
        group="tires", refines="tire_slip",
        tolerances={"friction_coefficient": (0.0, 0.10), "understeer_gradient_rad_per_mps2": (0.0, 0.20)},
        joint_grid=_saturation_grid,
        separated_from={"tire_slip": "harder cornering separates them: saturation appears near the friction limit"},
    ),
    Effect(
        name="sensor_delay", term="recorded yaw_rate(t) <- yaw rate(t - delay); heading and position on time",
        parameters=(Parameter("sensor_delay_s", "s", (0.0, 0.8), 0.05, grid=DELAY_GRID_S),),
        public_keys=("delay_s",),
        fingerprint="the recorded yaw rate lags the steering, but the recorded heading and position do not: a "
                    "late or filtered gyro channel, not a late car",
        concealed="the yaw_rate column is sampled late by the delay; heading and position are on time",
        synth_defaults={"delay_s": 0.10}, synth_bounds={"delay_s": (0.0, 1.0)},
        conceal={"delay_s": ChainField("sensor_delay_s", 0.0)},
        chain_fields=(ChainField("sensor_delay_s", 0.0, gyro_only=True),),
        set_params=lambda v, ctx: {"sensor_delay_s": v["sensor_delay_s"]},
        read_params=lambda p, ctx: {"sensor_delay_s": p.sensor_delay_s},
        report=lambda p, ctx: {"delay_s": p.sensor_delay_s},
        sentence=lambda p, ci: (f"the recorded yaw rate is {p['delay_s']:.3f} s +- {pm(ci['delay_s']):.3f} s late "
                                "while heading and position are not (a late or filtered gyro channel)"),
        needs_channel="yaw_rate",
    ),
    Effect(
        name="road_bank", term="vy' += g sin(bank) (needs tires: a kinematic bicycle cannot slip sideways)",
        parameters=(Parameter("bank_rad", "rad", (-0.3, 0.3), 0.01, linear=True,
                              move=ChainMove("bank_accel_mps2", 1e-3,
                                             (GRAVITY_MPS2 * math.sin(-0.3), GRAVITY_MPS2 * math.sin(0.3)))),),
        public_keys=("bank_rad",),
        fingerprint="a constant lateral force: the car crabs sideways (course minus heading shifts by a "
                    "speed-independent angle set by the rear tires) and pulls like a steering offset of "
                    "K g sin(bank); it needs a recorded position to tell from an offset",
        concealed="the single-track car drives on a cross slope: g sin(bank) is added to its lateral "
                  "acceleration (positive: the road falls to the left)",
        synth_defaults={"bank_rad": 0.05}, synth_bounds={"bank_rad": (-0.3, 0.3)},
        conceal={"bank_rad": ChainField("bank_rad", 0.0)}, chain_fields=(ChainField("bank_accel_mps2", 0.0),),
        set_params=lambda v, ctx: {"bank_accel_mps2": GRAVITY_MPS2 * math.sin(v["bank_rad"])},
        read_params=lambda p, ctx: {"bank_rad": math.asin(max(-1.0, min(1.0, p.bank_accel_mps2 / GRAVITY_MPS2)))},
        report=lambda p, ctx: {"bank_rad": math.asin(max(-1.0, min(1.0, p.bank_accel_mps2 / GRAVITY_MPS2)))},
        sentence=lambda p, ci: (f"the road is banked by {p['bank_rad']:+.4f} +- {pm(ci['bank_rad']):.4f} rad "
                                f"({math.degrees(p['bank_rad']):+.2f} deg; it falls to the "
                                f"{'left' if p['bank_rad'] > 0 else 'right'}): the car crabs downhill"),
        needs_group="tires", tolerances={"bank_rad": (0.005, 0.15)},
    ),
    Effect(
        name="delay_jitter", term="delta(t) <- delta(t - delay - jitter(t)), jitter white with std jitter_s",
        parameters=(Parameter("delay_s", "s", (0.0, 0.8), 0.05, grid=DELAY_GRID_S),
                    Parameter("jitter_s", "s", (0.0, 0.5), 0.01, linear=True, scatter=Scatter(JITTER.name, of=DELAY.name))),
        public_keys=("delay_s", "jitter_s"),
        fingerprint="a transport delay whose error variance grows with the square of the steering rate: "
                    "the mean response is the delay's, the residual scatter is jitter x d(yaw rate)/dt",
        concealed="each sample's command arrives late by delay + jitter, the jitter drawn white per sample "
                  "(Gaussian, clipped at zero delay)",
        synth_defaults={"jitter_s": 0.03, "delay_s": 0.10}, synth_bounds={"jitter_s": (0.0, 0.3), "delay_s": (0.0, 1.0)},
        conceal={"jitter_s": JITTER, "delay_s": DELAY}, chain_fields=(DELAY, JITTER),
        set_params=lambda v, ctx: {"delay_s": v["delay_s"], "jitter_s": v["jitter_s"]},
        read_params=lambda p, ctx: {"delay_s": p.delay_s, "jitter_s": p.jitter_s},
        report=lambda p, ctx: {"delay_s": p.delay_s, "jitter_s": p.jitter_s},
        sentence=lambda p, ci: (f"the car steers late by {p['delay_s']:.3f} s +- {pm(ci['delay_s']):.3f} s, and the "
                                f"delay jitters by {p['jitter_s']:.3f} s +- {pm(ci['jitter_s']):.3f} s (std): the "
                                "error scatter grows with the steering rate"),
        group="delay", refines="transport_delay", tolerances={"delay_s": (0.010, 0.10), "jitter_s": (0.005, 0.25)},
        varies_noise=True,
        separated_from={"transport_delay": "fast steering separates them: only a jittering delay scatters the yaw "
                                           "rate in proportion to the steering rate"},
    ),
)}

EFFECT_NAMES = tuple(EFFECTS)
# Parameter keys each effect reports (other tools read these names).
EFFECT_PARAM_KEYS = {name: e.public_keys for name, e in EFFECTS.items()}
# Free parameters each effect adds to the fit (its complexity).
EFFECT_DOF = {name: e.dof for name, e in EFFECTS.items()}
EFFECT_FINGERPRINTS = {name: e.fingerprint for name, e in EFFECTS.items()}


def separating_text(a: str, b: str) -> str:
    """What drive would tell effect ``a`` from ``b`` ('' when the registry does not say)."""
    return SPECS[a].separated_from.get(b) or SPECS[b].separated_from.get(a) or ""


# Every entry a candidate may hold: the library's effects and the terms residual discovery tries.
SPECS = ChainMap(EFFECTS, TERMS)

# The parameter records, built from the fields the entries declare (in the entries' order).
CHAIN_FIELDS = merged_fields(f for spec in (*EFFECTS.values(), *TERMS.values()) for f in spec.chain_fields)
ChainParams = kernel_record("ChainParams", CHAIN_FIELDS, __name__)
ChainParams.__doc__ = "The chain's parameters as the numba kernels take them: named floats (``cf_per_kg`` 0: no tires)."
EffectParams = fit_record("EffectParams", CHAIN_FIELDS, ChainParams, __name__, """The simulator's model plus every
    effect and discovery term, as the entries of :data:`SPECS` set them; the defaults are the plain simulator.

    A field declared ``absent_unless`` is None while that part of the car is absent (no tires: the
    kinematic bicycle); ``chain()`` gives the kernels' :data:`ChainParams`, ``from_chain`` the way back.""")
# A grid of parameter sets is a structured array with one named float field per chain parameter.
CHAIN_DTYPE = structured_dtype(CHAIN_FIELDS)
# Fields that act on the recorded gyro only (the chain's simulation does not read them), at their neutral values.
GYRO_ONLY_NEUTRAL = {f.name: f.neutral for f in CHAIN_FIELDS if f.gyro_only}
# make-recording's concealed physics: the fields the effects' ``conceal`` maps set.
CONCEALED_FIELDS = merged_fields(f for e in EFFECTS.values() for f in e.conceal.values())


def chain_grid(params: list) -> np.ndarray:
    """Parameter sets (:data:`ChainParams`) as a structured array of :data:`CHAIN_DTYPE` (what grid kernels take)."""
    return np.array([tuple(p) for p in params], dtype=CHAIN_DTYPE)


def simulate_yaw_rate(steer, speed, dt, delay_s, tau_s, gain, offset_rad, cf, cr, a_m, b_m, k2, with_slip=True):
    """Yaw rate [rad/s] and slip angle [rad] for the five classic effects (cf = 0: kinematic): the reference Lesson 4's
    replay, delay and tire exercises are graded against."""
    params = EffectParams(delay_s=delay_s, time_constant_s=tau_s, gain=gain, offset_rad=offset_rad,
                          cf_per_kg=cf if cf > 0 else None, cr_per_kg=cr if cf > 0 else None)
    r, _, slip = simulate(steer, speed, dt, params, a_m, b_m, k2, with_slip=with_slip)
    return r, slip


def neutral_of(name: str) -> dict:
    """The chain fields entry ``name`` sets, at their neutral values: the chain without it."""
    return {f.name: (None if f.absent_unless else f.neutral) for f in SPECS[name].chain_fields}


def params_from(effects: tuple[str, ...], values: dict[str, float], ctx: FitContext):
    """EffectParams for a candidate from its fitted coordinates (keyed ``effect.parameter``)."""
    kwargs: dict = {}
    for name in effects:
        e = SPECS[name]
        kwargs |= e.set_params({p.name: values[f"{name}.{p.name}"] for p in e.parameters}, ctx)
    return EffectParams(**kwargs)


def coordinates_of(effects: tuple[str, ...], params, ctx: FitContext) -> dict[str, float]:
    out = {}
    for name in effects:
        for key, value in SPECS[name].read_params(params, ctx).items():
            out[f"{name}.{key}"] = float(value)
    return out


def effect_report(name: str, params, ctx: FitContext) -> dict[str, float]:
    """An effect's parameters under their fixed public names."""
    if name not in SPECS:
        raise KeyError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}, {', '.join(TERMS)}")
    return {k: float(v) for k, v in SPECS[name].report(params, ctx).items()}


def scatter_of(effects: tuple[str, ...]) -> Parameter | None:
    """The candidate's variance coordinate (the parameter with a ``scatter``); None when it has none."""
    return next((p for name in effects for p in SPECS[name].parameters if p.scatter is not None), None)


def moved(params, field: str, by: float):
    """``params`` with chain field ``field`` moved by ``by`` (a finite-difference step along it)."""
    return replace(params, **{field: getattr(params, field) + by})


def transport_delay_s(params) -> float:
    """The chain's transport delay: the field the steering's delay effects set."""
    return getattr(params, DELAY.name)


def later_by(params, step_s: float):
    """``params`` with the chain's transport delay longer by ``step_s``."""
    return moved(params, DELAY.name, step_s)


def without_scatter(params):
    """``params`` with every variance coordinate at its neutral value: the chain's mean, no random variation."""
    return replace(params, **{p.scatter.field: p.neutral for spec in SPECS.values() for p in spec.parameters
                              if p.scatter is not None})


def delay_estimates(estimates: dict[str, dict[str, float]]) -> dict[str, float]:
    """The delays [s] among public estimates (entry -> its public values), by entry."""
    return {name: values[DELAY_KEY] for name, values in estimates.items() if DELAY_KEY in values}


def acts_on_gyro(name: str) -> bool:
    """Whether entry ``name`` acts on the recorded gyro only (a late gyro, not a late car)."""
    return any(f.gyro_only for f in SPECS[name].chain_fields)


# make-recording's concealed physics, stage by stage in the chain's order (synth runs them on its fine
# time grid; ``c`` is a ``synth.ConcealedEffects``). They live beside the entries whose fields they read,
# so that a new kind of concealed physics is written here, not in the recording maker.


def concealed_calibration(c, command_rad: np.ndarray) -> np.ndarray:
    """steering_gain and steering_offset: the command scaled, then shifted, before the wheels."""
    return c.gain * command_rad + c.offset_rad


def delay_jitters(c) -> bool:
    """Whether the concealed delay jitters (it then draws from its own random stream)."""
    return c.jitter_s > 0


def concealed_delay(t_s: np.ndarray, delta_rad: np.ndarray, c, jitter_rng: np.random.Generator | None,
                    frame_s: float | None) -> np.ndarray:
    """transport_delay and delay_jitter: the wheels follow ``delta_rad`` late (linear interpolation on the
    uniform grid ``t_s``); a jittering delay draws one delay per recording frame (``frame_s``), clipped at 0."""
    if delay_jitters(c):
        frame = np.floor((t_s - t_s[0]) / frame_s).astype(int)
        delays = np.maximum(c.delay_s + c.jitter_s * jitter_rng.standard_normal(frame.max() + 1), 0.0)
        return np.interp(t_s - delays[frame], t_s, delta_rad)
    if c.delay_s > 0:
        return np.interp(t_s - c.delay_s, t_s, delta_rad)
    return delta_rad


def concealed_servo(delta_rad: np.ndarray, dt_s: float, c) -> np.ndarray:
    """actuator_lag and steering_rate_limit: a first-order servo whose output moves at most the rate limit."""
    if c.time_constant_s > 0 or math.isfinite(c.max_rate_radps):
        out = np.empty_like(delta_rad)
        _servo(np.ascontiguousarray(delta_rad), dt_s, c.time_constant_s, c.max_rate_radps, out)
        return out
    return delta_rad


def concealed_understeer(c) -> float | None:
    """tire_slip: the understeer gradient [rad/(m/s^2)] the car's tires are given (None: its own)."""
    return c.understeer_rad_per_mps2


def concealed_road(c) -> tuple[float, float]:
    """tire_saturation and road_bank: (the tires' friction coefficient, inf for linear tires; the road's
    bank [rad]) the single-track car drives with."""
    return c.friction_coefficient, c.bank_rad


def concealed_gyro_delay_s(c) -> float:
    """sensor_delay: how late the recorded yaw rate is sampled [s]."""
    return c.sensor_delay_s
