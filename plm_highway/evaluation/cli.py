"""``plm-highway evaluate``: reference, baseline (and mitigated) closed-loop runs, as JSON + CSV.

- ``reference``: the policy without latency;
- ``baseline``: the same policy fed the delayed observations;
- ``mitigated`` (``--policy plm``): PLM-Net fed the delayed observations and told their age.
All runs share the track and the seed, so the same latency realisation.

The JSON holds ``track``, ``latency``, ``policy``, ``seed``, ``runs`` (per-run summary),
``steering`` (with ``--policy plm``: errors against the reference and PLM-Net's reductions),
``trajectory`` (``{part: {run: {metric: value}}}``, parts full/straight/left/right, see
:mod:`plm_highway.evaluation.trajectory`) and ``trajectory_method``. Beside it: one CSV per run
(``STEM_RUN.csv``, every logged column) and ``STEM_steps.csv`` with all runs side by side.
Inputs (track, latency spec, checkpoints, step limit) are checked before any run starts, and
nothing is written unless every run and metric succeeded.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from plm_highway.evaluation.closed_loop import RunLog, drive, make_env, write_log_csv
from plm_highway.evaluation.policies import POLICY_NAMES, make_policy, single_threaded_inference
from plm_highway.evaluation.trajectory import finite_or_none, trajectory_method, trajectory_metrics
from plm_highway.io.atomic import atomic_path, write_text_atomic
from plm_highway.latency import parse_profile
from plm_highway.road.track import TrackSpec, load_track

COMBINED_COLUMNS = ("steering", "latency_s", "observation_age_s", "x_m", "y_m", "lateral_offset_m", "segment")


def configure(parser) -> None:
    parser.add_argument("--track", default="test", help="train, test, unseen or a track JSON path")
    parser.add_argument("--latency", default="const:0.25", help="latency profile, e.g. const:0.2 or steps:0.0-0.35:1.0")
    parser.add_argument("--policy", choices=POLICY_NAMES, default="plm")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, help="stop each run after this many policy steps")
    parser.add_argument("--json", help="write the results here, and per-run step logs as CSV beside it")


def check_inputs(track, latency, max_steps=None) -> tuple[TrackSpec, str]:
    """Validate the track and latency spec the way the runs will use them; (track spec, latency spec)."""
    track_spec = load_track(track)
    latency_spec = parse_profile(latency).spec
    make_env(track, latency_spec).close()  # the latency must fit the wrapper's buffer
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"--max-steps {max_steps}: must be at least 1")
    return track_spec, latency_spec


def run_steps(track, max_steps: int | None) -> int | None:
    """``max_steps``, or on a closed track (which never ends by itself) the steps of one lap."""
    track_spec = load_track(track) if not isinstance(track, TrackSpec) else track
    if max_steps is not None or not track_spec.closed:
        return max_steps
    config = make_env(track, "const:0").unwrapped.config
    return math.ceil(track_spec.length_m / config["speed_mps"] * config["policy_frequency"]) + 1


def compare_runs(logs: dict[str, RunLog], track, latency_spec: str, policy: str, seed: int) -> dict:
    """The result dict of runs already driven (``reference``, ``baseline``, optionally ``mitigated``)."""
    result = {"track": str(track if not isinstance(track, TrackSpec) else track.name), "latency": latency_spec,
              "policy": policy, "seed": seed, "runs": {name: log.summary() for name, log in logs.items()}}
    if "mitigated" in logs:
        from plm_highway.evaluation.comparison import steering_comparison
        result["steering"] = steering_comparison(logs)
    track_spec = track if isinstance(track, TrackSpec) else load_track(track)
    result["trajectory"] = trajectory_metrics(logs, track_spec)
    result["trajectory_method"] = trajectory_method(track_spec)
    return json_safe(result)


def json_safe(value):
    """``value`` with NaN / inf floats replaced by None (strict JSON has neither)."""
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return finite_or_none(value)


def evaluate(track="test", latency="const:0.25", policy="plm", seed=0, max_steps=None, checkpoints=None) -> tuple[dict, dict]:
    """Run the comparison; returns (result dict, {run name: RunLog})."""
    _, latency_spec = check_inputs(track, latency, max_steps)
    max_steps = run_steps(track, max_steps)
    base_policy = "expert" if policy == "expert" else "bm"
    policies = {"reference": make_policy(base_policy, checkpoints), "baseline": make_policy(base_policy, checkpoints)}
    if policy == "plm":
        policies["mitigated"] = make_policy("plm", checkpoints)
    logs = {}
    for name, run_policy in policies.items():
        logs[name] = drive(name, run_policy, track, "const:0" if name == "reference" else latency_spec, seed,
                           max_steps=max_steps)
    return compare_runs(logs, track, latency_spec, policy, seed), logs


def write_combined_csv(logs: dict[str, RunLog], path: str | Path) -> None:
    """All runs side by side, one row per policy step: ``t_s`` then ``RUN_COLUMN`` for each run.

    Step k is the same instant in every run; a run that ended earlier has empty cells.
    """
    n_rows = max(log.steps for log in logs.values())
    longest = max(logs.values(), key=lambda log: log.steps)
    header = ["t_s"] + [f"{name}_{column}" for name in logs for column in COMBINED_COLUMNS]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for k in range(n_rows):
            row = [_cell(longest.columns["t_s"][k])]
            for log in logs.values():
                row += [_cell(log.columns[c][k]) if k < log.steps else "" for c in COMBINED_COLUMNS]
            writer.writerow(row)


def _cell(value) -> str:
    is_float = isinstance(value, float) or (hasattr(value, "dtype") and value.dtype.kind == "f")
    return f"{value:.6g}" if is_float else str(value)


def write_outputs(result: dict, logs: dict[str, RunLog], json_path: str | Path) -> None:
    json_path = Path(json_path)
    for name, log in logs.items():
        write_log_csv(log, json_path.with_name(f"{json_path.stem}_{name}.csv"))
    write_combined_csv(logs, json_path.with_name(f"{json_path.stem}_steps.csv"))
    write_text_atomic(json_path, json.dumps(result, indent=2, allow_nan=False) + "\n")


def run(args) -> int:
    with single_threaded_inference():
        result, logs = evaluate(args.track, args.latency, args.policy, args.seed, args.max_steps, args.checkpoints)
    text = json.dumps(result, indent=2, allow_nan=False)
    print(text)
    if args.json:
        write_outputs(result, logs, args.json)
    return 0

