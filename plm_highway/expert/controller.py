"""The expert driver: a privileged lane-centre tracker to learn from.

In lane coordinates (offset ``e`` to the lane centre, course error ``psi``: the direction of travel
relative to the lane, i.e. heading error plus the bicycle's slip angle beta) a car driving at
speed ``v`` with path curvature ``kappa`` obeys ``de/dt = v sin(psi)`` and
``dpsi/dt = v (kappa - kappa_lane)``. Commanding

    kappa = kappa_lane - k_e e - k_psi psi,   k_e = w^2 / v^2,  k_psi = 2 zeta w / v

makes the offset a damped oscillator of natural frequency ``w`` whatever the speed. The curvature
is then turned into a front-wheel angle by inverting highway-env's kinematic bicycle
(heading rate = v sin(beta) / (L/2), tan(delta) = 2 tan(beta)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from highway_env.vehicle.kinematics import Vehicle

HALF_LENGTH_M = Vehicle.LENGTH / 2


@dataclass(frozen=True)
class ExpertParams:
    natural_frequency_radps: float = 3.0
    damping_ratio: float = 0.9
    max_steering_rad: float = 0.2  # must match the env's max_steering_rad


def steering_for_curvature(curvature_1pm: float) -> float:
    """Front-wheel angle [rad] that makes highway-env's bicycle drive a path of this curvature."""
    sin_beta = max(-1.0, min(1.0, HALF_LENGTH_M * curvature_1pm))
    return math.atan(2.0 * math.tan(math.asin(sin_beta)))


def expert_steering(state: dict, params: ExpertParams = ExpertParams()) -> float:
    """Normalised steering in [-1, 1] (positive left) from a privileged state snapshot."""
    speed_mps = max(float(state["speed_mps"]), 1.0)
    w = params.natural_frequency_radps
    k_offset = w * w / (speed_mps * speed_mps)
    k_heading = 2.0 * params.damping_ratio * w / speed_mps
    # The course angle is heading + beta. Beta is taken from the road's curvature (its steady-state
    # value), not from the steering applied a moment ago: a camera sees the road but not the steering
    # wheel, so a policy that imitates this expert from images can learn exactly what it does.
    beta_rad = math.asin(max(-1.0, min(1.0, HALF_LENGTH_M * state["curvature_1pm"])))
    course_error_rad = state["heading_error_rad"] + beta_rad
    curvature_1pm = (state["curvature_preview_1pm"] - k_offset * state["lateral_offset_m"]
                     - k_heading * math.sin(course_error_rad))
    steering = steering_for_curvature(curvature_1pm) / params.max_steering_rad
    return max(-1.0, min(1.0, steering))


class ExpertPolicy:
    """Callable policy over the env's info: uses the observed (possibly delayed) state if present."""

    def __init__(self, params: ExpertParams = ExpertParams()):
        self.params = params

    @property
    def tracking(self) -> ExpertParams:
        """The law it steers by (the same attribute as the human-like demonstrator's)."""
        return self.params

    def reset(self) -> None:
        """The expert is stateless."""

    def __call__(self, frame, info: dict) -> float:
        return expert_steering(info.get("observed_state", info), self.params)
