"""Policies by name, for the command line: ``expert``, ``bm`` (Base Model), ``plm`` (PLM-Net)."""

from __future__ import annotations

from plm_highway.expert import ExpertPolicy

POLICY_NAMES = ("expert", "bm", "plm")


class VisionPolicy:
    """Adapts a model policy ``(frame, speed_mps, latency_s) -> steering`` to ``(frame, info)``.

    The latency it is told is the *measured* age of the observation, as PLM-Net is deployed.
    """

    def __init__(self, model_policy, latency_bias_s: float = 0.0):
        self.model_policy = model_policy
        self.latency_bias_s = latency_bias_s

    def reset(self) -> None:
        self.model_policy.reset()

    @property
    def clamped_count(self) -> int:
        return int(getattr(self.model_policy, "clamped_count", 0))

    def __call__(self, frame, info) -> float:
        latency_s = max(0.0, info["observation_age_s"] + self.latency_bias_s)
        return float(self.model_policy(frame, info["speed_mps"], latency_s))


def make_policy(name: str, checkpoint_dir=None, latency_bias_s: float = 0.0):
    """The policy named ``name``; model policies load the shipped checkpoints unless given a dir."""
    if name == "expert":
        return ExpertPolicy()
    if name not in POLICY_NAMES:
        raise ValueError(f"--policy {name!r}: expected one of {list(POLICY_NAMES)}")
    from plm_highway.models import policies, shipped

    if name == "bm":
        bm = shipped.load_shipped_base_model(checkpoint_dir)
        return VisionPolicy(policies.BaseModelPolicy(bm))
    return VisionPolicy(policies.PLMNetPolicy(shipped.load_shipped_plm_net(checkpoint_dir)), latency_bias_s)
