"""The conditions a closed-loop run is driven under, and what they decide about each run.

Conditions (``--conditions``):

- ``ideal``: this project's default setup (20 Hz loop, frames delivered with their exact age,
  PLM-Net told the measured age, no image noise).
- ``paper``: the paper's conditions as far as they can be set without retraining; each item names
  its source in :data:`PAPER_CONDITION_ITEMS`, and what is not reproduced is listed there too.

Seeds vary the latency realisation (random profiles), the start (lateral offset and heading
error, drawn from ``np.random.default_rng([seed, START_STREAM])``, :func:`start_perturbation`) and,
under ``paper``, the image noise. Seed 0 keeps the centred start, so the seed-0 run is the one earlier
reports showed.

Scoring ends before the camera can see the end of an open road: the runs stop after
:func:`scored_steps` steps, when the car is still ``sight_m`` (camera range plus its mount offset
and a margin) before the end. Earlier reports drove to the very end and the Base Model swerved in
its last second because it saw the road end.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from plm_highway.camera.pinhole import PAPER_CAMERA, CameraConfig
from plm_highway.envs.config import MAX_PROCESSING_DELAY_STEPS, MAX_STEERING_TIME_CONSTANT_S
from plm_highway.envs.speed import parse_sharp_turn_braking
from plm_highway.errors import BadInput
from plm_highway.lane_ekf.latency_stream import LatencyEstimation
from plm_highway.latency.profiles import legacy_baseline_spec
from plm_highway.road.spec import TrackSpec
from plm_highway.vehicle.models import PARAM_RANGES, checked_params, kinematic_car_with_friction, vehicle_model

START_STREAM = 11  # the start perturbation draws from np.random.default_rng([seed, START_STREAM])
RUN_OUT_MARGIN_M = 5.0  # beyond the camera's range: the car's length and one step of travel


@dataclass(frozen=True)
class Conditions:
    """How the closed loop is set up; one instance per ``--conditions`` name."""

    name: str
    policy_frequency_hz: int
    simulation_frequency_hz: int
    speed_mps: float
    injection: str  # LatencyWrapper injection: "time" (exact ages) or "legacy-fifo" (the original's FIFO)
    latency_source: str  # what PLM-Net is told: "measured" age or "requested" latency
    image_noise_std: float  # Gaussian pixel noise [grey levels]
    start_offset_max_m: float  # start perturbation: lateral offset drawn in +-this (seed > 0)
    start_heading_max_rad: float  # and heading error in +-this
    time_varying: tuple[str, ...]  # the time-varying settings run under these conditions
    checkpoint_preset: str  # the shipped checkpoint pair these conditions are meant for
    camera: dict = field(default_factory=dict)
    steering_time_constant_s: float = 0.0  # first-order steering actuator (env config)
    processing_delay_steps: int = 0  # policy steps between an action and the actuator (env config)
    demonstrator: str = "expert"  # who drove the training data of these conditions' checkpoints (collect)
    max_steering_rad: float = 0.2  # the car's front-wheel angle at steering +-1 (env config)
    # None: constant speed_mps; a dict (env config "sharp_turn_braking"): the original run scripts' speed logic
    sharp_turn_braking: dict | None = None
    vehicle_model: str = "kinematic"  # a name in plm_highway.vehicle.models.VEHICLE_MODELS (env config)
    vehicle_params: dict = field(default_factory=dict)  # overrides of that model's default parameters
    # None, or a plm_highway.lane_ekf.latency_stream.LatencyEstimation: every run estimates its latency from the
    # stream and logs it (latency_source "estimated": PLM-Net is told that estimate); see with_latency_source
    latency_estimation: object = None

    def env_config(self, start_offset_m: float = 0.0, start_heading_error_rad: float = 0.0) -> dict:
        return {"policy_frequency": self.policy_frequency_hz, "simulation_frequency": self.simulation_frequency_hz,
                "speed_mps": self.speed_mps, "start_offset_m": start_offset_m,
                "start_heading_error_rad": start_heading_error_rad,
                "steering_time_constant_s": self.steering_time_constant_s,
                "processing_delay_steps": self.processing_delay_steps, "max_steering_rad": self.max_steering_rad,
                "sharp_turn_braking": self.sharp_turn_braking, "vehicle_model": self.vehicle_model,
                "vehicle_params": dict(self.vehicle_params)}


# The original pipeline: the command computed from frame t reaches the car's steering at the earliest on the
# next iteration of its 30 Hz ROS loop, and the message synchroniser can hold it one more (notes: 30 Hz loop,
# synchroniser); the upper end of "one to two frames" is taken.
PAPER_PROCESSING_DELAY_STEPS = 2
# The original car's wheels followed the command through a PID-driven steering; modelled as a
# first-order actuator. 0.1 s is an assumption (no measured value in the papers or the notes).
PAPER_STEERING_TIME_CONSTANT_S = 0.1
# The paper's car could steer far more than this env's default 0.2 rad: its steering data (Table 1) reach -1.0 in
# units of 450 deg of steering wheel, 0.65 rad at the front wheels with a 12:1 ratio (OSRF car_demo's Prius, the
# papers' simulated car, limits its tyres to 0.6458 rad). 0.4 rad (23 deg), a
# passenger car's range, lets the Base Model's latency-driven oscillation reach the paper's amplitude
# (at 0.2 rad it saturates below the paper's 0.25-s MAE, 0.22 rad) while keeping the car on the road.
PAPER_MAX_STEERING_RAD = 0.4
TIME_VARYING_PAPER_TEXT = "steps:0.0-0.35:1.0"  # uniform in [0, 0.35] s, redrawn every 1 s (the paper's text)
ORIGINAL_LOOP_HZ = 30  # the original's ROS loop (paper Sec. 4.6); its latency FIFO took one frame per iteration
ORIGINAL_FRAME_READING_FPS = 60  # how its comments and the paper turn its frame counts into seconds (the 2x ambiguity)
# the original code: 9..21 frames of its 30 Hz loop, every 60 frames; the same frames read at 60 fps, as the paper
# states the range
TIME_VARYING_ORIGINAL = f"frames:9-21:60@{ORIGINAL_LOOP_HZ}"
TIME_VARYING_PAPER_READING = f"frames:9-21:60@{ORIGINAL_FRAME_READING_FPS}"

CONDITIONS = {
    "ideal": Conditions("ideal", 20, 20, 16.7, "time", "measured", 0.0, 0.2, 0.01, (TIME_VARYING_PAPER_TEXT,),
                        "default"),
    "paper": Conditions("paper", ORIGINAL_LOOP_HZ, ORIGINAL_LOOP_HZ, 16.7, "legacy-fifo", "requested", 3.0, 0.2, 0.01,
                        (TIME_VARYING_PAPER_TEXT, TIME_VARYING_ORIGINAL, TIME_VARYING_PAPER_READING), "paper",
                        camera=PAPER_CAMERA, steering_time_constant_s=PAPER_STEERING_TIME_CONSTANT_S,
                        processing_delay_steps=PAPER_PROCESSING_DELAY_STEPS, demonstrator="human",
                        max_steering_rad=PAPER_MAX_STEERING_RAD),
}
CONDITION_NAMES = tuple(CONDITIONS)
# What PLM-Net is told under each injection: the age of the frame it got (exact ages), or, as the original code
# did with its FIFO, the latency requested of the FIFO (which differs from the age while the FIFO refills).
INJECTION_LATENCY_SOURCE = {"time": "measured", "legacy-fifo": "requested"}


def with_injection(conditions: Conditions, injection: str | None) -> Conditions:
    """``conditions`` with latency ``injection`` (``--injection``; None: as they are): ``time`` delivers frames with
    their exact age and tells PLM-Net that age; ``legacy-fifo`` is the original's FIFO, PLM-Net told the requested
    latency and the BM baseline of a time-varying setting run at a constant one (:func:`baseline_latency`)."""
    if injection is None or injection == conditions.injection:
        return conditions
    if injection not in INJECTION_LATENCY_SOURCE:
        raise BadInput(f"--injection {injection!r}: expected one of {list(INJECTION_LATENCY_SOURCE)}")
    return replace(conditions, injection=injection, latency_source=INJECTION_LATENCY_SOURCE[injection])


LATENCY_SOURCE_NAMES = ("measured", "requested", "estimated")


def with_latency_source(conditions: Conditions, latency_source: str | None, estimation=None) -> Conditions:
    """``conditions`` with PLM-Net told ``latency_source`` (``--latency-source``; None: as they are): the measured age
    of its frame, the requested latency, or the latency estimated from the stream without timestamps. ``estimated``
    also makes every run estimate it and log the estimate beside the true age (``estimation``: a
    :class:`~plm_highway.lane_ekf.latency_stream.LatencyEstimation`, default its defaults)."""
    if latency_source is None:
        return conditions
    if latency_source not in LATENCY_SOURCE_NAMES:
        raise BadInput(f"--latency-source {latency_source!r}: expected one of {list(LATENCY_SOURCE_NAMES)}")
    if latency_source != "estimated":
        return replace(conditions, latency_source=latency_source, latency_estimation=None)
    if estimation is None:
        estimation = LatencyEstimation()
    return replace(conditions, latency_source=latency_source, latency_estimation=estimation)


# ``--speed-logic``: how the car's speed evolves. "constant" holds the conditions' speed_mps (the paper's text);
# "original-braking" is the original run scripts' throttle-and-brake logic
# (:class:`~plm_highway.envs.speed.SharpTurnBraking`, its thresholds from the original configuration, its
# acceleration and braking assumed), starting at speed_mps.
SPEED_LOGICS = {"constant": None, "original-braking": {}}


def with_speed_logic(conditions: Conditions, speed_logic: str) -> Conditions:
    """``conditions`` with the named speed logic (:data:`SPEED_LOGICS`)."""
    if speed_logic not in SPEED_LOGICS:
        raise BadInput(f"--speed-logic {speed_logic!r}: expected one of {list(SPEED_LOGICS)}")
    return replace(conditions, sharp_turn_braking=SPEED_LOGICS[speed_logic])


def with_pipeline(conditions: Conditions, processing_delay_steps: int | None = None,
                  steering_time_constant_s: float | None = None) -> Conditions:
    """``conditions`` with the assumed parts of its pipeline replaced (None keeps the conditions' value): the
    policy steps between an action and the actuator, and the first-order actuator's time constant. Both are
    assumptions under the paper conditions (no measured value in the papers or the notes), so a calibration can
    vary them."""
    if processing_delay_steps is not None:
        if isinstance(processing_delay_steps, bool) or not isinstance(processing_delay_steps, int) \
                or not 0 <= processing_delay_steps <= MAX_PROCESSING_DELAY_STEPS:
            raise BadInput(f"--processing-delay-steps {processing_delay_steps!r}: expected an integer in "
                           f"[0, {MAX_PROCESSING_DELAY_STEPS}]")
        conditions = replace(conditions, processing_delay_steps=processing_delay_steps)
    if steering_time_constant_s is not None:
        if not (isinstance(steering_time_constant_s, (int, float)) and not isinstance(steering_time_constant_s, bool)
                and 0.0 <= steering_time_constant_s <= MAX_STEERING_TIME_CONSTANT_S):
            raise BadInput(f"--steering-time-constant-s {steering_time_constant_s!r}: expected seconds in "
                           f"[0, {MAX_STEERING_TIME_CONSTANT_S:g}]")
        conditions = replace(conditions, steering_time_constant_s=float(steering_time_constant_s))
    return conditions


# ``--friction-coefficient``: the kinematic bicycle turns at any lateral acceleration its steering asks for; the
# papers' Gazebo car (OSRF car_demo's Prius) has wheels with friction coefficient 0.9 (plm_highway.vehicle.paper_units).
FRICTION_RANGE = PARAM_RANGES["friction_coefficient"]


def with_friction_limit(conditions: Conditions, friction_coefficient: float | None = None) -> Conditions:
    """``conditions`` with a car whose tires saturate at ``friction_coefficient`` g (None: as they are): the
    kinematic car's geometry on stiff magic-formula tires (:func:`~plm_highway.vehicle.models.kinematic_car_with_friction`),
    which steers close to the kinematic bicycle below the limit."""
    if friction_coefficient is None:
        return conditions
    low, high = FRICTION_RANGE
    if isinstance(friction_coefficient, bool) or not isinstance(friction_coefficient, (int, float)) \
            or not low <= friction_coefficient <= high:
        raise BadInput(f"--friction-coefficient {friction_coefficient!r}: expected a number in [{low:g}, {high:g}]")
    if conditions.vehicle_model != "kinematic":
        raise BadInput(f"--friction-coefficient: the {conditions.name} conditions' car is {conditions.vehicle_model!r}; "
                       "a friction limit is added to the kinematic car only")
    geometry = checked_params(vehicle_model("kinematic"), conditions.vehicle_params)
    params = asdict(kinematic_car_with_friction(friction_coefficient, geometry))
    return replace(conditions, vehicle_model="saturating", vehicle_params=params)


def top_speed_mps(conditions: Conditions) -> float:
    """The fastest the car can drive under ``conditions``: speed_mps, or under the braking logic its speed limit
    plus one policy step of full throttle (the brake is decided once per step)."""
    if conditions.sharp_turn_braking is None:
        return conditions.speed_mps

    logic = parse_sharp_turn_braking(conditions.sharp_turn_braking)
    return max(conditions.speed_mps, logic.max_speed_mps + logic.throttle_accel_mps2 / conditions.policy_frequency_hz)


def baseline_latency(spec: str, conditions: Conditions) -> str:
    """The latency the BM baseline of setting ``spec`` runs at: ``spec``, except under the legacy FIFO, where the
    original's BM saw a constant latency (:func:`legacy_baseline_spec`)."""
    return legacy_baseline_spec(spec) if conditions.injection == "legacy-fifo" else spec


# (item, value here, source) for the report and README: what ``--conditions paper`` sets, and what it does not
PAPER_CONDITION_ITEMS = (
    ("control loop", "30 Hz policy and simulation", "paper Sec. 4.6 (30 Hz control frequency); original ROS loop"),
    ("speed", "16.7 m/s constant", "paper Sec. 5 (constant speed, approximately 60 km/h)"),
    ("constant latencies", "0.15, 0.20, 0.25, 0.30 s", "paper Tables 3, A1, A3, A5"),
    ("time-varying latency, as stated", TIME_VARYING_PAPER_TEXT, "paper Sec. 4.5: [0, 0.35] s"),
    ("time-varying latency, as coded", f"{TIME_VARYING_ORIGINAL} (0.30-0.70 s)",
     "original code: integer frames 9..21 of its 30 Hz loop, redrawn every 60 frames"),
    ("time-varying latency, the paper's reading", f"{TIME_VARYING_PAPER_READING} (0.15-0.35 s)",
     "the same frames read at 60 fps: the 2x timebase ambiguity, both readings run"),
    ("latency injection", "legacy FIFO (`injection=\"legacy-fifo\"`)",
     "original code: a FIFO counted in loop frames, serving fresher frames while it refills"),
    ("latency PLM-Net is told", "the requested latency (`info[\"latency_s\"]`)", "original code"),
    ("BM baseline of a time-varying setting", "a constant latency, the middle of the profile's range (15 frames for "
     "9..21)", "original code: the BM's input buffer kept its configured constant delta; the paper's time-variant BM "
     "MAE 0.3336 equals its 0.25-s one, 0.3347 (`--injection time` runs it at the varying latency)"),
    ("image noise", "Gaussian, std 3 grey levels, seeded", "original camera (notes: image noise)"),
    ("camera", "800x800 px, 80 deg, 1.83 m high, pitch 2.3 deg down; rows 380-520 resized to 160x160",
     "original code (notes: crop rows 380-520, 160x160); pitch: 'small', set so the strip's top row is the horizon"),
    ("processing delay", f"{PAPER_PROCESSING_DELAY_STEPS} loop steps ({PAPER_PROCESSING_DELAY_STEPS / 30:.3f} s) "
     "between an action and the actuator", "original ROS loop and synchroniser: one to two frames"),
    ("steering actuator", f"first order, time constant {PAPER_STEERING_TIME_CONSTANT_S:g} s",
     "original PID-driven steering; the time constant is assumed"),
    ("steering range", f"+-{PAPER_MAX_STEERING_RAD:g} rad at the front wheels (this env's default: 0.2)",
     "paper Table 1: steering down to -1.0 x 450 deg of steering wheel; the papers' car (OSRF car_demo's Prius, "
     "12.16:1) steers its tyres to 0.6458 rad; 0.4 rad assumed"),
    ("training data", "human-like demonstrator (plm_highway/expert/human.py) at 30 Hz with the paper camera, "
     "train track only; `paper` checkpoints (5,800,550 / 6,250,205 trainable)",
     "paper Sec. 4.2 (a human at a Logitech G920), Table 1 (steering spread), Table 2 (sizes)"),
    ("start perturbation", "offset +-0.2 m, heading +-0.01 rad (seed > 0)", "this protocol (seed-to-seed spread)"),
)
PAPER_CONDITIONS_NOT_REPRODUCED = (
    "the spread of the paper's steering data: the demonstrator's std is 0.125 in the paper's unit in the recorded "
    "training set (quartiles -0.081 and 0.084), against the paper's 0.177 (quartiles -0.069 and 0.059); a driver "
    "stiff or noisy enough to reach 0.177 weaves out of its lane",
    "a human driver: the demonstrator is a model of one (delay, hand lag and rate limit, wander, motor noise)",
    "the original run scripts' speed logic: they throttled up to 22 m/s and braked (0.5 for 1.7 s) whenever "
    "|steering| exceeded 0.25 in the paper's unit, which slows a car whose BM oscillates; the paper states a constant "
    "speed of about 60 km/h, and these conditions keep 16.7 m/s constant. The logic can be run (`plm-highway "
    "calibrate --speed-logic original-braking`, its throttle and braking assumed): it leaves the BM's calibration "
    "missed (0.66/0.73/0.37/0.55x the paper's, off the road in 0/1/4/5 of 5 seeds; "
    "figures/bm-calibration-original-braking.png)",
    "the BM's degradation with latency only in part: the `paper` BM's steering MAE at 0.15/0.20/0.25/0.30 s is "
    "0.54/0.88/0.44/0.60x the paper's in front-wheel radians (`plm-highway calibrate`, figures/bm-calibration.png), "
    "within the factor 2 except at 0.25 s; and at 0.25 and 0.30 s it leaves the road in every seed, where the paper's"
    " BM drove on. Judged on the protocol's second variant instead (every step after leaving the road counted as an "
    "error of 1, normalised), it is 1.59x and 2.45x the paper's there: the paper's BM lies between our two variants, "
    "and the rule is missed under both. Why (`plm-highway bm-response`, figures/bm-response.png): the BM steers like "
    "its driver's law within 2.5 m of the lane centre but at 0.53-0.93x of it in heading error and saturates beyond 3"
    " m, and at 0.25 s the weave reaches heading errors of 0.28-0.32 rad, where it damps at about 0.6x. The "
    "saturation is not what takes it off the road: a BM also taught the driver's law on the states a delayed BM "
    "visits (DAgger-style, README) answers offsets like the law out to 5 m and still leaves the road at 0.25 s; what "
    "every BM measured shares is the weak answer to heading error (0.16-0.93x the law). That answer alone is enough "
    "to make the BM's curve: the driver's own law from the delayed true state, with the lane aliasing a camera has, "
    "gives 1.38/1.29/0.76/1.50x the paper's and leaves the road at 0.25 / 0.30 s in 1 / 3 of 5 seeds; with only its "
    "heading gain cut to 0.67x it gives 0.36/0.83/0.46/0.61x and leaves at 0.25 s in 2 of 5, and at 0.5x "
    "0.29/0.74/0.31/0.44x, off from 0.25 s in every seed (README). Teaching the heading answer directly (training "
    "frames re-rendered with the camera yawed and labelled with the law's answer, added to the DAgger-style states; "
    "README) kept the BM on the road at 0.25 s in three of four training runs, at 1.14-1.18x the paper's there, but "
    "each missed elsewhere: 0.22x or 0.35x at 0.15 s, 2.00-2.32x at 0.20 s, or 2.21-2.57x at 0.30 s penalised; "
    "between training seeds the ratio at 0.15 s ran from 0.22x to 2.39x, and none is shipped. Neither the assumed "
    "pipeline (processing delay 1-3 steps x actuator 0.05-0.2 s) nor the exploratory drivers tried (README) meet the "
    "rule. Nor does a friction limit: the papers' Gazebo car has wheels with friction 0.9 (OSRF car_demo's Prius), "
    "and on tires that saturate there (`plm-highway calibrate --friction-coefficient 0.9`, "
    "figures/bm-calibration-friction.png) the BM leaves the road from 0.20 s in every seed (0.33/0.84/0.44/0.59x the "
    "paper's); the same stiff tires with a limit that never binds (3 g) keep it on the road at 0.20 s "
    "(0.34/0.78/0.41/0.63x). A car that cannot turn harder cannot catch the weave: friction does not explain how the "
    "paper's BM stayed on the road. Nor does the other reading of the latencies: as the original counted them, "
    "9/12/15/18 frames of its 30 Hz loop (`plm-highway calibrate --reading loop-frames`, "
    "figures/bm-calibration-loop-frames.png), the BM gives 0.80/0.65/0.35/0.50x the paper's and leaves the road in "
    "every seed. The miss at 0.25 s is not one unlucky training run: five trainings of the shipped recipe on the same"
    " data (the shipped BM and training seeds 0-3 retrained) give 0.37-0.50x there; the one at 0.50x (0.502) leaves "
    "the road at 0.20 s in every seed, and none is shipped for meeting the rule",
)


def start_perturbation(seed: int, conditions: Conditions) -> tuple[float, float]:
    """(lateral offset [m], heading error [rad]) at the start: centred for seed 0, else drawn from the seed."""
    if seed == 0:
        return 0.0, 0.0
    rng = np.random.default_rng([seed, START_STREAM])
    return (float(rng.uniform(-conditions.start_offset_max_m, conditions.start_offset_max_m)),
            float(rng.uniform(-conditions.start_heading_max_rad, conditions.start_heading_max_rad)))


def sight_m(camera: dict | None = None) -> float:
    """How far ahead of the car's reference point the camera can see road [m], plus the run-out margin."""
    config = CameraConfig.from_dict(camera or {})
    return config.max_range_m + config.forward_offset_m + RUN_OUT_MARGIN_M


def scored_steps(track_spec: TrackSpec, conditions: Conditions, max_steps: int | None = None,
                 start_arc_length_m: float = 0.0) -> int | None:
    """Policy steps each run drives: on an open track, until the camera could first see the road's end
    (:func:`sight_m` before it) at the car's top speed; on a closed track one lap; never more than ``max_steps``."""
    step_m = top_speed_mps(conditions) / conditions.policy_frequency_hz
    if track_spec.closed:
        steps = math.ceil(track_spec.length_m / step_m) + 1
    else:
        scored_m = track_spec.length_m - start_arc_length_m - sight_m(conditions.camera)
        if scored_m <= step_m:
            raise ValueError(f"track {track_spec.name!r}: {track_spec.length_m:.0f} m long, too short to score "
                             f"anything before the camera sees its end ({sight_m(conditions.camera):.0f} m ahead)")
        steps = math.floor(scored_m / step_m)
    return steps if max_steps is None else min(steps, max_steps)


__all__ = ["CONDITIONS", "CONDITION_NAMES", "INJECTION_LATENCY_SOURCE", "LATENCY_SOURCE_NAMES", "PAPER_CONDITION_ITEMS",
           "PAPER_CONDITIONS_NOT_REPRODUCED", "SPEED_LOGICS", "Conditions", "baseline_latency", "legacy_baseline_spec",
           "scored_steps", "sight_m", "start_perturbation", "top_speed_mps", "with_friction_limit", "with_injection",
           "with_latency_source", "with_pipeline", "with_speed_logic"]
