"""Outline check: the centreline against the middle of the tube's outline in each camera's view.

The fit and the alignment both place the axis by the depth of the wall the cameras see. A matcher's bias beside
the notches moves that wall, and where it moves it far (spines narrower than the matcher's window, no pixel
clear of the slots) the fit and the alignment follow it together, and no figure built on the wall's depth shows
it. Where the tube lies across a camera's view, the extent of that camera's wall points across its view is the
tube's diameter, centred on the axis whatever their depth: its middle is a second observable of the axis across
the view. It is coarser than the wall's depth (edge pixels are mixed with the background; a cut at the outline
narrows it): on a sound axis its RMS offset stays within a pixel footprint. It is used as a check, not to place
the axis: an axis further from it than OUTLINE_TOLERANCE_PX footprints went astray by about that much.

The alignment rests on the wall facing each camera, which places the axis across the view only by the wall's
slope (weakly: the facing points lie within about 25 deg of the line of sight); the fit's circles rest on the whole
wall seen, its sides included. Where the aligned axis went astray and the fit did not, the fit's placement across
the views is taken (across_views_from), and the alignment's along them kept.
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.robot.geometry import TubeGeometry

# An axis whose RMS offset from the outlines' middles exceeds this many pixel footprints went astray: on a sound
# axis it stays within one (0.04-0.23 mm, 0.3-0.95 px, over 99 of 100 simulated scenes at 75-110 mm; the 100th,
# 2.25 px, was 0.47 mm off).
OUTLINE_TOLERANCE_PX = 1.5

# The extent across a view is read between these percentiles of the points' offsets: the outermost points are
# the edge pixels a matcher mixed with the background, kept or dropped by a margin's whim.
EXTENT_PERCENTILES = (1.0, 99.0)

# A window's outline counts when its extent is within this share of the radius of the tube's diameter: the tube
# seen whole across the view (not cut short by the end, a clamp or an occlusion, nor merged with a neighbour).
WIDTH_TOLERANCE_RADII = 0.5

# The tube lies across a camera's view where its axis is at least this far from the camera's line of sight.
LEAST_CROSSING = np.radians(45.0)


# A camera adds its direction across its view to those of the cameras before it when that direction lies more than
# 30 deg from theirs (opposed cameras share one: their views' depth stays the alignment's).
LEAST_NEW_DIRECTION = np.sin(np.radians(30.0))


def went_astray(offset: float | None, footprint: float) -> bool:
    """Whether an axis whose outline offset (m, outline_offset) is `offset` went astray."""
    return offset is not None and offset > OUTLINE_TOLERANCE_PX * footprint


def across_views_from(reference: Centerline, centerline: Centerline, origins: np.ndarray) -> Centerline:
    """The centreline placed across the cameras' views where the reference is, and left along them where it was.

    Per sample, its offset to the reference's point at the same s is projected onto the directions across the
    cameras' views (tangent x the direction to the camera, orthonormalised in the cameras' order; LEAST_NEW_DIRECTION)
    and added. origins: the cameras' optical centres."""
    points, tangents = centerline.points, centerline.tangents
    offset = reference.frames_at(centerline.s)[0] - points
    basis: list[np.ndarray] = []
    moved = np.zeros_like(points)
    for origin in np.asarray(origins, float):
        view = origin - points
        view -= tangents * np.einsum("ij,ij->i", view, tangents)[:, None]
        across = np.cross(tangents, view / np.maximum(np.linalg.norm(view, axis=1), 1e-12)[:, None])
        for direction in basis:
            across -= direction * np.einsum("ij,ij->i", across, direction)[:, None]
        length = np.linalg.norm(across, axis=1)
        across = np.where((length > LEAST_NEW_DIRECTION)[:, None], across / np.maximum(length, 1e-12)[:, None], 0.0)
        basis.append(across)
        moved += across * np.einsum("ij,ij->i", offset, across)[:, None]
    step = float(centerline.s[1] - centerline.s[0])
    return Centerline.from_points(points + moved, centerline.binormals[0], step)


def outline_offset(coords: TubeCoordinates, frames: tuple, xyz: np.ndarray, viewpoints: np.ndarray,
                   camera: np.ndarray, geometry: TubeGeometry, gate: float, end_s: float,
                   minimum_points: int = 30) -> float | None:
    """RMS (m), over windows of a notch pitch up to end_s and the cameras that see the tube across their view
    there, of how far across the view the middle of the camera's wall points' extent lies from the axis; None
    where no window's outline was seen whole. coords, frames: the points' projection onto the centreline checked;
    viewpoints: each point's camera's optical centre; camera: each point's camera index; gate: the wall's."""
    camera = np.ascontiguousarray(camera, np.intp)
    middles = _middles(coords, frames, xyz, viewpoints, camera, int(camera.max()) + 1, geometry, gate, end_s,
                       minimum_points)
    middles = middles[np.isfinite(middles)]
    return float(np.sqrt(np.mean(middles ** 2))) if len(middles) else None


def outline_rigid_offset(coords: TubeCoordinates, frames: tuple, xyz: np.ndarray, viewpoints: np.ndarray,
                         camera: np.ndarray, cameras: int, geometry: TubeGeometry, end_s: float,
                         minimum_windows: int = 4, minimum_points: int = 30) -> tuple[float, float] | None:
    """How far apart two opposed cameras' outlines lie across their views (m), the mean over the windows where both
    saw the tube's outline whole of the sum of their middles' offsets from the axis (a shift of one camera relative
    to the other reads with the same sign in both views), and that mean's standard error; None for other than two
    cameras or fewer than minimum_windows such windows. Every point within an outer radius of the wall counts (not
    the wall's gate): a camera whose pose in the rig file is a millimetre or more off has its whole outline that far
    across its view, where the wall's gate and the limbs' search (limb_profile.SEARCH_PX) no longer reach it. Across its
    view a camera's outline does not depend on its depth, so a pose off the camera's moves it alike in every window
    (trace.rigid_offset); only windows both cameras saw whole count, so that a stretch one sees end-on or cut
    short does not pass for an offset."""
    if cameras != 2:
        return None
    middles = _middles(coords, frames, xyz, viewpoints, np.ascontiguousarray(camera, np.intp), cameras, geometry,
                       geometry.outer_radius, end_s, minimum_points)
    summed = middles.reshape(-1, cameras).sum(axis=1)
    summed = summed[np.isfinite(summed)]
    if len(summed) < minimum_windows:
        return None
    return abs(float(np.mean(summed))), float(np.std(summed, ddof=1) / np.sqrt(len(summed)))


def _middles(coords: TubeCoordinates, frames: tuple, xyz: np.ndarray, viewpoints: np.ndarray, camera: np.ndarray,
             cameras: int, geometry: TubeGeometry, gate: float, end_s: float, minimum_points: int) -> np.ndarray:
    """_outline_middles over the points within `gate` of the wall, windows of a notch pitch."""
    position, tangent, _, _ = frames
    return _outline_middles(coords.s, coords.radius, np.ascontiguousarray(xyz, dtype=float), position, tangent,
                            np.ascontiguousarray(viewpoints, dtype=float), camera, cameras, geometry.outer_radius,
                            gate, end_s, geometry.notch_pitch, np.cos(LEAST_CROSSING), minimum_points,
                            *EXTENT_PERCENTILES, WIDTH_TOLERANCE_RADII)


@jit
def _outline_middles(s, radius, xyz, position, tangent, viewpoints, camera, cameras, outer_radius, gate, end_s,
                     window, least_crossing_cosine, minimum_points, low_percentile, high_percentile,
                     width_tolerance_radii):
    """Per window of s and camera (window x cameras + camera) the middle of the wall points' extent across the
    camera's view, about the axis; NaN where under minimum_points or the extent is not the tube's diameter."""
    count = s.shape[0]
    windows = max(int(np.ceil(end_s / window)), 1)
    offset = np.empty(count)
    group = np.full(count, -1, np.intp)
    sizes = np.zeros(windows * cameras, np.intp)
    for i in range(count):
        if not (abs(radius[i] - outer_radius) < gate and 0.0 <= s[i] < end_s):
            continue
        v0, v1 = viewpoints[i, 0] - position[i, 0], viewpoints[i, 1] - position[i, 1]
        v2 = viewpoints[i, 2] - position[i, 2]
        t0, t1, t2 = tangent[i, 0], tangent[i, 1], tangent[i, 2]
        along = v0 * t0 + v1 * t1 + v2 * t2
        a0, a1, a2 = v0 - along * t0, v1 - along * t1, v2 - along * t2
        distance = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if not (distance > 0.0 and distance > least_crossing_cosine * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)):
            continue  # the tube runs along this camera's line of sight here: no outline across it
        # across the view: tangent x the direction to the camera
        c0, c1, c2 = (t1 * a2 - t2 * a1) / distance, (t2 * a0 - t0 * a2) / distance, (t0 * a1 - t1 * a0) / distance
        offset[i] = ((xyz[i, 0] - position[i, 0]) * c0 + (xyz[i, 1] - position[i, 1]) * c1
                     + (xyz[i, 2] - position[i, 2]) * c2)
        group[i] = min(int(s[i] / window), windows - 1) * cameras + camera[i]
        sizes[group[i]] += 1
    starts = np.zeros(len(sizes) + 1, np.intp)
    starts[1:] = np.cumsum(sizes)
    filled = starts[:-1].copy()
    ordered = np.empty(starts[-1])
    for i in range(count):
        if group[i] >= 0:
            ordered[filled[group[i]]] = offset[i]
            filled[group[i]] += 1
    middles = np.full(len(sizes), np.nan)
    for g in range(len(sizes)):
        if sizes[g] < minimum_points:
            continue
        run = np.sort(ordered[starts[g]:starts[g + 1]])
        low, high = _percentile_of_sorted(run, low_percentile), _percentile_of_sorted(run, high_percentile)
        if abs(high - low - 2.0 * outer_radius) < width_tolerance_radii * outer_radius:
            middles[g] = (low + high) / 2.0
    return middles


@jit
def _percentile_of_sorted(values, percentile):
    """np.percentile (linear) of ascending values."""
    position = percentile / 100.0 * (len(values) - 1)
    below = int(np.floor(position))
    above = min(below + 1, len(values) - 1)
    fraction = position - below
    return values[below] * (1.0 - fraction) + values[above] * fraction
