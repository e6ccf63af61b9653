"""Perception latency: profiles of how late the camera is, and a wrapper that makes it so."""

from plm_highway.latency.profiles import SPEC_HELP, LatencyProfile, parse_profile
from plm_highway.latency.wrapper import INJECTIONS, LatencyWrapper

__all__ = ["INJECTIONS", "SPEC_HELP", "LatencyProfile", "LatencyWrapper", "parse_profile"]
