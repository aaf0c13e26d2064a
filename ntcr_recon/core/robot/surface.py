"""The true surface of a posed robot: dense samples with each point's part and tube coordinates, and the
distance of any point to that surface (the ground truth the simulator renders and the metrics measure against).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.robot.geometry import TubeGeometry

# Surface parts of a sampled robot (SurfaceSample.part).
PART_OUTER_WALL = 0
PART_INNER_WALL = 1  # the bore; seen through the notches and at the tip
PART_NOTCH_FLOOR = 2  # the cut plane of the backbone at the bottom of a notch
PART_CUT_FACE = 3  # the spines' faces that bound a notch
PART_END_CAP = 4  # the annular ends of the tube (base and tip)

# Sample spacing of the dense surface that surface_distance measures against.
DISTANCE_SAMPLE_SPACING = 0.04e-3


@dataclass
class SurfaceSample:
    """A dense sample of the true surface; base frame."""

    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3) unit, outward from the material
    part: np.ndarray  # (N,) PART_* code
    s: np.ndarray  # (N,) centreline arc length of the cross-section the point belongs to
    angle: np.ndarray  # (N,) angle about the axis from the notch side (radians, -pi..pi)
    radius: np.ndarray  # (N,) distance from the centreline in the cross-section plane


class PosedTube(Protocol):
    """What the surface needs of a posed robot (kinematics.TubeShape is one): the geometry, the segments
    (spine, notch, spine, ...) by arc-length start, length and curvature, and the centreline's frames."""

    geometry: TubeGeometry
    segment_starts: np.ndarray
    segment_lengths: np.ndarray
    segment_curvatures: np.ndarray
    length: float

    def centerline(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


# A piece of the sampled surface: (s, angle, radius, normal in the cross-section's frame (N, 3), part).
Piece = tuple


def _wall(s_values, radius: float, angle_limit: float, part: int, outward: bool, spacing: float) -> list[Piece]:
    """A wall at `radius` over the arc lengths; the material spans |angle| >= angle_limit (0: the whole ring)."""
    span = 2.0 * math.pi - 2.0 * angle_limit
    if span <= 0:
        return []
    count = max(int(math.ceil(span * radius / spacing)), 3)
    whole = angle_limit == 0
    angles = np.arange(count) * (span / count) if whole else angle_limit + np.linspace(0.0, span, count + 1)
    angles = np.angle(np.exp(1j * angles))
    ss, aa = (a.ravel() for a in np.meshgrid(s_values, angles, indexing="ij"))
    sign = 1.0 if outward else -1.0
    normal = sign * np.stack([np.cos(aa), np.sin(aa), np.zeros_like(aa)], axis=1)
    return [(ss, aa, np.full(ss.shape, radius), normal, part)]


def _annulus(s_value: float, normal_z: float, only_removed: bool, part: int, g: TubeGeometry,
             spacing: float) -> list[Piece]:
    """The annular cross-section at s_value; only_removed: the part a notch cuts away (x > -d)."""
    r_o, r_i, d = g.outer_radius, g.inner_radius, g.chord_offset
    pieces = []
    for radius in np.linspace(r_i, r_o, max(int(math.ceil((r_o - r_i) / spacing)) + 1, 2)):
        half = math.acos(min(1.0, max(-1.0, -d / radius))) if only_removed else math.pi
        if half <= 0:
            continue
        count = 2 * max(int(math.ceil(half * radius / spacing)), 1)  # even: angle 0 is sampled
        angles = np.linspace(-half, half, count + 1) if half < math.pi else np.arange(count) * (2 * math.pi / count)
        angles = np.angle(np.exp(1j * angles))
        normal = np.tile([0.0, 0.0, normal_z], (angles.size, 1))
        pieces.append((np.full(angles.size, s_value), angles, np.full(angles.size, radius), normal, part))
    return pieces


def _notch_floor(s_values, g: TubeGeometry, spacing: float) -> Piece:
    """The notch floor: the chord x = -d between the outer circle and the bore."""
    r_o, r_i, d = g.outer_radius, g.inner_radius, g.chord_offset
    half_o = math.sqrt(max(r_o**2 - d**2, 0.0))
    half_i = math.sqrt(max(r_i**2 - d**2, 0.0)) if abs(d) < r_i else 0.0
    count = max(int(math.ceil((half_o - half_i) / spacing)), 1)
    ys = np.linspace(half_i, half_o, count + 1)
    ys = np.concatenate([-ys[::-1], ys]) if half_i > 0 else np.linspace(-half_o, half_o, 2 * count + 1)
    ss, yy = (a.ravel() for a in np.meshgrid(s_values, ys, indexing="ij"))
    xx = np.full(ss.shape, -d)
    normal = np.tile([1.0, 0.0, 0.0], (ss.size, 1))
    return ss, np.arctan2(yy, xx), np.hypot(xx, yy), normal, PART_NOTCH_FLOOR


def _segment_pieces(shape: PosedTube, spacing: float) -> list[Piece]:
    """Spines: outer wall and bore. Notches: the backbone's walls, its floor and the two bounding cut faces."""
    g = shape.geometry
    inner_limit = math.acos(min(1.0, max(-1.0, -g.chord_offset / g.inner_radius)))
    last = len(shape.segment_starts) - 1
    pieces: list[Piece] = []
    for k, (start, length, kappa) in enumerate(zip(shape.segment_starts, shape.segment_lengths,
                                                   shape.segment_curvatures, strict=True)):
        if length <= 0:
            continue
        count = max(int(math.ceil(length * (1.0 + kappa * g.outer_radius) / spacing)), 1)
        s_values = start + np.linspace(0.0, length, count + 1)[: None if k == last else -1]
        if k % 2 == 0:  # a spine
            pieces += _wall(s_values, g.outer_radius, 0.0, PART_OUTER_WALL, True, spacing)
            pieces += _wall(s_values, g.inner_radius, 0.0, PART_INNER_WALL, False, spacing)
            continue
        pieces += _wall(s_values, g.outer_radius, g.gap_half_angle, PART_OUTER_WALL, True, spacing)
        pieces += _wall(s_values, g.inner_radius, inner_limit, PART_INNER_WALL, False, spacing)
        pieces.append(_notch_floor(s_values, g, spacing))
        pieces += _annulus(start, 1.0, True, PART_CUT_FACE, g, spacing)
        pieces += _annulus(start + length, -1.0, True, PART_CUT_FACE, g, spacing)
    return pieces


def sample_surface_parts(shape: PosedTube, spacing: float) -> SurfaceSample:
    """Dense sample of the true surface, at most `spacing` apart, with each point's part and coordinates.

    Spines: outer wall and bore. Notches: the backbone's outer wall and bore (the bore is what one
    sees through the cut), the cut plane between them (notch floor), and the two faces of the
    neighbouring spines that bound the gap. Ends: annular caps at base and tip.
    """
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    pieces = _segment_pieces(shape, spacing)
    pieces += _annulus(0.0, -1.0, False, PART_END_CAP, shape.geometry, spacing)
    pieces += _annulus(shape.length, 1.0, False, PART_END_CAP, shape.geometry, spacing)
    s = np.concatenate([p[0] for p in pieces])
    angle = np.concatenate([p[1] for p in pieces])
    radius = np.concatenate([p[2] for p in pieces])
    normal_local = np.concatenate([p[3] for p in pieces])
    part = np.concatenate([np.full(p[0].size, p[4], dtype=np.uint8) for p in pieces])
    centre, frame = shape.centerline(s)
    local = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(s)], axis=1)
    points = centre + np.einsum("nij,nj->ni", frame, local)
    normals = np.einsum("nij,nj->ni", frame, normal_local)
    return SurfaceSample(points, normals, part, s, angle, radius)


class SurfaceDistance:
    """Unsigned distance of points to a shape's true surface, over a dense sample indexed once.

    Over the k nearest samples: the distance to a sample's tangent plane when the point lies over that sample
    (so the result does not carry the sampling step), else the distance to the sample itself (beyond an edge).
    Accurate to about a micrometre.
    """

    def __init__(self, shape: PosedTube) -> None:
        sample = sample_surface_parts(shape, DISTANCE_SAMPLE_SPACING)
        self._tree, self._samples, self._normals = cKDTree(sample.points), sample.points, sample.normals

    def __call__(self, points) -> np.ndarray:
        query = np.asarray(points, dtype=float).reshape(-1, 3)
        _, nearest = self._tree.query(query, k=8, workers=-1)
        delta = query[:, None, :] - self._samples[nearest]
        along_normal = np.abs(np.einsum("nkj,nkj->nk", delta, self._normals[nearest]))
        squared = np.einsum("nkj,nkj->nk", delta, delta)
        lateral = np.sqrt(np.maximum(squared - along_normal**2, 0.0))
        distance = np.where(lateral <= DISTANCE_SAMPLE_SPACING, along_normal, np.sqrt(squared))
        return distance.min(axis=1)
