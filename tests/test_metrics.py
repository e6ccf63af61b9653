"""The strict curve metrics against similaritymeasures 1.5.0, plus resampling, DTSI and the bench.

The drop-in module (plm_highway.metrics.similarity) has its own tests: test_metrics_similarity.py.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import similaritymeasures as sm
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from plm_highway import cli
from plm_highway import metrics as pm
from plm_highway.bench import metrics as bench

REL_TOL = 1e-9
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
COORDS = st.floats(-100.0, 100.0, allow_nan=False, allow_subnormal=False)


@st.composite
def curve_pairs(draw, n_dims=2, max_points=60):
    n_exp = draw(st.integers(2, max_points))
    n_num = n_exp if draw(st.booleans()) else draw(st.integers(2, max_points))
    exp = draw(hnp.arrays(np.float64, (n_exp, n_dims), elements=COORDS))
    num = draw(hnp.arrays(np.float64, (n_num, n_dims), elements=COORDS))
    return exp, num


def quietly(fn, *args, **kwargs):
    """Call without numpy's divide/invalid warnings, which the reference emits on degenerate curves."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return fn(*args, **kwargs)


def assert_matches(ours, reference, atol: float = 0.0):
    np.testing.assert_allclose(ours, reference, rtol=REL_TOL, atol=atol, equal_nan=True)


# PCM and the curve-length measure work on curves normalised to their range (dimensionless, O(1) values): where the
# exact result is 0, numpy's CPU-dispatched kernels leave a few 1e-16 on one CPU and exactly 0 on another (seen:
# PCM 3.1e-16 against 0 for curves equal up to repeated end points).
NORMALISED_ATOL = 1e-12


def area_atol(*curves) -> float:
    """The reference sums signed triangle areas, and numpy's CPU-dispatched kernels round that sum differently
    on AVX-512 and AVX2 CPUs: two identical curves with coordinates ~50 gave 9e-13 on one, exactly 0 on another."""
    return 1e-12 * max(1.0, *(float(np.max(np.abs(c))) for c in curves)) ** 2


def smooth_pair(n_points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    return bench.make_curves(n_points, seed)


# ---------------------------------------------------------------------------------------------
# equality with similaritymeasures
# ---------------------------------------------------------------------------------------------


@SETTINGS
@given(
    n_dims=st.integers(1, 3),
    p=st.sampled_from([1, 2, 3, 0.5, math.inf]),
    data=st.data(),
)
def test_frechet_matches_reference(n_dims, p, data):
    exp, num = data.draw(curve_pairs(n_dims=n_dims))
    assert_matches(pm.frechet_dist(exp, num, p=p), sm.frechet_dist(exp, num, p=p))


DTW_METRICS = [
    ("euclidean", {}),
    ("sqeuclidean", {}),
    ("cityblock", {}),
    ("chebyshev", {}),
    ("minkowski", {"p": 3}),
    ("canberra", {}),  # not computed inline: goes through scipy's cdist
]


@SETTINGS
@given(n_dims=st.integers(1, 3), metric=st.sampled_from(DTW_METRICS), data=st.data())
def test_dtw_distance_and_matrix_match_reference(n_dims, metric, data):
    exp, num = data.draw(curve_pairs(n_dims=n_dims))
    name, kwargs = metric
    ref_distance, ref_matrix = quietly(sm.dtw, exp, num, name, **kwargs)
    distance, matrix = quietly(pm.dtw, exp, num, name, **kwargs)
    assert matrix.shape == ref_matrix.shape
    assert_matches(matrix, ref_matrix)
    assert_matches(distance, ref_distance)
    assert_matches(quietly(pm.dtw, exp, num, name, return_matrix=False, **kwargs), ref_distance)


@SETTINGS
@given(pair=curve_pairs())
def test_area_matches_reference(pair):
    exp, num = pair
    assert_matches(pm.area_between_two_curves(exp, num), sm.area_between_two_curves(exp, num), area_atol(exp, num))


@SETTINGS
@given(pair=curve_pairs())
def test_curve_length_measure_matches_reference(pair):
    exp, num = pair
    reference = quietly(sm.curve_length_measure, exp, num)
    if np.all(exp == exp[0]):
        assert np.isnan(reference)
        with pytest.raises(ValueError, match="exp_data: curve has zero length"):
            pm.curve_length_measure(exp, num)
        return
    assert_matches(quietly(pm.curve_length_measure, exp, num), reference, NORMALISED_ATOL)


@SETTINGS
@given(pair=curve_pairs(), norm_seg_length=st.booleans())
def test_pcm_matches_reference(pair, norm_seg_length):
    exp, num = pair
    reference = quietly(sm.pcm, exp, num, norm_seg_length)
    if np.any(np.ptp(exp, axis=0) == 0):
        assert np.isnan(reference)
        with pytest.raises(ValueError, match="range is zero"):
            pm.pcm(exp, num, norm_seg_length)
        return
    assert_matches(pm.pcm(exp, num, norm_seg_length), reference, NORMALISED_ATOL)


def test_pcm_with_num_collapsed_to_a_point_matches_reference():
    exp, _ = smooth_pair(30, seed=4)
    for n_num in (3, 12):  # np.interp searches linearly up to 4 points, by bisection beyond
        num = np.tile(exp[7] + 0.5, (n_num, 1))
        assert_matches(pm.pcm(exp, num), quietly(sm.pcm, exp, num))


@pytest.mark.parametrize("seed", [0, 1])
def test_larger_smooth_curves_match_reference(seed):
    exp, num = smooth_pair(300, seed)
    num = num[:250]
    for name in ("frechet_dist", "area_between_two_curves", "curve_length_measure", "pcm"):
        for a, b in ((exp, num), (num, exp)):
            assert_matches(getattr(pm, name)(a, b), getattr(sm, name)(a, b))
    distance, matrix = pm.dtw(exp, num)
    ref_distance, ref_matrix = sm.dtw(exp, num)
    assert_matches(matrix, ref_matrix)
    assert_matches(distance, ref_distance)


def test_area_with_ties_and_vertical_segments_matches_reference():
    # equal-length and vertical segments exercise the original's tie-break and np.interp branches
    rng = np.random.default_rng(7)
    exp = np.column_stack([np.arange(300.0), 5 + np.round(rng.normal(size=300))])
    num = np.column_stack([np.repeat(np.arange(0.0, 300.0, 6.0), 2), 5 + np.round(rng.normal(size=100))])
    num = np.vstack([num, [[299.0, 5.0]]])
    assert_matches(pm.area_between_two_curves(exp, num), sm.area_between_two_curves(exp, num), area_atol(exp, num))
    assert_matches(pm.area_between_two_curves(num, exp), sm.area_between_two_curves(num, exp), area_atol(exp, num))


def test_results_are_plain_floats_and_inputs_untouched():
    exp, num = smooth_pair(40, seed=2)
    exp_before, num_before = exp.copy(), num.copy()
    for name in ("frechet_dist", "area_between_two_curves", "curve_length_measure", "pcm"):
        assert isinstance(getattr(pm, name)(exp, num), float)
    assert isinstance(pm.dtw(exp, num, return_matrix=False), float)
    np.testing.assert_array_equal(exp, exp_before)
    np.testing.assert_array_equal(num, num_before)


def test_dtw_with_a_callable_metric_matches_reference():
    exp, num = smooth_pair(30, seed=6)

    def manhattan(u, v):
        return float(np.abs(u - v).sum())

    distance, matrix = pm.dtw(exp, num, manhattan)
    ref_distance, ref_matrix = sm.dtw(exp, num, manhattan)
    assert_matches(matrix, ref_matrix)
    assert_matches(distance, ref_distance)


def test_accepts_lists_and_integer_arrays_like_the_original():
    exp = [[0, 0], [1, 2], [3, 3], [4, 1]]
    num = np.array([[0, 1], [2, 2], [4, 2]])
    assert_matches(pm.frechet_dist(exp, num), sm.frechet_dist(exp, num))
    assert_matches(pm.dtw(exp, num)[0], sm.dtw(exp, num)[0])


# ---------------------------------------------------------------------------------------------
# resampling
# ---------------------------------------------------------------------------------------------


def polyline_length(xy: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1)))


@SETTINGS
@given(
    xy=hnp.arrays(np.float64, st.tuples(st.integers(2, 30), st.just(2)), elements=COORDS),
    spacing_m=st.floats(0.05, 50.0),
)
def test_resampling_properties(xy, spacing_m):
    total_m = polyline_length(xy)
    if total_m == 0:
        with pytest.raises(ValueError, match="zero length"):
            pm.resample_by_arc_length(xy, spacing_m)
        return
    out = pm.resample_by_arc_length(xy, spacing_m)
    np.testing.assert_array_equal(out[0], xy[0])
    np.testing.assert_array_equal(out[-1], xy[-1])
    assert len(out) in (math.floor(total_m / spacing_m) + 1, math.floor(total_m / spacing_m) + 2)
    chords_m = np.linalg.norm(np.diff(out, axis=0), axis=1)
    # a chord never exceeds the arc length it spans
    assert np.all(chords_m <= spacing_m * (1 + 1e-9))
    assert polyline_length(out) <= total_m * (1 + 1e-12)


def test_resampling_a_straight_line_keeps_spacing_and_length():
    xy = np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0], [6.6, 8.8]])  # 11 m along one direction
    out = pm.resample_by_arc_length(xy, 2.0)
    chords_m = np.linalg.norm(np.diff(out, axis=0), axis=1)
    np.testing.assert_allclose(chords_m, [2, 2, 2, 2, 2, 1], rtol=1e-12)
    assert polyline_length(out) == pytest.approx(11.0, rel=1e-12)


def test_resampling_an_exact_multiple_does_not_duplicate_the_end():
    out = pm.resample_by_arc_length([[0.0, 0.0], [10.0, 0.0]], 2.5)
    np.testing.assert_allclose(out[:, 0], [0, 2.5, 5, 7.5, 10])


def test_resampling_a_curve_much_shorter_than_the_spacing_keeps_both_ends():
    out = pm.resample_by_arc_length([[5e-39, 0.0], [0.0, 0.0]], 1.0)
    np.testing.assert_array_equal(out, [[5e-39, 0.0], [0.0, 0.0]])


def test_resampling_a_circle_preserves_length():
    angle = np.linspace(0, 2 * np.pi, 2001)
    xy = 100 * np.column_stack([np.cos(angle), np.sin(angle)])
    out = pm.resample_by_arc_length(xy, 1.0)
    assert polyline_length(out) == pytest.approx(polyline_length(xy), rel=1e-4)


def test_resampling_drops_repeated_points_and_keeps_extra_dimensions():
    xy = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.0, 2.0]])
    out = pm.resample_by_arc_length(xy, 1.0)
    np.testing.assert_allclose(out, [[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 0, 1], [2, 0, 2]])


def test_resampling_makes_dtw_independent_of_sampling_density():
    exp, _ = smooth_pair(200, seed=3)
    dense = pm.resample_by_arc_length(exp, 0.05)
    a = pm.resample_by_arc_length(exp, 1.0)
    b = pm.resample_by_arc_length(dense, 1.0)
    assert len(a) == len(b)
    # the dense copy cuts corners by micrometres, so the stations drift a little
    assert pm.dtw(a, b, return_matrix=False) / len(a) < 1e-4
    assert pm.dtw(exp, dense, return_matrix=False) / len(dense) > 0.01


@pytest.mark.parametrize("spacing_m", [0.0, -1.0, math.nan, math.inf])
def test_resampling_rejects_bad_spacing(spacing_m):
    with pytest.raises(ValueError, match="spacing_m"):
        pm.resample_by_arc_length([[0.0, 0.0], [1.0, 0.0]], spacing_m)


# ---------------------------------------------------------------------------------------------
# DTSI
# ---------------------------------------------------------------------------------------------


def test_dtsi_against_hand_computed_values():
    offset_m = [0.0, -0.5, 1.0, -2.0]
    t_s = [0.0, 0.5, 1.0, 3.0]  # the last gap (2 s) is not a derivative
    result = pm.lane_deviation(offset_m, t_s)
    mmdc = (5.256 * (0.2 - 0.1) + 2.0) / 4  # |e| = 1.0 is in the blend, 2.0 in the linear part
    assert result.mdc_m == pytest.approx(3.5 / 4)
    assert result.mmdc_m == pytest.approx(mmdc)
    assert result.mddc_m_per_s == pytest.approx((0.5 / 0.5 + 1.5 / 0.5) / 2)
    assert result.emdc == pytest.approx(0.5 * mmdc + 0.5 * 2.0)
    assert pm.dtsi(offset_m, t_s) == result.emdc


def test_dtsi_penalty_edges():
    from plm_highway.metrics.lane import modified_offset_m

    values = modified_offset_m([0.7, 0.7071, 1.15, 1.2, -1.2])
    np.testing.assert_allclose(
        values,
        [0.0, 5.256 * (0.2 * 0.7071**4 - 0.1 * 0.7071**2), 5.256 * (0.2 * 1.15**4 - 0.1 * 1.15**2), 1.2, 1.2],
    )


@pytest.mark.parametrize(
    ("offset_m", "t_s", "message"),
    [
        ([0.0, 0.1, 0.2], [0.0, 0.1], "offset_m and t_s: lengths differ"),
        ([0.0, 0.1, 0.2], [0.0, 0.1, 0.1], "t_s: must increase strictly, but t_s\\[2\\] <= t_s\\[1\\]"),
        ([0.0, 0.1], [0.0, 5.0], "every time gap exceeds 1.0 s"),
        ([0.0], [0.0], "offset_m: needs at least 2 samples"),
        ([0.0, math.nan], [0.0, 0.1], "offset_m: 1 NaN value"),
    ],
)
def test_dtsi_rejects_bad_input(offset_m, t_s, message):
    with pytest.raises(ValueError, match=message):
        pm.dtsi(offset_m, t_s)


# ---------------------------------------------------------------------------------------------
# bad curves
# ---------------------------------------------------------------------------------------------

GOOD = np.column_stack([np.arange(10.0), np.arange(10.0) ** 2])


def with_nan_rows(rows):
    bad = GOOD.copy()
    bad[rows, 1] = np.nan
    return bad


@pytest.mark.parametrize(
    ("exp", "num", "message"),
    [
        (with_nan_rows([4, 5, 9]), GOOD, r"^exp_data: 3 NaN values at rows \[4, 5, 9\]$"),
        (GOOD, np.where(GOOD > 80, np.inf, GOOD), r"^num_data: 1 inf value at row \[9\]$"),
        (GOOD[:1], GOOD, "exp_data: needs at least 2 points, got 1"),
        (GOOD[:, 0], GOOD, r"exp_data: expected a 2-D array .* got shape \(10,\); .*reshape"),
        (GOOD, np.zeros((4, 3)), r"num_data: expected 2 columns \(x, y\), got shape \(4, 3\)"),
        (GOOD, [["a", "b"], ["c", "d"]], "num_data: cannot be read as an array of floats"),
    ],
)
@pytest.mark.parametrize("name", ["pcm", "area_between_two_curves", "curve_length_measure"])
def test_xy_metrics_reject_bad_curves(name, exp, num, message):
    with pytest.raises(ValueError, match=message):
        getattr(pm, name)(exp, num)


def test_nan_message_lists_at_most_ten_rows():
    bad = np.full((30, 2), np.nan)
    with pytest.raises(
        ValueError, match=r"exp_data: 60 NaN values at rows \[0, 1, .*, 9, \.\.\. \(30 rows in all\)\]"
    ):
        pm.frechet_dist(bad, GOOD)


@pytest.mark.parametrize("name", ["frechet_dist", "dtw"])
def test_dynamic_programs_reject_mismatched_dimensions(name):
    with pytest.raises(ValueError, match="exp_data and num_data: different numbers of columns"):
        getattr(pm, name)(GOOD, np.zeros((5, 3)))


@pytest.mark.parametrize("p", [0, -1, math.nan])
def test_frechet_rejects_non_positive_p(p):
    with pytest.raises(ValueError, match="p: the Minkowski p-norm needs p > 0"):
        pm.frechet_dist(GOOD, GOOD, p=p)


def test_pcm_rejects_zero_range_exp():
    flat = np.column_stack([np.arange(5.0), np.zeros(5)])
    with pytest.raises(ValueError, match="exp_data: y range is zero"):
        pm.pcm(flat, GOOD)


# ---------------------------------------------------------------------------------------------
# bench command
# ---------------------------------------------------------------------------------------------


def test_top_level_exports_no_name_that_shadows_similaritymeasures_differently():
    # mae and mse are similaritymeasures' curve errors; the steering errors are steering_mae, ...
    for name in ("mae", "mse", "rmse"):
        assert not hasattr(pm, name)
    assert pm.similarity.mae is not None and pm.steering_mae is not None


def test_make_curves_is_seeded_and_positive():
    exp, num = bench.make_curves(100, seed=5)
    assert exp.shape == (100, 2) and num.shape == (90, 2)
    assert exp.min() >= 10.0 - 1e-9 and num.min() >= 10.0 - 1e-9
    np.testing.assert_array_equal(exp, bench.make_curves(100, seed=5)[0])


def test_bench_against_reference_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "metrics", "--points", "40", "--repeat", "1", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "warm-up" in captured.err  # progress goes to stderr, the table to stdout
    payload = json.loads(out.read_text())
    assert payload["points"] == [40, 36]
    assert payload["similaritymeasures"] == sm.__version__
    public = {name for name in dir(sm) if callable(getattr(sm, name)) and not name.startswith("_")}
    functions = public - {"distance", "division", "similaritymeasures", "version"}  # modules and a __future__ flag
    assert set(payload["functions"]) == functions | {"frechet+dtw", "five curve metrics"}
    for name, row in payload["functions"].items():
        assert name in captured.out
        assert row["max_rel_diff"] <= REL_TOL
        assert row["similaritymeasures_s"] > 0 and row["speedup"] > 0
    assert "not measured (" in captured.out  # the target is stated for 3,000 points, not 40
    assert [p.name for p in tmp_path.iterdir()] == ["bench.json"]  # no temporary file left


def test_bench_max_rel_diff_sees_every_number():
    assert bench.max_rel_diff((1.0, np.array([2.0, np.nan])), (1.0, np.array([2.0, np.nan]))) == 0.0
    assert bench.max_rel_diff((1.0, np.array([2.0, 4.0])), (1.0, np.array([2.0, 5.0]))) == pytest.approx(0.2)
    assert bench.max_rel_diff([True, False], [True, True]) == 1.0
    assert bench.max_rel_diff(np.zeros((2, 2)), np.zeros((2, 3))) == math.inf


def test_bench_target_line_judges_only_at_the_target_size():
    row = {"frechet+dtw": {"speedup": 150.0}}
    assert bench.target_line(row, 3000).endswith("150x, met")
    assert bench.target_line({"frechet+dtw": {"speedup": 99.0}}, 3000).endswith("99x, NOT met")
    assert "not measured" in bench.target_line(row, 2000)
    assert "not measured" in bench.target_line({"frechet+dtw": {"speedup": None}}, 3000)


def test_bench_skip_reference(capsys):
    assert cli.main(["bench", "metrics", "--points", "30", "--skip-reference", "--repeat", "1"]) == 0
    captured = capsys.readouterr()
    assert "similaritymeasures 1" not in captured.out + captured.err
    assert "not measured (no reference run)" in captured.out


def test_bench_refuses_a_foreign_json_before_benchmarking(tmp_path, capsys):
    foreign = tmp_path / "notes.json"
    foreign.write_text('{"mine": true}')
    assert cli.main(["bench", "metrics", "--points", "30", "--json", str(foreign)]) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr()
    assert "refusing to replace" in err.err and "curves:" not in err.out
    assert foreign.read_text() == '{"mine": true}'
