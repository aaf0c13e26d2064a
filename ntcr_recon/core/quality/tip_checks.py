"""The checks of the tip: what it rests on (an end cap, a rim the matcher eroded) and where it lies against the
robot's known length (short of it, carried past the end seen)."""

from __future__ import annotations

import math

import numpy as np

from ntcr_recon.core.quality.findings import Finding, finding
from ntcr_recon.core.quality.measures import (
    nearest_box_face,
    unseen_figures,
)
from ntcr_recon.core.quality.trace import Derived, Trace
from ntcr_recon.core.relocation.tip import LENGTH_AGREEMENT_SIGMAS

# The project's floor (issue 9) on the tip: an uncertainty above it is worth a note.
TIP_FLOOR = 0.15e-3


def tip_end(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """A tip uncertain beyond its floor: what it rests on, the end cap's plane or a stereo-eroded rim (a tip carried
    past the end seen is not where the cameras saw it: tip_against_length says so)."""
    tip = d.tip
    if math.hypot(tip.along, tip.across) <= TIP_FLOOR or tip.hidden_across:
        return {}, []
    weighed = " (the robot's known length weighed in)" if tip.weighed else ""
    across = f", and by {tip.across * 1e3:.2f} mm across it ({tip.why})" if tip.across else ""
    figures = {"along_mm": tip.along * 1e3, "across_mm": tip.across * 1e3, "across_because": tip.because}
    along = t.tip_along
    if t.tip_from_cap and along is not None and along.beyond_seen:
        return {}, [finding("TIP_ON_END_CAP",
                            f"the end cap's points stop {(along.expected_s - along.seen_s) * 1e3:.2f} mm short of the "
                            f"robot's length at this bend (smeared over {along.seen_uncertainty * 1e3:.2f} mm: the "
                            "stereo matcher mixes the cap's ring with the bore behind it, and only ever moves them "
                            f"towards the base): the tip is that length, uncertain by about {tip.along * 1e3:.2f} mm "
                            f"along the tube{across}", short_of_length_mm=(along.expected_s - along.seen_s) * 1e3,
                            smeared_mm=along.seen_uncertainty * 1e3, **figures)]
    if t.tip_from_cap:
        return {}, [finding("TIP_ON_END_CAP",
                            f"the tip is the end cap's plane, whose points the stereo matcher smeared over "
                            f"{tip.along * 1e3:.2f} mm towards the bore behind its ring: its position is uncertain by "
                            f"about {tip.along * 1e3:.2f} mm along the tube{weighed}{across}", **figures)]
    how = ", as the edge band measured in the depth images" if tip.measured else ""
    return {}, [finding("TIP_ON_ERODED_RIM",
                        f"the tip rests on a stereo-eroded rim ({t.tip_erosion * 1e3:.2f} mm given back{how}): its "
                        f"position is uncertain by about {tip.along * 1e3:.2f} mm along the tube{weighed}{across}",
                        erosion_mm=t.tip_erosion * 1e3, edge_band_measured=tip.measured, **figures)]



def tip_against_length(t: Trace, d: Derived) -> tuple[dict, list[Finding]]:
    """The end seen against the robot's length at the bend measured: off it beyond both their uncertainties, or
    far short of (past) it, with why (the crop box, a camera too near or pointed at); a tip left there is stated as
    uncertain as the shortfall (a controller reads the figures, not the warning). The tip's figures."""
    tip, along, warnings = d.tip, t.tip_along, []
    short, expected = tip.short, tip.expected_length
    if along is not None and not along.length_weighed and along.tolerance is not None and (
            not tip.ends_off_length and abs(along.disagreement) > LENGTH_AGREEMENT_SIGMAS):
        warnings.append(finding("TIP_OFF_LENGTH",
                                f"the end seen lies {abs(short) * 1e3:.2f} mm {'short of' if short > 0 else 'past'} "
                                f"the robot's length at this bend ({expected * 1e3:.2f} mm), more than both are known "
                                f"to ({along.seen_uncertainty * 1e3:.2f} and {along.tolerance * 1e3:.2f} mm, "
                                "robot.length_tolerance with the bend's): the tip is where the end was seen; check the "
                                "robot's notch layout, its base position along it and robot.length_tolerance",
                                short_of_length_mm=short * 1e3))
    if tip.ends_off_length:
        warnings.append(_tube_ends_off_length(t, d))
    held_over = max(t.tip_s - tip.held_from, 0.0)
    return {"tip_s_mm": t.tip_s * 1e3, "tip_seen_s_mm": d.seen_end * 1e3, "expected_length_mm": expected * 1e3,
            "tip_length_weighed": tip.weighed, "tip_uncertainty_mm": tip.stated_along * 1e3,
            "tip_across_uncertainty_mm": None if d.centreline_known is None and not tip.held
            and not tip.hidden_across and not tip.left_short else tip.stated_across * 1e3,
            "tip_held_shift_mm": tip.held * 1e3, "tip_held_over_mm": held_over * 1e3,
            "tip_carried_mm": tip.carried * 1e3,
            # how far past the end seen the tip was carried, where every camera was kept from the rest (0: it was not)
            "tip_hidden_mm": (t.tip_s - d.seen_end) * 1e3 if tip.hidden_across else 0.0}, warnings


def _tube_ends_off_length(t: Trace, d: Derived) -> Finding:
    """TUBE_ENDS_SHORT (or TIP_CARRIED where every camera was kept from the rest and the tip carried on there)."""
    tip, short, expected = d.tip, d.tip.short, d.tip.expected_length
    warning = (f"the tube ends {abs(short) * 1e3:.1f} mm {'short of' if short > 0 else 'past'} the robot's length "
               f"({expected * 1e3:.1f} mm at this bend): the tip is uncertain")
    face = None
    if short > 0 and t.tip_position is not None and t.crop_box is not None:
        axis, plane, distance = nearest_box_face(np.asarray(t.tip_position, float), t.crop_box)
        if distance < t.geometry.outer_diameter:  # the points were cut there, not the robot
            face = ("xyz"[axis], plane)
            warning += (f"; it ends on the crop box's face {face[0]} = {plane * 1e3:.1f} mm: the robot may go on "
                        "outside the box (filters.crop_box_min / crop_box_max; below the base plane, "
                        "filters.clamp_radius lets the automatic box reach there)")
    reached = t.reach is not None and short >= 0
    why = t.reach.why_unseen(list(t.camera_names), d.seen_end, expected, continued=True) if reached else ""
    carried = bool(why and tip.hidden_across)
    if carried:
        warning = (f"the tube seen ends {short * 1e3:.1f} mm short of the robot's length ({expected * 1e3:.1f} mm "
                   f"at this bend); {why}: that hides the rest, and the tip is carried on there, bending as the "
                   f"notches seen did, to the robot's length: uncertain by about {tip.along * 1e3:.2f} mm along the "
                   f"tube and {tip.across * 1e3:.2f} mm across it, the centreline with it by "
                   f"{d.stated_centreline * 1e3:.2f} mm (RMS over the robot's length)")
    elif why:
        warning += f"; {why}: that may hide the rest"
    if tip.left_short:
        warning += (f"; left at the end seen, the tip may lie up to {abs(short) * 1e3:.1f} mm off, along the tube "
                    "or across it, and its uncertainty is stated so")
    return finding("TIP_CARRIED" if carried else "TUBE_ENDS_SHORT", warning, short_of_length_mm=short * 1e3,
                   at_crop_box=face is not None, crop_box_face=None if face is None else face[0],
                   crop_box_face_mm=None if face is None else float(face[1]) * 1e3,
                   **(unseen_figures(t.reach, list(t.camera_names), d.seen_end, expected) if reached else {}))
