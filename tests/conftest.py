"""Shared test set-up: headless plotting and rendering before anything imports them.

``PLM_FAST=1`` puts the notebooks in their CI mode (short loops, shipped checkpoints). It is set here,
at collection, so the kernels nbval starts for solutions/ inherit it: run ``python -m pytest`` from the
repository root (pytest collects tests/ and solutions/ together).
"""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("PLM_FAST", "1")

from pathlib import Path

import pytest
from hypothesis import settings

# Property tests explore new examples on developers' machines; CI (CI=true) replays a fixed sequence so a
# landing never depends on the luck of the draw.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

REPO_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT
