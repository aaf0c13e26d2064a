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
projected axis, in metres at the axis's depth. Shading darkens a tube towards its limbs, so each limb reads
inward by up to a pixel (a blurred lens more); the middle cancels what the two sides share. The levels are read
about where the axis puts each limb, so an axis a pixel or more off is moved part of the way (about half).

    views = {"cam_a": CameraView(color, intrinsics, extrinsic), ...}
    placement = limb_offsets(centerline, s, view, outer_radius)   # per station: offset (m, NaN) along `across`
    moved, figures = placed_by_limbs(centerline, views, outer_radius, window, end_s)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from ntcr_recon.core.cloud.deproject import Intrinsics, crop_window
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.outline import LEAST_CROSSING

# Profile samples per pixel across the tube.
SAMPLES_PER_PX = 4

# A limb is looked for this far either side of where the axis puts it (px): the axis as aligned on depth is off
# by up to a millimetre's fraction (about a pixel at 90 mm), a shaded limb reads up to a pixel inward.
SEARCH_PX = 3.0

# The background is read this far outside the expected limb, the tube this far inside it (px): beyond the blur
# of the lens and the search.
BACKGROUND_PX = (1.5, 4.0)
TUBE_PX = (1.5, 3.0)

# The least colour contrast between tube and background at a limb (8-bit levels, Euclidean in RGB): a few times
# a sensor's noise, so that noise does not place the crossing.
MIN_CONTRAST = 15.0

# A station counts where its limbs lie within this of the tube's projected width apart (px): a notch cutting a
# limb, the end cap, a neighbour or a prop behind the tube give another width.
WIDTH_TOLERANCE_PX = 1.5

# Stations a window (a notch pitch) needs, per camera, to place the axis there (their median: a few stations at
# a prop's edge do not move it).
MIN_STATIONS = 3

# Cameras a window's limbs must be measured in to place the axis there: one camera alone is not checked against
# another (a prop behind the tube matching its colour, a highlight on one side).
MIN_CAMERAS = 2

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

    def within(self, box_min, box_max) -> CameraView:
        """The view cut to the image window through which the camera can see the base-frame box (its intrinsics
        shifted by the window; deproject.crop_window): what the limbs need of it, and what camera_node publishes.
        Itself where the window is the whole image or there is none."""
        k = self.intrinsics
        window = crop_window(k, self.extrinsic, box_min, box_max)
        if window is None or (window.u0, window.v0, window.u1, window.v1) == (0, 0, k.width, k.height):
            return self
        cut = Intrinsics(window.u1 - window.u0, window.v1 - window.v0, k.fx, k.fy, k.cx - window.u0,
                         k.cy - window.v0)
        return CameraView(self.color[window.v0:window.v1, window.u0:window.u1], cut, self.extrinsic)

    @cached_property
    def channels(self) -> tuple[np.ndarray, ...]:
        """The image's three channels as float32 (what the profiles are sampled from), made once."""
        return tuple(np.ascontiguousarray(self.color[:, :, c], dtype=np.float32) for c in range(3))


@dataclass(frozen=True)
class LimbPlacement:
    """Per station: the axis's offset across the camera's view (m, + along `across`; NaN where unmeasured)."""

    s: np.ndarray
    offset: np.ndarray
    across: np.ndarray      # (S, 3) unit, base frame: across the view, perpendicular to the tangent


def limb_offsets(centerline: Centerline, s: np.ndarray, view: CameraView, outer_radius: float) -> LimbPlacement:
    """How far across the camera's view the middle of the tube's limbs lies from the centreline at stations s."""
    position, tangent, _, _ = centerline.frames_at(np.asarray(s, float))
    rotation, origin = view.extrinsic[:3, :3], view.extrinsic[:3, 3]
    optical, heading = (position - origin) @ rotation, tangent @ rotation
    k = view.intrinsics
    depth = optical[:, 2]
    offset = np.full(len(s), np.nan)
    across = np.zeros((len(s), 3))
    in_front = depth > 2.0 * outer_radius
    if not np.any(in_front):
        return LimbPlacement(np.asarray(s, float), offset, across)
    safe = np.where(in_front, depth, 1.0)
    pixel = np.stack([k.fx * optical[:, 0] / safe + k.cx, k.fy * optical[:, 1] / safe + k.cy], axis=1)
    # the axis's direction in the image, and across it (the derivative of the projection along the tangent)
    image_heading = np.stack([k.fx * (heading[:, 0] - optical[:, 0] * heading[:, 2] / safe),
                              k.fy * (heading[:, 1] - optical[:, 1] * heading[:, 2] / safe)], axis=1) / safe[:, None]
    sideways = np.stack([-image_heading[:, 1], image_heading[:, 0]], axis=1)
    length = np.linalg.norm(sideways, axis=1)
    view_dir = optical / np.linalg.norm(optical, axis=1)[:, None]
    crossing = np.linalg.norm(np.cross(heading, view_dir), axis=1) > np.cos(LEAST_CROSSING)
    half_width = k.fx * outer_radius / np.sqrt(np.maximum(safe**2 - outer_radius**2, 1e-12))
    reach = half_width + SEARCH_PX + BACKGROUND_PX[1] + 1.0
    inside = ((pixel[:, 0] - reach >= 0) & (pixel[:, 0] + reach <= k.width - 1)
              & (pixel[:, 1] - reach >= 0) & (pixel[:, 1] + reach <= k.height - 1))
    usable = in_front & crossing & inside & (length > 0)
    if not np.any(usable):
        return LimbPlacement(np.asarray(s, float), offset, across)
    sideways = sideways[usable] / length[usable, None]
    middle, width = _limb_middles(view.channels, pixel[usable], sideways, half_width[usable])
    good = np.abs(width - 2.0 * half_width[usable]) <= WIDTH_TOLERANCE_PX
    offset[np.flatnonzero(usable)[good]] = (middle * depth[usable] / k.fx)[good]
    # across in 3-D: the image's sideways direction in the optical frame, made perpendicular to the line of sight
    direction = np.concatenate([sideways, np.zeros((len(sideways), 1))], axis=1)
    direction -= view_dir[usable] * np.einsum("ij,ij->i", direction, view_dir[usable])[:, None]
    across[usable] = (direction / np.linalg.norm(direction, axis=1)[:, None]) @ rotation.T
    return LimbPlacement(np.asarray(s, float), offset, across)


def _limb_middles(channels: tuple[np.ndarray, ...], pixel: np.ndarray, sideways: np.ndarray, half_width: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per station, the middle of its two limbs (px along `sideways` from `pixel`) and their distance apart (px);
    NaN where a limb was not found."""
    most = float(np.max(half_width)) + SEARCH_PX + BACKGROUND_PX[1]
    ks = np.arange(-most, most + 0.5 / SAMPLES_PER_PX, 1.0 / SAMPLES_PER_PX)
    points = pixel[:, None, :] + ks[None, :, None] * sideways[:, None, :]
    where = [points[..., 1].ravel(), points[..., 0].ravel()]
    profile = np.stack([ndimage.map_coordinates(channel, where, order=1, mode="nearest").reshape(points.shape[:2])
                        for channel in channels], axis=-1)
    limbs = [_limb(profile, ks, side * half_width, side) for side in (-1.0, 1.0)]
    return (limbs[0] + limbs[1]) / 2.0, limbs[1] - limbs[0]


def _limb(profile: np.ndarray, ks: np.ndarray, expected: np.ndarray, side: float) -> np.ndarray:
    """Per station, where the profile crosses half-way from the tube to the background (px along ks) nearest the
    expected limb (on the `side` of the axis: -1 or +1); NaN without contrast or crossing."""
    beyond = side * (ks[None, :] - expected[:, None])  # px outward from the expected limb
    background = _band_mean(profile, (beyond >= BACKGROUND_PX[0]) & (beyond <= BACKGROUND_PX[1]))
    tube = _band_mean(profile, (-beyond >= TUBE_PX[0]) & (-beyond <= TUBE_PX[1]))
    contrast = tube - background
    strength = np.einsum("ij,ij->i", contrast, contrast)
    # 0 at the background's colour, 1 at the tube's
    level = np.einsum("ikc,ic->ik", profile - background[:, None, :], contrast) / np.maximum(strength, 1e-9)[:, None]
    above = level[:, :-1] - 0.5
    below = level[:, 1:] - 0.5
    changes = (np.sign(above) != np.sign(below)) & (np.abs(beyond[:, :-1]) <= SEARCH_PX)
    fraction = above / np.where(above != below, above - below, 1.0)
    at = ks[None, :-1] + fraction * (ks[1] - ks[0])
    distance = np.where(changes, np.abs(at - expected[:, None]), np.inf)
    nearest = np.argmin(distance, axis=1)
    found = np.isfinite(distance[np.arange(len(nearest)), nearest]) & (strength >= MIN_CONTRAST**2)
    return np.where(found, at[np.arange(len(nearest)), nearest], np.nan)


def _band_mean(profile: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Per station, the mean colour of the profile's samples in the band (S, K) mask (0 where it holds none)."""
    weights = band.astype(profile.dtype)
    return np.einsum("ik,ikc->ic", weights, profile) / np.maximum(weights.sum(axis=1), 1.0)[:, None]


@dataclass(frozen=True)
class LimbFigures:
    """What the limbs said: per camera the windows they placed the axis in, and how far they moved it (m, RMS
    over the centreline's samples; 0: not moved)."""

    windows: dict[str, int]
    moved_rms: float


def placed_by_limbs(centerline: Centerline, views: dict[str, CameraView], outer_radius: float, window: float,
                    end_s: float) -> tuple[Centerline, LimbFigures]:
    """The centreline moved across the cameras' views towards the middle of the tube's limbs in their images (part
    of the way where it was off by a pixel or more: the levels each limb is read between are sampled about where
    the axis puts it, and a shaded rim in one band pulls the crossing back).

    Per window of s (a notch pitch) and camera, the median offset of its stations; per window the least move
    across the tangent that gives every camera placing it its offset (opposed cameras share one direction: the
    move lies along it, depth keeps the axis along the views); between windows interpolated, beyond the first and
    last faded out over a window. Up to end_s (the end of the wall seen); unchanged where no window was placed."""
    move, windows = _limb_move(centerline, views, outer_radius, window, end_s)
    if move is None:
        return centerline, LimbFigures(windows, 0.0)
    moved = Centerline.from_points(centerline.points + move, centerline.binormals[0],
                                   float(centerline.s[1] - centerline.s[0]))
    return moved, LimbFigures(windows, float(np.sqrt(np.mean(np.sum(move**2, axis=1)))))


def _limb_move(centerline: Centerline, views: dict[str, CameraView], outer_radius: float, window: float,
               end_s: float) -> tuple[np.ndarray | None, dict[str, int]]:
    """placed_by_limbs' move at each of the centreline's samples (None: no window placed), and
    the windows each camera placed."""
    stations = np.arange(window / 8, max(end_s - outer_radius, window / 8), max(window / 8, 1e-5))
    count = max(int(np.ceil(end_s / window)), 1)
    rows: list[list[tuple[np.ndarray, float]]] = [[] for _ in range(count)]
    placed = {}
    for name, view in views.items():
        placement = limb_offsets(centerline, stations, view, outer_radius)
        which = np.minimum((stations / window).astype(int), count - 1)
        placed[name] = 0
        for w in range(count):
            here = (which == w) & np.isfinite(placement.offset)
            if np.count_nonzero(here) >= MIN_STATIONS:
                centre = np.flatnonzero(here)[np.count_nonzero(here) // 2]
                rows[w].append((placement.across[centre], float(np.median(placement.offset[here]))))
                placed[name] += 1
    centres, moves = [], []
    for w, constraints in enumerate(rows):
        if len(constraints) >= min(MIN_CAMERAS, len(views)):
            directions = np.array([direction for direction, _ in constraints])
            offsets = np.array([value for _, value in constraints])
            # directions that are not distinct (DISTINCT_DIRECTIONS_RCOND) count as one (else their small difference
            # would carry their offsets' disagreement far along the views)
            moves.append(np.linalg.lstsq(directions, offsets, rcond=DISTINCT_DIRECTIONS_RCOND)[0])
            centres.append((w + 0.5) * window)
    if not moves:
        return None, placed
    centres, moves = np.array(centres), np.array(moves)
    move = np.stack([np.interp(centerline.s, centres, moves[:, axis]) for axis in range(3)], axis=1)
    # beyond the windows placed nothing says where the axis lies across the views: the move fades out over a
    # window (held on, it would carry one window's move along a stretch that may turn, e.g. towards a camera)
    beyond = np.maximum(centres[0] - centerline.s, centerline.s - centres[-1]) / window
    move *= np.clip(1.0 - beyond, 0.0, 1.0)[:, None]
    # across the tangent only: a move along it would stretch the centreline
    return move - centerline.tangents * np.einsum("ij,ij->i", move, centerline.tangents)[:, None], placed
