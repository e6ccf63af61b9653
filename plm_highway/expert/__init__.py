"""The privileged expert driver that demonstrations are recorded from."""

from plm_highway.expert.controller import ExpertParams, ExpertPolicy, expert_steering, steering_for_curvature

__all__ = ["ExpertParams", "ExpertPolicy", "expert_steering", "steering_for_curvature"]
