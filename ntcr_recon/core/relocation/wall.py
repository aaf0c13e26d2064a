"""Where this cloud's outer-wall points lie: the robust level and spread of their radial offsets.

Stereo depth puts the seen wall a little off r_o (flattening) and spreads it (noise). Notch interiors (cut
faces, floor, bore) lie well inside, so the band is measured on the points near the wall only (`spine`:
optionally only the points on spines, away from the cuts, so notch interiors cannot widen it).
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.base.compiled import jit

MAD_TO_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation


@jit
def _select(values, k):
    """The k-th smallest of values (k from 0), found by partitioning values in place (Hoare, median-of-three
    pivots); values[:k] end up no larger than it."""
    low, high = 0, values.shape[0] - 1
    while high > low:
        a, b, c = values[low], values[(low + high) // 2], values[high]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = low, high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    return values[k]


@jit
def median(values):
    """The median of values, as np.median (the mean of the two middle values of an even count), by selection
    on a copy (np.median's sort-free partition costs more in numpy's overhead, and numba's is slower still);
    NaN for no values or any NaN among them."""
    if values.shape[0] == 0 or np.isnan(values).any():
        return np.nan
    scratch = values.copy()
    half = scratch.shape[0] // 2
    upper = _select(scratch, half)
    if scratch.shape[0] % 2:
        return upper
    return (scratch[:half].max() + upper) / 2


@jit
def quantile(values, q):
    """np.quantile(values, q) (its default, linear interpolation, to the bit: the same virtual index and the
    same two-sided interpolation), by selection on a copy; NaN for no values or any NaN among them."""
    count = values.shape[0]
    if count == 0 or np.isnan(values).any():
        return np.nan
    scratch = values.copy()
    index = (count - 1) * q
    below = min(max(int(np.floor(index)), 0), count - 1)
    above = min(below + 1, count - 1)
    low = _select(scratch, below)
    high = scratch[below + 1:].min() if above > below else low  # the selection left the larger ones above
    gamma = index - below
    difference = high - low
    return high - difference * (1.0 - gamma) if gamma >= 0.5 else low + difference * gamma


@jit
def _median_absolute_deviation(values, centre):
    """Median of |values - centre|."""
    return median(np.abs(values - centre))


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
    return level, _median_absolute_deviation(near, level), count


def robust_spread(values: np.ndarray, centre: float) -> float:
    """sigma estimated from the median absolute deviation about `centre`."""
    return MAD_TO_SIGMA * float(_median_absolute_deviation(values, centre)) if values.size else 0.0


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
