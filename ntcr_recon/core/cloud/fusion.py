"""Fusion (paper Eq. 9): move each camera's cloud of a frame pair (core.cloud.pairing) into the base frame, concatenate.

Public API:
    CameraFrame    one camera's frame: a depth image + intrinsics (+ colour), or points in its optical frame
    FramePair      the frames of one instant, by camera name; one camera alone is allowed
    depth_points(frame, config, box) -> CameraPoints  # a depth frame's points inside the box, optical and base
                                                      # frame (camera_node's cloud, and each camera's here)
    fuse(pair, config, box=None) -> Cloud  # base frame, cropped to the configured box (or a region of
                                           # interest inside it), camera index and pixel per point
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ntcr_recon.core.base.robust import median
from ntcr_recon.core.base.transforms import transform_points
from ntcr_recon.core.cloud.deproject import Intrinsics, crop_window, depth_to_points
from ntcr_recon.core.cloud.filters import crop_mask
from ntcr_recon.core.cloud.points import Cloud, finite_rows, rows
from ntcr_recon.core.config.rig import RigConfig


@dataclass(frozen=True)
class CameraFrame:
    """One camera's data at one stamp. Either `depth` (+ `intrinsics`, optional RGB `color`, `depth_unit`
    overriding the configured one, e.g. 1.0 for 32FC1 metres) or `points` (optical frame, + packed `rgb`,
    + `organised_width` when the cloud is organised)."""

    camera: str
    stamp_ns: int
    depth: np.ndarray | None = None
    intrinsics: Intrinsics | None = None
    color: np.ndarray | None = None
    depth_unit: float | None = None
    points: np.ndarray | None = None
    rgb: np.ndarray | None = None
    organised_width: int = 0     # points of an organised cloud (row-major, NaN = no return): its width

    def __post_init__(self):
        if (self.depth is None) == (self.points is None):
            raise ValueError(f"camera frame of {self.camera} needs either a depth image or points")
        if self.depth is not None and self.intrinsics is None:
            raise ValueError(f"depth frame of {self.camera} has no intrinsics (camera_info)")


@dataclass(frozen=True)
class FramePair:
    stamp_ns: int
    frames: dict[str, CameraFrame] = field(default_factory=dict)


@dataclass(frozen=True)
class CameraPoints:
    """One camera's points inside a box: in its optical frame and in the base frame, their colours and pixels."""

    optical: np.ndarray             # (N, 3) in the camera's optical frame
    xyz: np.ndarray                 # (N, 3) in the base frame
    rgb: np.ndarray | None
    pixel: np.ndarray | None        # (N, 2) int32 (u, v); None for an unorganised cloud


def deprojected(frame: CameraFrame, config: RigConfig, window=None
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """A depth frame's valid points in the camera's optical frame, their colours and pixels (core.cloud.deproject),
    of `window`'s pixels only (None: the whole image); in the frame's depth unit, else the configured one."""
    unit = config.cameras[frame.camera].depth_unit if frame.depth_unit is None else frame.depth_unit
    return depth_to_points(frame.depth, frame.intrinsics, unit, frame.color, window, config.flying_pixel_step)


def depth_points(frame: CameraFrame, config: RigConfig, box: tuple[np.ndarray, np.ndarray],
                 windows: dict | None = None) -> CameraPoints:
    """A depth frame's points inside `box` (base frame; the clamp kept out, core.cloud.filters.crop_mask), only the
    pixels that can see the box deprojected (core.cloud.deproject.crop_window). The one camera cloud of the graph
    (camera_node) and the offline path (camera_cloud). windows: a cache of the crop windows by intrinsics, for a
    caller whose box stays the same."""
    camera = config.cameras[frame.camera]
    if windows is not None and frame.intrinsics in windows:
        window = windows[frame.intrinsics]
    else:
        window = crop_window(frame.intrinsics, camera.extrinsic, *box)
        if windows is not None:
            windows[frame.intrinsics] = window
    if window is None:  # the camera cannot see the box at all
        return CameraPoints(np.empty((0, 3)), np.empty((0, 3)), None, np.empty((0, 2), np.int32))
    xyz, rgb, pixel = deprojected(frame, config, window)
    return _inside_box(xyz, rgb, pixel, frame.camera, config, box)


def _inside_box(optical: np.ndarray, rgb: np.ndarray | None, pixel: np.ndarray | None, name: str,
                config: RigConfig, box: tuple[np.ndarray, np.ndarray]) -> CameraPoints:
    """The points (optical frame) that lie inside the box in the base frame, the clamp kept out (crop_mask)."""
    camera = config.cameras[name]
    xyz = transform_points(camera.extrinsic, optical)
    index = rows(crop_mask(xyz, config, box, camera.translation))
    return CameraPoints(np.take(optical, index, axis=0), np.take(xyz, index, axis=0),
                        None if rgb is None else rgb[index], None if pixel is None else np.take(pixel, index, axis=0))


def camera_cloud(frame: CameraFrame, config: RigConfig, box_min: np.ndarray, box_max: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, float]:
    """One camera's points in the base frame cropped to the box (the clamp kept out), their colours, their pixels
    (None for an unorganised cloud) and the pixel footprint (m, 0 unknown)."""
    box = (box_min, box_max)
    if frame.depth is not None:
        points = depth_points(frame, config, box)
    else:
        xyz = np.asarray(frame.points, dtype=np.float64)
        rgb = frame.rgb
        finite = finite_rows(xyz)
        pixel = None
        if frame.organised_width:  # an organised cloud (row-major) keeps its pixel grid
            flat = np.flatnonzero(finite)
            pixel = np.stack([flat % frame.organised_width, flat // frame.organised_width], axis=1).astype(np.int32)
        xyz, rgb = xyz[finite], None if rgb is None else np.asarray(rgb)[finite]
        points = _inside_box(xyz, rgb, pixel, frame.camera, config, box)
    footprint = 0.0
    if frame.intrinsics is not None and len(points.optical):  # a point frame gives it too when its camera_info came
        footprint = float(median(points.optical[:, 2])) / frame.intrinsics.fx
    return points.xyz, points.rgb, points.pixel, footprint


def fuse(pair: FramePair, config: RigConfig, box: tuple[np.ndarray, np.ndarray] | None = None) -> Cloud:
    """Eq. 9 for every camera of the pair, concatenated; unknown camera names are refused.

    box: a (min, max) region of interest in the base frame inside the configured crop box (e.g. around the
    robot of the previous frame); only the pixels that can see it are deprojected.
    """
    box_min, box_max = config.crop_box() if box is None else box
    parts, colours, pixels, cameras, footprints = [], [], [], [], []
    for name, frame in pair.frames.items():
        if name not in config.cameras:
            raise ValueError(f"frame from camera {name!r}, which the rig configuration does not list")
        xyz, rgb, pixel, footprint = camera_cloud(frame, config, box_min, box_max)
        parts.append(xyz)
        colours.append(rgb)
        pixels.append(pixel)
        cameras.append(np.full(len(xyz), config.camera_names.index(name), dtype=np.int8))
        if footprint > 0:
            footprints.append(footprint)
    if not parts:
        return Cloud(np.empty((0, 3)), None, np.empty(0, np.int8), pair.stamp_ns)
    rgb = None if any(c is None for c in colours) else np.concatenate(colours)
    pixel = None if any(p is None for p in pixels) else np.concatenate(pixels)
    return Cloud(np.concatenate(parts), rgb, np.concatenate(cameras), pair.stamp_ns,
                 float(np.mean(footprints)) if footprints else 0.0, pixel)
