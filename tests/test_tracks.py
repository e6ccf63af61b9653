"""Track specs: loading, hand-checked geometry, validation errors, the built road network."""

from __future__ import annotations

import cmath
import json
import math

import numpy as np
import pytest
from highway_env.road.lane import CircularLane, StraightLane
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.road.builder import build_road
from plm_highway.road.geometry import reference_pose_at, sample_reference
from plm_highway.road.track import SHIPPED_TRACKS, end_pose, load_track, parse_track


def straight(length_m: float) -> dict:
    return {"type": "straight", "length_m": length_m}


def arc(radius_m: float, angle_deg: float, direction: str = "left") -> dict:
    return {"type": "arc", "radius_m": radius_m, "angle_deg": angle_deg, "direction": direction}


def spec(*segments: dict, **top) -> dict:
    return {"name": "t", "lanes": 3, "lane_width_m": 4.0, "segments": list(segments), **top}


def unchecked(raw: dict):
    """Parse without the self-overlap check: geometry and builder tests use roads no car should drive."""
    from unittest.mock import patch

    from plm_highway.road import track as track_module

    with patch.object(track_module, "_check_no_overlap", lambda track: None):
        return parse_track(raw)


def square_loop(side_m: float = 100.0, radius_m: float = 50.0) -> dict:
    return spec(*[s for _ in range(4) for s in (straight(side_m), arc(radius_m, 90))], closed=True)


# -- loading ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SHIPPED_TRACKS)
def test_shipped_tracks_load(name, repo_root):
    track = load_track(name)
    raw = json.loads((repo_root / "plm_highway" / "road" / "tracks" / f"{name}.json").read_text())
    assert track.name == name
    assert track.lanes == 3 and track.lane_width_m == 4.0 and track.closed is False
    assert len(track.segments) == len(raw["segments"]) >= 5
    # The length is the sum of the straights plus R * angle of each arc.
    expected_m = sum(s["length_m"] if s["type"] == "straight" else s["radius_m"] * math.radians(s["angle_deg"])
                     for s in raw["segments"])
    assert track.length_m == pytest.approx(expected_m)
    assert {seg.direction for seg in track.segments} == {"straight", "left", "right"}


def test_shipped_names_are_the_expected_three():
    assert set(SHIPPED_TRACKS) == {"train", "test", "unseen"}


def test_test_track_opens_with_a_straight_then_a_left_curve():
    track = load_track("test")
    first, second = track.segments[:2]
    assert (first.kind, first.length_m) == ("straight", 120.0)
    assert (second.kind, second.direction, second.radius_m) == ("arc", "left", 100.0)
    assert second.length_m == pytest.approx(100.0 * math.radians(70))
    assert second.curvature_1pm == pytest.approx(0.01)


def test_load_track_from_a_file(tmp_path):
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(spec(straight(100), arc(50, 90))))
    track = load_track(path)
    assert track.name == "t" and len(track.segments) == 2
    assert track.source == str(path)


def test_load_track_missing_file_and_bad_json(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.json"):
        load_track(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_track(bad)


# -- hand-computed geometry ------------------------------------------------------------------------


def test_end_pose_straight_then_left_quarter_circle():
    track = parse_track(spec(straight(100), arc(50, 90, "left")))
    x, y, heading = end_pose(track)
    # Straight to (100, 0); the left arc's centre is (100, 50); a quarter turn ends at (150, 50) facing north.
    assert (x, y, heading) == pytest.approx((150.0, 50.0, math.pi / 2), abs=1e-9)
    assert track.length_m == pytest.approx(100 + 50 * math.pi / 2)


def test_end_pose_straight_then_right_quarter_circle():
    track = parse_track(spec(straight(100), arc(50, 90, "right")))
    assert end_pose(track) == pytest.approx((150.0, -50.0, -math.pi / 2), abs=1e-9)


def test_end_pose_half_circle_left():
    # A left half circle of radius 20 from the origin heading east ends at (0, 40) heading west.
    track = parse_track(spec(arc(20, 180, "left")))
    assert end_pose(track) == pytest.approx((0.0, 40.0, math.pi), abs=1e-9)


def test_reference_pose_half_way_round_a_left_arc():
    track = parse_track(spec(straight(100), arc(50, 90, "left")))
    s_m = 100 + 50 * math.pi / 4  # 45 degrees into the arc
    x, y, heading = reference_pose_at(track, s_m)
    assert (x, y, heading) == pytest.approx(
        (100 + 50 * math.sin(math.pi / 4), 50 - 50 * math.cos(math.pi / 4), math.pi / 4), abs=1e-9)
    with pytest.raises(ValueError, match="outside"):
        reference_pose_at(track, track.length_m + 1.0)


def test_sample_reference_includes_segment_ends_and_curvature_sign():
    track = parse_track(spec(straight(100), arc(50, 90, "left"), arc(40, 30, "right")))
    ref = sample_reference(track, spacing_m=1.0)
    assert (ref.x_m[0], ref.y_m[0], ref.heading_rad[0]) == (0.0, 0.0, 0.0)
    i = int(np.argmin(np.abs(ref.s_m - 100.0)))
    assert ref.s_m[i] == pytest.approx(100.0) and (ref.x_m[i], ref.y_m[i]) == pytest.approx((100.0, 0.0))
    assert np.allclose(ref.curvature_1pm[ref.segment_index == 1], 1 / 50)
    assert np.allclose(ref.curvature_1pm[ref.segment_index == 2], -1 / 40)
    # The offset line 2 m to the left of an eastward straight lies at y = +2.
    left_x, left_y = ref.offset(2.0)
    assert left_y[0] == pytest.approx(2.0) and left_x[0] == pytest.approx(0.0)


# -- validation ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("raw", "fragments"),
    [
        (spec(straight(10), colour="red"), ["unknown keys", "colour"]),
        (spec(straight(10), {"type": "straight", "length_m": 5, "width": 3}), ["segment 1", "unknown keys", "width"]),
        (spec(straight(10), straight(0)), ["segment 1", "length_m"]),
        (spec(straight(-5)), ["segment 0", "length_m"]),
        (spec(straight(10), arc(0, 90)), ["segment 1", "radius_m"]),
        (spec(straight(10), straight(10), arc(-20, 90)), ["segment 2", "radius_m"]),
        # 3 lanes of 4 m: the road is 6 m either side; a radius below 6 + 4 = 10 m is too tight.
        (spec(straight(10), arc(9.5, 90)), ["segment 1", "radius_m", "too tight"]),
        (spec(straight(10), arc(50, 90, "up")), ["segment 1", "direction", "up"]),
        (spec(arc(50, 0)), ["segment 0", "angle_deg"]),
        (spec(arc(50, 400)), ["segment 0", "angle_deg"]),
        (spec(straight(10), {"type": "spiral", "length_m": 5}), ["segment 1", "type", "spiral"]),
        (spec(straight(10), {"type": "arc", "radius_m": 50, "angle_deg": 90}), ["segment 1", "missing", "direction"]),
        (spec(), ["segments", "non-empty"]),
        (spec(straight(100), arc(50, 90), straight(100), arc(50, 90), closed=True), ["closed"]),
        (spec(straight(float("nan"))), ["segment 0", "length_m"]),
        (spec(straight(True)), ["segment 0", "length_m"]),
        (spec(straight(10), lanes=0), ["lanes"]),
        (spec(straight(10), lane_width_m=-1), ["lane_width_m"]),
        ({"segments": [straight(10)]}, ["missing", "name"]),
    ],
)
def test_validation_errors_name_segment_and_field(raw, fragments):
    with pytest.raises(ValueError) as excinfo:
        parse_track(raw, source="unit")
    message = str(excinfo.value)
    assert message.startswith("unit")
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_minimum_radius_boundary_is_accepted():
    # Exactly half the road (6 m) plus one lane (4 m) is allowed.
    track = parse_track(spec(straight(10), arc(10, 90)))
    assert track.segments[1].radius_m == 10.0
    # A single 3 m lane: 1.5 + 3 = 4.5 m.
    parse_track(spec(arc(4.5, 90), lanes=1, lane_width_m=3.0))
    with pytest.raises(ValueError, match="radius_m"):
        parse_track(spec(arc(4.4, 90), lanes=1, lane_width_m=3.0))


def test_error_in_a_file_names_the_file(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(spec(straight(10), arc(50, 90, "sideways"))))
    with pytest.raises(ValueError) as excinfo:
        load_track(path)
    assert str(path) in str(excinfo.value) and "segment 1" in str(excinfo.value)
    assert "direction" in str(excinfo.value)


def test_closed_loop_that_closes_builds():
    track = parse_track(square_loop(), source="loop")
    assert track.closed
    assert end_pose(track) == pytest.approx((0.0, 0.0, 2 * math.pi), abs=1e-9)
    built = build_road(track)
    assert len(built.edges) == 8
    # The last edge comes back to the first node.
    assert built.edges[-1].key == ("n7", "n0")
    assert built.edges[0].key == ("n0", "n1")


def test_closed_loop_with_a_gap_is_rejected():
    raw = square_loop(side_m=100.0)
    raw["segments"][-2] = straight(101.0)  # 1 m too long: misses the start by 1 m
    with pytest.raises(ValueError, match="closed"):
        parse_track(raw)


# -- the built road network ------------------------------------------------------------------------


@pytest.mark.parametrize(("angle_deg", "pieces"), [(90, 1), (169, 1), (180, 2), (270, 2), (340, 2), (360, 3)])
def test_long_arcs_are_split_into_several_edges(angle_deg, pieces):
    track = unchecked(spec(straight(20), arc(60, angle_deg), straight(20)))
    built = build_road(track)
    arc_edges = [edge for edge in built.edges if edge.segment_index == 1]
    assert len(arc_edges) == pieces
    assert len(built.edges) == pieces + 2
    assert sum(edge.length_m for edge in arc_edges) == pytest.approx(60 * math.radians(angle_deg))
    for edge in arc_edges:
        assert edge.length_m / 60 < math.pi  # every piece well below the wrap of local_coordinates
        for lane_id in range(3):
            assert isinstance(built.network.get_lane((*edge.key, lane_id)), CircularLane)
    # Edges are contiguous in arc length.
    starts = [edge.start_s_m for edge in built.edges]
    assert starts == pytest.approx(np.concatenate([[0.0], np.cumsum([e.length_m for e in built.edges])[:-1]]))


def test_split_arc_pieces_join_up():
    track = parse_track(spec(arc(60, 300, "left")))
    built = build_road(track)
    assert len(built.edges) == 2
    first = built.network.get_lane((*built.edges[0].key, 1))
    second = built.network.get_lane((*built.edges[1].key, 1))
    assert first.position(first.length, 0) == pytest.approx(second.position(0, 0), abs=1e-6)
    # End of the 300-degree left arc around the centre (0, 60).
    end = second.position(second.length, 0)
    expected = (60 * math.sin(math.radians(300)), 60 - 60 * math.cos(math.radians(300)))
    assert end == pytest.approx(expected, abs=1e-6)
    # Points on the far side of the circle project back onto the right piece (no wrap at pi).
    lon, lat = second.local_coordinates(np.array(expected))
    assert lon == pytest.approx(second.length, abs=1e-6) and lat == pytest.approx(0.0, abs=1e-6)


def test_lane_zero_is_leftmost_on_a_straight():
    track = parse_track(spec(straight(100), arc(50, 90)))
    built = build_road(track)
    assert built.lane_offsets_m == pytest.approx((4.0, 0.0, -4.0))
    key = built.edges[0].key
    lanes = [built.network.get_lane((*key, i)) for i in range(3)]
    assert all(isinstance(lane, StraightLane) for lane in lanes)
    # Heading east, left is north: lane 0 is 4 m north of lane 1, lane 2 4 m south.
    y = [lane.position(50.0, 0.0)[1] for lane in lanes]
    assert y == pytest.approx([4.0, 0.0, -4.0])
    # A lane's positive lateral coordinate points to the driver's left (north here).
    assert lanes[1].position(50.0, 1.0) == pytest.approx((50.0, 1.0))
    assert lanes[1].local_coordinates(np.array([30.0, 1.5])) == pytest.approx((30.0, 1.5))


@pytest.mark.parametrize("direction", ["left", "right"])
def test_inner_lane_of_an_arc_has_the_smaller_radius(direction):
    track = parse_track(spec(straight(100), arc(50, 90, direction)))
    built = build_road(track)
    key = built.edges[1].key
    lanes = [built.network.get_lane((*key, i)) for i in range(3)]
    radii = [lane.radius for lane in lanes]
    if direction == "left":  # lane 0 (leftmost) is on the inside
        assert radii == pytest.approx([46.0, 50.0, 54.0])
    else:
        assert radii == pytest.approx([54.0, 50.0, 46.0])
    sign = 1 if direction == "left" else -1
    centre = np.array([100.0, sign * 50.0])
    for lane, radius in zip(lanes, radii):
        for s in (0.0, lane.length / 2, lane.length):
            assert np.linalg.norm(lane.position(s, 0.0) - centre) == pytest.approx(radius)
    # The middle lane starts where the straight ends and ends at the hand-computed end pose.
    assert lanes[1].position(0.0, 0.0) == pytest.approx((100.0, 0.0), abs=1e-9)
    assert lanes[1].position(lanes[1].length, 0.0) == pytest.approx((150.0, sign * 50.0), abs=1e-9)
    assert lanes[1].heading_at(lanes[1].length) == pytest.approx(sign * math.pi / 2)
    # Positive lateral still means left of the direction of travel: at the arc's start (heading east)
    # that is north for both directions.
    assert lanes[1].position(0.0, 1.0) == pytest.approx((100.0, 1.0), abs=1e-9)


# -- property: the sampled reference line is continuous --------------------------------------------

MIN_RADIUS_M = 10.0  # 3 lanes of 4 m

segment_strategy = st.one_of(
    st.builds(straight, st.floats(0.5, 200.0)),
    st.builds(arc, st.floats(MIN_RADIUS_M, 400.0), st.floats(1.0, 360.0), st.sampled_from(["left", "right"])),
)


def _independent_end(segments: list[dict]) -> tuple[complex, float]:
    """End position (as a complex number) and heading, by rotating about each arc's centre."""
    position, heading = 0j, 0.0
    for seg in segments:
        if seg["type"] == "straight":
            position += seg["length_m"] * cmath.exp(1j * heading)
        else:
            sign = 1 if seg["direction"] == "left" else -1
            centre = position + sign * 1j * seg["radius_m"] * cmath.exp(1j * heading)
            turn = sign * math.radians(seg["angle_deg"])
            position = centre + (position - centre) * cmath.exp(1j * turn)
            heading += turn
    return position, heading


@settings(max_examples=40, deadline=None)
@given(segments=st.lists(segment_strategy, min_size=1, max_size=6), spacing_m=st.sampled_from([0.25, 0.5, 1.0, 2.0]))
def test_sampled_reference_line_is_continuous(segments, spacing_m):
    track = unchecked(spec(*segments))
    ref = sample_reference(track, spacing_m=spacing_m)
    steps_m = np.hypot(np.diff(ref.x_m), np.diff(ref.y_m))
    assert np.all(steps_m <= spacing_m + 1e-6)
    assert np.all(np.diff(ref.s_m) > 0)
    assert np.all(np.diff(ref.s_m) <= spacing_m + 1e-9)
    # Heading never jumps by more than spacing / the tightest radius.
    turns = np.abs(np.diff(ref.heading_rad))
    assert np.all(turns <= spacing_m / MIN_RADIUS_M + 1e-9)
    # The line starts at the origin heading east and ends where rotating about the arc centres says.
    assert (ref.x_m[0], ref.y_m[0], ref.heading_rad[0]) == (0.0, 0.0, 0.0)
    end, heading = _independent_end(segments)
    assert ref.s_m[-1] == pytest.approx(track.length_m)
    assert (ref.x_m[-1], ref.y_m[-1]) == pytest.approx((end.real, end.imag), abs=1e-6)
    assert ref.heading_rad[-1] == pytest.approx(heading, abs=1e-9)
    assert set(np.unique(ref.segment_index)) == set(range(len(segments)))


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.floats(1.0, 200.0), min_size=1, max_size=8), closed=st.booleans(),
       queries=st.lists(st.floats(-50.0, 2000.0), min_size=1, max_size=60))
def test_segment_lookup_with_its_cache_agrees_with_the_vectorised_lookup(lengths, closed, queries):
    """The scalar look-up remembers the last segment; any order of queries gives the searched answer."""
    from plm_highway.road.geometry import SegmentLookup, segment_index_at
    from plm_highway.road.spec import Segment, TrackSpec

    track = TrackSpec("q", 3, 4.0, tuple(Segment("straight", length) for length in lengths), closed)
    lookup = SegmentLookup(track)
    for s_m in queries:
        assert lookup.segment_index(s_m) == int(segment_index_at(track, s_m)), s_m


@settings(max_examples=60, deadline=None)
@given(radius_m=st.floats(20.0, 500.0), angle_deg=st.floats(5.0, 169.0), direction=st.sampled_from(["left", "right"]),
       offset_m=st.sampled_from([-4.0, 0.0, 4.0]), points=st.lists(st.tuples(st.floats(-300, 300), st.floats(-300, 300)),
                                                                     min_size=1, max_size=10))
def test_scalar_lane_frames_are_highway_env_lanes_to_the_last_bits(radius_m, angle_deg, direction, offset_m, points):
    """The env's tracker replaces highway-env's lane arithmetic, operation for operation, in ``math`` instead of
    numpy. Equal to a few units in the last place, not bit for bit: numpy's float64 ``arctan2`` is CPU-dispatched
    (on an AVX-512 Xeon it differs from libm's ``atan2`` in the last bit, on an AVX2 CPU it agreed)."""
    from plm_highway.road.builder import ArcFrame, StraightFrame

    built = build_road(parse_track(spec(straight(37.5), arc(radius_m, angle_deg, direction))))
    for edge in built.edges:
        for lane in built.network.graph[edge.key[0]][edge.key[1]]:
            frame = StraightFrame.of(lane) if isinstance(lane, StraightLane) else ArcFrame.of(lane)
            assert frame.length_m == lane.length
            for x_m, y_m in points:
                expected = lane.local_coordinates(np.array([x_m, y_m]))
                scale_m = radius_m + abs(x_m) + abs(y_m)  # the size of the numbers the arithmetic handles
                got = frame.local_coordinates(x_m, y_m)
                for ours, theirs in zip(got, (float(expected[0]), float(expected[1]))):
                    assert abs(ours - theirs) <= 8 * math.ulp(scale_m), (got, expected)
                assert frame.heading_at(expected[0]) == pytest.approx(lane.heading_at(expected[0]), rel=0, abs=1e-14)
