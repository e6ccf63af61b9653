"""What a discovered term looks like, and what the data say on their own, for the figures.

For a steering-map term the data's own view is a binned estimate: the recording's error after the
discovered model with that term left out (the rest of the chain as refitted with it) is regressed (weighted least squares over every recorded channel) on the channels'
response to a small steering offset applied only while the command is in one bin (or, for the
speed-dependent ratio, a small gain change only while the speed is in one bin). The estimates, with
their standard errors, show the departure from the chain's linear steering at each command level
without assuming the term's shape; the discovered term's curve is drawn over them. A gyro bias is
shown as the gyro's mean error per speed band, a delay track over time, a bank field along the lap.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from plm_highway.sim2real.fit.problem import FitProblem
from plm_highway.sim2real.physics.chain import calibrated, command_change, steering_map
from plm_highway.sim2real.physics.effects import EffectParams, effect_report, neutral_of
from plm_highway.sim2real.physics.replay import channel_prediction, model_outputs

BINS = 12
STEP = 1e-4  # rad of offset (or relative gain) per bin for the sensitivities


def _predictions(problem: FitProblem, params: EffectParams, steer: np.ndarray) -> list[np.ndarray]:
    rec = replace(problem.recording, steer_rad=steer)
    out = model_outputs(rec, params, with_slip=False)
    return [channel_prediction(c, rec, params, out) for c in problem.channels]


def binned(problem: FitProblem, params: EffectParams, bin_of_sample: np.ndarray, n_bins: int, relative_gain: bool = False,
           sign: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per bin, the steering offset [rad] (or, with ``relative_gain``, the relative gain change) that the
    recording's error after ``params`` asks for while the sample is in that bin (times ``sign``
    per sample when given), and its standard error."""
    steer = problem.recording.steer_rad
    base = _predictions(problem, params, steer)
    masks = [c.usable for c in problem.channels]
    sign = np.ones(steer.size) if sign is None else sign
    columns = []
    for b in range(n_bins):
        inside = (bin_of_sample == b) * sign
        moved = steer * (1 + STEP * inside) if relative_gain else steer + command_change(params, STEP) * inside
        columns.append([(p - q) / STEP for p, q in zip(_predictions(problem, params, moved), base)])
    gram = np.zeros((n_bins, n_bins))
    rhs = np.zeros(n_bins)
    sse, count = 0.0, 0
    for i, (c, w, mask) in enumerate(zip(problem.channels, problem.weights, masks)):
        j = np.column_stack([col[i][mask] for col in columns])
        e = (c.values - base[i])[mask]
        gram += w * j.T @ j
        rhs += w * j.T @ e
    estimate = np.linalg.lstsq(gram + 1e-12 * np.trace(gram) * np.eye(n_bins), rhs, rcond=None)[0]
    for i, (c, w, mask) in enumerate(zip(problem.channels, problem.weights, masks)):
        j = np.column_stack([col[i][mask] for col in columns])
        e = (c.values - base[i])[mask] - j @ estimate
        sse += w * float(e @ e)
        count += int(mask.sum())
    cov = sse / max(count - n_bins, 1) * count * np.linalg.pinv(gram) / count
    return estimate, np.sqrt(np.maximum(np.diag(cov), 0.0))


def _quantile_bins(values: np.ndarray, usable: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    edges = np.unique(np.quantile(values[usable], np.linspace(0, 1, n + 1)))
    index = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    return np.where(usable, index, -1), edges


def _mapped(params: EffectParams, steer: np.ndarray, speed: np.ndarray) -> np.ndarray:
    command = np.ascontiguousarray(calibrated(params, steer), float)
    out = np.empty_like(command)
    steering_map(command, np.ascontiguousarray(speed, float), params.chain(), out)
    return out


def shape_data(problem: FitProblem, found) -> dict:
    """Everything the figure of a discovered term (``found``, a :class:`~.discovery.Found`) draws."""
    rec = problem.recording
    usable = problem.signal.usable
    if found.name == "delay_track":
        track = found.detail["track"]
        return {"kind": "time", "t_s": rec.t_s, "track_delay_s": track.delay_at_sample_s, "error_s": track.standard_error_s,
                "visible": track.visible, "base_delay_s": track.base_delay_s}
    if found.name == "bank_along_track":
        field = found.detail["field"]
        return {"kind": "place", "anchor_bank_rad": field.anchor_bank_rad, "error_rad": field.standard_error_rad,
                "anchors_xy": field.anchors_xy, "curvature": field.curvature, "spacing_m": field.spacing_m,
                "x_m": rec.x_m, "y_m": rec.y_m}
    after = found.detail["params"]
    # The data's view and the curve in one frame: the discovered model with this term left out.
    before = replace(after, **neutral_of(found.name))
    estimates = effect_report(found.name, after, problem.ctx)
    if found.name == "gyro_bias":
        gyro = next(i for i, c in enumerate(problem.channels) if c.name == "yaw_rate")
        residual = problem.channels[gyro].values - problem.predictions(before)[gyro]
        bins, edges = _quantile_bins(rec.speed_mps, problem.channels[gyro].usable, 8)
        means = np.array([np.mean(residual[bins == b]) for b in range(len(edges) - 1)])
        errors = np.array([np.std(residual[bins == b]) / np.sqrt(max((bins == b).sum(), 1)) for b in
                           range(len(edges) - 1)])
        return {"kind": "speed", "x": 0.5 * (edges[1:] + edges[:-1]), "y": means, "y_error": errors,
                "curve_x": edges, "curve_y": np.full(edges.size, estimates["bias_radps"]), "xlabel": "speed [m/s]",
                "ylabel": "gyro error without the bias [rad/s]"}
    if found.name == "speed_dependent_steering":
        bins, edges = _quantile_bins(rec.speed_mps, usable, BINS)
        estimate, error = binned(problem, before, bins, len(edges) - 1, relative_gain=True)
        speeds = np.linspace(edges[0], edges[-1], 50)
        ratio = estimates["gain_slope_per_mps"] * (speeds - estimates["speed_ref_mps"])
        return {"kind": "speed", "x": 0.5 * (edges[1:] + edges[:-1]), "y": estimate, "y_error": error,
                "curve_x": speeds, "curve_y": ratio, "xlabel": "speed [m/s]",
                "ylabel": "relative change of the steering gain"}
    command = calibrated(before, rec.steer_rad)
    departure = _mapped(after, rec.steer_rad, rec.speed_mps) - _mapped(before, rec.steer_rad, rec.speed_mps)
    if found.name == "steering_backlash":
        # A play's departure depends on how far the command has moved since it last reversed.
        direction, travel = reversals(command)
        bins, edges = _quantile_bins(travel, usable, BINS)
        estimate, error = binned(problem, before, bins, len(edges) - 1, sign=direction)
        x, along = 0.5 * (edges[1:] + edges[:-1]), departure * direction
        order = np.argsort(travel[usable])
        return {"kind": "command", "x": x, "y": estimate, "y_error": error, "curve_x": travel[usable][order],
                "curve_y": along[usable][order], "xlabel": "command travel since its last reversal [rad]",
                "ylabel": "wheel angle minus the linear steering's,\nalong the command's motion [rad]"}
    bins, edges = _quantile_bins(command, usable, BINS)
    estimate, error = binned(problem, before, bins, len(edges) - 1)
    order = np.argsort(command[usable])
    return {"kind": "command", "x": 0.5 * (edges[1:] + edges[:-1]), "y": estimate, "y_error": error,
            "curve_x": command[usable][order], "curve_y": departure[usable][order],
            "xlabel": "steering command after calibration [rad]", "ylabel": "wheel angle minus the linear steering's [rad]"}


def reversals(command: np.ndarray, threshold_rad: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the command's direction of motion (+1 rising, -1 falling; a reversal counts once it
    has moved ``threshold_rad`` back) and how far it has travelled since the last reversal."""
    direction = np.ones(command.size)
    travel = np.zeros(command.size)
    current, extreme, start = 1.0, command[0], command[0]
    for k, value in enumerate(command):
        if (value - extreme) * current > 0:
            extreme = value
        elif abs(value - extreme) > threshold_rad:
            current, start, extreme = -current, extreme, value
        direction[k] = current
        travel[k] = abs(value - start)
    return direction, travel
