"""The Base Model's steering beside its demonstrator's tracking law, pose by pose (why a calibration misses).

A Base Model learns its demonstrator's steering only where the demonstrations went. Under latency the car
weaves further from the lane centre than any demonstration did, and what the BM does there decides whether
the weave stays bounded or grows until the car leaves the road. This probe places the car in the middle of
a track's longest straight (or left or right turn) at a lateral offset (heading along the road) or at a heading
error (on the lane centre), with no latency and nothing moving yet, and records two steerings for the first frame:

- the BM's, from the camera image (the conditions' camera and checkpoints, as ``calibrate`` drives them);
- the demonstrator's tracking law from the true state (:func:`~plm_highway.expert.controller.expert_steering`
  with the conditions' demonstrator's natural frequency and damping), i.e. what the demonstrations were
  generated from, without the human's delays and noise.

The ratio BM / law at each pose says where the imitation follows the law, where it is stiffer, and where it
saturates (its steering stops growing while the law's keeps growing).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import gymnasium
import numpy as np

from plm_highway.data.collect import make_demonstrator
from plm_highway.envs import ENV_ID
from plm_highway.errors import BadInput
from plm_highway.evaluation.protocol import PAPER_TRACK
from plm_highway.expert.controller import ExpertParams, expert_steering
from plm_highway.io import file_kind, pyplot, write_figure_and_numbers
from plm_highway.models.checkpoints import load_base_model
from plm_highway.models.inference import BaseModelPolicy
from plm_highway.road.geometry import SEGMENT_TITLES, longest_segment_middle_m
from plm_highway.rollout.conditions import CONDITIONS, Conditions
from plm_highway.rollout.policies import checkpoint_pair

OFFSETS_M = tuple(round(float(x), 2) for x in np.arange(-5.0, 5.001, 0.5))
HEADINGS_RAD = tuple(round(float(x), 2) for x in np.arange(-0.20, 0.2001, 0.04))
RESPONSE_JSON = file_kind("bm-response", "a plm-highway BM response result JSON file")
DEFAULT_OUT = Path("figures") / "bm-response.png"


def demonstrator_law(conditions: Conditions) -> ExpertParams:
    """The tracking law the conditions' demonstrator steers by, as ``collect`` builds that demonstrator."""
    driver = make_demonstrator(conditions.demonstrator, conditions.policy_frequency_hz, np.random.default_rng(0),
                               conditions.max_steering_rad)
    return driver.tracking


def bm_response(track: str = PAPER_TRACK, conditions: str = "paper", checkpoints=None,
                offsets_m: Sequence[float] = OFFSETS_M, headings_rad: Sequence[float] = HEADINGS_RAD,
                segment: str = "straight") -> dict:
    """The BM's and the demonstrator's law's normalised steering at each posed start (see the module text), in
    the middle of the track's longest ``segment`` (:data:`SEGMENTS`); offsets beyond the road (from the start
    lane's centre to the road edge) are refused."""
    chosen = CONDITIONS[conditions]
    law = demonstrator_law(chosen)
    bm_path, _ = checkpoint_pair(checkpoints, chosen.checkpoint_preset)
    policy = BaseModelPolicy(load_base_model(bm_path), batch_invariant=True)
    env = gymnasium.make(ENV_ID, config=dict(chosen.env_config(), track=track, camera=chosen.camera))
    try:
        env.reset(seed=0)
        unwrapped = env.unwrapped
        room_m = unwrapped.track.road_half_width_m - abs(unwrapped.start_lane_offset_m)
        too_far = [o for o in offsets_m if abs(o) >= room_m]
        if too_far:
            raise BadInput(f"offsets {too_far} m would pose the car off the road of track {track!r}: "
                           f"at most {room_m:g} m from the start lane's centre to the road edge")
        arc_m = longest_segment_middle_m(unwrapped.track, segment)

        def steer(offset_m: float, heading_rad: float) -> tuple[float, float]:
            obs, info = env.reset(options={"start_arc_length_m": arc_m, "start_offset_m": offset_m,
                                           "start_heading_error_rad": heading_rad})
            policy.reset()
            return float(policy(np.array(obs), info["speed_mps"], 0.0)), float(expert_steering(info, law))

        sweeps = {}
        for name, poses in (("offset", [(o, 0.0) for o in offsets_m]), ("heading", [(0.0, h) for h in headings_rad])):
            steered = [steer(*pose) for pose in poses]
            sweeps[name] = {"offset_m": [p[0] for p in poses], "heading_error_rad": [p[1] for p in poses],
                            "bm": [s[0] for s in steered], "law": [s[1] for s in steered]}
    finally:
        env.close()
    return {"track": track, "conditions": conditions, "segment": segment, "arc_length_m": arc_m,
            "speed_mps": chosen.speed_mps, "max_steering_rad": chosen.max_steering_rad,
            "law": {"natural_frequency_radps": law.natural_frequency_radps, "damping_ratio": law.damping_ratio,
                    "demonstrator": chosen.demonstrator},
            "checkpoint": f"shipped {bm_path.name}" if checkpoints is None else str(bm_path), "sweeps": sweeps}


def ratio_lines(result: dict) -> list[str]:
    """One line per sweep: BM / law at each pose whose law steering is not ~0 (sign included)."""
    lines = []
    for name, unit, key in (("offset", "m", "offset_m"), ("heading", "rad", "heading_error_rad")):
        sweep = result["sweeps"][name]
        parts = [f"{x:+g}: {b / w:.2f}" for x, b, w in zip(sweep[key], sweep["bm"], sweep["law"]) if abs(w) > 0.02]
        lines.append(f"BM / law along the {name} sweep [{unit}]: " + ", ".join(parts))
    return lines


def response_figure(result: dict):
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.2))
    for ax, name, key, xlabel in ((axes[0], "offset", "offset_m", "lateral offset from the lane centre [m]"),
                                  (axes[1], "heading", "heading_error_rad", "heading error [rad]")):
        sweep = result["sweeps"][name]
        ax.plot(sweep[key], sweep["law"], "s--", color="tab:red", label="demonstrator's law, true state")
        ax.plot(sweep[key], sweep["bm"], "o-", color="tab:blue", label="Base Model, camera image")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"steering [1 = {result['max_steering_rad']:g} rad at the front wheels]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"BM vs its demonstrator's law ({result['law']['natural_frequency_radps']:g} rad/s, damping "
                 f"{result['law']['damping_ratio']:g}), {result['conditions']} conditions, {result['track']} "
                 f"track, {SEGMENT_TITLES[result['segment']]}, no latency", fontsize=10)
    fig.tight_layout()
    return fig


def write_response(result: dict, out=DEFAULT_OUT, overwrite: bool = False) -> tuple[Path, Path]:
    """The figure (``out``, PNG) and its numbers (same name, ``.json``), published together."""
    return write_figure_and_numbers(response_figure(result), result, out, RESPONSE_JSON, overwrite=overwrite)
