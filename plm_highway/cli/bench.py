"""``plm-highway bench ...``: benchmarks that print both sides of a comparison and their ratio."""

from __future__ import annotations

import importlib

from plm_highway.cli._common import Command, add_overwrite, bounded_float, bounded_int

GROUP_HELP = "benchmarks: both sides of a comparison in one run, and their ratio"


def _delegate(module_name: str) -> tuple:
    """configure/run of a benchmark module in plm_highway.bench (imported only when that benchmark runs)."""

    def configure(parser) -> None:
        importlib.import_module(f"plm_highway.bench.{module_name}").configure(parser)
        add_overwrite(parser)

    def run(args) -> int:
        return importlib.import_module(f"plm_highway.bench.{module_name}").run(args)

    return configure, run


def configure_estimation(parser) -> None:
    parser.add_argument("--delay", type=bounded_float(0.0, 1.0, open_minimum=True), default=0.3,
                        help="camera delay the re-estimation covers [s], up to the filter's 1 s history")
    parser.add_argument("--repeats", type=bounded_int(1, 1000), default=5, help="timed repeats; the median counts")
    parser.add_argument("--json", metavar="OUT.json", help="also write the results to this JSON file")
    add_overwrite(parser)


def run_estimation(args) -> int:
    from plm_highway.bench import BENCH_RESULT
    from plm_highway.estimation.bench import bench_dict, bench_estimation, bench_lines
    from plm_highway.io import check_target, write_json

    if args.json is not None:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench_estimation(delay_s=args.delay, repeats=args.repeats)
    print("\n".join(bench_lines(result)))
    if args.json is not None:
        write_json(args.json, bench_dict(result), BENCH_RESULT, overwrite=args.overwrite)
        print(f"wrote {args.json}")
    return 0


def configure_lessons(parser) -> None:
    from plm_highway.cli.lessons import configure_timing

    configure_timing(parser)


def run_lessons(args) -> int:
    from plm_highway.cli.lessons import run_timing

    return run_timing(args)


def configure_sim2real(parser) -> None:
    from plm_highway.cli.sim2real import configure_bench

    configure_bench(parser)


def run_sim2real(args) -> int:
    from plm_highway.cli.sim2real import run_bench

    return run_bench(args)


COMMANDS = [
    Command("env", "env + camera + latency steps/s against highway-env's own camera envs", *_delegate("env")),
    Command("models", "parameter counts and inference time of BM and PLM-Net", *_delegate("models")),
    Command("metrics", "trajectory metrics against similaritymeasures", *_delegate("metrics")),
    Command("estimation", "EKF costs per step with and without delay compensation, camera lane fit accuracy",
            configure_estimation, run_estimation),
    Command("lessons", "wall-clock time of each lesson top to bottom (budget 5 minutes on 2 cores)",
            configure_lessons, run_lessons),
    Command("sim2real", "sim2real diagnosis: seed sweeps (recovery, match rate, outside the library) and the "
            "10-minute timing beside a baseline tree", configure_sim2real, run_sim2real),
]
