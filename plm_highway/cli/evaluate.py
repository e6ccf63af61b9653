"""``plm-highway evaluate``: reference, baseline and mitigated closed-loop runs."""

from __future__ import annotations

import sys

from plm_highway.cli._common import (
    Command,
    add_device,
    add_overwrite,
    add_seed,
    bounded_int,
    device_of,
    static_defaults,
    static_names,
)

MAX_STEPS = 10_000_000


def configure(parser) -> None:
    # Read from the library's source, not imported: the help page stays fast (tests/test_cli_help.py).
    d = static_defaults("plm_highway.evaluation.evaluate", "evaluate")
    CONDITION_NAMES, INJECTION_LATENCY_SOURCE, LATENCY_SOURCE_NAMES = (
        static_names("plm_highway.rollout.conditions", name)
        for name in ("CONDITION_NAMES", "INJECTION_LATENCY_SOURCE", "LATENCY_SOURCE_NAMES"))
    POLICY_NAMES = static_names("plm_highway.rollout.policies", "POLICY_NAMES")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--latency", default=d["latency"],
                        help="latency profile, e.g. const:0.2 or steps:0.0-0.35:1.0")
    parser.add_argument("--policy", choices=POLICY_NAMES, default=d["policy"],
                        help="plm: reference + BM baseline + PLM-Net; bm-warp, bm-smith: the same with the BM and a "
                             "plug-in mitigation instead of PLM-Net (docs: mitigations); bm: the first two; expert: "
                             "the expert twice; "
                             "ekf: the EKF lane keeper without latency, without and with delay compensation, its LQR "
                             "designed for the conditions' loop, actuator and processing delay")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: the shipped pair)")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=d["conditions"],
                        help="ideal: this simulator's setup; paper: the paper's loop, pipeline, camera, latency "
                             "injection and the `paper` checkpoints, as reproduce --conditions paper drives them")
    parser.add_argument("--injection", choices=INJECTION_LATENCY_SOURCE,
                        help="latency injection instead of the conditions' own (ideal: time, paper: legacy-fifo), as "
                             "for reproduce; legacy-fifo also runs the BM baseline of a time-varying profile at its "
                             "middle latency, as the original code did")
    parser.add_argument("--latency-source", choices=LATENCY_SOURCE_NAMES,
                        help="what the mitigation is told instead of the conditions' own (ideal: measured, paper: "
                             "requested): measured (the frame's true age), requested, or estimated (from the camera "
                             "and the car's fast sensors, no capture timestamps; every run then logs the estimate, "
                             "latency_estimate_s and latency_estimable, beside the true age)")
    add_seed(parser, d["seed"])
    parser.add_argument("--seeds", help="run every run once per seed: a count N (seeds --seed .. --seed+N-1) or a "
                                        "list a,b,c; the JSON adds per_seed and over_seeds (mean, 95%% CI)")
    parser.add_argument("--max-steps", type=bounded_int(1, MAX_STEPS), help="stop each run after this many policy steps")
    parser.add_argument("--json", metavar="OUT.json", help="write the result JSON here")
    parser.add_argument("--out", metavar="DIR", help="write result.json and per-step CSV logs (one per run, and "
                                                     "steps.csv with the runs side by side) into this directory")
    parser.add_argument("--print-json", action="store_true",
                        help="print the full result JSON instead of the short summary")
    add_overwrite(parser)
    add_device(parser)


def run(args) -> int:
    from plm_highway.latency.profiles import parse_profile

    # parsed at the boundary, before the simulator and the models are imported: a typo is refused at once
    latency = parse_profile(args.latency)
    from plm_highway.evaluation.evaluate import (
        EVALUATION_DIR,
        EVALUATION_JSON,
        evaluate,
        publish_results,
        summary_lines,
    )
    from plm_highway.io import check_target, json_text
    from plm_highway.rollout.policies import single_threaded_inference

    for path, kind in ((args.json, EVALUATION_JSON), (args.out, EVALUATION_DIR)):
        if path is not None:
            check_target(path, kind, overwrite=args.overwrite)
    with single_threaded_inference():
        result, logs = evaluate(args.track, latency, args.policy, seed=args.seed, max_steps=args.max_steps,
                                checkpoints=args.checkpoints, seeds=args.seeds, conditions=args.conditions,
                                injection=args.injection, device=device_of(args), latency_source=args.latency_source)
    if args.json or args.out:
        publish_results(result, logs, args.json, args.out, overwrite=args.overwrite)
    if args.print_json:
        sys.stdout.write(json_text(result, EVALUATION_JSON))
        return 0
    print("\n".join(summary_lines(result)))
    written = [path for path in (args.json, args.out) if path]
    print(f"full result: {', '.join(map(str, written))}" if written else
          "full result: --json OUT.json or --out DIR writes it (--print-json prints it)")
    return 0


COMMANDS = [Command("evaluate", "closed-loop reference / baseline / mitigated runs", configure, run)]
