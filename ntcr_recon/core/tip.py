"""Tip: where the tube seen in the cloud ends, judged by what the cameras can see there.

The end is where the outer wall stops: per slab of arc length (one pixel footprint), the angular sectors
about the axis holding wall points. Which sectors a camera can see at all follows from its pose and the
local tangent (a sector whose outward direction turns more than `grazing` from the camera is not seen),
so occupancy is counted over the visible sectors only: a distal part pointing at one camera, which the
other hardly sees, still counts as tube. Where no sector is visible (the tube points straight at a camera)
the wall showing in a few sectors counts. The search never runs past the robot's known length plus a margin.

The end is then refined below a slab: per occupied sector near the coarse end the last wall point, the
median of those. A stereo matcher erodes (or smears) the rim at the tip as it does the silhouettes, so the
erosion measured on each camera's silhouettes of plain tube is given back (`silhouette_erosion`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ntcr_recon.core.compiled import jit
from ntcr_recon.core.wall import surface_band

if TYPE_CHECKING:  # centerline.py imports this module
    from ntcr_recon.core.centerline import Centerline, TubeCoordinates

GRAZING = np.radians(80.0)  # a surface turned further than this from a camera gives it (almost) no depth
MIN_SECTORS_WHEN_UNSEEN = 3  # of the ring's sectors, holding wall points where no sector faces a camera


def visible_sectors(centerline: Centerline, s: np.ndarray, viewpoints: np.ndarray, sectors: int,
                    grazing: float = GRAZING) -> np.ndarray:
    """(len(s), sectors) bool: some camera (optical centres `viewpoints` (C, 3)) sees the sector's wall."""
    position, _, normal, binormal = centerline.frames_at(s)
    angles = -np.pi + (np.arange(sectors) + 0.5) * (2 * np.pi / sectors)
    return _visible_kernel(position, normal, binormal, np.cos(angles), np.sin(angles),
                           np.atleast_2d(viewpoints).astype(float), np.cos(grazing))


@jit
def _visible_kernel(position, normal, binormal, cos_angles, sin_angles, viewpoints, least_cosine):
    """Per slab (its frame) and sector (its angle), whether the sector's outward direction
    cos normal + sin binormal is within acos(least_cosine) of the direction to some viewpoint."""
    seen = np.zeros((position.shape[0], cos_angles.shape[0]), np.bool_)
    for i in range(position.shape[0]):
        for origin in viewpoints:
            v0, v1, v2 = origin[0] - position[i, 0], origin[1] - position[i, 1], origin[2] - position[i, 2]
            length = max(np.sqrt(v0 * v0 + v1 * v1 + v2 * v2), 1e-12)
            along_normal = (v0 * normal[i, 0] + v1 * normal[i, 1] + v2 * normal[i, 2]) / length
            along_binormal = (v0 * binormal[i, 0] + v1 * binormal[i, 1] + v2 * binormal[i, 2]) / length
            for k in range(cos_angles.shape[0]):
                seen[i, k] |= cos_angles[k] * along_normal + sin_angles[k] * along_binormal > least_cosine
    return seen


def tube_end(coords: TubeCoordinates, radius: float, gate: float, cell: float, sectors: int = 24,
             max_s: float = np.inf, centerline: Centerline | None = None, viewpoints: np.ndarray | None = None,
             spine: np.ndarray | None = None, band: tuple[float, float] | None = None) -> float:
    """Arc length where the tube seen in the cloud ends, to a fraction of `cell` (see the module docstring).

    Without `centerline` and `viewpoints` every sector counts as visible. spine: points to measure the wall
    band on (see wall.surface_band); band: that band (level, spread) when the caller has it already.
    """
    offset = coords.radius - radius
    level, spread = surface_band(offset, gate, spine) if band is None else band
    on_wall = (np.abs(offset - level) <= spread) & (coords.s >= 0) & (coords.s <= max_s)
    if np.count_nonzero(on_wall) < 8:
        return float(min(coords.s.max(initial=0.0), max_s))
    s_wall = coords.s[on_wall]
    slab = (s_wall / cell).astype(np.intp)
    sector = ((coords.angle[on_wall] + np.pi) / (2 * np.pi) * sectors).astype(np.intp) % sectors
    grid = np.zeros((slab.max() + 2, sectors), dtype=bool)
    grid[slab, sector] = True
    if centerline is not None and viewpoints is not None:
        visible = visible_sectors(centerline, (np.arange(len(grid)) + 0.5) * cell, viewpoints, sectors)
        seen = np.count_nonzero(grid & visible, axis=1)
        count = np.count_nonzero(visible, axis=1)
        # sectors visible to no camera say nothing; a slab with few visible (under a quarter of the ring: the
        # tube points at a camera) is tube where its wall shows in a few sectors at least (a stray flying
        # pixel is not)
        some = (np.count_nonzero(grid, axis=1) >= MIN_SECTORS_WHEN_UNSEEN).astype(float)
        occupied = np.where(count >= sectors // 4, seen / np.maximum(count, 1), some)
    else:
        occupied = np.count_nonzero(grid, axis=1) / float(sectors)
    occupied = np.convolve(occupied, np.ones(3) / 3.0, mode="same")
    half = 0.5 * float(np.median(occupied[occupied > 0]))
    above = np.flatnonzero(occupied >= half)
    last = int(above[-1])
    a, b = occupied[last] - half, occupied[last + 1] - half if last + 1 < len(occupied) else -half
    fraction = a / (a - b) if a != b else 0.5
    coarse = (last + 0.5 + float(np.clip(fraction, 0.0, 1.0))) * cell
    return float(min(coarse, max_s))


def silhouette_erosion(coords: TubeCoordinates, frames: tuple, camera: np.ndarray, origins: np.ndarray,
                       radius: float, usable: np.ndarray, quantile: float = 0.98) -> float:
    """How much of the tube's rim each camera loses at a depth edge (m), measured on its silhouettes.

    A stereo matcher drops or smears the pixels next to a depth edge. The tube's true half-width across
    each camera's view is its outer radius, and depth pixels sample the lateral coordinate uniformly, so
    the rim lost is r_o - q-quantile(|lateral|) / q over the camera's points on plain tube (usable: not in
    a notch, not at the ends). The median over cameras is returned; 0 when it cannot be measured.
    """
    position, _, normal, binormal = frames
    estimates = []
    for index in np.unique(camera):
        mine = usable & (camera == index)
        if np.count_nonzero(mine) < 50:
            continue
        view = origins[index] - position[mine]
        view_x = (view * normal[mine]).sum(axis=1)
        view_y = (view * binormal[mine]).sum(axis=1)
        length = np.hypot(view_x, view_y)
        lateral = (view_x * coords.y[mine] - view_y * coords.x[mine]) / np.maximum(length, 1e-12)
        estimates.append(radius - float(np.quantile(np.abs(lateral), quantile)) / quantile)
    return max(float(np.median(estimates)), 0.0) if estimates else 0.0


def give_back_erosion(tip_s: float, coords: TubeCoordinates, frames: tuple, camera: np.ndarray, origins: np.ndarray,
                      radius: float, gate: float, notch_intervals: list[tuple[float, float]], cell: float) -> float:
    """The tip moved out by the rim erosion measured on plain tube (away from the base, the tip and notches).

    The tip's rim, an edge seen against the background, loses what the tube's silhouettes lose to the
    stereo matcher.
    """
    plain = (coords.s > 2 * radius) & (coords.s < tip_s - 2 * radius)
    for start, end in notch_intervals:
        plain &= (coords.s < start - 2 * cell) | (coords.s > end + 2 * cell)
    offset = coords.radius - radius
    level, spread = surface_band(offset, gate, plain)
    plain &= np.abs(offset - level) <= spread
    return tip_s + silhouette_erosion(coords, frames, camera, origins, radius, plain)


def cap_faces_a_camera(centerline: Centerline, tip_s: float, viewpoints: np.ndarray, least_sine: float) -> bool:
    """Some camera looks onto the tip's end cap: the tangent at the tip turned towards it by at least
    asin(least_sine) from across its view (the cap's diameter then shows foreshortened by that sine)."""
    position, tangent, _, _ = centerline.frames_at(np.array([tip_s]))
    view = np.atleast_2d(viewpoints) - position
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return bool(np.any(view @ tangent[0] > least_sine))


def end_cap_plane(coords: TubeCoordinates, inner_radius: float, outer_radius: float, coarse_end: float,
                  reach: float, cell: float) -> float | None:
    """Arc length of the end cap where a camera looks onto it: the cap is a disc of the tube's cross-section,
    so its points pile up at one s (a peak of the points' density along s within the annulus), while the wall
    near a tube pointing at the camera is seen thinly and flying pixels trail behind the cap. None when no
    such peak stands out within `reach` of the coarse end."""
    near = (np.abs(coords.s - coarse_end) < reach) & (coords.radius > 0.5 * inner_radius)
    near &= coords.radius < outer_radius + cell
    if np.count_nonzero(near) < 20:
        return None
    s = coords.s[near]
    edges = np.arange(coarse_end - reach, coarse_end + reach + cell, cell)
    counts, _ = np.histogram(s, bins=edges)
    peak = int(np.argmax(counts))
    if counts[peak] < max(10, 4.0 * float(np.median(counts))):
        return None
    in_peak = (s >= edges[max(peak - 1, 0)]) & (s < edges[min(peak + 2, len(edges) - 1)])
    return float(np.median(s[in_peak]))
