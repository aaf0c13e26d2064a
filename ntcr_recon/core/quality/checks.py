"""The self-check of a reconstruction as a list of checks: how sure the result is, in figures and coded warnings.

`assess(trace)` looks only at what the reconstruction's steps recorded (a `Trace`, quality.trace) and the
configuration, never at ground truth. The figures several checks rest on (the centreline's and the tip's stated
uncertainties, the end seen against the robot's length, each camera's share of the tube) are derived once
(`trace.derive`); then each check of CHECKS returns its figures for the `quality` document and its warnings
(quality.findings). Adding a check touches one place: a function and its entry in CHECKS. The helpers the checks
measure with live in quality.measures; the tip's two checks in quality.tip_checks.

    notches_found           NOTCHES_MISSING, NOTCH_WIDTH_FROM_BEND
    widths_against_bends    NOTCH_WIDTH_MISREAD, NOTCH_WIDTH_UNCHECKED; each width's 90 % bound
    icp_reference           ICP_MOVED_REFERENCE
    tip_end                 TIP_ON_END_CAP, TIP_ON_ERODED_RIM
    camera_views            DISTAL_ONE_CAMERA, CAMERA_SHORT_VIEW
    tip_against_length      TIP_OFF_LENGTH, TUBE_ENDS_SHORT, TIP_CARRIED
    notch_side              NOTCH_SIDE_UNSETTLED, NOTCH_SIDE_RULED_OUT, ROBOT_ROLLED, NOTCH_SIDE_OFF
    depth_resolution        PIXEL_FOOTPRINT_COARSE, DEPTH_QUANTISED
    centerline              CENTERLINE_UNCERTAIN, OUTLINE_UNCHECKED, ALIGNMENT_ASTRAY, CENTERLINE_UNSUPPORTED,
                            DISTAL_END_ON, SLOTS_LEAN
    extrinsics              EXTRINSICS_DISAGREE
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ntcr_recon.core.quality.findings import Finding, finding, notch_width_uncertainties, uncertainty_mm
from ntcr_recon.core.quality.measures import (
    depth_quantisation_warning,
    notches_lie,
    unseen_figures,
    where_notches_went_unseen,
)
from ntcr_recon.core.quality.tip_checks import tip_against_length, tip_end
from ntcr_recon.core.quality.trace import Derived, Trace, derive, extrinsics_apart, rigid_offset
from ntcr_recon.core.relocation.notch_widths import MISREAD_WIDTH_FRACTION, chord_residuals, weighing_of, width_as_read
from ntcr_recon.core.relocation.outline import OUTLINE_TOLERANCE_PX

# Thresholds, relative to the robot and the camera so that no robot is special.
SIDE_OFF_DEG = 10.0                # measured notch side this far from the configured one: warn
FOOTPRINT_RADIUS_FRACTION = 1 / 7  # pixel footprint above this fraction of r_o: too few pixels across
BIAS_WARN_FOOTPRINTS = 0.5         # a lean into the slots above this many footprints: warn
# The project's floor (issue 9) on the centreline: an uncertainty above it is worth a note.
CENTERLINE_FLOOR = 0.08e-3

Check = Callable[[Trace, Derived], tuple[dict, list[Finding]]]


def assess(trace: Trace) -> tuple[dict, list[Finding]]:
    """The `quality` document and the warnings: every check of CHECKS over the trace, then the result's bounds."""
    derived = derive(trace)
    quality: dict = {}
    warnings: list[Finding] = []
    for check in CHECKS:
        figures, found = check(trace, derived)
        quality.update(figures)
        warnings += found
    quality["uncertainty_mm"] = uncertainty_mm(quality, quality["notch_width_uncertainty_mm"].values())
    return quality, warnings


def notches_found(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """Notches found of expected, by which signal, and where the comb puts the missing ones: past the end seen,
    where a camera did not see the tube, or where the cameras saw it and nothing in its wall marked the cut."""
    geometry, found, missing = t.geometry, d.found, d.missing
    beyond, unseen, unmarked, warnings = [], {}, [], []
    by_signal: dict[str, int] = {}
    for notch in t.notches:
        by_signal[notch.signal] = by_signal.get(notch.signal, 0) + 1
    if missing:
        warning = (f"{len(found)} of {geometry.notch_count} notches found (missing: "
                   f"{', '.join(str(i) for i in missing)}): their widths are unknown")
        if t.notch_centres is not None:  # where the comb puts them: past the end seen, or out of a camera's view
            half = geometry.notch_width / 2
            beyond, unseen = where_notches_went_unseen(missing, t.notch_centres, half, t.coords_s, t.camera,
                                                       t.camera_names, d.seen_end, d.cell,
                                                       pool=geometry.outer_diameter)
            for name, indices in unseen.items():
                why = "" if t.reach is None else t.reach.why_unseen(
                    [name], t.notch_centres[indices[0]] - half, min(t.notch_centres[indices[-1]] + half, d.seen_end))
                warning += f"; {notches_lie(indices)} where {name} did not see the tube{f' ({why})' if why else ''}"
            if beyond:
                warning += f"; {notches_lie(beyond)} beyond the end seen ({d.seen_end * 1e3:.1f} mm along the tube)"
            if t.camera is not None:  # seen, yet not found: what a depth pixel there is against the cut
                unmarked = [i for i in missing if i not in beyond and not any(i in v for v in unseen.values())]
            if unmarked:
                them = "it" if len(unmarked) == 1 else "them"
                warning += (f"; {notches_lie(unmarked)} where the cameras saw the tube, yet no gap or dip of the wall "
                            f"marks {them} (a {geometry.notch_width * 1e3:.1f} mm cut spans "
                            f"{geometry.notch_width / t.footprint:.0f} px in the depth images there: a stereo "
                            "matcher's window that wide or wider fills it; or it opens to a side no camera saw)")
        warnings.append(finding("NOTCHES_MISSING", warning, missing=missing, beyond_end=beyond,
                                unseen_by={name: list(indices) for name, indices in unseen.items()},
                                unmarked=unmarked))
    dips = sorted(n.index for n in t.notches if n.signal == "dip")
    outlined = sorted(n.index for n in t.notches if n.signal == "outline")
    if dips or outlined:
        shown = [f"notches {', '.join(map(str, dips))} show only as a shallow dip of the wall's coverage where the "
                 "comb puts them"] if dips else []
        shown += [f"notches {', '.join(map(str, outlined))} show in no depth, only as the tube's outline receding "
                  "where the comb puts them in a colour image"] if outlined else []
        warnings.append(finding("NOTCH_WIDTH_FROM_BEND",
                                f"{'; '.join(shown)} (slots narrower than the stereo matcher's window, which fills "
                                "them): their edges were not measured, and their widths are what their measured bends "
                                "imply", notches=sorted(dips + outlined), outline=outlined))
    return {"notches_found": len(found), "notches_expected": geometry.notch_count, "notches_missing": missing,
            "notches_missing_beyond_end": beyond, "notches_missing_unseen_by": unseen,
            "notches_missing_unmarked": unmarked, "notches_by_signal": by_signal,
            "notch_signal": {str(n.index): n.signal for n in sorted(t.notches, key=lambda n: n.index)}}, warnings


def widths_against_bends(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """Each notch's width against the one its measured bend implies (the gap on the outer wall of a notch of neutral
    length h bent by theta: notch_widths.calibrate_and_check gave a misread one its bend's), the notches that could not
    be checked so, and each width's 90 % bound from how the widths read disagree with their bends'."""
    geometry, misread, warnings = t.geometry, t.misread_widths or {}, []
    # per notch how far the width read is off its bend's (a misread one's, a weighed one's as read)
    off_model = {n.index: misread.get(n.index, width_as_read(n)) - geometry.notch_width_at_bend(n.bend or 0.0)
                 for n in t.notches if n.edges_measured or n.index in misread}
    if misread:
        listed = ", ".join(f"{n.index} ({misread[n.index] * 1e3:.2f} mm read, {n.width * 1e3:.2f} implied)"
                           for n in t.notches if n.index in misread)
        warnings.append(finding("NOTCH_WIDTH_MISREAD",
                                f"notches whose edges read a width their bends rule out: {listed}; their rims were "
                                "misread (a slot seen through over a narrow run, a rim merged with a cut face, the "
                                "last notch's distal rim where the tube seen thins out), and their widths are what "
                                "their measured bends imply (for the last notch found, whose own bend no whole spine "
                                "beyond measures, the bend of the two before it; a robot whose cuts are off its "
                                "drawing would read so too)",
                                notches=sorted(misread),
                                read_width_mm={str(i): w * 1e3 for i, w in sorted(misread.items())},
                                implied_width_mm={str(n.index): n.width * 1e3 for n in t.notches
                                                  if n.index in misread}))
    # a notch whose next one is missing where the tube seen ends within a pitch: its bend is a chord that may run
    # into a tube cut short; with no measured notch before it either, its width, as read, was checked against nothing
    unchecked = list(t.unchecked or ())
    if unchecked:
        warnings.append(finding("NOTCH_WIDTH_UNCHECKED",
                                "widths not checked against their bends, as read: notches "
                                f"{', '.join(map(str, unchecked))} (the next notch was not found and the tube seen "
                                "ends within a pitch: no whole spine beyond measures the bend, and no notch before it "
                                "whose bend was measured)", notches=unchecked))
    # a misread one took its steady bend's width, as a dip does: known to the spread, as a dip is; a weighed one as
    # notch_widths.calibrate_and_check weighed its two measurements, and no better than its own chord, where that
    # stands out of its neighbours', puts it (the bend's error weighs ybar + r_o less the read one's weight of ybar
    # in the weighed width): as far as its width's disagreement with its bend's shows (ybar times it) - a chord
    # standing out where the rims agree with it is the robot's own bend (a kink)
    weighed, ybar = weighing_of(t.notches, geometry), geometry.neutral_axis_offset
    residuals = chord_residuals({n.index: n.bend for n in t.notches if n.edges_measured})
    lever = ybar * (1.0 - weighed.read) + geometry.outer_radius
    bend_off = {n.index: lever * min(abs(residuals.get(n.index, 0.0)), abs(off_model[n.index]) / ybar)
                for n in t.notches if n.read_width is not None}
    width_known = notch_width_uncertainties(off_model, d.found, MISREAD_WIDTH_FRACTION * geometry.notch_width,
                                            misread, bend_off, weighed)
    return {"notch_width_vs_bend_mm": {str(i): off * 1e3 for i, off in sorted(off_model.items())},
            "notches_unchecked": unchecked,
            "notch_width_uncertainty_mm": {str(i): width_known[i] * 1e3 for i in d.found}}, warnings


def icp_reference(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """Relocated by ICP: how far it moved its reference off the pose the centreline gave it, and the tip with it;
    a warning where that is further than the centreline or its tip is known to."""
    moved, tip = t.reference_moved, d.tip
    if moved is None:
        return {"relocation_reference_move_mm": None}, []
    warnings = []
    if moved.rms > (d.stated_centreline or 0.0) or (math.hypot(tip.icp_along, tip.icp_across)
                                                    > math.hypot(tip.centreline_along, tip.centreline_across)):
        warnings.append(finding("ICP_MOVED_REFERENCE",
                                "relocated by ICP (relocation.method icp), which moved the reference "
                                f"{moved.rms * 1e3:.2f} mm (RMS) off the pose the centreline gave it, and the tip "
                                f"{tip.icp_along * 1e3:.2f} mm along the tube and {tip.icp_across * 1e3:.2f} mm across "
                                "it: further than the centreline or its tip is known to. The two relocations disagree "
                                "by that much, and the relocated surface and the tip are known no better",
                                reference_move_mm=moved.rms * 1e3))
    return {"relocation_reference_move_mm": {"rms": moved.rms * 1e3, "tip_along": tip.icp_along * 1e3,
                                             "tip_across": tip.icp_across * 1e3}}, warnings


def camera_views(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """Each camera's share of the length and a distal stretch one camera alone saw (with why the other did not);
    the nearest depth each returned and the nearest the tube comes to it."""
    warnings = []
    for name, length in d.one_sided.items():
        others = [n for n in t.camera_names if n != name]
        why = "" if t.reach is None else t.reach.why_unseen(others, t.tip_s - length, t.tip_s)
        warnings.append(finding("DISTAL_ONE_CAMERA",
                                f"the distal {length * 1e3:.0f} mm is seen by {name} "
                                f"alone{f' ({why})' if why else ''}: the tube's far side there is inferred, not "
                                "measured, and the centreline there rests on one side, the tip with it: no second "
                                "view checked where it lies across the tube",
                                camera=name, length_mm=length * 1e3,
                                **unseen_figures(t.reach, others, t.tip_s - length, t.tip_s)))
    for name, fraction in d.share.items():
        if fraction < 0.5:
            warnings.append(finding("CAMERA_SHORT_VIEW", f"{name} saw only {fraction:.0%} of the robot's length",
                                    camera=name, share=fraction))
    if t.colour_missing:
        views = "its view" if len(t.colour_missing) == 1 else "their views"
        warnings.append(finding("COLOUR_VIEW_MISSING", f"no colour image of {' or '.join(t.colour_missing)} came "
                                f"with its depth (relocation.limbs): across {views} the axis was placed by depth "
                                "alone, as uncertain as stated", cameras=list(t.colour_missing)))
    reach = t.reach
    return {"length_seen_share": d.share, "distal_one_camera_mm": {k: v * 1e3 for k, v in d.alone.items()},
            # per camera the nearest depth it returned, and the tube seen's nearest to it (its surface, optical axis)
            "camera_nearest_depth_mm": {} if reach is None else {
                k: v * 1e3 for k, v in reach.nearest_returned.items()},
            "tube_nearest_depth_mm": {} if reach is None else {
                k: float(v[reach.s <= d.seen_end].min()) * 1e3 for k, v in reach.depth.items()}}, warnings


def notch_side(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """The measured notch side against the configured one: no consistent measurement, or the robot rolled in its
    clamp (or maybe, within what the side is known to)."""
    warnings = []
    side_off = math.degrees(math.remainder(t.notch_side - t.configured_side, 2 * math.pi))
    if t.side_unsettled is not None:
        first, then = (math.degrees(angle) for angle in t.side_unsettled)
        warnings.append(finding("NOTCH_SIDE_UNSETTLED",
                                f"the notches' side measured {first:+.0f} deg from the configured robot.notch_side, "
                                f"then {then:+.0f} deg more in the frame turned to it: no consistent measurement, the "
                                "configured side is kept (check the robot's roll in its clamp)",
                                side_off_deg=[first, then]))
    if t.side_ruled_out is not None and t.bend_plane is not None and t.bend_plane.shown is not None:
        measured, known_deg = (math.degrees(angle) for angle in t.side_ruled_out)
        shown, shown_sd = (math.degrees(angle) for angle in t.bend_plane.shown)
        warnings.append(finding("NOTCH_SIDE_RULED_OUT",
                                f"the notches' edges put their side {measured:+.0f} deg from the configured "
                                f"robot.notch_side (known to +-{known_deg:.0f} deg), a roll in the clamp the robot's "
                                f"bend rules out (its plane lies {shown:+.1f} +- {shown_sd:.1f} deg off): the "
                                "configured side is kept", side_off_deg=measured, side_uncertainty_deg=known_deg,
                                plane_roll_deg=shown, plane_roll_sd_deg=shown_sd))
    if abs(side_off) > SIDE_OFF_DEG:
        known_deg = None if t.side_uncertainty is None else math.degrees(t.side_uncertainty)
        known = "" if known_deg is None else f" (known to +-{known_deg:.0f} deg)"
        beyond = known_deg is None or abs(side_off) > known_deg
        rolled = ("is rolled in its clamp" if beyond
                  else "may be rolled in its clamp: the offset is within what the side is known to")
        # within what the measurement is known to, the offset proves no roll: a note (the measured side is used)
        warnings.append(finding("ROBOT_ROLLED" if beyond else "NOTCH_SIDE_OFF",
                                f"the notches open {side_off:+.0f} deg from the configured robot.notch_side{known}: "
                                f"the robot {rolled} (measured side used)", side_off_deg=side_off,
                                side_uncertainty_deg=known_deg))
    return {"notch_side_deg": math.degrees(t.notch_side), "notch_side_configured_deg": math.degrees(t.configured_side),
            "notch_side_unsettled_deg": None if t.side_unsettled is None
            else [math.degrees(a) for a in t.side_unsettled]}, warnings


def bend_plane(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """The plane the axis was held to (relocation.bend_plane): its roll off the configured side, and a robot that
    bends in another plane than that beyond robot.roll_tolerance."""
    plane = t.bend_plane
    if plane is None:
        return {}, []
    figures = plane.figures()
    turned = [finding(
        "BEND_PLANE_TURNED", f"the robot bends in a plane turned {figures['roll_deg']:+.1f} deg from the configured "
        f"robot.notch_side (+-{figures['roll_sd_deg']:.1f} deg; robot.roll_tolerance "
        f"{math.degrees(t.geometry.roll_tolerance):.1f} deg): the axis is held to that plane; the robot is rolled in "
        "its clamp, or the rig file's notch_side or its calibration is off", roll_deg=figures["roll_deg"],
        roll_sd_deg=figures["roll_sd_deg"])] if plane.roll_measured else []
    return {"bend_plane": figures}, turned


def depth_resolution(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """The pixel footprint against the tube, and the depth step each camera's data showed."""
    geometry, footprint, warnings = t.geometry, t.footprint, []
    if footprint > FOOTPRINT_RADIUS_FRACTION * geometry.outer_radius:
        warnings.append(finding("PIXEL_FOOTPRINT_COARSE",
                                f"a depth pixel covers {footprint * 1e3:.2f} mm, the tube is only "
                                f"{geometry.outer_diameter / footprint:.0f} px across: depth resolves its roundness "
                                "coarsely, which the stated uncertainties carry (a higher depth resolution, or cameras "
                                "closer, down to the D405's minimum depth of about 70 mm)",
                                pixel_footprint_mm=footprint * 1e3))
    warnings += [finding("DEPTH_QUANTISED", w, camera=name, depth_step_mm=step * 1e3)
                 for name, step in t.depth_steps.items() if (w := depth_quantisation_warning(name, step, geometry))]
    return {"pixel_footprint_mm": footprint * 1e3,
            "depth_step_mm": {k: v * 1e3 for k, v in t.depth_steps.items()}}, warnings


def centerline(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """How sure the centreline is, and the stretches where nothing measured it: what the self-check of the
    alignment (cameras' spread, outline, slots' lean, backbone, wall's level) found."""
    warnings = []
    if d.uncertainty is not None and d.stated_centreline > CENTERLINE_FLOOR:  # the stated: its terms and more
        warnings.append(_centerline_uncertain(t, d))
    if d.outline_unchecked:
        # the check ran (points carry their camera) and no window's outline spanned the tube's diameter: the
        # matcher spoiled the silhouettes (a wide window over a near backdrop)
        warnings.append(finding("OUTLINE_UNCHECKED",
                                "no camera's view showed the tube's outline whole (across each view its wall points "
                                "spanned no diameter: the matcher spoiled the silhouettes' pixels): the centreline "
                                "was not checked against the middle of the outline, and across the views it, and the "
                                "tip at its free end, may lie further off than the cameras' spread says: they are "
                                f"stated as uncertain as a pixel footprint at least ({t.footprint * 1e3:.2f} mm), "
                                "what that check resolves", pixel_footprint_mm=t.footprint * 1e3))
    if t.across_from_fit is not None:
        aligned, fit = t.across_from_fit
        warnings.append(finding("ALIGNMENT_ASTRAY",
                                f"the alignment moved the axis {aligned * 1e3:.2f} mm (RMS) from the middle of the "
                                f"tube's outline in the cameras' views ({aligned / t.footprint:.1f} px, where a sound "
                                f"axis lies within {OUTLINE_TOLERANCE_PX:g}): it followed a wall stereo moved across "
                                f"the views, and across them the axis is the fit's, which lies "
                                f"{fit / t.footprint:.1f} px from that middle",
                                aligned_offset_mm=aligned * 1e3, fit_offset_mm=fit * 1e3))
    warnings += _unmeasured_stretches(t, d)
    if d.lean > BIAS_WARN_FOOTPRINTS * t.footprint:
        names = " and ".join(t.looking_into_slots)
        consequence = (f"a camera facing the backbone placed the axis along its line of sight instead, by its level on "
                       f"the plain tube ({t.backbone_shift * 1e3:.2f} mm moved)" if d.levelled else
                       f"the centreline there may lean up to {d.lean * 1e3:.2f} mm away from {names}")
        warnings.append(finding("SLOTS_LEAN", f"{names} looks into the notches' slots, and the wall between them reads "
                                f"{t.notched_thinning * 1e3:.2f} mm deeper than the plain tube (its matcher averages "
                                f"the spines with the slot floors): {consequence}",
                                cameras=list(t.looking_into_slots), lean_mm=d.lean * 1e3,
                                notched_thinning_mm=t.notched_thinning * 1e3, levelled=d.levelled))
    return {"fit_residual_mm": t.wall_residual * 1e3, "wall_level_mm": _mm(t.wall_level),
            "centerline_bias_mm": {"notch_side": t.bias_notch_side * 1e3, "binormal": t.bias_binormal * 1e3},
            "notched_thinning_mm": _mm(t.notched_thinning), "cameras_looking_into_slots": list(t.looking_into_slots),
            "centerline_cross_view_mm": _mm(t.cross_view_spread),
            "centerline_level_scatter_mm": _mm(t.level_scatter),
            "centerline_base_offset_mm": _mm(t.base_offset),
            "centerline_cross_view_at_tip_mm": _mm(t.distal_cross_view),
            "centerline_alignment_scatter_mm": _mm(t.alignment_scatter),
            "centerline_outline_offset_mm": _mm(t.outline_offset),
            # the aligned axis's offset, when it went astray and the fit placed the axis across the views instead
            "centerline_aligned_outline_offset_mm": None if t.across_from_fit is None else t.across_from_fit[0] * 1e3,
            "centerline_uncertainty_mm": _mm(d.stated_centreline),
            "centerline_unsupported_mm": [[start * 1e3, end * 1e3] for start, end in t.unsupported],
            "distal_end_on_mm": d.end_on * 1e3}, warnings


def _centerline_uncertain(t: Trace, d: Derived) -> Finding:
    """CENTERLINE_UNCERTAIN: the centreline's own uncertainty beyond its floor, and what it is made of."""
    message = (f"the centreline is uncertain by about {d.uncertainty * 1e3:.2f} mm: stereo matching beside the notches "
               f"moves the wall it sees (the cameras place the axis {(t.cross_view_spread or 0.0) * 1e3:.2f} mm apart "
               "across their views, and the wall between the notches reads "
               f"{(t.notched_thinning or 0.0) * 1e3:+.2f} mm deeper than the plain tube); "
               f"{abs(t.bias_notch_side) * 1e3:.2f} mm of lean towards the notch side was removed")
    if t.alignment_scatter:
        message += (f", a correction that varies along the tube by {t.alignment_scatter * 1e3:.2f} mm (RMS), which "
                    "the wall facing the cameras cannot tell from a wall stereo moved alike in every view")
    if t.limbs_across is not None:
        disagreement, share, interpolated = t.limbs_across
        message += (f"; across the views the tube's limbs in the colour images placed the axis over {share:.0%} of "
                    f"the length, agreeing to {disagreement * 1e3:.3f} mm")
        if interpolated is not None and share < 1.0:
            message += (f", and the rest by interpolation, which misses by {interpolated * 1e3:.3f} mm (RMS) where "
                        "they can check it")
    if t.level_scatter is not None:
        message += (f"; the walls the two cameras see read apart by an amount that varies along the tube by "
                    f"{2 * t.level_scatter * 1e3:.3f} mm (SD), half of which the axis, midway, may be off along the "
                    "views")
    if d.resting_on_level:
        message += (f"; over the distal {sum(d.one_sided.values()) * 1e3:.0f} mm seen by one camera alone, the wall's "
                    f"level ({t.wall_level * 1e3:+.2f} mm, the flattening of the views) places the axis along that "
                    "camera's view, and no second view checked it")
    if t.base_offset is not None:
        message += (f"; over the proximal segment the axis lies {t.base_offset * 1e3:.3f} mm off the base's, which the "
                    "robot defines: a camera's pose off in the rig file moves it so all along the tube")
    if d.astray is not None:
        message += (f"; the axis lies {d.astray * 1e3:.2f} mm (RMS) from the middle of the tube's outline in the "
                    f"cameras' views, {d.astray / t.footprint:.1f} px where a sound one lies within "
                    f"{OUTLINE_TOLERANCE_PX:g}: the fit and the alignment followed a wall stereo moved that far")
    return finding("CENTERLINE_UNCERTAIN", message, uncertainty_mm=d.uncertainty * 1e3, outline_offset_mm=_mm(d.astray),
                   cross_view_mm=(t.cross_view_spread or 0.0) * 1e3,
                   notched_thinning_mm=(t.notched_thinning or 0.0) * 1e3,
                   alignment_scatter_mm=(t.alignment_scatter or 0.0) * 1e3, level_scatter_mm=_mm(t.level_scatter),
                   limbs_disagreement_mm=None if t.limbs_across is None else _mm(t.limbs_across[0]),
                   limbs_interpolated_mm=None if t.limbs_across is None else _mm(t.limbs_across[2]),
                   one_camera_wall_level_mm=t.wall_level * 1e3 if d.resting_on_level else None,
                   base_offset_mm=_mm(t.base_offset))


def _unmeasured_stretches(t: Trace, d: Derived) -> list[Finding]:
    """CENTERLINE_UNSUPPORTED where no camera saw the wall facing it; DISTAL_END_ON where every camera sees the
    distal wall nearly edge-on (nothing placed the axis there across the tube; in the sweeps, most such tips missed
    their floor), unless an unsupported stretch reaching the tip says as much already."""
    warnings = []
    if t.unsupported:
        listed = ", ".join(f"{start * 1e3:.0f}-{end * 1e3:.0f}" for start, end in t.unsupported)
        to_tip = " (and the tip with it)" if d.unsupported_to_tip else ""
        warnings.append(finding("CENTERLINE_UNSUPPORTED",
                                f"over s = {listed} mm no camera saw the tube's wall facing it on the tube's radius: "
                                f"the centreline there{to_tip} follows points off the wall (pixels a matcher mixed "
                                "with the background, a wall seen edge-on), and how far off it is was not measured",
                                stretches_mm=[[a * 1e3, b * 1e3] for a, b in t.unsupported],
                                to_tip=d.unsupported_to_tip))
    if d.end_on_warned and not d.unsupported_to_tip:
        angles = " and ".join(f"{math.degrees(angle):.0f} deg of {name}'s" for name, angle in d.end_on_angles.items())
        warnings.append(finding("DISTAL_END_ON",
                                f"the distal {d.end_on * 1e3:.0f} mm points within {angles} line of sight: every "
                                "camera sees its wall nearly edge-on there, and the centreline there and the tip with "
                                "it rest on that wall: how far off across the tube they are was not measured",
                                length_mm=d.end_on * 1e3,
                                angles_deg={name: math.degrees(angle) for name, angle in d.end_on_angles.items()}))
    return warnings


def _mm(value: float | None) -> float | None:
    return None if value is None else value * 1e3


def extrinsics(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """Whether the cameras' poses in the rig file agree across their views. Each camera alone places the axis across its
    view, window by window, by the tube's limbs in its colour image (limbs.LimbFigures.rigid) or else by depth
    (cross_view.CrossView), and by its whole outline where that lies beyond what those reach (a pose a millimetre
    off; trace.GROSS_OFFSET_PX): the noise varies along the tube, a camera whose pose is off moves every window alike.
    Two opposed cameras' shifts read with the same sign for a shift of one relative to the other, so their sum is
    the rigid offset between them; the fused axis lies half of it off. Warned where it stands beyond
    trace.EXTRINSICS_SIGMAS standard errors and beyond what the measure's own bias reaches (trace.RigidOffset.least;
    issue 62: beyond the level that breaks the floor): a matcher's window reaching the slots on one side of a view
    pulls the two cameras' depth apart alike all along a notched tube too, the limbs far less. Along the views no
    such check exists: two opposed cameras read an offset there as they read a depth bias common to both (the wall's
    level)."""
    rigid = rigid_offset(t)
    if rigid is None or t.centerline_tolerance is None:
        return {"cameras_across_view_offset_mm": None, "cameras_across_view_turn_deg": None}, []
    offset, error = rigid.offset, rigid.error
    distance = _camera_distance(t)
    # every result says how far apart the cameras place the axis, and the turn of one camera that would explain it
    turn_deg = None if distance is None else math.degrees(offset / distance)
    figures = {"cameras_across_view_offset_mm": offset * 1e3, "cameras_across_view_turn_deg": turn_deg}
    if not extrinsics_apart(t):
        return figures, []
    turn = "" if turn_deg is None else f", as a turn of one about the robot about {turn_deg:.2f} deg"
    return figures, [finding("EXTRINSICS_DISAGREE",
                             f"the cameras place the axis {offset * 1e3:.2f} mm apart across their views, alike all "
                             f"along the tube ({offset / error:.0f} standard errors: not the matcher's noise){turn}: "
                             "their poses in the rig file disagree, and the centreline lies "
                             f"{'up to all' if rigid.whole else 'about half'} of that off; "
                             "recalibrate with `ntcr-recon calibrate`", offset_mm=offset * 1e3, by_outlines=rigid.whole,
                             offset_error_mm=error * 1e3, turn_deg=turn_deg)]


def _camera_distance(t: Trace) -> float | None:
    """The cameras' mean distance to the tube (m; the nearest depth each sees of it), None without a reach."""
    if t.reach is None or not t.reach.depth:
        return None
    return float(np.mean([np.median(depth) for depth in t.reach.depth.values()]))


# The checks, in the order their warnings are listed.
CHECKS: tuple[Check, ...] = (notches_found, widths_against_bends, icp_reference, tip_end, camera_views,
                             tip_against_length, notch_side, bend_plane, depth_resolution, centerline, extrinsics)
