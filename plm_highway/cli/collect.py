"""``plm-highway collect``: record expert demonstrations with recovery episodes."""

from __future__ import annotations

import json

from plm_highway.cli._common import Command, add_overwrite, static_fields, static_names

FIELD_HELP = {
    "episodes": "number of episodes (1 to 100,000)",
    "episode_seconds": "length of each episode [s], up to 3,600",
    "displaced_fraction": "share of episodes that start off-centre (recovery demonstrations), in [0, 1]",
    "max_offset_m": "largest start offset from the lane centre [m]; the car must start on the road",
    "max_heading_error_deg": "largest start heading error [deg], up to 45",
    "speed_mps": "constant speed [m/s], up to 70",
    "seed": "random seed (0 to 2**63-1)",
}


def configure(parser) -> None:
    from types import SimpleNamespace


    # Read from the library's source, not imported: the help page imports no simulator.
    defaults = SimpleNamespace(**static_fields("plm_highway.data.collect", "CollectConfig"))
    CAMERAS, DEMONSTRATORS = (static_names("plm_highway.data.collect", name) for name in ("CAMERAS", "DEMONSTRATORS"))
    CONDITION_NAMES = static_names("plm_highway.rollout.conditions", "CONDITION_NAMES")
    parser.add_argument("--track", default="train", help="train, test, unseen or a track JSON path")
    parser.add_argument("--out", required=True, help="dataset directory to write (must not exist, or be an "
                                                     "earlier dataset with --overwrite)")
    for name, help_text in FIELD_HELP.items():
        default = getattr(defaults, name)
        parser.add_argument(f"--{name.replace('_', '-')}", type=type(default), default=default, help=help_text)
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=defaults.conditions,
                        help="loop rate, steering actuator, camera and demonstrator of these conditions (ideal: 20 Hz, "
                             "default camera, expert; paper: 30 Hz, 0.1 s actuator, original camera, human-like driver)")
    parser.add_argument("--camera", choices=CAMERAS, default=defaults.camera,
                        help="override the conditions' camera; paper: the original's road strip resized to 160x160")
    parser.add_argument("--demonstrator", choices=DEMONSTRATORS, default=defaults.demonstrator,
                        help="override the conditions' driver: expert (noise-free lane-centre tracker) or human "
                             "(reaction delay, slow hand, lane wander, motor noise)")
    add_overwrite(parser)


def run(args) -> int:
    from plm_highway.data.collect import CollectConfig, collect
    from plm_highway.data.dataset import DATASET, write_dataset
    from plm_highway.io import check_target

    config = CollectConfig(camera=args.camera, conditions=args.conditions, demonstrator=args.demonstrator,
                           **{name: getattr(args, name) for name in FIELD_HELP})
    check_target(args.out, DATASET, overwrite=args.overwrite)
    frames, steps, manifest = collect(args.track, config=config)
    manifest["command"] = args.command_line
    out = write_dataset(args.out, frames, steps, manifest, overwrite=args.overwrite)
    print(json.dumps({"out": str(out), "samples": len(frames), "episodes": config.episodes}))
    return 0


COMMANDS = [Command("collect", "record expert demonstrations with recovery perturbations", configure, run)]
