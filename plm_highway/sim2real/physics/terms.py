"""Terms outside the library of effects, which residual discovery (:mod:`.discovery`) tries on top of
the library's best chain. Each is one :class:`~plm_highway.sim2real.physics.effect_spec.Effect` entry of
:data:`TERMS`, fitted by the library's own machinery; the library's candidate search never offers
them (it reads ``effects.EFFECTS`` only).

======================== ============================================= ====================================
term                     what it adds (before the delay)               parameters (public names)
======================== ============================================= ====================================
steering_dead_band       delta <- delta - clip(delta, -d, d)           ``dead_band_rad`` (half-width)
steering_backlash        a play operator of total width w              ``play_rad``
steering_saturation      delta <- clip(delta, -s, s)                   ``saturation_rad``
steering_asymmetry       delta <- delta + a |delta| (left 1+a, right   ``asymmetry``, ``left_right_ratio``
                         1-a)
speed_dependent_steering delta <- delta (1 + k (v - v_ref))            ``gain_slope_per_mps``,
                                                                       ``speed_ref_mps``
gyro_bias                recorded yaw_rate <- yaw rate + b             ``bias_radps``
======================== ============================================= ====================================

Function-valued terms (a delay that varies in time, a road bank that varies along the track) are
not entries: :mod:`.delay_track` and :mod:`.track_bank` fit them.
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.sim2real.physics.effect_spec import ChainField, ChainMove, Effect, FitContext, Parameter


def _no_synthesis(**kwargs) -> dict:
    """Discovery terms are not concealed by make-recording (the concealed benchmark has its own generator)."""
    return {"concealed": "not concealed by make-recording", "synth_defaults": {}, "synth_bounds": {}, "conceal": {}}


def _small_commands(ctx: FitContext) -> np.ndarray:
    """Dead-band half-widths and plays worth trying: from a twentieth of the typical command to the median."""
    lo = max(0.25 * ctx.steer_quantile(0.1), 2e-4)
    hi = max(ctx.steer_quantile(0.6), 2 * lo)
    return np.geomspace(lo, hi, 12)


def _large_commands(ctx: FitContext) -> np.ndarray:
    """End stops worth trying: between the median and the largest commands."""
    lo = max(ctx.steer_quantile(0.5), 1e-4)
    hi = max(ctx.steer_quantile(0.99), 1.5 * lo)
    return np.geomspace(lo, hi, 10)


# A working gyro's bias is a few hundredths of this.
MAX_GYRO_BIAS_RADPS = 0.05


def _deg(rad: float) -> float:
    return math.degrees(rad)


def _interval(ci: list[float], digits: int = 4) -> str:
    return f"95% {ci[0]:.{digits}f} to {ci[1]:.{digits}f}"


TERMS: dict[str, Effect] = {e.name: e for e in (
    Effect(
        name="steering_dead_band", term="delta <- delta - clip(delta, -d, d) (before the delay)",
        parameters=(Parameter("dead_band_rad", "rad", lambda ctx: (0.0, max(ctx.steer_quantile(0.9), 1e-3)), 0.001,
                              grid=_small_commands),),
        public_keys=("dead_band_rad",),
        fingerprint="small corrections do nothing: the yaw rate answers large steering and ignores small, in "
                    "both directions",
        chain_fields=(ChainField("dead_band_rad", 0.0),),
        set_params=lambda v, ctx: {"dead_band_rad": v["dead_band_rad"]},
        read_params=lambda p, ctx: {"dead_band_rad": p.dead_band_rad},
        report=lambda p, ctx: {"dead_band_rad": p.dead_band_rad},
        sentence=lambda p, ci: (f"the steering has a dead band of +-{p['dead_band_rad']:.4f} rad "
                                f"(+-{_deg(p['dead_band_rad']):.2f} deg; {_interval(ci['dead_band_rad'])}) around the "
                                "centre: smaller commands do not move the wheels"),
        doubts=lambda p, ctx: [f"a dead band of +-{p['dead_band_rad']:.4f} rad is over half the median command "
                               f"({ctx.steer_quantile(0.5):.4f} rad): the car could hardly steer"]
        if p["dead_band_rad"] > 0.5 * ctx.steer_quantile(0.5) else [],
        **_no_synthesis(),
    ),
    Effect(
        name="steering_backlash", term="a play operator: the wheels follow only once the command has crossed the play",
        parameters=(Parameter("play_rad", "rad", lambda ctx: (0.0, max(2 * ctx.steer_quantile(0.9), 2e-3)), 0.001,
                              grid=lambda ctx: 2 * _small_commands(ctx)),),
        public_keys=("play_rad",),
        fingerprint="after every reversal the wheels wait: a lag that depends on the amplitude, not the frequency, "
                    "and none in a held turn",
        chain_fields=(ChainField("play_rad", 0.0),),
        set_params=lambda v, ctx: {"play_rad": v["play_rad"]},
        read_params=lambda p, ctx: {"play_rad": p.play_rad},
        report=lambda p, ctx: {"play_rad": p.play_rad},
        sentence=lambda p, ci: (f"the steering has {p['play_rad']:.4f} rad ({_deg(p['play_rad']):.2f} deg; "
                                f"{_interval(ci['play_rad'])}) of free play (backlash): after a reversal the wheels "
                                "wait until the command has crossed it"),
        doubts=lambda p, ctx: [f"a play of {p['play_rad']:.4f} rad exceeds the median command "
                               f"({ctx.steer_quantile(0.5):.4f} rad)"] if p["play_rad"] > ctx.steer_quantile(0.5) else [],
        **_no_synthesis(),
    ),
    Effect(
        name="steering_saturation", term="delta <- clip(delta, -s, s) (end stops or a limited actuator)",
        parameters=(Parameter("saturation_rad", "rad", lambda ctx: (0.2 * max(ctx.steer_quantile(0.5), 1e-4),
                                                                    10 * max(ctx.steer_quantile(0.99), 1e-3)),
                              0.002, grid=_large_commands),),
        public_keys=("saturation_rad",),
        fingerprint="the yaw rate stops growing with the steering above one angle, in both directions and at every "
                    "speed",
        chain_fields=(ChainField("saturation_rad", math.inf),),
        set_params=lambda v, ctx: {"saturation_rad": v["saturation_rad"]},
        read_params=lambda p, ctx: {"saturation_rad": p.saturation_rad},
        report=lambda p, ctx: {"saturation_rad": p.saturation_rad},
        sentence=lambda p, ci: (f"the wheels stop at +-{p['saturation_rad']:.4f} rad (+-{_deg(p['saturation_rad']):.2f}"
                                f" deg; {_interval(ci['saturation_rad'])}): larger commands are clipped"),
        doubts=lambda p, ctx: [f"end stops at {p['saturation_rad']:.4f} rad would clip most commands "
                               f"(median {ctx.steer_quantile(0.5):.4f} rad)"]
        if p["saturation_rad"] < ctx.steer_quantile(0.5) else [],
        **_no_synthesis(),
    ),
    Effect(
        name="steering_asymmetry", term="delta <- delta + a |delta| (left commands 1 + a, right ones 1 - a)",
        parameters=(Parameter("asymmetry", "1", (-0.6, 0.6), 0.02, linear=True,
                              move=ChainMove("asymmetry", 1e-3, (-0.6, 0.6))),),
        public_keys=("asymmetry", "left_right_ratio"),
        fingerprint="left and right turns of the same command give different yaw rates, at every speed",
        chain_fields=(ChainField("asymmetry", 0.0),),
        set_params=lambda v, ctx: {"asymmetry": v["asymmetry"]},
        read_params=lambda p, ctx: {"asymmetry": p.asymmetry},
        report=lambda p, ctx: {"asymmetry": p.asymmetry,
                               "left_right_ratio": (1 + p.asymmetry) / max(1 - p.asymmetry, 1e-9)},
        sentence=lambda p, ci: (f"the steering is asymmetric: the wheels turn {p['left_right_ratio']:.3f} times as far "
                                f"left as right for the same command ({_interval(ci['left_right_ratio'], 3)}; "
                                f"left {1 + p['asymmetry']:.3f}x, right {1 - p['asymmetry']:.3f}x)"),
        **_no_synthesis(),
    ),
    Effect(
        name="speed_dependent_steering", term="delta <- delta (1 + k (v - v_ref))",
        parameters=(Parameter("speed_gain_slope", "1/(m/s)", (-0.1, 0.1), 0.002, linear=True,
                              move=ChainMove("speed_gain_slope", 1e-4, (-0.1, 0.1))),),
        public_keys=("gain_slope_per_mps", "speed_ref_mps"),
        fingerprint="the yaw gain changes linearly with speed, also in small steady turns (tire slip bends it "
                    "only with lateral acceleration and as u/(L + K u^2))",
        chain_fields=(ChainField("speed_gain_slope", 0.0), ChainField("speed_ref_mps", 0.0)),
        set_params=lambda v, ctx: {"speed_gain_slope": v["speed_gain_slope"], "speed_ref_mps": ctx.speed_median_mps},
        read_params=lambda p, ctx: {"speed_gain_slope": p.speed_gain_slope},
        report=lambda p, ctx: {"gain_slope_per_mps": p.speed_gain_slope, "speed_ref_mps": p.speed_ref_mps},
        sentence=lambda p, ci: (f"the steering ratio changes with speed: the wheels turn "
                                f"{100 * p['gain_slope_per_mps']:+.2f}% more per m/s "
                                f"({_interval([100 * c for c in ci['gain_slope_per_mps']], 2)}%) around "
                                f"{p['speed_ref_mps']:.1f} m/s"),
        **_no_synthesis(),
    ),
    Effect(
        name="gyro_bias", term="recorded yaw_rate <- yaw rate + b (the gyro only)",
        parameters=(Parameter("gyro_bias_radps", "rad/s", (-0.5, 0.5), 0.002, linear=True,
                              move=ChainMove("gyro_bias_radps", 1e-4, (-0.5, 0.5))),),
        public_keys=("bias_radps",),
        fingerprint="the gyro is off by the same amount at every speed and steering; the heading and the "
                    "positions are not (a steering offset would grow with speed and move them too)",
        chain_fields=(ChainField("gyro_bias_radps", 0.0, gyro_only=True),),
        set_params=lambda v, ctx: {"gyro_bias_radps": v["gyro_bias_radps"]},
        read_params=lambda p, ctx: {"gyro_bias_radps": p.gyro_bias_radps},
        report=lambda p, ctx: {"bias_radps": p.gyro_bias_radps},
        sentence=lambda p, ci: (f"the gyro reads {p['bias_radps']:+.4f} rad/s ({_deg(p['bias_radps']):+.3f} deg/s; "
                                f"{_interval(ci['bias_radps'])}) off at every speed: a sensor bias"),
        doubts=lambda p, ctx: [f"a gyro bias of {p['bias_radps']:+.3f} rad/s is over {MAX_GYRO_BIAS_RADPS} rad/s "
                               "(a working gyro's is a few hundredths of that)"]
        if abs(p["bias_radps"]) > MAX_GYRO_BIAS_RADPS else [],
        needs_channel="yaw_rate",
        **_no_synthesis(),
    ),
)}
