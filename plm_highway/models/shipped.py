"""Checkpoints shipped inside the package (``plm_highway/checkpoints``).

Layout, flat because package data is collected by ``checkpoints/*.pt`` and ``checkpoints/*.json``:
``bm_{preset}.pt`` + ``bm_{preset}.json`` and ``tapm_{preset}.pt`` + ``tapm_{preset}.json``,
i.e. the ``model.pt`` / ``model.json`` pairs that ``plm-highway train bm|tapm`` writes, renamed.
"""

from __future__ import annotations

from pathlib import Path

import torch

from plm_highway.models.checkpoints import checkpoint_paths, load_plm_net
from plm_highway.models.plm_net import PLMNet


def shipped_checkpoint_dir() -> Path:
    return Path(__file__).resolve().parent.parent / "checkpoints"


def shipped_checkpoint_paths(preset: str = "default") -> tuple[Path, Path]:
    """(BM, TAPM) weight files for ``preset``; they may not exist."""
    directory = shipped_checkpoint_dir()
    return directory / f"bm_{preset}.pt", directory / f"tapm_{preset}.pt"


def load_shipped_plm_net(preset: str = "default", device: str | torch.device = "cpu") -> PLMNet:
    bm_path, tapm_path = shipped_checkpoint_paths(preset)
    missing = [
        path.name for pair in (bm_path, tapm_path) for path in checkpoint_paths(pair) if not path.is_file()
    ]
    if missing:
        raise FileNotFoundError(
            f"no shipped PLM-Net checkpoints for preset {preset!r} in {shipped_checkpoint_dir()} "
            f"(missing {', '.join(missing)}); train them with 'plm-highway train bm' and "
            f"'plm-highway train tapm', then copy model.pt/model.json there as bm_{preset}.* and tapm_{preset}.*"
        )
    return load_plm_net(bm_path, tapm_path, device)
