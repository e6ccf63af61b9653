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


COMMANDS = [Command("table3", "reproduce seed paper 004's Table 3 in simulation (camera, EKF, delay-compensated EKF)",
                    configure_table3, run_table3)]
