"""Robust statistics over arrays, compiled: median and quantiles by selection, spread by the median absolute
deviation (used by the fusion's depth checks and every relocation step)."""

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
def median_absolute_deviation(values, centre):
    """Median of |values - centre|."""
    return median(np.abs(values - centre))


def robust_spread(values: np.ndarray, centre: float) -> float:
    """sigma estimated from the median absolute deviation about `centre`."""
    return MAD_TO_SIGMA * float(median_absolute_deviation(values, centre)) if values.size else 0.0
