"""Where this cloud's outer-wall points lie: the robust level and spread of their radial offsets.

Stereo depth puts the seen wall a little off r_o (flattening) and spreads it (noise). Notch interiors (cut
faces, floor, bore) lie well inside, so the band is measured on the points near the wall only (`spine`:
optionally only the points on spines, away from the cuts, so notch interiors cannot widen it).
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.robust import MAD_TO_SIGMA, median, median_absolute_deviation


@jit
def _level_and_deviation(offset, gate, spine):
    """Median and median absolute deviation of the offsets within the gate (those on `spine` only, when at
    least 8 of them are; spine of length 0: no such choice), and how many offsets they are taken over."""
    near_count, spine_count = 0, 0
    for i in range(offset.shape[0]):
        if abs(offset[i]) < gate:
            near_count += 1
            if spine.shape[0] and spine[i]:
                spine_count += 1
    on_spine = spine_count >= 8
    near = np.empty(spine_count if on_spine else near_count)
    count = 0
    for i in range(offset.shape[0]):
        if abs(offset[i]) < gate and (not on_spine or spine[i]):
            near[count] = offset[i]
            count += 1
    if count < 8:
        return 0.0, 0.0, count
    level = median(near)
    return level, median_absolute_deviation(near, level), count

def surface_band(offset: np.ndarray, gate: float, spine: np.ndarray | None = None) -> tuple[float, float]:
    """Robust level and spread (3 sigma) of the radial offsets from the outer wall, within the gate.

    The band level +- spread is where this cloud's outer-wall points lie, cut faces and flying pixels
    mostly outside. spine: (N,) bool, measure on these points only (when at least 8 of them are near).
    """
    if spine is not None and spine.shape != offset.shape:  # (the kernel does not check its indices)
        raise ValueError(f"spine has shape {spine.shape}, the offsets {offset.shape}")
    level, deviation, count = _level_and_deviation(offset, gate, np.zeros(0, bool) if spine is None else spine)
    if count < 8:
        return 0.0, gate
    spread = 3.0 * (MAD_TO_SIGMA * deviation)
    return float(level), min(max(spread, 1e-6), gate)

def band_gate(level: float, spread: float, gate: float, least: float = 0.0) -> float:
    """How far from the outer radius a wall point may lie and still be the wall (m): the band's level (surface_band)
    off r_o plus its spread, at least `least`, never wider than `gate`. A gate a millimetre wide lets in pixels a
    stereo matcher mixed with the background behind the robot; the band leaves them out."""
    return min(gate, max(abs(level) + spread, least))
