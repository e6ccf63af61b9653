"""plm_highway.metrics.similarity against the installed similaritymeasures 1.5.0.

Every public function is called on both sides with the same (deep-copied) arguments, on tables
of random and degenerate inputs and on hypothesis-drawn ones. Where the original returns, the
drop-in returns the same types, shapes and dtypes with values within 1e-9 relative (NaN where
NaN), and leaves its arguments as the original leaves them; where the original raises, the
drop-in raises the same exception type.
"""

from __future__ import annotations

import copy
import inspect
import math
import warnings

import numpy as np
import pytest
import similaritymeasures as sm
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import plm_highway.metrics.similarity as dropin
from plm_highway.bench.metrics import make_curves
from plm_highway.metrics import curves as strict

REL_TOL = 1e-9
# Absolute tolerance per squared coordinate unit for the areas: the reference sums signed triangle areas, and
# numpy's CPU-dispatched kernels (AVX-512 vs AVX2) round that sum differently, so a zero area can come out as
# +-1e-13 on one CPU and exactly 0 on another (seen: 2.3e-13 for two identical curves with coordinates ~50).
AREA_ABS_TOL_PER_UNIT2 = 1e-12
NORMALISED_ABS_TOL = 1e-12
SETTINGS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# attributes of similaritymeasures that are not part of its API: its two submodules and the
# `from __future__ import division` flag its source carries
NOT_API = {"similaritymeasures", "version", "division"}


# ---------------------------------------------------------------------------------------------
# comparing one call on both sides
# ---------------------------------------------------------------------------------------------


def outcome(fn, args, kwargs):
    """("value", result, args after the call) or ("raised", exception, args after the call)."""
    args, kwargs = copy.deepcopy(args), copy.deepcopy(kwargs)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the original warns on 0/0; the drop-in may warn the same
        try:
            return "value", fn(*args, **kwargs), args
        except Exception as exc:
            return "raised", exc, args


def as_comparable(value) -> np.ndarray:
    array = np.asarray(value)
    return array.astype(float) if array.dtype == object else array


def assert_same_value(ours, reference, where: str, atol: float = 0.0) -> None:
    if isinstance(reference, (tuple, list)):
        assert type(ours) is type(reference) and len(ours) == len(reference), f"{where}: {ours!r} vs {reference!r}"
        for k, (a, b) in enumerate(zip(ours, reference)):
            assert_same_value(a, b, f"{where}[{k}]", atol)
        return
    assert type(ours) is type(reference), f"{where}: type {type(ours).__name__} vs {type(reference).__name__}"
    if reference is None or isinstance(reference, (str, bytes)) or callable(reference):
        assert ours == reference, f"{where}: {ours!r} vs {reference!r}"  # a metric name, p or callable
        return
    a, b = as_comparable(ours), as_comparable(reference)
    assert a.shape == b.shape and a.dtype == b.dtype, f"{where}: {a.shape} {a.dtype} vs {b.shape} {b.dtype}"
    np.testing.assert_allclose(a, b, rtol=REL_TOL, atol=atol, equal_nan=True, err_msg=where)


def area_tolerance(name: str, args) -> float:
    """The absolute tolerance of ``name``'s result: 0, except for an area (see AREA_ABS_TOL_PER_UNIT2) and the
    measures of range-normalised curves (PCM, curve length: values O(1), a zero can come out as a few 1e-16)."""
    if name in ("pcm", "curve_length_measure"):
        return NORMALISED_ABS_TOL
    if name != "area_between_two_curves":
        return 0.0
    scale = max((float(np.max(np.abs(np.asarray(a, dtype=float)), initial=0.0)) for a in args
                 if isinstance(a, np.ndarray) and a.dtype.kind == "f"), default=0.0)
    return AREA_ABS_TOL_PER_UNIT2 * max(1.0, scale) ** 2


def mismatch(name: str, *args, **kwargs) -> str | None:
    """None when dropin.<name> behaves as similaritymeasures.<name> on these arguments, else why not."""
    ref_kind, ref, ref_args = outcome(getattr(sm, name), args, kwargs)
    our_kind, ours, our_args = outcome(getattr(dropin, name), args, kwargs)
    if ref_kind == "raised":
        if our_kind != "raised" or not isinstance(ours, type(ref)):
            return f"similaritymeasures raised {type(ref).__name__}({ref}), the drop-in gave {ours!r:.120}"
        return None
    if our_kind == "raised":
        return f"the drop-in raised {type(ours).__name__}({ours}), similaritymeasures returned {ref!r:.120}"
    try:
        assert_same_value(ours, ref, "result", area_tolerance(name, args))
        assert_same_value(our_args, ref_args, "arguments after the call")
    except AssertionError as exc:
        return str(exc)
    return None


def assert_all_match(cases) -> None:
    """cases: (label, function name, args, kwargs); fails listing every case that differs."""
    failures = []
    for label, name, args, kwargs in cases:
        why = mismatch(name, *args, **kwargs)
        if why is not None:
            failures.append(f"{name}({label}): {why}")
    assert not failures, f"{len(failures)} of {len(cases)} cases differ:\n" + "\n".join(failures[:20])


# ---------------------------------------------------------------------------------------------
# the API itself
# ---------------------------------------------------------------------------------------------

PUBLIC = sorted(name for name in dir(sm) if not name.startswith("_") and name not in NOT_API)
FUNCTIONS = [name for name in PUBLIC if inspect.isfunction(getattr(sm, name))]


def test_every_public_name_is_there():
    assert len(FUNCTIONS) == 14
    missing = [name for name in PUBLIC if not hasattr(dropin, name)]
    assert not missing
    assert dropin.np is np and dropin.distance is sm.distance
    assert dropin.__version__ == sm.__version__ == "1.5.0"
    assert sorted(dropin.__all__) == FUNCTIONS


@pytest.mark.parametrize("name", FUNCTIONS)
def test_same_signature(name):
    ours = inspect.signature(getattr(dropin, name)).parameters
    theirs = inspect.signature(getattr(sm, name)).parameters
    assert [(p.name, p.kind, p.default) for p in ours.values()] == [(p.name, p.kind, p.default) for p in theirs.values()]


def test_empty_curve_error_is_an_index_error_and_a_value_error():
    with pytest.raises(IndexError) as raised:
        dropin.frechet_dist(np.zeros((0, 2)), np.ones((3, 2)))
    assert isinstance(raised.value, ValueError)
    assert str(raised.value).startswith("exp_data: has no points")
    with pytest.raises(IndexError, match="num_data: has no points"):
        dropin.dtw(np.ones((3, 2)), np.zeros((0, 2)))


# ---------------------------------------------------------------------------------------------
# tables of inputs
# ---------------------------------------------------------------------------------------------

_rng = np.random.default_rng(20240514)


def _random(n: int, n_dims: int = 2) -> np.ndarray:
    return 5.0 + 3.0 * _rng.normal(size=(n, n_dims))


def _with(curve: np.ndarray, row: int, column: int, value: float) -> np.ndarray:
    out = curve.copy()
    out[row, column] = value
    return out


CURVES = {
    "random": _random(7),
    "random_shorter": _random(5),
    "random_longer": _random(9),
    "random_3d": _random(6, 3),
    "random_4d": _random(5, 4),
    "one_column": _random(6, 1),
    "flat_in_x": np.column_stack([np.full(6, 2.0), np.arange(6.0)]),
    "flat_in_y": np.column_stack([np.arange(6.0), np.full(6, 2.0)]),
    "zero_length": np.full((5, 2), 3.0),
    "all_zeros": np.zeros((5, 2)),
    "single_point": np.array([[1.0, 2.0]]),
    "no_points": np.zeros((0, 2)),
    "repeated_points": 1.0 + np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [2.0, 0.0], [3.0, 1.0]]),
    "vertical_segments": np.array([[1.0, 0.0], [1.0, 1.0], [1.0, 3.0], [2.0, 3.0], [2.0, 1.0]]),
    "ties": np.column_stack([np.arange(8.0), 5.0 + np.round(_rng.normal(size=8))]),
    "negative": _random(6) - 20.0,
    "integers": _rng.integers(-5, 10, size=(6, 2)),
    "integers_longer": _rng.integers(1, 10, size=(8, 2)),
    "int32": _rng.integers(1, 10, size=(6, 2)).astype(np.int32),
    "uint8": _rng.integers(1, 10, size=(5, 2)).astype(np.uint8),
    "float32": _random(6).astype(np.float32),
    "bool": _rng.integers(0, 2, size=(5, 2)).astype(bool),
    "object": _random(4).astype(object),
    "complex": _random(4) + 0j,
    "list": _random(5).tolist(),
    "integer_list": [[0, 0], [1, 2], [3, 3], [4, 1]],
    "tuple": tuple(map(tuple, _random(4))),
    "strings": [["a", "b"], ["c", "d"]],
    "fortran_order": np.asfortranarray(_random(6)),
    "strided": _random(12)[::2],
    "transposed_view": np.ascontiguousarray(_random(6).T).T,
    "nan": _with(_random(5), 2, 1, np.nan),
    "inf": _with(_random(5), 1, 0, np.inf),
    "one_d": np.arange(5.0),
    "three_d": np.zeros((3, 2, 2)),
    "scalar": 3.0,
}
PARTNERS = ("random", "random_shorter", "random_longer", "integers", "list", "single_point", "no_points", "nan",
            "random_3d", "float32", "zero_length", "flat_in_y")
PAIR_FUNCTIONS = ("frechet_dist", "dtw", "area_between_two_curves", "curve_length_measure", "pcm", "mae", "mse")


@pytest.mark.parametrize("name", PAIR_FUNCTIONS)
@pytest.mark.parametrize("first", list(CURVES))
def test_curve_functions_on_the_table(name, first):
    cases = []
    for partner in sorted({*PARTNERS, first}):
        cases.append((f"{first}, {partner}", name, (CURVES[first], CURVES[partner]), {}))
        cases.append((f"{partner}, {first}", name, (CURVES[partner], CURVES[first]), {}))
    assert_all_match(cases)


SOME_CURVES = ("random", "random_shorter", "random_3d", "single_point", "no_points", "integers", "list", "nan",
               "float32", "bool", "one_d", "strings")


@pytest.mark.parametrize("p", [1, 2, 3, 0.5, math.inf, 0, -1, math.nan, np.float32(3), "a", None, [2]])
def test_frechet_p_values(p):
    assert_all_match([(f"{a}, {b}, p={p!r}", "frechet_dist", (CURVES[a], CURVES[b]), {"p": p})
                      for a in SOME_CURVES for b in ("random", "random_longer", a)])


def _manhattan(u, v):
    return float(np.abs(u - v).sum())


DTW_METRICS = [
    ("euclidean", {}), ("sqeuclidean", {}), ("cityblock", {}), ("chebyshev", {}), ("minkowski", {}),
    ("minkowski", {"p": 3}), ("minkowski", {"p": 1}), ("minkowski", {"p": math.inf}), ("minkowski", {"p": 0}),
    ("euclid", {}), ("EUCLIDEAN", {}), ("canberra", {}), ("cosine", {}), (_manhattan, {}), ("nonsense", {}),
    ("euclidean", {"w": [1.0, 2.0]}), ("euclidean", {"p": 3}), (3, {}),
]


@pytest.mark.parametrize(("metric", "kwargs"), DTW_METRICS, ids=[f"{getattr(m, '__name__', m)}-{k}" for m, k in DTW_METRICS])
def test_dtw_metrics(metric, kwargs):
    assert_all_match([(f"{a}, {b}", "dtw", (CURVES[a], CURVES[b], metric), kwargs)
                      for a in SOME_CURVES for b in ("random", "random_longer", a)])


@pytest.mark.parametrize("norm_seg_length", [True, False])
def test_pcm_norm_seg_length(norm_seg_length):
    assert_all_match([(f"{a}, {b}", "pcm", (CURVES[a], CURVES[b], norm_seg_length), {})
                      for a in CURVES for b in ("random", "random_longer", "flat_in_x", a)])


def test_get_arc_length_on_the_table():
    assert_all_match([(name, "get_arc_length", (curve,), {}) for name, curve in CURVES.items()])


def _dtw_matrix(a: str, b: str) -> np.ndarray:
    return sm.dtw(CURVES[a], CURVES[b])[1]


MATRICES = {
    "random": _rng.random((5, 7)),
    "all_ties": np.zeros((4, 4)),
    "integer_ties": _rng.integers(0, 3, (6, 5)),
    "nan": np.where(_rng.random((5, 5)) < 0.3, np.nan, _rng.random((5, 5))),
    "inf": np.where(_rng.random((5, 5)) < 0.3, np.inf, _rng.random((5, 5))),
    "one_row": _rng.random((1, 6)),
    "one_column": _rng.random((6, 1)),
    "one_cell": np.ones((1, 1)),
    "empty_0x0": np.zeros((0, 0)),
    "empty_0x1": np.zeros((0, 1)),
    "empty_1x0": np.zeros((1, 0)),
    "empty_0x3": np.zeros((0, 3)),
    "empty_3x0": np.zeros((3, 0)),
    "one_d": np.arange(4.0),
    "three_d": np.zeros((2, 2, 2)),
    "list": [[1.0, 2.0], [3.0, 4.0]],
    "float32": _rng.random((5, 4)).astype(np.float32),
    "uint8": _rng.integers(0, 4, (5, 5)).astype(np.uint8),
    "object": _rng.random((4, 4)).astype(object),
    "complex": _rng.random((3, 3)) + 1j,
    "bool": _rng.random((4, 4)) > 0.5,
    "fortran_order": np.asfortranarray(_rng.random((5, 6))),
    "strided": _rng.random((10, 12))[::2, ::3],
    "dtw_of_random_curves": _dtw_matrix("random", "random_longer"),
    "dtw_of_integer_curves": _dtw_matrix("integers", "integers_longer"),
    "dtw_of_repeated_points": _dtw_matrix("repeated_points", "zero_length"),
    "dtw_of_nan_curves": _dtw_matrix("nan", "random"),
}


def test_dtw_path_on_the_table():
    assert_all_match([(name, "dtw_path", (matrix,), {}) for name, matrix in MATRICES.items()])


VECTORS = {
    "random": _rng.random(6),
    "integers": _rng.integers(0, 5, 6),
    "list": [0.0, 1.0, 3.0, 2.0],
    "integer_list": [0, 1, 3, 2],
    "bool_list": [True, False, True],
    "zeros": np.zeros(5),
    "empty": np.zeros(0),
    "one": np.ones(1),
    "two": np.array([1.0, 2.0]),
    "longer": _rng.random(9),
    "negative": -_rng.random(6),
    "nan": np.array([0.0, np.nan, 1.0]),
    "float32": _rng.random(5).astype(np.float32),
    "uint8": np.array([3, 1, 2], dtype=np.uint8),
    "object": np.array([1.0, 2.0, 4.0], dtype=object),
    "complex": _rng.random(4) + 1j,
    "strided": _rng.random(12)[::2],
    "two_d": _rng.random((4, 2)),
    "column": _rng.random((4, 1)),
    "scalar": 2.0,
}
VECTOR_PARTNERS = ("random", "list", "float32", "longer", "empty")


@pytest.mark.parametrize("name", ["get_length", "normalizeTwoCurves", "poly_area"])
def test_vector_helpers_on_the_table(name):
    cases = []
    for first in VECTORS:
        for partner in sorted({*VECTOR_PARTNERS, first}):
            for x, y, label in ((VECTORS[first], VECTORS[partner], f"{first}, {partner}"),
                                (VECTORS[partner], VECTORS[first], f"{partner}, {first}")):
                if name == "get_length":
                    cases += [(f"{label}, {norm}", name, (x, y, norm), {}) for norm in (True, False)]
                    cases.append((label, name, (x, y), {}))
                elif name == "normalizeTwoCurves":
                    cases.append((label, name, (x, y, y, x), {}))
                else:
                    cases.append((label, name, (x, y), {}))
    assert_all_match(cases)


QUADS = [
    ([0, 1, 1, 0], [0, 1, 0, 1]),  # complex (a bow tie) in the first order
    ([0, 0, 1, 1], [0, 1, 1, 0]),  # simple
    ([0, 2, 1, 1], [0, 0, 1, -1]),
    ([0.0, 1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 0.0]),  # collinear
    ([0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]),  # one point
    ([0.0, np.nan, 1.0, 0.0], [0.0, 1.0, 1.0, 0.0]),
    ([0.0, 1.0, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]),
]


def _edges(x, y) -> list:
    return [[x[(k + 1) % 4] - x[k], y[(k + 1) % 4] - y[k]] for k in range(4)]


def test_quad_helpers_on_the_table():
    cases = []
    for x, y in QUADS:
        label = f"{x}, {y}"
        # makeQuad reorders its arguments in place: the comparison checks they end up alike
        cases.append((f"lists {label}", "makeQuad", (list(x), list(y)), {}))
        cases.append((f"arrays {label}", "makeQuad", (np.array(x), np.array(y)), {}))
        cases.append((label, "is_simple_quad", tuple(_edges(x, y)), {}))
        cases.append((f"arrays {label}", "is_simple_quad", tuple(np.array(e) for e in _edges(x, y)), {}))
    cases.append(("a batch", "is_simple_quad", tuple(np.ones((3, 2)) for _ in range(4)), {}))
    cases.append(("vectors of 3", "is_simple_quad", ([1, 2, 3], [1, 2], [0, 0], [1, 1]), {}))
    cases.append(("vector of 1", "is_simple_quad", ([1], [1, 2], [0, 0], [1, 1]), {}))
    assert_all_match(cases)


def test_makequad_reorders_its_lists_in_place_like_the_original():
    x, y = [0, 1, 1, 0], [0, 1, 0, 1]  # a bow tie: swapping vertices 0 and 1 leaves another one,
    area = dropin.makeQuad(x, y)  # then the original order with vertices 1 and 2 swapped is the square
    assert (x, y) == ([0, 1, 1, 0], [0, 0, 1, 1])
    assert area == 1.0


# ---------------------------------------------------------------------------------------------
# hypothesis-drawn curves
# ---------------------------------------------------------------------------------------------

SPECIAL = (0.0, 1.0, np.nan, np.inf, -np.inf)


@st.composite
def curve_pairs(draw, max_points: int = 10):
    """Two curves of one width (sometimes not), with repeated, special or integer values."""
    n_dims = draw(st.sampled_from([1, 2, 2, 2, 3]))
    pair = []
    for _ in range(2):
        n_points = draw(st.integers(0, max_points))
        width = n_dims if draw(st.integers(0, 9)) else draw(st.integers(1, 3))
        curve = draw(hnp.arrays(np.float64, (n_points, width),
                                elements=st.floats(-50.0, 50.0, allow_nan=False, allow_subnormal=False)))
        if n_points and draw(st.integers(0, 4)) == 0:
            curve[draw(st.integers(0, n_points - 1)), draw(st.integers(0, width - 1))] = draw(st.sampled_from(SPECIAL))
        if n_points > 1 and draw(st.integers(0, 4)) == 0:
            curve[1:] = curve[:-1].copy()  # repeated points
        form = draw(st.sampled_from(["array", "array", "integers", "list", "fortran"]))
        if form == "integers" and np.isfinite(curve).all():
            curve = np.round(curve).astype(np.int64)
        elif form == "list":
            curve = curve.tolist()
        elif form == "fortran":
            curve = np.asfortranarray(curve)
        pair.append(curve)
    return tuple(pair)


@SETTINGS
@given(pair=curve_pairs(), p=st.sampled_from([1, 2, 3, 0.7, math.inf]))
def test_curve_functions_on_drawn_curves(pair, p):
    exp, num = pair
    assert_all_match([("exp, num", name, (exp, num), {}) for name in PAIR_FUNCTIONS]
                     + [("num, exp", name, (num, exp), {}) for name in ("area_between_two_curves", "pcm")]
                     + [("p", "frechet_dist", (exp, num), {"p": p}),
                        ("norm", "pcm", (exp, num, True), {}),
                        ("cityblock", "dtw", (exp, num, "cityblock"), {}),
                        ("arc", "get_arc_length", (exp,), {})])


@SETTINGS
@given(pair=curve_pairs(max_points=15))
def test_dtw_path_on_drawn_curves(pair):
    try:
        matrix = sm.dtw(*pair)[1]
    except (ValueError, IndexError):
        return  # dtw itself raises: covered by the test above
    assert_all_match([("dtw matrix", "dtw_path", (matrix,), {})])


@SETTINGS
@given(x=hnp.arrays(np.float64, st.integers(0, 12), elements=st.floats(-50, 50, allow_subnormal=False)),
       y=hnp.arrays(np.float64, st.integers(0, 12), elements=st.floats(-50, 50, allow_subnormal=False)),
       norm=st.booleans())
def test_get_length_on_drawn_vectors(x, y, norm):
    assert_all_match([("x, y", "get_length", (x, y, norm), {}), ("lists", "get_length", (x.tolist(), y.tolist(), norm), {})])


# ---------------------------------------------------------------------------------------------
# larger curves, and where the drop-in and the strict module part ways
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_larger_smooth_curves(seed):
    exp, num = make_curves(300, seed)
    num = num[:250]
    cases = [(f"{name}", name, (exp, num), {}) for name in PAIR_FUNCTIONS if name not in ("mae", "mse")]
    cases += [(f"{name} swapped", name, (num, exp), {}) for name in ("area_between_two_curves", "pcm", "frechet_dist")]
    cases += [("same shape", "mae", (exp[:250], num), {}), ("same shape", "mse", (exp[:250], num), {})]
    cases += [("dtw matrix", "dtw_path", (sm.dtw(exp, num)[1],), {})]
    assert_all_match(cases)


def test_integer_curves_are_truncated_where_points_are_inserted_but_not_by_the_strict_module():
    exp = np.array([[0, 0], [1, 0], [2, 0], [3, 0]])
    num = np.array([[0, 2], [3, 0]])
    # the midpoints (1.5, 1) then (2, 0.5) become (1, 1) and (2, 0): 1.5 + 0.5 + 0 by hand
    assert dropin.area_between_two_curves(exp, num) == sm.area_between_two_curves(exp, num) == 2.0
    # in float64 the points are (1.5, 1) then (0.75, 1.5): 1.5 + 1 + 0.5
    assert strict.area_between_two_curves(exp, num) == sm.area_between_two_curves(exp * 1.0, num * 1.0) == 3.0


def test_questionable_answers_are_kept_in_the_drop_in_and_refused_by_the_strict_module():
    flat = CURVES["flat_in_y"]
    assert np.isnan(dropin.pcm(flat, CURVES["random"])) and np.isnan(sm.pcm(flat, CURVES["random"]))
    with pytest.raises(ValueError, match="exp_data: y range is zero"):
        strict.pcm(flat, CURVES["random"])
    zero = CURVES["zero_length"]
    with np.errstate(all="ignore"):
        assert np.isnan(dropin.curve_length_measure(zero, zero)) and np.isnan(sm.curve_length_measure(zero, zero))
    with pytest.raises(ValueError, match="exp_data: curve has zero length"):
        strict.curve_length_measure(zero, zero)
    with pytest.raises(IndexError):
        dropin.frechet_dist(CURVES["no_points"], CURVES["random"])
    with pytest.raises(ValueError, match="exp_data: needs at least 2 points, got 0"):
        strict.frechet_dist(CURVES["no_points"], CURVES["random"])
