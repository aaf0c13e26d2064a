"""The second camera's pose refined relative to the first from the robot as the graph runs (issue 62,
`calibration.refine`; relocation_node).

A calibrated rig drifts: a camera knocked, a mount relaxing. The same model fit as `ntcr-recon calibrate`
(core.calibration.rig_fit) runs over a few of the graph's own frames, each a recording of the robot in whatever pose
it held (its bends fitted), with the first camera held where the rig file puts it: the base frame the file defines
stays, and only the second camera moves. Frames are taken spread over `calibration.refine_period`
(RefineWindow), so that a refinement sees the robot in several poses rather than one instant many times.

    window = RefineWindow(config.calibration)
    window.offer(stamp_s, recording_from_cloud("frame", cloud, config, views))   # every relocated frame
    if window.due(stamp_s): refined = refine_relative(window.take(stamp_s), config)  # RefinedPose | CalibrationError

What it resolves: across the views, the tube's limbs fix the second camera to a few hundredths of a millimetre;
along them only depth does, and a matcher's depth bias that differs along the tube (the notches smeared into its
window, a highlight) moves the refined pose by 0.2-0.5 deg and about 0.2 mm with an exact rig
(benchmarks/refine_matrix.py), and with the real matcher's depth most rigs leave a turn undetermined (refused,
CalibrationError naming it). A refinement therefore reports the change against the rig file beside
its uncertainty and calls it `significant` only beyond REFINE_RESOLUTION and beyond its own uncertainty
(SIGNIFICANT_CHI2): it corrects a camera knocked by a degree or a millimetre, and a smaller drift is better told by the
reconstruction's own EXTRINSICS_DISAGREE check (core.quality.checks.extrinsics).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.base.transforms import invert_transform, transform_points
from ntcr_recon.core.calibration.recordings import MAX_POINTS, sampled
from ntcr_recon.core.calibration.rig_fit import Recording, fit_rig, pivot_of, pose_change
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import CalibrationConfig, RigConfig
from ntcr_recon.core.relocation.limbs import CameraView

# Points per camera and frame a refinement takes (a fit over a few frames: fewer than calibrate's per bag).
REFINE_POINTS = MAX_POINTS // 2
# A change is significant where its six parameters' sum of squared standard scores exceeds this (chi-square, 6
# degrees of freedom: 5 % of exact rigs beyond it, were the uncertainties exact; they are 2-3 times the errors)...
SIGNIFICANT_CHI2 = 12.6
# ...and its turn or shift beyond what the fit reaches with an exact rig (deg, mm; benchmarks/refine_matrix.py: up to
# 0.54 deg and 0.27 mm on emulated depth; 0.69 deg and 0.31 mm with the real matcher's, where the chi-square decides).
REFINE_RESOLUTION = (0.6, 0.3)


@dataclass(frozen=True)
class RefinedPose:
    """The second camera's pose refined against the first (held), and how it differs from the rig file's."""

    camera: str
    reference: str
    extrinsic: np.ndarray          # 4x4, the camera's optical frame in the base frame
    change: np.ndarray             # from the rig file's pose per base-frame axis: turns (deg), shifts (mm)
    uncertainty: np.ndarray        # 1-sigma of each, same units
    residual_mm: dict[str, float]  # each camera's robust RMS off the fitted tube
    frames: int

    @property
    def chi2(self) -> float:
        """The change's sum of squared standard scores (its parameters taken as independent)."""
        return float(np.sum((self.change / np.maximum(self.uncertainty, 1e-9)) ** 2))

    @property
    def significant(self) -> bool:
        """The rig file's pose is off by more than the refinement's own uncertainty and resolution."""
        beyond_resolution = (np.linalg.norm(self.change[:3]) > REFINE_RESOLUTION[0]
                             or np.linalg.norm(self.change[3:]) > REFINE_RESOLUTION[1])
        return bool(beyond_resolution and self.chi2 > SIGNIFICANT_CHI2)

    def as_dict(self) -> dict:
        """The figures as plain numbers (for /diagnostics and a report)."""
        return {"camera": self.camera, "reference": self.reference, "frames": self.frames,
                "significant": self.significant, "chi2": round(self.chi2, 2),
                "turn_deg": [round(float(v), 4) for v in self.change[:3]],
                "shift_mm": [round(float(v), 4) for v in self.change[3:]],
                "uncertainty_turn_deg": [round(float(v), 4) for v in self.uncertainty[:3]],
                "uncertainty_shift_mm": [round(float(v), 4) for v in self.uncertainty[3:]],
                "residual_mm": {name: round(float(v), 4) for name, v in self.residual_mm.items()}}


def recording_from_cloud(name: str, cloud: Cloud, config: RigConfig, views: dict[str, CameraView] | None = None,
                         max_points: int = REFINE_POINTS, seed: int = 0) -> Recording:
    """A fused cloud (base frame, each point's camera known) as a calibration recording: each camera's points moved
    back into its optical frame by the rig file's pose, at most max_points of them (an even random sample).
    views: each camera's colour window of the cloud's instant (the relocator's), for the limbs."""
    if cloud.camera is None:
        raise ValueError("the cloud does not say which camera saw each point: it cannot refine a camera's pose")
    rng = np.random.default_rng(seed)
    points, pixels = {}, {}
    for index, camera in enumerate(config.camera_names):
        optical = transform_points(invert_transform(config.cameras[camera].extrinsic), cloud.xyz[cloud.camera == index])
        pixels[camera] = len(optical)
        points[camera] = sampled(optical, max_points, rng)
    footprint = cloud.pixel_footprint if cloud.pixel_footprint > 0 else Recording.footprint
    return Recording(name, points, pixels, straight=False, footprint=footprint,
                     views={camera: (view.color, view.intrinsics) for camera, view in (views or {}).items()})


def refine_relative(recordings: list[Recording], config: RigConfig) -> RefinedPose:
    """The second camera refined against the first over the recordings. CalibrationError when they leave a pose
    parameter undetermined (the turn about the robot's axis while it is straight or bent along a camera's view, say),
    naming it: no refinement then, rather than one with that parameter kept at the rig file's value (with a camera
    knocked 1 deg, the others then took up the knock: 3 deg off about y, on the rig bending towards cam_a)."""
    reference, camera = config.camera_names[:2]
    start = {name: config.cameras[name].extrinsic for name in (reference, camera)}
    fit = fit_rig(recordings, config.robot, start, held=(reference,))
    change = pose_change(start[camera], fit.extrinsics[camera], pivot_of(config.robot))
    return RefinedPose(camera, reference, fit.extrinsics[camera], change, fit.uncertainty[camera], fit.residual_mm,
                       len(recordings))


class RefineWindow:
    """The frames the next refinement fits: at most refine_frames, each at least refine_period / refine_frames after
    the one before, the oldest dropped first; a refinement is due once the window is full and refine_period has
    passed since the last (stamps in seconds, the frames' own clock)."""

    def __init__(self, settings: CalibrationConfig):
        self.settings = settings
        self.frames: deque[tuple[float, Recording]] = deque(maxlen=settings.refine_frames)
        self.last_refined: float | None = None

    @property
    def spacing(self) -> float:
        return self.settings.refine_period / self.settings.refine_frames

    def wants(self, stamp: float) -> bool:
        """Whether a frame of this stamp would be kept (ask before building its recording)."""
        return not self.frames or stamp - self.frames[-1][0] >= self.spacing or stamp < self.frames[-1][0]

    def offer(self, stamp: float, recording: Recording) -> bool:
        """Keep the frame when wanted; a stamp earlier than the last kept (a replay looping) starts afresh."""
        if not self.wants(stamp):
            return False
        if self.frames and stamp < self.frames[-1][0]:
            self.frames.clear()
            self.last_refined = None
        self.frames.append((stamp, recording))
        return True

    def due(self, stamp: float) -> bool:
        full = len(self.frames) == self.frames.maxlen
        return full and (self.last_refined is None or stamp - self.last_refined >= self.settings.refine_period)

    def take(self, stamp: float) -> list[Recording]:
        """The frames to fit now (kept: the next refinement slides over them)."""
        self.last_refined = stamp
        return [recording for _, recording in self.frames]
