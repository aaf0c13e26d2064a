"""How far each camera alone puts the axis across its line of sight from the aligned one, and where no camera
holds enough trusted wall to place it (cross_view_spread): what bounds the centreline's uncertainty, and a rig
file's pose off the camera's (CrossView.offsets)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.relocation.alignment import WallTrust, camera_window_sums
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.robot.comb import clear_of_cuts


@dataclass(frozen=True)
class CrossView:
    """What each camera's trusted wall says about the fused axis (cross_view_spread)."""
    spread: float | None  # m, RMS over windows and cameras of each camera's own axis across its view; None: none
    unsupported: tuple[tuple[float, float], ...] = ()  # s intervals (m) of two windows or more where no camera
                                                         # holds enough trusted wall points to place the axis
    distal: float | None = None  # m, the same RMS over the cameras in the last window where any places the axis
    # per camera (in camera order) its shift's mean over the windows and that mean's standard error (m); None for a
    # camera placing the axis in fewer than MIN_OFFSET_WINDOWS windows. What the windows share is rigid: a pose
    # in the rig file off the camera's (matcher noise varies window to window)
    offsets: tuple[tuple[float, float] | None, ...] = ()
    # how much two cameras' walls apart vary along the tube (m, half the standard deviation over the windows both
    # placed of the sum of their wall levels about the fused axis; None: not two cameras, or fewer than
    # MIN_OFFSET_WINDOWS windows): each window's axis lies midway between the walls, off by half their depth
    # biases' difference, which no depth measures; the biases varying independently, it varies as their sum does
    level_scatter: float | None = None


MIN_OFFSET_WINDOWS = 4  # windows a camera's mean shift across its view is taken over, at least


def cross_view_spread(centerline: Centerline, coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray,
                      camera: np.ndarray, cameras: int, trust: WallTrust, minimum_points: int = 10,
                      min_sine_spread: float = 0.05) -> CrossView:
    """How far each camera alone puts the axis across its line of sight from the centreline given (m, RMS over
    windows of a notch pitch and cameras; None when no window holds enough trusted points of any camera), and
    where no camera holds enough trusted points to place the axis at all.

    Across its line of sight a camera places the axis by itself: a shift b that way raises the wall it sees on
    one side of its view and lowers it on the other, offset = b sin(a) + level (a: the view angle, the shift
    along the line of sight and the level alike near a = 0). Each camera's b on the trusted points of each
    window, about the aligned centreline, is what it disagrees with the fit: stereo depth beside the notches is
    not symmetric about a view (a matcher's window reaches the slots on one side), two cameras then pull the
    axis apart, and the fused axis is known no better than their spread.

    Where no camera sees trusted wall (facing it, on the tube's radius) over two windows or more, the centreline
    there followed whatever points lay near it - flying pixels a matcher mixed with the background, a wall seen
    edge-on - and nothing measured how far off it is: those stretches are `unsupported` (a window counts in
    proportion to its part between the base's and the end's margins; one under half inside is not judged).
    `distal` is the spread in the last window alone: at the free end no window beyond holds the axis, and the
    tip is known across the tube no better than the cameras agree there.
    """
    window, end_s = trust.geometry.notch_pitch, trust.end_s
    away_from_cuts = clear_of_cuts(coords, trust.geometry, centerline, trust.cut_margin)
    sums = camera_window_sums(centerline, coords, frames, viewpoints, camera, cameras, trust, away_from_cuts, window)
    count, sine, sine2, offset, sine_offset = np.moveaxis(sums[:, :, :5], 2, 0)
    unsupported = _unsupported(count.max(axis=1), window, trust.silhouette_margin, end_s, minimum_points)
    spread = count * sine2 - sine * sine  # count^2 x the variance of sin(a)
    solvable = (count >= minimum_points) & (spread > (min_sine_spread * count) ** 2)
    if not np.any(solvable):
        return CrossView(None, unsupported)
    slope = np.full(count.shape, np.nan)
    slope[solvable] = (count * sine_offset - sine * offset)[solvable] / spread[solvable]
    last = slope[np.flatnonzero(solvable.any(axis=1))[-1]]
    offsets = tuple((float(np.mean(b)), float(np.std(b, ddof=1) / np.sqrt(len(b))))
                    if len(b := column[~np.isnan(column)]) >= MIN_OFFSET_WINDOWS else None for column in slope.T)
    # each camera's wall level per window: the offset at sin(a) = 0
    level = (offset - np.nan_to_num(slope) * sine) / np.maximum(count, 1)
    both = np.all(solvable, axis=1) if cameras == 2 else np.zeros(len(count), bool)
    level_scatter = (float(np.std(level[both].sum(axis=1), ddof=1) / 2)
                     if np.count_nonzero(both) >= MIN_OFFSET_WINDOWS else None)
    return CrossView(float(np.sqrt(np.nanmean(slope ** 2))), unsupported,
                     float(np.sqrt(np.nanmean(last ** 2))), offsets, level_scatter)


def _unsupported(best_count: np.ndarray, window: float, margin: float, end_s: float, minimum_points: int
                 ) -> tuple[tuple[float, float], ...]:
    """Runs of two windows or more whose best camera holds under `minimum_points` trusted points (scaled by the
    window's share inside [margin, end_s - margin]; windows under half inside are not judged), as s intervals
    clipped to that range."""
    starts = np.arange(len(best_count)) * window
    inside = np.clip(np.minimum(starts + window, end_s - margin) - np.maximum(starts, margin), 0.0, window) / window
    short = (inside >= 0.5) & (best_count < minimum_points * inside)
    runs, k = [], 0
    while k < len(short):
        if not short[k]:
            k += 1
            continue
        first = k
        while k < len(short) and short[k]:
            k += 1
        if k - first >= 2:
            runs.append((float(max(starts[first], margin)), float(min(starts[k - 1] + window, end_s - margin))))
    return tuple(runs)
