"""PLM-Net in open loop, along the reference run: how well its heads predict the BM's own future action.

A closed-loop reduction mixes two things: how well the TAPM predicts the action the BM would take
``delta`` later, and how the mitigated car's own trajectory then differs from the delayed BM's (the
delayed BM weaves; PLM-Net's anticipation damps or feeds that weave). Along the reference run, the BM
driving the same seed without latency, only the first remains: at step t, the delayed BM would act on
the frame of step t - n (the frame the latency wrapper serves: n = ceil(delta x the policy rate)) and send
the action that frame gave, while PLM-Net would send its prediction from that same frame, told the
latency the conditions tell it (delta requested, or the frame's age n / rate). Both are compared with the
action the BM took at t. No second run is driven, so neither side's errors feed back.

The two errors, over every step t >= n of the reference run:

    holding  = mean |a[t - n] - a[t]|          the delayed BM, had it stayed on the reference trajectory
    PLM-Net  = mean |p_delta[t - n] - a[t]|    p_delta[k]: PLM-Net's action from frame k

A TAPM that beats holding here predicts the BM's future; one that does not can still reduce the
closed-loop error, by damping the weave the delayed BM drives itself into, but then its gain is not
prediction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from plm_highway.evaluation import protocol
from plm_highway.latency.wrapper import served_steps
from plm_highway.metrics.intervals import mean_ci
from plm_highway.metrics.steering import reduction_pct
from plm_highway.road.track import TrackSpec
from plm_highway.rollout.cells import Cell, drive_options
from plm_highway.rollout.closed_loop import drive
from plm_highway.rollout.conditions import Conditions, scored_steps

PREDICTION_BATCH = 128  # frames per forward pass: the paper BM's activations for 128 160x160 frames are ~80 MB


@dataclass(frozen=True)
class ReferenceRecording:
    """The frames the BM saw in its reference run, with the speed it was told and the action it took."""

    frames: np.ndarray  # (T, H, W) uint8, as the policy got them (image noise included)
    speeds_mps: np.ndarray  # (T,)
    steering: np.ndarray  # (T,) normalised, the BM's action at each step


class _Recorder:
    """A policy that passes every call on and keeps the frame and speed it was given."""

    def __init__(self, policy):
        self.policy = policy
        self.frames: list[np.ndarray] = []
        self.speeds_mps: list[float] = []

    def reset(self) -> None:
        self.policy.reset()

    def __call__(self, frame: np.ndarray, info: dict) -> float:
        self.frames.append(np.array(frame, copy=True))
        self.speeds_mps.append(float(info["speed_mps"]))
        return self.policy(frame, info)


def record_reference(bm_policy, track_spec: TrackSpec, conditions: Conditions, seed: int,
                     steps: int | None) -> ReferenceRecording:
    """Drive the reference run of ``seed`` (the BM without latency, as ``reproduce`` drives it) and keep its frames."""
    recorder = _Recorder(bm_policy)
    cell = Cell("reference", "bm", "const:0", seed)
    log = drive("reference", recorder, track_spec, "const:0", seed, **drive_options(cell, conditions, steps))
    return ReferenceRecording(np.stack(recorder.frames), np.asarray(recorder.speeds_mps, np.float32),
                              np.asarray(log.columns["steering"], np.float64))


def lag_steps(latency_s: float, policy_frequency_hz: float) -> int:
    """Policy steps between the frame served for ``latency_s`` and now, as the latency wrapper serves it (at 30 Hz,
    0.15 s is 5 steps: the newest frame at least 0.15 s old)."""
    lag = served_steps(latency_s, 1.0 / policy_frequency_hz)
    if lag < 1:
        raise ValueError(f"latency {latency_s} s is less than one {policy_frequency_hz:g} Hz step")
    return lag


def constant_latencies(specs: Sequence[str], policy_frequency_hz: float) -> list[float]:
    """The constant latencies among ``specs`` (``const:X``) of at least one policy step."""
    latencies = [protocol.constant_latency_s(spec) for spec in specs if protocol.is_constant(spec)]
    return [latency_s for latency_s in latencies if served_steps(latency_s, 1.0 / policy_frequency_hz) >= 1]


def told_latency_s(latency_s: float, lag: int, conditions: Conditions) -> float:
    """What PLM-Net is told in the closed loop: the requested latency, or the age of the frame it got."""
    return latency_s if conditions.latency_source == "requested" else lag / conditions.policy_frequency_hz


def open_loop_errors(steering: np.ndarray, predicted: np.ndarray, lag: int) -> tuple[float, float]:
    """``(holding MAE, predicted MAE)`` along one run (see the module docstring).

    ``steering[t]``: the action taken at step t; ``predicted[k]``: the action predicted from step k's frame for
    ``lag`` steps later.
    """
    steering = np.asarray(steering, np.float64)
    predicted = np.asarray(predicted, np.float64)
    if steering.shape != predicted.shape or steering.ndim != 1:
        raise ValueError(f"steering {steering.shape} and predicted {predicted.shape} must be equal 1-D shapes")
    if not 1 <= lag < len(steering):
        raise ValueError(f"lag {lag} steps: must lie in [1, {len(steering) - 1}] for a run of {len(steering)} steps")
    later = steering[lag:]
    return float(np.mean(np.abs(steering[:-lag] - later))), float(np.mean(np.abs(predicted[:-lag] - later)))


def predict(plm_model_policy, recording: ReferenceRecording, latency_s: float) -> np.ndarray:
    """PLM-Net's action from every frame of ``recording``, told ``latency_s``."""
    frames, speeds = recording.frames, recording.speeds_mps
    parts = [plm_model_policy.steer_batch(frames[i:i + PREDICTION_BATCH], speeds[i:i + PREDICTION_BATCH],
                                          np.full(len(frames[i:i + PREDICTION_BATCH]), latency_s, np.float32))
             for i in range(0, len(frames), PREDICTION_BATCH)]
    return np.concatenate(parts)


def measure_open_loop(track_spec: TrackSpec, conditions: Conditions, policies: dict, seeds: Sequence[int],
                      latencies_s: Sequence[float], max_steps: int | None = None, progress=None) -> dict:
    """Per latency, over ``seeds``: ``{"lag_steps", "holding_mae", "plm_mae", "reduction_pct"}`` (Estimates;
    the reduction is computed per seed), plus ``per_seed`` lists of (holding, PLM-Net) MAEs.

    ``policies``: ``{"bm", "plm"}`` as :func:`~plm_highway.rollout.policies.make_policies` gives them.
    """
    steps = scored_steps(track_spec, conditions, max_steps)
    lags = {latency_s: lag_steps(latency_s, conditions.policy_frequency_hz) for latency_s in latencies_s}
    per_seed: dict[float, list[tuple[float, float]]] = {latency_s: [] for latency_s in latencies_s}
    for seed in seeds:
        recording = record_reference(policies["bm"], track_spec, conditions, seed, steps)
        for latency_s, lag in lags.items():
            predicted = predict(policies["plm"].model_policy, recording, told_latency_s(latency_s, lag, conditions))
            per_seed[latency_s].append(open_loop_errors(recording.steering, predicted, lag))
        if progress is not None:
            progress.update(1)
    out = {}
    for latency_s, pairs in per_seed.items():
        holding, plm = zip(*pairs)
        out[latency_s] = {
            "lag_steps": lags[latency_s],
            "holding_mae": mean_ci(list(holding), scale="positive"), "plm_mae": mean_ci(list(plm), scale="positive"),
            "reduction_pct": mean_ci([reduction_pct(h, p) for h, p in pairs], scale="reduction"),
            "per_seed": [{"holding_mae": h, "plm_mae": p} for h, p in pairs]}
    return out
