"""``plm-highway evaluate``: reference, baseline (and mitigated) closed-loop runs, as JSON + CSV.

- ``reference``: the policy without latency;
- ``baseline``: the same policy fed the delayed observations;
- ``mitigated`` (``--policy plm``): PLM-Net fed the delayed observations and told their age.
All runs share the track and the seed, so the same latency realisation.
"""

from __future__ import annotations

import json
from pathlib import Path

from plm_highway.data.atomic import write_text_atomic
from plm_highway.evaluation.closed_loop import drive, write_log_csv
from plm_highway.evaluation.policies import POLICY_NAMES, make_policy
from plm_highway.latency import parse_profile


def configure(parser) -> None:
    parser.add_argument("--track", default="test", help="train, test, unseen or a track JSON path")
    parser.add_argument("--latency", default="const:0.25", help="latency profile, e.g. const:0.2 or steps:0.0-0.35:1.0")
    parser.add_argument("--policy", choices=POLICY_NAMES, default="plm")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, help="stop each run after this many policy steps")
    parser.add_argument("--json", help="write the results here, and per-run step logs as CSV beside it")


def evaluate(track="test", latency="const:0.25", policy="plm", seed=0, max_steps=None, checkpoints=None) -> tuple[dict, dict]:
    """Run the comparison; returns (result dict, {run name: RunLog})."""
    latency_spec = parse_profile(latency).spec  # validate before any run starts
    base_policy = "expert" if policy == "expert" else "bm"
    logs = {
        "reference": drive("reference", make_policy(base_policy, checkpoints), track, "const:0", seed, max_steps=max_steps),
        "baseline": drive("baseline", make_policy(base_policy, checkpoints), track, latency_spec, seed, max_steps=max_steps),
    }
    if policy == "plm":
        logs["mitigated"] = drive("mitigated", make_policy("plm", checkpoints), track, latency_spec, seed,
                                  max_steps=max_steps)
    result = {"track": str(track), "latency": latency_spec, "policy": policy, "seed": seed,
              "runs": {name: log.summary() for name, log in logs.items()}}
    if policy == "plm":
        from plm_highway.evaluation.steering import steering_comparison
        result["steering"] = steering_comparison(logs)
    return result, logs


def run(args) -> int:
    result, logs = evaluate(args.track, args.latency, args.policy, args.seed, args.max_steps, args.checkpoints)
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        json_path = Path(args.json)
        for name, log in logs.items():
            write_log_csv(log, json_path.with_name(f"{json_path.stem}_{name}.csv"))
        write_text_atomic(json_path, text + "\n")
    return 0
