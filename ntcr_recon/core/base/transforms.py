"""Rigid transforms: quaternions (x, y, z, w, as in geometry_msgs and tf2) and 4x4 matrices.

A transform maps points of a child frame into its parent frame, p_parent = R p_child + t, which is
how a camera's extrinsics are given in the rig configuration (the TF parent is the base frame).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# A quaternion whose norm is this far from one is a typo, not rounding.
_QUATERNION_NORM_TOLERANCE = 1e-3


def quaternion_to_matrix(rotation_xyzw) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w). Refuses one that is not of unit norm."""
    q = np.asarray(rotation_xyzw, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"a quaternion needs 4 finite numbers (x, y, z, w), got {rotation_xyzw!r}")
    norm = np.linalg.norm(q)
    if abs(norm - 1.0) > _QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"quaternion {rotation_xyzw!r} has norm {norm:.6f}, expected 1")
    return Rotation.from_quat(q / norm).as_matrix()


def matrix_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix, with w >= 0."""
    q = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat()
    return q if q[3] >= 0 else -q


def rigid_transform(translation, rotation_xyzw) -> np.ndarray:
    """4x4 homogeneous matrix from a translation (x, y, z) and a quaternion (x, y, z, w)."""
    t = np.asarray(translation, dtype=float)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"a translation needs 3 finite numbers (x, y, z), got {translation!r}")
    matrix = np.eye(4)
    matrix[:3, :3] = quaternion_to_matrix(rotation_xyzw)
    matrix[:3, 3] = t
    return matrix


def invert_transform(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform, without a general matrix inverse."""
    inverse = np.eye(4)
    rotation_t = matrix[:3, :3].T
    inverse[:3, :3] = rotation_t
    inverse[:3, 3] = -rotation_t @ matrix[:3, 3]
    return inverse


def transform_points(matrix: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points; keeps the input's float dtype."""
    points = np.asarray(xyz)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    dtype = points.dtype if np.issubdtype(points.dtype, np.floating) else np.float64
    rotation = matrix[:3, :3].astype(dtype)
    translation = matrix[:3, 3].astype(dtype)
    return points.astype(dtype, copy=False) @ rotation.T + translation
