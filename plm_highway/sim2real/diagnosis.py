"""A diagnosis as a record: what the pipeline (:mod:`plm_highway.sim2real.diagnose`) finds and its rendering
(:mod:`plm_highway.sim2real.rendering`) states, the verdicts, and the thresholds that decide them and that the
summaries quote."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.fit.problem import FitProblem
from plm_highway.sim2real.fit.selection import Selection
from plm_highway.sim2real.physics.replay import FitSignal, PoseReplay
from plm_highway.sim2real.record.consistency import Consistency
from plm_highway.sim2real.record.recording import Recording
from plm_highway.sim2real.residual.discovery import Discovery

VERDICTS = ("match", "mismatch", "partly explained", "unexplained", "unexcited", "inconclusive", "inconsistent",
            "discovered")
# The steering (through the plain model) or the car must move the yaw rate this many noise levels.
EXCITATION_NOISE_FACTOR = 3.0
# A fit that explains less than this share of the error above the noise leaves the recording partly explained.
PARTLY_EXPLAINED_BELOW = 0.8
# A mixed result: a signal's error changes by more than this fraction the other way.
SIGNAL_CHANGE = 0.05
# A structured leftover matters when the fit explains less than this share of the error above the
# noise: beyond it, what is left is the replay's own accuracy (e.g. a 1:10 car's stiff tire
# dynamics replayed at the sample rate leave +30-40% noise variance, under 0.5% of its error).
STRUCTURE_MATTERS_BELOW = 0.98


@dataclass
class Diagnosis:
    """A recording's diagnosis. An ``inconsistent`` recording stops at its consistency checks: it
    has no signal, selection, replay or fit (those fields stay None)."""

    recording: Recording
    signal: FitSignal | None
    noise_sigma: float
    selection: Selection | None
    block_s: float
    anchor_s: float
    heldout: np.ndarray | None
    before: np.ndarray | None  # the primary channel as the plain model predicts it
    after: np.ndarray | None  # ... as the chosen model predicts it (held-out samples: out of fold)
    best: np.ndarray | None  # ... as the best-scoring candidate predicts it (== after on a mismatch)
    pose_before: PoseReplay | None
    pose_after: PoseReplay | None
    windows: list[list[float]]
    conditions: dict
    fit: dict
    summary: str
    checks: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # caveats found by the diagnosis itself
    verdict: str = "match"
    confidence: str = "normal"
    data: dict = field(default_factory=dict)
    residual: dict = field(default_factory=dict)
    channels: list[FitSignal] = field(default_factory=list)
    problem: FitProblem | None = None
    consistency: Consistency | None = None
    library_verdict: str | None = None  # the verdict of the library alone (differs on "discovered")
    discovery: Discovery | None = None
