"""Matplotlib drawing shared by the figures: the road seen from above, north up, never mirrored."""

from __future__ import annotations

import numpy as np

from plm_highway.road.geometry import sample_reference
from plm_highway.road.track import TrackSpec


def draw_road(ax, track: TrackSpec, window: tuple[float, float] | None = None) -> None:
    """Road edges (solid) and lane markings (dashed) of ``track``, optionally only arc lengths in ``window``."""
    ref = sample_reference(track, spacing_m=1.0)
    keep = np.ones(len(ref.s_m), bool) if window is None else (ref.s_m >= window[0]) & (ref.s_m <= window[1])
    left_x, left_y = ref.offset(track.road_half_width_m)
    right_x, right_y = ref.offset(-track.road_half_width_m)
    ax.fill(np.concatenate([left_x[keep], right_x[keep][::-1]]), np.concatenate([left_y[keep], right_y[keep][::-1]]),
            color="0.85", zorder=0)
    for boundary in range(track.lanes + 1):
        x, y = ref.offset(track.road_half_width_m - boundary * track.lane_width_m)
        outer = boundary in (0, track.lanes)
        ax.plot(x[keep], y[keep], color="0.3" if outer else "0.55", lw=1.2 if outer else 0.8,
                ls="-" if outer else (0, (4, 6)), zorder=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (east)")
    ax.set_ylabel("y [m] (north)")
