"""The delay-compensated lane-coordinate EKF (Sensors 2025, 25, 6251, Sections 3.2-3.4).

Every sensor step (100 Hz in the paper) the filter predicts with the steering-angle sensor and updates
with the IMU. A camera measurement updates the state only when one is due (Eq. (26): otherwise the
step is prediction only). Camera measurements arrive ``tau`` (~0.3 s) after their frame was captured:

- **without delay compensation** the measurement is applied when it arrives, as if it were current;
- **with delay compensation** it is re-stamped at its capture time ``t - tau`` (Eq. (28)) and the filter
  is re-run from that step to now over the stored inputs and IMU measurements (Eq. (29)).

Both use one code path: a camera measurement is filed under a step of the history (its capture step,
or the newest step when not compensating) and :func:`reestimate` re-runs the filter from there. The
history keeps, per step, what entered it (state and covariance), its inputs and its measurements, for
``history_s`` seconds: the longest delay the filter can compensate.

The filter is plain numpy for the prediction (the model is nonlinear, Eq. (23)) and filterpy's
functional :func:`filterpy.kalman.update` (Joseph form) for the updates, which are linear in the state
(Eq. (24)). Keeping ``(x, P)`` as plain values, not inside a filter object, is what makes rolling back
to an old step a matter of reading it from the history.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import update as kalman_update

from plm_highway.lane_ekf.lane_model import (
    H_CAMERA,
    N_STATES,
    imu_model,
    lane_dynamics,
    lane_dynamics_jacobian,
    single_track_rows,
)
from plm_highway.vehicle.single_track import SEED_PAPER_VEHICLE, SingleTrackParams

TIME_EPS_S = 1e-6


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise model and history of the estimator; standard deviations in the state's units."""

    vehicle: SingleTrackParams = SEED_PAPER_VEHICLE
    # Process noise as white-noise intensities [unit/sqrt(s)] of d, dpsi, v_n, v, r, kappa: how far the
    # model may be wrong per second (tire nonlinearity, road curvature changes, sensor bias).
    process_std: tuple[float, ...] = (0.02, 0.005, 0.2, 0.2, 0.02, 0.003)
    yaw_rate_std_radps: float = 0.005
    lateral_acceleration_std_mps2: float = 0.15
    # Camera lane measurement [d m, dpsi rad, kappa 1/m]: set from its measured error on calibration
    # seeds (see plm_highway.lane_ekf.table3.CALIBRATION_SEEDS), never on the scored ones.
    camera_std: tuple[float, float, float] = (0.05, 0.006, 0.002)
    initial_std: tuple[float, ...] = (1.0, 0.05, 0.5, 0.5, 0.05, 0.01)
    history_s: float = 1.0  # longest camera delay that can be compensated
    max_euler_step_s: float = 0.01  # longer prediction steps are split into Euler steps of at most this

    def __post_init__(self):
        for name in ("process_std", "initial_std"):
            values = getattr(self, name)
            if len(values) != N_STATES or not all(math.isfinite(v) and v >= 0 for v in values):
                raise ValueError(f"EstimatorConfig.{name}: need {N_STATES} finite values >= 0, got {values!r}")
        if len(self.camera_std) != 3 or not all(math.isfinite(v) and v > 0 for v in self.camera_std):
            raise ValueError(f"EstimatorConfig.camera_std: need 3 positive values, got {self.camera_std!r}")
        for name in ("yaw_rate_std_radps", "lateral_acceleration_std_mps2"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"EstimatorConfig.{name} must be positive, got {getattr(self, name)!r}")
        if not (math.isfinite(self.max_euler_step_s) and 0 < self.max_euler_step_s <= 0.1):
            raise ValueError(f"EstimatorConfig.max_euler_step_s={self.max_euler_step_s!r} must be in (0, 0.1] s")
        if not (math.isfinite(self.history_s) and 0 < self.history_s <= 10):
            raise ValueError(f"EstimatorConfig.history_s={self.history_s!r} must be in (0, 10] s")

    @property
    def imu_covariance(self) -> np.ndarray:
        return np.diag([self.lateral_acceleration_std_mps2 ** 2, self.yaw_rate_std_radps ** 2])

    @property
    def camera_covariance(self) -> np.ndarray:
        return np.diag(np.square(self.camera_std))


@dataclass
class StepRecord:
    """One filter step: its inputs and measurements, and the estimate entering and leaving it."""

    time_s: float
    dt_s: float  # since the previous step (0 for the first)
    steer_rad: float
    speed_mps: float
    imu: np.ndarray | None  # [a_y m/s^2, r rad/s]
    x_before: np.ndarray
    p_before: np.ndarray
    cameras: list[np.ndarray] = field(default_factory=list)  # [d, dpsi, kappa] stamped at this step
    x: np.ndarray | None = None
    p: np.ndarray | None = None


def ekf_predict(x, p, steer_rad: float, speed_mps: float, dt_s: float, config: EstimatorConfig):
    """Time update over ``dt_s``: forward Euler of Eq. (23), the covariance through its Jacobian.

    Steps longer than ``config.max_euler_step_s`` are split (a 20 Hz policy step is five Euler steps), so
    stiff tires or low speeds do not make the explicit step unstable.
    """
    rows = single_track_rows(speed_mps, config.vehicle)
    n_sub = max(1, math.ceil(dt_s / config.max_euler_step_s - 1e-9))
    h_s = dt_s / n_sub
    q_matrix = np.diag(np.square(config.process_std)) * h_s
    for _ in range(n_sub):
        f_matrix = np.eye(N_STATES) + h_s * lane_dynamics_jacobian(x, speed_mps, rows)
        x = x + h_s * lane_dynamics(x, steer_rad, speed_mps, rows)
        p = f_matrix @ p @ f_matrix.T + q_matrix
    return x, p


def filter_step(x, p, record: StepRecord, config: EstimatorConfig):
    """Predict to ``record``'s time, then update with its IMU and camera measurements (Eq. (26) if none)."""
    if record.dt_s > 0:
        x, p = ekf_predict(x, p, record.steer_rad, record.speed_mps, record.dt_s, config)
    if record.imu is not None:
        h_imu, steer_gain = imu_model(record.speed_mps, single_track_rows(record.speed_mps, config.vehicle))
        # a_y has a steering feed-through: subtract it so the update is the plain linear one.
        x, p = kalman_update(x, p, record.imu - steer_gain * record.steer_rad, config.imu_covariance, h_imu)
    for z_camera in record.cameras:
        x, p = kalman_update(x, p, z_camera, config.camera_covariance, H_CAMERA)
    return x, p


def reestimate(history: list[StepRecord], start: int, config: EstimatorConfig):
    """Re-run the filter from ``history[start]`` to the newest step (Eq. (29)); returns the newest estimate.

    Each step starts from what the previous (re-run) step left, so a measurement filed under an old
    step reaches the present through the same predictions and IMU updates the filter made then.
    """
    x, p = history[start].x_before, history[start].p_before
    for index in range(start, len(history)):
        record = history[index]
        record.x_before, record.p_before = x, p
        x, p = filter_step(x, p, record, config)
        record.x, record.p = x, p
    return x, p


class LaneStateEstimator:
    """The EKF over the lane-coordinate state, with or without delay compensation.

    Call :meth:`step` once per sensor sample (times strictly increasing), then :meth:`add_camera` for
    each camera measurement that arrived by then, with its capture time. :attr:`state` is the newest
    estimate ``[d, dpsi, v_n, v, r, kappa]``.
    """

    def __init__(self, config: EstimatorConfig = EstimatorConfig(), compensate_delay: bool = True,
                 initial_state: np.ndarray | None = None):
        self.config = config
        self.compensate_delay = compensate_delay
        self.initial_state = np.zeros(N_STATES) if initial_state is None else _finite(initial_state, "initial_state")
        if self.initial_state.shape != (N_STATES,):
            raise ValueError(f"initial_state: need {N_STATES} values, got shape {self.initial_state.shape}")
        self.reset()

    def reset(self) -> None:
        self.history: list[StepRecord] = []
        self.last_capture_time_s = -math.inf
        self.reestimated_steps = 0  # steps re-run by camera measurements since reset (for the benchmark)

    @property
    def state(self) -> np.ndarray:
        if not self.history:
            return self.initial_state.copy()
        return self.history[-1].x

    @property
    def covariance(self) -> np.ndarray:
        if not self.history:
            return np.diag(np.square(self.config.initial_std))
        return self.history[-1].p

    @property
    def now_s(self) -> float:
        return self.history[-1].time_s if self.history else -math.inf

    def step(self, time_s: float, steer_rad: float, speed_mps: float, imu: np.ndarray | None = None) -> np.ndarray:
        """Advance to ``time_s`` with the measured front-wheel angle and speed, and the IMU ``[a_y, r]``."""
        for name, value in (("time_s", time_s), ("steer_rad", steer_rad), ("speed_mps", speed_mps)):
            if not math.isfinite(value):
                raise ValueError(f"estimator step: {name}={value!r} is not finite")
        if speed_mps <= 0.5:
            raise ValueError(f"estimator step: speed_mps={speed_mps!r} must exceed 0.5 m/s (the model divides by it)")
        if time_s <= self.now_s:
            raise ValueError(f"estimator step: time_s={time_s!r} is not after the previous step at {self.now_s!r} s")
        imu = None if imu is None else _finite(imu, "imu")
        if imu is not None and imu.shape != (2,):
            raise ValueError(f"estimator step: imu must be [a_y, r], got shape {imu.shape}")
        if self.history:
            x, p, dt_s = self.history[-1].x, self.history[-1].p, time_s - self.now_s
        else:
            x, p, dt_s = self.initial_state.copy(), self.covariance, 0.0
        record = StepRecord(float(time_s), dt_s, float(steer_rad), float(speed_mps), imu, x, p)
        record.x, record.p = filter_step(x, p, record, self.config)
        self.history.append(record)
        self._forget_old()
        return record.x

    def add_camera(self, z_camera: np.ndarray, capture_time_s: float) -> np.ndarray:
        """Fuse a camera measurement ``[d, dpsi, kappa]`` of the frame captured at ``capture_time_s``."""
        z_camera = _finite(z_camera, "camera measurement")
        if z_camera.shape != (3,):
            raise ValueError(f"camera measurement must be [d, dpsi, kappa], got shape {z_camera.shape}")
        if not math.isfinite(capture_time_s):
            raise ValueError(f"camera capture_time_s={capture_time_s!r} is not finite")
        if not self.history:
            raise ValueError("camera measurement before the first estimator step")
        if capture_time_s > self.now_s + TIME_EPS_S:
            raise ValueError(f"camera capture time {capture_time_s} s is after now ({self.now_s} s): negative delay")
        if capture_time_s < self.last_capture_time_s - TIME_EPS_S:
            raise ValueError(f"camera capture time {capture_time_s} s is before the previous one "
                             f"({self.last_capture_time_s} s): measurements must arrive in capture order")
        index = self._index_at(capture_time_s) if self.compensate_delay else len(self.history) - 1
        self.last_capture_time_s = capture_time_s
        self.history[index].cameras.append(z_camera)
        self.reestimated_steps += len(self.history) - index
        reestimate(self.history, index, self.config)
        return self.state

    def _index_at(self, time_s: float) -> int:
        """The history step nearest ``time_s`` (the frame's capture), refusing one older than the history."""
        times = [record.time_s for record in self.history]
        index = int(np.searchsorted(times, time_s))
        if index == len(times) or (index > 0 and time_s - times[index - 1] < times[index] - time_s):
            index -= 1
        oldest_s = times[0]
        step_s = times[1] - times[0] if len(times) > 1 else 0.0
        if time_s < oldest_s - 0.5 * step_s - TIME_EPS_S:
            raise ValueError(
                f"camera delay {self.now_s - time_s:.3f} s reaches before the {self.now_s - oldest_s:.3f} s of "
                f"history kept (EstimatorConfig.history_s={self.config.history_s}); raise history_s"
            )
        return index

    def _forget_old(self) -> None:
        # Keep the newest step at or before now - history_s, so a delay of exactly history_s is served.
        cut = 0
        while cut + 1 < len(self.history) and self.history[cut + 1].time_s <= self.now_s - self.config.history_s + TIME_EPS_S:
            cut += 1
        if cut:
            del self.history[:cut]


def _finite(values, what: str) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what}: {values!r} contains NaN or infinity")
    return array
