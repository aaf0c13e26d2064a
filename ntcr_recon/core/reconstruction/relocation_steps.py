"""The steps of the relocation (paper Sec. IV) as `core.reconstruction.relocate.Relocator.relocate` runs them,
each a function of the frame's `Scene` and what the steps before it handed on:

    align               step 2: the fitted axis onto the wall stereo measures without bias (align_step)
    notches_and_side    step 4: the notches (find_notches, again past a refined end), and the side they open to
    seen_end            step 5: the end the cameras saw
    centreline_thinning how far the centreline may be off (the wall read deep beside the notches)
    tip_by_length       step 5': the tip along the tube, the robot's known length weighed in
    assess              step 7: the self-check
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.quality.checks import assess as assess_trace
from ntcr_recon.core.quality.findings import Z90, Finding
from ntcr_recon.core.quality.measures import (
    CameraReach,
    camera_reach,
    cameras_looking_into_slots,
    centerline_uncertainty,
    notched_thinning,
)
from ntcr_recon.core.quality.trace import Trace, missing_views
from ntcr_recon.core.reconstruction.edge_bands import EdgeBands
from ntcr_recon.core.relocation.alignment import (
    SILHOUETTE_MARGIN_PX,
    Alignment,
)
from ntcr_recon.core.relocation.bend_plane import BendPlane, base_offset
from ntcr_recon.core.relocation.bends import continued_bend, held_bend, turn_from_base
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates, cameras_round_tube
from ntcr_recon.core.relocation.centerline_fit import CenterlineSettings
from ntcr_recon.core.relocation.cross_view import CrossView
from ntcr_recon.core.relocation.icp import ReferenceMove
from ntcr_recon.core.relocation.limbs import CameraView, LimbFigures
from ntcr_recon.core.relocation.notch_side import measure_notch_side
from ntcr_recon.core.relocation.notches import Notch, detect_notches
from ntcr_recon.core.relocation.outline_notches import comb_shift_in_outline, notches_in_outline
from ntcr_recon.core.relocation.tip import (
    LENGTH_AGREEMENT_SIGMAS,
    RimViews,
    TipAlongTube,
    cap_faces_a_camera,
    carried_to_length,
    end_cap_plane,
    give_back_erosion,
    rim_tip,
    with_known_length,
)
from ntcr_recon.core.relocation.wall import surface_band
from ntcr_recon.core.robot.comb import cut_intervals, inside_intervals

# A measured notch side further than this from the configured one turns the tube frame (smaller: within
# what the measurement scatters, and the open window is wide enough for it).
ROLL_TO_REFRAME = np.radians(6.0)

# A tube whose end tangent turns at least this far towards a camera (from across its view) points at it.
CAP_PLANE_ANGLE = np.radians(45.0)

# The band a stereo matcher spoils at a depth edge, where no depth image measured it: half a D405's 7 px window.
UNMEASURED_EDGE_BAND_PX = 3.5


@dataclass(frozen=True)
class Scene:
    """What every step of one relocation reads: the rig, the cloud, the fit's settings, the cameras."""

    config: RigConfig
    cloud: Cloud
    settings: CenterlineSettings
    seen_by: np.ndarray | None          # each point's camera index; None: a cloud from elsewhere
    origins: np.ndarray                 # each camera's optical centre in the base frame, by camera index
    edge_bands: EdgeBands               # the cameras' edge bands (core.reconstruction.edge_bands)
    depth_steps: dict[str, float]       # per camera, the depth quantisation seen in its first frame
    bands: np.ndarray | None = None     # rad per camera index (NaN: not measured), once the notches need them
    views: dict[str, CameraView] = field(default_factory=dict)  # the cameras' colour images, where the data had them

    @property
    def geometry(self):
        return self.config.robot

    @property
    def extrinsics(self) -> dict[str, np.ndarray]:
        """Each camera's optical frame in the base frame (4x4), by name in camera_names' order."""
        return {name: self.config.cameras[name].extrinsic for name in self.config.camera_names}


# What each step hands on to the next.

@dataclass(frozen=True)
class Axis:
    """An axis and the cloud's points about it, replaced whole where a step moves or turns the axis."""

    centerline: Centerline
    coords: TubeCoordinates         # the points about the axis
    frames: tuple                   # (position, tangent, normal, binormal) at each point's s
    rays: tuple | None = None       # relocation.reference.along_rays: the points along their viewing rays onto the wall

    @property
    def measured(self) -> TubeCoordinates:
        """The points as their cameras saw them (along their viewing rays onto the wall), else as fused."""
        return self.coords if self.rays is None else self.rays[0]

    def rolled(self, angle: float) -> Axis:
        """The same axis with its frame turned by `angle` about the tangent (towards the notch side measured)."""
        position, tangent, normal, binormal = self.frames
        return Axis(self.centerline.rolled(angle), self.coords.rolled(angle),
                    (position, tangent, *_rolled_axes(normal, binormal, angle)),
                    None if self.rays is None else (self.rays[0].rolled(angle), self.rays[1]))


@dataclass(frozen=True)
class Aligned:
    """Step 2: the axis moved onto the trusted wall, and what the checks on it found (None: no cameras known)."""

    axis: Axis
    alignment: Alignment | None = None
    cross_view: CrossView = CrossView(None)
    backbone_shift: float | None = None           # m, backbone.level_by_backbone's
    outline: float | None = None                  # m, outline.outline_offset of the final axis
    across_from_fit: tuple[float, float] | None = None  # the aligned and fitted axes' outline offsets (fit taken)
    scatter: float | None = None                  # m, alignment.shift_scatter
    limbs: LimbFigures | None = None              # what the limbs in the colour images did (None: no image)
    outline_rigid: tuple[float, float] | None = None  # outline.outline_rigid_offset about the final axis
    bend_plane: BendPlane | None = None           # the axis held to the bend plane (None: not held)
    steps: tuple[tuple[str, Centerline], ...] = ()  # the axis after each step that moved it: (step, axis), in order


@dataclass(frozen=True)
class Sided:
    """Step 4: the notches, found in the frame turned to the side they open to (where it was measured)."""

    axis: Axis
    notches: list[Notch]
    notch_side: float                             # rad, measured (or the configured one)
    unsettled: tuple[float, float] | None         # a turn that did not settle: (turned by, then measured off)
    side_uncertainty: float | None                # rad; None: the side not measured
    ruled_out: tuple[float, float] | None = None  # a side the robot's bend rules out: (measured off, known to)


@dataclass(frozen=True)
class SeenEnd:
    """Step 5: the end the cameras saw."""

    tip_s: float
    eroded_end: float                             # the end before the rim a matcher erodes was given back
    refinement: str                               # how it was placed (quality's tip_refinement)
    tip_uncertainty: float | None = None          # m along the tube; None: nothing measured the erosion
    from_cap: bool = False                        # placed on the end cap's points (a lower bound)


@dataclass(frozen=True)
class ByLength:
    """Step 5': the tip along the tube with the robot's known length weighed in."""

    centerline: Centerline                        # carried on past the fit's end, bending as the notches did
    along: TipAlongTube                           # core.relocation.tip.with_known_length's (or carried_to_length's)
    total_bend: float                             # rad, at the tip
    end_turn_off: float | None                    # rad, the free end's bend against the bend held short of it
    reach: CameraReach                            # how near the tube came to each camera
    fitted_end: float                             # m, where the fit's wall ended


@dataclass(frozen=True)
class Thinning:
    """How far the centreline may be off: what stereo beside the notches does to the wall."""

    thinning: object                              # core.quality.measures.notched_thinning's
    looking: tuple                                # the cameras looking into the slots
    off: float                                    # m, core.quality.measures.centerline_uncertainty (0: none)


def find_notches(scene: Scene, axis: Axis, tip_s: float, wall) -> list[Notch]:
    """The robot's comb matched to the evidence about the axis, up to tip_s (core.relocation.notches)."""
    options, settings = scene.config.relocation, scene.settings
    in_views = (axis.centerline, scene.views, scene.geometry)
    outline = functools.partial(notches_in_outline, *in_views, end_s=tip_s) if scene.views else None
    comb_shift = functools.partial(comb_shift_in_outline, *in_views, end_s=tip_s) if scene.views else None
    return detect_notches(axis.measured, axis.centerline, geometry=scene.geometry, gate=settings.gate,
                          footprint=settings.cell, kernel_px=options.notch_kernel_px,
                          min_width_fraction=options.min_notch_width_fraction, tip_s=tip_s,
                          observed=axis.coords, wall=wall, outline=outline, comb_shift=comb_shift)


def notches_and_side(scene: Scene, axis: Axis, tip_s: float, wall, plane: BendPlane | None = None) -> Sided:
    """Step 4: the notches found in the configured frame; the side they open to measured, and where it is off
    the configured one the tube frame turned to it and the notches found again there (the robot's roll in its
    clamp is never exact), unless the plane the robot bends in (relocation.bend_plane) rules that roll out."""
    geometry, settings, footprint = scene.geometry, scene.settings, scene.settings.cell
    found = find_notches(scene, axis, tip_s, wall)
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
        # one edge or none placed the window, or each was seen by another camera: one's smear is not the other's
        if not by_edges or not _one_camera_faces_both_edges(scene, axis, edged, roll):
            side_uncertainty += _edge_reach(scene, footprint, axis.centerline) / geometry.outer_radius
        if plane is not None:  # the plane the robot bends in measures its roll too (off the configured side)
            turned_by = notch_side - geometry.notch_side
            if plane.rules_out(turned_by + roll, side_uncertainty):
                return Sided(*configured, geometry.notch_side, None, None, (turned_by + roll, side_uncertainty))
            if plane.shown is not None:  # stated as a bound, as the edges' is: Z90 times the SD of the two together
                weighed, sd = plane.weighed_with(turned_by + roll, side_uncertainty)
                roll, side_uncertainty = weighed - turned_by, Z90 * sd
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
        again = find_notches(scene, turned, tip_s, wall)
        # judged by what depth found in each frame's notch window (the outlines' are the same in any frame)
        if sum(n.signal != "outline" for n in again) < sum(n.signal != "outline" for n in found):
            side_uncertainty = None
            break  # the turned frame explains the data worse: the measurement was not to be trusted
        notch_side += roll
        axis, found = turned, again
    return Sided(axis, found, notch_side, unsettled, side_uncertainty)


def seen_end(scene: Scene, axis: Axis, notches: list[Notch], coarse_end: float, comb_centres: np.ndarray
             ) -> SeenEnd:
    """Step 5: the end the cameras saw, refined from the coarse end: the end cap where the tube points at a
    camera, else each camera's rim with the band its matcher erodes given back (core.relocation.tip)."""
    settings, seen_by = scene.settings, scene.seen_by
    geometry, footprint, centerline = scene.geometry, settings.cell, axis.centerline
    # a camera looking onto the end cap (wider than 4 px, a matcher's band): the end is that face, not an eroded rim
    cap_seen = seen_by is not None and cap_faces_a_camera(centerline, coarse_end, scene.origins,
                                                          min(2 * footprint / geometry.outer_radius, 1.0))
    if cap_seen and cap_faces_a_camera(centerline, coarse_end, scene.origins, np.sin(CAP_PLANE_ANGLE)):
        # the tube points at a camera: its thinly seen wall cannot place the end, the cap's own points can; the
        # cap lies the distal ring's length past the last notch (a pile-up nearer it is that notch's cut face)
        last_cut = float(np.max(comb_centres)) + geometry.notch_width / 2
        cap = end_cap_plane(axis.measured, geometry.inner_radius, geometry.outer_radius, coarse_end,
                            geometry.outer_diameter, footprint, after=last_cut + geometry.distal_length / 2)
        if cap is None:
            return SeenEnd(coarse_end, coarse_end, "coarse end (no end cap found)")
        # the matcher's smear of the cap's points bounds how well it placed it
        return SeenEnd(cap[0], cap[0], "end cap", max(cap[1], footprint / 2), from_cap=True)
    if seen_by is None:
        return SeenEnd(coarse_end, coarse_end, "coarse end (no camera seen)")
    # each camera's end where its wall points thin to half, plus the band its matcher spoils at depth
    # edges, measured in its depth images, as far as it reaches into the end's outline in its image
    # (where the end turns towards a camera, the cap makes that outline; core.relocation.tip)
    intervals = np.array([(n.start_s - 2 * footprint, n.end_s + 2 * footprint) for n in notches])
    rim = rim_tip(axis.coords, RimViews(seen_by, scene.origins, scene.bands), centerline, coarse_end,
                  geometry.outer_radius, settings.gate, footprint, scene.config.relocation.notch_kernel_px * footprint,
                  ~inside_intervals(axis.coords.s, intervals), 2 * geometry.notch_pitch,
                  last_notch_s=float(np.max(comb_centres)))
    if rim is not None:
        eroded_end, tip_s, tip_uncertainty = rim
        return SeenEnd(tip_s, eroded_end, "half-density end + edge band measured in the depth images",
                       tip_uncertainty)
    if cap_seen:
        return SeenEnd(coarse_end, coarse_end, "coarse end (the end turns towards a camera; no edge band "
                                               "measured)")
    # no depth images (clouds only): the erosion the silhouettes show, given back
    tip_s = give_back_erosion(coarse_end, axis.coords, axis.frames, seen_by, scene.origins,
                              geometry.outer_radius, settings.gate, [(n.start_s, n.end_s) for n in notches],
                              footprint)
    return SeenEnd(tip_s, coarse_end, "coarse end + silhouette erosion (no edge band: no depth images with a "
                                      "far background)")


def centreline_thinning(scene: Scene, aligned: Aligned, axis: Axis, wall, tip_s: float) -> Thinning:
    """How far the centreline may be off: what stereo beside the notches does to the wall
    (core.quality.measures)."""
    geometry, settings = scene.geometry, scene.settings
    thinning = notched_thinning(axis.coords.radius - geometry.outer_radius, axis.coords.s,
                                cut_intervals(geometry, axis.centerline, 0.0), tip_s, settings.gate,
                                2 * settings.cell, spine=wall[0])
    looking = tuple(cameras_looking_into_slots(axis.centerline, geometry, scene.origins, scene.config.camera_names))
    off = centerline_uncertainty(aligned.cross_view.spread, thinning, looking, bool(aligned.backbone_shift),
                                 limbs=limbs_across(aligned, tip_s, geometry.notch_pitch),
                                 level_scatter=aligned.cross_view.level_scatter,
                                 bend_plane=aligned.bend_plane) or 0.0
    return Thinning(thinning, looking, off)


def limbs_across(aligned: Aligned, tip_s: float, window: float) -> tuple[float, float, float | None] | None:
    """Where the limbs placed the axis across the views (quality.measures.centerline_uncertainty): their
    disagreement (m), the share of the windows up to tip_s they placed (the fewest any camera placed: the least
    squares needs every camera in a window) and LimbFigures.interpolated; None: none placed, or one camera alone."""
    limbs = aligned.limbs
    if limbs is None or limbs.disagreement is None or len(limbs.windows) < 2:
        return None
    return (limbs.disagreement, min(min(limbs.windows.values()) / max(np.ceil(tip_s / window), 1.0), 1.0),
            limbs.interpolated)


def tip_by_length(scene: Scene, centerline: Centerline, end: SeenEnd, centreline_off: float,
                  comb_centres: np.ndarray, notches: list[Notch]) -> ByLength:
    """Step 5': the tip along the tube, the end seen weighed with the robot's own length at the bend measured
    (core.relocation.tip); carried on to that length where every camera was kept from seeing the rest."""
    geometry, footprint, tip_s = scene.geometry, scene.settings.cell, end.tip_s
    # a tip left at the coarse end is known as well as the band the matcher spoils there (none given back)
    seen_uncertainty = (end.tip_uncertainty if end.tip_uncertainty is not None
                        else _unrefined_tip_uncertainty(scene, centerline, tip_s, footprint))
    # the fit reaches as far as the wall is seen whole; past it the curve carries on bending as the notches did
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
                         tip_s, expected_length, geometry.outer_radius, footprint, scene.extrinsics,
                         scene.cloud.xyz, scene.seen_by)
    # an end seen far short of the robot's length where every camera was kept from seeing the rest (nearer than
    # its depth range, pointing at it): the robot goes on there, bending as the notches seen did (two at least,
    # found by any signal: an outline's or a dip's bend is its spines' chords', as an edged one's)
    if (along.disagreement > LENGTH_AGREEMENT_SIGMAS and len(notches) >= 2
            and reach.why_unseen(list(scene.config.camera_names), tip_s, expected_length, continued=True)):
        for _ in range(2):  # the hidden notches' own bend shortens the centreline further
            total_bend = turn_from_base(centerline, geometry, expected_length)
            expected_length = geometry.bent_length(total_bend)
        along = carried_to_length(replace(along, expected_s=expected_length), centerline)
    return ByLength(centerline, along, total_bend, end_turn_off, reach, fitted_end)


def assess(scene: Scene, aligned: Aligned, sided: Sided, end: SeenEnd, length: ByLength, *, notches: list[Notch],
           tip: np.ndarray, thinning: Thinning, misread, unchecked, comb_centres: np.ndarray,
           reference_moved: ReferenceMove | None) -> tuple[dict, list[Finding]]:
    """Step 7: the self-check (core.quality.checks): how sure this result is, in figures and in plain words."""
    geometry, alignment, axis, settings = scene.geometry, aligned.alignment, sided.axis, scene.settings
    offset = axis.coords.radius - geometry.outer_radius
    level, _ = surface_band(offset, settings.gate)
    near_wall = np.abs(offset - level) < settings.gate
    wall_residual = float(np.sqrt(np.mean((offset[near_wall] - level) ** 2))) if np.any(near_wall) else 0.0
    held_shift, distal_cross_view, end_by_limbs = _distal_across(aligned, length.along.s, geometry.notch_pitch)
    quality, warnings = assess_trace(Trace(
        geometry=geometry, camera_names=scene.config.camera_names, notches=notches,
        coords_s=axis.measured.s, camera=scene.seen_by, tip_s=length.along.s, total_bend=length.total_bend,
        footprint=settings.cell, wall_residual=wall_residual, notch_side=sided.notch_side,
        configured_side=geometry.notch_side,
        bias_notch_side=0.0 if alignment is None else alignment.bias_notch_side,
        bias_binormal=0.0 if alignment is None else alignment.bias_binormal, depth_steps=dict(scene.depth_steps),
        tip_erosion=end.tip_s - end.eroded_end, tip_uncertainty=end.tip_uncertainty, tip_position=tip,
        tip_along=length.along, crop_box=scene.config.crop_box(),
        notched_thinning=thinning.thinning, looking_into_slots=thinning.looking, tip_from_cap=end.from_cap,
        side_unsettled=sided.unsettled, side_uncertainty=sided.side_uncertainty, side_ruled_out=sided.ruled_out,
        cross_view_spread=aligned.cross_view.spread, distal_cross_view=distal_cross_view,
        level_scatter=aligned.cross_view.level_scatter, bend_plane=aligned.bend_plane,
        limbs_across=limbs_across(aligned, length.along.s, geometry.notch_pitch),
        cross_view_offsets=aligned.cross_view.offsets,
        limbs_rigid=None if aligned.limbs is None else aligned.limbs.rigid, outline_rigid=aligned.outline_rigid,
        centerline_tolerance=scene.config.quality.centerline_tolerance,
        alignment_scatter=aligned.scatter, outline_offset=aligned.outline, across_from_fit=aligned.across_from_fit,
        unsupported=aligned.cross_view.unsupported, backbone_shift=aligned.backbone_shift, misread_widths=misread,
        held_shift=held_shift, end_by_limbs=end_by_limbs, unchecked=unchecked, reach=length.reach,
        colour_missing=missing_views(scene.config, scene.cloud, scene.views),
        notch_centres=comb_centres, wall_level=level, fitted_end=length.fitted_end,
        reference_moved=reference_moved, base_offset=base_offset(length.centerline, axis.measured.s, geometry)))
    backbone_shift, side_uncertainty = aligned.backbone_shift, sided.side_uncertainty
    quality = {**quality, "tip_refinement": end.refinement,
               "centerline_backbone_shift_mm": None if backbone_shift is None else backbone_shift * 1e3,
               # None: the side could not be measured (or did not settle): the configured one is kept
               "notch_side_uncertainty_deg": None if side_uncertainty is None else float(np.degrees(
                   side_uncertainty)),
               "edge_band_mrad": {name: band * 1e3 for name, band in scene.edge_bands.angles.items()},
               # the notch pitches whose limbs in each camera's colour image placed the axis across its view, how
               # far that moved it, how far a window they did not place may be off (None: no colour image)
               "centerline_limbs": None if (limbs := aligned.limbs) is None else {
                   "windows": dict(limbs.windows), "moved_mm": limbs.moved_rms * 1e3,
                   "disagreement_mm": None if limbs.disagreement is None else limbs.disagreement * 1e3,
                   "interpolated_mm": None if limbs.interpolated is None else limbs.interpolated * 1e3},
               "robot_bend_end_off_deg": None if length.end_turn_off is None else float(np.degrees(
                   length.end_turn_off))}
    return quality, warnings


def _distal_across(aligned: Aligned, tip_s: float, window: float) -> tuple[tuple | None, float | None, bool]:
    """What holds the axis across the views at the free end: (the alignment's held shift of the end, as far as
    nothing measured it; the cameras' spread across their views there; whether the limbs placed it). Where the
    limbs placed the axis in the last window before the tip, they measured it across the views: the held shift
    counts along them only, the spread is the limbs' (their disagreement) instead of depth's."""
    alignment, limbs = aligned.alignment, aligned.limbs
    by_limbs = (limbs is not None and limbs.disagreement is not None and limbs.reach >= tip_s - window)
    held = None if alignment is None else (
        limbs.unchecked(alignment.end_move, tip_s - window) if by_limbs and alignment.end_move is not None
        else alignment.end_shift, alignment.held_from)
    return held, limbs.disagreement if by_limbs else aligned.cross_view.distal, by_limbs


def _unrefined_tip_uncertainty(scene: Scene, centerline: Centerline, tip_s: float, footprint: float) -> float:
    """How well a tip left at the coarse end is known along the tube: half a pixel for the end, and the band
    the stereo matcher spoils at depth edges, not given back (the widest band measured, at the tip's distance
    from its camera; none measured, UNMEASURED_EDGE_BAND_PX)."""
    tip = centerline.frames_at(np.array([tip_s]))[0][0]
    bands = [scene.edge_bands.measure(name) * float(np.linalg.norm(origin - tip))
             for name, origin in zip(scene.config.camera_names, scene.origins, strict=True)]
    measured = [band for band in bands if np.isfinite(band)]
    return footprint / 2 + (max(measured) if measured else UNMEASURED_EDGE_BAND_PX * footprint)


def _edge_reach(scene: Scene, footprint: float, centerline: Centerline) -> float:
    """How far (m) round the tube the cameras' matchers move a depth edge on it: their edge bands (per camera,
    `Scene.bands`) at their distances from the robot's base (the mean over the cameras that measured one);
    without one, half a matcher's window (SILHOUETTE_MARGIN_PX pixel footprints)."""
    distances = np.linalg.norm(scene.origins - centerline.points[0], axis=1)
    bands = scene.bands
    measured = np.isfinite(bands)
    if not np.any(measured):
        return SILHOUETTE_MARGIN_PX * footprint
    return float(np.mean(bands[measured] * distances[measured]))


def _one_camera_faces_both_edges(scene: Scene, axis: Axis, notches: list[Notch], roll: float) -> bool:
    """Whether one camera faces both edges of the notches' open window (roll +- the gap's half angle about the axis,
    at the middle notch): its matcher then smears the two alike, and their mean cancels that. True without the
    cameras (nothing to tell)."""
    if scene.seen_by is None or not notches:
        return True
    middle = np.array([np.median([notch.center_s for notch in notches])])
    towards = cameras_round_tube(axis.centerline.frames_at(middle), scene.origins)[0]  # (C, 2): normal, binormal
    cameras = np.arctan2(towards[:, 1], towards[:, 0])
    edges = roll + np.array([-1.0, 1.0]) * scene.geometry.gap_half_angle
    return bool(np.any(np.all(np.cos(edges[None, :] - cameras[:, None]) > 0.0, axis=1)))


def _rolled_axes(normal: np.ndarray, binormal: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-point frame axes turned by `angle` about the tangent (as Centerline.rolled)."""
    c, s = np.cos(angle), np.sin(angle)
    return c * normal + s * binormal, c * binormal - s * normal
