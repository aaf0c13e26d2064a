"""Reference-guided relocation: every observed point within a gate of the reference surface moves onto it.

The reference is the parametric NTCR swept along the estimated centreline: the outer wall (radius r_o) over
[0, tip], and inside each detected notch the surfaces its cut exposes - the notch floor (the chord plane
x = -d), the bore (r_i) and the spines' cut faces (the normal planes at the notch's ends) - plus the annular
tip cap. Each point is moved to the nearest of the surfaces that exist at its arc length (for the walls:
its radial projection at its arc length, which keeps s and the angle), unless that is farther than the
gate: then it is rejected and counted. The reference normal of each relocated point is kept (outward from
the material) for meshing.

Stereo depth is the uncertain coordinate of a point, its pixel's direction is not: where the camera that
saw a point is known, a point bound for the outer wall moves along its viewing ray to where the ray meets
the wall (`along_rays`), and only falls back to the radial projection when the ray misses the tube (beyond
a silhouette). This undoes the flattening of each camera's face instead of squeezing it radially, and keeps
a notch's edges where the camera saw them even when rays cross the tube obliquely.

Public API:
    along_rays(coords, frames, origins, radius, gate) -> (TubeCoordinates, hit)
    relocate_points(coords, centerline, geometry, notches, tip_s, gate, ray_coords=None) -> RelocatedPoints
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates, unit_direction
from ntcr_recon.core.relocation.notches import Notch
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.surface import (
    PART_CUT_FACE,
    PART_END_CAP,
    PART_INNER_WALL,
    PART_NOTCH_FLOOR,
    PART_OUTER_WALL,
)


@dataclass(frozen=True)
class RelocatedPoints:
    accepted: np.ndarray   # (N,) bool over the input points
    points: np.ndarray     # (A, 3) relocated positions of the accepted points, base frame
    normals: np.ndarray    # (A, 3) reference surface normals, outward
    part: np.ndarray       # (A,) robot.surface.PART_* of the surface each point went to
    distance: np.ndarray   # (A,) how far each point moved
    coordinates: TubeCoordinates | None = None  # tube coordinates of the relocated points

    @property
    def rejected(self) -> int:
        return int(np.count_nonzero(~self.accepted))


@jit
def _along_rays_kernel(s, x, y, position, tangent, normal, binormal, origins, radius, gate):
    """Each point (tube coordinates s, x, y; its frame) moved along its ray from `origins` onto the local
    cylinder of `radius` about the tangent, to the intersection nearer the camera: new (s, x, y), and
    whether the ray meets the cylinder within `gate` (where not, the point keeps its coordinates)."""
    count = s.shape[0]
    moved_s, moved_x, moved_y = np.empty(count), np.empty(count), np.empty(count)
    hit = np.empty(count, np.bool_)
    for i in range(count):
        r0 = position[i, 0] + x[i] * normal[i, 0] + y[i] * binormal[i, 0] - origins[i, 0]
        r1 = position[i, 1] + x[i] * normal[i, 1] + y[i] * binormal[i, 1] - origins[i, 1]
        r2 = position[i, 2] + x[i] * normal[i, 2] + y[i] * binormal[i, 2] - origins[i, 2]
        length = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        r0, r1, r2 = r0 / length, r1 / length, r2 / length
        ray_t = r0 * tangent[i, 0] + r1 * tangent[i, 1] + r2 * tangent[i, 2]
        ray_x = r0 * normal[i, 0] + r1 * normal[i, 1] + r2 * normal[i, 2]
        ray_y = r0 * binormal[i, 0] + r1 * binormal[i, 1] + r2 * binormal[i, 2]
        a = ray_x * ray_x + ray_y * ray_y
        b = x[i] * ray_x + y[i] * ray_y
        c = x[i] * x[i] + y[i] * y[i] - radius * radius
        discriminant = b * b - a * c
        step = (-b - np.sqrt(max(discriminant, 0.0))) / (a if a > 1e-12 else 1.0)
        hit[i] = discriminant >= 0 and a > 1e-12 and abs(step) <= gate
        if not hit[i]:
            step = 0.0
        moved_s[i], moved_x[i], moved_y[i] = s[i] + step * ray_t, x[i] + step * ray_x, y[i] + step * ray_y
    return moved_s, moved_x, moved_y, hit


def along_rays(coords: TubeCoordinates, frames: tuple, origins: np.ndarray, radius: float, gate: float
               ) -> tuple[TubeCoordinates, np.ndarray]:
    """Tube coordinates of each point moved along its viewing ray onto the tube of `radius`.

    The tube is taken as the local cylinder about the tangent at the point's arc length; of the ray's two
    intersections the one nearer the camera is the surface the camera saw. hit: the ray meets the tube within
    `gate` of the point; other points keep their coordinates. frames: Centerline.project_with_frames's.
    """
    origins = np.ascontiguousarray(np.broadcast_to(origins, (len(coords.s), 3)), dtype=float)  # or one for all
    moved_s, moved_x, moved_y, hit = _along_rays_kernel(coords.s, coords.x, coords.y, *frames, origins, radius,
                                                        gate)
    return TubeCoordinates(moved_s, moved_x, moved_y), hit


@jit
def _nearest_surface_kernel(s, x, y, starts, ends, outer_radius, inner_radius, chord_offset, tip_s, gate,
                            ray_s, ray_x, ray_y, hit):
    """Per point (tube coordinates s, x, y) the nearest reference surface that exists at its arc length, and
    where on it the point goes (see the module docstring); the points farther than `gate` are left out.

    starts, ends: the notches' intervals along s (sorted); ray_*, hit: along_rays's (a point bound for the
    outer wall whose ray hits it within [0, tip_s] goes there instead of radially). Returns accepted (N,), the
    distance moved, the new tube coordinates, local normal (x, y, along the tangent) and PART_* of each
    accepted point.
    """
    r_o, r_i, d = outer_radius, inner_radius, chord_offset
    half_o = np.sqrt(max(r_o**2 - d**2, 0.0))
    half_i = np.sqrt(max(r_i**2 - d**2, 0.0)) if abs(d) < r_i else 0.0
    count, notches = s.shape[0], starts.shape[0]
    accepted = np.zeros(count, np.bool_)
    distance, new_s, new_x, new_y = np.empty(count), np.empty(count), np.empty(count), np.empty(count)
    local_normal = np.zeros((count, 3))
    part = np.empty(count, np.uint8)
    kept = 0
    for i in range(count):
        si, xi, yi = s[i], x[i], y[i]
        radius = np.sqrt(xi * xi + yi * yi)
        unit_x, unit_y = unit_direction(xi, yi)
        k = min(max(np.searchsorted(starts, si, side="right") - 1, 0), notches - 1)
        in_notch = notches > 0 and starts[k] <= si <= ends[k]
        face_radius = min(max(radius, r_i), r_o)
        floor_y, face_s = 0.0, si
        # candidates in order: outer wall, bore, notch floor, cut face, tip cap (the first nearest wins)
        best, choice = np.inf, 0
        if not (in_notch and r_o * unit_x > -d):
            best = np.sqrt((radius - r_o) ** 2 + (si - min(max(si, 0.0), tip_s)) ** 2)
        if in_notch:
            if r_i * unit_x < -d and abs(radius - r_i) < best:
                best, choice = abs(radius - r_i), 1
            floor_y = np.sign(yi) * min(max(abs(yi), half_i), half_o)
            floor = np.sqrt((xi + d) ** 2 + (yi - floor_y) ** 2)
            if floor < best:
                best, choice = floor, 2
            face_s = starts[k] if si - starts[k] < ends[k] - si else ends[k]
            face = np.sqrt((si - face_s) ** 2 + (radius - face_radius) ** 2)
            if xi > -d and face < best:
                best, choice = face, 3
        if si > tip_s:
            cap = np.sqrt((si - tip_s) ** 2 + (radius - face_radius) ** 2)
            if cap < best:
                best, choice = cap, 4
        if not best <= gate:
            continue
        accepted[i] = True
        if choice == 0 and hit[i] and 0.0 <= ray_s[i] <= tip_s:
            si, xi, yi = ray_s[i], ray_x[i], ray_y[i]
            unit_x, unit_y = unit_direction(xi, yi)
        distance[kept] = best
        new_s[kept] = min(max(si, 0.0), tip_s)
        if choice == 0:
            new_x[kept], new_y[kept] = r_o * unit_x, r_o * unit_y
            local_normal[kept, 0], local_normal[kept, 1] = unit_x, unit_y
            part[kept] = PART_OUTER_WALL
        elif choice == 1:
            new_x[kept], new_y[kept] = r_i * unit_x, r_i * unit_y
            local_normal[kept, 0], local_normal[kept, 1] = -unit_x, -unit_y
            part[kept] = PART_INNER_WALL
        elif choice == 2:
            new_x[kept], new_y[kept] = -d, floor_y
            local_normal[kept, 0] = 1.0
            part[kept] = PART_NOTCH_FLOOR
        elif choice == 3:
            new_s[kept] = face_s
            new_x[kept], new_y[kept] = face_radius * unit_x, face_radius * unit_y
            local_normal[kept, 2] = -1.0 if si > face_s else 1.0  # cut faces look into the gap
            part[kept] = PART_CUT_FACE
        else:
            new_s[kept] = tip_s
            new_x[kept], new_y[kept] = face_radius * unit_x, face_radius * unit_y
            local_normal[kept, 2] = 1.0
            part[kept] = PART_END_CAP
        kept += 1
    return (accepted, distance[:kept], new_s[:kept], new_x[:kept], new_y[:kept], local_normal[:kept],
            part[:kept])


def relocate_points(coords: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry,
                    notches: list[Notch], tip_s: float, gate: float,
                    ray_coords: tuple[TubeCoordinates, np.ndarray] | None = None) -> RelocatedPoints:
    """Move each point onto the nearest existing reference surface within `gate`.

    ray_coords: `along_rays` output; a point bound for the outer wall whose ray hits it goes there.
    """
    starts = np.array([n.start_s for n in notches], dtype=float)
    ends = np.array([n.end_s for n in notches], dtype=float)
    if ray_coords is None:
        ray_coords = coords, np.zeros(len(coords.s), dtype=bool)
    accepted, distance, s, x, y, local_normal, part = _nearest_surface_kernel(
        coords.s, coords.x, coords.y, starts, ends, geometry.outer_radius, geometry.inner_radius,
        geometry.chord_offset, tip_s, gate, ray_coords[0].s, ray_coords[0].x, ray_coords[0].y, ray_coords[1])
    points, normals = _in_base_frame(*centerline.frames_at(s), x, y, local_normal)
    return RelocatedPoints(accepted, points, normals, part, distance, TubeCoordinates(s, x, y))


@jit
def _in_base_frame(position, tangent, normal, binormal, x, y, local_normal):
    """Points (tube coordinates x, y at their frames) and normals (local: along normal, binormal, tangent) in
    the base frame, in one pass (numpy's broadcasting took four temporaries of (N, 3))."""
    points, normals = np.empty_like(position), np.empty_like(position)
    for i in range(position.shape[0]):
        for d in range(3):
            points[i, d] = position[i, d] + x[i] * normal[i, d] + y[i] * binormal[i, d]
            normals[i, d] = (local_normal[i, 0] * normal[i, d] + local_normal[i, 1] * binormal[i, d]
                             + local_normal[i, 2] * tangent[i, d])
    return points, normals
