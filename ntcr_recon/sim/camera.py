"""An Intel RealSense D405 as a pinhole camera, and the poses of the two cameras of the rig.

Pixel convention (ROS / OpenCV): pixel (row v, column u) is centred on image coordinates (u, v); a point
(x, y, z) of the optical frame (z forward, x right, y down) projects to u = fx x / z + cx, v = fy y / z + cy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.base.transforms import matrix_to_quaternion

MAX_IMAGE_SIDE = 4096
MAX_IMAGE_PIXELS = 1920 * 1200


@dataclass(frozen=True)
class D405Intrinsics:
    """Depth stream of a D405 at 848x480 (the intrinsics of a real unit)."""

    width: int = 848
    height: int = 480
    fx: float = 421.61
    fy: float = 421.61
    cx: float = 428.71
    cy: float = 238.07
    baseline: float = 0.018  # m, between the two imagers; the right imager sits at +x of the left one
    depth_unit: float = 1e-4  # m per raw 16UC1 unit (the D405 default, 0.1 mm)
    fps: float = 30.0
    min_depth: float = 0.07  # m: nearer than this the disparity search range (848x480) is exceeded
    max_depth: float = 0.5  # m: beyond this the D405 reports nothing useful

    def __post_init__(self) -> None:
        """Refuse an image the renderer cannot hold: it keeps some tens of float arrays of the image's size
        (40000x40000 asked for 35.8 GiB at once, issue 66); the D405 itself streams at most 1280x720."""
        if not all(isinstance(v, int) and 1 <= v <= MAX_IMAGE_SIDE for v in (self.width, self.height)):
            raise ValueError(f"image size {self.width}x{self.height} px: each side must be 1 to {MAX_IMAGE_SIDE} px")
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise ValueError(f"image size {self.width}x{self.height} px is {self.width * self.height / 1e6:.1f} "
                             f"megapixels, more than the simulator renders ({MAX_IMAGE_PIXELS / 1e6:.1f}, e.g. "
                             "1920x1200; a D405 streams at most 1280x720)")
        if not all(math.isfinite(v) and v > 0 for v in (self.fx, self.fy)):
            raise ValueError(f"focal lengths must be finite and > 0 px, got fx={self.fx}, fy={self.fy}")
        if not all(math.isfinite(v) for v in (self.cx, self.cy)):
            raise ValueError(f"principal point must be finite, got cx={self.cx}, cy={self.cy}")

    @property
    def focal_baseline(self) -> float:
        """f b in pixel metres: disparity (px) = f b / z."""
        return self.fx * self.baseline

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) ray directions (x/z, y/z, 1) through the pixel centres: a point at depth z is z * ray."""
        u = (np.arange(self.width) - self.cx) / self.fx
        v = (np.arange(self.height) - self.cy) / self.fy
        rays = np.empty((self.height, self.width, 3))
        rays[..., 0] = u[None, :]
        rays[..., 1] = v[:, None]
        rays[..., 2] = 1.0
        return rays


@dataclass(frozen=True)
class CameraPose:
    """Pose of `<name>_optical_frame` in the base frame: p_base = rotation @ p_cam + translation."""

    name: str
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    @property
    def frame_id(self) -> str:
        return f"{self.name}_optical_frame"

    @property
    def quaternion(self) -> np.ndarray:
        """(x, y, z, w)."""
        return matrix_to_quaternion(self.rotation)

    @property
    def extrinsic(self) -> np.ndarray:
        """4x4 transform taking points of the optical frame into the base frame (CameraConfig.extrinsic)."""
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = self.rotation, self.translation
        return matrix

    def to_camera(self, points_base: np.ndarray) -> np.ndarray:
        return (np.asarray(points_base) - self.translation) @ self.rotation

    def to_base(self, points_cam: np.ndarray) -> np.ndarray:
        return np.asarray(points_cam) @ self.rotation.T + self.translation


def facing_pair(distance: float, target=(0.010, 0.0, 0.022), names=("cam_a", "cam_b"),
                distances: tuple[float, float] | None = None, yaw_deg: tuple[float, float] = (0.0, 0.0),
                pitch_deg: tuple[float, float] = (0.0, 0.0)) -> list[CameraPose]:
    """Two cameras facing each other across the robot along the base frame's y axis.

    Each optical axis passes through `target` (base frame) and the camera sits `distance` from it:
    the first camera on the -y side looking along +y, the second on the +y side looking along -y. Both are
    rolled so that the image's long side (848 px) runs along the robot's axis (base +z, base at the
    left of the image), so a robot bending towards +x (the default notch side) is seen side-on.

    A real rig is never that exact: `distances` (one per camera) overrides `distance`, and each camera can be
    turned about its own optical centre by `yaw_deg` (about its image's down axis) and `pitch_deg` (about its
    image's right axis), so its axis misses the target. The poses returned are the true ones (what a
    calibration measures).
    """
    distances = (distance, distance) if distances is None else tuple(distances)
    if not all(d > 0 for d in distances):
        raise ValueError(f"camera distance must be > 0 m, got {distances}")
    target = np.asarray(target, dtype=float)
    ex, ey, ez = np.eye(3)
    poses = []
    for name, forward, d, yaw, pitch in zip(names, (ey, -ey), distances, yaw_deg, pitch_deg, strict=True):
        right = ez
        down = np.cross(forward, right)  # right x down = forward: a right-handed optical frame
        rotation = np.column_stack([right, down, forward])
        rotation = rotation @ _axis_rotation(1, np.radians(yaw)) @ _axis_rotation(0, np.radians(pitch))
        poses.append(CameraPose(name, rotation, target - d * forward))
    return poses


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation by `angle` about the camera's own x (0), y (1) or z (2) axis."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    rotation = np.eye(3)
    rotation[i, i], rotation[i, j], rotation[j, i], rotation[j, j] = c, -s, s, c
    return rotation


def deproject(depth_m: np.ndarray, intrinsics: D405Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) in the optical frame of the valid (> 0, finite) pixels, and their flat pixel indices."""
    depth = np.asarray(depth_m, dtype=float).ravel()
    index = np.flatnonzero(np.isfinite(depth) & (depth > 0))
    rays = intrinsics.pixel_rays().reshape(-1, 3)
    return rays[index] * depth[index, None], index
