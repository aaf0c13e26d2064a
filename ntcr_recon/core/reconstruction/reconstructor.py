"""The reconstruction chain on a frame pair: one object the CLI, the benchmark and the ROS nodes all call.

    reconstructor = Reconstructor(config)              # a RigConfig (core.config.rig.load_rig_config)
    result = reconstructor.process(frame_pair)          # fuse -> filter -> relocate (-> mesh if asked)

Each stage is callable on its own, so each ROS node wraps one:

    cloud = reconstructor.fuse(frame_pair)              # Cloud in the base frame (Eq. 9)
    cloud = reconstructor.filter(cloud)                 # crop, colour, SOR, MLS, voxel (Sec. II-B)
    relocation = reconstructor.relocate(cloud)          # centreline, notches, tip, relocated cloud (Sec. IV)
    mesh = reconstructor.mesh(relocation)               # the configured mesher: tube (default) or Poisson
                                                        # (Eq. 7-8), a core.reconstruction.mesh.Mesh

`relocate` warm-starts from the previous call's centreline (a still or slowly moving robot converges in
one or two iterations) and `fuse` then deprojects only the pixels that can see a region of interest around
the robot found last (its bounding box grown by `relocation.roi_margin_fraction` of the robot's length
on every side); a frame whose robot is not found whole there is fused again from the full crop box.
`reset()` forgets both. Several frames of a still robot are combined by relocating
`Cloud.concatenate(filtered clouds)`. Every stage times itself into `timings_ms`.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ntcr_recon.core.cloud.filters import filter_cloud
from ntcr_recon.core.cloud.fusion import FramePair, fuse
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.quality.checks import Trace, assess
from ntcr_recon.core.quality.findings import Finding, result_status
from ntcr_recon.core.quality.measures import (
    CameraReach,
    camera_reach,
    cameras_looking_into_slots,
    centerline_uncertainty,
    depth_step,
    notched_thinning,
)
from ntcr_recon.core.relocation.alignment import (
    SILHOUETTE_MARGIN_PX,
    Alignment,
    CrossView,
    align_to_trusted_wall,
    cross_view_spread,
    level_by_backbone,
    shift_scatter,
)
from ntcr_recon.core.relocation.centerline import (
    Centerline,
    TubeCoordinates,
    continued_bend,
    estimate_centerline,
    held_bend,
    settings_for,
    turn_from_base,
)
from ntcr_recon.core.relocation.icp import (
    ReferenceMove,
    icp,
    mesh_reference,
    posed_reference,
    reference_move,
    relocate_onto_reference,
)
from ntcr_recon.core.relocation.notches import (
    Notch,
    calibrate_and_check,
    detect_notches,
    measure_notch_side,
    spine_wall,
)
from ntcr_recon.core.relocation.outline import across_views_from, outline_offset, went_astray
from ntcr_recon.core.relocation.reference import RelocatedPoints, along_rays, relocate_points
from ntcr_recon.core.relocation.tip import (
    EDGE_BAND_ATTEMPTS,
    LENGTH_AGREEMENT_SIGMAS,
    MAX_EDGE_BAND_RAD,
    TipAlongTube,
    cap_faces_a_camera,
    carried_to_length,
    edge_band_angle,
    end_cap_plane,
    give_back_erosion,
    rim_tip,
    tube_end,
    with_known_length,
)
from ntcr_recon.core.relocation.wall import band_gate, surface_band
from ntcr_recon.core.robot.comb import cut_intervals, expected_centres, inside_intervals

# A measured notch side further than this from the configured one turns the tube frame (smaller: within
# what the measurement scatters, and the open window is wide enough for it).
ROLL_TO_REFRAME = np.radians(6.0)


# Alignment passes: each selects the trusted points about the axis the previous one moved.
ALIGNMENT_PASSES = 3

# A tube whose end tangent turns at least this far towards a camera (from across its view) points at it.
CAP_PLANE_ANGLE = np.radians(45.0)

# The band a stereo matcher spoils at a depth edge, where no depth image measured it: half a D405's 7 px window.
UNMEASURED_EDGE_BAND_PX = 3.5


class ReconstructionError(RuntimeError):
    """A frame the chain cannot reconstruct (e.g. no robot points in it); the message says why."""


@dataclass(frozen=True)
class RelocationResult:
    """What the relocation stage (paper Sec. IV, `Reconstructor.relocate`) makes of one cloud: centreline, tip,
    notches, and the points moved onto the reference surface (each point's move: `core.relocation.reference`)."""

    centerline: Centerline          # base to the observed tip
    tip: np.ndarray                 # (3,) tip position, base frame
    notches: list[Notch]
    relocated: Cloud                # accepted points, moved onto the reference surface
    normals: np.ndarray             # (A, 3) outward reference normals of the relocated points
    rejected: int                   # points outside the gate
    coordinates: TubeCoordinates    # tube coordinates of the input points (before relocation)
    iterations: int                 # centreline iterations run
    part: np.ndarray | None = None  # (A,) robot_surface.PART_* of the surface each relocated point lies on
    relocated_coordinates: TubeCoordinates | None = None  # tube coordinates of the relocated points
    quality: dict = field(default_factory=dict)  # the self-check (core.quality.measures): figures, units in the keys
    warnings: tuple[Finding, ...] = ()           # what the self-check found doubtful, coded (core.quality.findings)
    notch_side: float | None = None              # rad, the side the notches open to, as measured
    status: str = "warn"                         # ok / warn / error (core.quality.findings.status)


@dataclass
class FrameResult:
    fused: Cloud
    filtered: Cloud
    relocation: RelocationResult
    mesh: object | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


# What each step of `Reconstructor.relocate` hands on to the next.

@dataclass(frozen=True)
class _Axis:
    """An axis and the cloud's points about it, replaced whole where a step moves or turns the axis."""

    centerline: Centerline
    coords: TubeCoordinates         # the points about the axis
    frames: tuple                   # (position, tangent, normal, binormal) at each point's s
    rays: tuple | None = None       # relocation.reference.along_rays: the points along their viewing rays onto the wall

    @property
    def measured(self) -> TubeCoordinates:
        """The points as their cameras saw them (along their viewing rays onto the wall), else as fused."""
        return self.coords if self.rays is None else self.rays[0]

    def rolled(self, angle: float) -> _Axis:
        """The same axis with its frame turned by `angle` about the tangent (towards the notch side measured)."""
        position, tangent, normal, binormal = self.frames
        return _Axis(self.centerline.rolled(angle), self.coords.rolled(angle),
                     (position, tangent, *_rolled_axes(normal, binormal, angle)),
                     None if self.rays is None else (self.rays[0].rolled(angle), self.rays[1]))


@dataclass(frozen=True)
class _Aligned:
    """Step 2: the axis moved onto the trusted wall, and what the checks on it found (None: no cameras known)."""

    axis: _Axis
    alignment: Alignment | None = None
    cross_view: CrossView = CrossView(None)
    backbone_shift: float | None = None           # m, alignment.level_by_backbone's
    outline: float | None = None                  # m, outline.outline_offset of the final axis
    across_from_fit: tuple[float, float] | None = None  # the aligned and fitted axes' outline offsets, where the
                                                        # fit's placement across the views was taken
    scatter: float | None = None                  # m, alignment.shift_scatter


@dataclass(frozen=True)
class _Sided:
    """Step 4: the notches, found in the frame turned to the side they open to (where it was measured)."""

    axis: _Axis
    notches: list[Notch]
    notch_side: float                             # rad, measured (or the configured one)
    unsettled: tuple[float, float] | None         # a turn that did not settle: (turned by, then measured off)
    side_uncertainty: float | None                # rad; None: the side not measured


@dataclass(frozen=True)
class _SeenEnd:
    """Step 5: the end the cameras saw."""

    tip_s: float
    eroded_end: float                             # the end before the rim a matcher erodes was given back
    refinement: str                               # how it was placed (quality's tip_refinement)
    tip_uncertainty: float | None = None          # m along the tube; None: nothing measured the erosion
    from_cap: bool = False                        # placed on the end cap's points (a lower bound)


@dataclass(frozen=True)
class _ByLength:
    """Step 5': the tip along the tube with the robot's known length weighed in."""

    centerline: Centerline                        # carried on past the fit's end, bending as the notches did
    along: TipAlongTube                           # core.relocation.tip.with_known_length's (or carried_to_length's)
    total_bend: float                             # rad, at the tip
    end_turn_off: float | None                    # rad, the free end's bend against the bend held short of it
    reach: CameraReach                            # how near the tube came to each camera
    fitted_end: float                             # m, where the fit's wall ended


class Reconstructor:
    def __init__(self, config: RigConfig):
        self.config = config
        self.geometry = config.robot
        self._prior: Centerline | None = None
        self._roi: tuple[np.ndarray, np.ndarray] | None = None
        self._roi_count = 0
        self._fused_within: tuple[np.ndarray, np.ndarray] | None = None  # the region the last fuse kept to
        # optical centre of each camera in the base frame, by camera index (viewing rays for relocation)
        self._camera_origins = config.camera_origins
        # each camera's optical frame in the base frame (4x4), by name in camera_names' order (the self-check)
        self._extrinsics = {name: config.cameras[name].extrinsic for name in config.camera_names}
        self.timings_ms: dict[str, float] = {}
        self._depth_steps: dict[str, float] = {}  # per camera, the depth quantisation seen in its first frame
        # per camera, the band its matcher spoils at depth edges (core.relocation.tip.edge_band) over its focal length
        # (an angle: the band in metres at any distance), measured when the tip first needs it on the latest
        # depth image noted until then (depth, unit, focal length), e.g. the first frame's
        self._edge_bands: dict[str, float] = {}
        self._edge_images: dict[str, tuple[np.ndarray, float, float]] = {}
        self._edge_attempts: dict[str, int] = {}  # images measured per camera, at most EDGE_BAND_ATTEMPTS
        self._mesh_reference = None  # relocation.reference_mesh, sampled once

    def reset(self) -> None:
        """Forget the previous centreline and region of interest (the next frame starts cold)."""
        self._prior = None
        self._roi = None

    def _timed(self, stage: str, start: float) -> None:
        self.timings_ms[stage] = (time.perf_counter() - start) * 1e3

    def fuse(self, pair: FramePair) -> Cloud:
        start = time.perf_counter()
        self._note_depth_steps(pair)
        cloud, self._fused_within = None, self._roi
        if self._roi is not None:
            cloud = fuse(pair, self.config, self._roi)
            if len(cloud) < 0.8 * self._roi_count:  # the robot moved out of the region: look everywhere
                cloud = None
        if cloud is None:
            cloud, self._fused_within = fuse(pair, self.config), None
        self._timed("fuse", start)
        return cloud

    def _note_depth_steps(self, pair: FramePair) -> None:
        """The depth step each camera's data show, measured once per camera (for the self-check); and its
        latest depth image while its edge band is not yet measured (for the tip: `_edge_band`)."""
        for name, frame in pair.frames.items():
            if frame.depth is None or name not in self.config.cameras:
                continue
            unit = frame.depth_unit if frame.depth_unit is not None else self.config.cameras[name].depth_unit
            if name not in self._depth_steps:
                self._depth_steps[name] = depth_step(frame.depth, unit)
            if (name not in self._edge_bands and frame.intrinsics is not None
                    and self._edge_attempts.get(name, 0) < EDGE_BAND_ATTEMPTS):
                self._edge_images[name] = (frame.depth, unit, frame.intrinsics.fx)

    def _edge_band(self, name: str) -> float:
        """The camera's edge band as an angle (rad), NaN while no depth image of it showed one."""
        if name not in self._edge_bands and name in self._edge_images:
            self._edge_attempts[name] = self._edge_attempts.get(name, 0) + 1
            angle = edge_band_angle(*self._edge_images.pop(name))
            if angle is not None:
                self._edge_bands[name] = angle
        return self._edge_bands.get(name, np.nan)

    def _edge_reach(self, bands: np.ndarray, footprint: float, centerline: Centerline) -> float:
        """How far (m) round the tube the cameras' matchers move a depth edge on it: their edge bands (per camera,
        `_edge_band`) at their distances from the robot's base (the mean over the cameras that measured one);
        without one, half a matcher's window (SILHOUETTE_MARGIN_PX pixel footprints)."""
        distances = np.linalg.norm(self._camera_origins - centerline.points[0], axis=1)
        measured = np.isfinite(bands)
        if not np.any(measured):
            return SILHOUETTE_MARGIN_PX * footprint
        return float(np.mean(bands[measured] * distances[measured]))

    def note_edge_band(self, camera: str, angle: float) -> None:
        """A camera's edge band (rad, `core.relocation.tip.edge_band_angle`) measured where its depth images are: in the
        graph by camera_node, as this process sees clouds only. ValueError for an unknown camera or a band
        that cannot be one."""
        if camera not in self.config.camera_names:
            raise ValueError(f"edge band of camera {camera!r}, which the rig configuration does not list")
        if not (math.isfinite(angle) and 0.0 <= angle < MAX_EDGE_BAND_RAD):
            raise ValueError(f"edge band of {camera} is {angle} rad: not in [0, {MAX_EDGE_BAND_RAD}) rad")
        self._edge_bands[camera] = float(angle)

    def filter(self, cloud: Cloud) -> Cloud:
        start = time.perf_counter()
        cloud = filter_cloud(cloud, self.config)
        self._timed("filter", start)
        return cloud

    def relocate(self, cloud: Cloud, warm_start: bool = True) -> RelocationResult:
        """Reference-guided relocation (paper Sec. IV) as the list of its steps, one module each:

        centreline -> alignment -> notches (and the notch side) -> tip -> relocation -> quality.
        """
        start = time.perf_counter()
        geometry, options = self.geometry, self.config.relocation
        minimum = 32
        if len(cloud) < minimum:
            raise ReconstructionError(f"only {len(cloud)} points left after filtering (need {minimum}): is the "
                                      "robot in view and inside the crop box?")
        settings = settings_for(geometry, cloud.pixel_footprint, options)
        seen_by = cloud.camera if cloud.camera is not None and len(cloud.camera) else None

        # 1. centreline: fixed-radius circle fits per slab, smoothed, iterated (core.relocation.centerline)
        centerline, iterations, coords, frames = self._centerline(cloud, settings, warm_start)
        fitted = _Axis(centerline, coords, frames)
        # 2. alignment: the reference tube shifted onto the wall points stereo measures without bias; each point
        # then as its camera saw it, along its viewing ray onto the wall (relocation.alignment, relocation.reference)
        aligned = self._align(cloud, fitted, settings, seen_by)
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
        bands = np.array([self._edge_band(name) for name in self.config.camera_names])
        sided = self._notches_and_side(axis, coarse_end, settings, wall, bands)
        axis, notches = sided.axis, sided.notches
        comb_centres = expected_centres(geometry, axis.centerline)  # where the robot's notches lie on the final frame
        # 5. tip, refined: the rim the stereo matcher erodes at depth edges given back, or the end cap seen
        end = self._seen_end(axis, notches, coarse_end, comb_centres, settings, bands, seen_by)
        # the coarse end may stop at the last cut, where little of a thinly seen ring is left: notches the refined
        # end now reaches past are looked for again (kept if more are found)
        if any(coarse_end <= centre + geometry.notch_width / 2 < end.tip_s for centre in comb_centres):
            again = self._find_notches(axis, end.tip_s, settings, wall)
            notches = again if len(again) > len(notches) else notches
        # how far the centreline may be off: what stereo beside the notches does to the wall (core.quality.measures)
        thinning = notched_thinning(axis.coords.radius - geometry.outer_radius, axis.coords.s,
                                    cut_intervals(geometry, axis.centerline, 0.0), end.tip_s, settings.gate,
                                    2 * settings.cell, spine=wall[0])
        looking = tuple(cameras_looking_into_slots(axis.centerline, geometry, self._camera_origins,
                                                   self.config.camera_names))
        centreline_off = centerline_uncertainty(aligned.cross_view.spread, thinning, looking,
                                                bool(aligned.backbone_shift)) or 0.0
        # 5'. tip along the tube: the robot's own length at the bend measured weighed in (core.relocation.tip)
        length = self._tip_by_length(cloud, axis.centerline, end, centreline_off, comb_centres, notches, settings,
                                     seen_by)
        centerline, along = length.centerline, length.along
        tip_s = along.s
        # the rims the matcher moves (over the cut faces the cameras see), against the spines' known length; a
        # notch whose width its bend rules out was misread, and is given its bend's
        notches, misread, unchecked = calibrate_and_check(notches, geometry, centerline,
                                                          None if seen_by is None else self._camera_origins,
                                                          along.seen_s if along.hidden_across is not None else tip_s)
        # 6. relocation: every point within the gate onto the reference surface (core.relocation.reference)
        tip_position, tip_tangents, _, _ = centerline.frames_at(np.array([tip_s]))
        tip, tip_tangent = tip_position[0], tip_tangents[0]
        reference_moved = None  # how far ICP moved its reference off the centreline's pose
        if options.method == "icp":  # the paper's KD-tree + ICP onto a reference (core.relocation.icp)
            moved, tip, reference_moved = self._relocate_by_icp(cloud, centerline, notches, tip_s, tip, tip_tangent,
                                                                settings.gate, settings.cell)
        else:
            moved = relocate_points(axis.coords, centerline, geometry, notches, tip_s, settings.gate, axis.rays)
        relocated = cloud.subset(moved.accepted, xyz=moved.points)
        # 7. quality: how sure this result is (core.quality.measures)
        quality, warnings = self._assess(
            axis, aligned, sided, end, length, notches=notches, settings=settings, seen_by=seen_by, tip=tip,
            thinning=thinning, looking=looking, misread=misread, unchecked=unchecked, comb_centres=comb_centres,
            reference_moved=reference_moved)
        # the next frame warm-starts from the fit's own fixed point, not from the aligned curve (else each call
        # would shift the curve once more, and results would depend on what came before)
        self._prior = fitted.centerline
        self._update_roi(relocated)
        self._timed("relocate", start)
        status = result_status(warnings, quality, self.config.quality)
        return RelocationResult(centerline.up_to(tip_s), tip, notches, relocated, moved.normals, moved.rejected,
                                axis.coords, iterations, moved.part, moved.coordinates, quality, tuple(warnings),
                                sided.notch_side, status)

    def _align(self, cloud: Cloud, fitted: _Axis, settings, seen_by: np.ndarray | None) -> _Aligned:
        """Step 2: the fitted axis moved onto the wall stereo measures without bias (core.relocation.alignment), checked
        against the tube's outline in each camera's view (relocation.outline) and levelled by the cameras facing the
        backbone; and each point moved along its viewing ray onto the wall (core.relocation.reference). Without the
        points' cameras (seen_by None: a cloud from elsewhere), the fit as it is."""
        if seen_by is None:
            return _Aligned(fitted)
        geometry, footprint = self.geometry, settings.cell
        viewpoints = np.take(self._camera_origins, seen_by, axis=0)
        end = tube_end(fitted.coords, geometry.outer_radius, settings.gate, footprint, max_s=geometry.reach)
        # trusted wall lies within the wall's band on the spines: the fit's gate, a millimetre wide, lets in
        # pixels a matcher mixed with the background behind, which pull the axis across the cameras' views
        trusted_gate = _wall_band_gate(fitted.coords, fitted.centerline, geometry, settings.gate, footprint)
        # which points face their camera depends on where the axis is: selected again about the moved axis
        alignment = align_to_trusted_wall(fitted.centerline, fitted.coords, fitted.frames, viewpoints, geometry,
                                          trusted_gate, footprint, end, xyz=cloud.xyz, passes=ALIGNMENT_PASSES)
        centerline = alignment.centerline
        coords, frames = centerline.project_with_frames(cloud.xyz, alignment.arc_lengths)
        # the alignment against the middle of the tube's outline in each camera's view: where it followed a wall
        # stereo moved across the views and the fit did not, the fit places the axis across them (relocation.outline)
        outline_of = functools.partial(outline_offset, xyz=cloud.xyz, viewpoints=viewpoints, camera=seen_by,
                                       geometry=geometry, gate=settings.gate, end_s=end)
        aligned_outline, across_from_fit = outline_of(coords, frames), None
        fit_outline = outline_of(fitted.coords, fitted.frames) if went_astray(aligned_outline, footprint) else None
        if fit_outline is not None and not went_astray(fit_outline, footprint):
            centerline = across_views_from(fitted.centerline, centerline, self._camera_origins)
            alignment = alignment.moved_to(centerline, fitted.centerline)
            coords, frames = centerline.project_with_frames(cloud.xyz, coords.s)
            across_from_fit = aligned_outline, fit_outline
        # how much the lean it removed varies along the tube: the axis is known no better (quality)
        scatter = shift_scatter(fitted.centerline, centerline, end)
        # the cameras facing the backbone place the axis along their views by the plain tube's level
        leveled, backbone_shift = level_by_backbone(centerline, coords, frames, viewpoints, seen_by,
                                                    self._camera_origins, geometry, trusted_gate, footprint, end)
        outline = aligned_outline if across_from_fit is None else None  # of the axis as it stands
        if leveled is not centerline:
            centerline, outline = leveled, None
            coords, frames = centerline.project_with_frames(cloud.xyz, coords.s)
        # what each camera alone says about the axis across its view: the fused axis is known no better
        cross_view = cross_view_spread(centerline, coords, frames, viewpoints, seen_by, len(self._camera_origins),
                                       geometry, trusted_gate, footprint, end)
        # each point as its camera saw it: along its viewing ray onto the wall
        rays = along_rays(coords, frames, viewpoints, geometry.outer_radius, settings.gate)
        return _Aligned(_Axis(centerline, coords, frames, rays), alignment, cross_view, backbone_shift,
                        # the axis against the middle of the tube's outline in each camera's view (depth errors lie
                        # along the rays)
                        outline_of(coords, frames) if outline is None else outline, across_from_fit, scatter)

    def _find_notches(self, axis: _Axis, tip_s: float, settings, wall) -> list[Notch]:
        """The robot's comb matched to the evidence about the axis, up to tip_s (core.relocation.notches)."""
        options = self.config.relocation
        return detect_notches(axis.measured, axis.centerline, geometry=self.geometry, gate=settings.gate,
                              footprint=settings.cell, kernel_px=options.notch_kernel_px,
                              min_width_fraction=options.min_notch_width_fraction, tip_s=tip_s,
                              observed=axis.coords, wall=wall)

    def _notches_and_side(self, axis: _Axis, tip_s: float, settings, wall, bands: np.ndarray) -> _Sided:
        """Step 4: the notches found in the configured frame; the side they open to measured, and where it is off
        the configured one the tube frame turned to it and the notches found again there (the robot's roll in its
        clamp is never exact)."""
        geometry, footprint = self.geometry, settings.cell
        found = self._find_notches(axis, tip_s, settings, wall)
        notch_side, unsettled, side_uncertainty = geometry.notch_side, None, None
        configured = axis, found
        for turn in range(2):  # the second pass measures in the turned frame (the window fits better there)
            # a dip is found where the comb puts it, not where its cut opens: no evidence of the side
            edged = [notch for notch in found if notch.edges_measured]
            side_measured = measure_notch_side(axis.coords, edged, geometry, axis.centerline, settings.gate,
                                               footprint, wall=wall)
            if side_measured is None:
                break
            roll, side_uncertainty, by_edges = side_measured
            if not by_edges:  # one edge or none placed the window: the matcher's smear of it is not cancelled
                side_uncertainty += self._edge_reach(bands, footprint, axis.centerline) / geometry.outer_radius
            if abs(roll) <= ROLL_TO_REFRAME:
                notch_side += roll  # reported as measured; too small a turn to find the notches again for
                break
            if turn:  # turned to the side measured, the notches should open there: a measurement that does
                # not settle is no measurement, and the configured frame is kept
                unsettled, side_uncertainty = (notch_side - geometry.notch_side, roll), None
                notch_side = geometry.notch_side
                axis, found = configured
                break
            turned = axis.rolled(roll)
            again = self._find_notches(turned, tip_s, settings, wall)
            if len(again) < len(found):
                side_uncertainty = None
                break  # the turned frame explains the data worse: the measurement was not to be trusted
            notch_side += roll
            axis, found = turned, again
        return _Sided(axis, found, notch_side, unsettled, side_uncertainty)

    def _seen_end(self, axis: _Axis, notches: list[Notch], coarse_end: float, comb_centres: np.ndarray, settings,
                  bands: np.ndarray, seen_by: np.ndarray | None) -> _SeenEnd:
        """Step 5: the end the cameras saw, refined from the coarse end: the end cap where the tube points at a
        camera, else each camera's rim with the band its matcher erodes given back (core.relocation.tip)."""
        geometry, footprint, centerline = self.geometry, settings.cell, axis.centerline
        # where a camera looks onto the end cap - wider in its image than 4 pixels, more than a matcher's
        # silhouette band - the end is that face (measured), not a rim the matcher erodes
        cap_seen = seen_by is not None and cap_faces_a_camera(centerline, coarse_end, self._camera_origins,
                                                              min(2 * footprint / geometry.outer_radius, 1.0))
        if cap_seen and cap_faces_a_camera(centerline, coarse_end, self._camera_origins, np.sin(CAP_PLANE_ANGLE)):
            # the tube points at a camera: its thinly seen wall cannot place the end, the cap's own points can; the
            # cap lies the distal ring's length past the last notch (a pile-up nearer it is that notch's cut face)
            last_cut = float(np.max(comb_centres)) + geometry.notch_width / 2
            cap = end_cap_plane(axis.measured, geometry.inner_radius, geometry.outer_radius, coarse_end,
                                geometry.outer_diameter, footprint, after=last_cut + geometry.distal_length / 2)
            if cap is None:
                return _SeenEnd(coarse_end, coarse_end, "coarse end (no end cap found)")
            # the matcher's smear of the cap's points bounds how well it placed it
            return _SeenEnd(cap[0], cap[0], "end cap", max(cap[1], footprint / 2), from_cap=True)
        if seen_by is None:
            return _SeenEnd(coarse_end, coarse_end, "coarse end (no camera seen)")
        # each camera's end where its wall points thin to half, plus the band its matcher spoils at depth
        # edges, measured in its depth images, as far as it reaches into the end's outline in its image
        # (where the end turns towards a camera, the cap makes that outline; core.relocation.tip)
        intervals = np.array([(n.start_s - 2 * footprint, n.end_s + 2 * footprint) for n in notches])
        rim = rim_tip(axis.coords, seen_by, self._camera_origins, centerline, coarse_end, geometry.outer_radius,
                      settings.gate, footprint, self.config.relocation.notch_kernel_px * footprint, bands,
                      ~inside_intervals(axis.coords.s, intervals), 2 * geometry.notch_pitch,
                      last_notch_s=float(np.max(comb_centres)))
        if rim is not None:
            eroded_end, tip_s, tip_uncertainty = rim
            return _SeenEnd(tip_s, eroded_end, "half-density end + edge band measured in the depth images",
                            tip_uncertainty)
        if cap_seen:
            return _SeenEnd(coarse_end, coarse_end, "coarse end (the end turns towards a camera; no edge band "
                                                    "measured)")
        # no depth images (clouds only): the erosion the silhouettes show, given back
        tip_s = give_back_erosion(coarse_end, axis.coords, axis.frames, seen_by, self._camera_origins,
                                  geometry.outer_radius, settings.gate, [(n.start_s, n.end_s) for n in notches],
                                  footprint)
        return _SeenEnd(tip_s, coarse_end, "coarse end + silhouette erosion (no edge band: no depth images with a "
                                           "far background)")

    def _tip_by_length(self, cloud: Cloud, centerline: Centerline, end: _SeenEnd, centreline_off: float,
                       comb_centres: np.ndarray, notches: list[Notch], settings, seen_by: np.ndarray | None
                       ) -> _ByLength:
        """Step 5': the tip along the tube, the end seen weighed with the robot's own length at the bend measured
        (core.relocation.tip); carried on to that length where every camera was kept from seeing the rest."""
        geometry, footprint, tip_s = self.geometry, settings.cell, end.tip_s
        # a tip left at the coarse end is known as well as the band the matcher spoils there, not given back
        # (assess is told no uncertainty then: nothing measured the erosion given back)
        seen_uncertainty = (end.tip_uncertainty if end.tip_uncertainty is not None
                            else self._unrefined_tip_uncertainty(centerline, tip_s, footprint))
        # the fit reaches as far as the tube's wall is seen whole; the tip may lie beyond, over a last notch seen
        # thinly: the curve carries on bending there as the notches before it did
        fitted_end = centerline.length
        centerline = continued_bend(centerline, geometry.reach, comb_centres, geometry)
        # the robot's own length, at the bend measured, is a measurement of the tip too (relocation.tip); the bend is
        # known as well as the centreline's turn over a notch pitch, and as the curve's free end, whose tangent
        # follows only the data before it, agrees with the bend read short of it (held_bend)
        total_bend = turn_from_base(centerline, geometry, tip_s)
        expected_length = geometry.bent_length(total_bend)
        held = held_bend(centerline, geometry, tip_s, comb_centres)
        end_turn_off = None if held is None else abs(total_bend - held)
        length_known = None if geometry.length_tolerance is None else float(np.linalg.norm([
            geometry.length_tolerance, geometry.neutral_axis_offset * centreline_off / geometry.notch_pitch,
            geometry.neutral_axis_offset * (end_turn_off or 0.0)]))
        # the cap's points only ever lie short of it (the matcher mixes its ring with the bore behind): a lower bound
        along = with_known_length(tip_s, seen_uncertainty, expected_length, length_known, lower_bound=end.from_cap)
        # how near the tube comes to each camera, carried on past the end seen to the robot's length
        reach = camera_reach(continued_bend(centerline.up_to(tip_s), expected_length, comb_centres, geometry),
                             tip_s, expected_length, geometry.outer_radius, footprint, self._extrinsics, cloud.xyz,
                             seen_by)
        # an end seen far short of the robot's length where every camera was kept from seeing the rest (nearer than
        # its depth range, pointing at it): the robot goes on there, bending as the notches seen did (two at least)
        if (along.disagreement > LENGTH_AGREEMENT_SIGMAS and sum(n.edges_measured for n in notches) >= 2
                and reach.why_unseen(list(self.config.camera_names), tip_s, expected_length, continued=True)):
            for _ in range(2):  # the hidden notches' own bend shortens the centreline further
                total_bend = turn_from_base(centerline, geometry, expected_length)
                expected_length = geometry.bent_length(total_bend)
            along = carried_to_length(replace(along, expected_s=expected_length), centerline)
        return _ByLength(centerline, along, total_bend, end_turn_off, reach, fitted_end)

    def _assess(self, axis: _Axis, aligned: _Aligned, sided: _Sided, end: _SeenEnd, length: _ByLength, *,
                notches: list[Notch], settings, seen_by, tip: np.ndarray, thinning, looking, misread, unchecked,
                comb_centres: np.ndarray, reference_moved: ReferenceMove | None) -> tuple[dict, list[Finding]]:
        """Step 7: the self-check (core.quality.measures): how sure this result is, in figures and in plain words."""
        geometry, alignment = self.geometry, aligned.alignment
        offset = axis.coords.radius - geometry.outer_radius
        level, _ = surface_band(offset, settings.gate)
        near_wall = np.abs(offset - level) < settings.gate
        wall_residual = float(np.sqrt(np.mean((offset[near_wall] - level) ** 2))) if np.any(near_wall) else 0.0
        quality, warnings = assess(Trace(
            geometry=geometry, camera_names=self.config.camera_names, notches=notches,
            coords_s=axis.measured.s, camera=seen_by, tip_s=length.along.s, total_bend=length.total_bend,
            footprint=settings.cell, wall_residual=wall_residual, notch_side=sided.notch_side,
            configured_side=geometry.notch_side,
            bias_notch_side=0.0 if alignment is None else alignment.bias_notch_side,
            bias_binormal=0.0 if alignment is None else alignment.bias_binormal, depth_steps=dict(self._depth_steps),
            tip_erosion=end.tip_s - end.eroded_end, tip_uncertainty=end.tip_uncertainty, tip_position=tip,
            tip_along=length.along, crop_box=self.config.crop_box(),
            notched_thinning=thinning, looking_into_slots=looking, tip_from_cap=end.from_cap,
            side_unsettled=sided.unsettled, side_uncertainty=sided.side_uncertainty,
            cross_view_spread=aligned.cross_view.spread, distal_cross_view=aligned.cross_view.distal,
            cross_view_offsets=aligned.cross_view.offsets,
            centerline_tolerance=self.config.quality.centerline_tolerance,
            alignment_scatter=aligned.scatter, outline_offset=aligned.outline, across_from_fit=aligned.across_from_fit,
            unsupported=aligned.cross_view.unsupported, backbone_shift=aligned.backbone_shift, misread_widths=misread,
            held_shift=None if alignment is None else (alignment.end_shift, alignment.held_from),
            unchecked=unchecked, reach=length.reach,
            notch_centres=comb_centres, wall_level=level, fitted_end=length.fitted_end,
            reference_moved=reference_moved))
        backbone_shift, side_uncertainty = aligned.backbone_shift, sided.side_uncertainty
        quality = {**quality, "tip_refinement": end.refinement,
                   "centerline_backbone_shift_mm": None if backbone_shift is None else backbone_shift * 1e3,
                   # None: the side could not be measured (or did not settle): the configured one is kept
                   "notch_side_uncertainty_deg": None if side_uncertainty is None else float(np.degrees(
                       side_uncertainty)),
                   "edge_band_mrad": {name: band * 1e3 for name, band in self._edge_bands.items()},
                   "robot_bend_end_off_deg": None if length.end_turn_off is None else float(np.degrees(
                       length.end_turn_off))}
        return quality, warnings

    def _unrefined_tip_uncertainty(self, centerline: Centerline, tip_s: float, footprint: float) -> float:
        """How well a tip left at the coarse end is known along the tube: half a pixel for the end, and the band
        the stereo matcher spoils at depth edges, not given back (the widest band measured, at the tip's distance
        from its camera; none measured, UNMEASURED_EDGE_BAND_PX)."""
        tip = centerline.frames_at(np.array([tip_s]))[0][0]
        bands = [self._edge_band(name) * float(np.linalg.norm(origin - tip))
                 for name, origin in zip(self.config.camera_names, self._camera_origins, strict=True)]
        measured = [band for band in bands if np.isfinite(band)]
        return footprint / 2 + (max(measured) if measured else UNMEASURED_EDGE_BAND_PX * footprint)

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

    def _centerline(self, cloud: Cloud, settings, warm_start: bool):
        prior = self._prior if warm_start else None
        viewpoints = self._camera_origins if cloud.camera is not None and len(cloud.camera) else None
        centerline, iterations, (coords, frames, exact) = estimate_centerline(cloud.xyz, self.geometry, settings,
                                                                              prior, viewpoints)
        if centerline.length < 2 * settings.bin_length:
            self._prior = None
            raise ReconstructionError("no tube found along the robot's base axis: is the robot in view and the "
                                      "base pose in the configuration right?")
        if not exact:
            coords, frames = centerline.project_with_frames(cloud.xyz, None if coords is None else coords.s)
        return centerline, iterations, coords, frames

    def _update_roi(self, relocated: Cloud) -> None:
        """Region of interest for the next frame: the robot's bounding box, grown, inside the crop box."""
        if len(relocated) < 32:
            self._roi = None
            return
        margin = self.config.relocation.roi_margin_fraction * self.geometry.length + self.geometry.outer_diameter
        box_min, box_max = self.config.crop_box()
        low, high = _bounds(relocated.xyz)
        self._roi = (np.maximum(low - margin, box_min), np.minimum(high + margin, box_max))
        self._roi_count = len(relocated)

    def mesh(self, relocation: RelocationResult):
        """The configured mesher: `tube` (the relocated outer wall meshed on the tube's own grid) or
        `poisson` (open3d's screened Poisson, the paper's Eq. 7-8)."""
        from ntcr_recon.core.reconstruction.mesh import poisson_mesh, tube_mesh  # open3d is imported only by who meshes

        start = time.perf_counter()
        if self.config.mesh.method == "tube":
            mesh = tube_mesh(relocation, self.geometry)
        else:
            mesh = poisson_mesh(relocation.relocated.xyz, relocation.normals, self.config.mesh)
        self._timed("mesh", start)
        return mesh

    def process(self, pair: FramePair, with_mesh: bool = False) -> FrameResult:
        """fuse -> filter -> relocate (-> mesh) on one frame pair.

        The frame is fused around the robot's last box (the region of interest) when there is one; where the
        robot found reaches that box's side, or none is found in it, the box may have cut it (the robot moved, or
        the last frame saw only part of it), and the frame is done again over the whole crop box, warm-started as
        the first pass was (timings_ms: the two passes' sums)."""
        self.timings_ms = {}
        prior = self._prior

        def chain() -> tuple[Cloud, Cloud, RelocationResult]:
            fused = self.fuse(pair)
            filtered = self.filter(fused)
            return fused, filtered, self.relocate(filtered)

        try:
            fused, filtered, relocation = chain()
            again = self._fused_within is not None and _reaches_side(
                relocation.relocated.xyz, self._fused_within, self.config.crop_box(), self.geometry.outer_diameter)
        except ReconstructionError:
            if self._fused_within is None:
                raise
            again = True
        if again:
            first, self._roi, self._prior = self.timings_ms, None, prior
            self.timings_ms = {}
            fused, filtered, relocation = chain()
            self.timings_ms = {stage: first.get(stage, 0.0) + ms for stage, ms in self.timings_ms.items()}
        mesh = self.mesh(relocation) if with_mesh else None
        return FrameResult(fused, filtered, relocation, mesh, dict(self.timings_ms))


def _reaches_side(xyz: np.ndarray, box: tuple[np.ndarray, np.ndarray], crop: tuple[np.ndarray, np.ndarray],
                  distance: float) -> bool:
    """Whether points come within `distance` of a side of `box` that lies inside the crop box (a side on the
    crop box's own cuts nothing the crop box would not)."""
    if not len(xyz):
        return False
    low, high = _bounds(xyz)
    inside_low, inside_high = box[0] > crop[0], box[1] < crop[1]
    return bool(np.any(inside_low & (low - box[0] < distance)) or np.any(inside_high & (box[1] - high < distance)))


def _bounds(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (N, 3) points' axis-aligned bounds (low, high)."""
    # a column at a time: min/max over the long axis of an (N, 3) array cost ten times more
    columns = xyz.T
    return np.array([c.min() for c in columns]), np.array([c.max() for c in columns])


def _wall_band_gate(coords: TubeCoordinates, centerline: Centerline, geometry, gate: float, footprint: float
                    ) -> float:
    """The gate of the wall points the alignment trusts (m): the outer wall's band on the spines (its level's
    distance from r_o plus its spread, notches.spine_wall), never wider than the fit's gate."""
    _, level, spread = spine_wall(coords, centerline, geometry, gate, footprint)
    return band_gate(level, spread, gate)


def _rolled_axes(normal: np.ndarray, binormal: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-point frame axes turned by `angle` about the tangent (as Centerline.rolled)."""
    c, s = np.cos(angle), np.sin(angle)
    return c * normal + s * binormal, c * binormal - s * normal


