"""``plm-highway estimate ...``: the model-based side (the delay-compensated lane EKF of Kim, Kang and Ahn, Sensors 2025)."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_overwrite,
    bounded_float,
    bounded_int,
    static_defaults,
    static_fields,
    static_names,
    static_value,
)

GROUP_HELP = ("model-based latency compensation: the delay-compensated lane-coordinate EKF (Kim, Kang and Ahn, "
              "Sensors 2025)")


def configure_table3(parser) -> None:
    # Read from the library's source, not imported: the help page imports no scipy (tests/test_cli_help.py).
    MAX_SEEDS = static_value("plm_highway.lane_ekf.table3", "MAX_SEEDS")
    MEASUREMENTS = static_names("plm_highway.lane_ekf.table3", "MEASUREMENTS")
    parser.add_argument("--seeds", type=bounded_int(1, MAX_SEEDS), default=5,
                        help="scored seeds 0..N-1 (at least 5 for the report's confidence intervals)")
    parser.add_argument("--scenarios", default="1,2,3,4", help="comma-separated scenario numbers (default all four)")
    parser.add_argument("--measurements", default=",".join(MEASUREMENTS),
                        help="comma-separated lane measurements: clean (the simulated camera's fit as it comes), "
                             "realistic (plus the error the kit's detector makes on the kit's own frames)")
    parser.add_argument("--json", metavar="OUT.json", help="write the results to this JSON file")
    parser.add_argument("--out", metavar="DIR", help="write table3.json, table3.md and the Figure 7-10 style plots "
                                                     "(first seed) into this directory")
    add_overwrite(parser)


def run_table3(args) -> int:
    from plm_highway.errors import BadInput
    from plm_highway.io import check_target
    from plm_highway.lane_ekf.report import TABLE3_JSON, TABLE3_REPORT, publish_table3
    from plm_highway.lane_ekf.table3 import MEASUREMENTS, scenarios_by_number, table3_report

    scenarios = scenarios_by_number(args.scenarios)
    measurements = tuple(dict.fromkeys(m.strip() for m in args.measurements.split(",") if m.strip()))
    unknown = [m for m in measurements if m not in MEASUREMENTS]
    if unknown or not measurements:
        raise BadInput(f"--measurements {args.measurements!r}: expected a comma-separated choice of {list(MEASUREMENTS)}")
    for path, kind in ((args.json, TABLE3_JSON), (args.out, TABLE3_REPORT)):
        if path is not None:  # refuse before minutes of simulation, not after
            check_target(path, kind, overwrite=args.overwrite)
    runs: dict = {}
    result = table3_report(args.seeds, measurements, scenarios, keep_runs=runs if args.out else None)
    print(result.markdown())
    for path in publish_table3(result, runs, args.json, args.out, overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


def configure_compare(parser) -> None:
    # Read from the library's source, not imported: the help page imports no scipy (tests/test_cli_help.py).
    MAX_SEEDS = static_value("plm_highway.evaluation.plm_vs_ekf", "MAX_SEEDS")
    d = static_defaults("plm_highway.evaluation.plm_vs_ekf", "compare")
    c = static_fields("plm_highway.evaluation.plm_vs_ekf", "CompareConfig")
    parser.add_argument("--conditions", default="ideal,paper",
                        help="comma-separated conditions, each driven in full (ideal: this simulator's setup; paper: "
                             "the paper's loop, pipeline, camera, latency injection and checkpoints)")
    parser.add_argument("--seeds", type=bounded_int(1, MAX_SEEDS), default=d["seeds"],
                        help="seeds 0..N-1, each a start perturbation, latency realisation, image noise and EKF "
                             "sensor noise")
    parser.add_argument("--track", default=c["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--settings", default=",".join(c["settings"]),
                        help="comma-separated latency profiles every policy drives (no latency is always driven)")
    parser.add_argument("--bias-latency", default=c["bias_latency"],
                        help="latency at which PLM-Net and the EKF are told a wrong latency (with --biases)")
    parser.add_argument("--biases", default="", help="comma-separated latency estimate errors [s] (default: none)")
    parser.add_argument("--max-steps", type=bounded_int(2, 10_000_000),
                        help="stop each run after this many policy steps (default: the whole scored track)")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: the conditions' "
                                              "shipped pair)")
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
    names = tuple(dict.fromkeys(n.strip() for n in args.conditions.split(",") if n.strip()))
    if not names:
        raise BadInput(f"--conditions {args.conditions!r}: name at least one of ideal, paper")
    configs = [CompareConfig(conditions=name, track=args.track, settings=settings, bias_latency=args.bias_latency,
                             biases_s=biases, max_steps=args.max_steps) for name in names]
    for path, kind in ((args.json, COMPARE_JSON), (args.out, COMPARE_REPORT)):
        if path is not None:  # refuse before hours of driving, not after
            check_target(path, kind, overwrite=args.overwrite)
    results = [compare(args.seeds, config, args.checkpoints, workers=args.workers) for config in configs]
    print(markdown([result.to_dict() for result in results]))
    for path in publish_comparison(results, args.json, args.out, overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


def configure_latency(parser) -> None:
    from types import SimpleNamespace


    # LatencySuite's defaults read from the library's source: the help page imports no scipy.
    d = SimpleNamespace(**static_fields("plm_highway.evaluation.latency_estimation", "LatencySuite"))
    parser.add_argument("--out", default="figures/latency-estimation",
                        help="report directory: results.json, report.md (rendered from it) and the figures")
    parser.add_argument("--seeds", type=bounded_int(1, 100), default=len(d.seeds), help="seeds 0..N-1")
    parser.add_argument("--conditions", default=",".join(d.conditions), help="comma-separated: ideal, paper")
    parser.add_argument("--tracks", default=",".join(d.tracks), help="comma-separated track names or JSON paths")
    parser.add_argument("--duration-s", type=bounded_float(1.0, 1e5), default=d.duration_s,
                        help="drive each closed-loop run for the scored track's first this many seconds")
    parser.add_argument("--whole-track", action="store_true", help="drive each run over the whole scored track")
    parser.add_argument("--table3-seeds", type=bounded_int(0, 100), default=len(d.table3_seeds),
                        help="seeds of the EKF's Table 3 scenarios (0: skip them)")
    parser.add_argument("--workers", type=bounded_int(0, 64), default=0,
                        help="runs driven at once in worker processes (0: in this process)")
    parser.add_argument("--cache", metavar="DIR",
                        help="keep each finished run here (one JSON per run) and reuse them: an interrupted "
                             "measurement resumes")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--real-recording", metavar="CSV",
                        help="a real recording (sim2real format) whose perception delay the report puts beside its "
                             "diagnosis's delays (default: only the simulated recording)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(parser)


def run_latency(args) -> int:
    from plm_highway.evaluation.latency_estimation import LatencySuite, measure
    from plm_highway.evaluation.latency_estimation_report import LATENCY_REPORT, write_latency_report
    from plm_highway.io import check_target
    from plm_highway.rollout.policies import single_threaded_inference
    from plm_highway.sim2real.perception_tie_in import tie_in

    suite = LatencySuite(conditions=tuple(c.strip() for c in args.conditions.split(",") if c.strip()),
                         tracks=tuple(t.strip() for t in args.tracks.split(",") if t.strip()),
                         seeds=tuple(range(args.seeds)), duration_s=None if args.whole_track else args.duration_s,
                         table3_seeds=tuple(range(args.table3_seeds)))
    check_target(args.out, LATENCY_REPORT, overwrite=args.overwrite)  # refuse before hours of driving, not after
    with single_threaded_inference():
        sim2real = tie_in(args.real_recording, args.checkpoints)  # a bad recording fails before hours of driving
        results = measure(suite, args.command_line, args.cache, args.workers, args.checkpoints,
                          progress=not args.no_progress)
    results["sim2real"] = sim2real
    for target in results["targets"]:
        print(f"{'met   ' if target['met'] else 'MISSED'} {target['target']}: {target['detail']}")
    for path in write_latency_report(results, args.out, overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


COMMANDS = [Command("table3", "reproduce the EKF paper's Table 3 in simulation (camera, EKF, delay-compensated EKF)",
                    configure_table3, run_table3),
            Command("compare", "PLM-Net, the Base Model and the EKF lane keeper without and with delay compensation "
                               "in the closed loop (same track, conditions, latencies, seeds)", configure_compare,
                    run_compare),
            Command("latency", "the perception latency estimated from the stream (no timestamps): accuracy, "
                               "robustness, and PLM-Net and the EKF driven by the estimate", configure_latency,
                    run_latency)]
