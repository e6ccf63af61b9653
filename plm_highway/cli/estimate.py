"""``plm-highway estimate ...``: the model-based side (seed paper 004's delay-compensated lane EKF)."""

from __future__ import annotations

from plm_highway.cli._common import Command, add_overwrite, bounded_int

GROUP_HELP = "model-based latency compensation: the delay-compensated lane-coordinate EKF (seed paper 004)"


def configure_table3(parser) -> None:
    from plm_highway.estimation.table3 import MAX_SEEDS

    parser.add_argument("--seeds", type=bounded_int(1, MAX_SEEDS), default=5,
                        help="scored seeds 0..N-1 (at least 5 for the report's confidence intervals)")
    parser.add_argument("--scenarios", default="1,2,3,4", help="comma-separated scenario numbers (default all four)")
    parser.add_argument("--json", metavar="OUT.json", help="write the results to this JSON file")
    parser.add_argument("--out", metavar="DIR", help="write table3.json, table3.md and the Figure 7-10 style plots "
                                                     "(first seed) into this directory")
    add_overwrite(parser)


def run_table3(args) -> int:
    from plm_highway.estimation.report import TABLE3_JSON, TABLE3_REPORT, publish_table3
    from plm_highway.estimation.table3 import scenarios_by_number, table3
    from plm_highway.io import check_target

    scenarios = scenarios_by_number(args.scenarios)
    for path, kind in ((args.json, TABLE3_JSON), (args.out, TABLE3_REPORT)):
        if path is not None:  # refuse before minutes of simulation, not after
            check_target(path, kind, overwrite=args.overwrite)
    runs: list = []
    result = table3(args.seeds, scenarios=scenarios, keep_runs=runs if args.out else None)
    print(result.markdown())
    for path in publish_table3(result, runs, args.json, args.out, overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


def configure_compare(parser) -> None:
    from plm_highway.cli._common import defaults_of
    from plm_highway.evaluation.plm_vs_ekf import MAX_SEEDS, CompareConfig, compare

    d, c = defaults_of(compare), defaults_of(CompareConfig)
    parser.add_argument("--seeds", type=bounded_int(1, MAX_SEEDS), default=d["seeds"],
                        help="seeds 0..N-1, each a start pose, latency realisation and EKF sensor noise")
    parser.add_argument("--track", default=c["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--settings", default=",".join(c["settings"]),
                        help="comma-separated latency profiles every policy drives")
    parser.add_argument("--bias-latency", default=c["bias_latency"],
                        help="latency at which PLM-Net and the EKF are told a wrong latency")
    parser.add_argument("--biases", default=",".join(f"{b:g}" for b in c["biases_s"]),
                        help="comma-separated latency estimate errors [s] (empty: none)")
    parser.add_argument("--max-steps", type=bounded_int(2, 10_000_000),
                        help="stop each run after this many policy steps (default: the whole track)")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--workers", type=bounded_int(1, 16), default=d["workers"],
                        help="seeds driven at once in worker processes")
    parser.add_argument("--json", metavar="OUT.json", help="write the result JSON here")
    parser.add_argument("--out", metavar="DIR", help="write compare.json, compare.md, runs.csv and compare.png here "
                                                     "(e.g. figures/estimation/compare)")
    add_overwrite(parser)


def run_compare(args) -> int:
    from plm_highway.errors import BadInput
    from plm_highway.evaluation.plm_vs_ekf import CompareConfig, compare, markdown
    from plm_highway.evaluation.plm_vs_ekf_report import COMPARE_JSON, COMPARE_REPORT, publish_comparison
    from plm_highway.io import check_target

    try:
        biases = tuple(float(b) for b in args.biases.split(",") if b.strip())
    except ValueError:
        raise BadInput(f"--biases {args.biases!r}: expected comma-separated numbers of seconds") from None
    settings = tuple(s.strip() for s in args.settings.split(",") if s.strip())
    config = CompareConfig(track=args.track, settings=settings, bias_latency=args.bias_latency, biases_s=biases,
                           max_steps=args.max_steps)
    for path, kind in ((args.json, COMPARE_JSON), (args.out, COMPARE_REPORT)):
        if path is not None:  # refuse before an hour of driving, not after
            check_target(path, kind, overwrite=args.overwrite)
    result = compare(args.seeds, config, args.checkpoints, workers=args.workers)
    print(markdown(result.to_dict()))
    for path in publish_comparison(result, args.json, args.out, overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


COMMANDS = [Command("table3", "reproduce seed paper 004's Table 3 in simulation (camera, EKF, delay-compensated EKF)",
                    configure_table3, run_table3),
            Command("compare", "PLM-Net beside the delay-compensated EKF policy in the closed loop (same track, "
                               "latencies, seeds)", configure_compare, run_compare)]
