"""Alignment: the reference tube moved onto the wall points that stereo depth measures without bias.

The centreline fit uses every wall point, and some of them are biased in a way that does not cancel
around the tube. A stereo matcher gives each pixel the mean depth of its window over the surface it lies on:
within half a window of the tube's silhouette the window is cut by the edge and the pixel is pulled towards
the nearer rows (the silhouette bulges outward), and beside a notch the rows the cut leaves open are missing
from the window while the backbone's rows are not (the face is flattened unevenly); pixels next to an edge
with a valid background behind are mixed with it and filtered away, those whose background the matcher's
left-right check invalidates keep their bulge. None of that is symmetric about the view once a notch is near,
so the fitted axis drifts towards the notches: 0.07-0.2 mm, more with a larger pixel footprint.

Trusted are the wall points within the gate given (the pipeline's: the outer wall's band measured on the spines, so
that pixels a matcher mixed with the background behind stay out) that face their camera, `silhouette_margin_px`
pixel footprints or more inside the tube's silhouette in its image (a view angle a with r (1 - sin a) above the
margin, never beyond `max_view_angle`), clear of the cuts (the expected notches grown by `cut_margin_px`, over the
angles where they open the wall: the backbone opposite a cut is whole wall; comb.clear_of_cuts), on that backbone
`slot_margin_px` or more beyond the slot's edge across the camera's view (clear_of_slots_in_view: nearer it the
matcher's window reaches into the slot and reads the wall deep, on one side of the view only) and as far from the
base and the tube's end (depth edges too). The criterion is in pixels, so it follows the footprint: on a rig twice
as far the facing zone narrows to what the matcher leaves unbiased. Along the robot, in
windows of a notch pitch, the shift of the reference tube (of the known radius, at the wall's level per window) that
best fits those points is solved by least squares (offset = c_x cos(phi) + c_y sin(phi) + level, the level scaled
per point by its camera's squared distance from the robot's base: cameras at different distances see the wall
flattened differently), all windows jointly with a penalty on the difference of consecutive shifts (a window's few
facing points place it to a tenth of a millimetre only); the shifts, interpolated along s and held beyond the last
window (the free end follows its data as the rest of the fit does, and leans as the wall before it measured), move
the centreline. The pipeline runs it a few times, each selecting the facing points about the axis the last one
moved. The fit's lean towards the notch side (minus the mean shift) is reported as its bias.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.robust import median
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates, unit_direction
from ntcr_recon.core.robot.comb import clear_of_cuts, near_cuts
from ntcr_recon.core.robot.geometry import TubeGeometry

# Mean resultant length of a window's point directions about the axis above which it is seen from one side.
MAX_ONE_SIDEDNESS = 0.6

# Trusted points lie at least this many pixels inside the tube's silhouette in their camera's image: a stereo
# matcher's window (7-11 px on a D405) reaches half its width across a depth edge, and every pixel within that
# reach of the silhouette - or of the rows a notch leaves open beside it - has its depth pulled towards the
# nearer rows of its window (the silhouette bulges outward, the rows next to a notch fall inward), a bias that
# is not symmetric about the view once a notch is near.
SILHOUETTE_MARGIN_PX = 4.0

# Beside a cut the alignment trusts the wall this many pixel footprints or more beyond the slot's edge across its
# camera's view: a matcher's window from the wall nearer that edge reaches furthest into the slot and reads it
# deepest (about the true axis, deeper than the spines by 35-95 um 0-2 px beyond the edge and under 25 um further
# in the simulator; by 110-130, 70-80 and 20 um 1-2, 2-3 and 3-4 px beyond it in the second renderer). The
# silhouette's margin of 4 px left a camera that sees the backbone side-on too few points beside the
# cuts on far rigs, whose distal windows then followed the wall before them (tips 0.03-0.07 mm further off at
# 93-102 mm), so the margin is half it.
SLOT_MARGIN_PX = 2.0

# Weight of the difference of two consecutive windows' shifts, in a window's typical information.
SHIFT_SMOOTHING = 0.3


def facing_cosine(outer_radius: float, footprint: float, margin_px: float, max_view_angle: float) -> float:
    """The least cosine of the view angle (between a wall point's outward direction and the direction to its
    camera) of a point lying `margin_px` pixel footprints or more inside the tube's silhouette, never above
    `max_view_angle`: a point at view angle a lies r (1 - sin a) inside the silhouette, across the view."""
    sine = min(max(1.0 - margin_px * footprint / outer_radius, 0.0), np.sin(max_view_angle))
    return float(np.sqrt(1.0 - sine * sine))


@dataclass(frozen=True)
class WallTrust:
    """Which wall points the alignment and the checks over it trust (see the module docstring), and up to where:
    the robot, the wall's gate, the pixel footprint and the tube's end seen (m), the view angle (rad) and the
    margins in pixel footprints."""

    geometry: TubeGeometry
    gate: float
    footprint: float
    end_s: float
    max_view_angle: float = np.radians(45.0)
    cut_margin_px: float = 1.0
    silhouette_margin_px: float = SILHOUETTE_MARGIN_PX
    slot_margin_px: float = SLOT_MARGIN_PX

    @property
    def cut_margin(self) -> float:
        return self.cut_margin_px * self.footprint

    @property
    def silhouette_margin(self) -> float:
        """The margin trusted points keep from the base and the end (depth edges too, as the silhouette)."""
        return self.silhouette_margin_px * self.footprint

    @property
    def least_cosine(self) -> float:
        """The least cosine of a trusted point's view angle."""
        return facing_cosine(self.geometry.outer_radius, self.footprint, self.silhouette_margin_px,
                             self.max_view_angle)


@dataclass(frozen=True)
class Alignment:
    centerline: Centerline
    bias_notch_side: float   # m, the fit's lean towards the notch side (+): minus the mean shift applied
    bias_binormal: float     # m, the same across the bending plane (along normal x tangent)
    trusted: int             # points the alignment rests on
    arc_lengths: np.ndarray | None = None  # the points' s on the curve the last pass started from (passes > 1)
    # beyond the last window whose shift was solved (at s = held_from, m) no trusted wall measured the fit's
    # lean: the shift there is held to the tube's end, and end_shift (m) is how far it moved the end
    held_from: float | None = None
    end_shift: float = 0.0
    end_move: np.ndarray | None = None  # (3,) m: the end's move itself (end_shift its length)

    def moved_to(self, centerline: Centerline, fit: Centerline) -> Alignment:
        """This alignment with its axis replaced by `centerline` (outline.across_views_from): the lean removed and
        the end's move as that axis has them against the fit (the lean: the mean shift over its samples)."""
        shift, across = shift_from_fit(fit, centerline, centerline.length)
        lean = across.mean(axis=0)
        return dataclasses.replace(self, centerline=centerline, bias_notch_side=-float(lean[0]),
                                   bias_binormal=-float(lean[1]), end_shift=float(np.linalg.norm(shift[-1])),
                                   end_move=shift[-1])


def shift_from_fit(fit: Centerline, aligned: Centerline, end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The aligned curve's samples up to end_s moved off the fit at the same s: (N, 3) and, on the fit's normal
    (towards the notch side) and binormal there, (N, 2) (m)."""
    seen = aligned.s <= end_s
    position, _, normal, binormal = fit.frames_at(aligned.s[seen])
    shift = aligned.points[seen] - position
    return shift, np.stack([np.einsum("ij,ij->i", shift, normal), np.einsum("ij,ij->i", shift, binormal)], axis=1)


@jit
def _trusted_window_sums(s, x, y, position, normal, binormal, viewpoints, camera, cameras, base, outer_radius, gate,
                         start_s, end_s, least_cosine, away_from_cuts, window, windows):
    """The trusted wall points and, per window of s, the normal equations of their offset model.

    Trusted: within `gate` of the wall, start_s < s < end_s, away from the cuts, and facing their camera (the
    cosine between the point's outward direction about the axis and the direction to its viewpoint above
    `least_cosine`). Returns per window the 3x3 matrix and right-hand side of offset = cx cos + cy sin +
    level d^2 summed over them (d: the distance of the point's camera from the robot's base), their count, the
    sum of their s and that of their unit directions (cos, sin) about the axis; the mean d^2 of the trusted
    points; and per window and camera (camera: each point's index, below `cameras`) the count and the sums of
    sin(a), sin(a)^2, offset, sin(a) offset, cos(a), cos(a)^2 and cos(a) offset over its trusted points, a the
    view angle about the tangent (see cross_view_spread, level_by_backbone).

    The level per camera scales with d^2: a stereo matcher gives a pixel the mean depth of its window, a fixed
    number of pixels, and on a convex wall of radius R the mean over a patch of width a lies about a^2 / (24 R)
    behind the wall, a growing with the pixel footprint, i.e. with the camera's distance. Two cameras at
    different distances see the wall at different levels; one level common to both would be read as a shift of
    the axis towards the nearer one. The distance is the rig's (camera to base), not each point's: where the
    robot's pose alone brings it nearer one camera, other biases than the flattening (a notch side facing that
    camera) dominate the level, and scaling them with the pose's distances moved the axis (a tube pointing at a
    camera, test_synthetic_oblique). On a rig whose cameras stand as far from the base: one level.
    """
    count = s.shape[0]
    matrix, rhs, counts = np.zeros((windows, 3, 3)), np.zeros((windows, 3)), np.zeros(windows, np.intp)
    s_sum, direction_sum = np.zeros(windows), np.zeros((windows, 2))
    cross_view = np.zeros((windows, cameras, 8))
    kept = 0
    distance2_sum = 0.0
    for i in range(count):
        radius = np.sqrt(x[i] * x[i] + y[i] * y[i])
        offset = radius - outer_radius
        if not (abs(offset) < gate and start_s < s[i] < end_s and away_from_cuts[i]):
            continue
        v0 = viewpoints[i, 0] - position[i, 0]
        v1 = viewpoints[i, 1] - position[i, 1]
        v2 = viewpoints[i, 2] - position[i, 2]
        vx = v0 * normal[i, 0] + v1 * normal[i, 1] + v2 * normal[i, 2]
        vy = v0 * binormal[i, 0] + v1 * binormal[i, 1] + v2 * binormal[i, 2]
        view = max(radius * np.sqrt(vx * vx + vy * vy), 1e-15)
        cosine = (x[i] * vx + y[i] * vy) / view  # of the view angle
        if not cosine > least_cosine:
            continue
        k = min(int(s[i] / window), windows - 1)
        cos_angle, sin_angle = unit_direction(x[i], y[i])
        sine = (x[i] * vy - y[i] * vx) / view  # of the view angle, about the tangent
        c = camera[i]
        cross_view[k, c, 0] += 1.0
        cross_view[k, c, 1] += sine
        cross_view[k, c, 2] += sine * sine
        cross_view[k, c, 3] += offset
        cross_view[k, c, 4] += sine * offset
        cross_view[k, c, 5] += cosine
        cross_view[k, c, 6] += cosine * cosine
        cross_view[k, c, 7] += cosine * offset
        b0, b1, b2 = viewpoints[i, 0] - base[0], viewpoints[i, 1] - base[1], viewpoints[i, 2] - base[2]
        distance2 = b0 * b0 + b1 * b1 + b2 * b2
        terms = (cos_angle, sin_angle, distance2)
        for row in range(3):
            rhs[k, row] += terms[row] * offset
            for column in range(3):
                matrix[k, row, column] += terms[row] * terms[column]
        counts[k] += 1
        s_sum[k] += s[i]
        direction_sum[k, 0] += cos_angle
        direction_sum[k, 1] += sin_angle
        distance2_sum += distance2
        kept += 1
    return matrix, rhs, counts, s_sum, direction_sum, distance2_sum / max(kept, 1), cross_view


def normalise_level(matrix: np.ndarray, rhs: np.ndarray, distance2_mean: float) -> None:
    """Rescale the normal equations of offset = cx cos + cy sin + level d^2 (d: the distance of the point's
    camera from the robot's base) in place to level (d^2 / distance2_mean), a regressor about 1: the same
    solution for the shifts, a level in metres and a system conditioned as the one-level model's."""
    if distance2_mean > 0:
        matrix[:, 2, :2] /= distance2_mean
        matrix[:, :2, 2] /= distance2_mean
        matrix[:, 2, 2] /= distance2_mean * distance2_mean
        rhs[:, 2] /= distance2_mean


@jit
def _smoothed_shifts_bands(matrix, weight):
    """smoothed_shifts' system in LAPACK's upper band storage (4, 3W): bands[3 - offset, column] =
    system[column - offset, column] (a window's 3x3 block, and its shifts tied to the next window's)."""
    count = matrix.shape[0]
    bands = np.zeros((4, 3 * count))
    for k in range(count):
        for row in range(3):
            for column in range(row, 3):
                bands[3 - (column - row), 3 * k + column] = matrix[k, row, column]
        bands[3, 3 * k + 2] += 1e-12 * (matrix[k, 0, 0] + matrix[k, 1, 1] + matrix[k, 2, 2])
    for k in range(count - 1):  # first differences of consecutive windows' shifts (cx, cy), per axis
        for axis in range(2):
            bands[3, 3 * k + axis] += weight
            bands[3, 3 * (k + 1) + axis] += weight
            bands[0, 3 * (k + 1) + axis] -= weight
    return bands


def smoothed_shifts(matrix: np.ndarray, rhs: np.ndarray, smoothing: float) -> np.ndarray:
    """The windows' shifts (W, 2) solved jointly: each window's normal equations of offset = cx cos + cy sin +
    level (matrix (W, 3, 3), rhs (W, 3), the level free per window) plus smoothing x (typical information of a
    window's shift) x the squared difference of consecutive windows' shifts. A window's few facing points
    place its shift only to a tenth of a millimetre; the robot's axis does not jump from one notch to the
    next, so its neighbours share the estimate (smoothing 0: each window alone)."""
    if not len(matrix):
        return np.zeros((0, 2))
    typical = float(median(matrix[:, 0, 0] + matrix[:, 1, 1])) / 2
    bands = _smoothed_shifts_bands(np.ascontiguousarray(matrix, dtype=float), smoothing * typical)
    solution = scipy.linalg.solveh_banded(bands, np.ascontiguousarray(rhs, dtype=float).reshape(-1))
    return solution.reshape(-1, 3)[:, :2]


def align_to_trusted_wall(centerline: Centerline, coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray,
                          trust: WallTrust, smoothing: float = SHIFT_SMOOTHING, minimum_points: int = 30,
                          xyz: np.ndarray | None = None, passes: int = 1) -> Alignment:
    """Shift the centreline onto the trusted wall points (see the module docstring), up to the tube's end
    trust.end_s.

    passes > 1 (with the points' base-frame positions xyz): which points face their camera depends on where
    the axis is, so each further pass projects the points onto the moved centreline, lays its comb of cuts,
    and selects and solves again; bias and shifts add up over the passes.
    """
    viewpoints = np.ascontiguousarray(viewpoints, dtype=float)
    away_from_cuts = _trusted_wall(coords, frames, viewpoints, centerline, trust)
    bias, end_move = np.zeros(2), np.zeros(3)
    result = Alignment(centerline, 0.0, 0.0, 0)
    for done in range(max(passes, 1)):
        if done:  # the moved axis: its points' coordinates, and its comb (the cuts move with its bends)
            coords, frames = centerline.project_with_frames(xyz, coords.s)
            away_from_cuts = _trusted_wall(coords, frames, viewpoints, centerline, trust)
        result = _align_once(centerline, coords, frames, viewpoints, away_from_cuts, trust, smoothing, minimum_points)
        bias += (result.bias_notch_side, result.bias_binormal)
        if result.centerline is centerline:
            break
        end_move += result.centerline.points[-1] - centerline.points[-1]
        if xyz is None:
            break
        centerline = result.centerline
    return Alignment(result.centerline, float(bias[0]), float(bias[1]), result.trusted, coords.s, result.held_from,
                     float(np.linalg.norm(end_move)), end_move)


def _trusted_wall(coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray, centerline: Centerline,
                  trust: WallTrust) -> np.ndarray:
    """(N,) bool: clear of the cuts and of the slots in view. Beside a cut, the wall a matcher reads into the slot
    from lies on one side of its camera's view: it would shift the axis across that view towards the notch side.
    Along s the cut's margin only: a matcher reaches as far from a spine into the slots, but a spine is all a
    side-on camera sees between the cuts (the slot margin along s too left the matrix 23 rows of 29 meeting their
    floors, against 24; 4 px, 21)."""
    geometry = trust.geometry
    near_cut = near_cuts(coords.s, geometry, centerline, trust.cut_margin)
    return clear_of_cuts(coords, geometry, centerline, trust.cut_margin, near_cut) & clear_of_slots_in_view(
        coords, frames, viewpoints, geometry, near_cut, trust.slot_margin_px * trust.footprint)


def camera_window_sums(centerline: Centerline, coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray,
                       camera: np.ndarray, cameras: int, trust: WallTrust, selected: np.ndarray,
                       window: float) -> np.ndarray:
    """_trusted_window_sums' per window and camera sums (W, C, 8) over the trusted points among `selected`, in
    windows of `window` up to trust.end_s."""
    margin, end_s = trust.silhouette_margin, trust.end_s
    position, _, normal, binormal = frames
    return _trusted_window_sums(coords.s, coords.x, coords.y, position, normal, binormal,
                                np.ascontiguousarray(viewpoints, dtype=float), np.ascontiguousarray(camera, np.intp),
                                cameras, centerline.points[0], trust.geometry.outer_radius, trust.gate, margin,
                                end_s - margin, trust.least_cosine, selected, window,
                                max(int(np.ceil(end_s / window)), 1))[-1]


def _determinants(matrix: np.ndarray) -> np.ndarray:
    """Determinants of (W, 3, 3) matrices by the rule of Sarrus (np.linalg.det's batched LU costs 25 us here)."""
    m = matrix
    return (m[:, 0, 0] * (m[:, 1, 1] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 1])
            - m[:, 0, 1] * (m[:, 1, 0] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 0])
            + m[:, 0, 2] * (m[:, 1, 0] * m[:, 2, 1] - m[:, 1, 1] * m[:, 2, 0]))


def _align_once(centerline: Centerline, coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray,
                away_from_cuts: np.ndarray, trust: WallTrust, smoothing: float, minimum_points: int) -> Alignment:
    """One pass of align_to_trusted_wall: select, solve the windows' shifts, move the centreline."""
    geometry, gate, margin, end_s = trust.geometry, trust.gate, trust.silhouette_margin, trust.end_s
    window = geometry.notch_pitch
    windows = max(int(np.ceil(end_s / window)), 1)
    position, _, normal, binormal = frames
    matrix, rhs, counts, s_sum, direction_sum, distance2_mean, _ = _trusted_window_sums(
        coords.s, coords.x, coords.y, position, normal, binormal, viewpoints, np.zeros(len(coords.s), np.intp), 1,
        centerline.points[0], geometry.outer_radius, gate, margin, end_s - margin, trust.least_cosine, away_from_cuts,
        window, windows)
    normalise_level(matrix, rhs, distance2_mean)
    count = int(counts.sum())
    if count < minimum_points:
        return Alignment(centerline, 0.0, 0.0, count)
    # a window seen from one side only cannot tell a shift towards the camera from the wall's level
    # (the offset model is then degenerate): it needs points spread around the axis
    resultant = np.hypot(direction_sum[:, 0], direction_sum[:, 1]) / np.maximum(counts, 1)
    solvable = (counts >= minimum_points // 3) & (resultant < MAX_ONE_SIDEDNESS)
    solvable &= np.abs(_determinants(matrix)) > 1e-9 * np.maximum(counts, 1) ** 3
    if not np.any(solvable):
        return Alignment(centerline, 0.0, 0.0, count)
    shifts = np.zeros((windows, 2))
    while True:
        shifts[solvable] = smoothed_shifts(matrix[solvable], rhs[solvable], smoothing)
        # a shift beyond the gate of the points that placed it is no stereo bias (those points would lie off the
        # moved wall): the window's few points did not determine it (flying pixels, one side seen); it is left to
        # its neighbours, as an unsolvable one
        wild = solvable & (np.hypot(shifts[:, 0], shifts[:, 1]) > gate)
        if not np.any(wild):
            break
        solvable &= ~wild
        if not np.any(solvable):
            return Alignment(centerline, 0.0, 0.0, count)
    centres = s_sum / np.maximum(counts, 1)  # where each window's trusted points lie on average
    # windows without enough trusted points take their neighbours' shift; the base stays clamped, and beyond the
    # last window its shift holds to the tube's end (the end's wall is fitted as the rest: it leans alike)
    known_s = np.concatenate([[0.0], centres[solvable]])
    node_shift = np.stack([np.interp(centerline.s, known_s, np.concatenate([[0.0], shifts[solvable, k]]))
                           for k in range(2)], axis=1)
    moved = centerline.points + node_shift[:, :1] * centerline.normals + node_shift[:, 1:] * centerline.binormals
    binormal_hint = centerline.binormals[0]
    step = float(centerline.s[1] - centerline.s[0])
    aligned = Centerline.from_points(moved, binormal_hint, step)
    weights = counts[solvable].astype(float)
    bias = weights @ shifts[solvable] / weights.sum()
    return Alignment(aligned, -float(bias[0]), -float(bias[1]), count, held_from=float(known_s[-1]))


def shift_scatter(fit: Centerline, aligned: Centerline, end_s: float) -> float:
    """How much the alignment's shift of the fit varies along the tube (m): the RMS, over the aligned curve's
    samples up to end_s, of its shift from the fit (across the tube, in the fit's frame) about the median shift.

    The shift is the fit's lean the trusted wall measured, which the matcher's bias beside the notches makes nearly
    the same all along a tube seen alike; where it varies window to window, the facing wall it rests on - a few
    pixels across its camera's view - was moved by stereo there too (the tube curling across a camera's baseline,
    its end's depth edge, a thin tube's facing points within a few degrees of the line of sight) as much as the lean
    changed, and nothing tells the two apart: the axis is known no better than that."""
    _, across = shift_from_fit(fit, aligned, end_s)
    if not len(across):
        return 0.0
    deviation = across - np.median(across, axis=0)
    return float(np.sqrt(np.mean(np.einsum("ij,ij->i", deviation, deviation))))


def clear_of_slots_in_view(coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray, geometry: TubeGeometry,
                           near_cut: np.ndarray, across: float) -> np.ndarray:
    """(N,) bool: the point lies outside the cuts grown along s (near_cut: comb.near_cuts of the points), or, in
    its camera's image, `across` (m) or more beyond the edge of the cuts' opening on its camera's side, towards
    the backbone. A matcher's window reaching from the backbone into a slot pulls the wall there deeper too: a
    camera a few tens of degrees past the gap's edge sees that edge a few pixels from the middle of the tube's
    image."""
    position, _, normal, binormal = frames
    return _clear_of_slot_edge(np.ascontiguousarray(near_cut, np.bool_), coords.x, coords.y, position, normal,
                               binormal, np.ascontiguousarray(viewpoints, dtype=float), geometry.outer_radius,
                               geometry.gap_half_angle, across)


@jit
def _clear_of_slot_edge(beside_cut, x, y, position, normal, binormal, viewpoints, outer_radius, gap_half_angle,
                        across):
    """clear_of_slots_in_view per point (compiled: it runs on every alignment pass)."""
    sin_gap, cos_gap = np.sin(gap_half_angle), np.cos(gap_half_angle)
    clear = np.ones(beside_cut.shape[0], np.bool_)
    for i in range(beside_cut.shape[0]):
        if not beside_cut[i]:
            continue
        v0 = viewpoints[i, 0] - position[i, 0]
        v1 = viewpoints[i, 1] - position[i, 1]
        v2 = viewpoints[i, 2] - position[i, 2]
        # the camera's direction round the tube from the notch side (cos, sin), and the point's
        cos_camera, sin_camera = unit_direction(v0 * normal[i, 0] + v1 * normal[i, 1] + v2 * normal[i, 2],
                                                v0 * binormal[i, 0] + v1 * binormal[i, 1] + v2 * binormal[i, 2])
        cos_point, sin_point = unit_direction(x[i], y[i])
        side = 1.0 if sin_camera >= 0.0 else -1.0  # the edge on the camera's side (either, square on)
        # across the camera's view, from the gap's edge on its side to the point (+: towards the backbone):
        # side r (sin(point - camera) - sin(side gap - camera))
        beyond_edge = side * outer_radius * ((sin_point * cos_camera - cos_point * sin_camera)
                                             - (side * sin_gap * cos_camera - cos_gap * sin_camera))
        clear[i] = beyond_edge >= across
    return clear
