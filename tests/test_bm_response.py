"""``plm-highway bm-response``: the BM's steering beside its demonstrator's law at posed starts."""

from __future__ import annotations

import json
import math

import pytest

from plm_highway import cli
from plm_highway.errors import BadInput
from plm_highway.evaluation.response import bm_response


def law_by_hand(curvature_1pm: float, max_steering_rad: float) -> float:
    # highway-env's bicycle: sin(beta) = (L/2) kappa with L = 5 m, steering = atan(2 tan(beta)).
    beta = math.asin(2.5 * curvature_1pm)
    return math.atan(2.0 * math.tan(beta)) / max_steering_rad


def test_the_law_column_is_the_demonstrators_law_from_the_true_pose():
    result = bm_response("test", "ideal", offsets_m=(1.0,), headings_rad=(0.1,))
    # ideal: the expert (3 rad/s, damping 0.9) at 16.7 m/s on a straight, 0.2 rad of steering range.
    k_offset, k_heading = 9.0 / 16.7 ** 2, 2 * 0.9 * 3.0 / 16.7
    assert result["sweeps"]["offset"]["law"][0] == pytest.approx(law_by_hand(-k_offset * 1.0, 0.2), abs=1e-3)
    assert result["sweeps"]["heading"]["law"][0] == pytest.approx(law_by_hand(-k_heading * math.sin(0.1), 0.2),
                                                                   abs=1e-3)
    assert result["law"] == {"natural_frequency_radps": 3.0, "damping_ratio": 0.9, "demonstrator": "expert"}


def test_the_paper_bm_follows_its_driver_near_the_centre_and_saturates_beyond_the_demonstrations():
    """The finding docs/calibration.md reports: within 2 m the shipped paper BM steers like the human-like driver's law
    (2 rad/s, damping 0.9); at 4.5 m and at 0.2 rad of heading error it steers well under half to two thirds of it."""
    result = bm_response("test", "paper", offsets_m=(-4.5, -1.0, 1.0, 2.0, 4.5), headings_rad=(-0.2, 0.2))
    assert result["law"]["natural_frequency_radps"] == 2.0 and result["max_steering_rad"] == 0.4
    offset = result["sweeps"]["offset"]
    ratios = [bm / law for bm, law in zip(offset["bm"], offset["law"])]
    assert all(0.7 <= r <= 1.5 for r in ratios[1:4])
    assert ratios[0] < 0.6 and ratios[4] < 0.6
    heading = result["sweeps"]["heading"]
    assert all(0.0 < bm / law < 0.75 for bm, law in zip(heading["bm"], heading["law"]))


@pytest.mark.parametrize(("segment", "curvature_1pm"), [("left", 1 / 110), ("right", -1 / 90)])
def test_on_a_turn_the_car_is_posed_in_the_longest_one_and_the_law_steers_its_curve(segment, curvature_1pm):
    # The test track's longest left arc has a radius of 110 m and its longest right arc 90 m (both 172.8 m long).
    # Posed on the lane centre along the road, the law steers the curve less its heading term: it counts the
    # bicycle's steady slip angle, asin((L/2) kappa) = asin(2.5 kappa), as course error.
    result = bm_response("test", "ideal", offsets_m=(0.0,), headings_rad=(0.0,), segment=segment)
    assert result["segment"] == segment
    k_heading = 2 * 0.9 * 3.0 / 16.7
    expected = law_by_hand(curvature_1pm - k_heading * 2.5 * curvature_1pm, 0.2)
    assert result["sweeps"]["offset"]["law"][0] == pytest.approx(expected, abs=1e-3)
    assert result["sweeps"]["offset"]["bm"][0] * curvature_1pm > 0  # the BM turns the same way
    straight = bm_response("test", "ideal", offsets_m=(0.0,), headings_rad=(0.0,))
    assert straight["segment"] == "straight" and straight["sweeps"]["offset"]["law"][0] == pytest.approx(0.0, abs=1e-6)


def test_a_track_without_such_a_segment_is_refused():
    from plm_highway.evaluation.response import longest_segment_middle_m
    from plm_highway.road.track import parse_track

    only_left = parse_track({"name": "ring", "lanes": 3, "lane_width_m": 4.0, "closed": False, "segments": [
        {"type": "straight", "length_m": 50}, {"type": "arc", "radius_m": 60, "angle_deg": 90, "direction": "left"},
        {"type": "straight", "length_m": 80}]})
    assert longest_segment_middle_m(only_left, "straight") == pytest.approx(50 + 60 * math.pi / 2 + 40)
    assert longest_segment_middle_m(only_left, "left") == pytest.approx(50 + 30 * math.pi / 2)
    with pytest.raises(BadInput, match="track 'ring' has no right turn segment"):
        longest_segment_middle_m(only_left, "right")
    with pytest.raises(BadInput, match=r"--segment: 'curve' is not one of \['straight', 'left', 'right'\]"):
        longest_segment_middle_m(only_left, "curve")


def test_a_pose_off_the_road_is_refused():
    with pytest.raises(BadInput, match=r"offsets \[7\.0\] m would pose the car off the road"):
        bm_response("test", "ideal", offsets_m=(0.0, 7.0), headings_rad=(0.0,))


def test_command_writes_the_figure_and_its_numbers_and_refuses_to_overwrite_them(tmp_path, capsys):
    out = tmp_path / "response.png"
    assert cli.main(["bm-response", "--conditions", "ideal", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    numbers = json.loads(out.with_suffix(".json").read_text())
    assert len(numbers["sweeps"]["offset"]["bm"]) == 21 and len(numbers["sweeps"]["heading"]["bm"]) == 11
    assert "BM / law along the offset sweep" in printed
    # On a straight the law is odd in the pose: mirrored offsets and headings steer mirrored.
    for sweep in numbers["sweeps"].values():
        assert sweep["law"] == pytest.approx([-w for w in reversed(sweep["law"])], abs=1e-9)
    before = out.read_bytes()
    assert cli.main(["bm-response", "--conditions", "ideal", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err and out.read_bytes() == before
