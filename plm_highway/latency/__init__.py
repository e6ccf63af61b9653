"""Perception latency: profiles of how late the camera is, and a wrapper that makes it so."""

from plm_highway.latency.profiles import LatencyProfile, parse_profile
from plm_highway.latency.wrapper import LatencyWrapper

__all__ = ["LatencyProfile", "LatencyWrapper", "parse_profile"]
