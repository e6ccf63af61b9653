"""The figure each lesson aims for, drawn with the kit's reference implementations.

The lessons' outputs are stripped, so each lesson shows its target figure as a stored image:
``figures/lessons/<lesson>.png``, embedded in the notebooks by ``plm-highway lessons build``. Regenerate
with ``plm-highway lessons figures --overwrite`` (a few minutes: Lesson 3 drives the whole test track
three times). Lesson 4's figure is made from another car with another concealed effect than the
lesson's, so that it shows what the plots look like without giving the answer away.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from plm_highway.data.collect import collect
from plm_highway.expert import ExpertPolicy
from plm_highway.grading.lesson3 import kit_table_3_runs
from plm_highway.io import save_figure
from plm_highway.lane_ekf.table3 import SCENARIOS, run_scenario
from plm_highway.models.plm_net import interpolate_actions
from plm_highway.models.tapm import DEFAULT_DELTA_GRID_S
from plm_highway.rollout.closed_loop import drive
from plm_highway.sim2real.physics.replay import noise_sigma
from plm_highway.sim2real.physics.synth import make_recording
from plm_highway.training.labels import future_steering_labels
from plm_highway.vehicle.kinematic import KinematicBicycleParams, kinematic_bicycle_rates

DPI = 80


def _save(fig, path: Path, overwrite: bool) -> Path:
    return save_figure(fig, path, overwrite=overwrite, dpi=DPI)


def lesson1_figure(plt):
    """Figure 2: the expert's lateral offset with fresh and with 0.25 s old snapshots."""
    fig, ax = plt.subplots(figsize=(10, 3.2))
    for latency_s, colour in ((0.0, "tab:green"), (0.25, "tab:red")):
        log = drive("figure", ExpertPolicy(), "test", f"const:{latency_s}", 0, max_steps=68 * 20)
        offsets_m = log.columns["lateral_offset_m"]
        rms_m = np.sqrt(np.mean(offsets_m ** 2))
        ax.plot(log.columns["t_s"], offsets_m, color=colour, label=f"latency {latency_s} s (RMS {rms_m:.2f} m)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("lateral offset [m] (left +)")
    ax.set_title("Lesson 1 target: the expert fed 0.25 s old snapshots weaves (the paper's Figure 2)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    return fig


def lesson2_figure(plt):
    """Future labels of one episode (Exercise A) and Algorithm 1 on one row of actions (Exercise C)."""
    _, steps, _ = collect(track="train", episodes=4, episode_seconds=6.0, seed=0, progress=False)
    labels, valid = future_steering_labels(steps["episode_id"], steps["t_s"], steps["steering"], DEFAULT_DELTA_GRID_S)
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.2), gridspec_kw={"width_ratios": [1.5, 1]})
    rows = steps["episode_id"] == 0
    axes[0].plot(steps["t_s"][rows], steps["steering"][rows], "k", lw=2, label="steering at t")
    for j in (0, 2, 4):
        axes[0].plot(steps["t_s"][rows & valid], labels[rows & valid, j],
                     label=f"label for delta = {DEFAULT_DELTA_GRID_S[j]} s")
    axes[0].set_xlabel("time t of the frame [s]")
    axes[0].set_ylabel("steering")
    axes[0].set_title("future labels: the steering curve shifted left")
    axes[0].legend(fontsize=8)
    delta_ref_s = np.array([0.0, *DEFAULT_DELTA_GRID_S])
    a_row = np.array([0.10, 0.40, 0.30, -0.20, 0.00, 0.50])
    latencies_s = np.linspace(0, 0.5, 201)
    axes[1].plot(latencies_s, interpolate_actions(latencies_s, delta_ref_s, np.tile(a_row, (len(latencies_s), 1))),
                 label="a_PLM")
    axes[1].plot(delta_ref_s, a_row, "o", label="a_ref (BM, then the heads)")
    axes[1].set_xlabel("measured latency [s]")
    axes[1].set_ylabel("steering")
    axes[1].set_title("Algorithm 1: a broken line, flat beyond the last head")
    axes[1].legend(fontsize=8)
    fig.suptitle("Lesson 2 targets")
    fig.tight_layout()
    return fig


def lesson3_figure(plt):
    """Figure 9: the steering of the three Table 3 runs (shipped checkpoints, whole test track)."""
    logs = kit_table_3_runs(None, None)
    fig, ax = plt.subplots(figsize=(10, 3.2))
    for run, colour, label in (("reference", "tab:blue", "BM, no latency"), ("baseline", "tab:green", "BM, 0.2 s"),
                               ("mitigated", "tab:red", "PLM-Net, 0.2 s")):
        ax.plot(logs[run].columns["t_s"], logs[run].columns["steering"], color=colour, lw=1, label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("steering (+ = left)")
    ax.set_title("Lesson 3 target: the paper's Figure 9, reproduced")
    ax.legend(loc="upper right")
    fig.tight_layout()
    return fig


def lesson4_figure(plt):
    """Section 1's plot for another car (a steering gain, not one of the lesson's concealed effects)."""
    recording, _ = make_recording({"steering_gain": 0.85}, rng=np.random.default_rng(7), duration_s=60.0,
                                  model="kinematic")
    geometry = KinematicBicycleParams(recording.vehicle.cg_to_front_m, recording.vehicle.cg_to_rear_m)
    replayed = kinematic_bicycle_rates(recording.steer_rad, recording.speed_mps, geometry)[0]
    residual = recording.yaw_rate_radps - replayed
    sigma = noise_sigma(residual, np.ones(recording.n, bool))
    t_s = recording.t_s
    excerpt = (t_s > 20) & (t_s < 50)
    fig, axes = plt.subplots(2, 1, figsize=(10, 4.2), sharex=True)
    axes[0].plot(t_s[excerpt], recording.yaw_rate_radps[excerpt], color="0.3", lw=1, label="recorded")
    axes[0].plot(t_s[excerpt], replayed[excerpt], color="tab:red", lw=1.2, label="simulator replay")
    axes[0].set_ylabel("yaw rate [rad/s]")
    axes[0].legend(loc="upper right")
    axes[0].set_title("Lesson 4: what Section 1's plot looks like (another car, another concealed effect)")
    axes[1].plot(t_s[excerpt], residual[excerpt], color="tab:red", lw=1)
    axes[1].axhspan(-2 * sigma, 2 * sigma, color="0.85", label="+-2 x noise")
    axes[1].set_ylabel("recorded - replay [rad/s]")
    axes[1].set_xlabel("time [s]")
    axes[1].legend(loc="upper right")
    fig.tight_layout()
    return fig


def lesson5_figure(plt):
    """Section 4's plot for scenario 1 on another seed: the kit's EKF with and without delay compensation."""
    run = run_scenario(SCENARIOS[0], 0)
    t_s = run.truth.time_s
    fig, ax = plt.subplots(figsize=(10, 3.6))
    ax.plot(t_s, run.truth.d_m, color="black", lw=2, label="ground truth")
    ax.plot(t_s, run.estimates["ekf"][:, 0], color="tab:blue", lw=1.2, label="EKF, camera fused on arrival")
    ax.plot(t_s, run.estimates["ekf_dc"][:, 0], color="tab:red", lw=1.2, label="EKF, delay compensated")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("lateral offset d [m]")
    ax.set_title("Lesson 5 target: scenario 1 (sine weave, 60 km/h, camera 0.25-0.35 s late)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    return fig


LESSON_FIGURES: dict[str, Callable] = {
    "01_latency_zigzag.png": lesson1_figure,
    "02_teaching_a_car_to_look_ahead.png": lesson2_figure,
    "03_measuring_mitigation.png": lesson3_figure,
    "04_when_the_simulator_lies.png": lesson4_figure,
    "05_predicting_through_the_delay.png": lesson5_figure,
}


def write_lesson_figures(out_dir: Path, overwrite: bool = False, names: list[str] | None = None) -> list[Path]:
    """Draw the lessons' target figures into ``out_dir``; returns the paths written."""
    import matplotlib  # lazy: matplotlib only when the figures are drawn, on Agg

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    unknown = sorted(set(names or []) - set(LESSON_FIGURES))
    if unknown:
        raise ValueError(f"unknown lesson figure(s) {unknown}; known: {sorted(LESSON_FIGURES)}")
    written = []
    for name, draw in LESSON_FIGURES.items():
        if names and name not in names:
            continue
        fig = draw(plt)
        try:
            written.append(_save(fig, Path(out_dir) / name, overwrite))
        finally:
            plt.close(fig)
    return written
