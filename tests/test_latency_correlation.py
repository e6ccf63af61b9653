"""The openpilot-style baseline (plm_highway.latency.correlation) and the claim scores after steps."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.errors import BadInput
from plm_highway.latency.correlation import (
    PUBLISHED,
    CorrelationLagConfig,
    CorrelationLagEstimator,
    masked_ncc,
    time_scaled,
)
from plm_highway.latency.estimate import FastSample, LaneSample
from plm_highway.latency.scoring import claim_step_metrics
from plm_highway.latency.synthetic import StreamSpec, Weave, synthetic_stream


@settings(max_examples=40, deadline=None)
@given(shift=st.integers(0, 15), drop=st.floats(0.0, 0.3), seed=st.integers(0, 10_000))
def test_the_masked_correlation_peaks_at_the_shift_whatever_is_masked(shift, drop, seed):
    rng = np.random.default_rng(seed)
    prompt = rng.normal(size=300)
    late = np.r_[np.zeros(shift), prompt[:300 - shift]]  # the same signal, `shift` samples later
    mask = rng.random(300) >= drop
    mask[:shift] = False  # nothing known before the late signal starts
    ncc = masked_ncc(prompt, late, mask, 20)
    assert int(np.argmax(ncc)) == shift
    assert ncc[shift] == pytest.approx(1.0, abs=1e-9)
    assert np.all(ncc <= 1.0) and np.all(ncc >= -1.0)


def feed(estimator, stream):
    answers = []
    for k in range(len(stream["time_s"])):
        lane = None
        if math.isfinite(stream["lane_heading_rad"][k]):
            lane = LaneSample(stream["lane_offset_m"][k], stream["lane_heading_rad"][k])
        fast = FastSample(stream["time_s"][k], stream["yaw_rate_radps"][k], stream["speed_mps"][k],
                          stream["steer_rad"][k])
        answers.append(estimator.update(fast, lane))
    return answers


def clean_weave(latency_s: float, duration_s: float):
    """A fast car weaving broadly (three tones) with a nearly noiseless camera: what the method needs to accept."""
    spec = StreamSpec(duration_s=duration_s, rate_hz=20.0, speed_mps=20.0, latency=latency_s,
                      weave=Weave((0.01, 0.008, 0.006), (0.37, 0.83, 1.41), (0.0, 1.0, 2.0)),
                      offset_noise_m=0.001, heading_noise_rad=0.0001)
    return synthetic_stream(spec, np.random.default_rng(3))


def test_the_scaled_baseline_claims_the_true_lag_once_its_blocks_agree_and_not_before():
    config = time_scaled(10.0)
    stream = clean_weave(0.3, 30.0)
    answers = feed(CorrelationLagEstimator(config), stream)
    claimed = [a for a in answers if a.estimable]
    assert claimed, "a broad, clean weave must be estimated within 30 s"
    first = next(k for k, a in enumerate(answers) if a.estimable)
    assert stream["time_s"][first] - stream["time_s"][0] >= config.first_claim_s - 0.05
    assert all(abs(a.latency_s - 0.3) <= 0.05 for a in claimed)  # within one 20 Hz frame
    assert all(a.held_s == pytest.approx(PUBLISHED.prior_latency_s) for a in answers[:first])


def test_with_its_published_durations_it_cannot_claim_within_a_run_of_30_s():
    assert PUBLISHED.first_claim_s == pytest.approx(150.0)
    answers = feed(CorrelationLagEstimator(PUBLISHED), clean_weave(0.3, 30.0))
    assert not any(a.estimable for a in answers)
    assert {a.state for a in answers} == {"unestimated"}


def test_a_claim_is_clamped_to_the_published_lag_range():
    stream = clean_weave(0.05, 30.0)
    answers = feed(CorrelationLagEstimator(time_scaled(10.0)), stream)
    claimed = [a.latency_s for a in answers if a.estimable]
    assert claimed and min(claimed) == pytest.approx(PUBLISHED.min_lag_s)


def test_bad_baseline_settings_are_refused_by_name():
    with pytest.raises(BadInput, match="window_s"):
        CorrelationLagConfig(window_s=0.0)
    with pytest.raises(BadInput, match="blocks_needed"):
        CorrelationLagConfig(blocks_needed=60, blocks_kept=50)
    with pytest.raises(BadInput, match="factor"):
        time_scaled(0.5)
    estimator = CorrelationLagEstimator(time_scaled(10.0))
    estimator.update(FastSample(1.0, 0.0, 20.0, 0.0))
    with pytest.raises(BadInput, match="not after"):
        estimator.update(FastSample(1.0, 0.0, 20.0, 0.0))


def test_claim_step_metrics_by_hand():
    # 10 Hz, tolerance 0.1 s; the truth 0.1 s, steps to 0.4 s at t = 2 s (3 tolerances), then to 0.45 s at t = 6 s
    # (half a tolerance: a boundary, not a step of two frames).
    t = np.arange(0.0, 8.0, 0.1)
    true = np.where(t < 2.0 - 1e-9, 0.1, np.where(t < 6.0 - 1e-9, 0.4, 0.45))
    held = np.where(t < 3.5 - 1e-9, 0.1, 0.4)  # the old value until 3.5 s, then the new one
    changing = np.zeros(len(t), bool)
    # claims the old value until 2.5 s (wrong from 2 s, but within the 1 s budget), the new one from 3.5 s
    claimed = (t < 2.5 - 1e-9) | (t >= 3.5 - 1e-9)
    scores = claim_step_metrics(t, true, held, claimed, changing, 0.1)
    assert scores["steps"] == 1 and scores["steps_judged"] == 1
    assert scores["stopped"] == 1 and scores["answered"] == 1 and scores["handled_fraction"] == 1.0
    # a wrong claim 1.5 s after the step: not stopped
    late_claim = claimed | ((t >= 3.4 - 1e-9) & (t < 3.5 - 1e-9))
    late_held = np.where((t >= 3.4 - 1e-9) & (t < 3.5 - 1e-9), 0.1, held)
    assert claim_step_metrics(t, true, late_held, late_claim, changing, 0.1)["stopped"] == 0
    # never claims the new value: answered only if it says "changing" from 1 s on until the 5-s budget
    silent = t < 2.5 - 1e-9
    assert claim_step_metrics(t, true, np.full(len(t), 0.1), silent, changing, 0.1)["answered"] == 0
    says_changing = (t >= 2.5 - 1e-9)
    assert claim_step_metrics(t, true, np.full(len(t), 0.1), silent, says_changing, 0.1)["answered"] == 1


def test_claim_step_metrics_leave_the_stream_start_unjudged_and_tell_unseen_steps_apart():
    # 10 Hz, tolerance 0.1 s: the camera's first frames make the age jump from 0 to 0.4 s at 0.4 s (the stream's
    # start), and the latency steps to 0.1 s at 3 s. Nothing is claimed and nothing is said but "not estimable".
    t = np.arange(0.0, 9.0, 0.1)
    true = np.where(t < 0.4 - 1e-9, 0.0, np.where(t < 3.0 - 1e-9, 0.4, 0.1))
    quiet = np.zeros(len(t), bool)
    held = np.full(len(t), 0.2)
    everything = claim_step_metrics(t, true, held, quiet, quiet, 0.1)
    assert everything["steps_judged"] == 2 and everything["answered"] == 0
    assert everything["unanswered_not_estimable"] == 2
    after_start = claim_step_metrics(t, true, held, quiet, quiet, 0.1, blind_s=1.0)
    assert after_start["steps"] == 1 and after_start["steps_judged"] == 1
    assert after_start["handled"] == 0 and after_start["unanswered_not_estimable"] == 1
    # "changing" said for a moment after the step: still not answered, but no longer unseen
    glimpse = (t >= 3.2 - 1e-9) & (t < 3.5 - 1e-9)
    seen = claim_step_metrics(t, true, held, quiet, glimpse, 0.1, blind_s=1.0)
    assert seen["answered"] == 0 and seen["unanswered_not_estimable"] == 0


@given(st.lists(st.tuples(st.integers(1, 40), st.sampled_from([0.0, 0.05, 0.1, 0.25, 0.4])), min_size=1, max_size=8),
       st.lists(st.sampled_from(["claim", "changing", "silent"]), min_size=1, max_size=50), st.floats(0.0, 3.0))
@settings(max_examples=60, deadline=None)
def test_claim_step_counts_hold_together(segments, answers, blind_s):
    true = np.concatenate([np.full(length, value) for length, value in segments])
    t = np.arange(len(true)) * 0.1
    states = np.resize(np.array(answers), len(true))
    held = np.roll(true, 3)
    scores = claim_step_metrics(t, true, held, states == "claim", states == "changing", 0.1, blind_s=blind_s)
    assert scores["handled"] <= min(scores["stopped"], scores["answered"])
    assert scores["stopped"] <= scores["steps_judged"] <= scores["steps"]
    assert scores["unanswered_not_estimable"] <= scores["steps_judged"] - scores["answered"]
    later = claim_step_metrics(t, true, held, states == "claim", states == "changing", 0.1, blind_s=blind_s + 1.0)
    assert later["steps"] <= scores["steps"]
