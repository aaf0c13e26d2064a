"""Depth image -> points in the camera's optical frame (paper Eq. 3-4), colour attached.

Only the pixels that can see the crop box are deprojected: the box's corners are projected into the image
to a pixel window and a depth range first, so a 848x480 frame costs the few thousand pixels of the robot,
not 400 000.

Public API:
    Intrinsics(width, height, fx, fy, cx, cy); Intrinsics.from_camera_info(msg)
    crop_window(intrinsics, extrinsic, box_min, box_max) -> PixelWindow | None   (None: box not in view)
    depth_to_points(depth, intrinsics, depth_unit, color=None, window=None, ramp_step=0)
        -> (xyz (N,3), rgb | None, uv (N,2))
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.transforms import invert_transform, transform_points
from ntcr_recon.core.cloud.points import pack_rgb


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics K of Eq. 4 for an image of width x height pixels (rectified: no distortion)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        if not (self.width > 0 and self.height > 0 and self.fx > 0 and self.fy > 0):
            raise ValueError(f"intrinsics need positive size and focal lengths, got {self}")

    @classmethod
    def from_camera_info(cls, msg) -> Intrinsics:
        """From a sensor_msgs/CameraInfo (rclpy or rosbags): K row-major [fx 0 cx; 0 fy cy; 0 0 1]."""
        k = np.asarray(msg.k, dtype=float).reshape(-1)
        if k.size != 9:
            raise ValueError(f"CameraInfo.k must have 9 entries, got {k.size}")
        return cls(int(msg.width), int(msg.height), float(k[0]), float(k[4]), float(k[2]), float(k[5]))


@dataclass(frozen=True)
class PixelWindow:
    """Pixel rows/columns [v0, v1) x [u0, u1) and the depth range [z_min, z_max] that can see a box."""

    u0: int
    u1: int
    v0: int
    v1: int
    z_min: float
    z_max: float


def crop_window(intrinsics: Intrinsics, extrinsic: np.ndarray, box_min, box_max) -> PixelWindow | None:
    """The image window and depth range through which the camera can see the base-frame box.

    extrinsic maps optical-frame points into the base frame. Returns None when the box is wholly behind the
    camera or outside its image.
    """
    corners = np.array(list(product(*zip(box_min, box_max, strict=True))), dtype=float)  # (8, 3); meshgrid cost 5x
    in_camera = transform_points(invert_transform(extrinsic), corners)
    z = in_camera[:, 2]
    if np.all(z <= 0):
        return None
    z_min, z_max = max(float(z.min()), 0.0), float(z.max())
    if np.any(z <= 0):  # the box straddles the camera plane: its projection is unbounded
        return PixelWindow(0, intrinsics.width, 0, intrinsics.height, z_min, z_max)
    u = intrinsics.fx * in_camera[:, 0] / z + intrinsics.cx
    v = intrinsics.fy * in_camera[:, 1] / z + intrinsics.cy
    u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, intrinsics.width)
    v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, intrinsics.height)
    if u0 >= u1 or v0 >= v1:
        return None
    return PixelWindow(u0, u1, v0, v1, z_min, z_max)


def depth_to_points(depth: np.ndarray, intrinsics: Intrinsics, depth_unit: float = 1.0,
                    color: np.ndarray | None = None, window: PixelWindow | None = None, ramp_step: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Deproject a depth image (16UC1 raw units times depth_unit, or 32FC1 metres with depth_unit 1).

    Zero, NaN and infinite depths are invalid and dropped, as are depths outside the window's range.
    ramp_step > 0 (m): flying pixels are dropped too - a pixel whose depth steps by more than ramp_step to both
    of its neighbours along its row or its column, the same way (nearer one, farther the other). A stereo
    matcher whose window straddles a depth edge mixes the two depths, and the pixels there ramp from the object
    to the background, floating in the space between; an object's own surface whose relief is under ramp_step
    never steps so, its silhouette pixel has one near neighbour, and a one-pixel slot seen through steps the
    opposite ways.
    color: (H, W, 3) uint8 RGB registered to the depth image (scaled if its size differs). Returns xyz
    float64 (N, 3) in the optical frame (x right, y down, z forward), packed rgb uint32 or None, and the
    pixel (u, v) of each point as int32 (N, 2).
    """
    if depth.ndim != 2:
        raise ValueError(f"a depth image must be 2-D, got shape {depth.shape}")
    height, width = depth.shape
    if (width, height) != (intrinsics.width, intrinsics.height):
        raise ValueError(f"depth image is {width}x{height} but the intrinsics are for "
                         f"{intrinsics.width}x{intrinsics.height}")
    if window is None:
        window = PixelWindow(0, width, 0, height, 0.0, np.inf)
    if not depth.dtype.isnative:      # (a compiled kernel reads native byte order only)
        depth = depth.astype(depth.dtype.newbyteorder("="))
    # the whole image (contiguous rows: the kernel's loops vectorise) and the window's bounds
    # clipped to the image: the kernel does not check its indices
    u0, u1 = min(max(int(window.u0), 0), width), min(max(int(window.u1), 0), width)
    v0, v1 = min(max(int(window.v0), 0), height), min(max(int(window.v1), 0), height)
    xyz, pixel = _deproject_window(np.ascontiguousarray(depth), float(depth_unit), u0, u1, v0, v1,
                                   float(window.z_min), float(window.z_max), float(intrinsics.fx),
                                   float(intrinsics.fy), float(intrinsics.cx), float(intrinsics.cy),
                                   float(ramp_step))
    u, v = pixel[:, 0].astype(np.intp), pixel[:, 1].astype(np.intp)
    rgb = None
    if color is not None:
        if color.ndim != 3 or color.shape[2] < 3:
            raise ValueError(f"a colour image must be (H, W, 3), got shape {color.shape}")
        cu = (u * color.shape[1]) // width
        cv = (v * color.shape[0]) // height
        rgb = pack_rgb(color[cv, cu, :3])
    return xyz, rgb, pixel


@jit
def _valid_depth(z, z_min, z_max):
    """A depth that is finite, positive and within [z_min, z_max] (NaN fails every comparison)."""
    # & rather than `and`: no branch per test, so a loop of it vectorises
    return (z > 0.0) & (z >= z_min) & (z <= z_max) & (z < np.inf)


@jit
def _steps_one_way(before, z, after, step):
    """z lies on a ramp between two valid neighbours' depths: more than `step` from each, between them."""
    return (_valid_depth(before, 0.0, np.inf) & _valid_depth(after, 0.0, np.inf)
            & (((z - before > step) & (after - z > step)) | ((before - z > step) & (z - after > step))))


@jit
def _on_ramp(depth, depth_unit, v, u, z, step):
    """The pixel (v, u) of depth z is a flying pixel (see depth_to_points' ramp_step): along its row or its
    column it steps by more than `step` to both neighbours, the same way. Pixels at the image's border have
    no neighbour beyond it, and one whose neighbour is invalid cannot be told: both kept."""
    height, width = depth.shape
    if 0 < u < width - 1 and _steps_one_way(np.float64(depth[v, u - 1]) * depth_unit, z,
                                            np.float64(depth[v, u + 1]) * depth_unit, step):
        return True
    return 0 < v < height - 1 and _steps_one_way(np.float64(depth[v - 1, u]) * depth_unit, z,
                                                 np.float64(depth[v + 1, u]) * depth_unit, step)


@jit
def _deproject_window(depth, depth_unit, u0, u1, v0, v1, z_min, z_max, fx, fy, cx, cy, ramp_step):
    """Eq. 3-4 over the window [v0, v1) x [u0, u1) of a depth image: the pixels whose depth z = raw value *
    depth_unit is finite, positive and within [z_min, z_max], and (ramp_step > 0) that are no flying pixel,
    row by row. Returns their points (x, y, z) = ((u - cx) z / fx, (v - cy) z / fy, z) (N, 3) and pixels
    (u, v) (N, 2) int32."""
    keep = np.zeros((max(v1 - v0, 0), max(u1 - u0, 0)), dtype=np.bool_)
    count = 0
    for v in range(v0, v1):
        for u in range(u0, u1):
            z = np.float64(depth[v, u]) * depth_unit
            valid = _valid_depth(z, z_min, z_max)
            if valid and ramp_step > 0.0:
                valid = not _on_ramp(depth, depth_unit, v, u, z, ramp_step)
            keep[v - v0, u - u0] = valid
            count += valid
    xyz = np.empty((count, 3))
    pixel = np.empty((count, 2), dtype=np.int32)
    point = 0
    for v in range(v0, v1):
        for u in range(u0, u1):
            if keep[v - v0, u - u0]:
                z = np.float64(depth[v, u]) * depth_unit
                xyz[point, 0] = (u - cx) * z / fx
                xyz[point, 1] = (v - cy) * z / fy
                xyz[point, 2] = z
                pixel[point, 0], pixel[point, 1] = u, v
                point += 1
    return xyz, pixel
