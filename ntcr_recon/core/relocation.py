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

from ntcr_recon.core.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.geometry import TubeGeometry
from ntcr_recon.core.notches import Notch
from ntcr_recon.core.robot_surface import (
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
    part: np.ndarray       # (A,) robot_surface.PART_* of the surface each point went to
    distance: np.ndarray   # (A,) how far each point moved
    coordinates: TubeCoordinates | None = None  # tube coordinates of the relocated points

    @property
    def rejected(self) -> int:
        return int(np.count_nonzero(~self.accepted))


def _length(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|(a, b)| elementwise (np.hypot guards against overflow, which millimetres never reach, at 3x the cost)."""
    return np.sqrt(a * a + b * b)


def along_rays(coords: TubeCoordinates, frames: tuple, origins: np.ndarray, radius: float, gate: float
               ) -> tuple[TubeCoordinates, np.ndarray]:
    """Tube coordinates of each point moved along its viewing ray onto the tube of `radius`.

    The tube is taken as the local cylinder about the tangent at the point's arc length; of the ray's two
    intersections the one nearer the camera is the surface the camera saw. hit: the ray meets the tube within
    `gate` of the point; other points keep their coordinates. frames: Centerline.project_with_frames's.
    """
    position, tangent, normal, binormal = frames
    points = position + coords.x[:, None] * normal + coords.y[:, None] * binormal
    ray = points - origins
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    ray_t = np.einsum("ij,ij->i", ray, tangent)
    ray_x = np.einsum("ij,ij->i", ray, normal)
    ray_y = np.einsum("ij,ij->i", ray, binormal)
    a = ray_x**2 + ray_y**2
    b = coords.x * ray_x + coords.y * ray_y
    c = coords.x**2 + coords.y**2 - radius**2
    discriminant = b * b - a * c
    safe_a = np.where(a > 1e-12, a, 1.0)
    step = (-b - np.sqrt(np.maximum(discriminant, 0.0))) / safe_a
    hit = (discriminant >= 0) & (a > 1e-12) & (np.abs(step) <= gate)
    step = np.where(hit, step, 0.0)
    moved = TubeCoordinates(coords.s + step * ray_t, coords.x + step * ray_x, coords.y + step * ray_y)
    return moved, hit


def relocate_points(coords: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry,
                    notches: list[Notch], tip_s: float, gate: float,
                    ray_coords: tuple[TubeCoordinates, np.ndarray] | None = None) -> RelocatedPoints:
    """Move each point onto the nearest existing reference surface within `gate` (vectorised).

    ray_coords: `along_rays` output; a point bound for the outer wall whose ray hits it goes there.
    """
    r_o, r_i, d = geometry.outer_radius, geometry.inner_radius, geometry.chord_offset
    s, x, y = coords.s, coords.x, coords.y
    radius, angle = coords.radius, coords.angle
    count = len(s)
    # which detected notch (if any) each point's arc length falls in
    starts = np.array([n.start_s for n in notches])
    ends = np.array([n.end_s for n in notches])
    if notches:
        k = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(notches) - 1)
        in_notch = (s >= starts[k]) & (s <= ends[k])
    else:
        k = np.zeros(count, dtype=np.intp)
        in_notch = np.zeros(count, dtype=bool)
    in_cut = in_notch & (x > -d)          # where the cut removed material
    along = np.clip(s, 0.0, tip_s)
    cos_angle = np.cos(angle)

    # candidate 1: outer wall, where it exists (not in a notch's open window, not beyond the ends)
    outer_exists = ~(in_notch & (r_o * cos_angle > -d))
    outer_distance = np.where(outer_exists, _length(radius - r_o, s - along), np.inf)
    # candidates 2-4 exist only inside a notch, 5 only beyond the tip: computed for those points alone
    bore_distance = np.full(count, np.inf)
    floor_distance = np.full(count, np.inf)
    face_distance = np.full(count, np.inf)
    cap_distance = np.full(count, np.inf)
    floor_y = np.zeros(count)
    face_s = s.copy()
    face_radius = np.clip(radius, r_i, r_o)
    inside = np.flatnonzero(in_notch)
    if len(inside):
        xi, yi, ri, si, ki = x[inside], y[inside], radius[inside], s[inside], k[inside]
        # candidate 2: bore, where the cut exposes it (behind the floor)
        bore_distance[inside] = np.where(r_i * cos_angle[inside] < -d, np.abs(ri - r_i), np.inf)
        # candidate 3: notch floor, the chord x = -d between bore and outer wall
        half_o = np.sqrt(max(r_o**2 - d**2, 0.0))
        half_i = np.sqrt(max(r_i**2 - d**2, 0.0)) if abs(d) < r_i else 0.0
        floor_y[inside] = np.sign(yi) * np.clip(np.abs(yi), half_i, half_o)
        floor_distance[inside] = _length(xi + d, yi - floor_y[inside])
        # candidate 4: the cut faces at the notch's ends (annulus part removed by the cut)
        face_s[inside] = np.where(si - starts[ki] < ends[ki] - si, starts[ki], ends[ki])
        face_distance[inside] = np.where(in_cut[inside], _length(si - face_s[inside], ri - face_radius[inside]),
                                         np.inf)
    # candidate 5: the tip cap, for points beyond the tip
    beyond = s > tip_s
    cap_distance[beyond] = _length(s[beyond] - tip_s, radius[beyond] - face_radius[beyond])

    distances = np.stack([outer_distance, bore_distance, floor_distance, face_distance, cap_distance])
    choice = np.argmin(distances, axis=0)
    best = distances[choice, np.arange(count)]
    accepted = best <= gate
    if ray_coords is not None:
        on_ray = ray_coords[1] & (choice == 0) & (ray_coords[0].s >= 0) & (ray_coords[0].s <= tip_s)
        on_ray &= accepted
        s, x, y = (np.where(on_ray, new, old) for new, old in zip(
            (ray_coords[0].s, ray_coords[0].x, ray_coords[0].y), (s, x, y), strict=True))
        angle = np.arctan2(y, x)
    choice, s, x, y, radius, angle = (a[accepted] for a in (choice, s, x, y, radius, angle))
    floor_y, face_s, face_radius = floor_y[accepted], face_s[accepted], face_radius[accepted]
    unit_x = np.cos(angle)
    unit_y = np.sin(angle)
    new_s = np.clip(s, 0.0, tip_s)
    new_x = r_o * unit_x
    new_y = r_o * unit_y
    # local normal (x, y, along-tangent)
    nx, ny, nt = unit_x.copy(), unit_y.copy(), np.zeros_like(s)
    part = np.full(len(s), PART_OUTER_WALL, dtype=np.uint8)

    bore = choice == 1
    new_x[bore], new_y[bore] = r_i * unit_x[bore], r_i * unit_y[bore]
    nx[bore], ny[bore] = -unit_x[bore], -unit_y[bore]
    part[bore] = PART_INNER_WALL

    floor = choice == 2
    new_x[floor], new_y[floor] = -d, floor_y[floor]
    nx[floor], ny[floor] = 1.0, 0.0
    part[floor] = PART_NOTCH_FLOOR

    face = choice == 3
    new_s[face] = face_s[face]
    new_x[face], new_y[face] = face_radius[face] * unit_x[face], face_radius[face] * unit_y[face]
    nx[face], ny[face] = 0.0, 0.0
    nt[face] = np.where(s[face] > face_s[face], -1.0, 1.0)  # cut faces look into the gap
    part[face] = PART_CUT_FACE

    cap = choice == 4
    cap_radius = np.clip(radius[cap], r_i, r_o)
    new_s[cap] = tip_s
    new_x[cap], new_y[cap] = cap_radius * unit_x[cap], cap_radius * unit_y[cap]
    nx[cap], ny[cap], nt[cap] = 0.0, 0.0, 1.0
    part[cap] = PART_END_CAP

    position, tangent, normal, binormal = centerline.frames_at(new_s)
    points = position + new_x[:, None] * normal + new_y[:, None] * binormal
    normals = nx[:, None] * normal + ny[:, None] * binormal + nt[:, None] * tangent
    return RelocatedPoints(accepted, points, normals, part, best[accepted], TubeCoordinates(new_s, new_x, new_y))
