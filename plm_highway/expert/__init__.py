"""The privileged expert driver and the human-like demonstrator that demonstrations are recorded from."""

from plm_highway.expert.controller import ExpertParams, ExpertPolicy, expert_steering, steering_for_curvature
from plm_highway.expert.human import HUMAN_PARAM_SOURCES, HumanDemonstrator, HumanParams, paper_units

__all__ = ["HUMAN_PARAM_SOURCES", "ExpertParams", "ExpertPolicy", "HumanDemonstrator", "HumanParams",
           "expert_steering", "paper_units", "steering_for_curvature"]
