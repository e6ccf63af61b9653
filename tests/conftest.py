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


# The modules that take longest first: with --dist loadscope each module goes to one worker whole, and a long module
# handed out last leaves the other worker idle at the end. Order within a module is kept.
LONG_MODULES = ("test_population.py", "test_lessons_nbgrader.py", "test_faults.py", "test_lessons_browser.py",
                "test_determinism_reports.py", ".ipynb", "test_sim2real_diagnose.py", "test_sim2real_library.py",
                "test_reproduce.py", "test_lessons_mutants.py", "test_latency_estimation.py")


def _module_rank(item) -> int:
    name = item.path.name
    return next((rank for rank, suffix in enumerate(LONG_MODULES) if name.endswith(suffix)), len(LONG_MODULES))


def pytest_collection_modifyitems(config, items):
    items.sort(key=_module_rank)  # stable: every other order is kept
