"""``plm-highway mitigations``: plug-in mitigations around the frozen BM, judged on the population's committed pairs
and on the shipped pair, beside the BM, PLM-Net and the EKF lane keeper."""

from __future__ import annotations

from pathlib import Path

from plm_highway.cli._common import Command, bounded_int


def configure(parser) -> None:
    from plm_highway.rollout.backends import MAX_WORKERS, default_workers

    parser.add_argument("--population", type=Path, default=Path("figures/population"),
                        help="the population report whose committed pairs are judged (its pairs/pair-NN.json)")
    parser.add_argument("--work", type=Path, default=Path("runs/population/paper"),
                        help="the population's work directory holding those pairs' checkpoints (refused unless "
                             "their weights hash to the pair records')")
    parser.add_argument("--pairs", type=bounded_int(0, 1000),
                        help="judge only the first N committed pairs (default: all; 0: the shipped pair only)")
    parser.add_argument("--shipped-seeds", type=bounded_int(1, 100), default=5,
                        help="simulator seeds 0..N-1 for the shipped pair under the ideal conditions")
    parser.add_argument("--out", type=Path, default=Path("figures/mitigations"), help="report directory")
    parser.add_argument("--workers", type=bounded_int(0, MAX_WORKERS), default=default_workers(),
                        help="local worker processes (0: everything in this process)")
    parser.add_argument("--batch-size", type=bounded_int(1, 4096), default=16,
                        help="envs stepped together per worker")
    parser.add_argument("--report-only", action="store_true",
                        help="render the report from the parts committed under --out; drive nothing")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args) -> int:
    from plm_highway.population import mitigations as study
    from plm_highway.rollout.cells import local_workers

    if args.report_only:  # the committed parts as they are: no checkpoints needed (a fresh clone has none)
        summary = study.render(args.out, study.committed_parts(args.out))
    else:
        # the shipped pair first: the cheapest part, and the only one a fresh clone can drive without a population
        parts = [study.shipped_part(range(args.shipped_seeds))]
        if args.pairs != 0:
            parts += study.population_parts(args.population, args.work, args.pairs)
        with local_workers(args.workers) as backend:
            summary = study.run_study(parts, args.out, backend, args.batch_size, not args.no_progress)
    for line in study.headline(summary):
        print(line)
    print(f"report: {args.out / 'report.md'}")
    return 0


COMMANDS = [Command("mitigations", "judge plug-in mitigations around the frozen BM (view warp, Smith correction) "
                    "on the population's pairs and the shipped pair, beside PLM-Net and the EKF lane keeper",
                    configure, run)]
