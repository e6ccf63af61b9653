"""Sweeps: grids of closed-loop runs on a local process pool or a Ray cluster, resumable, one tidy table.

- :mod:`~plm_highway.sweep.grid`: the grid (conditions x latencies x tracks x seeds x policies) and its cells;
- :mod:`~plm_highway.sweep.runner`: :func:`run_sweep` into a resumable output directory;
- where the runs go (in this process, a local process pool, Ray): :mod:`plm_highway.rollout.backends`;
- :mod:`~plm_highway.sweep.table`: the results table and figures.
"""

from plm_highway.sweep.grid import SweepCell, SweepGrid, grid_from_mapping, load_grid
from plm_highway.sweep.runner import run_sweep

__all__ = ["SweepCell", "SweepGrid", "grid_from_mapping", "load_grid", "run_sweep"]
