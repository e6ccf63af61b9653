"""How hard a policy answers the lane, from camera frames of the car posed at known offsets and headings.

The car is posed at the middle of a track's longest straight at a lateral offset (heading along the road) or a
heading error (on the lane centre), nothing moving; the least-squares slopes of the steering a policy answers are
its feedback gains on offset [1/m] and heading error [1/rad] (normalised steering). The population study measures
PLM-Net's gains against its BM's with it; the ``smith`` mitigation takes its BM's as the map from a predicted change
of the lane state to a change of steering.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium
import numpy as np

from plm_highway.envs import ENV_ID
from plm_highway.road.geometry import longest_segment_middle_m

POSE_OFFSETS_M = (-1.0, -0.5, 0.0, 0.5, 1.0)  # inside the lane: what the demonstrations covered
POSE_HEADINGS_RAD = (-0.04, -0.02, 0.0, 0.02, 0.04)


def slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of ``y`` on ``x`` (with an intercept)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return float(np.polyfit(x, y, 1)[0])


def posed_frames(env_config: dict, track: str, camera: dict | None, offsets_m: Sequence[float] = POSE_OFFSETS_M,
                 headings_rad: Sequence[float] = POSE_HEADINGS_RAD) -> list[tuple[str, np.ndarray, dict]]:
    """``[(sweep, frame, info)]``: sweep "offset" (the car at each of ``offsets_m``, heading along the road), then
    "heading" (at each of ``headings_rad``, on the lane centre), at the middle of ``track``'s longest straight."""
    env = gymnasium.make(ENV_ID, config=dict(env_config, track=track, camera=camera or {}))
    posed = []
    try:
        env.reset(seed=0)
        arc_m = longest_segment_middle_m(env.unwrapped.track, "straight")
        poses = [("offset", o, 0.0) for o in offsets_m] + [("heading", 0.0, h) for h in headings_rad]
        for sweep, offset_m, heading_rad in poses:
            frame, info = env.reset(options={"start_arc_length_m": arc_m, "start_offset_m": offset_m,
                                             "start_heading_error_rad": heading_rad})
            posed.append((sweep, np.array(frame), info))
    finally:
        env.close()
    return posed


def gains_from_answers(answers: dict[str, list[float]], offsets_m: Sequence[float] = POSE_OFFSETS_M,
                       headings_rad: Sequence[float] = POSE_HEADINGS_RAD) -> dict:
    """``{"offset_gain_per_m", "heading_gain_per_rad"}`` from the steering answered in each sweep of
    :func:`posed_frames` (``answers["offset"]``, ``answers["heading"]``)."""
    return {"offset_gain_per_m": slope(offsets_m, answers["offset"]),
            "heading_gain_per_rad": slope(headings_rad, answers["heading"])}
