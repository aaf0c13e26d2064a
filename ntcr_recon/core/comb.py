"""The robot's known comb of notches laid along an estimated centreline: where each notch should be.

The configuration gives the notch count, pitch and width in the undeformed robot; bending shortens the
tube's centreline by ybar * theta per notch (the neutral axis keeps its length, the centreline lies ybar
nearer the notches), so the k-th notch centre sits at its undeformed arc length less ybar times the
centreline's turn up to it. The turn comes from the estimated centreline, so the comb bends with it.
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.compiled import jit
from ntcr_recon.core.geometry import TubeGeometry


def expected_centres(geometry: TubeGeometry, centerline) -> np.ndarray:
    """(K,) centreline arc length of each notch centre, the comb bent by the centreline's turn."""
    undeformed = geometry.notch_centers_s
    turned = np.abs(np.atleast_1d(centerline.bend_angle(0.0, np.minimum(undeformed, centerline.length))))
    return undeformed - geometry.neutral_axis_offset * turned


def cut_intervals(geometry: TubeGeometry, centerline, margin: float) -> np.ndarray:
    """(K, 2) [start, end] of each expected notch grown by `margin` on both sides (the undeformed width,
    the widest a notch gets)."""
    centres = expected_centres(geometry, centerline)
    half = geometry.notch_width / 2.0 + margin
    return np.stack([centres - half, centres + half], axis=1)


def inside_intervals(s: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """(N,) bool: s lies in one of the sorted, disjoint (K, 2) intervals."""
    return _inside_kernel(np.ascontiguousarray(s, dtype=float), np.ascontiguousarray(intervals[:, 0], dtype=float),
                          np.ascontiguousarray(intervals[:, 1], dtype=float))


@jit
def _inside_kernel(s, starts, ends):
    """Whether each s lies in [starts[k], ends[k]] of the last interval starting at or before it."""
    inside = np.zeros(s.shape[0], np.bool_)
    if starts.shape[0] == 0:
        return inside
    for i in range(s.shape[0]):
        k = max(np.searchsorted(starts, s[i], side="right") - 1, 0)
        inside[i] = starts[k] <= s[i] <= ends[k]
    return inside
