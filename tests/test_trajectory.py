"""Trajectory comparison against the lane centre: exact cases worked out by hand, parts, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plm_highway.evaluation.trajectory import (
    METRICS,
    PARTS,
    RESAMPLE_SPACING_M,
    LaneCentre,
    compare_to_lane_centre,
    representative_segment,
    run_trajectory_metrics,
    segments_by_kind,
    start_lane_offset_m,
    trajectory_method,
)
from plm_highway.road.geometry import reference_pose_at, segment_starts_m
from plm_highway.road.track import load_track, parse_track

TEST_TRACK = load_track("test")
STEP_M = 16.7 * 0.05  # one policy step at 60 km/h


def drive_along(track, offset_m: float, step_m: float = STEP_M, until_m: float | None = None) -> dict:
    """Log columns of a car that holds ``offset_m`` left of the reference line exactly."""
    s = np.arange(0.0, until_m if until_m is not None else track.length_m, step_m)
    poses = np.array([reference_pose_at(track, float(v)) for v in s])
    return {"t_s": s / 16.7, "arc_length_m": s,
            "x_m": poses[:, 0] - offset_m * np.sin(poses[:, 2]), "y_m": poses[:, 1] + offset_m * np.cos(poses[:, 2]),
            "lateral_offset_m": np.full(len(s), offset_m)}


def offset_piece(centre_xy: np.ndarray, offset_m: float) -> np.ndarray:
    """A straight piece moved ``offset_m`` to its left."""
    direction = (centre_xy[-1] - centre_xy[0]) / np.linalg.norm(centre_xy[-1] - centre_xy[0])
    return centre_xy + offset_m * np.array([-direction[1], direction[0]])


def test_a_curve_against_itself_scores_zero_on_every_metric():
    centre = LaneCentre(TEST_TRACK).between(0.0, TEST_TRACK.length_m)
    t_s = np.linspace(0.0, 68.0, len(centre))
    metrics = compare_to_lane_centre(centre, centre, np.zeros(len(centre)), t_s, origin_m=(-10.0, -70.0))
    assert set(metrics) == set(METRICS)
    for name, value in metrics.items():  # the area adds quads of a 1 km curve: rounding at 1e-8 m^2
        assert value == pytest.approx(0.0, abs=1e-6 if name == "area_between_two_curves" else 1e-9), name


def test_a_run_on_the_lane_centre_scores_about_zero_in_every_part():
    # The run's points lie on the arcs 0.835 m apart, the lane centre is a 0.25 m polyline: their
    # chords differ by about a millimetre (sagitta 0.835^2 / (8 x 80 m) = 1.1 mm), nothing more.
    result = run_trajectory_metrics(drive_along(TEST_TRACK, 0.0), TEST_TRACK)
    assert set(result) == set(PARTS)
    for part in PARTS:
        assert result[part]["frechet_dist"] < 2.5e-3, part
        assert result[part]["dtsi"] == 0.0
        assert result[part]["area_between_two_curves"] < 1e-3 * TEST_TRACK.length_m, part  # < 1 mm mean gap
    assert result["straight"]["frechet_dist"] < 1e-9  # straights: exact


def test_constant_offset_on_a_straight_by_hand():
    """60 m straight (segment 2), path 0.3 m to its left: resampled every 0.1 m both have 601 points.

    Frechet = 0.3 (every pair is 0.3 apart and no coupling can do better); area = 0.3 x 60 = 18 m^2
    (a parallelogram strip); DTW = 601 x 0.3 = 180.3 (the diagonal coupling, each term 0.3).
    """
    assert RESAMPLE_SPACING_M == 0.1
    start_m, end_m = segment_starts_m(TEST_TRACK)[2:4]
    assert end_m - start_m == pytest.approx(60.0)
    centre = LaneCentre(TEST_TRACK).between(start_m, end_m)
    path = offset_piece(centre, 0.3)
    metrics = compare_to_lane_centre(path, centre, np.full(len(path), 0.3), np.arange(len(path)) * 0.05,
                                     origin_m=(0.0, -70.0))
    assert metrics["frechet_dist"] == pytest.approx(0.3, abs=1e-9)
    assert metrics["area_between_two_curves"] == pytest.approx(18.0, rel=1e-9)
    assert metrics["dtw"] == pytest.approx(180.3, rel=1e-9)
    assert metrics["dtsi"] == 0.0  # 0.3 m is inside the 0.7071 m dead zone and never changes


def test_dtsi_of_a_steady_1m_offset_by_hand():
    # MMDC = f(1.0) = 5.256 (0.2 - 0.1) = 0.5256; MDDC = 0 (constant); EMDC = 0.5 MMDC = 0.2628
    start_m, end_m = segment_starts_m(TEST_TRACK)[2:4]
    centre = LaneCentre(TEST_TRACK).between(start_m, end_m)
    path = offset_piece(centre, 1.0)
    metrics = compare_to_lane_centre(path, centre, np.ones(len(path)), np.arange(len(path)) * 0.05)
    assert metrics["dtsi"] == pytest.approx(0.2628, rel=1e-12)
    assert metrics["frechet_dist"] == pytest.approx(1.0, abs=1e-9)


def test_parts_average_every_segment_of_their_kind():
    d = 0.4
    log = drive_along(TEST_TRACK, d)
    result = run_trajectory_metrics(log, TEST_TRACK)
    # straights: each is measured over the stretch the run's points cover, an exact parallel strip
    starts = segment_starts_m(TEST_TRACK)
    areas = []
    for index in segments_by_kind(TEST_TRACK)["straight"]:
        inside = log["arc_length_m"][(log["arc_length_m"] >= starts[index]) & (log["arc_length_m"] < starts[index + 1])]
        areas.append(d * (inside.max() - inside.min()))
    assert result["straight"]["frechet_dist"] == pytest.approx(d, abs=1e-9)
    assert result["straight"]["area_between_two_curves"] == pytest.approx(np.mean(areas), rel=1e-6)
    # on arcs the offset path is shorter or longer than the lane centre, the two resamplings drift out
    # of phase and coupled points can be up to half a spacing apart along the road; the logged points'
    # chords also cut the arcs by up to a millimetre (0.835^2 / (8 x 80 m))
    for part in ("left", "right", "full"):
        assert d - 1e-3 <= result[part]["frechet_dist"] <= math.hypot(d, RESAMPLE_SPACING_M / 2) + 1.2e-3, part
    # PCM is undefined on the first straight (heading east: zero y range) and is skipped there
    assert result["straight"]["pcm"] is not None and math.isfinite(result["straight"]["pcm"])


def test_resampling_makes_metrics_independent_of_the_logging_rate():
    coarse = run_trajectory_metrics(drive_along(TEST_TRACK, 0.3), TEST_TRACK)
    fine = run_trajectory_metrics(drive_along(TEST_TRACK, 0.3, step_m=STEP_M / 2), TEST_TRACK)
    for metric in ("dtw", "pcm", "curve_length_measure", "area_between_two_curves", "frechet_dist"):
        assert fine["full"][metric] == pytest.approx(coarse["full"][metric], rel=0.02), metric


def test_parts_a_short_run_never_reached_are_none():
    result = run_trajectory_metrics(drive_along(TEST_TRACK, 0.2, until_m=60.0), TEST_TRACK)
    assert all(value is None for value in result["left"].values())
    assert all(value is None for value in result["right"].values())
    assert result["straight"]["pcm"] is None  # only the east-heading first straight: PCM undefined
    assert result["straight"]["frechet_dist"] == pytest.approx(0.2, abs=1e-9)
    assert result["full"]["frechet_dist"] == pytest.approx(0.2, abs=1e-9)


def test_lane_centre_is_the_start_lane_centre():
    assert start_lane_offset_m(TEST_TRACK) == 0.0  # middle of three lanes: the reference line
    two_lanes = parse_track({"name": "two", "lanes": 2, "segments": [{"type": "straight", "length_m": 100}]})
    assert start_lane_offset_m(two_lanes) == pytest.approx(-2.0)  # lanes // 2 = lane 1, right of the reference
    assert start_lane_offset_m(two_lanes, 0) == pytest.approx(2.0)
    centre = LaneCentre(two_lanes, -2.0).between(10.0, 20.0)
    np.testing.assert_allclose(centre[[0, -1]], [[10.0, -2.0], [20.0, -2.0]], atol=1e-12)
    with pytest.raises(ValueError, match="start_lane 5"):
        start_lane_offset_m(two_lanes, 5)


def test_method_documents_the_segments_used():
    method = trajectory_method(TEST_TRACK)
    assert method["resample_spacing_m"] == RESAMPLE_SPACING_M
    assert method["parts"]["straight"]["segments"] == [0, 2, 4, 7, 9]
    assert method["parts"]["left"]["segments"] == [1, 5, 8]
    assert method["parts"]["right"]["segments"] == [3, 6]
    assert representative_segment(TEST_TRACK, "straight") == 2  # not the run-in straight
    assert representative_segment(TEST_TRACK, "left") == 1


@pytest.mark.parametrize("bad, message", [
    ({"path": np.array([[0.0, 0.0], [1.0, np.nan], [2.0, 0.0]])}, r"path_xy: 1 NaN value at row \[1\]"),
    ({"path": np.array([[0.0, 0.0]])}, "path_xy: needs at least 2 points, got 1"),
    ({"centre": np.array([[0.0, 0.0]])}, "centre_xy: needs at least 2 points, got 1"),
    ({"centre": np.array([[0.0, 0.0], [np.inf, 1.0]])}, r"centre_xy: 1 inf value at row \[1\]"),
    ({"offset": np.array([0.0, 0.1])}, "lengths differ"),
])
def test_bad_curves_are_refused_with_a_clear_message(bad, message):
    centre = np.array([[0.0, 0.0], [1.0, 0.1], [2.0, 0.0]])
    path = bad.get("path", centre + [0.0, 0.2])
    offset = bad.get("offset", np.full(len(path), 0.2))
    with pytest.raises(ValueError, match=message):
        compare_to_lane_centre(path, bad.get("centre", centre), offset, np.arange(len(path)) * 0.05)
