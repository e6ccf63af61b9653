"""``plm-highway bench metrics``: time plm_highway.metrics against similaritymeasures.

Both libraries run in the same process on the same seeded curve pair (n and 0.9 n points). Ours
are warmed up first (numba compiles on first use, then loads from its cache) and timed as the
fastest of ``--repeat`` runs; the reference runs once because it takes minutes at 6,000 points.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from plm_highway.bench import BENCH_RESULT
from plm_highway.io import check_target, write_json
from plm_highway.metrics import curves

METRICS = ("frechet_dist", "dtw", "area_between_two_curves", "curve_length_measure", "pcm")
COMBINED = {"frechet+dtw": ("frechet_dist", "dtw"), "all five": METRICS}
MATCH_REL_TOL = 1e-9
# Seconds similaritymeasures 1.5.0 took on the 2-core dev machine at 6,000 points, for the ETA.
_REFERENCE_S_AT_6000 = {"frechet_dist": 36.0, "dtw": 25.0, "area_between_two_curves": 129.0}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--points", type=int, default=6000, help="points on the first curve (default 6000)")
    parser.add_argument("--json", type=Path, metavar="OUT", help="also write the results to this JSON file")
    parser.add_argument(
        "--skip-reference", action="store_true", help="time plm_highway only (no similaritymeasures)"
    )
    parser.add_argument("--repeat", type=int, default=3, help="runs of each of our metrics; fastest counts")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random curves")


def make_curves(n_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
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


def _fastest_s(fn: Callable, repeat: int):
    best_s, result = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        best_s = min(best_s, time.perf_counter() - start)
    return best_s, result


def _max_rel_diff(ours, reference) -> float:
    """Largest |ours - reference| / |reference| over every number returned (dtw: matrix too)."""
    pairs = zip(ours, reference) if isinstance(reference, tuple) else [(ours, reference)]
    worst = 0.0
    for a, b in pairs:
        a, b = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
        diff = np.abs(a - b)
        scale = np.abs(b)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(diff == 0, 0.0, diff / scale)
        worst = max(worst, float(np.max(rel)))
    return worst


def _warm_up() -> float:
    exp, num = make_curves(20, seed=1)
    start = time.perf_counter()
    for name in METRICS:
        getattr(curves, name)(exp, num)
    curves.dtw(exp, num, return_matrix=False)
    return time.perf_counter() - start


def _reference_eta_s(n_points: int) -> float:
    scale = n_points / 6000
    return sum(s * scale ** (3 if name.startswith("area") else 2) for name, s in _REFERENCE_S_AT_6000.items())


def _say(text: str, end: str = "\n") -> None:
    print(text, end=end, flush=True)


def _run_metrics(exp, num, repeat: int, skip_reference: bool) -> dict[str, dict]:
    rows: dict[str, dict] = {}
    for name in METRICS:
        _say(f"  plm_highway        {name:<24}", end="")
        ours_s, ours = _fastest_s(lambda name=name: getattr(curves, name)(exp, num), repeat)
        _say(f"{ours_s:10.4f} s (fastest of {repeat})")
        rows[name] = {"plm_highway_s": ours_s, "similaritymeasures_s": None, "max_rel_diff": None}
        rows[name]["_result"] = ours
    if skip_reference:
        return rows
    import similaritymeasures

    eta_s = _reference_eta_s(len(exp))
    eta = f"{eta_s / 60:.0f} min" if eta_s >= 120 else f"{eta_s:.0f} s"
    _say(f"similaritymeasures {similaritymeasures.__version__}: expect roughly {eta} on a 2-core machine")
    for name in METRICS:
        _say(f"  similaritymeasures {name:<24}", end="")
        ref_s, ref = _fastest_s(lambda name=name: getattr(similaritymeasures, name)(exp, num), 1)
        rows[name]["similaritymeasures_s"] = ref_s
        rows[name]["max_rel_diff"] = _max_rel_diff(rows[name]["_result"], ref)
        _say(f"{ref_s:10.4f} s")
    return rows


def _combine(rows: dict[str, dict]) -> dict[str, dict]:
    table = {name: {k: v for k, v in row.items() if not k.startswith("_")} for name, row in rows.items()}
    for label, names in COMBINED.items():
        parts = [table[n] for n in names]
        have_ref = all(p["similaritymeasures_s"] is not None for p in parts)
        table[label] = {
            "plm_highway_s": sum(p["plm_highway_s"] for p in parts),
            "similaritymeasures_s": sum(p["similaritymeasures_s"] for p in parts) if have_ref else None,
            "max_rel_diff": max(p["max_rel_diff"] for p in parts) if have_ref else None,
        }
    for row in table.values():
        ref_s = row["similaritymeasures_s"]
        row["speedup"] = ref_s / row["plm_highway_s"] if ref_s is not None else None
    return table


def _format_table(table: dict[str, dict]) -> str:
    def num(value, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    header = (
        f"{'metric':<26}{'similaritymeasures s':>21}{'plm_highway s':>15}{'speed-up':>11}{'max rel diff':>14}"
    )
    lines = [header, "-" * len(header)]
    for name, row in table.items():
        if name in COMBINED and name == next(iter(COMBINED)):
            lines.append("-" * len(header))
        speedup = "-" if row["speedup"] is None else f"{row['speedup']:,.0f}x"
        lines.append(
            f"{name:<26}{num(row['similaritymeasures_s'], '.3f'):>21}{num(row['plm_highway_s'], '.4f'):>15}"
            f"{speedup:>11}{num(row['max_rel_diff'], '.1e'):>14}"
        )
    return "\n".join(lines)


def _check_args(args: argparse.Namespace) -> None:
    if args.points < 3:
        raise ValueError(f"--points: needs at least 3, got {args.points}")
    if args.repeat < 1:
        raise ValueError(f"--repeat: needs at least 1, got {args.repeat}")
    if args.json is not None:  # fail now rather than after minutes of benchmarking
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    exp, num = make_curves(args.points, args.seed)
    _say(f"curves: {len(exp)} and {len(num)} points (seed {args.seed})")
    warm_s = _warm_up()
    _say(f"numba warm-up (compiles on first use, else loads its cache; not timed below): {warm_s:.2f} s")
    table = _combine(_run_metrics(exp, num, args.repeat, args.skip_reference))
    _say("")
    _say(_format_table(table))
    mismatched = [n for n in METRICS if (table[n]["max_rel_diff"] or 0.0) > MATCH_REL_TOL]
    if args.json is not None:
        payload = {
            "points": [len(exp), len(num)],
            "seed": args.seed,
            "repeat": args.repeat,
            "numba_warmup_s": warm_s,
            "python": sys.version.split()[0],
            "metrics": table,
        }
        write_json(args.json, payload, BENCH_RESULT, overwrite=args.overwrite)
        _say(f"wrote {args.json}")
    if mismatched:
        _say(f"MISMATCH beyond {MATCH_REL_TOL:g} relative: {', '.join(mismatched)}")
        return 1
    return 0
