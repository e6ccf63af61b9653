"""Figures like the paper's Figures 7-10: truth, camera, and both estimators over time, per scenario."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from plm_highway.io import pyplot, save_figure_into
from plm_highway.lane_ekf.table3 import ScenarioRun


def plot_scenario_run(run: ScenarioRun, path: str | Path, measurement: str = "clean") -> Path:
    """d, dpsi and v_n over time for one run, saved at ``path`` (a place staged by :mod:`plm_highway.io`)."""
    plt = pyplot()

    truth = run.truth
    t = truth.time_s
    truth_columns = (truth.d_m, np.degrees(truth.dpsi_rad), truth.vn_mps)
    scales = (1.0, 180.0 / math.pi, 1.0)
    labels = ("d [m]", "Δψ [deg]", "v_n [m/s]")
    arrived = run.camera_arrived
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(t, truth_columns[i], color="black", lw=2.0, label="ground truth")
        ax.plot(t[arrived], run.estimates["camera_held"][arrived, i] * scales[i], "o", color="tab:green", ms=4,
                label="camera only (at arrival)")
        ax.plot(t, run.estimates["ekf"][:, i] * scales[i], color="tab:blue", lw=1.2, label="EKF, no delay compensation")
        ax.plot(t, run.estimates["ekf_dc"][:, i] * scales[i], color="tab:red", lw=1.2, label="EKF, delay compensated")
        ax.axvspan(t[0], run.scenario.lead_in_s, color="0.9", lw=0)
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[-1].set_xlabel("time [s] (grey: lead-in, not scored)")
    fig.suptitle(f"Scenario {run.scenario.number}: {run.scenario.description} (seed {run.seed}, "
                 f"{measurement} lane measurement)")
    fig.tight_layout()
    path = Path(path)
    save_figure_into(fig, path, dpi=110)
    plt.close(fig)
    return path
