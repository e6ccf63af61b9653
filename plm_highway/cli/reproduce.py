"""``plm-highway reproduce``: the paper's tables and figures on our simulator."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_device,
    add_overwrite,
    add_seed,
    bounded_float,
    bounded_int,
    device_of,
    static_fields,
    static_names,
)


def configure(parser) -> None:
    # Read from the library's source, not imported: the help page imports no torch (tests/test_cli_help.py).
    d = static_fields("plm_highway.evaluation.reproduce", "ReproduceOptions")
    CONDITION_NAMES, INJECTION_LATENCY_SOURCE, LATENCY_SOURCE_NAMES = (
        static_names("plm_highway.rollout.conditions", name)
        for name in ("CONDITION_NAMES", "INJECTION_LATENCY_SOURCE", "LATENCY_SOURCE_NAMES"))
    parser.add_argument("--out", help="output directory (default: figures/reproduce, figures/reproduce/TRACK for a "
                                      "track other than test, figures/reproduce-paper-conditions[/TRACK] under "
                                      "--conditions paper)")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=d["conditions"],
                        help="ideal: this project's setup; paper: the paper's loop rate, latency profiles and the "
                             "original's FIFO injection (see the report's Conditions section)")
    parser.add_argument("--injection", choices=tuple(INJECTION_LATENCY_SOURCE),
                        help="latency injection instead of the conditions' own (ideal: time, paper: legacy-fifo): "
                             "time delivers frames of their exact age and tells PLM-Net that age; legacy-fifo is the "
                             "original's FIFO (fresher frames while it refills, PLM-Net told the requested latency, "
                             "the BM baseline of a time-varying setting at a constant latency). The report compares "
                             "the time-varying settings under both")
    parser.add_argument("--latency-source", choices=LATENCY_SOURCE_NAMES,
                        help="what PLM-Net is told instead of the conditions' own (ideal: measured, paper: requested): "
                             "measured, requested, or estimated from the stream without capture timestamps (every "
                             "run then logs the estimate beside the true age)")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--settings", nargs="+", metavar="SPEC",
                        help="latency specs, space or comma separated (default: 0.15, 0.2, 0.25, 0.3 s and the "
                             "conditions' time-varying profiles)")
    parser.add_argument("--seeds", default=str(d["seeds"]),
                        help="seeds per setting: a count N (seeds --seed .. --seed+N-1) or a list a,b,c")
    parser.add_argument("--generalise", nargs="*", metavar="TRACK",
                        help="tracks for the generalisation section (default: unseen when --track is test; "
                             "give the flag alone for none)")
    parser.add_argument("--sweep", action="store_true",
                        help="also the latency sweep 0-0.5 s and PLM-Net with a wrong latency estimate")
    parser.add_argument("--sweep-max", type=bounded_float(0.0, 1.0), default=d["sweep_max"], help="last sweep latency [s]")
    parser.add_argument("--sweep-step", type=bounded_float(0.001, 1.0), default=d["sweep_step"],
                        help="sweep latency step [s]")
    add_seed(parser, d["seed"])
    parser.add_argument("--max-steps", type=bounded_int(1, 10_000_000),
                        help="stop each run after this many policy steps (quick looks)")
    parser.add_argument("--workers", type=bounded_int(0, 256),
                        help="local processes driving the runs, each batched (default: one per CPU; 0: batched in "
                             "this process); the results do not depend on it")
    parser.add_argument("--batch-size", type=bounded_int(1, 4096), default=d["batch_size"],
                        help="envs stepped together, one forward pass per model and step")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(parser)
    add_device(parser)


def run(args) -> int:
    from plm_highway.evaluation.protocol import setting_label
    from plm_highway.evaluation.reproduce import ReproduceOptions, output_dir, reproduce
    from plm_highway.rollout.policies import single_threaded_inference

    options = ReproduceOptions(
        track=args.track, settings=None if args.settings is None else tuple(args.settings),
        checkpoints=args.checkpoints, seed=args.seed, seeds=args.seeds, conditions=args.conditions,
        injection=args.injection, latency_source=args.latency_source, max_steps=args.max_steps,
        generalise=None if args.generalise is None else tuple(args.generalise), sweep=args.sweep,
        sweep_max=args.sweep_max, sweep_step=args.sweep_step, workers=args.workers, batch_size=args.batch_size,
        out=args.out, overwrite=args.overwrite, progress=not args.no_progress, command=args.command_line,
        device=device_of(args))
    with single_threaded_inference():
        results = reproduce(options)
    out = output_dir(args.out, args.track, results["track"], args.conditions)
    for target in results["targets"]:
        print(f"{'met   ' if target['met'] else 'MISSED'} {setting_label(target['setting']):>26}: {target['target']}: "
              f"{target['detail']}")
    print(f"report: {out / 'report.md'}")
    return 0


COMMANDS = [Command("reproduce", "the paper's tables and figures on the test track, over seeds, with CIs", configure,
                    run)]
