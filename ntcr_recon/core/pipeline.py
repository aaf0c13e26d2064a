"""The reconstruction chain on a frame pair: one object the CLI, the benchmark and the ROS nodes all call.

    reconstructor = Reconstructor(config)              # a RigConfig (core.config.load_rig_config)
    result = reconstructor.process(frame_pair)          # fuse -> filter -> relocate (-> mesh if asked)

Each stage is callable on its own, so each ROS node wraps one:

    cloud = reconstructor.fuse(frame_pair)              # Cloud in the base frame (Eq. 9)
    cloud = reconstructor.filter(cloud)                 # crop, colour, SOR, MLS, voxel (Sec. II-B)
    relocation = reconstructor.relocate(cloud)          # centreline, notches, relocated cloud (Sec. IV)
    mesh = reconstructor.mesh(relocation)               # Poisson mesh (Eq. 7-8), core.mesh.Mesh

`relocate` warm-starts from the previous call's centreline (a still or slowly moving robot converges in
one or two iterations) and `fuse` then deprojects only the pixels that can see a region of interest around
the robot found last (its bounding box grown by `relocation.roi_margin_fraction` of the robot's length
on every side); a frame whose robot is not found whole there is fused again from the full crop box.
`reset()` forgets both. Several frames of a still robot are combined by relocating
`Cloud.concatenate(filtered clouds)`. Every stage times itself into `timings_ms`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ntcr_recon.core.centerline import (
    Centerline,
    TubeCoordinates,
    estimate_centerline,
    settings_for,
    surface_band,
    tube_end,
)
from ntcr_recon.core.cloud import Cloud
from ntcr_recon.core.config import RigConfig
from ntcr_recon.core.filters import filter_cloud
from ntcr_recon.core.fusion import FramePair, fuse
from ntcr_recon.core.notches import Notch, detect_notches, silhouette_erosion
from ntcr_recon.core.relocation import RelocatedPoints, along_rays, relocate_points


class ReconstructionError(RuntimeError):
    """A frame the chain cannot reconstruct (e.g. no robot points in it); the message says why."""


@dataclass(frozen=True)
class Relocation:
    """What the relocation stage makes of one cloud."""

    centerline: Centerline          # base to the observed tip
    tip: np.ndarray                 # (3,) tip position, base frame
    notches: list[Notch]
    relocated: Cloud                # accepted points, moved onto the reference surface
    normals: np.ndarray             # (A, 3) outward reference normals of the relocated points
    rejected: int                   # points outside the gate
    coordinates: TubeCoordinates    # tube coordinates of the input points (before relocation)
    iterations: int                 # centreline iterations run
    part: np.ndarray | None = None  # (A,) robot.PART_* of the surface each relocated point lies on
    relocated_coordinates: TubeCoordinates | None = None  # tube coordinates of the relocated points


@dataclass
class FrameResult:
    fused: Cloud
    filtered: Cloud
    relocation: Relocation
    mesh: object | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


class Reconstructor:
    def __init__(self, config: RigConfig):
        self.config = config
        self.geometry = config.robot
        self._prior: Centerline | None = None
        self._roi: tuple[np.ndarray, np.ndarray] | None = None
        self._roi_count = 0
        # optical centre of each camera in the base frame, by camera index (viewing rays for relocation)
        self._camera_origins = np.array([config.cameras[name].translation for name in config.camera_names], float)
        self.timings_ms: dict[str, float] = {}

    def reset(self) -> None:
        """Forget the previous centreline and region of interest (the next frame starts cold)."""
        self._prior = None
        self._roi = None

    def _timed(self, stage: str, start: float) -> None:
        self.timings_ms[stage] = (time.perf_counter() - start) * 1e3

    def fuse(self, pair: FramePair) -> Cloud:
        start = time.perf_counter()
        cloud = None
        if self._roi is not None:
            cloud = fuse(pair, self.config, self._roi)
            if len(cloud) < 0.8 * self._roi_count:  # the robot moved out of the region: look everywhere
                cloud = None
        if cloud is None:
            cloud = fuse(pair, self.config)
        self._timed("fuse", start)
        return cloud

    def filter(self, cloud: Cloud) -> Cloud:
        start = time.perf_counter()
        cloud = filter_cloud(cloud, self.config)
        self._timed("filter", start)
        return cloud

    def relocate(self, cloud: Cloud, warm_start: bool = True) -> Relocation:
        """Centreline (fixed-radius fits + smoothing, iterated), notches, then relocation onto the reference."""
        start = time.perf_counter()
        geometry, settings_config = self.geometry, self.config.relocation
        minimum = 32
        if len(cloud) < minimum:
            raise ReconstructionError(f"only {len(cloud)} points left after filtering (need {minimum}): is the "
                                      "robot in view and inside the crop box?")
        settings = settings_for(geometry, cloud.pixel_footprint, settings_config)
        prior = self._prior if warm_start else None
        centerline, iterations, (coords, frames, exact) = estimate_centerline(cloud.xyz, geometry, settings, prior)
        if centerline.length < 2 * settings.bin_length:
            self._prior = None
            raise ReconstructionError("no tube found along the robot's base axis: is the robot in view and the "
                                      "base pose in the configuration right?")
        if not exact:
            coords, frames = centerline.project_with_frames(cloud.xyz, None if coords is None else coords.s)
        footprint = cloud.pixel_footprint
        import os
        if cloud.camera is not None and len(cloud.camera) and os.environ.get("ALIGN", "1") == "1":
            from ntcr_recon.core.alignment import align_to_trusted_wall
            end = tube_end(coords, geometry.outer_radius, settings.gate, settings.cell)
            alignment = align_to_trusted_wall(centerline, coords, frames, self._camera_origins[cloud.camera],
                                              geometry, settings.gate, settings.cell, end,
                                              np.radians(float(os.environ.get("ALIGN_VIEW", 45))),
                                              float(os.environ.get("ALIGN_MARGIN", 1)))
            self.last_alignment = alignment
            centerline = alignment.centerline
            coords, frames = centerline.project_with_frames(cloud.xyz, coords.s)
        rays = None
        measured = coords
        if cloud.camera is not None and len(cloud.camera):
            origins = self._camera_origins[cloud.camera]
            rays = along_rays(coords, frames, origins, geometry.outer_radius, settings.gate)
            measured = rays[0]
        tip_s = tube_end(measured, geometry.outer_radius, settings.gate, settings.cell)
        notches = detect_notches(measured, centerline, geometry, settings.gate, footprint,
                                 settings_config.notch_kernel_px, settings_config.min_notch_width_fraction, tip_s,
                                 observed=coords)
        if cloud.camera is not None and len(cloud.camera):
            # The tip's rim, an edge seen against the background, loses what the tube's silhouettes lose
            # to the stereo matcher; measure that on plain tube and give it back.
            plain = (coords.s > geometry.outer_diameter) & (coords.s < tip_s - geometry.outer_diameter)
            for notch in notches:
                plain &= (coords.s < notch.start_s - 2 * settings.cell) | (coords.s > notch.end_s + 2 * settings.cell)
            offset = coords.radius - geometry.outer_radius
            level, spread = surface_band(offset, settings.gate)
            plain &= np.abs(offset - level) <= spread
            erosion = silhouette_erosion(coords, frames, cloud.camera, self._camera_origins, geometry.outer_radius,
                                         plain)
            tip_s += erosion
        notches = _calibrate_rims(notches, geometry)
        moved: RelocatedPoints = relocate_points(coords, centerline, geometry, notches, tip_s, settings.gate,
                                                 rays)
        tip = centerline.frames_at(np.array([tip_s]))[0][0]
        relocated = cloud.subset(moved.accepted).with_points(moved.points)
        self._prior = centerline
        self._update_roi(relocated)
        self._timed("relocate", start)
        return Relocation(_cut(centerline, tip_s), tip, notches, relocated, moved.normals, moved.rejected, coords,
                          iterations, moved.part, moved.coordinates)

    def _update_roi(self, relocated: Cloud) -> None:
        """Region of interest for the next frame: the robot's bounding box, grown, inside the crop box."""
        if len(relocated) < 32:
            self._roi = None
            return
        margin = self.config.relocation.roi_margin_fraction * self.geometry.length + self.geometry.outer_diameter
        box_min, box_max = self.config.crop_box()
        low = np.maximum(relocated.xyz.min(axis=0) - margin, box_min)
        high = np.minimum(relocated.xyz.max(axis=0) + margin, box_max)
        self._roi = (low, high)
        self._roi_count = len(relocated)

    def mesh(self, relocation: Relocation):
        """The configured mesher: `tube` (the relocated outer wall meshed on the tube's own grid) or
        `poisson` (open3d's screened Poisson, the paper's Eq. 7-8)."""
        from ntcr_recon.core.mesh import poisson_mesh, tube_mesh  # open3d is imported only by who meshes

        start = time.perf_counter()
        if self.config.mesh.method == "tube":
            mesh = tube_mesh(relocation, self.geometry)
        else:
            mesh = poisson_mesh(relocation.relocated.xyz, relocation.normals, self.config.mesh)
        self._timed("mesh", start)
        return mesh

    def process(self, pair: FramePair, with_mesh: bool = False) -> FrameResult:
        """fuse -> filter -> relocate (-> mesh) on one frame pair."""
        self.timings_ms = {}
        fused = self.fuse(pair)
        filtered = self.filter(fused)
        relocation = self.relocate(filtered)
        mesh = self.mesh(relocation) if with_mesh else None
        return FrameResult(fused, filtered, relocation, mesh, dict(self.timings_ms))


def _calibrate_rims(notches: list[Notch], geometry) -> list[Notch]:
    """Correct the notch edges for what the stereo matcher does to rims at depth edges.

    A matcher erodes (or, where it averages across a shallow gap, extends) the rim on both sides of every
    notch by about the same amount e. The spines between notches are rigid, of the robot's nominal length
    pitch - width whatever the bend, so e = (nominal - observed spine length) / 2, the median over the
    spines between consecutive detected notches; every edge moves back by e. (A robot whose spines are all
    shorter than its drawing says would have that read as erosion.)
    """
    by_index = {n.index: n for n in notches}
    spine = geometry.notch_pitch - geometry.notch_width
    observed = [by_index[i + 1].start_s - by_index[i].end_s for i in sorted(by_index) if i + 1 in by_index]
    if len(observed) < 3:
        return notches
    erosion = float(np.median(spine - np.array(observed))) / 2.0
    return [Notch(n.index, n.center_s, n.start_s + erosion, n.end_s - erosion, max(n.width - 2 * erosion, 0.0),
                  n.bend) for n in notches]


def _cut(centerline: Centerline, tip_s: float) -> Centerline:
    """The centreline from the base to the tip (extended along the end tangent when the tip lies beyond)."""
    step = float(centerline.s[1] - centerline.s[0]) if len(centerline.s) > 1 else tip_s
    count = max(int(np.ceil(tip_s / step)), 1) + 1
    s = np.linspace(0.0, tip_s, count)
    position, tangent, normal, binormal = centerline.frames_at(s)
    return Centerline(s, position, tangent, normal, binormal)
