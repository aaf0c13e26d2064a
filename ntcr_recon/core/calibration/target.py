"""A rigid calibration target given as a mesh (a machined block, balls on a post): how far points lie from it.

For a rig without a robot mounted yet, `ntcr-recon calibrate --target MESH` fits the cameras' poses to a rigid
object whose mesh the user gives, in the mesh's own frame (the base frame then is the mesh's). The mesh is sampled
once, SAMPLES_PER_MM2 points per square millimetre of its faces with the faces' normals; a point's distance is the
signed distance to the tangent plane of its nearest sample (exact on flat faces, to the sampling's sag on curved
ones), its gradient that sample's normal.

    target = RigidTarget.from_mesh(vertices, triangles)     # metres
    measured = target.distance(points)                      # core.calibration.tube_distance.TubeDistance
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.calibration.tube_distance import TubeDistance

# Samples per square millimetre of the mesh's faces (about 0.15 mm apart).
SAMPLES_PER_MM2 = 50.0
# At most this many samples, whatever the target's size.
MAX_SAMPLES = 2_000_000


@dataclass(frozen=True)
class RigidTarget:
    """The sampled mesh: points (N, 3), unit normals (N, 3), its KD-tree, its centre and its longest axis."""

    samples: np.ndarray
    normals: np.ndarray
    tree: cKDTree
    centre: np.ndarray
    axis: np.ndarray

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, triangles: np.ndarray, seed: int = 0) -> RigidTarget:
        """Sample a triangle mesh (vertices in metres); a mesh without area is refused."""
        corners = np.asarray(vertices, float)[np.asarray(triangles, int)]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area = np.linalg.norm(cross, axis=1) / 2.0
        if not np.isfinite(area).all() or area.sum() <= 0:
            raise ValueError("the target mesh has no area (no triangle, or all of them degenerate)")
        count = int(min(max(area.sum() * 1e6 * SAMPLES_PER_MM2, 1000), MAX_SAMPLES))
        rng = np.random.default_rng(seed)
        chosen = rng.choice(len(area), count, p=area / area.sum())
        a, b = rng.random(count), rng.random(count)
        flip = a + b > 1.0
        a, b = np.where(flip, 1.0 - a, a), np.where(flip, 1.0 - b, b)
        triangle = corners[chosen]
        samples = triangle[:, 0] + a[:, None] * (triangle[:, 1] - triangle[:, 0]) \
            + b[:, None] * (triangle[:, 2] - triangle[:, 0])
        normals = cross[chosen] / np.maximum(np.linalg.norm(cross[chosen], axis=1), 1e-300)[:, None]
        centre = samples.mean(axis=0)
        axis = np.linalg.svd(samples - centre, full_matrices=False)[2][0]
        return cls(samples, normals, cKDTree(samples), centre, axis)

    def distance(self, points: np.ndarray) -> TubeDistance:
        """Signed distance (m, along the nearest sample's outward normal) and its gradient; `foot_s`: the point's
        place along the target's longest axis (m), for the stretches a matcher's window spans."""
        _, nearest = self.tree.query(points, workers=-1)
        normals = self.normals[nearest]
        distance = np.einsum("ij,ij->i", points - self.samples[nearest], normals)
        along = (points - self.centre) @ self.axis
        return TubeDistance(distance, normals.copy(), along - along.min(initial=0.0), np.zeros(len(points), bool))
