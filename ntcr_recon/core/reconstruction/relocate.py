"""The relocation (paper Sec. IV) of one filtered cloud, as the list of its steps, and what it keeps between frames.

    relocator = Relocator(config)                 # a RigConfig (core.config.rig.load_rig_config)
    relocator.note_frames(frame_pair)             # optional: the depth images' step and edge band (self-check, tip)
    relocator.note_views(frame_pair, fused)       # optional: the colour windows the limbs are read in
    relocator.note_edge_band(camera, angle)       # or a camera's edge band measured elsewhere (camera_node)
    result = relocator.relocate(cloud)            # centreline, notches, tip, relocated cloud: a RelocationResult

`relocate` warm-starts from the previous call's centreline (a still or slowly moving robot converges in one or two
iterations); `reset()` forgets it. Between frames it keeps only that centreline, each camera's edge band
(core.reconstruction.edge_bands) and depth step, and a reference mesh once sampled. The steps themselves:
core.reconstruction.relocation_steps. The Reconstructor (the offline frame loop) and relocation_node (the graph)
both relocate through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import FramePair
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.fit.robot_fit import RobotFit, fit_robot, model_axis
from ntcr_recon.core.quality.findings import Finding, result_status
from ntcr_recon.core.quality.measures import depth_step
from ntcr_recon.core.reconstruction.align_step import align
from ntcr_recon.core.reconstruction.edge_bands import EdgeBands
from ntcr_recon.core.reconstruction.relocation_steps import (
    Axis,
    Scene,
    assess,
    centreline_thinning,
    find_notches,
    notches_and_side,
    seen_end,
    tip_by_length,
)
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.relocation.centerline_fit import estimate_centerline, settings_for
from ntcr_recon.core.relocation.icp import (
    ReferenceMove,
    icp,
    mesh_reference,
    posed_reference,
    reference_move,
    relocate_onto_reference,
)
from ntcr_recon.core.relocation.limbs import CameraView
from ntcr_recon.core.relocation.notch_widths import calibrate_and_check
from ntcr_recon.core.relocation.notches import Notch, spine_wall
from ntcr_recon.core.relocation.outline_tip import end_in_outline
from ntcr_recon.core.relocation.reference import RelocatedPoints, relocate_points
from ntcr_recon.core.relocation.tip import MAX_EDGE_BAND_RAD, tube_end
from ntcr_recon.core.robot.comb import expected_centres

MINIMUM_POINTS = 32  # a cloud with fewer is not relocated


class ReconstructionError(RuntimeError):
    """A frame the chain cannot reconstruct (e.g. no robot points in it); the message says why."""


@dataclass(frozen=True)
class RelocationResult:
    """What the relocation stage (paper Sec. IV, `Relocator.relocate`) makes of one cloud: centreline, tip,
    notches, and the points moved onto the reference surface (each point's move: `core.relocation.reference`)."""

    centerline: Centerline          # base to the observed tip
    tip: np.ndarray                 # (3,) tip position, base frame
    notches: list[Notch]
    relocated: Cloud                # accepted points, moved onto the reference surface
    normals: np.ndarray             # (A, 3) outward reference normals of the relocated points
    rejected: int                   # points outside the gate
    coordinates: TubeCoordinates    # tube coordinates of the input points (before relocation)
    iterations: int                 # centreline iterations run
    part: np.ndarray | None = None  # (A,) robot.surface.PART_* of the surface each relocated point lies on
    relocated_coordinates: TubeCoordinates | None = None  # tube coordinates of the relocated points
    quality: dict = field(default_factory=dict)  # the self-check (core.quality.checks): figures, units in the keys
    warnings: tuple[Finding, ...] = ()           # what the self-check found doubtful, coded (core.quality.findings)
    notch_side: float | None = None              # rad, the side the notches open to, as measured
    status: str = "warn"                         # ok / warn / error (core.quality.findings.result_status)


class Relocator:
    """The relocation of filtered clouds, one after another (warm-started from the previous one's centreline)."""

    def __init__(self, config: RigConfig):
        self.config = config
        self.geometry = config.robot
        self.prior: Centerline | None = None  # the previous call's fitted centreline (the warm start)
        # optical centre of each camera in the base frame, by camera index (viewing rays for relocation)
        self._camera_origins = config.camera_origins
        self.depth_steps: dict[str, float] = {}  # per camera, the depth quantisation seen in its first frame
        # per camera, the band its matcher spoils at depth edges (core.relocation.tip.edge_band) over its focal length
        # (an angle: the band in metres at any distance), measured when the tip first needs it on the latest
        # depth image noted until then (depth, unit, focal length), e.g. the first frame's
        self.edge_bands = EdgeBands()
        self._mesh_reference = None  # relocation.reference_mesh, sampled once
        # per camera, its latest colour image (aligned with its depth) with its intrinsics and pose: the limbs there
        # place the axis across the views (core.relocation.limbs)
        self.views: dict[str, CameraView] = {}
        self.fit: RobotFit | None = None  # the previous call's model fit (relocation.model_fit; the warm start)
        # the last call's axis after each step of its alignment that moved it (Aligned.steps)
        self.alignment_steps: tuple[tuple[str, Centerline], ...] = ()

    def reset(self) -> None:
        """Forget the previous centreline and model fit (the next frame starts cold)."""
        self.prior, self.fit = None, None

    def note_frames(self, pair: FramePair) -> None:
        """The depth step each camera's data show, measured once per camera (for the self-check); and its latest
        depth image while its edge band is not yet measured (for the tip: EdgeBands)."""
        for name, frame in pair.frames.items():
            if frame.depth is None or name not in self.config.cameras:
                continue
            unit = frame.depth_unit if frame.depth_unit is not None else self.config.cameras[name].depth_unit
            if name not in self.depth_steps:
                self.depth_steps[name] = depth_step(frame.depth, unit)
            if frame.intrinsics is not None and self.edge_bands.wants(name):
                self.edge_bands.note_image(name, frame.depth, unit, frame.intrinsics.fx)

    def note_views(self, pair: FramePair, fused: Cloud) -> None:
        """The views the next relocation places the axis with (relocation.limbs): each camera's colour image of the
        pair (pixel-aligned with its depth: CameraView.aligned) cut around its pixels in the cloud fused from the
        pair, as camera_node cuts the window it publishes. A camera the pair lacks, or whose colour is of another
        size, has none (an image of another instant shows the robot elsewhere)."""
        self.views = {}
        if not self.config.relocation.limbs or fused.pixel is None or fused.camera is None:
            return
        for index, name in enumerate(self.config.camera_names):
            frame = pair.frames.get(name)
            if frame is None or frame.color is None or frame.intrinsics is None:
                continue
            view = CameraView.aligned(frame.color, frame.intrinsics, self.config.cameras[name].extrinsic)
            view = None if view is None else view.around(fused.pixel[fused.camera == index])
            if view is not None:
                self.views[name] = view

    def note_view(self, camera: str, color: np.ndarray, intrinsics: Intrinsics) -> None:
        """A camera's colour window (H, W, 3 uint8, aligned with its depth, with the window's intrinsics), as
        camera_node publishes it: the next relocations place the axis across its view by the tube's limbs there.
        ValueError for an unknown camera or an image that does not fit its intrinsics."""
        if camera not in self.config.camera_names:
            raise ValueError(f"colour image of camera {camera!r}, which the rig configuration does not list")
        self.views[camera] = CameraView(np.asarray(color), intrinsics, self.config.cameras[camera].extrinsic)

    def note_edge_band(self, camera: str, angle: float) -> None:
        """A camera's edge band (rad, `core.relocation.tip.edge_band_angle`) measured where its depth images are: in
        the graph by camera_node, as relocation_node sees clouds only. ValueError for an unknown camera or a band
        that cannot be one."""
        if camera not in self.config.camera_names:
            raise ValueError(f"edge band of camera {camera!r}, which the rig configuration does not list")
        if not (math.isfinite(angle) and 0.0 <= angle < MAX_EDGE_BAND_RAD):
            raise ValueError(f"edge band of {camera} is {angle} rad: not in [0, {MAX_EDGE_BAND_RAD}) rad")
        self.edge_bands.set(camera, angle)

    def relocate(self, cloud: Cloud, warm_start: bool = True) -> RelocationResult:
        """Reference-guided relocation (paper Sec. IV) as the list of its steps (core.reconstruction.relocation_steps):

        centreline -> alignment -> notches (and the notch side) -> tip -> relocation -> quality.
        """
        geometry = self.geometry
        if len(cloud) < MINIMUM_POINTS:
            raise ReconstructionError(f"only {len(cloud)} points left after filtering (need {MINIMUM_POINTS}): is "
                                      "the robot in view and inside the crop box?")
        settings = settings_for(geometry, cloud.pixel_footprint, self.config.relocation)
        seen_by = cloud.camera if cloud.camera is not None and len(cloud.camera) else None
        scene = Scene(self.config, cloud, settings, seen_by, self._camera_origins, self.edge_bands, self.depth_steps,
                      views=dict(self.views) if seen_by is not None else {})

        # 1. centreline: fixed-radius circle fits per slab, smoothed, iterated (core.relocation.centerline_fit)
        centerline, iterations, coords, frames = self._centerline(cloud, settings, warm_start)
        fitted = Axis(centerline, coords, frames)
        # 2. alignment: the reference tube shifted onto the wall points stereo measures without bias; each point
        # then as its camera saw it, along its viewing ray onto the wall (relocation.alignment, relocation.reference)
        model = self._model(cloud, settings, fitted.centerline, warm_start) if seen_by is not None else None
        aligned = align(scene, fitted, model)
        self.alignment_steps = aligned.steps
        axis = aligned.axis
        # 3. tip, coarse: where the wall stops, over the sectors the cameras can see (core.relocation.tip)
        coarse_end = tube_end(axis.measured, geometry.outer_radius, settings.gate, settings.cell,
                              max_s=geometry.reach, centerline=axis.centerline,
                              viewpoints=self._camera_origins if seen_by is not None else None)
        # 4. notches: the robot's comb matched to the evidence, edges refined locally, and the side they open to
        # (relocation.notches); the spines and the wall band on them are the same in a turned frame (same s and radii)
        wall = spine_wall(axis.coords, axis.centerline, geometry, settings.gate, settings.cell)
        # per camera the band its matcher spoils at depth edges (an angle; NaN: not measured): what smears a notch
        # window's edge round the tube, and what the tip's rim refinement gives back
        scene = replace(scene, bands=np.array([self.edge_bands.measure(name) for name in self.config.camera_names]))
        sided = notches_and_side(scene, axis, coarse_end, wall, aligned.bend_plane)
        axis, notches = sided.axis, sided.notches
        comb_centres = expected_centres(geometry, axis.centerline)  # where the robot's notches lie on the final frame
        # 5. tip, refined: the rim the stereo matcher erodes at depth edges given back, or the end cap seen
        end = seen_end(scene, axis, notches, coarse_end, comb_centres)
        # and where the colour images show the tube's outline ending: sharp where depth smears the end
        # (core.relocation.outline_tip)
        outline_end = (end_in_outline(axis.centerline, end.tip_s, scene.views, geometry, settings.cell)
                       if scene.views and not end.from_cap else None)
        if outline_end is not None:
            tip_s, tip_uncertainty = outline_end.with_depth(end.tip_s, end.tip_uncertainty)
            end = replace(end, tip_s=tip_s, tip_uncertainty=tip_uncertainty,
                          refinement=f"{end.refinement}, with the tube's outline ending in the colour images")
        # the coarse end may stop at the last cut, where little of a thinly seen ring is left: notches the refined
        # end now reaches past are looked for again (kept if more are found)
        if any(coarse_end <= centre + geometry.notch_width / 2 < end.tip_s for centre in comb_centres):
            again = find_notches(scene, axis, end.tip_s, wall)
            notches = again if len(again) > len(notches) else notches
        # how far the centreline may be off: what stereo beside the notches does to the wall (core.quality.measures)
        thinning = centreline_thinning(scene, aligned, axis, wall, end.tip_s)
        # 5'. tip along the tube: the robot's own length at the bend measured weighed in (core.relocation.tip)
        length = tip_by_length(scene, axis.centerline, end, thinning.off, comb_centres, notches)
        centerline, along = length.centerline, length.along
        # with the robot's own model fitted, its tip: the robot's known length at the bends measured
        tip_s = along.s if model is None else self.fit.shape.length
        # the rims the matcher moves (over the cut faces the cameras see), against the spines' known length; a
        # notch whose width its bend rules out was misread, and is given its bend's
        notches, misread, unchecked = calibrate_and_check(notches, geometry, centerline,
                                                          None if seen_by is None else self._camera_origins,
                                                          along.seen_s if along.hidden_across is not None else tip_s)
        # 6. relocation: every point within the gate onto the reference surface (core.relocation.reference)
        moved, tip, reference_moved = self._move(scene, axis, centerline, notches, tip_s)
        relocated = cloud.subset(moved.accepted, xyz=moved.points)
        # 7. quality: how sure this result is (core.quality.checks)
        quality, warnings = assess(scene, aligned, sided, end, length, notches=notches, tip=tip, thinning=thinning,
                                   misread=misread, unchecked=unchecked, comb_centres=comb_centres,
                                   reference_moved=reference_moved)
        if model is not None:
            quality = {**quality, "model_fit": self.fit.figures(self.config.camera_names)}
        # the next frame warm-starts from the fit's own fixed point, not from the aligned curve (else each call
        # would shift the curve once more, and results would depend on what came before)
        self.prior = fitted.centerline
        status = result_status(warnings, quality, self.config.quality)
        return RelocationResult(centerline.up_to(tip_s), tip, notches, relocated, moved.normals, moved.rejected,
                                axis.coords, iterations, moved.part, moved.coordinates, quality, tuple(warnings),
                                sided.notch_side, status)

    def _move(self, scene: Scene, axis: Axis, centerline: Centerline, notches: list[Notch], tip_s: float
              ) -> tuple[RelocatedPoints, np.ndarray, ReferenceMove | None]:
        """Step 6: every point within the gate onto the reference surface (core.relocation.reference, or by ICP), the
        tip, and how far ICP moved its reference off the centreline's pose (None: no ICP)."""
        tip_position, tip_tangents, _, _ = centerline.frames_at(np.array([tip_s]))
        tip, tip_tangent = tip_position[0], tip_tangents[0]
        if self.config.relocation.method == "icp":  # the paper's KD-tree + ICP onto a reference (core.relocation.icp)
            return self._relocate_by_icp(scene.cloud, centerline, notches, tip_s, tip, tip_tangent,
                                         scene.settings.gate, scene.settings.cell)
        moved = relocate_points(axis.coords, centerline, self.geometry, notches, tip_s, scene.settings.gate, axis.rays)
        return moved, tip, None

    def _relocate_by_icp(self, cloud: Cloud, centerline: Centerline, notches: list[Notch], tip_s: float,
                         tip: np.ndarray, tip_tangent: np.ndarray, gate: float, footprint: float
                         ) -> tuple[RelocatedPoints, np.ndarray, ReferenceMove]:
        """The reference (a user's mesh, or the configured robot posed by the centreline) aligned to the cloud by
        ICP, every point onto its nearest reference point within the gate; the tip moved with the reference, and
        how far ICP moved it."""
        options, spacing = self.config.relocation, footprint / 2
        if options.reference_mesh:
            if self._mesh_reference is None:
                self._mesh_reference = mesh_reference(options.reference_mesh, spacing)
            points, normals, part = self._mesh_reference
        else:
            points, normals, part = posed_reference(centerline, self.geometry, notches, tip_s, spacing)
        rotation, translation, _ = icp(points, cloud.xyz, gate, options.icp_iterations)
        moved = relocate_onto_reference(cloud.xyz, points @ rotation.T + translation, normals @ rotation.T, part,
                                        gate)
        # tube coordinates of the relocated points, for the tube mesher (a mesh reference of another object
        # than a tube wants mesh.method: poisson)
        moved = replace(moved, coordinates=centerline.project(moved.points))
        return moved, rotation @ tip + translation, reference_move(points, rotation, translation, tip, tip_tangent)


    def _model(self, cloud: Cloud, settings, guide: Centerline, warm_start: bool) -> Centerline | None:
        """Step 1': the robot's own model (its roll and bends) fitted to the points and the limbs in the colour
        views (core.fit.robot_fit), warm-started from the previous call's fit, else from the freely fitted
        centreline (`guide`); its axis (None: relocation.model_fit off)."""
        if not self.config.relocation.model_fit:
            return None
        views = {index: self.views[name] for index, name in enumerate(self.config.camera_names) if name in self.views}
        self.fit = fit_robot(cloud.xyz, cloud.camera, self._camera_origins, self.geometry, views,
                             guide, self.fit if warm_start else None)
        return model_axis(self.fit, self.geometry, settings.bin_length)

    def _centerline(self, cloud: Cloud, settings, warm_start: bool):
        prior = self.prior if warm_start else None
        viewpoints = self._camera_origins if cloud.camera is not None and len(cloud.camera) else None
        centerline, iterations, (coords, frames, exact) = estimate_centerline(cloud.xyz, self.geometry, settings,
                                                                              prior, viewpoints)
        if centerline.length < 2 * settings.bin_length:
            self.prior = None
            raise ReconstructionError("no tube found along the robot's base axis: is the robot in view and the "
                                      "base pose in the configuration right?")
        if not exact:
            coords, frames = centerline.project_with_frames(cloud.xyz, None if coords is None else coords.s)
        return centerline, iterations, coords, frames

