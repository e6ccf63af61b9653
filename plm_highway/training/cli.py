"""``plm-highway train bm`` and ``plm-highway train tapm``.

Option bounds are :class:`~plm_highway.training.train.TrainConfig`'s (``--epochs`` in [1, 1000],
``--max-samples`` in [2, 10**9], ``--balance-max-per-bin`` 0 (off) or in [1, 10**9], ``--seed``
in [0, 2**63 - 1]), ``--threads`` in [1, the CPUs this process may use] (more only oversubscribes
the cores), and ``--delta-grid`` as :func:`~plm_highway.models.tapm.validate_delta_grid` (1 to 32
latencies in (0, 10] s, increasing). All are checked before the dataset is read.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex

from plm_highway.models.tapm import DEFAULT_DELTA_GRID_S, validate_delta_grid

PRESET_CHOICES = ("default", "paper")


def configure(parser: argparse.ArgumentParser) -> None:
    command = parser.get_default("command")
    parser.add_argument("--data", required=True, help="dataset directory written by 'plm-highway collect'")
    parser.add_argument("--out", required=True, help="output directory for model.pt + model.json")
    if command == "train tapm":
        parser.add_argument("--bm", required=True, help="Base Model checkpoint (directory or .pt/.json file)")
        parser.add_argument(
            "--delta-grid",
            default=",".join(f"{d:g}" for d in DEFAULT_DELTA_GRID_S),
            help="TAPM latencies in seconds, comma separated (default: %(default)s)",
        )
        parser.add_argument(
            "--preset", choices=PRESET_CHOICES, help="optional: check that the BM has this preset"
        )
    else:
        parser.add_argument(
            "--preset", choices=PRESET_CHOICES, default="default", help="model input size preset"
        )
    from plm_highway.training.train import TrainConfig

    parser.add_argument(
        "--epochs", type=int, default=TrainConfig.epochs, help="maximum epochs (early stopping, patience 3)"
    )
    parser.add_argument(
        "--max-samples", type=int, help="use at most N samples (seeded subset), for fast runs"
    )
    parser.add_argument("--seed", type=int, default=TrainConfig.seed)
    parser.add_argument(
        "--balance-max-per-bin",
        type=int,
        default=TrainConfig.balance_max_per_bin,
        help="steering histogram cap per bin (35 bins); 0 disables",
    )
    parser.add_argument("--no-augment", action="store_true", help="disable flip and brightness augmentation")
    parser.add_argument(
        "--threads", type=int, help="torch intra-op threads (default: the CPUs this process may use)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars or per-epoch lines")


def run(args: argparse.Namespace) -> int:
    import torch

    from plm_highway.training.samples import Augmentation
    from plm_highway.training.train import TrainConfig, train_base_model, train_tapm

    threads = check_threads(args.threads)
    if args.balance_max_per_bin is not None and args.balance_max_per_bin < 0:
        raise ValueError(f"--balance-max-per-bin: must be 0 (off) or >= 1, got {args.balance_max_per_bin}")
    config = TrainConfig(
        epochs=args.epochs,
        seed=args.seed,
        max_samples=args.max_samples,
        balance_max_per_bin=args.balance_max_per_bin or None,
        augmentation=None if args.no_augment else Augmentation(),
        show_progress=not args.quiet,
    )
    delta_grid_s = parse_delta_grid(args.delta_grid) if args.command == "train tapm" else None
    torch.set_num_threads(threads)
    command = command_line(args)
    if args.command == "train bm":
        description = train_base_model(args.data, args.out, args.preset, config, command)
    else:
        _check_bm_preset(args.bm, args.preset)
        description = train_tapm(args.data, args.out, args.bm, config, delta_grid_s, command)
    training = description["training"]
    print(
        json.dumps(
            {
                "out": args.out,
                "best_val_loss": training["best_val_loss"],
                "best_epoch": training["best_epoch"],
                "epochs_run": training["epochs_run"],
                "rows_train": training["rows_train"],
                "rows_val": training["rows_val"],
            }
        )
    )
    return 0


def command_line(args: argparse.Namespace) -> str:
    """The command as parsed (with defaults filled in), to record in the checkpoint."""
    words = ["plm-highway", *args.command.split()]
    for name, value in vars(args).items():
        if name == "command" or value is None or value is False:
            continue
        words.append("--" + name.replace("_", "-"))
        if value is not True:
            words.append(str(value))
    return shlex.join(words)


def available_cpus() -> int:
    """CPUs this process may run on (respects affinity / container limits, unlike os.cpu_count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_threads(threads: int | None) -> int:
    """``--threads`` (None: every available CPU) within [1, available CPUs]."""
    from plm_highway.models.config_checks import check_int

    cpus = available_cpus()
    return cpus if threads is None else check_int("--threads", threads, 1, cpus)


def parse_delta_grid(text: str) -> tuple[float, ...]:
    """``--delta-grid`` "0.15,0.2,..." -> latencies in seconds, checked like the TAPM's grid."""
    parts = [part.strip() for part in text.split(",")]
    try:
        grid = [float(part) for part in parts if part]
    except ValueError as exc:
        raise ValueError(f"--delta-grid: expected comma-separated seconds, got {text!r}") from exc
    if not grid:
        raise ValueError(f"--delta-grid: expected at least one latency in seconds, got {text!r}")
    return validate_delta_grid(grid, field="--delta-grid")


def _check_bm_preset(bm_path: str, preset: str | None) -> None:
    if preset is None:
        return
    from plm_highway.models.checkpoints import KIND_BASE_MODEL, read_description

    bm_preset = read_description(bm_path, KIND_BASE_MODEL).get("preset")
    if bm_preset != preset:
        raise ValueError(
            f"--preset {preset} given, but the BM at {bm_path} was trained with preset {bm_preset!r}"
        )

