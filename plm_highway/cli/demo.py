"""``plm-highway demo zigzag``: the paper's Figure 2."""

from __future__ import annotations

from plm_highway.cli._common import Command, add_overwrite, add_seed, static_defaults

GROUP_HELP = "quick demonstrations"


def configure_zigzag(parser) -> None:
    # Read from the library's source, not imported: the help page stays fast (tests/test_cli_help.py).
    d = static_defaults("plm_highway.evaluation.demo", "zigzag")
    parser.add_argument("--latency", default=d["latency"], help="a profile spec, or seconds (e.g. 0.25)")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--policy", choices=["auto", "bm", "expert"], default=d["policy"],
                        help="auto: the shipped Base Model if present, else the expert")
    add_seed(parser, d["seed"])
    parser.add_argument("--out", default=d["out"], help="figure to write (PNG)")
    add_overwrite(parser)


def run_zigzag(args) -> int:
    from plm_highway.evaluation.demo import zigzag

    result = zigzag(args.latency, args.track, args.policy, args.seed, args.out, overwrite=args.overwrite)
    print(f"policy: {result['policy']}")
    for name, summary in result.items():
        if isinstance(summary, dict):
            print(f"{name:>24}: lateral offset max {summary['lateral_offset_max_m']:.3f} m, "
                  f"RMS {summary['lateral_offset_rms_m']:.3f} m, left road: {summary['left_road']}")
    print(f"figure: {result['figure']}")
    return 0


COMMANDS = [Command("zigzag", "Figure 2: the lane keeper with and without latency", configure_zigzag, run_zigzag)]
