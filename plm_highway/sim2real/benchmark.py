"""Seed sweeps and timings of the diagnosis (``plm-highway sim2real bench``): the large batteries
that the tests run only a few seeds of.

* ``recovery``: each case (an effect alone, or paired with an older one; small car; low sample
  rates with irregular timestamps and dropped rows) on several seeds: is the right set named, is
  every parameter within its tolerance (:data:`TOLERANCES`), what verdict, how much of the error
  is explained.
* ``match``: the simulator's own model plus noise, many seeds: the share of "match" verdicts.
* ``outside``: physics outside the library: never "match", never a tight fit that leaves more
  than 20% of the error unexplained without the "partly explained" verdict.
* ``timing``: a 10-minute 50 Hz recording, wall and CPU seconds; with ``--baseline-tree`` the same
  recording diagnosed by another source tree (e.g. the previous release) in a subprocess, so that
  both sides are printed from one run on the same (possibly loaded) machine.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field

import numpy as np
from tqdm import tqdm

from plm_highway.errors import BadInput
from plm_highway.io import BENCH_RESULT, check_target, write_json
from plm_highway.sim2real.diagnose import diagnose
from plm_highway.sim2real.physics.effects import EFFECTS
from plm_highway.sim2real.physics.synth import as_read, make_recording
from plm_highway.sim2real.rendering import to_json

# Per public parameter, from the registry: |estimate - truth| <= max(absolute, relative x |truth|).
TOLERANCES = {key: tolerance for e in EFFECTS.values() for key, tolerance in e.tolerances.items()}


def within_tolerance(key: str, estimate: float, truth: float) -> bool:
    if key not in TOLERANCES:
        return True  # cornering stiffnesses individually: reported, not graded
    absolute, relative = TOLERANCES[key]
    return abs(estimate - truth) <= max(absolute, relative * abs(truth))


@dataclass(frozen=True)
class Case:
    """One recovery case: concealed effects and how the recording is made."""

    name: str
    effects: dict
    options: dict = field(default_factory=dict)  # make_recording keyword arguments
    expect: tuple[str, ...] | None = None  # named set (default: the truth's effects)


NEW_EFFECT_CASES = [
    Case("steering_rate_limit", {"steering_rate_limit": 0.12}),
    Case("steering_rate_limit + transport_delay", {"steering_rate_limit": 0.12, "transport_delay": 0.1}),
    Case("tire_saturation", {"tire_saturation": 0.4}),
    Case("tire_saturation + transport_delay", {"tire_saturation": 0.45, "transport_delay": 0.12}),
    Case("sensor_delay", {"sensor_delay": 0.1}),
    Case("sensor_delay + steering_gain", {"sensor_delay": 0.1, "steering_gain": 0.9}),
    Case("road_bank", {"road_bank": 0.05}),
    Case("road_bank + transport_delay", {"road_bank": -0.05, "transport_delay": 0.15}),
    Case("delay_jitter", {"delay_jitter": 0.03}),
    Case("delay_jitter + steering_gain", {"delay_jitter": 0.03, "steering_gain": 1.1}),
]
SCALE_CASES = [
    Case("small car: transport_delay + tire_slip", {"transport_delay": 0.08, "tire_slip": None},
         {"car": "small"}),
    Case("small car: actuator_lag", {"actuator_lag": 0.1}, {"car": "small"}),
    Case("25 Hz irregular: transport_delay", {"transport_delay": 0.15},
         {"sample_hz": 25.0, "timestamp_jitter": 0.2, "drop_fraction": 0.1}),
    Case("10 Hz irregular: transport_delay + tire_slip", {"transport_delay": 0.2, "tire_slip": None},
         {"sample_hz": 10.0, "timestamp_jitter": 0.2, "drop_fraction": 0.05}),
    Case("15 Hz, small car: transport_delay", {"transport_delay": 0.1},
         {"sample_hz": 15.0, "car": "small", "timestamp_jitter": 0.1, "drop_fraction": 0.05}),
]
OLD_EFFECT_CASES = [
    Case("transport_delay", {"transport_delay": 0.15}),
    Case("actuator_lag", {"actuator_lag": 0.15}),
    Case("tire_slip", {"tire_slip": 0.003}),
    Case("steering_gain", {"steering_gain": 0.9}),
    Case("steering_offset", {"steering_offset": -0.006}),
    Case("transport_delay + tire_slip", {"transport_delay": 0.2, "tire_slip": None}),
    Case("actuator_lag + steering_offset", {"actuator_lag": 0.2, "steering_offset": 0.006}),
    Case("steering_gain + steering_offset", {"steering_gain": 0.85, "steering_offset": 0.008}),
]
OUTSIDE_CASES = [
    Case("steering_backlash", {"steering_backlash": 0.006}),
    Case("steering_backlash + transport_delay", {"steering_backlash": 0.008, "transport_delay": 0.1}),
    Case("commonroad multi-body", {}, {"model": "commonroad-mb", "duration_s": 60.0}),
]
CASE_SETS = {"new": NEW_EFFECT_CASES, "scale": SCALE_CASES, "old": OLD_EFFECT_CASES, "outside": OUTSIDE_CASES}


@dataclass
class Outcome:
    case: str
    seed: int
    verdict: str
    named: list[str]
    expected: list[str]
    named_right: bool
    parameters_ok: bool
    errors: dict[str, float]  # estimate - truth per parameter
    explained_fraction: float
    rmse_ratio: float  # held-out RMSE after / before (primary signal)
    seconds: float


def run_case(case: Case, seed: int, duration_s: float = 120.0) -> Outcome:
    options = {"duration_s": duration_s} | case.options
    recording, truth = make_recording(case.effects, rng=np.random.default_rng(seed), **options)
    started = time.perf_counter()
    result = to_json(diagnose(as_read(recording)))
    seconds = time.perf_counter() - started
    found = {e["name"]: e["params"] for e in result["effects"]}
    expected = sorted(case.expect if case.expect is not None else truth["effects"])
    errors, ok = {}, True
    for name, params in truth["effects"].items():
        for key, value in params.items():
            estimate = found.get(name, {}).get(key)
            if estimate is None:
                if key in TOLERANCES:
                    ok = False
                continue
            errors[f"{name}.{key}"] = estimate - value
            ok &= within_tolerance(key, estimate, value)
    fit = result["fit"]
    return Outcome(case.name, seed, result["verdict"], sorted(found), expected, sorted(found) == expected,
                   ok and sorted(found) == expected, errors, fit["explained_fraction"],
                   fit["rmse_after"] / fit["rmse_before"] if fit["rmse_before"] else math.nan, seconds)


def recovery(cases: Iterable[Case], seeds: Iterable[int], duration_s: float = 120.0, progress=None
             ) -> list[Outcome]:
    out = []
    for case in cases:
        for seed in seeds:
            out.append(run_case(case, seed, duration_s))
            if progress is not None:
                progress(out[-1])
    return out


def match_rate(seeds: Iterable[int], duration_s: float = 60.0, progress=None) -> list[str]:
    verdicts = []
    for seed in seeds:
        recording, _ = make_recording({}, rng=np.random.default_rng(50_000 + seed), duration_s=duration_s,
                                      model="simulator")
        verdicts.append(diagnose(recording).verdict)
        if progress is not None:
            progress(verdicts[-1])
    return verdicts


def timing(duration_s: float = 600.0, sample_hz: float = 50.0, seed: int = 5) -> dict:
    """Wall and CPU seconds of one diagnosis of a long recording (kernels warmed up first)."""
    recording, _ = make_recording({"transport_delay": 0.2, "tire_slip": None}, rng=np.random.default_rng(seed),
                                  duration_s=duration_s, sample_hz=sample_hz)
    diagnose(recording.slice(0, 1000))
    wall, cpu = time.perf_counter(), time.process_time()
    result = diagnose(recording)
    return {"samples": recording.n, "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
            "verdict": result.verdict, "named": list(result.selection.winner.effects),
            "load_average": os.getloadavg()[0], "cpus": os.cpu_count()}


_BASELINE_SNIPPET = """
import json, os, time, numpy as np
from plm_highway.sim2real.physics.synth import make_recording
from plm_highway.sim2real.diagnose import diagnose
rec, _ = make_recording({"transport_delay": 0.2, "tire_slip": None}, rng=np.random.default_rng(%d),
                        duration_s=%r, sample_hz=%r)
diagnose(rec.slice(0, 1000))
wall, cpu = time.perf_counter(), time.process_time()
result = diagnose(rec)
print(json.dumps({"samples": rec.n, "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
                  "verdict": result.verdict, "named": list(result.selection.winner.effects),
                  "load_average": os.getloadavg()[0]}))
"""


def baseline_timing(tree: str, duration_s: float = 600.0, sample_hz: float = 50.0, seed: int = 5) -> dict:
    """The same timing with another source tree (a subprocess with PYTHONPATH set to ``tree``)."""
    env = dict(os.environ, PYTHONPATH=tree)
    done = subprocess.run([sys.executable, "-c", _BASELINE_SNIPPET % (seed, duration_s, sample_hz)], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def summarize(outcomes: list[Outcome]) -> list[dict]:
    """Per case: seeds, named right, parameters within tolerance, verdicts, median |error| per parameter."""
    rows = []
    for case in dict.fromkeys(o.case for o in outcomes):
        mine = [o for o in outcomes if o.case == case]
        keys = sorted({k for o in mine for k in o.errors})
        rows.append({
            "case": case, "seeds": len(mine), "named_right": sum(o.named_right for o in mine),
            "parameters_ok": sum(o.parameters_ok for o in mine),
            "verdicts": {v: sum(o.verdict == v for o in mine) for v in sorted({o.verdict for o in mine})},
            "median_abs_error": {k: float(np.median([abs(o.errors[k]) for o in mine if k in o.errors]))
                                 for k in keys},
            "median_rmse_ratio": float(np.median([o.rmse_ratio for o in mine])),
            "median_seconds": float(np.median([o.seconds for o in mine])),
        })
    return rows


def markdown_table(rows: list[dict]) -> str:
    lines = ["| case | seeds | named right | parameters within tolerance | verdicts | median abs. error | "
             "held-out RMSE after/before |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        errors = ", ".join(f"{k.split('.')[-1]} {v:.3g}" for k, v in r["median_abs_error"].items())
        verdicts = ", ".join(f"{k} {v}" for k, v in r["verdicts"].items())
        lines.append(f"| {r['case']} | {r['seeds']} | {r['named_right']}/{r['seeds']} | "
                     f"{r['parameters_ok']}/{r['seeds']} | {verdicts} | {errors} | {r['median_rmse_ratio']:.2f} |")
    return "\n".join(lines)


def outcomes_json(outcomes: list[Outcome]) -> list[dict]:
    return [asdict(o) for o in outcomes]


def run_benchmarks(names: list[str], *, seeds: int = 3, duration_s: float = 600.0, baseline_tree: str | None = None,
                   json_path=None, overwrite: bool = False, command: str = "") -> int:
    """``plm-highway bench sim2real``: print each asked benchmark; ``names`` from timing, match and
    :data:`CASE_SETS`. Returns the exit code (0)."""

    unknown = sorted(set(names) - {"timing", "match", *CASE_SETS})
    if unknown or not names:
        raise BadInput(f"--cases: unknown {', '.join(unknown) or '(none given)'}; known: timing, match, "
                       f"{', '.join(CASE_SETS)}")
    if json_path is not None:
        check_target(json_path, BENCH_RESULT, overwrite=overwrite)
    results: dict = {"command": command, "seeds": seeds, "load_average_at_start": os.getloadavg()[0],
                     "cpus": os.cpu_count()}
    for name in names:
        if name == "timing":
            mine = timing(duration_s)
            results["timing"] = {"this_tree": mine}
            print(f"timing: {duration_s:.0f} s at 50 Hz ({mine['samples']} samples): {mine['wall_s']:.1f} s wall, "
                  f"{mine['cpu_s']:.1f} s CPU, verdict {mine['verdict']} ({' + '.join(mine['named'])}); "
                  f"load average {mine['load_average']:.1f} on {mine['cpus']} CPUs")
            if baseline_tree:
                other = baseline_timing(baseline_tree, duration_s)
                results["timing"]["baseline"] = other | {"tree": baseline_tree}
                print(f"baseline {baseline_tree}: {other['wall_s']:.1f} s wall, {other['cpu_s']:.1f} s CPU, verdict "
                      f"{other['verdict']}; this tree / baseline wall = {mine['wall_s'] / other['wall_s']:.2f}")
        elif name == "match":
            bar = tqdm(total=20 * seeds, desc="match", file=sys.stderr)
            verdicts = match_rate(range(20 * seeds), progress=lambda _, bar=bar: bar.update())
            bar.close()
            counts = {v: verdicts.count(v) for v in sorted(set(verdicts))}
            results["match"] = counts
            print(f"match: simulator's own model + noise, {len(verdicts)} seeds: {counts} "
                  f"({100 * counts.get('match', 0) / len(verdicts):.0f}% match)")
        else:
            cases = CASE_SETS[name]
            bar = tqdm(total=len(cases) * seeds, desc=name, file=sys.stderr)
            outcomes = recovery(cases, range(1, seeds + 1), progress=lambda _, bar=bar: bar.update())
            bar.close()
            results[name] = {"summary": summarize(outcomes), "outcomes": outcomes_json(outcomes)}
            print(f"\n{name} (seeds 1-{seeds}, 120 s recordings):\n{markdown_table(summarize(outcomes))}")
    if json_path is not None:
        write_json(json_path, results, BENCH_RESULT, overwrite=overwrite)
        print(f"wrote {json_path}")
    return 0
