"""What the self-check of a reconstruction measures with (core.quality.checks runs the checks over these).

How much of the tube each camera saw and a distal stretch one camera alone saw (`camera_coverage`), where the comb
puts the missing notches (`where_notches_went_unseen`), how near the tube comes to each camera or how close to its
line of sight it points (`CameraReach`, `camera_reach`), how much deeper the wall reads between the notches than on
the plain tube (`notched_thinning`) and which camera looks into the slots, the stretches no camera measured
(`unmeasured_share`), the centreline's uncertainty (`centerline_uncertainty`) and what carrying it on past the
fitted end leaves of the tip (`carried_to_tip`), the depth step seen in a depth image (`depth_step`) and the
warning for one too coarse for the tube (`depth_quantisation_warning`, which camera_node gives too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from ntcr_recon.core.base.robust import median
from ntcr_recon.core.quality.findings import Z90
from ntcr_recon.core.relocation.bend_plane import BendPlane
from ntcr_recon.core.relocation.centerline import cameras_round_tube
from ntcr_recon.core.relocation.wall import surface_band
from ntcr_recon.core.robot.comb import expected_centres, inside_intervals

# Thresholds, relative to the robot and the camera so that no robot is special (those of the checks: quality.checks).
SEEN_DENSITY_FRACTION = 0.2        # a camera saw a stretch holding this share of its typical wall points there
QUANTISATION_RADIUS_FRACTION = 1 / 8   # depth step above this fraction of r_o: the tube's roundness is lost
# A tube whose axis lies this near a camera's line of sight shows it its wall 60 deg or more from facing it:
# a thin band of pixels, matched poorly (relocation.tip.GRAZING: past 80 deg none) - named as why that camera missed it.
END_ON_DEG = 30.0


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


def unseen_figures(reach, names: list[str], start: float, end: float) -> dict:
    """CameraReach.unseen as a warning's figures: per camera how near the stretch comes (too_near_mm) or how close
    to its line of sight it points (end_on_deg); {} without a reach."""
    if reach is None:
        return {}
    too_near, end_on = reach.unseen(names, start, end)
    return {"too_near_mm": {k: v * 1e3 for k, v in too_near.items()},
            "end_on_deg": {k: math.degrees(v) for k, v in end_on.items()}}


def notches_lie(indices: list[int]) -> str:
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
    `carried`, the centreline up to tip_s carried on past it as the robot bends (bends.continued_bend) to the
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


def carried_to_tip(fitted_end: float | None, tip_s: float, notch_centres: np.ndarray | None, geometry,
                   centerline_off: float) -> tuple[float, float]:
    """How far past the fitted curve's end the tip lies (m), and how far across the tube that leaves it uncertain
    (m): there the centreline was carried on at the steady bend (bends.continued_bend), each notch it bent over
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
                           varying_lean: float | None = None, limbs: tuple[float, float] | None = None,
                           level_scatter: float | None = None,
                           bend_plane: BendPlane | None = None) -> float | None:
    """How far the centreline may be off (m), from what the data show of where each view places it; None when
    nothing could be measured.

    Across a camera's line of sight each camera places the axis by itself: their spread about the fused axis
    (cross_view.cross_view_spread) is how well the fused one is known that way by depth. Where the tube's limbs in
    the colour images placed it (limbs: (their disagreement, the share of the length seen they placed it over, how
    far the move interpolated into a window they did not place misses: LimbFigures.interpolated)), it is known
    across the views as well as the limbs agree: Z90 times their disagreement there (the least squares' residual,
    each window's own error), Z90 times the interpolation's miss over the rest (depth's spread where not measured).
    Along the lines of sight the cameras' levels decide. Each window's axis lies midway between the two walls, off
    by half the difference of their depth biases, which no depth measures; biases that vary independently vary as
    their sum does, which shows in how far apart the walls read (level_scatter, cross_view.CrossView.level_scatter):
    Z90 times that. A matcher whose window averages the spines with the slots reads the wall between the notches
    deeper than the plain tube (notched_thinning): carried by a camera that looks into the slots alone, the axis
    leans away from it by up to twice that (it reads half pooled) unless a camera facing the backbone placed the
    axis along the views (levelled). Without level_scatter (not two cameras), the deficit bounds the lean whoever
    looks into the slots. one_sided: (the share of the length seen by one camera alone, the outer wall's level about
    the r_o circle, m): there the axis along that camera's view rests on the level the fit gives its one side,
    which no second view checks and which stereo's flattening changes with distance and view angle by up to the level
    itself: that much again over that share. varying_lean: how much the alignment's shift of the fit varies along
    the tube (alignment.shift_scatter): the cameras' spread misses a facing wall stereo moved alike in every view,
    and that shows there.
    bend_plane: the axis held to the robot's bend plane (relocation.bend_plane): the terms along the views scaled by
    what that left of them (along_views_kept), how far off the plane may lie added (plane_uncertainty).
    The terms are orthogonal: added in quadrature (the shares as weights, as the RMS over the length). astray:
    how far the axis lies from the middle of the tube's outline where that shows it went astray (m): the wall
    the others are measured on moved with it, and the axis is known no better than that.
    """
    if cross_view_spread is None and notched_thinning is None and limbs is None and level_scatter is None:
        return astray
    across = cross_view_spread or 0.0
    if limbs is not None:
        disagreement, share, interpolated = limbs
        # a window the limbs did not place takes the move its neighbours' give it: off by what that interpolation
        # misses where it can be checked (the placed windows, each left out), not by depth's own spread
        unplaced = across if interpolated is None else Z90 * interpolated
        across = float(np.sqrt(share * (Z90 * disagreement) ** 2 + (1.0 - share) * unplaced**2))
    slot_lean = 2.0 * (notched_thinning or 0.0) if looking_into_slots and not levelled else 0.0
    along_views = (float(np.hypot(Z90 * level_scatter, slot_lean)) if level_scatter is not None
                   else slot_lean or (notched_thinning or 0.0))
    share, level = one_sided if one_sided is not None else (0.0, 0.0)
    kept, plane = (1.0, 0.0) if bend_plane is None else (bend_plane.along_views_kept, bend_plane.plane_uncertainty)
    along = kept**2 * (along_views**2 + share * level**2) + plane**2
    return max(float(np.sqrt(across**2 + along + (varying_lean or 0.0) ** 2)), astray or 0.0)


def nearest_box_face(point: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> tuple[int, float, float]:
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
