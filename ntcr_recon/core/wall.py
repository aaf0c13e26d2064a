"""Where this cloud's outer-wall points lie: the robust level and spread of their radial offsets.

Stereo depth puts the seen wall a little off r_o (flattening) and spreads it (noise). Notch interiors (cut
faces, floor, bore) lie well inside, so the band is measured on the points near the wall only (`spine`:
optionally only the points on spines, away from the cuts, so notch interiors cannot widen it).
"""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation


def robust_spread(values: np.ndarray, centre: float) -> float:
    """sigma estimated from the median absolute deviation about `centre`."""
    return MAD_TO_SIGMA * float(np.median(np.abs(values - centre))) if values.size else 0.0


def surface_band(offset: np.ndarray, gate: float, spine: np.ndarray | None = None) -> tuple[float, float]:
    """Robust level and spread (3 sigma) of the radial offsets from the outer wall, within the gate.

    The band level +- spread is where this cloud's outer-wall points lie, cut faces and flying pixels
    mostly outside. spine: (N,) bool, measure on these points only (when at least 8 of them are near).
    """
    near_wall = np.abs(offset) < gate
    if spine is not None and np.count_nonzero(near_wall & spine) >= 8:
        near_wall &= spine
    near = offset[near_wall]
    if near.size < 8:
        return 0.0, gate
    level = float(np.median(near))
    spread = 3.0 * robust_spread(near, level)
    return level, min(max(spread, 1e-6), gate)
