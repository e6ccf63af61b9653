"""``plm-highway bench metrics``: every function of the similaritymeasures drop-in against the original.

Both sides run in one process on the same seeded curve pair: a smooth random drive of ``n``
points about 0.5 m apart and a laterally offset copy of 0.9 n points. Each function is called with
the same arguments on both sides (``dtw_path`` on the DTW matrix of that pair; the scalar helpers
``is_simple_quad`` and ``makeQuad`` on every quadrilateral between the curves, as
``area_between_two_curves`` uses them). Each side runs up to ``repeat`` times, stopping once a
function has taken ``BUDGET_S``, and its fastest run counts; ours is warmed up first (numba
compiles on first use, then loads from its cache). Both results are compared to within
``MATCH_REL_TOL`` relative. The target is a Frechet + DTW speed-up of at least 100x on
3,000-point curves, the default size.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.metrics import similarity

DEFAULT_POINTS = 3000  # the size the target is stated on (TARGET_POINTS)
DEFAULT_REPEAT = 3
DEFAULT_SEED = 0
BUDGET_S = 2.0  # stop repeating a function once its runs have taken this long (the reference takes minutes)
MATCH_REL_TOL = 1e-9
CURVE_METRICS = ("frechet_dist", "dtw", "area_between_two_curves", "curve_length_measure", "pcm")
COMBINED = {"frechet+dtw": ("frechet_dist", "dtw"), "five curve metrics": CURVE_METRICS}
TARGET_COMBINATION, TARGET_SPEEDUP, TARGET_POINTS = "frechet+dtw", 100.0, 3000
# Seconds similaritymeasures 1.5.0 took on the loaded 2-core dev machine at 3,000 points, for the ETA.
_REFERENCE_S_AT_3000 = {"frechet_dist": 16.0, "dtw": 22.0, "area_between_two_curves": 34.0, "pcm": 0.2}






def check_settings(n_points: int, repeat: int) -> None:
    if n_points < 3:
        raise BadInput(f"--points: needs at least 3, got {n_points}")
    if repeat < 1:
        raise BadInput(f"--repeat: needs at least 1, got {repeat}")


def make_curves(n_points: int, seed: int = DEFAULT_SEED) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random drive (n_points, about 0.5 m apart) and a laterally offset copy of 0.9 n points.

    Coordinates are shifted to start at 10 m because curve_length_measure divides by the mean
    x and y and is undefined for curves centred on the origin.
    """
    rng = np.random.default_rng(seed)
    n_fine = 4 * n_points
    heading_rad = np.cumsum(rng.normal(0.0, 0.002, n_fine))
    fine_xy = np.cumsum(0.125 * np.column_stack([np.cos(heading_rad), np.sin(heading_rad)]), axis=0)
    fine_s = np.arange(n_fine) * 0.125

    def along(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.column_stack([np.interp(s, fine_s, fine_xy[:, k]) for k in range(2)])
        return xy, np.interp(s, fine_s, heading_rad)

    exp, _ = along(np.linspace(0.0, fine_s[-1], n_points))
    base, heading_num = along(np.linspace(0.0, fine_s[-1], max(2, round(0.9 * n_points))))
    walk = np.cumsum(rng.normal(0.0, 1.0, len(base)))
    window = max(3, len(base) // 50)
    lateral = np.convolve(walk - walk.mean(), np.ones(window) / window, mode="same")
    lateral_m = 0.3 * lateral / max(np.max(np.abs(lateral)), 1e-12)
    num = base + lateral_m[:, None] * np.column_stack([-np.sin(heading_num), np.cos(heading_num)])
    shift = 10.0 - np.minimum(exp.min(axis=0), num.min(axis=0))
    return exp + shift, num + shift


@dataclass(frozen=True)
class Call:
    """One benchmarked function: how to call it on a module that has it (ours or the original)."""

    name: str
    call: Callable[[ModuleType], object]


def benchmark_calls(exp: np.ndarray, num: np.ndarray) -> list[Call]:
    """Every public function of similaritymeasures 1.5.0, with its arguments built from one curve pair."""
    cost_matrix = similarity.dtw(exp, num)[1]
    head = exp[: len(num)]  # mae and mse compare curves of one shape
    quads_x = [[exp[i - 1, 0], exp[i, 0], head[i, 0], head[i - 1, 0]] for i in range(1, len(head))]
    quads_y = [[exp[i - 1, 1], exp[i, 1], head[i, 1], head[i - 1, 1]] for i in range(1, len(head))]
    edges = [[[x[(k + 1) % 4] - x[k], y[(k + 1) % 4] - y[k]] for k in range(4)] for x, y in zip(quads_x, quads_y)]
    return [
        Call("frechet_dist", lambda m: m.frechet_dist(exp, num)),
        Call("dtw", lambda m: m.dtw(exp, num)),
        Call("dtw_path", lambda m: m.dtw_path(cost_matrix)),
        Call("area_between_two_curves", lambda m: m.area_between_two_curves(exp, num)),
        Call("curve_length_measure", lambda m: m.curve_length_measure(exp, num)),
        Call("pcm", lambda m: m.pcm(exp, num)),
        Call("get_arc_length", lambda m: m.get_arc_length(exp)),
        Call("get_length", lambda m: m.get_length(exp[:, 0], exp[:, 1])),
        Call("normalizeTwoCurves", lambda m: m.normalizeTwoCurves(exp[:, 0], exp[:, 1], num[:, 0], num[:, 1])),
        Call("poly_area", lambda m: m.poly_area(exp[:, 0], exp[:, 1])),
        Call("mae", lambda m: m.mae(head, num)),
        Call("mse", lambda m: m.mse(head, num)),
        # makeQuad reorders its lists in place: each run gets fresh copies
        Call("makeQuad", lambda m: [m.makeQuad(list(x), list(y)) for x, y in zip(quads_x, quads_y)]),
        Call("is_simple_quad", lambda m: [m.is_simple_quad(*quad) for quad in edges]),
    ]


def fastest_s(fn: Callable[[], object], repeat: int, budget_s: float = BUDGET_S) -> tuple[float, object]:
    """Fastest wall time of up to ``repeat`` runs of ``fn`` (fewer once ``budget_s`` is spent), and its result."""
    best_s, spent_s, result = float("inf"), 0.0, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        elapsed_s = time.perf_counter() - start
        best_s, spent_s = min(best_s, elapsed_s), spent_s + elapsed_s
        if spent_s >= budget_s:
            break
    return best_s, result


def max_rel_diff(ours, reference) -> float:
    """Largest |ours - reference| / |reference| over every number returned (0 where both are equal)."""
    if isinstance(reference, (tuple, list)) and not np.isscalar(reference):
        if not isinstance(ours, (tuple, list)) or len(ours) != len(reference):
            return float("inf")
        return max((max_rel_diff(a, b) for a, b in zip(ours, reference)), default=0.0)
    a, b = np.asarray(ours, dtype=float), np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        return float("inf")
    diff = np.abs(a - b)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where((a == b) | (np.isnan(a) & np.isnan(b)), 0.0, diff / np.abs(b))
    return float(np.max(rel, initial=0.0))


def _progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def warm_up() -> float:
    """Seconds to compile (or load from numba's cache) every kernel, on small curves."""
    exp, num = make_curves(20, seed=1)
    start = time.perf_counter()
    for call in benchmark_calls(exp, num):
        call.call(similarity)
    return time.perf_counter() - start


def run_benchmark(n_points: int = DEFAULT_POINTS, seed: int = DEFAULT_SEED, repeat: int = DEFAULT_REPEAT,
                  skip_reference: bool = False) -> dict:
    """Time every function on both sides; returns the JSON-ready result with one row per function."""
    exp, num = make_curves(n_points, seed)
    _progress(f"curves: {len(exp)} and {len(num)} points (seed {seed})")
    warm_s = warm_up()
    _progress(f"numba warm-up (compiles on first use, else loads its cache; not timed below): {warm_s:.2f} s")
    calls = benchmark_calls(exp, num)
    rows: dict[str, dict] = {}
    results = {}
    for call in calls:
        ours_s, results[call.name] = fastest_s(lambda call=call: call.call(similarity), repeat)
        rows[call.name] = {"plm_highway_s": ours_s, "similaritymeasures_s": None, "max_rel_diff": None}
        _progress(f"  plm_highway        {call.name:<24}{ours_s:10.3g} s")
    reference_version = None
    if not skip_reference:
        import similaritymeasures  # lazy: the reference side only, skipped by --skip-reference

        reference_version = similaritymeasures.__version__
        eta_s = sum(s * (n_points / 3000) ** (3 if n.startswith("area") else 2) for n, s in _REFERENCE_S_AT_3000.items())
        _progress(f"similaritymeasures {reference_version}: expect roughly {eta_s:.0f} s on a 2-core machine")
        for call in calls:
            ref_s, reference = fastest_s(lambda call=call: call.call(similaritymeasures), repeat)
            rows[call.name]["similaritymeasures_s"] = ref_s
            rows[call.name]["max_rel_diff"] = max_rel_diff(results[call.name], reference)
            _progress(f"  similaritymeasures {call.name:<24}{ref_s:10.3g} s")
    return {"points": [len(exp), len(num)], "seed": seed, "repeat": repeat, "budget_s": BUDGET_S,
            "numba_warmup_s": warm_s, "python": sys.version.split()[0], "similaritymeasures": reference_version,
            "functions": with_combinations(rows)}


def with_combinations(rows: dict[str, dict]) -> dict[str, dict]:
    """``rows`` plus the combined rows of COMBINED (summed times), each with its speed-up."""
    table = dict(rows)
    for label, names in COMBINED.items():
        parts = [rows[n] for n in names]
        have_ref = all(p["similaritymeasures_s"] is not None for p in parts)
        table[label] = {
            "plm_highway_s": sum(p["plm_highway_s"] for p in parts),
            "similaritymeasures_s": sum(p["similaritymeasures_s"] for p in parts) if have_ref else None,
            "max_rel_diff": max(p["max_rel_diff"] for p in parts) if have_ref else None,
        }
    return {name: {**row, "speedup": None if row["similaritymeasures_s"] is None
                   else row["similaritymeasures_s"] / row["plm_highway_s"]} for name, row in table.items()}


def mismatches(table: dict[str, dict]) -> list[str]:
    return [name for name, row in table.items() if name not in COMBINED and (row["max_rel_diff"] or 0.0) > MATCH_REL_TOL]


def format_table(table: dict[str, dict]) -> str:
    def num(value, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    header = f"{'function':<26}{'similaritymeasures s':>21}{'plm_highway s':>15}{'speed-up':>11}{'max rel diff':>14}"
    lines = [header, "-" * len(header)]
    for name, row in table.items():
        if name == next(iter(COMBINED)):
            lines.append("-" * len(header))
        speedup = "-" if row["speedup"] is None else f"{row['speedup']:,.1f}x"
        lines.append(
            f"{name:<26}{num(row['similaritymeasures_s'], '.3g'):>21}{num(row['plm_highway_s'], '.3g'):>15}"
            f"{speedup:>11}{num(row['max_rel_diff'], '.1e'):>14}"
        )
    return "\n".join(lines)


def target_line(table: dict[str, dict], n_points: int) -> str:
    """The target and, when measured at its size (3,000 points), whether it is met."""
    target = f"target: {TARGET_COMBINATION} >= {TARGET_SPEEDUP:.0f}x on {TARGET_POINTS:,}-point curves"
    speedup = table[TARGET_COMBINATION]["speedup"]
    if speedup is None:
        return f"{target}: not measured (no reference run)"
    if n_points != TARGET_POINTS:
        return f"{target}: not measured ({speedup:,.0f}x on {n_points:,}-point curves)"
    return f"{target}: {speedup:,.0f}x, {'met' if speedup >= TARGET_SPEEDUP else 'NOT met'}"
