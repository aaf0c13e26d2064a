"""The paper's own relocation (Sec. IV, Eq. 10-11): a reference surface aligned to the cloud by KD-tree + ICP,
then every point within the gate moved onto its nearest reference surface point.

The reference is either the configured robot posed by the estimated centreline (its outer wall, and inside
each notch the floor, bore and cut faces, and the tip cap, sampled densely: `posed_reference`), or a mesh
of the robot the user supplies (PLY/STL in the base frame, for a robot that is not a notched tube:
`mesh_reference`). Point-to-point ICP: correspondences by a KD-tree (scipy cKDTree) on the reference,
pairs farther than the gate dropped, the rigid motion (R, t) minimising sum |R p + t - q|^2 (Eq. 10) solved
in closed form (Kabsch, SVD), applied to the reference (Eq. 11), iterated until it moves less than a
tolerance. Each observed point then moves onto its nearest reference point within the gate (taking that
point's outward normal and surface part); the others are rejected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.reference import RelocatedPoints
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.surface import (
    PART_CUT_FACE,
    PART_END_CAP,
    PART_INNER_WALL,
    PART_NOTCH_FLOOR,
    PART_OUTER_WALL,
)


def posed_reference(centerline: Centerline, geometry: TubeGeometry, notches: list, tip_s: float, spacing: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (K, 3), outward normals (K, 3) and parts (K,) of the configured robot swept along the centreline,
    with the notches where they were found (or where the comb puts them), `spacing` apart."""
    r_o, r_i, d = geometry.outer_radius, geometry.inner_radius, geometry.chord_offset
    s = np.arange(0.0, tip_s + 1e-12, spacing)
    in_notch = np.zeros(len(s), dtype=bool)
    for notch in notches:
        in_notch |= (s >= notch.start_s) & (s <= notch.end_s)
    pieces = []  # (s, x, y, normal x, normal y, normal along, part)

    def ring(s_values, radius, part, outward, open_half_angle=0.0):
        count = max(int(np.ceil(2 * np.pi * radius / spacing)), 8)
        angle = -np.pi + (np.arange(count) + 0.5) * (2 * np.pi / count)
        if open_half_angle > 0:
            angle = angle[np.abs(angle) >= open_half_angle]
        ss, aa = (a.ravel() for a in np.meshgrid(s_values, angle, indexing="ij"))
        sign = 1.0 if outward else -1.0
        pieces.append((ss, radius * np.cos(aa), radius * np.sin(aa), sign * np.cos(aa), sign * np.sin(aa),
                       np.zeros_like(ss), part))

    ring(s[~in_notch], r_o, PART_OUTER_WALL, True)
    ring(s[~in_notch], r_i, PART_INNER_WALL, False)
    if np.any(in_notch):
        ring(s[in_notch], r_o, PART_OUTER_WALL, True, geometry.gap_half_angle)
        ring(s[in_notch], r_i, PART_INNER_WALL, False, np.arccos(np.clip(-d / r_i, -1.0, 1.0)))
        half_o = np.sqrt(max(r_o**2 - d**2, 0.0))
        half_i = np.sqrt(max(r_i**2 - d**2, 0.0)) if abs(d) < r_i else 0.0
        lateral = np.arange(-half_o, half_o + 1e-12, spacing)
        lateral = lateral[np.abs(lateral) >= half_i]
        ss, yy = (a.ravel() for a in np.meshgrid(s[in_notch], lateral, indexing="ij"))
        pieces.append((ss, np.full_like(ss, -d), yy, np.ones_like(ss), np.zeros_like(ss), np.zeros_like(ss),
                       PART_NOTCH_FLOOR))
    radii = np.arange(r_i, r_o + 1e-12, spacing)
    for notch in notches:  # cut faces: the annulus part removed by the cut, at both ends, facing the gap
        for face_s, facing in ((notch.start_s, 1.0), (notch.end_s, -1.0)):
            for radius in radii:
                half = np.arccos(np.clip(-d / radius, -1.0, 1.0))
                count = max(int(np.ceil(2 * half * radius / spacing)), 2)
                angle = np.linspace(-half, half, count)
                pieces.append((np.full(count, face_s), radius * np.cos(angle), radius * np.sin(angle),
                               np.zeros(count), np.zeros(count), np.full(count, facing), PART_CUT_FACE))
    for radius in radii:  # the tip cap
        count = max(int(np.ceil(2 * np.pi * radius / spacing)), 8)
        angle = np.arange(count) * (2 * np.pi / count)
        pieces.append((np.full(count, tip_s), radius * np.cos(angle), radius * np.sin(angle), np.zeros(count),
                       np.zeros(count), np.ones(count), PART_END_CAP))
    ss, xx, yy, nx, ny, nt = (np.concatenate([p[i] for p in pieces]) for i in range(6))
    part = np.concatenate([np.full(len(p[0]), p[6], dtype=np.uint8) for p in pieces])
    position, tangent, normal, binormal = centerline.frames_at(ss)
    points = position + xx[:, None] * normal + yy[:, None] * binormal
    normals = nx[:, None] * normal + ny[:, None] * binormal + nt[:, None] * tangent
    return points, normals, part


def mesh_reference(path: str | Path, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, outward normals and parts (all PART_OUTER_WALL) sampled `spacing` apart on a PLY/STL mesh of the
    robot given in the base frame."""
    import open3d as o3d  # imported only by who asks for a mesh reference

    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"relocation.reference_mesh {path}: no triangles read")
    mesh.compute_triangle_normals()
    count = max(int(mesh.get_surface_area() / spacing**2), 1000)
    sample = mesh.sample_points_uniformly(number_of_points=count, use_triangle_normal=True)
    points, normals = np.asarray(sample.points), np.asarray(sample.normals)
    return points, normals, np.full(len(points), PART_OUTER_WALL, dtype=np.uint8)


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising sum |R source + t - target|^2 (Eq. 10), in closed form (Kabsch)."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    covariance = (source - source_mean).T @ (target - target_mean)
    u, _, vt = np.linalg.svd(covariance)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ flip @ u.T
    return rotation, target_mean - rotation @ source_mean


def icp(reference: np.ndarray, cloud: np.ndarray, gate: float, iterations: int = 20, tolerance: float = 1e-7
        ) -> tuple[np.ndarray, np.ndarray, int]:
    """Align the reference to the cloud (Eq. 10-11, iterated): for each cloud point its nearest reference point
    (KD-tree), pairs within the gate, the rigid motion of the reference onto them. Returns R, t (applied to
    the reference: R q + t) and the iterations run."""
    rotation, translation = np.eye(3), np.zeros(3)
    moved = reference
    iteration = 0
    for iteration in range(1, iterations + 1):  # noqa: B007 - reported
        distance, nearest = cKDTree(moved).query(cloud, distance_upper_bound=gate)
        paired = np.isfinite(distance)
        if np.count_nonzero(paired) < 6:
            break
        step_r, step_t = rigid_fit(moved[nearest[paired]], cloud[paired])
        moved = moved @ step_r.T + step_t
        rotation, translation = step_r @ rotation, step_r @ translation + step_t
        if np.linalg.norm(step_t) < tolerance and np.abs(step_r - np.eye(3)).max() < tolerance / gate:
            break
    return rotation, translation, iteration


@dataclass(frozen=True)
class ReferenceMove:
    """How far ICP moved the reference from the pose it was given (m): RMS over its points, and the tip's move
    along the tube and across it. The pose came from the centreline: the move is how far the two relocations
    disagree, and the tip and the relocated surface are known no better than that."""

    rms: float
    tip_along: float
    tip_across: float


def reference_move(reference: np.ndarray, rotation: np.ndarray, translation: np.ndarray, tip: np.ndarray,
                   tangent: np.ndarray) -> ReferenceMove:
    """The ReferenceMove of ICP's (R, t) on the reference points (K, 3) and on the tip, `tangent` the tube's there."""
    moved = reference @ rotation.T + translation - reference
    tip_move = rotation @ tip + translation - tip
    along = float(tip_move @ tangent)
    return ReferenceMove(float(np.sqrt(np.mean(np.einsum("ij,ij->i", moved, moved)))), abs(along),
                         float(np.linalg.norm(tip_move - along * tangent)))


def relocate_onto_reference(cloud: np.ndarray, reference: np.ndarray, normals: np.ndarray, part: np.ndarray,
                            gate: float) -> RelocatedPoints:
    """Each point onto its nearest reference point within the gate (KD-tree); the others rejected."""
    distance, nearest = cKDTree(reference).query(cloud, distance_upper_bound=gate)
    accepted = np.isfinite(distance)
    chosen = nearest[accepted]
    return RelocatedPoints(accepted, reference[chosen], normals[chosen], part[chosen], distance[accepted])
