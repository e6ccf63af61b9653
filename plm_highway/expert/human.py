"""A human-like demonstrator: the expert's lane tracking, seen late and noisily, steered by a slow hand.

The paper's Base Model imitated a person at a racing wheel (Logitech G920). What makes a human's
steering different from :func:`~plm_highway.expert.controller.expert_steering`, and what this
demonstrator adds, in the order a command goes through it:

1. **Imperfect tracking** (perception): the driver holds a lateral position that wanders, i.e. the
   offset and heading the driver steers by carry a slowly varying error, an Ornstein-Uhlenbeck
   process with a correlation time of seconds, and the driver tracks loosely (lower natural
   frequency than the expert).
2. **Reaction delay**: the command decided now is applied ``reaction_delay_s`` later.
3. **Motor noise**: white noise on the command, per policy step.
4. **Bounded bandwidth**: the hand follows the command through a first-order lag
   (``hand_time_constant_s``) and a rate limit (``max_steering_rate_radps``, front-wheel angle).

Every random draw comes from the ``np.random.Generator`` the caller passes to :meth:`reset`, so a
run is reproducible from the caller's seed. Parameters are data (:class:`HumanParams`); each one's
source is in :data:`HUMAN_PARAM_SOURCES`.

Calibration targets: the spread of the paper's steering data (Table 1: std 0.177, quartiles -0.069
and 0.059, in units of 450 deg of steering wheel; with the 12:1 steering ratio of
:mod:`plm_highway.evaluation.protocol`, 0.177 is 0.116 rad at the front wheels), and, through the Base Model
that imitates this driver, the paper's BM degradation with latency. The tracking is the stiffest that keeps
the car on the train track with the paper conditions' 0.4 rad steering range; the recorded labels' std is
0.125 in the paper's unit. :func:`paper_units` converts; ``tests/test_expert_human.py`` states the band that
the labels are held to.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from plm_highway.expert.controller import ExpertParams, expert_steering
from plm_highway.vehicle.paper_units import PAPER_FULL_SCALE_DEG, PAPER_STEERING_RATIO


@dataclass(frozen=True)
class HumanParams:
    reaction_delay_s: float = 0.15
    hand_time_constant_s: float = 0.08
    max_steering_rate_radps: float = 1.0  # front-wheel angle rate
    natural_frequency_radps: float = 2.0
    damping_ratio: float = 0.9
    offset_noise_m: float = 0.2  # stationary std of the wander in the lateral position the driver steers by
    heading_noise_rad: float = 0.02  # stationary std of the heading-error misjudgement
    wander_time_constant_s: float = 2.0  # correlation time of both
    motor_noise_rad: float = 0.03  # std of the per-step command noise, front-wheel angle
    max_steering_rad: float = 0.4  # the car's full scale (front wheels): the paper conditions' car


HUMAN_PARAM_SOURCES = {
    "reaction_delay_s": "human visual-motor delay in compensatory tracking, 0.15-0.3 s (McRuer & Jex 1967, "
                        "crossover model tau_e), its lower end (a driver with preview of the road); the paper's "
                        "introduction: a human's reaction time is above zero",
    "hand_time_constant_s": "neuromuscular lag of the arms on a wheel, about 0.1-0.2 s (McRuer crossover model T_N)",
    "max_steering_rate_radps": "1.0 rad/s at the front wheels = 690 deg/s at a 12:1 hand wheel, the upper end of the "
                               "300-700 deg/s hand-wheel rates measured for ordinary and evasive driving (0.6 rad/s "
                               "adds enough phase lag to make this driver weave off the road)",
    "natural_frequency_radps": "calibrated: the stiffest tracking this driver keeps on the road over the "
                               "whole train track (2.0 rad/s; 2.2 leaves it at 0.15 s reaction delay); the Base Model "
                               "imitating it inherits the gain without the driver's delays, so it is stable without "
                               "latency and, like the paper's BM, oscillates once 0.15-0.3 s of latency are added "
                               "(plm-highway calibrate, figures/bm-calibration.png)",
    "damping_ratio": "the expert's 0.9",
    "offset_noise_m": "calibrated: with the motor noise, makes the labels' std approach the paper's Table 1 "
                      "(see tests/test_expert_human.py for the band reached) while the car stays on the road",
    "heading_noise_rad": "calibrated with offset_noise_m",
    "wander_time_constant_s": "the slow lateral wander of human lane keeping (seconds)",
    "motor_noise_rad": "calibrated with offset_noise_m: per-step hand noise, smoothed by the hand's lag",
    "max_steering_rad": "the car's full scale: the paper conditions' 0.4 rad (plm_highway.rollout.conditions)",
}


def paper_units(normalised_steering, max_steering_rad: float = 0.2,
                steering_ratio: float = PAPER_STEERING_RATIO):
    """Normalised steering (1 = ``max_steering_rad`` at the front wheels) in the paper's unit
    (1 = 450 deg of steering wheel)."""
    return np.asarray(normalised_steering) * max_steering_rad * steering_ratio / math.radians(PAPER_FULL_SCALE_DEG)


def ou_step(value: float, std: float, time_constant_s: float, dt_s: float, rng: np.random.Generator) -> float:
    """One exact step of a stationary Ornstein-Uhlenbeck process (mean 0, stationary ``std``)."""
    decay = math.exp(-dt_s / time_constant_s)
    return value * decay + std * math.sqrt(1.0 - decay * decay) * float(rng.standard_normal())


def hand_step(steering: float, command: float, dt_s: float, params: HumanParams) -> float:
    """The hand's position after one step towards ``command``: first-order lag, then the rate limit
    (both on normalised steering, the rate converted from front-wheel radians)."""
    decay = math.exp(-dt_s / params.hand_time_constant_s) if params.hand_time_constant_s > 0 else 0.0
    target = command + (steering - command) * decay
    max_step = params.max_steering_rate_radps / params.max_steering_rad * dt_s
    return max(-1.0, min(1.0, steering + max(-max_step, min(max_step, target - steering))))


class HumanDemonstrator:
    """Callable policy ``(frame, info) -> normalised steering`` that drives like :data:`HUMAN_PARAM_SOURCES`
    describes. ``policy_frequency_hz`` is the loop it is called at (the reaction delay is counted in
    its steps); call :meth:`reset` with the caller's generator before each episode."""

    def __init__(self, policy_frequency_hz: float, params: HumanParams = HumanParams(),
                 rng: np.random.Generator | None = None):
        if not policy_frequency_hz > 0:
            raise ValueError(f"policy_frequency_hz = {policy_frequency_hz!r}: must be > 0")
        self.params = params
        self.dt_s = 1.0 / policy_frequency_hz
        self.delay_steps = int(round(params.reaction_delay_s / self.dt_s))
        # The law it steers by (public: a Base Model imitating this driver is compared with it, bm-response).
        self.tracking = ExpertParams(params.natural_frequency_radps, params.damping_ratio, params.max_steering_rad)
        self.reset(rng if rng is not None else np.random.default_rng(0))

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Start a new episode: hand centred, no decision pending, wander drawn from its stationary law."""
        if rng is not None:
            self.rng = rng
        self.offset_wander_m = self.params.offset_noise_m * float(self.rng.standard_normal())
        self.heading_wander_rad = self.params.heading_noise_rad * float(self.rng.standard_normal())
        self.steering = 0.0
        self._pending: deque[float] = deque()

    def decide(self, state: dict) -> float:
        """The command the driver decides on now, from a misjudged view of ``state`` (before the delay)."""
        p = self.params
        self.offset_wander_m = ou_step(self.offset_wander_m, p.offset_noise_m, p.wander_time_constant_s,
                                       self.dt_s, self.rng)
        self.heading_wander_rad = ou_step(self.heading_wander_rad, p.heading_noise_rad, p.wander_time_constant_s,
                                          self.dt_s, self.rng)
        perceived = dict(state, lateral_offset_m=state["lateral_offset_m"] + self.offset_wander_m,
                         heading_error_rad=state["heading_error_rad"] + self.heading_wander_rad)
        motor_noise = p.motor_noise_rad / p.max_steering_rad  # in normalised steering
        return expert_steering(perceived, self.tracking) + motor_noise * float(self.rng.standard_normal())

    def __call__(self, frame, info: dict) -> float:
        self._pending.append(self.decide(info))
        # Until the first decision has waited its delay the hand holds where it was.
        command = self._pending.popleft() if len(self._pending) > self.delay_steps else self.steering
        self.steering = hand_step(self.steering, command, self.dt_s, self.params)
        return self.steering
