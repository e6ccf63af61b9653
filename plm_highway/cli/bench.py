"""``plm-highway bench ...``: benchmarks that print both sides of a comparison and their ratio."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_device,
    add_overwrite,
    bounded_float,
    bounded_int,
    defaults_of,
    device_of,
    static_defaults,
    static_names,
    static_value,
)

GROUP_HELP = "benchmarks: both sides of a comparison in one run, and their ratio"


def configure_estimation(parser) -> None:
    parser.add_argument("--delay", type=bounded_float(0.0, 1.0, open_minimum=True), default=0.3,
                        help="camera delay the re-estimation covers [s], up to the filter's 1 s history")
    parser.add_argument("--repeats", type=bounded_int(1, 1000), default=5, help="timed repeats; the median counts")
    parser.add_argument("--json", metavar="OUT.json", help="also write the results to this JSON file")
    add_overwrite(parser)


def run_estimation(args) -> int:
    from plm_highway.io import BENCH_RESULT, check_target, write_json
    from plm_highway.lane_ekf.bench import bench_dict, bench_estimation, bench_lines

    if args.json is not None:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench_estimation(delay_s=args.delay, repeats=args.repeats)
    print("\n".join(bench_lines(result)))
    if args.json is not None:
        write_json(args.json, bench_dict(result), BENCH_RESULT, overwrite=args.overwrite)
        print(f"wrote {args.json}")
    return 0


def configure_memory(parser) -> None:
    from plm_highway.bench.memory import MAX_STEPS, MIN_STEPS, memory_run

    d = defaults_of(memory_run)
    parser.add_argument("--steps", type=bounded_int(MIN_STEPS, MAX_STEPS), default=d["steps"],
                        help="policy steps measured after the warm-up")
    parser.add_argument("--warmup-steps", type=bounded_int(0, MAX_STEPS), default=d["warmup_steps"],
                        help="policy steps before the starting RSS is read (imports and caches settle)")
    parser.add_argument("--sample-every", type=bounded_int(1, MAX_STEPS), default=d["sample_every"],
                        help="read the RSS every this many steps (for the slope)")
    parser.add_argument("--latency", default=d["latency"], help="latency profile of the wrapper")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--json", metavar="OUT.json", help="also write the figures to this JSON file")
    add_overwrite(parser)


def run_memory(args) -> int:
    from tqdm import tqdm

    from plm_highway.bench.memory import memory_lines, memory_run
    from plm_highway.io import BENCH_RESULT, check_target, write_json

    if args.json is not None:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    with tqdm(total=args.steps, unit="step", desc="bench memory", mininterval=2.0) as bar:
        result = memory_run(args.steps, args.latency, args.track, args.warmup_steps, args.sample_every,
                            progress=bar.update)
    print("\n".join(memory_lines(result)))
    if args.json is not None:
        write_json(args.json, {**result.as_dict(), "command": args.command_line}, BENCH_RESULT,
                   overwrite=args.overwrite)
        print(f"wrote {args.json}")
    return 0


def configure_lessons(parser) -> None:
    from plm_highway.cli.lessons import configure_timing

    configure_timing(parser)


def run_lessons(args) -> int:
    from plm_highway.cli.lessons import run_timing

    return run_timing(args)


def configure_metrics(parser) -> None:
    from types import SimpleNamespace


    # Read from the library's source, not imported: the help page imports no scipy (tests/test_cli_help.py).
    bench = SimpleNamespace(**{name: static_value("plm_highway.bench.metrics", name)
                               for name in ("DEFAULT_POINTS", "DEFAULT_REPEAT", "DEFAULT_SEED")})

    parser.add_argument("--points", type=int, default=bench.DEFAULT_POINTS, help="points on the first curve")
    parser.add_argument("--json", metavar="OUT.json", help="also write the results to this JSON file")
    parser.add_argument("--skip-reference", action="store_true", help="time plm_highway only (no similaritymeasures)")
    parser.add_argument("--repeat", type=int, default=bench.DEFAULT_REPEAT,
                        help="runs of each function per side; fastest counts")
    parser.add_argument("--seed", type=int, default=bench.DEFAULT_SEED, help="seed of the random curves")
    add_overwrite(parser)


def run_metrics(args) -> int:
    from plm_highway.bench import metrics as bench
    from plm_highway.io import BENCH_RESULT, check_target, write_json

    bench.check_settings(args.points, args.repeat)
    if args.json is not None:  # fail now rather than after minutes of benchmarking
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench.run_benchmark(args.points, args.seed, args.repeat, args.skip_reference)
    print(bench.format_table(result["functions"]))
    print(bench.target_line(result["functions"], result["points"][0]))
    if args.json is not None:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
        print(f"wrote {args.json}")
    mismatched = bench.mismatches(result["functions"])
    if mismatched:
        print(f"MISMATCH beyond {bench.MATCH_REL_TOL:g} relative: {', '.join(mismatched)}")
        return 1
    return 0


def configure_models(parser) -> None:
    from types import SimpleNamespace


    # Read from the library's source, not imported: the help page imports no torch (tests/test_cli_help.py).
    bench = SimpleNamespace(PRESETS=static_names("plm_highway.bench.models", "PRESETS"),
                            WEIGHTS=static_names("plm_highway.bench.models", "WEIGHTS"),
                            TRAIN_BATCH_SIZE=static_value("plm_highway.bench.models", "TRAIN_BATCH_SIZE"))

    parser.add_argument("--preset", choices=(*bench.PRESETS, "both"), default="both", help="model size preset(s) to time")
    parser.add_argument("--frames", type=int, default=500, help="timed frames per side and repeat (>= 500 for the report)")
    parser.add_argument("--warmup", type=int, default=50, help="untimed frames per side first")
    parser.add_argument("--repeats", type=int, default=3, help="repeats of every measurement; medians are reported")
    parser.add_argument("--train-batches", type=int, default=10,
                        help=f"training batches of {bench.TRAIN_BATCH_SIZE} per timed epoch")
    parser.add_argument("--closed-loop", action="store_true",
                        help="also drive the shipped checkpoints with PLM-Net's reference forward, its exact fused "
                             "form and its int8 TAPM form (steering MAE before/after, 5 seeds, 95%% CIs), each "
                             "preset under its conditions (default: ideal, paper: paper)")
    parser.add_argument("--closed-loop-steps", type=bounded_int(10, 1_000_000), default=None,
                        help="stop each closed-loop run after this many policy steps (default: the scored track)")
    parser.add_argument("--weights", choices=bench.WEIGHTS, default="shipped",
                        help="shipped: each preset's shipped checkpoints on frames the simulator renders under its "
                             "conditions (what the closed loop runs); random: fresh weights on random frames "
                             "(PLM-Net's one-frame cost depends on how many image features are zero)")
    add_device(parser)
    parser.add_argument("--json", metavar="OUT.json", help="write the results to this JSON file")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random weights and inputs")
    add_overwrite(parser)


def run_models(args) -> int:
    import os

    import torch

    from plm_highway.bench import models as bench
    from plm_highway.io import BENCH_RESULT, check_target, write_json
    from plm_highway.models.config_checks import check_int

    check_int("--frames", args.frames, 1, bench.MAX_FRAMES)
    check_int("--warmup", args.warmup, 0, bench.MAX_FRAMES)
    check_int("--repeats", args.repeats, 1, bench.MAX_REPEATS)
    check_int("--train-batches", args.train_batches, 1, 10_000)
    check_int("--threads", args.threads, 1, os.cpu_count() or 1)
    check_int("--seed", args.seed, 0, 2**32 - 1)
    device = device_of(args)
    if args.json:  # refuse before the benchmark runs, not after
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    torch.set_num_threads(args.threads)
    presets = bench.PRESETS if args.preset == "both" else (args.preset,)
    result = bench.benchmark_models(presets, args.frames, args.warmup, args.repeats, args.train_batches, args.seed,
                                    args.closed_loop, args.closed_loop_steps, device, args.weights)
    result["command"] = args.command_line
    print(bench.format_report(result))
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
    return 0


def configure_sim2real(parser) -> None:
    from plm_highway.cli.sim2real import configure_bench

    configure_bench(parser)


def run_sim2real(args) -> int:
    from plm_highway.cli.sim2real import run_bench

    return run_bench(args)


def configure_env(parser) -> None:
    from plm_highway.bench.env import EnvBenchConfig

    defaults = EnvBenchConfig()
    parser.add_argument("--steps", type=int, default=defaults.steps, help="policy steps per repeat and side")
    parser.add_argument("--repeats", type=int, default=defaults.repeats,
                        help="repeats per side, stepped in turn; the median is reported")
    parser.add_argument("--latency", default=defaults.latency, help="latency profile of our wrapped side")
    parser.add_argument("--track", default=defaults.track, help="track of our side")
    parser.add_argument("--json", metavar="OUT.json", help="also write the figures to this JSON file")
    add_overwrite(parser)


def run_env(args) -> int:
    from plm_highway.bench.env import EnvBenchConfig, bench_env, format_bench
    from plm_highway.io import BENCH_RESULT, check_target, write_json

    config = EnvBenchConfig(args.steps, args.repeats, args.latency, args.track)
    if args.json:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench_env(config)
    print(format_bench(result))
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
    return 0


def configure_sweep(parser) -> None:
    parser.add_argument("--envs", type=bounded_int(1, 256), default=16, help="runs (seeds 0..N-1) driven each way")
    parser.add_argument("--steps", type=bounded_int(2, 100_000), default=100, help="policy steps per run")
    parser.add_argument("--policy", choices=("bm", "plm"), default="plm", help="model policy driving every run")
    parser.add_argument("--latency", default="steps:0.0-0.35:1.0", help="latency profile of every run")
    parser.add_argument("--track", default="test", help="track of every run")
    parser.add_argument("--workers", type=bounded_int(1, 64), default=2, help="processes of the pool sides")
    parser.add_argument("--repeats", type=bounded_int(1, 100), default=3,
                        help="times every side is timed (interleaved); medians are reported")
    parser.add_argument("--no-two-thread-serial", action="store_true",
                        help="leave out the one-env side on two torch threads (very slow on a loaded machine)")
    parser.add_argument("--json", metavar="OUT.json", help="also write the figures to this JSON file")
    add_overwrite(parser)


def run_sweep(args) -> int:
    from plm_highway.bench.sweep import bench_sweep, report_lines
    from plm_highway.io import BENCH_RESULT, check_target, write_json

    if args.json:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench_sweep(args.envs, args.steps, args.policy, args.latency, args.track, args.workers,
                         not args.no_two_thread_serial, args.repeats)
    print("\n".join(report_lines(result)))
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
        print(f"wrote {args.json}")
    return 0


def configure_reproduce(parser) -> None:
    # Read from the library's source, not imported: the help page imports no scipy (tests/test_cli_help.py).
    d = static_defaults("plm_highway.bench.sweep", "bench_reproduce")
    CONDITION_NAMES = static_names("plm_highway.rollout.conditions", "CONDITION_NAMES")
    parser.add_argument("--seeds", type=bounded_int(1, 1000), default=d["seeds"], help="seeds per setting")
    parser.add_argument("--max-steps", type=bounded_int(1, 10_000_000), default=d["max_steps"],
                        help="stop each run after this many policy steps (a full run is ~1,400 on the test track)")
    parser.add_argument("--workers", type=bounded_int(1, 64), default=d["workers"], help="processes of the parallel side")
    parser.add_argument("--batch-size", type=bounded_int(1, 4096), default=d["batch_size"],
                        help="envs stepped together on the batched sides")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=d["conditions"],
                        help="the conditions reproduce's runs are driven under (paper: its 160x160 checkpoints)")
    parser.add_argument("--json", metavar="OUT.json", help="also write the figures to this JSON file")
    add_overwrite(parser)


def run_reproduce(args) -> int:
    from plm_highway.bench.sweep import bench_reproduce, reproduce_report_lines
    from plm_highway.io import BENCH_RESULT, check_target, write_json

    if args.json:
        check_target(args.json, BENCH_RESULT, overwrite=args.overwrite)
    result = bench_reproduce(args.seeds, args.max_steps, args.workers, conditions=args.conditions,
                             batch_size=args.batch_size)
    print("\n".join(reproduce_report_lines(result)))
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
        print(f"wrote {args.json}")
    return 0


COMMANDS = [
    Command("env", "env + camera + latency steps/s against highway-env's own camera envs", configure_env, run_env),
    Command("models", "parameter counts and inference time of BM and PLM-Net", configure_models, run_models),
    Command("sweep", "N closed-loop runs one env at a time vs batched (own envs, gymnasium vector API) vs a "
            "process pool", configure_sweep, run_sweep),
    Command("reproduce", "reproduce's runs (default settings, --seeds) serial vs batched vs on a process pool",
            configure_reproduce, run_reproduce),
    Command("metrics", "trajectory metrics against similaritymeasures", configure_metrics, run_metrics),
    Command("estimation", "EKF costs per step with and without delay compensation, camera lane fit accuracy",
            configure_estimation, run_estimation),
    Command("memory", "RSS over a long run (200k policy steps) of the env with the latency wrapper",
            configure_memory, run_memory),
    Command("lessons", "wall-clock time of each lesson top to bottom (budget 5 minutes on 2 cores)",
            configure_lessons, run_lessons),
    Command("sim2real", "sim2real diagnosis: seed sweeps (recovery, match rate, outside the library) and the "
            "10-minute timing beside a baseline tree", configure_sim2real, run_sim2real),
]
