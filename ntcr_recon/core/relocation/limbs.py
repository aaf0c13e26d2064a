"""The tube's limbs in each camera's colour image: where the axis lies across the camera's view (issue 61, part 1).

A D405's colour comes from its left imager, pixel-aligned with its depth: the silhouette there is sharp where a
stereo matcher's depth is smeared (fattened silhouettes, a wall read deeper on one side than the other beside the
slots or under a highlight), so the middle of the two limbs places the axis across the view better than any
depth does (along the view, depth stays the only measure).

Per station along the axis the colour profile across the projected tube is sampled; each limb is where the
profile crosses half-way from the background just outside the expected limb to the tube just inside it (in colour:
the background may be darker or brighter than the tube, and differ in hue only). A station counts where both limbs
were found with contrast and lie a tube's width apart (within WIDTH_TOLERANCE_PX): not at a notch cutting a limb,
not at the end cap, not where a prop behind matches the tube. Its offset is the limbs' middle against the
projected axis, in metres at the axis's depth. Shading darkens a tube towards its limbs, so a crossing read
half-way to the tube's mean colour inside lies inward by up to a pixel and a half (a blurred lens, a dark background
more): each limb is read half-way to the tube's colour carried on from inside to the blur's reach
(limb_profile.SHADED_EDGE_PX), and the middle cancels what the two sides still share. The levels are read
about where the axis puts each limb, so an axis a pixel or more off is moved part of the way (about half): the
alignment reads them twice (align_step.LIMB_PASSES), the second time about where the first left the axis. Measured
on both depth sources (accuracy_matrix --matcher both) that took the error across the views from 0.044 to 0.038 mm
(median) and the results saying ok from 18 to 20, at 1.7 ms a frame pair.

    views = {"cam_a": CameraView(color, intrinsics, extrinsic), ...}
    placement = limb_offsets(centerline, s, view, outer_radius)   # per station: offset (m, NaN) along `across`
    moved, figures = placed_by_limbs(centerline, views, outer_radius, window, end_s)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limb_profile import BACKGROUND_PX, SEARCH_PX, limb_crossings
from ntcr_recon.core.relocation.outline import LEAST_CROSSING

# A station counts where its limbs lie within this of the tube's projected width apart (px): a notch cutting a
# limb, the end cap, a neighbour or a prop behind the tube give another width.
WIDTH_TOLERANCE_PX = 1.5

# Stations a window (a notch pitch) needs, per camera, to place the axis there (their median: a few stations at
# a prop's edge do not move it).
MIN_STATIONS = 3

# How far the window a camera's limbs are read in reaches past the robot's pixels (px): a profile reaches
# SEARCH_PX + BACKGROUND_PX[1] (+1 to interpolate) past the expected limb, which lies up to a matcher's eroded
# band (half its window, 3.5 px) past the pixels depth kept.
WINDOW_MARGIN_PX = 16

# Cameras a window's limbs must be measured in to place the axis there: one camera alone is not checked against
# another (a prop behind the tube matching its colour, a highlight on one side).
MIN_CAMERAS = 2

# Windows both cameras must have placed for their offset apart (LimbFigures.rigid) to be measured.
MIN_RIGID_WINDOWS = 4

# Windows placed that the move's interpolation error is measured on (LimbFigures.interpolated): each left out, the
# rest interpolate it; with fewer, one left out leaves too little to interpolate from.
MIN_INTERPOLATED = 4

# The cameras' directions across their views are solved for in least squares whose singular values under this share
# of the largest are cut: two directions count as distinct beyond about 53 deg apart (tan(angle / 2) > 0.5);
# opposed cameras share one, and are averaged along it.
DISTINCT_DIRECTIONS_RCOND = 0.5


@dataclass(frozen=True)
class CameraView:
    """One camera's colour image (H, W, 3 uint8, aligned with its depth), intrinsics and pose (4x4 optical frame
    in the base frame)."""

    color: np.ndarray
    intrinsics: Intrinsics
    extrinsic: np.ndarray

    def __post_init__(self):
        shape = np.shape(self.color)
        if len(shape) != 3 or shape[2] != 3 or shape[:2] != (self.intrinsics.height, self.intrinsics.width):
            raise ValueError(f"a colour image of {self.intrinsics.width}x{self.intrinsics.height} (H, W, 3) was "
                             f"expected, got an array of shape {shape}")

    @classmethod
    def aligned(cls, color: np.ndarray, intrinsics: Intrinsics, extrinsic: np.ndarray) -> CameraView | None:
        """The view of a colour image pixel-aligned with the depth whose intrinsics are given (a D405's: both from
        its left imager); None for one of another size (a colour stream registered to depth only by scaling,
        which places no edge to a pixel)."""
        if np.shape(color)[:2] != (intrinsics.height, intrinsics.width) or np.ndim(color) != 3:
            return None
        return cls(np.asarray(color), intrinsics, extrinsic)

    def around(self, pixels: np.ndarray) -> CameraView | None:
        """The view cut to the robot's pixels (N, 2: u, v; those of its depth points inside the crop box) and
        WINDOW_MARGIN_PX about them, its intrinsics shifted by the cut: what the limbs read (a profile reaches
        past the silhouette by less than the margin, so a larger window reads the same) and what camera_node
        publishes. None without a pixel (the camera does not see the robot)."""
        if len(pixels) == 0:
            return None
        k = self.intrinsics
        low = np.maximum(np.min(pixels, axis=0).astype(int) - WINDOW_MARGIN_PX, 0)
        high = np.minimum(np.max(pixels, axis=0).astype(int) + WINDOW_MARGIN_PX + 1, (k.width, k.height))
        cut = Intrinsics(int(high[0] - low[0]), int(high[1] - low[1]), k.fx, k.fy, k.cx - low[0], k.cy - low[1])
        return CameraView(self.color[low[1]:high[1], low[0]:high[0]], cut, self.extrinsic)


@dataclass(frozen=True)
class LimbPlacement:
    """Per station: the axis's offset across the camera's view (m, + along `across`; NaN where unmeasured)."""

    s: np.ndarray
    offset: np.ndarray
    across: np.ndarray      # (S, 3) unit, base frame: across the view, perpendicular to the tangent


def limb_offsets(centerline: Centerline, s: np.ndarray, view: CameraView, outer_radius: float,
                 end_s: float = np.inf, shaded: bool = True) -> LimbPlacement:
    """How far across the camera's view the middle of the tube's limbs lies from the centreline at stations s;
    none within the end disc's reach of end_s in the image (outer_radius |cos| of the tangent to the line of
    sight: a profile there may cross the end cap's outline instead of the limbs). shaded: as limb_crossings'."""
    edges = limb_edges(centerline, s, view, outer_radius, end_s, shaded)
    offset = np.full(len(s), np.nan)
    usable = edges.usable
    if np.any(usable):
        limbs = edges.limbs[usable]
        middle, width = (limbs[:, 0] + limbs[:, 1]) / 2.0, limbs[:, 1] - limbs[:, 0]
        good = np.abs(width - 2.0 * edges.half_width[usable]) <= WIDTH_TOLERANCE_PX
        offset[np.flatnonzero(usable)[good]] = (middle * edges.metres_per_px[usable])[good]
    return LimbPlacement(np.asarray(s, float), offset, edges.across)


@dataclass(frozen=True)
class LimbEdges:
    """Per station, where the camera sees the tube's two limbs: each (px along the image's sideways direction from
    the projected axis; NaN: not found), where a whole tube's would lie (half_width, px), a pixel's size there (m)
    and the direction across the view in 3-D (the base frame, perpendicular to the line of sight)."""

    limbs: np.ndarray           # (S, 2): the limb at -half_width and the one at +half_width
    half_width: np.ndarray      # (S,)
    metres_per_px: np.ndarray   # (S,)
    across: np.ndarray          # (S, 3), zero where not usable
    usable: np.ndarray          # (S,) bool: in front of the camera, inside its image, crossing its view
    contrast: np.ndarray        # (S, 2, 3): the colour inside each limb less the colour outside it (NaN: unread)

    def inward(self) -> np.ndarray:
        """(S, 2): how far inside a whole tube's outline each limb lies (m; NaN: not found)."""
        return (self.half_width[:, None] + self.limbs * np.array([1.0, -1.0])) * self.metres_per_px[:, None]


@dataclass(frozen=True)
class StationsInView:
    """Stations of a centreline as a camera sees them: whether in front of it (beyond a tube's diameter), their depth
    (1 where not in front), pixel, the axis's direction in the image (px per metre of arc length: the derivative of
    the projection along the tangent), the tube's half width (px), and the unit line of sight and the tangent, both
    in the optical frame."""

    in_front: np.ndarray
    depth: np.ndarray
    pixel: np.ndarray
    image_heading: np.ndarray
    half_width: np.ndarray
    sight: np.ndarray
    heading: np.ndarray


def stations_in_view(centerline: Centerline, s: np.ndarray, view: CameraView, outer_radius: float
                     ) -> StationsInView:
    """The stations s of `centerline` projected into `view` (StationsInView): what the limbs and the end's outline
    (relocation.outline_tip) are read about."""
    position, tangent, _, _ = centerline.frames_at(np.asarray(s, float))
    rotation, origin = view.extrinsic[:3, :3], view.extrinsic[:3, 3]
    optical, heading = (position - origin) @ rotation, tangent @ rotation
    k = view.intrinsics
    in_front = optical[:, 2] > 2.0 * outer_radius
    depth = np.where(in_front, optical[:, 2], 1.0)
    half_width = k.fx * outer_radius / np.sqrt(np.maximum(depth**2 - outer_radius**2, 1e-12))
    pixel = np.stack([k.fx * optical[:, 0] / depth + k.cx, k.fy * optical[:, 1] / depth + k.cy], axis=1)
    image_heading = np.stack([k.fx * (heading[:, 0] - optical[:, 0] * heading[:, 2] / depth),
                              k.fy * (heading[:, 1] - optical[:, 1] * heading[:, 2] / depth)], axis=1) / depth[:, None]
    sight = optical / np.linalg.norm(optical, axis=1)[:, None]
    return StationsInView(in_front, depth, pixel, image_heading, half_width, sight, heading)


def limb_edges(centerline: Centerline, s: np.ndarray, view: CameraView, outer_radius: float,
               end_s: float = np.inf, shaded: bool = False) -> LimbEdges:
    """The limbs the camera sees at stations s (LimbEdges; limb_offsets' end margin; shaded: limb_crossings')."""
    s = np.asarray(s, float)
    seen = stations_in_view(centerline, s, view, outer_radius)
    in_front, pixel, half_width, view_dir, heading = (seen.in_front, seen.pixel, seen.half_width, seen.sight,
                                                      seen.heading)
    k = view.intrinsics
    limbs = np.full((len(s), 2), np.nan)
    across = np.zeros((len(s), 3))
    contrast = np.full((len(s), 2, 3), np.nan)
    edges = LimbEdges(limbs, half_width, seen.depth / k.fx, across, np.zeros(len(s), bool), contrast)
    if not np.any(in_front):
        return edges
    # across the axis's direction in the image
    sideways = np.stack([-seen.image_heading[:, 1], seen.image_heading[:, 0]], axis=1)
    length = np.linalg.norm(sideways, axis=1)
    crossing = np.linalg.norm(np.cross(heading, view_dir), axis=1) > np.cos(LEAST_CROSSING)
    crossing &= s <= end_s - outer_radius * np.abs(np.einsum("ij,ij->i", heading, view_dir))
    reach = half_width + SEARCH_PX + BACKGROUND_PX[1] + 1.0
    inside = ((pixel[:, 0] - reach >= 0) & (pixel[:, 0] + reach <= k.width - 1)
              & (pixel[:, 1] - reach >= 0) & (pixel[:, 1] + reach <= k.height - 1))
    usable = in_front & crossing & inside & (length > 0)
    if not np.any(usable):
        return edges
    sideways = sideways[usable] / length[usable, None]
    limbs[usable], contrast[usable] = limb_crossings(view.color, pixel[usable], sideways, half_width[usable], shaded)
    # across in 3-D: the image's sideways direction in the optical frame, made perpendicular to the line of sight
    direction = np.concatenate([sideways, np.zeros((len(sideways), 1))], axis=1)
    direction -= view_dir[usable] * np.einsum("ij,ij->i", direction, view_dir[usable])[:, None]
    across[usable] = (direction / np.linalg.norm(direction, axis=1)[:, None]) @ view.extrinsic[:3, :3].T
    return dataclasses.replace(edges, usable=usable)


@dataclass(frozen=True)
class LimbFigures:
    """What the limbs said: per camera the windows they placed the axis in, how far they moved it (m, RMS over the
    centreline's samples; 0: not moved), and how well the cameras agreed on where it lies across their views (m,
    RMS over the windows: the least squares' residual, half the difference of two opposed cameras' offsets, about
    how far their mean may be off; None: no window measured by more cameras than it has directions)."""

    windows: dict[str, int]
    moved_rms: float
    disagreement: float | None = None
    reach: float = 0.0                        # m: the end of the last window the limbs placed the axis in (0: none)
    distal_across: np.ndarray | None = None   # (k, 3): the directions across the views they placed it along there
    # two opposed cameras' offsets apart across their views, alike all along the tube (m; a pose in the rig file off
    # the other's: the matcher's noise varies window to window), and its standard error; None: fewer than
    # MIN_RIGID_WINDOWS windows both placed, or not two cameras
    rigid: tuple[float, float] | None = None
    centres: np.ndarray | None = None         # (W,) m of s: the middles of the windows placed
    # how far a window's move lies from the move the windows either side of it give by interpolation (m, RMS, one
    # left out at a time; interpolation_error): how far off the axis may lie in a window the limbs did not place,
    # which takes its move so; None: fewer than MIN_INTERPOLATED windows placed
    interpolated: float | None = None

    def unchecked(self, shift: np.ndarray, reaching: float) -> float:
        """How much of a shift of the axis (3,) the limbs did not measure: its part off the directions across the
        views they placed the axis along in their last window, when that window reaches `reaching` (m of s);
        else all of it (m)."""
        shift = np.asarray(shift, float)
        if self.distal_across is None or self.reach < reaching:
            return float(np.linalg.norm(shift))
        across = np.linalg.pinv(self.distal_across, rcond=DISTINCT_DIRECTIONS_RCOND)  # (3, k)
        return float(np.linalg.norm(shift - across @ (self.distal_across @ shift)))


def placed_by_limbs(centerline: Centerline, views: dict[str, CameraView], outer_radius: float, window: float,
                    end_s: float) -> tuple[Centerline, LimbFigures]:
    """The centreline moved across the cameras' views towards the middle of the tube's limbs in their images (part
    of the way where it was off by a pixel or more: the levels each limb is read between are sampled about where
    the axis puts it, and a shaded rim in one band pulls the crossing back).

    Per window of s (a notch pitch) and camera, the median offset of its stations; per window the least move
    across the tangent that gives every camera placing it its offset (opposed cameras share one direction: the
    move lies along it, depth keeps the axis along the views); between windows interpolated, before the first
    faded in over a window, past the last held to the end. Up to end_s (the end of the wall seen); unchanged where
    no window was placed."""
    move, figures = _limb_move(centerline, views, outer_radius, window, end_s)
    if move is None:
        return centerline, figures
    moved = Centerline.from_points(centerline.points + move, centerline.binormals[0],
                                   float(centerline.s[1] - centerline.s[0]))
    return moved, dataclasses.replace(figures, moved_rms=float(np.sqrt(np.mean(np.sum(move**2, axis=1)))))


def _limb_move(centerline: Centerline, views: dict[str, CameraView], outer_radius: float, window: float,
               end_s: float) -> tuple[np.ndarray | None, LimbFigures]:
    """placed_by_limbs' move at each of the centreline's samples (None: no window placed), and what the limbs
    said (LimbFigures, but for moved_rms)."""
    stations = np.arange(window / 8, max(end_s, window / 8), max(window / 8, 1e-5))
    count = max(int(np.ceil(end_s / window)), 1)
    which = np.minimum((stations / window).astype(int), count - 1)  # each station's window (ascending)
    directions = np.zeros((count, len(views), 3))  # per window and camera: its direction across the view...
    offsets = np.zeros((count, len(views)))         # ...and the median offset of its stations (0, 0: none)
    placed = {}
    for camera, (name, view) in enumerate(views.items()):
        placement = limb_offsets(centerline, stations, view, outer_radius, end_s)
        measured = np.flatnonzero(np.isfinite(placement.offset))  # in s order, so grouped by window
        sizes = np.bincount(which[measured], minlength=count)
        enough = sizes >= MIN_STATIONS
        placed[name] = int(np.count_nonzero(enough))
        if not placed[name]:
            continue
        starts = (np.cumsum(sizes) - sizes)[enough]
        # the median per window: the offsets sorted within each window, its middle one (or two)
        ranked = placement.offset[measured][np.lexsort((placement.offset[measured], which[measured]))]
        offsets[enough, camera] = (ranked[starts + (sizes[enough] - 1) // 2] + ranked[starts + sizes[enough] // 2]) / 2
        # the direction at the window's middle station
        directions[enough, camera] = placement.across[measured[starts + sizes[enough] // 2]]
    solved = np.count_nonzero(np.any(directions != 0.0, axis=2), axis=1) >= min(MIN_CAMERAS, len(views))
    if not np.any(solved):
        return None, LimbFigures(placed, 0.0)
    # per window the least move giving every camera its offset; directions that are not distinct
    # (DISTINCT_DIRECTIONS_RCOND) count as one (else their small difference would carry their offsets'
    # disagreement far along the views); a camera without a row adds none
    moves = np.einsum("wjc,wc->wj", np.linalg.pinv(directions[solved], rcond=DISTINCT_DIRECTIONS_RCOND),
                      offsets[solved])
    rows = np.any(directions[solved] != 0.0, axis=2)  # the cameras that placed each window
    residual = offsets[solved] - np.einsum("wcj,wj->wc", directions[solved], moves)
    disagreement = float(np.sqrt(np.mean(residual[rows] ** 2))) if len(views) >= MIN_CAMERAS else None
    rigid = _rigid_offset(residual, rows)
    last = np.flatnonzero(solved)[-1]
    distal = directions[last][np.any(directions[last] != 0.0, axis=1)]
    centres = (np.flatnonzero(solved) + 0.5) * window
    move = np.stack([np.interp(centerline.s, centres, moves[:, axis]) for axis in range(3)], axis=1)
    # before the first window placed nothing says where the axis lies across the views: the move fades in over a
    # window from the base. Past the last it is held (np.interp's ends) to the free end: there a matcher smears
    # depth most (it fattens the end, and the fit curls with it), and the last window's move is the nearest word
    # on where the end lies (faded out, the tip fell back on depth's curl: 0.29 mm across on the real matcher's
    # bend90, 0.05 held)
    move *= np.clip(1.0 - (centres[0] - centerline.s) / window, 0.0, 1.0)[:, None]
    # across the tangent only: a move along it would stretch the centreline
    return (move - centerline.tangents * np.einsum("ij,ij->i", move, centerline.tangents)[:, None],
            LimbFigures(placed, 0.0, disagreement, float(min((last + 1) * window, end_s)), distal, rigid, centres,
                        interpolation_error(centres, moves)))


def interpolation_error(centres: np.ndarray, moves: np.ndarray) -> float | None:
    """LimbFigures.interpolated: each placed window's move (moves (W, 3) at `centres`, m of s) against the one the
    other windows give it as _limb_move gives a window it did not place (interpolated, held past the ends), RMS."""
    if len(centres) < MIN_INTERPOLATED:
        return None
    # one left out, its neighbours interpolate it (the ends: the next one in, held)
    weight = ((centres[1:-1] - centres[:-2]) / (centres[2:] - centres[:-2]))[:, None]
    predicted = np.concatenate([moves[1:2], (1.0 - weight) * moves[:-2] + weight * moves[2:], moves[-2:-1]])
    return float(np.sqrt(np.mean(np.sum((moves - predicted) ** 2, axis=1))))


def _rigid_offset(residual: np.ndarray, rows: np.ndarray) -> tuple[float, float] | None:
    """LimbFigures.rigid from the least squares' residuals (windows, cameras) where `rows` (both cameras measured).
    Opposed cameras share one direction across their views: each window's residuals are half their offsets'
    sum, alike in both, and that sum is how far one camera places the tube from the other (a shift of one relative
    to the other reads with the same sign in both images)."""
    if residual.shape[1] != 2:
        return None
    both = np.all(rows, axis=1)
    sums = residual[both].sum(axis=1)
    if len(sums) < MIN_RIGID_WINDOWS:
        return None
    return abs(float(np.mean(sums))), float(np.std(sums, ddof=1) / np.sqrt(len(sums)))
