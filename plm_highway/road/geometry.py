"""Closed-form geometry of a track's reference line (the centre of the road).

Everything that draws or measures the road (camera map, figures, curvature look-ups, segment
tables) samples it here, so there is one definition of where the road is.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.road.spec import TrackSpec, advance_pose

SEGMENT_KINDS = ("straight", "left", "right")


@dataclass(frozen=True)
class ReferenceLine:
    """Samples of the reference line; arrays share one index."""

    s_m: np.ndarray  # arc length from the start
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray  # positive turns left
    segment_index: np.ndarray

    def offset(self, lateral_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Points ``lateral_m`` to the left of the reference line."""
        return (self.x_m - lateral_m * np.sin(self.heading_rad),
                self.y_m + lateral_m * np.cos(self.heading_rad))


def segment_starts_m(track: TrackSpec) -> np.ndarray:
    """Arc length at which each segment starts, with the total length appended."""
    return np.concatenate([[0.0], np.cumsum([seg.length_m for seg in track.segments])])


def segment_kind(track: TrackSpec, index: int) -> str:
    """'straight', 'left' or 'right' for the segment at ``index``."""
    return track.segments[index].direction


def segment_index_at(track: TrackSpec, s_m: np.ndarray | float) -> np.ndarray:
    starts = segment_starts_m(track)
    s_m = np.asarray(s_m, dtype=float)
    if track.closed:
        s_m = np.mod(s_m, starts[-1])
    return np.clip(np.searchsorted(starts, s_m, side="right") - 1, 0, len(track.segments) - 1)


def curvature_at(track: TrackSpec, s_m: np.ndarray | float) -> np.ndarray:
    """Reference-line curvature at arc length ``s_m`` (zero past the end of an open track)."""
    curvatures = np.array([seg.curvature_1pm for seg in track.segments])
    s_arr = np.asarray(s_m, dtype=float)
    values = curvatures[segment_index_at(track, s_arr)]
    if not track.closed:
        values = np.where((s_arr < 0) | (s_arr > track.length_m), 0.0, values)
    return values


class SegmentLookup:
    """Scalar segment and curvature look-ups by arc length, for the per-step hot path."""

    def __init__(self, track: TrackSpec):
        self.closed = track.closed
        self.length_m = track.length_m
        self.starts_m = segment_starts_m(track)[:-1].tolist()
        self.curvatures_1pm = [seg.curvature_1pm for seg in track.segments]
        # [start, end) of the segment found last: a car stays on one segment for many steps.
        self._last = (0, self.starts_m[0], self.starts_m[1] if len(self.starts_m) > 1 else math.inf)

    def segment_index(self, s_m: float) -> int:
        if self.closed:
            s_m %= self.length_m
        index, start_m, end_m = self._last
        if start_m <= s_m < end_m:
            return index
        index = min(max(bisect.bisect_right(self.starts_m, s_m) - 1, 0), len(self.starts_m) - 1)
        if self.starts_m[index] <= s_m:  # below the first start the clamp answers; do not cache that
            end_m = self.starts_m[index + 1] if index + 1 < len(self.starts_m) else math.inf
            self._last = (index, self.starts_m[index], end_m)
        return index

    def curvature(self, s_m: float) -> float:
        if not self.closed and not 0.0 <= s_m <= self.length_m:
            return 0.0
        return self.curvatures_1pm[self.segment_index(s_m)]


@functools.lru_cache(maxsize=32)
def segment_lookup(track: TrackSpec) -> SegmentLookup:
    return SegmentLookup(track)


def sample_reference(track: TrackSpec, spacing_m: float = 0.5) -> ReferenceLine:
    """Sample the reference line at about ``spacing_m``, always including every segment's ends."""
    pose = (0.0, 0.0, 0.0)
    s0_m = 0.0
    parts: list[tuple[np.ndarray, ...]] = []
    for index, seg in enumerate(track.segments):
        n = max(2, int(math.ceil(seg.length_m / spacing_m)) + 1)
        local_s = np.linspace(0.0, seg.length_m, n)
        if index < len(track.segments) - 1:
            local_s = local_s[:-1]  # the next segment starts here
        x, y, heading = _pose_along(pose, seg, local_s)
        parts.append((s0_m + local_s, x, y, heading, np.full(len(local_s), seg.curvature_1pm),
                      np.full(len(local_s), index)))
        pose = advance_pose(pose, seg)
        s0_m += seg.length_m
    s, x, y, heading, curvature, seg_index = (np.concatenate(column) for column in zip(*parts))
    return ReferenceLine(s, x, y, heading, curvature, seg_index.astype(int))


def _pose_along(pose, seg, local_s: np.ndarray):
    x0, y0, h0 = pose
    if seg.kind == "straight":
        return x0 + local_s * math.cos(h0), y0 + local_s * math.sin(h0), np.full(len(local_s), h0)
    sign = 1.0 if seg.direction == "left" else -1.0
    cx = x0 - sign * seg.radius_m * math.sin(h0)
    cy = y0 + sign * seg.radius_m * math.cos(h0)
    heading = h0 + sign * local_s / seg.radius_m
    return cx + sign * seg.radius_m * np.sin(heading), cy - sign * seg.radius_m * np.cos(heading), heading


def reference_pose_at(track: TrackSpec, s_m: float) -> tuple[float, float, float]:
    """Exact pose (x, y, heading) of the reference line at arc length ``s_m``."""
    if track.closed:
        s_m = s_m % track.length_m
    if not 0.0 <= s_m <= track.length_m:
        raise BadInput(f"track {track.name!r}: arc length {s_m} m outside [0, {track.length_m:.1f}] m")
    pose = (0.0, 0.0, 0.0)
    for seg in track.segments:
        if s_m <= seg.length_m:
            x, y, heading = _pose_along(pose, seg, np.array([s_m]))
            return float(x[0]), float(y[0]), float(heading[0])
        s_m -= seg.length_m
        pose = advance_pose(pose, seg)
    return pose


SEGMENTS = ("straight", "left", "right")  # where the car can be posed: the middle of the longest of that kind
SEGMENT_TITLES = {"straight": "straight", "left": "left turn", "right": "right turn"}


def longest_segment_middle_m(track, segment: str = "straight") -> float:
    """Arc length [m] at the middle of the track's longest ``segment`` (straight, left or right arc)."""
    if not isinstance(segment, str) or segment not in SEGMENTS:
        raise BadInput(f"--segment: {segment!r} is not one of {list(SEGMENTS)}")
    arc_m, best = 0.0, None
    for part in track.segments:
        if part.direction == segment and (best is None or part.length_m > best[1]):
            best = (arc_m + 0.5 * part.length_m, part.length_m)
        arc_m += part.length_m
    if best is None:
        raise BadInput(f"track {track.name!r} has no {SEGMENT_TITLES[segment]} segment to pose the car on")
    return best[0]
