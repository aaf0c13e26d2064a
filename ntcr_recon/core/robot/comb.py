"""The robot's known comb of notches laid along an estimated centreline: where each notch should be.

The configuration gives the notch count, pitch and width in the undeformed robot; bending shortens the
tube's centreline by ybar * theta per notch (the neutral axis keeps its length, the centreline lies ybar
nearer the notches), so the k-th notch centre sits at its undeformed arc length less ybar times the
centreline's turn up to it. The turn comes from the estimated centreline, so the comb bends with it.
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.robot.geometry import TubeGeometry

# expected_centres' fixed point: at most this many passes, done when no centre moves more than the tolerance (m);
# 283 deg of bend takes 8 (a quarter of each move is left after a pass)
COMB_ITERATIONS = 20
COMB_TOLERANCE = 1e-6


def expected_centres(geometry: TubeGeometry, centerline) -> np.ndarray:
    """(K,) centreline arc length of each notch centre, the comb bent by the centreline's turn: each centre lies
    short of its undeformed place by ybar times the turn up to itself, the centre where that holds (a fixed point:
    the turn taken at the undeformed place counts the notches beyond it once the comb has shortened by a pitch, and
    put a 280 deg bend's centres 0.7 mm off). The iteration contracts by ybar times a notch's curvature, a
    quarter for a notch closed to its limit.

    Remembered on the centreline (read-only), per geometry: a relocation lays the comb on one axis for each of
    its steps, eight to twelve times a frame, and the fixed point costs 30 us."""
    remembered = centerline.__dict__.setdefault("_expected_centres", {})  # a frozen dataclass: its own dict
    centres = remembered.get(geometry)
    if centres is None:
        centres = remembered[geometry] = _bent_comb(geometry, centerline)
        centres.flags.writeable = False
    return centres


def _bent_comb(geometry: TubeGeometry, centerline) -> np.ndarray:
    """expected_centres' fixed point."""
    undeformed = geometry.notch_centers_s
    centres = undeformed
    for _ in range(COMB_ITERATIONS):
        turned = np.abs(np.atleast_1d(centerline.bend_angle(0.0, np.minimum(centres, centerline.length))))
        previous, centres = centres, undeformed - geometry.neutral_axis_offset * turned
        if np.max(np.abs(centres - previous), initial=0.0) < COMB_TOLERANCE:
            break
    return centres


def cut_intervals(geometry: TubeGeometry, centerline, margin: float) -> np.ndarray:
    """(K, 2) [start, end] of each expected notch grown by `margin` on both sides (the undeformed width,
    the widest a notch gets)."""
    centres = expected_centres(geometry, centerline)
    half = geometry.notch_width / 2.0 + margin
    return np.stack([centres - half, centres + half], axis=1)


def near_cuts(s: np.ndarray, geometry: TubeGeometry, centerline, margin: float) -> np.ndarray:
    """(N,) bool: arc length s lies within an expected notch grown by `margin` along s (cut_intervals)."""
    return inside_intervals(s, cut_intervals(geometry, centerline, margin))


def clear_of_cuts(coords, geometry: TubeGeometry, centerline, margin: float,
                  near_cut: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the point (TubeCoordinates, x towards the notch side) lies where no expected cut opens the
    outer wall: outside every notch grown by `margin` along s (near_cuts, unless the caller has it), or round the
    tube from the notch side beyond the gap's half-angle grown by as much, on the backbone a cut leaves whole."""
    if near_cut is None:
        near_cut = near_cuts(coords.s, geometry, centerline, margin)
    opening = np.abs(coords.angle) < geometry.gap_half_angle + margin / geometry.outer_radius
    return ~(near_cut & opening)


def inside_intervals(s: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """(N,) bool: s lies in one of the (K, 2) [start, end] intervals (ends included)."""
    s = np.asarray(s, dtype=float)
    intervals = np.asarray(intervals, dtype=float).reshape(-1, 2)
    return _inside_any(s.ravel(), np.ascontiguousarray(intervals[:, 0]),
                       np.ascontiguousarray(intervals[:, 1])).reshape(s.shape)


@jit
def _inside_any(s, starts, ends):
    """Each value tested against every interval, branch-free: for the comb's 10-20 intervals this compiles to
    vector compares, six times faster than a binary search (numpy's searchsorted or a compiled one), whose
    branches the unsorted values mispredict."""
    inside = np.empty(s.shape[0], np.bool_)
    for i in range(s.shape[0]):
        value, found = s[i], False
        for k in range(starts.shape[0]):
            found |= (starts[k] <= value) & (value <= ends[k])
        inside[i] = found
    return inside
