"""``plm-highway collect``: record expert demonstrations with recovery episodes."""

from __future__ import annotations

import json

from plm_highway.cli._common import Command, add_overwrite, add_seed, bounded_float, bounded_int, defaults_of

MAX_EPISODES = 100_000
MAX_EPISODE_SECONDS = 3_600.0


def configure(parser) -> None:
    from plm_highway.data.collect import collect

    d = defaults_of(collect)
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--out", required=True, help="dataset directory to write (must not exist, or be an "
                                                     "earlier dataset with --overwrite)")
    parser.add_argument("--episodes", type=bounded_int(1, MAX_EPISODES), default=d["episodes"],
                        help="number of episodes")
    parser.add_argument("--episode-seconds", type=bounded_float(0.0, MAX_EPISODE_SECONDS, open_minimum=True),
                        default=d["episode_seconds"], help="length of each episode [s]")
    parser.add_argument("--displaced-fraction", type=bounded_float(0.0, 1.0), default=d["displaced_fraction"],
                        help="share of episodes that start off-centre (recovery demonstrations)")
    parser.add_argument("--max-offset-m", type=bounded_float(0.0, 10.0), default=d["max_offset_m"],
                        help="largest start offset from the lane centre [m]; it must stay on the road")
    parser.add_argument("--max-heading-error-deg", type=bounded_float(0.0, 45.0), default=d["max_heading_error_deg"],
                        help="largest start heading error [deg]")
    parser.add_argument("--speed-mps", type=bounded_float(0.0, 70.0, open_minimum=True), default=d["speed_mps"],
                        help="constant speed [m/s]")
    parser.add_argument("--camera", choices=["default", "paper"], default=d["camera"],
                        help="paper: 160x160 frames like the original PLM-Net input")
    add_seed(parser, d["seed"])
    add_overwrite(parser)


def run(args) -> int:
    from plm_highway.data.collect import collect
    from plm_highway.data.dataset import DATASET, write_dataset
    from plm_highway.io import check_target

    check_target(args.out, DATASET, overwrite=args.overwrite)
    frames, steps, manifest = collect(
        args.track, args.episodes, args.episode_seconds, args.displaced_fraction, args.max_offset_m,
        args.max_heading_error_deg, args.speed_mps, args.camera, args.seed,
    )
    manifest["command"] = args.command_line
    out = write_dataset(args.out, frames, steps, manifest, overwrite=args.overwrite)
    print(json.dumps({"out": str(out), "samples": len(frames), "episodes": int(args.episodes)}))
    return 0


COMMANDS = [Command("collect", "record expert demonstrations with recovery perturbations", configure, run)]
