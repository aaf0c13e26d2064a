"""Density of points along the tube's arc length on a fine grid: where notch edges and the tube's end are read.

Each depth pixel stands for a cell of one footprint, so the density, smoothed by a kernel of about half a
footprint, falls to half its plateau exactly at an edge of what was seen (core.relocation.notches, core.relocation.tip).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ntcr_recon.core.base.compiled import jit


def coverage_profile(s: np.ndarray, lo: float, hi: float, cell: float, kernel: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Points per metre along s on a grid of `cell`, smoothed by a Gaussian of width `kernel`."""
    edges = np.arange(lo, hi + cell, cell)
    counts = _counts_in_bins(np.ascontiguousarray(s, dtype=float), edges)
    density = gaussian_filter1d(counts, max(kernel / cell, 0.5), mode="constant") / cell
    return 0.5 * (edges[:-1] + edges[1:]), density


@jit
def _counts_in_bins(values, edges):
    """np.histogram(values, bins=edges)[0] as floats, for evenly spaced edges: each value's bin from its
    distance to the first edge, then checked against the bin's own edges (as numpy bins them: [left, right),
    the last bin closed), in one pass instead of numpy's sort."""
    bins = edges.shape[0] - 1
    counts = np.zeros(max(bins, 0))
    if bins < 1:
        return counts
    first, last = edges[0], edges[bins]
    step = (last - first) / bins
    for v in values:
        if not first <= v <= last:  # (outside, or NaN)
            continue
        i = min(max(int((v - first) / step), 0), bins - 1)
        while i > 0 and v < edges[i]:
            i -= 1
        while i < bins - 1 and v >= edges[i + 1]:
            i += 1
        counts[i] += 1.0
    return counts
