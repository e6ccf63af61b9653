"""Command-line adapters: ``plm-highway estimate table3`` and ``plm-highway bench estimation``.

Argument parsing only; the work is :func:`plm_highway.estimation.table3.table3` and
:func:`plm_highway.estimation.bench.bench_estimation`. One module serves both commands: the router
sets ``command`` as a parser default before calling :func:`configure`.
"""

from __future__ import annotations

import json

TABLE3_COMMAND = "estimate table3"
BENCH_COMMAND = "bench estimation"
DEFAULT_FIGURES_DIR = "figures/estimation"


def configure(parser) -> None:
    command = parser.get_default("command") or TABLE3_COMMAND
    parser.add_argument("--json", help="also write the results to this JSON file")
    if command == BENCH_COMMAND:
        parser.add_argument("--delay", type=float, default=0.3, help="camera delay the re-estimation covers [s]")
        parser.add_argument("--repeats", type=int, default=5)
        return
    parser.add_argument("--seeds", type=int, default=5, help="scored seeds 0..N-1 (at least 5 for the report)")
    parser.add_argument("--figures", default=DEFAULT_FIGURES_DIR,
                        help="directory for the Figure 7-10 style plots (seed 0); '' for none")
    parser.add_argument("--markdown", help="also write the table as Markdown to this file")
    parser.add_argument("--scenarios", default="1,2,3,4", help="comma-separated scenario numbers (default all four)")


def run(args) -> int:
    from plm_highway.io import write_text_atomic

    if getattr(args, "command", TABLE3_COMMAND) == BENCH_COMMAND:
        from plm_highway.estimation.bench import bench_dict, bench_estimation, bench_lines

        result = bench_estimation(delay_s=args.delay, repeats=args.repeats)
        print("\n".join(bench_lines(result)))
        if args.json:
            write_text_atomic(args.json, json.dumps(bench_dict(result), indent=1))
        return 0

    from pathlib import Path

    from plm_highway.estimation.figures import plot_scenario_run
    from plm_highway.estimation.table3 import scenarios_by_number, table3

    runs: list = []
    result = table3(args.seeds, scenarios=scenarios_by_number(args.scenarios), keep_runs=runs)
    print(result.markdown())
    if args.figures:
        for run in runs:
            if run.seed == result.seeds[0]:
                path = plot_scenario_run(run, Path(args.figures) / f"scenario{run.scenario.number}_{run.scenario.key}.png")
                print(f"figure: {path}")
    if args.json:
        write_text_atomic(args.json, json.dumps(result.to_dict(), indent=1))
    if args.markdown:
        write_text_atomic(args.markdown, result.markdown() + "\n")
    return 0
