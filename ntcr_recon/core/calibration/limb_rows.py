"""The tube's limbs in each camera's colour image as rows of the calibration's fit: the axis across each view.

A D405's colour comes from its left imager, pixel-aligned with its depth, and its silhouette is sharp where the
matcher's depth is smeared: the middle of the two limbs places the axis across the view to a few hundredths of a
millimetre where depth, beside a notch or under a highlight, errs by a tenth (core.relocation.limbs reads them).
Once the fit has the robot within a pixel or two, every camera's limbs are read along the posed model's axis, at
stations STATION_STEP_M apart: each station where both limbs were found gives the limbs' middle as a point on
its line of sight (optical frame, at the axis's depth) and the direction across the view. Its residual is the
model axis's distance from that point across the view; a turn or shift of the camera moves the point with it, a
change of the bends moves the axis.

    rows = limb_rows(recording_index, camera_index, shape, color, intrinsics, extrinsic)   # LimbRows or None
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limbs import CameraView, limb_offsets
from ntcr_recon.core.robot.kinematics import TubeShape

# Stations along the robot where the limbs are read (m): about a pixel at 90 mm.
STATION_STEP_M = 0.2e-3
# The model's axis is sampled this finely for the limbs' search (m).
AXIS_STEP_M = 0.1e-3
# Least stations a camera's recording needs for its limbs to count.
MIN_STATIONS = 10


@dataclass(frozen=True)
class LimbRows:
    """One camera's limb measurements in one recording: station arc lengths (S,), the limbs' middles (S, 3) and the
    directions across the view (S, 3), both in the camera's optical frame."""

    recording: int
    camera: int
    s: np.ndarray
    points: np.ndarray
    across: np.ndarray


def limb_rows(recording: int, camera: int, shape: TubeShape, color: np.ndarray, intrinsics: Intrinsics,
              extrinsic: np.ndarray) -> LimbRows | None:
    """The limbs read about the posed shape as the camera at `extrinsic` sees it; None when fewer than
    MIN_STATIONS were measured (no colour contrast, the robot out of view)."""
    view = CameraView.aligned(color, intrinsics, extrinsic)
    if view is None:
        return None
    s = np.linspace(0.0, shape.length, max(int(np.ceil(shape.length / AXIS_STEP_M)), 1) + 1)
    centerline = Centerline.from_frames(s, *shape.centerline(s))
    stations = np.arange(STATION_STEP_M, shape.length - STATION_STEP_M, STATION_STEP_M)
    # read as the calibration's fit was measured on: the shaded reading (limb_profile.SHADED_EDGE_PX) left its
    # errors as they were (calibration_matrix: median shifts within 0.02 mm, within twice their sigma 7 -> 4 of 48)
    placement = limb_offsets(centerline, stations, view, shape.geometry.outer_radius, shaded=False)
    found = np.isfinite(placement.offset)
    if found.sum() < MIN_STATIONS:
        return None
    axis = shape.centerline_points(stations[found])
    middles = axis + placement.offset[found, None] * placement.across[found]
    rotation, origin = extrinsic[:3, :3], extrinsic[:3, 3]
    return LimbRows(recording, camera, stations[found], (middles - origin) @ rotation,
                    placement.across[found] @ rotation)
