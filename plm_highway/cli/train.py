"""``plm-highway train bm`` and ``plm-highway train tapm``.

Option bounds are :class:`~plm_highway.training.train.TrainConfig`'s (``--epochs`` in [1, 1000],
``--max-samples`` in [2, 10**9], ``--balance-max-per-bin`` 0 (off) or in [1, 10**9], ``--seed``
in [0, 2**63 - 1]), ``--threads`` in [1, the CPUs this process may use] (more only oversubscribes
the cores; default 2 whatever the CPU affinity, so that one command trains the same bytes everywhere), and
``--delta-grid`` as :func:`~plm_highway.models.tapm.validate_delta_grid` (1 to 32 latencies in (0, 10] s,
increasing). All are checked before the dataset is read, ``--device cuda`` where torch has no CUDA too (exit 2).
"""

from __future__ import annotations

import argparse
import json
import os

from plm_highway.cli._common import Command, add_device, add_overwrite, device_of, static_fields, static_value
from plm_highway.errors import BadInput

PRESET_CHOICES = ("default", "paper")
GROUP_HELP = "train the Base Model or the Timed Action Prediction Model"


def _common_options(parser: argparse.ArgumentParser) -> None:
    from types import SimpleNamespace


    # TrainConfig's defaults read from the library's source: the help page imports no torch.
    defaults = SimpleNamespace(**static_fields("plm_highway.training.train", "TrainConfig"))
    parser.add_argument("--data", required=True, help="dataset directory written by 'plm-highway collect'")
    parser.add_argument("--out", required=True, help="checkpoint directory to write (model.pt + model.json)")
    parser.add_argument("--epochs", type=int, default=defaults.epochs,
                        help="maximum epochs (early stopping, patience 3)")
    parser.add_argument("--max-samples", type=int, help="use at most N samples (seeded subset), for fast runs")
    parser.add_argument("--seed", type=int, default=defaults.seed, help="random seed (0 to 2**63-1)")
    parser.add_argument("--balance-max-per-bin", type=int,
                        default=defaults.balance_max_per_bin, help="steering histogram cap per bin (35 bins); 0 disables")
    parser.add_argument("--no-augment", action="store_true", help="disable flip and brightness augmentation")
    parser.add_argument("--label-lead-s", type=float, default=defaults.label_lead_s,
                        help="label alignment: label the frame at t with the steering recorded at t + this lead "
                             "[s] of the same episode (0 to 2; 0 pairs each frame with its own steering, as the "
                             "original did)")
    parser.add_argument("--threads", type=int,
                        help="torch intra-op threads (default 2 whatever the CPUs: the thread count changes the "
                             "weights' last bits, so one command gives one result; recorded in model.json)")
    parser.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                        help="no progress bars or per-epoch lines (--no-progress, as the other commands spell it)")
    add_device(parser)
    add_overwrite(parser)


def configure_bm(parser: argparse.ArgumentParser) -> None:
    _common_options(parser)
    parser.add_argument("--preset", choices=PRESET_CHOICES, default="default", help="model input size preset")


def configure_tapm(parser: argparse.ArgumentParser) -> None:
    DEFAULT_DELTA_GRID_S = static_value("plm_highway.models.tapm", "DEFAULT_DELTA_GRID_S")
    _common_options(parser)
    parser.add_argument("--bm", required=True, help="Base Model checkpoint (directory or .pt/.json file)")
    parser.add_argument("--delta-grid", default=",".join(f"{d:g}" for d in DEFAULT_DELTA_GRID_S),
                        help="TAPM latencies in seconds, comma separated")
    parser.add_argument("--preset", choices=PRESET_CHOICES, help="optional: check that the BM has this preset")


def _config(args):
    from plm_highway.training.samples import Augmentation
    from plm_highway.training.train import TrainConfig

    if args.balance_max_per_bin is not None and args.balance_max_per_bin < 0:
        raise BadInput(f"--balance-max-per-bin: must be 0 (off) or >= 1, got {args.balance_max_per_bin}")
    return TrainConfig(epochs=args.epochs, seed=args.seed, max_samples=args.max_samples,
                       balance_max_per_bin=args.balance_max_per_bin or None,
                       augmentation=None if args.no_augment else Augmentation(), show_progress=not args.quiet,
                       label_lead_s=args.label_lead_s)


def _set_threads(args) -> None:
    import torch

    from plm_highway.models.config_checks import check_int
    from plm_highway.training.train import DEFAULT_THREADS

    # A fixed default, not the CPUs this process may use: the thread count splits torch's reductions, so
    # the same command must use the same count on every machine and under every CPU affinity.
    cpus = available_cpus()
    threads = DEFAULT_THREADS if args.threads is None else check_int("--threads", args.threads, 1,
                                                                       max(cpus, DEFAULT_THREADS))
    torch.set_num_threads(threads)


def run_bm(args) -> int:
    from plm_highway.training.train import train_base_model

    config, device = _config(args), device_of(args)
    _set_threads(args)
    description = train_base_model(args.data, args.out, args.preset, config, args.command_line,
                                   overwrite=args.overwrite, device=device)
    return _report(args, description)


def run_tapm(args) -> int:
    from plm_highway.training.train import check_bm_preset, parse_delta_grid, train_tapm

    config, delta_grid_s, device = _config(args), parse_delta_grid(args.delta_grid), device_of(args)
    _set_threads(args)
    check_bm_preset(args.bm, args.preset)
    description = train_tapm(args.data, args.out, args.bm, config, delta_grid_s,
                             args.command_line, overwrite=args.overwrite, device=device)
    return _report(args, description)


def _report(args, description: dict) -> int:
    training = description["training"]
    print(json.dumps({"out": args.out, **{key: training[key] for key in (
        "best_val_loss", "best_epoch", "epochs_run", "rows_train", "rows_val")}}))
    return 0


def available_cpus() -> int:
    """CPUs this process may run on (respects affinity / container limits, unlike os.cpu_count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


COMMANDS = [
    Command("bm", "train the Base Model", configure_bm, run_bm),
    Command("tapm", "train the Timed Action Prediction Model on a frozen Base Model", configure_tapm, run_tapm),
]
