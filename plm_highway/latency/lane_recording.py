"""A recording's camera lane signal and fast sensors, without capture timestamps: the file format the latency
estimator reads offline.

A recording (the sim2real CSV format, :mod:`plm_highway.sim2real.record.recording`) may carry, beside its standard
columns, what a camera pipeline reported at each row about the lane:

========================  ========  =============================================================
column                    unit      meaning
========================  ========  =============================================================
``lane_offset``           m         the car's offset from the lane centre, left positive (empty: no frame)
``lane_heading``          rad       the car's heading minus the lane's
========================  ========  =============================================================

No capture timestamp: the row's time is when the measurement arrived. :func:`estimate_recording` runs the latency
estimator (:mod:`plm_highway.latency.estimate`) over such rows; :func:`write_lane_recording` writes a simulated
run's stream in this format.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import write_csv_into
from plm_highway.io.bounded import parse_float_text
from plm_highway.latency.estimate import LatencyEstimatorConfig, estimate_stream

LANE_COLUMNS = ("lane_offset", "lane_heading")
STREAM_COLUMNS = ("t", "steer", "speed", "x", "y", "heading", "yaw_rate", *LANE_COLUMNS)
MAX_BYTES = 256 << 20  # a lane recording is read whole: 150,000 rows of a dozen columns fit many times over
DEFAULT_ESTIMATOR = LatencyEstimatorConfig()


def write_lane_recording(path: str | os.PathLike, log, steer_rad=None) -> None:
    """A run's stream as a recording with lane columns (into ``path``, which the caller stages): the fast sensors
    and lane measurements the estimator was given (a run with ``LatencyEstimation(record=True)``), the pose, and
    no capture timestamp. ``steer_rad``: the ``steer`` column instead of the measured wheel angle (e.g. the
    command, as a recording's ``steer`` is)."""
    c = log.columns
    missing = [name for name in ("stream_time_s", "stream_lane_offset_m") if name not in c]
    if missing:
        raise BadInput(f"run {log.name!r}: no recorded stream ({missing}); drive it with LatencyEstimation(record=True)")
    steer = c["stream_steer_rad"] if steer_rad is None else steer_rad
    rows = zip(c["stream_time_s"], steer, c["stream_speed_mps"], c["x_m"], c["y_m"], c["heading_rad"],
               c["stream_yaw_rate_radps"], c["stream_lane_offset_m"], c["stream_lane_heading_rad"])
    write_csv_into(Path(path), STREAM_COLUMNS,
                   [[value if math.isfinite(float(value)) else "" for value in row] for row in rows])


def read_lane_recording(path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """The columns the estimator needs from a recording CSV, or None when it has no lane columns.

    ``yaw_rate`` is the heading's derivative where the recording has no gyro. Errors name the file, line and column.
    """
    path = Path(path)
    if path.stat().st_size > MAX_BYTES:
        raise BadInput(f"{path}: {path.stat().st_size} bytes, more than the {MAX_BYTES} a lane recording may have")
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.reader(handle)
        try:
            header = [name.strip() for name in next(reader)]
        except StopIteration:
            raise BadInput(f"{path}: empty file") from None
        if not all(name in header for name in LANE_COLUMNS):
            return None
        needed = ["t", "steer", "speed", *LANE_COLUMNS] + (["yaw_rate"] if "yaw_rate" in header else ["heading"])
        missing = [name for name in needed if name not in header]
        if missing:
            raise BadInput(f"{path}: line 1: missing columns {missing}")
        index = {name: header.index(name) for name in needed}
        values: dict[str, list[float]] = {name: [] for name in needed}
        for line, row in enumerate(reader, start=2):
            for name, column in index.items():
                text = row[column].strip() if column < len(row) else ""
                if text == "" and name in LANE_COLUMNS:
                    values[name].append(math.nan)
                    continue
                number = parse_float_text(text, f"{path}: line {line}, column {name!r}", non_finite=True)
                if not math.isfinite(number):
                    raise BadInput(f"{path}: line {line}, column {name!r}: {text!r} is not finite")
                values[name].append(number)
    columns = {name: np.asarray(column, float) for name, column in values.items()}
    if len(columns["t"]) < 2 or np.any(np.diff(columns["t"]) <= 0):
        raise BadInput(f"{path}: column 't' must hold at least two strictly increasing times")
    if "yaw_rate" not in columns:
        columns["yaw_rate"] = np.gradient(np.unwrap(columns.pop("heading")), columns["t"])
    return columns


def estimate_recording(columns: dict[str, np.ndarray], config: LatencyEstimatorConfig = DEFAULT_ESTIMATOR,
                       vehicle_params=None) -> dict[str, np.ndarray]:
    """The latency estimator over a lane recording's rows (:func:`~plm_highway.latency.estimate.estimate_stream`)."""
    return estimate_stream(columns["t"], columns["yaw_rate"], columns["speed"], columns["steer"],
                           columns["lane_offset"], columns["lane_heading"], config, vehicle_params)
