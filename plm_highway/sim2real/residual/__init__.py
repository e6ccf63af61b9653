"""Residual discovery: terms outside the library tried on what the library leaves (delays that vary along the track, a bank map, the residual's shape)."""
