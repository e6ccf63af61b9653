"""``plm-highway reproduce``: the paper's tables and figures on our simulator."""

from __future__ import annotations

from plm_highway.cli._common import Command, add_overwrite, add_seed, bounded_float, bounded_int, defaults_of


def configure(parser) -> None:
    from plm_highway.evaluation.reproduce import reproduce

    d = defaults_of(reproduce)
    parser.add_argument("--out", help="output directory (default: figures/reproduce, or figures/reproduce/TRACK "
                                      "for a track other than test)")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--settings", nargs="+", default=list(d["settings"]), metavar="SPEC",
                        help="latency specs, space or comma separated")
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
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(parser)


def run(args) -> int:
    from plm_highway.evaluation.policies import single_threaded_inference
    from plm_highway.evaluation.reproduce import output_dir, reproduce, setting_label

    with single_threaded_inference():
        results = reproduce(args.track, args.settings, args.checkpoints, args.seed, args.max_steps, args.out,
                            args.generalise, args.sweep, args.sweep_max, args.sweep_step, not args.no_progress,
                            args.command_line, overwrite=args.overwrite)
    out = output_dir(args.out, args.track, results["track"])
    for target in results["targets"]:
        print(f"{'met   ' if target['met'] else 'MISSED'} {setting_label(target['setting']):>26}: {target['target']}: "
              f"{target['detail']}")
    print(f"report: {out / 'report.md'}")
    return 0


COMMANDS = [Command("reproduce", "the paper's tables and figures on the test track", configure, run)]
