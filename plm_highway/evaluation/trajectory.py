"""Trajectory similarity as in the paper (Section 4.3.2): each run's path against the lane centre.

What is compared
    The run's x, y positions (one per policy step) against the **lane centre**: the centre line of
    the lane the car starts in, i.e. the track's reference line offset by that lane's offset (the
    middle lane on the shipped 3-lane tracks, so the reference line itself). The lane centre is
    cut to the stretch of road the run covered (from the arc length of its first to that of its
    last logged position in the part), so a run that leaves the road, or is stopped by
    ``max_steps``, is compared over what it drove and not against road it never reached.

Parts (the paper's panels (a)-(d))
    ``full``: the whole run. ``straight`` / ``left`` / ``right``: **every** segment of that kind in
    the track spec, each measured separately (run points whose arc length lies in the segment,
    against the lane centre over the same stretch), then averaged over those segments (segments
    the run has fewer than 2 points in are skipped). The paper shows one segment per kind; we
    average all of them because a single pick is arbitrary, and the natural one (the first) is,
    for straights, the run-in from a centred start where nothing has happened yet. The averages
    keep per-segment units, comparable in size to the paper's single-segment numbers.
    :func:`trajectory_method` lists the segments used.

Resampling
    PCM, DTW and the curve length measure change with the number of points, so both curves are
    resampled at one arc-length spacing, :data:`RESAMPLE_SPACING_M`, before comparing (the runs
    log a position every 0.835 m at 60 km/h and 20 Hz). The spacing is 0.1 m, not coarser, because
    of the discrete Frechet distance: two curves of slightly different length, each resampled from
    its own start, drift out of phase, so some coupled points are up to half a spacing apart along
    the road and the distance reads up to sqrt(d^2 + (spacing / 2)^2) instead of the true lateral
    deviation d. At 0.5 m an expert run that never strays more than 0.10 m from the lane centre
    measured 0.23 m; at 0.1 m it measures 0.101 m. The full test track then has about 11,500
    points per curve, about a second of metric time per run.

Metrics
    ``pcm``, ``frechet_dist``, ``area_between_two_curves``, ``curve_length_measure`` and ``dtw``
    (distance only) from :mod:`plm_highway.metrics` (drop-ins for similaritymeasures, lane centre
    as ``exp_data``, run as ``num_data``), and ``dtsi``: the reconstructed DTSI (EMDC, see
    :mod:`plm_highway.metrics.lane`) of the run's lateral offset from the lane centre and its time
    within the part. Frame: the curve length measure divides by the mean x and y of the lane
    centre, so it depends on the origin; all coordinates are shifted so that the road's bounding
    box has its lower-left corner at (0, 0) (a positive origin, as the measure assumes). The other
    metrics do not depend on the shift. PCM normalises by the lane centre's x and y ranges, so it
    is undefined (``None``) on a stretch that is exactly parallel to an axis (the first straight of
    the shipped tracks, heading east) and very large on one that is nearly so; the averages skip
    undefined values. Closed tracks: only the first lap is measured.
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.metrics import (
    area_between_two_curves,
    curve_length_measure,
    dtsi,
    dtw,
    frechet_dist,
    pcm,
    resample_by_arc_length,
)
from plm_highway.metrics._validation import as_curve, as_series, check_same_length
from plm_highway.road.builder import lane_offsets_m
from plm_highway.road.geometry import SEGMENT_KINDS, sample_reference, segment_starts_m
from plm_highway.road.track import TrackSpec, resolve_track

RESAMPLE_SPACING_M = 0.1  # arc-length spacing both curves are resampled at before comparing (see above)
LANE_CENTRE_SAMPLING_M = 0.25  # polyline the lane centre is cut from (chord error < 0.1 mm at R >= 80 m)
PARTS = ("full", *SEGMENT_KINDS)  # full, straight, left, right
METRICS = ("pcm", "frechet_dist", "area_between_two_curves", "curve_length_measure", "dtw", "dtsi")
METRIC_LABELS = {
    "pcm": "Partial Curve Mapping",
    "frechet_dist": "Frechet distance",
    "area_between_two_curves": "Area between curves",
    "curve_length_measure": "Curve length",
    "dtw": "Dynamic Time Warping",
    "dtsi": "DTSI (EMDC reconstruction)",
}
_AXIS_PARALLEL_TOL = 1e-9  # relative x or y range below which PCM's normalisation is undefined


def start_lane_offset_m(track: TrackSpec, start_lane: int | None = None) -> float:
    """Lateral offset of the starting lane's centre from the reference line (left positive)."""
    offsets = lane_offsets_m(track)
    lane = track.lanes // 2 if start_lane is None else int(start_lane)
    if not 0 <= lane < len(offsets):
        raise ValueError(f"start_lane {lane}: the track has lanes 0..{len(offsets) - 1}")
    return offsets[lane]


class LaneCentre:
    """The starting lane's centre line of ``track``, to be cut by arc length of the reference line."""

    def __init__(self, track: TrackSpec, lane_offset_m: float = 0.0):
        self.track = track
        self.lane_offset_m = float(lane_offset_m)
        ref = sample_reference(track, LANE_CENTRE_SAMPLING_M)
        x, y = ref.offset(self.lane_offset_m)
        self.s_m = ref.s_m
        self.xy = np.column_stack([x, y])
        edge_x = np.concatenate([ref.offset(track.road_half_width_m)[0], ref.offset(-track.road_half_width_m)[0]])
        edge_y = np.concatenate([ref.offset(track.road_half_width_m)[1], ref.offset(-track.road_half_width_m)[1]])
        # the positive-origin frame of the curve length measure (see the module docstring)
        self.origin_m = np.array([edge_x.min(), edge_y.min()])

    def between(self, s_from_m: float, s_to_m: float) -> np.ndarray:
        """Lane-centre points (n, 2) from reference arc length ``s_from_m`` to ``s_to_m``, ends exact."""
        s_from_m, s_to_m = max(float(s_from_m), 0.0), min(float(s_to_m), float(self.s_m[-1]))
        if not s_to_m > s_from_m:
            raise ValueError(f"lane centre: empty stretch [{s_from_m:.3f}, {s_to_m:.3f}] m")
        inner = (self.s_m > s_from_m) & (self.s_m < s_to_m)
        stations = np.concatenate([[s_from_m], self.s_m[inner], [s_to_m]])
        return np.column_stack([np.interp(stations, self.s_m, self.xy[:, k]) for k in range(2)])


def compare_to_lane_centre(path_xy, centre_xy, offset_m, t_s, spacing_m: float = RESAMPLE_SPACING_M,
                           origin_m=(0.0, 0.0)) -> dict[str, float | None]:
    """The six metrics of one path against one lane-centre piece.

    ``path_xy`` (n, 2) are the run's positions, ``offset_m`` and ``t_s`` (n,) its lateral offset
    from the lane centre and time at those positions; ``centre_xy`` (m, 2) the lane centre over
    the same stretch. Both curves are shifted by ``-origin_m`` and resampled every ``spacing_m``.
    Curves with NaN / inf values or fewer than 2 points raise ValueError naming the argument.
    ``pcm`` is ``None`` where undefined (lane centre parallel to an axis).
    """
    path = as_curve(path_xy, "path_xy", n_dims=2)
    centre = as_curve(centre_xy, "centre_xy", n_dims=2)
    offset = as_series(offset_m, "offset_m", min_len=2)
    t = as_series(t_s, "t_s", min_len=2)
    check_same_length(path, "path_xy", offset, "offset_m")
    check_same_length(path, "path_xy", t, "t_s")
    shift = np.asarray(origin_m, dtype=float)
    exp = resample_by_arc_length(centre - shift, spacing_m)
    num = resample_by_arc_length(path - shift, spacing_m)
    extent = np.ptp(exp, axis=0)
    axis_parallel = bool(np.any(extent <= _AXIS_PARALLEL_TOL * max(float(np.max(extent)), 1.0)))
    return {
        "pcm": None if axis_parallel else float(pcm(exp, num)),
        "frechet_dist": float(frechet_dist(exp, num)),
        "area_between_two_curves": float(area_between_two_curves(exp, num)),
        "curve_length_measure": float(curve_length_measure(exp, num)),
        "dtw": float(dtw(exp, num, return_matrix=False)),
        "dtsi": float(dtsi(offset, t)),
    }


def _first_lap(columns: dict, track: TrackSpec) -> np.ndarray:
    """Indices of the logged steps up to the first wrap of the arc length (closed tracks)."""
    s = np.asarray(columns["arc_length_m"], dtype=float)
    if not track.closed or len(s) < 2:
        return np.arange(len(s))
    wraps = np.flatnonzero(np.diff(s) < -0.5 * track.length_m)
    return np.arange(len(s) if len(wraps) == 0 else wraps[0] + 1)


def _measure(columns: dict, rows: np.ndarray, centre: LaneCentre, spacing_m: float) -> dict | None:
    """Metrics over ``rows`` of a run log, or None when fewer than 2 points (or no length) remain."""
    if len(rows) < 2:
        return None
    s = np.asarray(columns["arc_length_m"], dtype=float)[rows]
    if not np.all(np.isfinite(s)):
        as_series(s, "arc_length_m")  # raises, naming the rows
    if not s.max() > s.min():
        return None
    path = np.column_stack([np.asarray(columns["x_m"], dtype=float)[rows], np.asarray(columns["y_m"], dtype=float)[rows]])
    return compare_to_lane_centre(path, centre.between(s.min(), s.max()),
                                  np.asarray(columns["lateral_offset_m"], dtype=float)[rows],
                                  np.asarray(columns["t_s"], dtype=float)[rows], spacing_m, centre.origin_m)


def _mean_metrics(per_segment: list[dict]) -> dict[str, float | None]:
    out: dict[str, float | None] = {}
    for metric in METRICS:
        values = [m[metric] for m in per_segment if m is not None and m[metric] is not None]
        out[metric] = float(np.mean(values)) if values else None
    return out


def segments_by_kind(track: TrackSpec) -> dict[str, list[int]]:
    """Indices of the track's segments of each kind (straight, left, right), in track order."""
    return {kind: [i for i, seg in enumerate(track.segments) if seg.direction == kind] for kind in SEGMENT_KINDS}


def representative_segment(track: TrackSpec, kind: str) -> int | None:
    """The segment of ``kind`` the figures show: the first one that does not start the track
    (the opening straight is a run-in from a centred start), else the first; None if there is none."""
    indices = segments_by_kind(track)[kind]
    later = [i for i in indices if i > 0]
    return (later or indices or [None])[0]


def run_trajectory_metrics(columns: dict, track: TrackSpec, centre: LaneCentre | None = None,
                           spacing_m: float = RESAMPLE_SPACING_M) -> dict[str, dict[str, float | None]]:
    """{part: {metric: value}} of one run's log columns (``x_m``, ``y_m``, ``arc_length_m``,
    ``lateral_offset_m``, ``t_s``); parts a run never reached have every metric ``None``."""
    centre = centre or LaneCentre(track, 0.0)
    rows = _first_lap(columns, track)
    full = _measure(columns, rows, centre, spacing_m)
    result = {"full": full if full is not None else dict.fromkeys(METRICS)}
    s = np.asarray(columns["arc_length_m"], dtype=float)[rows]
    starts = segment_starts_m(track)
    for kind, indices in segments_by_kind(track).items():
        per_segment = []
        for index in indices:
            inside = rows[(s >= starts[index]) & (s < starts[index + 1])]
            per_segment.append(_measure(columns, inside, centre, spacing_m))
        result[kind] = _mean_metrics(per_segment)
    return result


def trajectory_metrics(logs: dict, track, start_lane: int | None = None,
                       spacing_m: float = RESAMPLE_SPACING_M) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{part: {run: {metric: value}}}`` for run logs ``{name: RunLog}`` on ``track`` (a spec, name or path)."""
    track = resolve_track(track)
    centre = LaneCentre(track, start_lane_offset_m(track, start_lane))
    per_run = {name: run_trajectory_metrics(log.columns, track, centre, spacing_m) for name, log in logs.items()}
    return {part: {name: per_run[name][part] for name in logs} for part in PARTS}


def trajectory_method(track, start_lane: int | None = None, spacing_m: float = RESAMPLE_SPACING_M) -> dict:
    """How the trajectory numbers were made, for the JSON beside them."""
    track = resolve_track(track)
    return {
        "compared_with": "centre line of the starting lane, over the stretch each run covered",
        "lane_offset_m": start_lane_offset_m(track, start_lane),
        "resample_spacing_m": spacing_m,
        "parts": {"full": "the whole run",
                  **{kind: {"segments": idx, "aggregate": "mean over segments, each measured separately"}
                     for kind, idx in segments_by_kind(track).items()}},
        "dtsi": "EMDC reconstruction (plm_highway.metrics.lane) of the lateral offset and time within the part",
        "pcm_undefined": "null where the lane centre is parallel to an axis (zero x or y range)",
    }


def finite_or_none(value) -> float | None:
    """JSON has no NaN: undefined numbers are written as null."""
    return None if value is None or (isinstance(value, float) and not math.isfinite(value)) else value
