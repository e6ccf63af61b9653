"""The saturating tire and the road bank (plm_highway.vehicle.tires) against the linear model and
closed-form steady states."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.vehicle.single_track import SEED_PAPER_VEHICLE, params_per_kg, single_track_rollout
from plm_highway.vehicle.tires import (
    GRAVITY_MPS2,
    axle_force,
    saturating_single_track_rollout,
    saturating_single_track_settled,
)

CF, CR, K2 = params_per_kg(SEED_PAPER_VEHICLE)
A, B = SEED_PAPER_VEHICLE.cg_to_front_m, SEED_PAPER_VEHICLE.cg_to_rear_m
K = SEED_PAPER_VEHICLE.understeer_gradient_rad_per_mps2


@settings(max_examples=50, deadline=None)
@given(stiffness=st.floats(5.0, 500.0), peak=st.floats(0.5, 30.0), alpha=st.floats(-1.0, 1.0))
def test_the_magic_formula_has_the_linear_slope_at_zero_and_never_exceeds_its_peak(stiffness, peak, alpha):
    force, slope = axle_force(alpha, stiffness, peak)
    assert abs(force) <= peak * (1 + 1e-12)
    assert axle_force(0.0, stiffness, peak)[1] == pytest.approx(stiffness, rel=1e-12)
    h = 1e-7
    numeric = (axle_force(alpha + h, stiffness, peak)[0] - axle_force(alpha - h, stiffness, peak)[0]) / (2 * h)
    assert slope == pytest.approx(numeric, rel=1e-4, abs=1e-6 * peak)


def test_without_a_friction_limit_the_replay_is_the_linear_single_track():
    t = np.arange(3000) * 0.02
    delta = 0.03 * np.sin(2 * math.pi * 0.4 * t) + 0.01 * np.sin(2 * math.pi * 1.3 * t)
    speed = 15 + 5 * np.sin(0.05 * t)
    r, vy = saturating_single_track_rollout(delta, speed, 0.02, CF, CR, A, B, K2)
    vy_lin, r_lin = single_track_rollout(delta, speed, 0.02, CF, CR, A, B, K2)
    assert np.max(np.abs(r - r_lin)) < 1e-3 * np.max(np.abs(r_lin))


@pytest.mark.parametrize("speed_mps", [10.0, 25.0])
def test_a_bank_pulls_like_an_offset_of_k_g_sin_bank_in_a_steady_state(speed_mps):
    bank = 0.05
    vy, r = saturating_single_track_settled(speed_mps, 0.0, CF, CR, A, B, K2, math.inf,
                                            GRAVITY_MPS2 * math.sin(bank))
    wheelbase = A + B
    assert r == pytest.approx(speed_mps * K * GRAVITY_MPS2 * math.sin(bank) / (wheelbase + K * speed_mps**2),
                              rel=1e-6)
    # The rear axle carries a share a/L of the lateral force: its slip angle sets the crab.
    rear_slip = -(vy - B * r) / speed_mps
    assert CR * rear_slip == pytest.approx(-A / wheelbase * GRAVITY_MPS2 * math.sin(bank) + A / wheelbase
                                           * speed_mps * r, rel=1e-6)


def test_saturation_lowers_the_steady_yaw_rate_only_near_the_friction_limit():
    u = 20.0
    ratios = []
    for delta in (0.005, 0.02, 0.04):
        _, r_lin = saturating_single_track_settled(u, delta, CF, CR, A, B, K2, math.inf, 0.0)
        _, r_sat = saturating_single_track_settled(u, delta, CF, CR, A, B, K2, 0.5, 0.0)
        ratios.append(r_sat / r_lin)
        assert abs(u * r_sat) < 0.5 * GRAVITY_MPS2
    assert ratios[0] > 0.99 > ratios[1] > ratios[2]
