"""Fusion (paper Eq. 9): move each camera's cloud of a frame pair (core.cloud.pairing) into the base frame, concatenate.

Public API:
    CameraFrame    one camera's frame: a depth image + intrinsics (+ colour), or points in its optical frame
    FramePair      the frames of one instant, by camera name; one camera alone is allowed
    fuse(pair, config, box=None) -> Cloud  # base frame, cropped to the configured box (or a region of
                                           # interest inside it), camera index and pixel per point
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ntcr_recon.core.base.transforms import transform_points
from ntcr_recon.core.cloud.deproject import Intrinsics, crop_window, depth_to_points
from ntcr_recon.core.cloud.filters import crop_mask
from ntcr_recon.core.cloud.points import Cloud, finite_rows, rows
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.relocation.wall import median


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


def camera_cloud(frame: CameraFrame, config: RigConfig, box_min: np.ndarray, box_max: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, float]:
    """One camera's points in the base frame cropped to the box (the clamp kept out), their colours, their pixels
    (None for an unorganised cloud) and the pixel footprint (m, 0 unknown)."""
    camera = config.cameras[frame.camera]
    extrinsic = camera.extrinsic
    footprint = 0.0
    if frame.depth is not None:
        window = crop_window(frame.intrinsics, extrinsic, box_min, box_max)
        if window is None:
            return np.empty((0, 3)), None, np.empty((0, 2), np.int32), 0.0
        unit = camera.depth_unit if frame.depth_unit is None else frame.depth_unit
        xyz, rgb, pixel = depth_to_points(frame.depth, frame.intrinsics, unit, frame.color, window,
                                         config.flying_pixel_step)
    else:
        xyz = np.asarray(frame.points, dtype=np.float64)
        rgb = frame.rgb
        finite = finite_rows(xyz)
        pixel = None
        if frame.organised_width:  # an organised cloud (row-major) keeps its pixel grid
            flat = np.flatnonzero(finite)
            pixel = np.stack([flat % frame.organised_width, flat // frame.organised_width], axis=1).astype(np.int32)
        xyz, rgb = xyz[finite], None if rgb is None else np.asarray(rgb)[finite]
    depth = xyz[:, 2]
    xyz = transform_points(extrinsic, xyz)
    inside = crop_mask(xyz, config, (box_min, box_max), camera.translation)
    if frame.intrinsics is not None and np.any(inside):  # a point frame gives it too when its camera_info came
        footprint = float(median(depth[inside])) / frame.intrinsics.fx
    index = rows(inside)
    return (np.take(xyz, index, axis=0), None if rgb is None else rgb[index],
            None if pixel is None else np.take(pixel, index, axis=0), footprint)


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
