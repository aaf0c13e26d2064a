"""Notches: gaps of outer-surface coverage on the notched side, measured in the tube's own coordinates.

In tube coordinates (arc length s of a point's cross-section, angle about the axis from the notch side) a
notch is the interval [s_start, s_end] of its cut at every angle where the cut opens the outer surface
(|angle| < gap_half_angle): its faces are the normal planes of the centreline at its ends. The coverage
profile along s of the outer-surface points in that angular window, smoothed by a kernel of about half a
pixel footprint, falls to half its local plateau exactly at an edge (each depth pixel stands for a cell of
one footprint), which gives the edges to a fraction of a pixel.

Width as in contracts.md: the gap on the outer surface line facing the notches, s_n (1 - kappa r_o)
= s_n - theta r_o, with theta the bend of the centreline across the notch.

Public API:
    coverage_edges(s, lo, hi, kernel) -> (profile grid, density)
    detect_notches(coords, centerline, geometry, gate, footprint, settings) -> list[Notch]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d, percentile_filter

from ntcr_recon.core.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.robot import TubeGeometry


@dataclass(frozen=True)
class Notch:
    index: int            # position in the robot's notch order (0 = nearest the base)
    center_s: float       # m, centreline arc length of the notch centre
    start_s: float
    end_s: float
    width: float          # m, outer-surface gap facing the notches
    bend: float | None    # rad, the centreline's turn across the notch


def coverage_profile(s: np.ndarray, lo: float, hi: float, cell: float, kernel: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Points per metre along s on a grid of `cell`, smoothed by a Gaussian of width `kernel`."""
    edges = np.arange(lo, hi + cell, cell)
    counts, _ = np.histogram(s, bins=edges)
    density = gaussian_filter1d(counts.astype(float), max(kernel / cell, 0.5), mode="constant") / cell
    return 0.5 * (edges[:-1] + edges[1:]), density


def _crossing(grid: np.ndarray, density: np.ndarray, level: np.ndarray, i: int, j: int) -> float:
    """Sub-cell s where density crosses level between grid cells i and j (linear interpolation)."""
    a, b = density[i] - level[i], density[j] - level[j]
    if a == b:
        return float(0.5 * (grid[i] + grid[j]))
    t = np.clip(a / (a - b), 0.0, 1.0)
    return float(grid[i] + t * (grid[j] - grid[i]))


def detect_notches(coords: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry, gate: float,
                   footprint: float, kernel_px: float, min_width_fraction: float, tip_s: float,
                   observed: TubeCoordinates | None = None) -> list[Notch]:
    """Gaps in outer-surface coverage within the open angular window, matched to the robot's notches.

    observed: the points' coordinates as measured, when `coords` are those points moved (e.g. along their
    viewing rays onto the wall): which points lie on the outer wall is judged by where they were seen, as a
    cut face seen through a notch would otherwise be moved onto the wall inside the notch and fill it.
    """
    r_o = geometry.outer_radius
    footprint = footprint if footprint > 0 else r_o / 8.0
    # the window where a notch removes the outer surface, less the angular uncertainty of a point
    margin = np.arcsin(min(1.0, 2.0 * footprint / r_o))
    window = geometry.gap_half_angle - margin
    # Only points on the outer wall count: the spines' cut faces, seen through an obliquely viewed notch,
    # lie exactly at its edges but inside the wall and would pile up there. The band is the outer wall's
    # own measured spread (robust) about its measured level (stereo flattening), within the gate.
    offset = (coords if observed is None else observed).radius - r_o
    near = offset[np.abs(offset) < gate]
    if near.size < 10:
        return []
    offset = offset - (float(np.median(near)) if observed is not None else 0.0)
    band = min(gate, max(3.0 * 1.4826 * float(np.median(np.abs(offset[np.abs(offset) < gate]))), footprint / 2))
    on_outer = (np.abs(offset) < band) & (np.abs(coords.angle) < window)
    on_outer &= (coords.s > 0) & (coords.s < tip_s)
    s = coords.s[on_outer]
    if len(s) < 10:
        return []
    cell = footprint / 8.0
    grid, density = coverage_profile(s, 0.0, tip_s, cell, kernel_px * footprint)
    # local plateau: the upper quartile over one notch pitch (a gap fills at most half of it)
    span = max(int(round(geometry.notch_pitch / cell)), 3)
    plateau = percentile_filter(density, 75, size=2 * span + 1, mode="nearest")
    level = 0.5 * plateau
    low = density < level
    # runs of low coverage
    change = np.diff(np.concatenate([[0], low.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(change == 1), np.flatnonzero(change == -1) - 1
    gaps = []
    for first, last in zip(starts, ends, strict=True):
        if first == 0 or last == len(grid) - 1:
            continue  # touches the base or the tip: not a notch
        start = _crossing(grid, density, level, first - 1, first)
        end = _crossing(grid, density, level, last, last + 1)
        if end - start < min_width_fraction * geometry.notch_width:
            continue
        if end - start > 2.0 * geometry.notch_width + 2 * footprint:
            continue  # a hole in the data wider than any notch
        gaps.append((start, end))
    return _assign(gaps, centerline, geometry)


def _assign(gaps: list[tuple[float, float]], centerline: Centerline, geometry: TubeGeometry) -> list[Notch]:
    """Index the gaps by the robot's notch order and measure width and bend."""
    if not gaps:
        return []
    r_o, pitch = geometry.outer_radius, geometry.notch_pitch
    centres = np.array([(a + b) / 2 for a, b in gaps])
    # Expected deformed centres: bending shortens the centreline by ybar * theta per notch; the bend up to
    # each point comes from the estimated centreline.
    undeformed = geometry.notch_centers_s
    turned = np.abs(np.atleast_1d(centerline.bend_angle(0.0, np.minimum(undeformed, centerline.length))))
    expected = undeformed - geometry.neutral_axis_offset * turned
    index = np.argmin(np.abs(centres[:, None] - expected[None, :]), axis=1)
    order = np.argsort(centres)
    chosen, used = [], set()
    for g in order:  # a handful of gaps: the first (nearest the base) claims an expected notch
        i = int(index[g])
        if i not in used and abs(centres[g] - expected[i]) <= pitch / 2:
            used.add(i)
            chosen.append(g)
    if not chosen:
        return []
    chosen = np.array(chosen)
    low = np.maximum(centres[chosen] - pitch / 2, 0.0)
    high = np.minimum(centres[chosen] + pitch / 2, centerline.length)
    bends = np.atleast_1d(centerline.bend_angle(low, np.maximum(high, low)))
    notches = []
    for g, bend in zip(chosen, bends, strict=True):
        start, end = gaps[g]
        width = (end - start) - bend * r_o  # s_n (1 - kappa r_o) with kappa s_n = theta
        notches.append(Notch(int(index[g]), float(centres[g]), float(start), float(end), float(max(width, 0.0)),
                             float(bend)))
    return notches
