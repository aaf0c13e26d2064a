"""Self-check of a reconstruction: how sure the result is, as plain numbers and plain-language warnings.

`assess` looks only at the data and the configuration (never at ground truth): notches found of expected
and by which signal, the share of the robot's length each camera saw (and a distal stretch seen by one
camera alone, or a tube ending short, with the camera it came nearer than any depth that camera returned or
pointed at: `camera_reach`), the wall fit's residual, the measured notch side against the configured one, the centreline
bias the alignment removed and how uncertain the centreline still is, the tip against the robot's known
length, the pixel footprint against the tube, the depth quantisation seen in the frames, each notch's width
against the width its measured bend implies (and the notches it could not be checked for), how far the tip's
position rests on the rim erosion given back (and, across the tube, on the alignment's last shift held to it),
how much deeper the wall reads between the notches than on the plain tube (a lean no fit can see), and the
stretches where no camera saw the wall facing it (where the centreline's error was not measured), or where every
camera sees the distal wall nearly edge-on, and how far the axis lies from the middle of the tube's outline in the
cameras' views (core.outline; or that no view showed the outline whole to check it). Every figure
is in the unit its key names; the warnings are sentences a user can act on. relocation_node puts them on
/diagnostics, the CLI prints them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from ntcr_recon.core.centerline import cameras_round_tube
from ntcr_recon.core.comb import expected_centres, inside_intervals
from ntcr_recon.core.findings import Finding, finding, notch_width_uncertainties, uncertainty_mm
from ntcr_recon.core.icp import ReferenceMove
from ntcr_recon.core.notches import MISREAD_WIDTH_FRACTION
from ntcr_recon.core.outline import OUTLINE_TOLERANCE_PX, went_astray
from ntcr_recon.core.tip import LENGTH_AGREEMENT_SIGMAS, TipAlongTube
from ntcr_recon.core.wall import median, surface_band

# Thresholds, relative to the robot and the camera so that no robot is special.
ONE_CAMERA_RUN_DIAMETERS = 1.0     # a distal stretch longer than this many diameters seen by one camera: warn
SEEN_DENSITY_FRACTION = 0.2        # a camera saw a stretch holding this share of its typical wall points there
SIDE_OFF_DEG = 10.0                # measured notch side this far from the configured one: warn
TIP_SHORT_DIAMETERS = 0.5          # tip this many diameters short of (or past) the robot's length: warn
FOOTPRINT_RADIUS_FRACTION = 1 / 7  # pixel footprint above this fraction of r_o: too few pixels across
QUANTISATION_RADIUS_FRACTION = 1 / 8   # depth step above this fraction of r_o: the tube's roundness is lost
BIAS_WARN_FOOTPRINTS = 0.5         # a lean into the slots above this many footprints: warn
# A tube whose axis lies this near a camera's line of sight shows it its wall 60 deg or more from facing it:
# a thin band of pixels, matched poorly (core.tip.GRAZING: past 80 deg none) - named as why that camera missed it.
END_ON_DEG = 30.0
END_ON_PITCHES = 2.0  # a distal stretch this many notch pitches long that every camera sees end-on: warn
# The project's floors (issue 9): a figure whose uncertainty exceeds its floor is worth a warning.
TIP_FLOOR = 0.15e-3
CENTERLINE_FLOOR = 0.08e-3
# An error growing linearly from the clamped base to the free end is sqrt(3) times its RMS over the length there.
FREE_END_FACTOR = math.sqrt(3.0)
# Two cameras whose own axes at the end lie +-b about the fused one (an RMS of b) lie 2 b apart: the free end
# follows whichever wall the matcher biased there, and nothing beyond it holds the axis.
DISTAL_CROSS_VIEW_FACTOR = 2.0


def _seen_cells(s: np.ndarray, camera: np.ndarray, cameras: int, tip_s: float, cell: float,
                pool: float) -> np.ndarray:
    """(cameras, cells) whether each camera saw each cell of [0, tip] (see camera_coverage)."""
    cells = max(int(np.ceil(tip_s / cell)), 1)
    counts = np.zeros((cameras, cells))
    inside = (s >= 0) & (s < tip_s)
    index = np.minimum((s[inside] / cell).astype(np.intp), cells - 1)
    np.add.at(counts, (camera[inside].astype(np.intp), index), 1.0)
    pooled = uniform_filter1d(counts, size=max(int(round(pool / cell)), 1), axis=1, mode="nearest")
    typical = np.percentile(pooled, 90, axis=1, keepdims=True)
    return (counts > 0) & (pooled >= SEEN_DENSITY_FRACTION * typical)


def camera_coverage(s: np.ndarray, camera: np.ndarray | None, camera_names: tuple[str, ...], tip_s: float,
                    cell: float, pool: float) -> tuple[dict[str, float], dict[str, float]]:
    """Per camera the share of [0, tip] (in cells) it saw, and the length (m) of the distal stretch that camera
    alone saw (0 when the other cameras see the tip too). A camera saw a cell that holds its wall points, when
    those within `pool` (m, centred on the cell) are at least SEEN_DENSITY_FRACTION of its typical count (their
    90th percentile over the tube): a few stray points where it cannot see the tube (nearer than its minimum
    depth) are no view of it."""
    if camera is None:
        return {}, {}
    seen = _seen_cells(s, camera, len(camera_names), tip_s, cell, pool)
    share = {name: float(seen[i].mean()) for i, name in enumerate(camera_names)}
    alone = {}
    for i, name in enumerate(camera_names):
        others = np.delete(seen, i, axis=0).any(axis=0)
        last_other = int(np.flatnonzero(others)[-1]) + 1 if np.any(others) else 0
        mine_beyond = seen[i, last_other:]
        alone[name] = float(np.count_nonzero(mine_beyond) * cell) if np.any(mine_beyond) else 0.0
    return share, alone


def where_notches_went_unseen(missing: list[int], centres: np.ndarray, half_width: float, s: np.ndarray,
                              camera: np.ndarray | None, camera_names: tuple[str, ...], seen_end: float,
                              cell: float, pool: float) -> tuple[list[int], dict[str, list[int]]]:
    """Of the `missing` notches (indices into the comb's `centres`, m along s), those lying beyond the end seen,
    and per camera those it did not see: under half the cells of the notch's cut (centre +- half_width) seen by
    it (camera_coverage's criterion). A notch a camera did not see may have opened towards it alone."""
    beyond = [i for i in missing if centres[i] - half_width >= seen_end]
    if camera is None:
        return beyond, {}
    seen = _seen_cells(s, camera, len(camera_names), seen_end, cell, pool)
    unseen: dict[str, list[int]] = {}
    for i in missing:
        if i in beyond:
            continue
        first = max(int((centres[i] - half_width) / cell), 0)
        stop = min(int(np.ceil((centres[i] + half_width) / cell)), seen.shape[1])
        for k, name in enumerate(camera_names):
            if stop <= first or seen[k, first:stop].mean() < 0.5:
                unseen.setdefault(name, []).append(i)
    return beyond, unseen


def _unseen_figures(reach, names: list[str], start: float, end: float) -> dict:
    """CameraReach.unseen as a warning's figures: per camera how near the stretch comes (too_near_mm) or how close
    to its line of sight it points (end_on_deg); {} without a reach."""
    if reach is None:
        return {}
    too_near, end_on = reach.unseen(names, start, end)
    return {"too_near_mm": {k: v * 1e3 for k, v in too_near.items()},
            "end_on_deg": {k: math.degrees(v) for k, v in end_on.items()}}


def _notches_lie(indices: list[int]) -> str:
    """'notch 7 lies', 'notches 12, 14 and 15 lie', 'notches 13-19 lie': runs of three or more as first-last."""
    runs, start = [], 0
    for k in range(1, len(indices) + 1):
        if k == len(indices) or indices[k] != indices[k - 1] + 1:
            run = indices[start:k]
            runs += [f"{run[0]}-{run[-1]}"] if len(run) >= 3 else [str(i) for i in run]
            start = k
    if len(indices) == 1:
        return f"notch {indices[0]} lies"
    return f"notches {runs[0] if len(runs) == 1 else ', '.join(runs[:-1]) + ' and ' + runs[-1]} lie"


def surface_depth(positions: np.ndarray, tangents: np.ndarray, extrinsic: np.ndarray, radius: float) -> np.ndarray:
    """Per axis point, the depth (m, along the camera's optical axis) of the tube's surface nearest the camera:
    the axis's depth less the radius times the sine between the tangent and the optical axis (the ring about
    the axis there reaches that far towards the camera; an end cap seen end-on, as far). extrinsic: the
    camera's optical frame in the base frame (4x4)."""
    axis = extrinsic[:3, 2]
    along = np.clip(np.asarray(tangents, float) @ axis, -1.0, 1.0)
    return (np.asarray(positions, float) - extrinsic[:3, 3]) @ axis - radius * np.sqrt(1.0 - along**2)


@dataclass(frozen=True)
class CameraReach:
    """How near the tube comes to each camera along it (its surface's nearest depth, `surface_depth`, at each
    sampled s; past the tip seen, carried on bending at its notches as before them, up to the robot's length) and
    how its axis lies to the camera's line of sight, and the nearest depth of any point each camera returned: a
    stretch nearer a camera than all it returned is one its stereo matching could not reach (a D405 at 848x480
    sees nothing nearer than about 70 mm); one pointing at it, one whose wall it sees nearly edge-on."""

    s: np.ndarray
    depth: dict[str, np.ndarray]
    nearest_returned: dict[str, float]
    sight_angle: dict[str, np.ndarray]  # per camera, the angle (rad, 0-90 deg) between the axis and its line of sight

    def _least(self, per_camera: dict[str, np.ndarray], name: str, start: float, end: float) -> float | None:
        """The least of camera `name`'s samples over the stretch [start, end] (None: none there, or no such
        camera)."""
        inside = (self.s >= start) & (self.s <= end)
        if name not in per_camera or not np.any(inside):
            return None
        return float(per_camera[name][inside].min())

    def too_near(self, name: str, start: float, end: float) -> float | None:
        """The stretch [start, end]'s nearest depth to camera `name` (m) when it is nearer than any the camera
        returned, else None."""
        nearest, returned = self._least(self.depth, name, start, end), self.nearest_returned.get(name)
        return nearest if nearest is not None and returned is not None and nearest < returned else None

    def end_on(self, name: str, start: float, end: float) -> float | None:
        """The smallest angle (rad) between the stretch [start, end]'s axis and camera `name`'s line of sight,
        when under END_ON_DEG, else None."""
        angle = self._least(self.sight_angle, name, start, end)
        return angle if angle is not None and angle < math.radians(END_ON_DEG) else None

    def end_on_to_every_camera(self, tip_s: float) -> tuple[float, dict[str, float]]:
        """The distal stretch, ending at the tip seen, whose axis lies within END_ON_DEG of every camera's line of
        sight (each sees its wall nearly edge-on): its length (m; 0 for none) and per camera the least angle (rad)
        between axis and line of sight over it."""
        inside = self.s <= tip_s
        if not np.any(inside) or not self.sight_angle:
            return 0.0, {}
        end_on = np.all([angle[inside] < math.radians(END_ON_DEG) for angle in self.sight_angle.values()], axis=0)
        off = np.flatnonzero(~end_on)
        first = int(off[-1]) + 1 if len(off) else 0  # the first sample of the end-on run that ends at the tip
        if first == len(end_on):
            return 0.0, {}
        start = float(self.s[inside][first])
        return tip_s - start, {name: self._least(self.sight_angle, name, start, tip_s) for name in self.sight_angle}

    def unseen(self, names: list[str], start: float, end: float) -> tuple[dict[str, float], dict[str, float]]:
        """Of `names`, the cameras the stretch [start, end] comes nearer than any depth they returned (how near, m)
        and those it points at (END_ON_DEG; the angle to the line of sight, rad)."""
        too_near, end_on = {}, {}
        for name in names:
            if (near := self.too_near(name, start, end)) is not None:
                too_near[name] = near
            elif (angle := self.end_on(name, start, end)) is not None:
                end_on[name] = angle
        return too_near, end_on

    def why_unseen(self, names: list[str], start: float, end: float, continued: bool = False) -> str:
        """The clause naming the cameras of `unseen` ('' for none); continued: the stretch is the tube continued at
        its last bend, not seen."""
        verb = "" if continued else "s"
        too_near, end_on = self.unseen(names, start, end)
        reasons = [f"come{verb} within {near * 1e3:.0f} mm of {name}, which returned no depth nearer than "
                   f"{self.nearest_returned[name] * 1e3:.0f} mm" for name, near in too_near.items()]
        reasons += [f"point{verb} within {math.degrees(angle):.0f} deg of {name}'s line of sight, which sees its wall "
                    "nearly edge-on" for name, angle in end_on.items()]
        if not reasons:
            return ""
        return f"{'continued at its last bend, it would' if continued else 'it'} {'; and '.join(reasons)}"


def camera_reach(carried, tip_s: float, length: float, radius: float, step: float,
                 extrinsics: dict[str, np.ndarray], xyz: np.ndarray, camera: np.ndarray | None) -> CameraReach:
    """The CameraReach of a tube seen up to tip_s of a robot `length` long (m): its axis sampled every `step` along
    `carried`, the centreline up to tip_s carried on past it as the robot bends (centerline.continued_bend) to the
    length; the points `xyz` returned by the cameras (by index into extrinsics' order, `camera`), none known
    without it."""
    seen = np.append(np.arange(0.0, tip_s, step), tip_s)
    if length > tip_s:
        seen = np.concatenate([seen, tip_s + np.arange(step, length - tip_s + step, step)])
    positions, tangents = carried.frames_at(seen)[:2]
    depth, nearest, sight = {}, {}, {}
    for index, (name, extrinsic) in enumerate(extrinsics.items()):
        depth[name] = surface_depth(positions, tangents, extrinsic, radius)
        towards = positions - extrinsic[:3, 3]
        cosine = np.abs(np.einsum("ij,ij->i", towards, tangents)) / np.linalg.norm(towards, axis=1)
        sight[name] = np.arccos(np.clip(cosine, 0.0, 1.0))
        mine = xyz[camera == index] if camera is not None else xyz[:0]
        if len(mine):
            nearest[name] = float(((mine - extrinsic[:3, 3]) @ extrinsic[:3, 2]).min())
    return CameraReach(seen, depth, nearest, sight)


def notched_thinning(offset: np.ndarray, s: np.ndarray, cuts: np.ndarray, tip_s: float, gate: float,
                     margin: float, spine: np.ndarray | None = None) -> float | None:
    """How much deeper (m, + thinner) the outer wall reads between the notches than on the plain tube beyond
    them: the wall level (wall.surface_band) of the spines in the notched section less that of the plain
    stretches before the first and after the last cut. offset: the points' radial offsets from the outer wall;
    cuts: (K, 2) the notches' [start, end] along s; margin: kept from every cut, the base and the tip; spine:
    the points outside the cuts grown by margin, when the caller has them (notches.spine_wall). None where
    either part has too few points to tell.

    A stereo matcher gives each pixel its window's mean depth: on a spine narrower than the window, seen by a
    camera that looks into the slots, the window reaches the slot floors behind it, and the spine reads deep.
    Pooled over opposed cameras the level does not depend on where the axis is put between them, so this
    measures what no fit can: a deficit carried by one camera moves the axis away from it by up to as much.
    """
    if len(cuts) == 0:
        return None
    first, last = float(np.min(cuts[:, 0])) - margin, float(np.max(cuts[:, 1])) + margin
    inside = (s > margin) & (s < tip_s - margin)
    if spine is None:
        spine = ~inside_intervals(s, np.column_stack([cuts[:, 0] - margin, cuts[:, 1] + margin]))
    notched = inside & (s > first) & (s < last) & spine
    plain = inside & ((s < first) | (s > last))
    if np.count_nonzero(notched) < 8 or np.count_nonzero(plain) < 8:
        return None
    notched_level, _ = surface_band(offset, gate, notched)
    plain_level, _ = surface_band(offset, gate, plain)
    return plain_level - notched_level


def cameras_looking_into_slots(centerline, geometry, camera_origins: np.ndarray,
                               camera_names: tuple[str, ...]) -> list[str]:
    """The cameras that look into the notches' slots: the angle about the axis between the direction to the
    camera and the notch side (the centreline's normal), median over the notches, within
    geometry.slot_floor_view_angle - their line of sight through a slot meets its floor."""
    centres = np.clip(expected_centres(geometry, centerline), 0.0, centerline.length)
    round_tube = cameras_round_tube(centerline.frames_at(centres), camera_origins)
    angle = np.ascontiguousarray(np.abs(np.arctan2(round_tube[..., 1], round_tube[..., 0])).T)  # per camera
    return [name for name, angles in zip(camera_names, angle, strict=True)
            if median(angles) < geometry.slot_floor_view_angle]


def unmeasured_share(unsupported: tuple[tuple[float, float], ...], end_on: float, tip_s: float) -> float:
    """The share of the length up to tip_s where nothing measured how far off the axis is: the stretches where no
    camera saw the wall facing it (`unsupported`) and the distal `end_on` m every camera sees end-on (0: none
    warned of), counted once where they overlap."""
    stretches = [(max(start, 0.0), min(end, tip_s)) for start, end in unsupported]
    if end_on > 0:
        stretches.append((tip_s - end_on, tip_s))
    covered, reached = 0.0, 0.0
    for start, end in sorted(stretches):
        start = max(start, reached)
        if end > start:
            covered, reached = covered + end - start, end
    return min(covered / tip_s, 1.0) if tip_s > 0 else 0.0


def assess(*, geometry, camera_names: tuple[str, ...], notches: list,
           coords_s: np.ndarray, camera: np.ndarray | None, tip_s: float, total_bend: float, footprint: float,
           wall_residual: float, notch_side: float, configured_side: float, bias_notch_side: float,
           bias_binormal: float, depth_steps: dict[str, float], tip_erosion: float = 0.0,
           tip_uncertainty: float | None = None, tip_position: np.ndarray | None = None,
           crop_box: tuple[np.ndarray, np.ndarray] | None = None,
           notched_thinning: float | None = None, looking_into_slots: tuple[str, ...] = (),
           tip_from_cap: bool = False, side_unsettled: tuple[float, float] | None = None,
           side_uncertainty: float | None = None,
           cross_view_spread: float | None = None, distal_cross_view: float | None = None,
           alignment_scatter: float | None = None, outline_offset: float | None = None,
           across_from_fit: tuple[float, float] | None = None, tip_along: TipAlongTube | None = None,
           backbone_shift: float | None = None, held_shift: tuple[float, float] | None = None,
           unsupported: tuple[tuple[float, float], ...] = (),
           misread_widths: dict[int, float] | None = None, unchecked: list[int] | None = None,
           reach: CameraReach | None = None, notch_centres: np.ndarray | None = None,
           wall_level: float | None = None, fitted_end: float | None = None,
           reference_moved: ReferenceMove | None = None) -> tuple[dict, list[Finding]]:
    """The `quality` document and the warnings (see the module docstring). tip_uncertainty: how well the tip's
    refinement placed it along the tube, when it measured the erosion it gave back (else the erosion itself
    counts as uncertain, and half a footprint). tip_position, crop_box: where the tip is and the box the points
    were cropped to (base frame), to tell a tube cut off by the box. notched_thinning: `notched_thinning`'s
    figure, when it could be measured; looking_into_slots: `cameras_looking_into_slots`; tip_from_cap: the tip is
    the end cap's plane (tip.end_cap_plane), tip_uncertainty the smear of its points; side_unsettled: the notch
    side measured off the configured one, then off again in the frame turned to it (rad), when the configured
    one was kept for it; side_uncertainty: how well the side measured is known (rad; None: not measured).
    tip_along: the tip between the end seen and the robot's length (tip.TipAlongTube);
    its uncertainty is the tip's then, and the end seen is what is judged against the robot's length.
    backbone_shift: how far alignment.level_by_backbone moved the axis (m; None or 0: no camera faced the
    backbone), which then places it along the views, not the slots' lean. unsupported: the stretches of s
    where no camera saw trusted wall (alignment.CrossView), where no uncertainty was measured. distal_cross_view:
    CrossView.distal, the cameras' spread across their views in the last window, which bounds the tip across
    the tube from below where it exceeds what the whole length implies. alignment_scatter: how much the
    alignment's shift of the fit varies along the tube (alignment.shift_scatter), part of the centreline's.
    misread_widths: the width each notch notches.calibrate_and_check found misread was read at (by index), now its
    bend's; unchecked: the notches it could not check (CheckedNotches.unchecked). held_shift: (how far the
    alignment moved the end, the s beyond which it held that shift unmeasured) (m; alignment.Alignment's end_shift
    and held_from), an uncertainty of the tip across the tube of its own: the fit's lean there was measured no
    nearer the tip. reach: how near the tube
    comes to each camera, to name a camera too near a stretch it did not see (CameraReach). notch_centres: the
    comb's notch centres along s (comb.expected_centres), to say where the missing notches lie. wall_level: the
    outer wall's level about the r_o circle (m, wall.surface_band of all points), on which the axis rests where
    one camera alone saw the tube (centerline_uncertainty). outline_offset: how far the axis lies from the middle
    of the tube's outline in the cameras' views (m, RMS; outline.outline_offset): beyond OUTLINE_TOLERANCE_PX
    footprints the axis went astray with the wall it rests on, and is known no better than that. across_from_fit:
    (the aligned axis's outline offset, the fit's; m) when the alignment went astray, the fit did not, and the fit
    placed the axis across the cameras' views (outline.across_views_from). fitted_end: where the fitted curve ended
    (m), past which the centreline was carried on bending to the tip (carried_to_tip). reference_moved: relocated
    by ICP, how far it moved its reference off the pose the centreline gave it (icp.ReferenceMove): the tip moved
    with it, and the tip and the relocated surface are known no better than that move."""
    warnings: list[Finding] = []
    r_o, diameter = geometry.outer_radius, geometry.outer_diameter
    found = sorted(n.index for n in notches)
    missing = sorted(set(range(geometry.notch_count)) - set(found))
    by_signal: dict[str, int] = {}
    for notch in notches:
        by_signal[notch.signal] = by_signal.get(notch.signal, 0) + 1
    cell = max(footprint, r_o / 8)
    seen_end = tip_s if tip_along is None else tip_along.seen_s
    beyond, unseen, unmarked = [], {}, []
    if missing:
        warning = (f"{len(found)} of {geometry.notch_count} notches found (missing: "
                   f"{', '.join(str(i) for i in missing)}): their widths are unknown")
        if notch_centres is not None:  # where the comb puts them: past the end seen, or out of a camera's view
            half = geometry.notch_width / 2
            beyond, unseen = where_notches_went_unseen(missing, notch_centres, half, coords_s, camera, camera_names,
                                                       seen_end, cell, pool=diameter)
            for name, indices in unseen.items():
                why = "" if reach is None else reach.why_unseen(
                    [name], notch_centres[indices[0]] - half, min(notch_centres[indices[-1]] + half, seen_end))
                warning += f"; {_notches_lie(indices)} where {name} did not see the tube{f' ({why})' if why else ''}"
            if beyond:
                warning += f"; {_notches_lie(beyond)} beyond the end seen ({seen_end * 1e3:.1f} mm along the tube)"
            if camera is not None:  # seen, yet not found: what a depth pixel there is against the cut
                unmarked = [i for i in missing if i not in beyond and not any(i in v for v in unseen.values())]
            if unmarked:
                them = "it" if len(unmarked) == 1 else "them"
                warning += (f"; {_notches_lie(unmarked)} where the cameras saw the tube, yet no gap or dip of the wall "
                            f"marks {them} (a {geometry.notch_width * 1e3:.1f} mm cut spans "
                            f"{geometry.notch_width / footprint:.0f} px in the depth images there: a stereo matcher's "
                            f"window that wide or wider fills it; or it opens to a side no camera saw)")
        warnings.append(finding("NOTCHES_MISSING", warning, missing=missing, beyond_end=beyond,
                                unseen_by={name: list(indices) for name, indices in unseen.items()},
                                unmarked=unmarked))
    dips = sorted(n.index for n in notches if n.signal == "dip")
    if dips:
        warnings.append(finding("NOTCH_WIDTH_FROM_BEND",
                                f"notches {', '.join(str(i) for i in dips)} show only as a shallow dip of the wall's "
                                "coverage where the comb puts them (slots narrower than the stereo matcher's window, "
                                "which fills them): their edges were not measured, and their widths are what their "
                                "measured bends imply", notches=dips))
    # a notch's width follows from its cut and its measured bend (the gap on the outer wall of a notch of neutral
    # length h bent by theta): one read far off it was misread, and given its bend's (notches.calibrate_and_check);
    # per notch how far the width read is off it (a misread one's as read)
    misread_widths = misread_widths or {}
    off_model = {n.index: misread_widths.get(n.index, n.width) - geometry.notch_width_at_bend(n.bend or 0.0)
                 for n in notches if n.edges_measured or n.index in misread_widths}
    if misread_widths:
        listed = ", ".join(f"{n.index} ({misread_widths[n.index] * 1e3:.2f} mm read, {n.width * 1e3:.2f} implied)"
                           for n in notches if n.index in misread_widths)
        warnings.append(finding("NOTCH_WIDTH_MISREAD",
                                f"notches whose edges read a width their bends rule out: {listed}; their rims were "
                                "misread (a slot seen through over a narrow run, a rim merged with a cut face, the "
                                "last notch's distal rim where the tube seen thins out), and their widths are what "
                                "their measured bends imply (for the last notch found, whose own bend no whole spine "
                                "beyond measures, the bend of the two before it; a robot whose cuts are off its "
                                "drawing would read so too)",
                                notches=sorted(misread_widths),
                                read_width_mm={str(i): w * 1e3 for i, w in sorted(misread_widths.items())},
                                implied_width_mm={str(n.index): n.width * 1e3 for n in notches
                                                  if n.index in misread_widths}))
    # a notch whose next one is missing where the tube seen ends within a pitch: its bend is a chord that may run
    # into a tube cut short; with no measured notch before it either, its width, as read, was checked against nothing
    unchecked = list(unchecked or ())
    if unchecked:
        warnings.append(finding("NOTCH_WIDTH_UNCHECKED",
                                "widths not checked against their bends, as read: notches "
                                f"{', '.join(map(str, unchecked))} (the next notch was not found and the tube seen "
                                "ends within a pitch: no whole spine beyond measures the bend, and no notch before it "
                                "whose bend was measured)", notches=unchecked))
    # the tip's rim is a depth edge: it rests on the erosion given back, known to about that much unless the
    # refinement measured it
    measured = tip_uncertainty is not None
    tip_uncertainty = tip_uncertainty if measured else abs(tip_erosion) + footprint / 2
    weighed = ""
    if tip_along is not None:
        tip_uncertainty = tip_along.uncertainty
        weighed = " (the robot's known length weighed in)" if tip_along.length_weighed else ""
    # relocated by ICP, the tip moved with the reference off where the centreline placed it
    centreline_tip_along = tip_uncertainty
    icp_along, icp_across = ((reference_moved.tip_along, reference_moved.tip_across) if reference_moved is not None
                             else (0.0, 0.0))
    tip_uncertainty = math.hypot(tip_uncertainty, icp_along)
    # pooled over two cameras, a deficit one of them carries alone reads half: the lean may reach twice it
    lean = 2.0 * notched_thinning if notched_thinning is not None and looking_into_slots else 0.0
    levelled = bool(backbone_shift)
    share, alone = camera_coverage(coords_s, camera, camera_names, tip_s, cell, pool=diameter)
    one_sided = {name: length for name, length in alone.items() if length > ONE_CAMERA_RUN_DIAMETERS * diameter}
    # (the share of the length one camera alone saw, the wall's level the axis rests on there), when both are known
    resting_on_level = ((min(sum(one_sided.values()) / max(seen_end, cell), 1.0), wall_level)
                        if one_sided and wall_level is not None else None)
    astray = outline_offset if went_astray(outline_offset, footprint) else None
    uncertainty = centerline_uncertainty(cross_view_spread, notched_thinning, looking_into_slots, levelled,
                                         one_sided=resting_on_level, astray=astray, varying_lean=alignment_scatter)
    # where no camera's view showed the tube's outline whole, nothing checked the axis across the views (outline.py):
    # it is known there no better than that check resolves, a pixel footprint (a sound axis lies within one of the
    # outline's middle), whatever the cameras' spread says (the warning below says so)
    outline_unchecked = camera is not None and outline_offset is None
    centreline_known = max(uncertainty or 0.0, footprint) if outline_unchecked else uncertainty
    # the tip sits on the centreline's free end, where an error growing along the tube is sqrt(3) its RMS, with
    # the shift the alignment measured last and held unchecked to the tip (the fit's lean it corrected there may
    # differ beyond); and where the cameras disagree in the last window, their own axes' distance apart
    end_spread = DISTAL_CROSS_VIEW_FACTOR * (distal_cross_view or 0.0)
    free_end = FREE_END_FACTOR * (centreline_known or 0.0)
    held, held_from = held_shift if held_shift is not None and held_shift[1] is not None else (0.0, tip_s)
    carried, carried_across = carried_to_tip(fitted_end, tip_s, notch_centres, geometry, centreline_known or 0.0)
    # carried past an end hidden from every camera: the hidden notches may bend otherwise than the ones seen
    hidden_across = 0.0 if tip_along is None or tip_along.hidden_across is None else tip_along.hidden_across
    centreline_across = math.hypot(free_end, held, carried_across, hidden_across)
    centreline_tip_across = max(centreline_across, end_spread)
    tip_across = max(math.hypot(centreline_across, icp_across), end_spread)
    if end_spread >= tip_across:
        why = "the cameras' axes that far apart across their views at the end"
        across_because = "cameras_apart"
    elif icp_across > max(free_end, held, carried_across, hidden_across):
        why = "ICP moved it that far off where the centreline placed it"
        across_because = "icp"
    elif hidden_across > max(free_end, held, carried_across):
        across_because = "hidden"
        why = (f"were the {(tip_s - seen_end) * 1e3:.1f} mm no camera saw straight, not bent as the notches seen, "
               "the tip would lie that far off")
    elif carried_across > max(free_end, held):
        across_because = "carried"
        why = (f"the centreline carried on bending over the {carried * 1e3:.1f} mm past where its fit reached, at "
               "the bend of the notches before")
    elif held > free_end:
        across_because = "held_shift"
        why = (f"the alignment moved the axis {held * 1e3:.2f} mm at the last wall it trusted, and held that shift "
               f"unchecked over the {max(tip_s - held_from, 0.0) * 1e3:.1f} mm to the tip")
    else:
        why = "the centreline's, at its free end"
        across_because = "free_end"
    across = f", and by {tip_across * 1e3:.2f} mm across it ({why})" if tip_across else ""
    # the centreline runs on past the end seen to a carried tip: along that stretch a straight hidden part leaves it
    # off by up to hidden_across, growing with the square of the distance carried (a fifth of its square in the
    # mean): the RMS over the robot's length
    stated_centreline = centreline_known
    if hidden_across:
        hidden_share = (tip_s - seen_end) / tip_s
        stated_centreline = math.sqrt((centreline_known or 0.0) ** 2 + hidden_share * hidden_across**2 / 5)
    # over the stretches where no camera saw the wall facing it, or every camera sees it end-on (both warned below),
    # nothing measured how far off the axis is: known there no better than a pixel footprint, their share of the
    # length weighs that in the RMS (as the outline check's resolution where it could not run)
    end_on, end_on_angles = (0.0, {}) if reach is None else reach.end_on_to_every_camera(tip_s)
    end_on_warned = end_on >= END_ON_PITCHES * geometry.notch_pitch
    unmeasured = unmeasured_share(unsupported, end_on if end_on_warned else 0.0, tip_s)
    if unmeasured and stated_centreline is not None:
        stated_centreline = math.sqrt(stated_centreline**2 + unmeasured * footprint**2)
    tip_total = math.hypot(tip_uncertainty, tip_across)
    if reference_moved is not None and (reference_moved.rms > (stated_centreline or 0.0)
                                        or math.hypot(icp_along, icp_across)
                                        > math.hypot(centreline_tip_along, centreline_tip_across)):
        warnings.append(finding("ICP_MOVED_REFERENCE",
                                "relocated by ICP (relocation.method icp), which moved the reference "
                                f"{reference_moved.rms * 1e3:.2f} mm (RMS) off the pose the centreline gave it, and "
                                f"the tip {icp_along * 1e3:.2f} mm along the tube and {icp_across * 1e3:.2f} mm across "
                                "it: further than the centreline or its tip is known to. The two relocations disagree "
                                "by that much, and the relocated surface and the tip are known no better",
                                reference_move_mm=reference_moved.rms * 1e3))
    # (a tip carried past the end seen is not where the cameras saw it: the warning of the tube ending short says so)
    if tip_total > TIP_FLOOR and tip_from_cap and not hidden_across:
        if tip_along is not None and tip_along.beyond_seen:
            warnings.append(finding("TIP_ON_END_CAP",
                                    f"the end cap's points stop {(tip_along.expected_s - tip_along.seen_s) * 1e3:.2f} "
                                    "mm short of the robot's length at this bend (smeared over "
                                    f"{tip_along.seen_uncertainty * 1e3:.2f} mm: the stereo matcher mixes the cap's "
                                    "ring with the bore behind it, and only ever moves them towards the base): the "
                                    f"tip is that length, uncertain by about {tip_uncertainty * 1e3:.2f} mm along the "
                                    f"tube{across}",
                                    short_of_length_mm=(tip_along.expected_s - tip_along.seen_s) * 1e3,
                                    smeared_mm=tip_along.seen_uncertainty * 1e3, along_mm=tip_uncertainty * 1e3,
                                    across_mm=tip_across * 1e3, across_because=across_because))
        else:
            warnings.append(finding("TIP_ON_END_CAP",
                                    "the tip is the end cap's plane, whose points the stereo matcher smeared over "
                                    f"{tip_uncertainty * 1e3:.2f} mm towards the bore behind its ring: its position "
                                    f"is uncertain by about {tip_uncertainty * 1e3:.2f} mm along the "
                                    f"tube{weighed}{across}", along_mm=tip_uncertainty * 1e3,
                                    across_mm=tip_across * 1e3, across_because=across_because))
    elif tip_total > TIP_FLOOR and not hidden_across:
        how = ", as the edge band measured in the depth images" if measured else ""
        warnings.append(finding("TIP_ON_ERODED_RIM",
                                f"the tip rests on a stereo-eroded rim ({tip_erosion * 1e3:.2f} mm given back{how}): "
                                f"its position is uncertain by about {tip_uncertainty * 1e3:.2f} mm along the "
                                f"tube{weighed}{across}", erosion_mm=tip_erosion * 1e3,
                                edge_band_measured=measured, along_mm=tip_uncertainty * 1e3,
                                across_mm=tip_across * 1e3, across_because=across_because))
    for name, length in one_sided.items():
        why = "" if reach is None else reach.why_unseen([n for n in camera_names if n != name], tip_s - length, tip_s)
        warnings.append(finding("DISTAL_ONE_CAMERA",
                                f"the distal {length * 1e3:.0f} mm is seen by {name} "
                                f"alone{f' ({why})' if why else ''}: the tube's far side there is inferred, not "
                                "measured, and the centreline there rests on one side, the tip with it: no second "
                                "view checked where it lies across the tube",
                                camera=name, length_mm=length * 1e3,
                                **_unseen_figures(reach, [n for n in camera_names if n != name], tip_s - length,
                                                  tip_s)))
    for name, fraction in share.items():
        if fraction < 0.5:
            warnings.append(finding("CAMERA_SHORT_VIEW", f"{name} saw only {fraction:.0%} of the robot's length",
                                    camera=name, share=fraction))
    # bending shortens the centreline by ybar * theta: what the tip should read with the measured bend
    expected_length = geometry.bent_length(total_bend)
    short = expected_length - seen_end
    ends_off_length = abs(short) > TIP_SHORT_DIAMETERS * diameter
    # a tip left at an end seen far short of (or past) the robot's length (not carried on) lies wherever the rest of
    # the robot reaches
    left_short = ends_off_length and not hidden_across
    if tip_along is not None and not tip_along.length_weighed and tip_along.tolerance is not None and (
            not ends_off_length and abs(tip_along.disagreement) > LENGTH_AGREEMENT_SIGMAS):
        warnings.append(finding("TIP_OFF_LENGTH",
                                f"the end seen lies {abs(short) * 1e3:.2f} mm {'short of' if short > 0 else 'past'} "
                                f"the robot's length at this bend ({expected_length * 1e3:.2f} mm), more than both are "
                                f"known to ({tip_along.seen_uncertainty * 1e3:.2f} and {tip_along.tolerance * 1e3:.2f} "
                                "mm, robot.length_tolerance with the bend's): the tip is where the end was seen; "
                                "check the robot's notch layout, its base position along it and robot.length_tolerance",
                                short_of_length_mm=short * 1e3))
    if ends_off_length:
        where = "short of" if short > 0 else "past"
        warning = (f"the tube ends {abs(short) * 1e3:.1f} mm {where} the robot's length "
                   f"({expected_length * 1e3:.1f} mm at this bend): the tip is uncertain")
        at_crop_box, crop_box_face, crop_box_face_mm = False, None, None
        if short > 0 and tip_position is not None and crop_box is not None:
            edge = _nearest_box_face(np.asarray(tip_position, float), crop_box)
            at_crop_box = bool(edge[2] < diameter)
            if at_crop_box:
                crop_box_face, crop_box_face_mm = "xyz"[edge[0]], float(edge[1]) * 1e3
            if at_crop_box:  # the points were cut there, not the robot
                warning += (f"; it ends on the crop box's face {'xyz'[edge[0]]} = {edge[1] * 1e3:.1f} mm: the robot "
                            "may go on outside the box (filters.crop_box_min / crop_box_max; below the base plane, "
                            "filters.clamp_radius lets the automatic box reach there)")
        why = "" if reach is None or short < 0 else reach.why_unseen(list(camera_names), seen_end, expected_length,
                                                                     continued=True)
        if why and hidden_across:
            warning = (f"the tube seen ends {short * 1e3:.1f} mm short of the robot's length "
                       f"({expected_length * 1e3:.1f} mm at this bend); {why}: that hides the rest, and the tip is "
                       "carried on there, bending as the notches seen did, to the robot's length: uncertain by about "
                       f"{tip_uncertainty * 1e3:.2f} mm "
                       f"along the tube and {tip_across * 1e3:.2f} mm across it, the centreline with it by "
                       f"{stated_centreline * 1e3:.2f} mm (RMS over the robot's length)")
        elif why:
            warning += f"; {why}: that may hide the rest"
        if left_short:
            warning += (f"; left at the end seen, the tip may lie up to {abs(short) * 1e3:.1f} mm off, along the tube "
                        "or across it, and its uncertainty is stated so")
        warnings.append(finding("TIP_CARRIED" if why and hidden_across else "TUBE_ENDS_SHORT", warning,
                                short_of_length_mm=short * 1e3, at_crop_box=at_crop_box,
                                crop_box_face=crop_box_face, crop_box_face_mm=crop_box_face_mm,
                                **({} if reach is None or short < 0 else
                                   _unseen_figures(reach, list(camera_names), seen_end, expected_length))))
    # such a tip states so in its figures too, up to the shortfall along the tube or across it (a robot controller
    # reads those, not the warning)
    if left_short:
        tip_uncertainty, tip_across = max(tip_uncertainty, abs(short)), max(tip_across, abs(short))
    side_off = math.degrees(math.remainder(notch_side - configured_side, 2 * math.pi))
    if side_unsettled is not None:
        first, then = (math.degrees(angle) for angle in side_unsettled)
        warnings.append(finding("NOTCH_SIDE_UNSETTLED",
                                f"the notches' side measured {first:+.0f} deg from the configured robot.notch_side, "
                                f"then {then:+.0f} deg more in the frame turned to it: no consistent measurement, the "
                                "configured side is kept (check the robot's roll in its clamp)",
                                side_off_deg=[first, then]))
    if abs(side_off) > SIDE_OFF_DEG:
        known = "" if side_uncertainty is None else f" (known to +-{math.degrees(side_uncertainty):.0f} deg)"
        rolled = ("is rolled in its clamp" if side_uncertainty is None or abs(side_off) > math.degrees(side_uncertainty)
                  else "may be rolled in its clamp: the offset is within what the side is known to")
        warnings.append(finding("ROBOT_ROLLED",
                                f"the notches open {side_off:+.0f} deg from the configured robot.notch_side{known}: "
                                f"the robot {rolled} (measured side used)", side_off_deg=side_off,
                                side_uncertainty_deg=None if side_uncertainty is None
                                else math.degrees(side_uncertainty)))
    if footprint > FOOTPRINT_RADIUS_FRACTION * r_o:
        warnings.append(finding("PIXEL_FOOTPRINT_COARSE",
                                f"a depth pixel covers {footprint * 1e3:.2f} mm, the tube is only "
                                f"{diameter / footprint:.0f} px across: expect errors above 0.1 mm (a higher depth "
                                "resolution, or cameras closer, down to the D405's minimum depth of about 70 mm)",
                                pixel_footprint_mm=footprint * 1e3))
    warnings += [finding("DEPTH_QUANTISED", w, camera=name, depth_step_mm=step * 1e3)
                 for name, step in depth_steps.items() if (w := depth_quantisation_warning(name, step, geometry))]
    if uncertainty is not None and uncertainty > CENTERLINE_FLOOR:
        message = (f"the centreline is uncertain by about {uncertainty * 1e3:.2f} mm: stereo matching beside the "
                   f"notches moves the wall it sees (the cameras place the axis {(cross_view_spread or 0.0) * 1e3:.2f} "
                   "mm apart across their views, and the wall between the notches reads "
                   f"{(notched_thinning or 0.0) * 1e3:+.2f} mm deeper than the plain tube); "
                   f"{abs(bias_notch_side) * 1e3:.2f} mm of lean towards the notch side was removed")
        if alignment_scatter:
            message += (f", a correction that varies along the tube by {alignment_scatter * 1e3:.2f} mm (RMS), which "
                        "the wall facing the cameras cannot tell from a wall stereo moved alike in every view")
        if resting_on_level:
            message += (f"; over the distal {sum(one_sided.values()) * 1e3:.0f} mm seen by one camera alone, the "
                        f"wall's level ({wall_level * 1e3:+.2f} mm, the flattening of the views) places the axis along "
                        "that camera's view, and no second view checked it")
        if astray is not None:
            message += (f"; the axis lies {astray * 1e3:.2f} mm (RMS) from the middle of the tube's outline in the "
                        f"cameras' views, {astray / footprint:.1f} px where a sound one lies within "
                        f"{OUTLINE_TOLERANCE_PX:g}: the fit and the alignment followed a wall stereo moved that far")
        warnings.append(finding("CENTERLINE_UNCERTAIN", message, uncertainty_mm=uncertainty * 1e3,
                                outline_offset_mm=None if astray is None else astray * 1e3,
                                cross_view_mm=(cross_view_spread or 0.0) * 1e3,
                                notched_thinning_mm=(notched_thinning or 0.0) * 1e3,
                                alignment_scatter_mm=(alignment_scatter or 0.0) * 1e3,
                                one_camera_wall_level_mm=wall_level * 1e3 if resting_on_level else None))
    if outline_unchecked:
        # the check ran (points carry their camera) and no window's outline spanned the tube's diameter: the
        # matcher spoiled the silhouettes (a wide window over a near backdrop); in the sweeps only such scenes,
        # 10 of 26 on the second renderer over the centreline's floor, 2 of them beyond what the spread stated
        warnings.append(finding("OUTLINE_UNCHECKED",
                                "no camera's view showed the tube's outline whole (across each view its wall points "
                                "spanned no diameter: the matcher spoiled the silhouettes' pixels): the centreline "
                                "was not checked against the middle of the outline, and across the views it, and the "
                                "tip at its free end, may lie further off than the cameras' spread says: they are "
                                f"stated as uncertain as a pixel footprint at least ({footprint * 1e3:.2f} mm), what "
                                "that check resolves", pixel_footprint_mm=footprint * 1e3))
    if across_from_fit is not None:
        aligned, fit = across_from_fit
        warnings.append(finding("ALIGNMENT_ASTRAY",
                                f"the alignment moved the axis {aligned * 1e3:.2f} mm (RMS) from the middle of the "
                                f"tube's outline in the cameras' views ({aligned / footprint:.1f} px, where a sound "
                                f"axis lies within {OUTLINE_TOLERANCE_PX:g}): it followed a wall stereo moved across "
                                f"the views, and across them the axis is the fit's, which lies {fit / footprint:.1f} "
                                "px from that middle",
                                aligned_offset_mm=aligned * 1e3, fit_offset_mm=fit * 1e3))
    unsupported_to_tip = bool(unsupported) and unsupported[-1][1] >= tip_s - geometry.notch_pitch
    if unsupported:
        listed = ", ".join(f"{start * 1e3:.0f}-{end * 1e3:.0f}" for start, end in unsupported)
        to_tip = " (and the tip with it)" if unsupported_to_tip else ""
        warnings.append(finding("CENTERLINE_UNSUPPORTED",
                                f"over s = {listed} mm no camera saw the tube's wall facing it on the tube's radius: "
                                f"the centreline there{to_tip} follows points off the wall (pixels a matcher mixed "
                                "with the background, a wall seen edge-on), and how far off it is was not measured",
                                stretches_mm=[[a * 1e3, b * 1e3] for a, b in unsupported], to_tip=unsupported_to_tip))
    # a distal stretch every camera sees nearly end-on: no camera's view of its wall faces it, and nothing placed
    # the axis there across the tube as well as elsewhere (in the sweeps, most such tips missed their floor); said
    # unless an unsupported stretch reaching the tip says as much already
    if end_on_warned and not unsupported_to_tip:
        angles = " and ".join(f"{math.degrees(angle):.0f} deg of {name}'s" for name, angle in end_on_angles.items())
        warnings.append(finding("DISTAL_END_ON",
                                f"the distal {end_on * 1e3:.0f} mm points within {angles} line of sight: every camera "
                                "sees its wall nearly edge-on there, and the centreline there and the tip with it "
                                "rest on that wall: how far off across the tube they are was not measured",
                                length_mm=end_on * 1e3,
                                angles_deg={name: math.degrees(angle) for name, angle in end_on_angles.items()}))
    if lean > BIAS_WARN_FOOTPRINTS * footprint:
        names = " and ".join(looking_into_slots)
        consequence = (f"a camera facing the backbone placed the axis along its line of sight instead, by its level on "
                       f"the plain tube ({backbone_shift * 1e3:.2f} mm moved)" if levelled else
                       f"the centreline there may lean up to {lean * 1e3:.2f} mm away from {names}")
        warnings.append(finding("SLOTS_LEAN", f"{names} looks into the notches' slots, and the wall between them reads "
                                f"{notched_thinning * 1e3:.2f} mm deeper than the plain tube (its matcher averages the "
                                f"spines with the slot floors): {consequence}",
                                cameras=list(looking_into_slots), lean_mm=lean * 1e3,
                                notched_thinning_mm=notched_thinning * 1e3, levelled=levelled))
    quality = {
        "notches_found": len(found), "notches_expected": geometry.notch_count, "notches_missing": missing,
        "notches_missing_beyond_end": beyond, "notches_missing_unseen_by": unseen,
        "notches_missing_unmarked": unmarked,
        "notches_by_signal": by_signal,
        "notch_signal": {str(n.index): n.signal for n in sorted(notches, key=lambda n: n.index)},
        "length_seen_share": share, "distal_one_camera_mm": {k: v * 1e3 for k, v in alone.items()},
        "fit_residual_mm": wall_residual * 1e3,
        "wall_level_mm": None if wall_level is None else wall_level * 1e3,
        "notch_side_deg": math.degrees(notch_side), "notch_side_configured_deg": math.degrees(configured_side),
        "notch_side_unsettled_deg": None if side_unsettled is None else [math.degrees(a) for a in side_unsettled],
        "centerline_bias_mm": {"notch_side": bias_notch_side * 1e3, "binormal": bias_binormal * 1e3},
        "tip_s_mm": tip_s * 1e3, "tip_seen_s_mm": seen_end * 1e3, "expected_length_mm": expected_length * 1e3,
        "tip_length_weighed": bool(tip_along is not None and tip_along.length_weighed),
        "tip_uncertainty_mm": tip_uncertainty * 1e3,
        "tip_across_uncertainty_mm": None if centreline_known is None and not held and not hidden_across
        and not left_short else tip_across * 1e3,
        "tip_held_shift_mm": held * 1e3, "tip_held_over_mm": max(tip_s - held_from, 0.0) * 1e3,
        "tip_carried_mm": carried * 1e3,
        # relocated by ICP: how far it moved its reference off the centreline's pose (RMS) and the tip with it
        "relocation_reference_move_mm": None if reference_moved is None else {
            "rms": reference_moved.rms * 1e3, "tip_along": icp_along * 1e3, "tip_across": icp_across * 1e3},
        # how far past the end seen the tip was carried, where every camera was kept from the rest (0: it was not)
        "tip_hidden_mm": (tip_s - seen_end) * 1e3 if hidden_across else 0.0,
        "notch_width_vs_bend_mm": {str(i): d * 1e3 for i, d in sorted(off_model.items())},
        "notches_unchecked": unchecked,
        "pixel_footprint_mm": footprint * 1e3,
        "depth_step_mm": {k: v * 1e3 for k, v in depth_steps.items()},
        "notched_thinning_mm": None if notched_thinning is None else notched_thinning * 1e3,
        "cameras_looking_into_slots": list(looking_into_slots),
        "centerline_cross_view_mm": None if cross_view_spread is None else cross_view_spread * 1e3,
        "centerline_cross_view_at_tip_mm": None if distal_cross_view is None else distal_cross_view * 1e3,
        "centerline_alignment_scatter_mm": None if alignment_scatter is None else alignment_scatter * 1e3,
        "centerline_outline_offset_mm": None if outline_offset is None else outline_offset * 1e3,
        # the aligned axis's offset, when it went astray and the fit placed the axis across the views instead
        "centerline_aligned_outline_offset_mm": None if across_from_fit is None else across_from_fit[0] * 1e3,
        "centerline_uncertainty_mm": None if stated_centreline is None else stated_centreline * 1e3,
        "centerline_unsupported_mm": [[start * 1e3, end * 1e3] for start, end in unsupported],
        "distal_end_on_mm": end_on * 1e3,
        # per camera the nearest depth it returned, and the tube seen's nearest to it (its surface, optical axis)
        "camera_nearest_depth_mm": {} if reach is None else {k: v * 1e3 for k, v in reach.nearest_returned.items()},
        "tube_nearest_depth_mm": {} if reach is None else {
            k: float(v[reach.s <= seen_end].min()) * 1e3 for k, v in reach.depth.items()},
    }
    # each width's 90 % bound, from how the widths read (those still the rims') disagree with their bends'
    width_known = notch_width_uncertainties({i: d for i, d in off_model.items() if i not in misread_widths}, found,
                                            MISREAD_WIDTH_FRACTION * geometry.notch_width)
    quality["notch_width_uncertainty_mm"] = {str(i): width_known[i] * 1e3 for i in found}
    quality["uncertainty_mm"] = uncertainty_mm(quality, quality["notch_width_uncertainty_mm"].values())
    return quality, warnings


def carried_to_tip(fitted_end: float | None, tip_s: float, notch_centres: np.ndarray | None, geometry,
                   centerline_off: float) -> tuple[float, float]:
    """How far past the fitted curve's end the tip lies (m), and how far across the tube that leaves it uncertain
    (m): there the centreline was carried on at the steady bend (centerline.continued_bend), each notch it bent over
    known as well as the centreline's turn over a pitch (centerline_off / pitch), alike, its lever the rest of the
    way to the tip. (0, 0) where the fit reached the tip, or its end or the comb is not known."""
    if fitted_end is None or notch_centres is None or tip_s <= fitted_end:
        return 0.0, 0.0
    centres = np.asarray(notch_centres, float)
    share = np.clip((centres + geometry.notch_width / 2 - fitted_end) / geometry.notch_width, 0.0, 1.0)
    lever = float(np.sum(share * np.clip(tip_s - centres, 0.0, None)))
    return tip_s - fitted_end, centerline_off / geometry.notch_pitch * lever


def centerline_uncertainty(cross_view_spread: float | None, notched_thinning: float | None,
                           looking_into_slots: tuple[str, ...] = (), levelled: bool = False,
                           one_sided: tuple[float, float] | None = None, astray: float | None = None,
                           varying_lean: float | None = None) -> float | None:
    """How far the centreline may be off (m), from what the data show of stereo's bias beside the notches;
    None when neither could be measured.

    Across a camera's line of sight each camera places the axis by itself: their spread about the fused axis
    (alignment.cross_view_spread) is how well the fused one is known that way. Along the lines of sight the
    cameras' levels decide, and a matcher whose window averages the spines with the slots reads the wall between
    the notches deeper than the plain tube (notched_thinning), a deficit no fit can place: a lean of about as
    much, twice it when a camera looks into the slots (carried by that camera alone, it reads half pooled) unless
    a camera facing the backbone placed the axis along the views (levelled). one_sided: (the share of the length
    seen by one camera alone, the outer wall's level about the r_o circle, m): there the axis along that camera's
    view rests on the level the fit gives its one side, which no second view checks and which stereo's
    flattening changes with distance and view angle by up to the level itself: that much again over that share.
    varying_lean: how much the alignment's shift of the fit varies along the tube (alignment.shift_scatter): the
    cameras' spread misses a facing wall stereo moved alike in every view, and that shows there.
    The four are orthogonal: added in quadrature (the share as weight, as the RMS over the length). astray:
    how far the axis lies from the middle of the tube's outline where that shows it went astray (m): the wall
    the four are measured on moved with it, and the axis is known no better than that.
    """
    if cross_view_spread is None and notched_thinning is None:
        return astray
    along_views = (2.0 if looking_into_slots and not levelled else 1.0) * (notched_thinning or 0.0)
    share, level = one_sided if one_sided is not None else (0.0, 0.0)
    return max(float(np.sqrt((cross_view_spread or 0.0) ** 2 + along_views ** 2 + share * level ** 2
                             + (varying_lean or 0.0) ** 2)), astray or 0.0)


def _nearest_box_face(point: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> tuple[int, float, float]:
    """The axis and coordinate of the box face nearest a point inside it, and the point's distance to it."""
    low, high = (np.asarray(corner, float) for corner in box)
    below, above = point - low, high - point
    axis = int(np.argmin(np.minimum(below, above)))
    if below[axis] <= above[axis]:
        return axis, float(low[axis]), float(below[axis])
    return axis, float(high[axis]), float(above[axis])


def depth_quantisation_warning(camera: str, step: float, geometry) -> str | None:
    """The warning for a camera whose depth steps (m) are too coarse for the tube's roundness, else None."""
    if step <= QUANTISATION_RADIUS_FRACTION * geometry.outer_radius:
        return None
    return (f"depth of {camera} is quantised in {step * 1e3:.2g} mm steps: a {geometry.outer_diameter * 1e3:.1f} mm "
            "tube loses most of its depth profile (realsense-ros records 1 mm units; use 0.1 mm)")


def depth_step(depth: np.ndarray, unit: float, samples: int = 4096) -> float:
    """The smallest depth step (m) in a depth image: its quantisation, seen in the data."""
    values = np.asarray(depth).ravel()
    values = values[values > 0]
    if values.size < 2:
        return 0.0
    if values.size > samples:
        values = values[:: values.size // samples]
    distinct = np.unique(values)
    if distinct.size < 2:
        return 0.0
    return float(np.min(np.diff(distinct.astype(np.float64)))) * unit
