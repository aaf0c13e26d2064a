"""What a reconstruction's steps recorded (`Trace`) and the figures several checks share, derived once from it
(`derive`): who saw how much of the tube, the centreline's stated uncertainty and the tip's bounds (`tip_bounds`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.quality.measures import (
    CameraReach,
    camera_coverage,
    carried_to_tip,
    centerline_uncertainty,
    unmeasured_share,
)
from ntcr_recon.core.relocation.bend_plane import BendPlane
from ntcr_recon.core.relocation.icp import ReferenceMove
from ntcr_recon.core.relocation.outline import went_astray
from ntcr_recon.core.relocation.tip import TipAlongTube

# Thresholds, relative to the robot and the camera so that no robot is special.
ONE_CAMERA_RUN_DIAMETERS = 1.0     # a distal stretch longer than this many diameters seen by one camera: warn
TIP_SHORT_DIAMETERS = 0.5          # tip this many diameters short of (or past) the robot's length: warn
END_ON_PITCHES = 2.0  # a distal stretch this many notch pitches long that every camera sees end-on: warn
# An error growing linearly from the clamped base to the free end is sqrt(3) times its RMS over the length there.
FREE_END_FACTOR = math.sqrt(3.0)
# Two cameras whose own axes at the end lie +-b about the fused one (an RMS of b) lie 2 b apart: the free end
# follows whichever wall the matcher biased there, and nothing beyond it holds the axis.
DISTAL_CROSS_VIEW_FACTOR = 2.0
# A mean shift across the views this many standard errors from none is rigid, not the matcher's noise.
EXTRINSICS_SIGMAS = 3.0
# Cameras whose outlines lie more than this many pixel footprints apart across their views are off by more than the
# limbs look for (limb_profile.SEARCH_PX) and the trusted wall's gate lets in: their outlines tell the offset
GROSS_OFFSET_PX = 3.0


@dataclass(frozen=True)
class Trace:
    """What the reconstruction's steps recorded of one result (m, rad), for the checks.

    tip_uncertainty: how well the tip's refinement placed it along the tube, when it measured the erosion it gave
    back (else the erosion itself counts as uncertain, and half a footprint). tip_position, crop_box: where the tip
    is and the box the points were cropped to (base frame), to tell a tube cut off by the box. notched_thinning:
    measures.notched_thinning's figure, when it could be measured; looking_into_slots:
    measures.cameras_looking_into_slots; tip_from_cap: the tip is the end cap's plane (tip.end_cap_plane),
    tip_uncertainty the smear of its points; side_unsettled: the notch side measured off the configured one, then
    off again in the frame turned to it, when the configured one was kept for it; side_uncertainty: how well the
    side measured is known (None: not measured); side_ruled_out: a side measured off the configured one by a roll
    the robot's bend plane rules out, and its uncertainty (rad; the configured side kept). tip_along: the tip
    between the end seen and the robot's length (tip.TipAlongTube); its uncertainty is the tip's then, and the end
    seen is what is judged against the robot's length. backbone_shift: how far backbone.level_by_backbone moved
    the axis (None or 0: no camera faced the backbone). unsupported: the stretches of s where no camera saw
    trusted wall (cross_view.CrossView).
    distal_cross_view: CrossView.distal, the cameras' spread across their views in the last window, which bounds the
    tip across the tube from below (the limbs' disagreement where they placed that window: end_by_limbs).
    alignment_scatter: how much the alignment's shift of the fit varies along the tube (alignment.shift_scatter).
    misread_widths: the width each notch notch_widths.calibrate_and_check found misread was read at (by index), now
    its bend's; unchecked: the notches it could not check. held_shift: (how far the alignment moved the end, the s
    beyond which it held that shift unmeasured) (alignment.Alignment's end_shift and held_from; with end_by_limbs
    its part along the views alone). reach: how near the tube comes to each camera (measures.CameraReach).
    notch_centres: the comb's notch centres along s (comb.expected_centres). wall_level: the outer wall's level
    about the r_o circle (wall.surface_band of all points). outline_offset: how far the axis lies from the middle of
    the tube's outline in the cameras' views (RMS; outline.outline_offset). across_from_fit: (the aligned axis's
    outline offset, the fit's) when the alignment went astray and the fit placed the axis across the views
    (outline.across_views_from). fitted_end: where the fitted curve ended, past which the centreline was carried on
    bending to the tip.
    reference_moved: relocated by ICP, how far it moved its reference off the centreline's pose (icp.ReferenceMove).
    """

    geometry: object
    camera_names: tuple[str, ...]
    notches: list
    coords_s: np.ndarray
    camera: np.ndarray | None
    tip_s: float
    total_bend: float
    footprint: float
    wall_residual: float
    notch_side: float
    configured_side: float
    bias_notch_side: float
    bias_binormal: float
    depth_steps: dict[str, float]
    tip_erosion: float = 0.0
    tip_uncertainty: float | None = None
    tip_position: np.ndarray | None = None
    crop_box: tuple[np.ndarray, np.ndarray] | None = None
    notched_thinning: float | None = None
    looking_into_slots: tuple[str, ...] = ()
    tip_from_cap: bool = False
    side_unsettled: tuple[float, float] | None = None
    side_ruled_out: tuple[float, float] | None = None
    side_uncertainty: float | None = None
    cross_view_spread: float | None = None
    level_scatter: float | None = None  # cross_view.CrossView.level_scatter
    bend_plane: BendPlane | None = None  # the axis held to the robot's bend plane (None: not held)
    # where the limbs in the colour images placed the axis across the views (limbs.LimbFigures): their disagreement
    # (m), the share of the length seen they placed it over, and how far a window they did not place may lie off (m,
    # LimbFigures.interpolated; None: not measured)
    limbs_across: tuple[float, float, float | None] | None = None
    distal_cross_view: float | None = None
    alignment_scatter: float | None = None
    outline_offset: float | None = None
    across_from_fit: tuple[float, float] | None = None
    tip_along: TipAlongTube | None = None
    backbone_shift: float | None = None
    held_shift: tuple[float, float] | None = None
    end_by_limbs: bool = False
    unsupported: tuple[tuple[float, float], ...] = ()
    misread_widths: dict[int, float] | None = None
    unchecked: list[int] | None = None
    reach: CameraReach | None = None
    notch_centres: np.ndarray | None = None
    wall_level: float | None = None
    fitted_end: float | None = None
    reference_moved: ReferenceMove | None = None
    colour_missing: tuple[str, ...] = ()  # cameras in the cloud without a colour image, relocation.limbs on
    cross_view_offsets: tuple[tuple[float, float] | None, ...] = ()  # cross_view.CrossView.offsets
    limbs_rigid: tuple[float, float] | None = None  # limbs.LimbFigures.rigid: the same, from the limbs
    outline_rigid: tuple[float, float] | None = None  # outline.outline_rigid_offset: the same, from the outlines
    centerline_tolerance: float | None = None  # config.rig.QualityConfig's, which the extrinsics check weighs against
    base_offset: float | None = None  # bend_plane.base_offset: the proximal axis off the base's (m)


@dataclass(frozen=True)
class Derived:
    """The figures several checks rest on, derived once from the trace (m)."""

    found: list[int]
    missing: list[int]
    cell: float                 # the coverage cells' length: a footprint, at least an eighth of the radius
    seen_end: float             # the end the cameras saw (the tip, unless carried on or weighed with the length)
    share: dict[str, float]     # each camera's share of the length
    alone: dict[str, float]     # the distal stretch each camera alone saw
    one_sided: dict[str, float]  # those longer than ONE_CAMERA_RUN_DIAMETERS diameters
    resting_on_level: tuple[float, float] | None  # (their share of the length, the wall's level the axis rests on)
    astray: float | None        # the outline offset, where the axis went astray
    lean: float                 # how far the slots' deficit may lean the axis
    levelled: bool              # a camera facing the backbone placed the axis along its view
    uncertainty: float | None   # the centreline's own (measures.centerline_uncertainty)
    outline_unchecked: bool
    centreline_known: float | None   # with the outline check's resolution where it could not run
    stated_centreline: float | None  # with the hidden part and the unmeasured stretches: what the result states
    end_on: float
    end_on_angles: dict[str, float]
    end_on_warned: bool
    unsupported_to_tip: bool
    tip: TipBounds


@dataclass(frozen=True)
class TipBounds:
    """How well the tip is known along and across the tube (m), and what the across bound rests on."""

    along: float                 # before a tube ending short widened it (what the rim's or cap's note says)
    across: float
    measured: bool               # the tip's refinement measured the erosion it gave back
    weighed: bool                # the robot's length was weighed in
    because: str                 # cameras_apart | icp | hidden | carried | held_shift | free_end
    why: str                     # the same, in words
    icp_along: float
    icp_across: float
    centreline_along: float      # the centreline's tip bounds, before ICP moved it
    centreline_across: float
    held: float
    held_from: float
    carried: float
    hidden_across: float
    expected_length: float       # the robot's length at the bend measured
    short: float                 # the expected length less the end seen
    ends_off_length: bool
    left_short: bool             # a tip left at an end seen far off the length: bounded by the shortfall

    @property
    def stated_along(self) -> float:
        return max(self.along, abs(self.short)) if self.left_short else self.along

    @property
    def stated_across(self) -> float:
        return max(self.across, abs(self.short)) if self.left_short else self.across


@dataclass(frozen=True)
class RigidOffset:
    """How far apart the cameras place the axis across their views, alike all along the tube (m): the sum of two
    opposed cameras' mean shifts (cross_view.CrossView.offsets; a shift of one camera relative to the other reads
    with the same sign in both views), and that sum's standard error."""

    offset: float
    error: float
    # what an offset must exceed, in the centreline's tolerances, to be told from the measure's own bias: depth's
    # matcher pulls two cameras 0.10-0.12 mm apart beside slots opening at +-45 deg, with exact extrinsics (so: its
    # half beyond a tolerance); the limbs read exact rigs 0.002-0.02 mm apart (0.01-0.07 with a real matcher), and
    # a pose 0.1 deg off 0.08-0.13 mm (0.08-0.18), which moves the centreline as far: beyond one tolerance
    least: float = 2.0
    # read from the cameras' whole outlines (an offset beyond the limbs' reach): the fused axis then lies anywhere
    # between the two cameras' own (the fit and the alignment may follow either), up to all of it off
    whole: bool = False

    @property
    def disagreeing(self) -> bool:
        """Beyond the matcher's noise (EXTRINSICS_SIGMAS standard errors): the poses in the rig file disagree."""
        return self.offset > EXTRINSICS_SIGMAS * self.error


def rigid_offset(t: Trace) -> RigidOffset | None:
    """The cameras' rigid offset across their views: from their limbs where both placed the axis there (sharp where
    depth is smeared; found within limb_profile.SEARCH_PX of the fused axis in both views, the cameras cannot be further
    apart than that); else from their whole outlines where those lie beyond what the trusted wall's gate reaches
    (GROSS_OFFSET_PX: a pose a millimetre off moves one camera's whole tube out of it, and out of the limbs' search);
    else from depth; None unless two cameras each placed the axis. Not the outlines where the limbs were found: a
    stereo matcher fattens a silhouette on one side, the same side of both opposed views, which reads as an offset
    (0.85 mm with the real matcher, the robot bent towards a camera, an exact rig)."""
    if t.limbs_rigid is not None:
        return RigidOffset(*t.limbs_rigid, least=1.0)
    if t.outline_rigid is not None and t.outline_rigid[0] > GROSS_OFFSET_PX * t.footprint:
        gross = RigidOffset(*t.outline_rigid, least=1.0, whole=True)
        if gross.disagreeing:
            return gross
    means = [offset for offset in t.cross_view_offsets if offset is not None]
    if len(means) != 2:
        return None
    (mean_a, error_a), (mean_b, error_b) = means
    return RigidOffset(abs(mean_a + mean_b), math.hypot(error_a, error_b))


def extrinsics_apart(t: Trace) -> float:
    """How far off the fused axis lies for the cameras' poses disagreeing (m): half their rigid offset (all of it,
    read from the outlines: RigidOffset.whole), where it is beyond the measure's noise and `least` of the
    centreline's tolerances (the EXTRINSICS_DISAGREE check); else 0 (a smaller offset is not told from the
    measure's own bias, RigidOffset.least)."""
    rigid = rigid_offset(t)
    if rigid is None or t.centerline_tolerance is None or not rigid.disagreeing:
        return 0.0
    if rigid.offset <= rigid.least * t.centerline_tolerance:
        return 0.0
    return rigid.offset if rigid.whole else rigid.offset / 2


def missing_views(config, cloud, views) -> tuple[str, ...]:
    """The cameras with points in the cloud whose colour image is not among `views` while relocation.limbs asks
    for them: across their views the axis was placed by depth alone."""
    if not config.relocation.limbs:
        return ()
    return tuple(name for name in cloud.cameras_in(config.camera_names) if name not in views)


def derive(t: Trace) -> Derived:
    """The figures several checks share: who saw how much of the tube, the centreline's and the tip's bounds."""
    geometry, footprint, diameter = t.geometry, t.footprint, t.geometry.outer_diameter
    found = sorted(n.index for n in t.notches)
    cell = max(footprint, geometry.outer_radius / 8)
    seen_end = t.tip_s if t.tip_along is None else t.tip_along.seen_s
    share, alone = camera_coverage(t.coords_s, t.camera, t.camera_names, t.tip_s, cell, pool=diameter)
    one_sided = {name: length for name, length in alone.items() if length > ONE_CAMERA_RUN_DIAMETERS * diameter}
    resting_on_level = ((min(sum(one_sided.values()) / max(seen_end, cell), 1.0), t.wall_level)
                        if one_sided and t.wall_level is not None else None)
    astray = t.outline_offset if went_astray(t.outline_offset, footprint) else None
    levelled = bool(t.backbone_shift)
    uncertainty = centerline_uncertainty(t.cross_view_spread, t.notched_thinning, t.looking_into_slots, levelled,
                                         one_sided=resting_on_level, astray=astray, varying_lean=t.alignment_scatter,
                                         limbs=t.limbs_across, level_scatter=t.level_scatter,
                                         bend_plane=t.bend_plane)
    # where no camera's view showed the tube's outline whole, nothing checked the axis across the views (outline.py):
    # it is known there no better than that check resolves, a pixel footprint, whatever the cameras' spread says
    outline_unchecked = t.camera is not None and t.outline_offset is None
    centreline_known = max(uncertainty or 0.0, footprint) if outline_unchecked else uncertainty
    # a rigid error of the whole axis, measured twice: the cameras' poses disagreeing, and the proximal axis off the
    # base's (which the robot defines) - the latter also along the views, where the cameras cannot disagree
    apart = max(extrinsics_apart(t), t.base_offset or 0.0)
    tip = tip_bounds(t, seen_end, centreline_known, apart)
    # the centreline runs on past the end seen to a carried tip: along that stretch a straight hidden part leaves it
    # off by up to hidden_across, growing with the square of the distance carried (a fifth of its square in the
    # mean): the RMS over the robot's length
    stated_centreline = centreline_known
    if tip.hidden_across:
        hidden_share = (t.tip_s - seen_end) / t.tip_s
        stated_centreline = math.sqrt((centreline_known or 0.0) ** 2 + hidden_share * tip.hidden_across**2 / 5)
    # over the stretches where no camera saw the wall facing it, or every camera sees it end-on (both warned),
    # nothing measured how far off the axis is: known there no better than a pixel footprint, their share of the
    # length weighs that in the RMS
    end_on, end_on_angles = (0.0, {}) if t.reach is None else t.reach.end_on_to_every_camera(t.tip_s)
    end_on_warned = end_on >= END_ON_PITCHES * geometry.notch_pitch
    unmeasured = unmeasured_share(t.unsupported, end_on if end_on_warned else 0.0, t.tip_s)
    if unmeasured and stated_centreline is not None:
        stated_centreline = math.sqrt(stated_centreline**2 + unmeasured * footprint**2)
    # cameras whose poses disagree place the fused axis half their rigid offset off, all along the tube (and the axis
    # off the base's, as far)
    if apart and stated_centreline is not None:
        stated_centreline = math.hypot(stated_centreline, apart)
    # pooled over two cameras, a deficit one of them carries alone reads half: the lean may reach twice it
    lean = 2.0 * t.notched_thinning if t.notched_thinning is not None and t.looking_into_slots else 0.0
    return Derived(
        found=found, missing=sorted(set(range(geometry.notch_count)) - set(found)), cell=cell, seen_end=seen_end,
        share=share, alone=alone, one_sided=one_sided, resting_on_level=resting_on_level, astray=astray, lean=lean,
        levelled=levelled, uncertainty=uncertainty, outline_unchecked=outline_unchecked,
        centreline_known=centreline_known, stated_centreline=stated_centreline, end_on=end_on,
        end_on_angles=end_on_angles, end_on_warned=end_on_warned,
        unsupported_to_tip=bool(t.unsupported) and t.unsupported[-1][1] >= t.tip_s - geometry.notch_pitch, tip=tip)


def tip_bounds(t: Trace, seen_end: float, centreline_known: float | None, apart: float = 0.0) -> TipBounds:
    """How well the tip is known: along the tube, the rim's or cap's refinement (or the length weighed in), across
    it the centreline's free end with the alignment's held shift, what it was carried over, a hidden part and ICP's
    move; where the cameras disagree in the last window, their own axes' distance apart."""
    measured = t.tip_uncertainty is not None
    # the tip's rim is a depth edge: it rests on the erosion given back, known to about that much unless the
    # refinement measured it
    along = t.tip_uncertainty if measured else abs(t.tip_erosion) + t.footprint / 2
    if t.tip_along is not None:
        along = t.tip_along.uncertainty
    icp_along, icp_across = ((t.reference_moved.tip_along, t.reference_moved.tip_across)
                             if t.reference_moved is not None else (0.0, 0.0))
    # the tip sits on the centreline's free end, where an error growing along the tube is sqrt(3) its RMS, with the
    # shift the alignment measured last and held unchecked to the tip (the fit's lean it corrected there may differ
    # beyond)
    end_spread = DISTAL_CROSS_VIEW_FACTOR * (t.distal_cross_view or 0.0)
    free_end = FREE_END_FACTOR * (centreline_known or 0.0)
    held, held_from = t.held_shift if t.held_shift is not None and t.held_shift[1] is not None else (0.0, t.tip_s)
    carried, carried_across = carried_to_tip(t.fitted_end, t.tip_s, t.notch_centres, t.geometry,
                                             centreline_known or 0.0)
    # carried past an end hidden from every camera: the hidden notches may bend otherwise than the ones seen
    hidden_across = 0.0 if t.tip_along is None or t.tip_along.hidden_across is None else t.tip_along.hidden_across
    centreline_across = math.hypot(free_end, held, carried_across, hidden_across, apart)
    # ICP's move is a displacement it made, not an error independent of the centreline's: the two add
    across = max(centreline_across + icp_across, end_spread)
    # named by the largest term, each weighed against those after it (ICP's move first, the free end last)
    terms = [("icp", icp_across), ("extrinsics", apart), ("hidden", hidden_across), ("carried", carried_across),
             ("held_shift", held)]
    because = "cameras_apart" if end_spread >= across else next(
        (name for i, (name, value) in enumerate(terms) if value > max([v for _, v in terms[i + 1:]] + [free_end])),
        "free_end")
    why = {"cameras_apart": "the cameras' axes that far apart across their views at the end",
           "icp": "ICP moved it that far off where the centreline placed it",
           "extrinsics": "the cameras' poses in the rig file disagree, or put the proximal axis off the base's: the "
                         "axis lies about that far off",
           "hidden": f"were the {(t.tip_s - seen_end) * 1e3:.1f} mm no camera saw straight, not bent as the notches "
                     "seen, the tip would lie that far off",
           "carried": f"the centreline carried on bending over the {carried * 1e3:.1f} mm past where its fit reached, "
                      "at the bend of the notches before",
           "held_shift": f"the alignment moved the axis {held * 1e3:.2f} mm"
                         f"{' along the views (across them the limbs placed it)' if t.end_by_limbs else ''}"
                         " at the last wall it trusted, and held that "
                         f"shift unchecked over the {max(t.tip_s - held_from, 0.0) * 1e3:.1f} mm to the tip",
           "free_end": "the centreline's, at its free end"}[because]
    # bending shortens the centreline by ybar * theta: what the tip should read with the measured bend
    expected_length = t.geometry.bent_length(t.total_bend)
    short = expected_length - seen_end
    ends_off_length = abs(short) > TIP_SHORT_DIAMETERS * t.geometry.outer_diameter
    return TipBounds(
        along=along + icp_along, across=across, measured=measured,
        weighed=bool(t.tip_along is not None and t.tip_along.length_weighed), because=because, why=why,
        icp_along=icp_along, icp_across=icp_across, centreline_along=along,
        centreline_across=max(centreline_across, end_spread), held=held, held_from=held_from, carried=carried,
        hidden_across=hidden_across, expected_length=expected_length, short=short, ends_off_length=ends_off_length,
        # a tip left at an end seen far short of (or past) the robot's length (not carried on) lies wherever the
        # rest of the robot reaches
        left_short=ends_off_length and not hidden_across)
