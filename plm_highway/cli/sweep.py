"""``plm-highway sweep``: a grid of closed-loop runs on a process pool or Ray, resumable, one tidy table."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_device,
    add_overwrite,
    bounded_int,
    static_defaults,
    static_fields,
    static_names,
    static_value,
)


def configure(parser) -> None:
    import argparse
    from types import SimpleNamespace

    from plm_highway.rollout.backends import BACKENDS, MAX_WORKERS, default_workers

    # Read from the library's source, not imported: the help page imports no simulator (tests/test_cli_help.py).
    POLICY_NAMES = static_names("plm_highway.rollout.policies", "POLICY_NAMES")
    MAX_STEPS = static_value("plm_highway.sweep.grid", "MAX_STEPS")
    grid = SimpleNamespace(**static_fields("plm_highway.sweep.grid", "SweepGrid"))
    d = static_defaults("plm_highway.sweep.runner", "run_sweep")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="sweep directory: cells/, results.csv, figures/; run again to resume")
    parser.add_argument("--grid", metavar="FILE", help="grid from a YAML or JSON file (conditions, latencies, tracks, "
                                                       "seeds, policies, max_steps); options below override it")
    parser.add_argument("--latency", default=argparse.SUPPRESS, nargs="+", metavar="SPEC",
                        help=f"latency profiles, e.g. const:0.2 steps:0.0-0.35:1.0 (default {' '.join(grid.latencies)})")
    parser.add_argument("--track", default=argparse.SUPPRESS, nargs="+", metavar="TRACK",
                        help=f"train, test, unseen or track JSON paths (default {' '.join(grid.tracks)})")
    parser.add_argument("--seeds", default=argparse.SUPPRESS, metavar="N|LIST", help="a count (5: seeds 0-4) or a list (0,3,7) (default 1)")
    parser.add_argument("--policy", default=argparse.SUPPRESS, nargs="+", choices=POLICY_NAMES,
                        help=f"policies (default {' '.join(grid.policies)}); references are added for the errors")
    parser.add_argument("--max-steps", default=argparse.SUPPRESS, type=bounded_int(1, MAX_STEPS),
                        help="stop each run after this many policy steps (default: the whole track)")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: shipped)")
    parser.add_argument("--backend", choices=BACKENDS, default=d["backend"],
                        help="local: a process pool on this machine; ray: a Ray cluster (pip install ray)")
    parser.add_argument("--workers", type=bounded_int(0, MAX_WORKERS), default=default_workers(),
                        help="processes (local) or CPUs of the private local Ray; 0: run in this process")
    parser.add_argument("--address", help="with --backend ray: a running cluster (HOST:PORT or auto); "
                                          "default: start a private local Ray")
    parser.add_argument("--batch-size", type=bounded_int(1, 4096), default=d["batch_size"],
                        help="envs stepped together per worker (one batched forward pass per step)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--prune", action="store_true",
                        help="remove from OUT/cells the results of other grids or inputs (kept by default: a grid or "
                             "input that comes back reuses them; they never enter this grid's table)")
    add_overwrite(parser)
    add_device(parser)


def run(args) -> int:
    from plm_highway.sweep.grid import grid_from_mapping, load_grid
    from plm_highway.sweep.runner import run_sweep

    data = load_grid(args.grid).as_dict() if args.grid else {}
    options = {"latencies": "latency", "tracks": "track", "seeds": "seeds", "policies": "policy", "max_steps": "max_steps"}
    data.update({key: getattr(args, option) for key, option in options.items() if hasattr(args, option)})
    grid = grid_from_mapping(data, "sweep options")
    summary = run_sweep(grid, args.out, workers=args.workers, backend=args.backend, address=args.address,
                        batch_size=args.batch_size, checkpoints=args.checkpoints, overwrite=args.overwrite,
                        progress=not args.no_progress, device=args.device, prune=args.prune)
    print(f"{summary['cells']} runs ({summary['ran']} run now, {summary['resumed']} kept from earlier)")
    if summary["pruned"]:
        print(f"removed {summary['pruned']} cell result(s) of other grids or inputs from {args.out}/cells")
    elif summary["other_cells"]:
        print(f"{summary['other_cells']} cell result(s) of other grids or inputs stay in {args.out}/cells, unused "
              "(--prune removes them)")
    print(f"wrote {summary['table']}")
    for path in summary["figures"]:
        print(f"wrote {path}")
    return 0


COMMANDS = [Command("sweep", "a grid of closed-loop runs (conditions x latencies x tracks x seeds x policies) on a "
                    "process pool or Ray; resumable; one results table and figures", configure, run)]
