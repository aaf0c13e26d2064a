"""A calibration recording from one still pose's camera frames: each camera's points of the robot, optical frame.

    recording = recording_from_frames("bent", frames, config, rng)   # core.calibration.rig_fit.Recording
    at_rest = recording_from_frames("straight", frames, config, rng, straight=True)

Every frame's depth is deprojected with its own intrinsics and kept inside the rig file's crop box grown by
CROP_MARGIN_M on every side (the rough poses may put the robot that far from where it is; core.cloud.fusion.
depth_points); at most `max_points` of each camera's points are kept, an even random sample.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ntcr_recon.core.calibration.rig_fit import Recording
from ntcr_recon.core.cloud.fusion import CameraFrame, depth_points
from ntcr_recon.core.config.rig import RigConfig

# Metres the crop box grows by on every side: a hand-measured pose (3 deg, 3 mm) moves the robot about this far.
CROP_MARGIN_M = 6.0e-3
# Points per camera and recording the fit takes: more add time, not accuracy (the covariance counts the pixels a
# matcher's window correlates once).
MAX_POINTS = 8000


def recording_from_frames(name: str, frames: Iterable[CameraFrame], config: RigConfig, rng: np.random.Generator,
                          max_points: int = MAX_POINTS, straight: bool = False,
                          box: tuple[np.ndarray, np.ndarray] | None = None) -> Recording:
    """The frames' points per configured camera (depth frames only), sampled down to max_points; `straight`: the
    robot was at rest, straight, in all of them. box: where to look (base frame; default the rig's crop box), grown
    by CROP_MARGIN_M."""
    low, high = config.crop_box() if box is None else box
    box = (low - CROP_MARGIN_M, high + CROP_MARGIN_M)
    parts: dict[str, list[np.ndarray]] = {camera: [] for camera in config.camera_names}
    footprints, views = [], {}
    for frame in frames:
        optical = depth_points(frame, config, box).optical
        parts[frame.camera].append(optical)
        if frame.color is not None and frame.depth is not None:
            views[frame.camera] = (frame.color, frame.intrinsics)  # the robot is still: one frame's colour serves
        if len(optical):
            footprints.append(float(np.median(optical[:, 2])) / frame.intrinsics.fx)
    points, pixels = {}, {}
    for camera, found in parts.items():
        joined = np.concatenate(found) if found else np.empty((0, 3))
        pixels[camera] = len(joined)
        points[camera] = sampled(joined, max_points, rng)
    footprint = float(np.median(footprints)) if footprints else Recording.footprint
    return Recording(name, points, pixels, straight, footprint, views)


def sampled(points: np.ndarray, max_points: int, rng: np.random.Generator) -> np.ndarray:
    """At most max_points of the points, an even random sample (all of them when fewer)."""
    return points[rng.choice(len(points), max_points, replace=False)] if len(points) > max_points else points
