"""The camera's perception delay beside a sim2real diagnosis's delays, for the latency-estimation report.

On the real recording (when one is given): the diagnosis and, where the recording carries a camera lane signal,
the perception delay (:mod:`plm_highway.sim2real.perception_delay`). On a simulated recording with a lane signal:
a run under the paper pipeline (a 0.1 s steering actuator behind two loop steps of processing) with PLM-Net told
the latency, so the vehicle side has delays of its own beside the camera's, and the truth of both is known.
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from plm_highway.lane_ekf.latency_stream import LatencyEstimation
from plm_highway.latency.lane_recording import write_lane_recording
from plm_highway.road.track import load_track
from plm_highway.rollout.cells import Cell, drive_options
from plm_highway.rollout.closed_loop import drive
from plm_highway.rollout.conditions import CONDITIONS, scored_steps
from plm_highway.rollout.policies import make_policy
from plm_highway.sim2real.diagnose import diagnose
from plm_highway.sim2real.perception_delay import diagnosis_delays, perception_delay
from plm_highway.sim2real.record.recording import read_recording

SIMULATED_CONDITIONS = "paper"
SIMULATED_TRACK = "test"
SIMULATED_LATENCY = "const:0.2"
SIMULATED_SEED = 0
SIMULATED_DURATION_S = 30.0


def diagnosed(path: Path, name: str) -> dict:
    """A recording's diagnosis verdict, its fitted delays and the perception delay the estimator finds."""
    recording = read_recording(path)
    result = diagnose(recording)
    return {"recording": name, "verdict": result.verdict, "diagnosis_delays_s": diagnosis_delays(result),
            "perception_delay": perception_delay(path, vehicle_params=recording.vehicle.kinematic)}


def simulated_recording(path: Path, checkpoints=None) -> dict:
    """Drive the simulated run and write its stream into ``path`` (``steer`` is the command, as a recording's
    is); the true camera latency and vehicle-side delays."""
    conditions = CONDITIONS[SIMULATED_CONDITIONS]
    estimating = replace(conditions, latency_estimation=LatencyEstimation(record=True))
    track_spec = load_track(SIMULATED_TRACK)
    steps = scored_steps(track_spec, estimating, round(SIMULATED_DURATION_S * conditions.policy_frequency_hz))
    options = drive_options(Cell("true", "", SIMULATED_LATENCY, SIMULATED_SEED), estimating, steps)
    policy = make_policy("plm", checkpoints, latency_source=conditions.latency_source,
                         preset=conditions.checkpoint_preset)
    log = drive("true", policy, track_spec, SIMULATED_LATENCY, SIMULATED_SEED, **options)
    write_lane_recording(path, log, steer_rad=np.asarray(log.columns["steering"], float) * conditions.max_steering_rad)
    frame_age_s = np.asarray(log.columns["observation_age_s"], float)
    return {"true_camera_latency_s": float(np.median(frame_age_s[len(frame_age_s) // 2:])),
            "true_vehicle_delays": {
                "processing_delay_s": conditions.processing_delay_steps / conditions.policy_frequency_hz,
                "steering_time_constant_s": conditions.steering_time_constant_s}}


def tie_in(real_recording=None, checkpoints=None) -> dict:
    """``{"real": ..., "simulated": ...}``: each recording's diagnosis beside its perception delay ("real" only
    when ``real_recording`` is given)."""
    out = {}
    if real_recording is not None:
        out["real"] = diagnosed(Path(real_recording), Path(real_recording).name)
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "simulated.csv"
        truth = simulated_recording(path, checkpoints)
        out["simulated"] = {**diagnosed(path, f"a {SIMULATED_CONDITIONS}-conditions run (PLM-Net at "
                                              f"{SIMULATED_LATENCY}; steer = the command)"), **truth}
    return out
