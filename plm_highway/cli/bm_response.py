"""``plm-highway bm-response``: the BM's steering beside its demonstrator's law at posed starts (a calibration's why)."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_overwrite,
    publish_figure_and_numbers,
    static_defaults,
    static_names,
    static_value,
)


def configure(parser) -> None:
    # Read from the library's source, not imported: the help page imports no simulator (tests/test_cli_help.py).
    DEFAULT_OUT = static_value("plm_highway.evaluation.response", "DEFAULT_OUT")
    SEGMENTS = static_names("plm_highway.road.geometry", "SEGMENTS")
    CONDITION_NAMES = static_names("plm_highway.rollout.conditions", "CONDITION_NAMES")
    d = static_defaults("plm_highway.evaluation.response", "bm_response")
    parser.add_argument("--out", default=str(DEFAULT_OUT),
                        help="figure to write (PNG); its numbers go beside it with the suffix .json")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=d["conditions"],
                        help="whose camera, steering range, demonstrator and shipped BM")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--segment", choices=SEGMENTS, default=d["segment"],
                        help="pose the car in the middle of the track's longest straight, left turn or right turn")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints, of which only the BM is "
                                              "used (default: the conditions' shipped BM)")
    add_overwrite(parser)


def run(args) -> int:
    from plm_highway.evaluation.response import RESPONSE_JSON, bm_response, ratio_lines, write_response

    def respond() -> dict:
        return bm_response(args.track, args.conditions, args.checkpoints, segment=args.segment)

    return publish_figure_and_numbers(args, respond, write_response, ratio_lines, RESPONSE_JSON)


COMMANDS = [Command("bm-response", "the BM's steering beside its demonstrator's tracking law at posed offsets and "
                                 "heading errors, no latency (where the imitation follows, stiffens or saturates)",
                    configure, run)]
