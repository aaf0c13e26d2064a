"""Which side the notches open to, measured: the angle about the axis where the notch windows' coverage gaps
centre, as the cameras saw them (against the configured notch side)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ntcr_recon.core.base.robust import median
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.relocation.notches import Notch, spine_wall
from ntcr_recon.core.robot.comb import inside_intervals
from ntcr_recon.core.robot.geometry import TubeGeometry


class SideMeasurement(NamedTuple):
    roll: float         # rad, how far the notches open from the frame's x axis (the configured side)
    uncertainty: float  # rad: half the spread of the window's two edges where both placed it (never under half a
                        # sector), else half the range of sides the sectors allow alike, plus half a sector
    by_edges: bool = False  # both window edges placed it (a matcher's even smear of the two cancels in their mean)


def measure_notch_side(observed: TubeCoordinates, notches: list[Notch], geometry: TubeGeometry, centerline: Centerline,
                       gate: float, footprint: float, search: float = np.radians(45.0),
                       wall: tuple[np.ndarray, float, float] | None = None) -> SideMeasurement | None:
    """How far (rad) the notches open from the frame's x axis (the configured side), measured on the data, and
    how well.

    Inside the found notches the outer wall is missing over |angle - side| < gap_half_angle; spines keep it
    all round. Per sector of angle, the wall points' density inside the notches relative to that on the
    spines (what the cameras can see cancels in the ratio) is matched to that window, slid over +-`search`
    (to a sector), then placed within a sector by its two edges where both are seen (_window_edges).
    None when fewer than two notches were found or half the ring or less is seen. wall:
    spine_wall(observed) when the caller has it already.
    """
    if len(notches) < 2:
        return None
    offset = observed.radius - geometry.outer_radius
    spine, level, spread = spine_wall(observed, centerline, geometry, gate, footprint) if wall is None else wall
    on_wall = np.abs(offset - level) <= spread
    intervals = np.array([[n.start_s + footprint, n.end_s - footprint] for n in notches])
    intervals = intervals[intervals[:, 1] > intervals[:, 0]]
    in_notch = on_wall & inside_intervals(observed.s, intervals)
    on_spine = on_wall & spine & (observed.s > notches[0].start_s) & (observed.s < notches[-1].end_s)
    sectors = 36
    width = 2 * np.pi / sectors
    index = ((observed.angle + np.pi) / width).astype(np.intp) % sectors
    notch_count = np.bincount(index[in_notch], minlength=sectors).astype(float)
    spine_count = np.bincount(index[on_spine], minlength=sectors).astype(float)
    seen = spine_count >= max(5.0, 0.1 * spine_count.max(initial=0.0))
    # the open window is wide: with half the ring unseen or more (one camera alone) its position is not fixed; and
    # the wall inside the notches has to be seen where the spines' is, for the one to be measured against the other
    if np.count_nonzero(seen) <= sectors // 2 or notch_count[seen].sum() == 0:
        return None
    ratio = (notch_count / np.maximum(spine_count, 1.0)) / (notch_count[seen].sum() / spine_count[seen].sum())
    centres = -np.pi + (np.arange(sectors) + 0.5) * width
    sides = np.arange(-search, search + 1e-9, np.radians(1.0))
    coarse = _coarse_side(ratio, seen, centres, sides, geometry.gap_half_angle)
    if coarse is None:
        return None
    side, allowed, outside = coarse
    # the sectors place the window to a sector; a window edge between two seen neighbouring sectors is
    # placed within them, where the ratio crosses half its level outside the window
    located = _window_edges(ratio, seen, centres, width, side, geometry.gap_half_angle, outside)
    if located:
        low, high = allowed[0] - width / 2, allowed[1] + width / 2  # what the sectors allow
        # the edges' spread shows a matcher smearing them unevenly inwards, not one edge smeared in and the other
        # out (which shifts both alike): each edge is placed between two sectors' centres, to half a sector
        return SideMeasurement(float(np.clip(np.mean(located), low, high)),
                               max(abs(located[0] - located[1]) / 2, width / 2), by_edges=True)
    # an edge that falls where nothing is seen: the sectors at the border of what is seen (grazing views thin
    # the wall there unevenly, which reads as the window's edge) may have placed the window; judged without
    # them as well, the smaller turn of the two stands (a side no edge placed moves no further than it must)
    judged = _coarse_side(ratio, seen & np.roll(seen, 1) & np.roll(seen, -1), centres, sides,
                          geometry.gap_half_angle)
    if judged is not None and abs(judged[0]) < abs(side):
        side, allowed = judged[0], judged[1]
    return SideMeasurement(side, (allowed[1] - allowed[0]) / 2 + width / 2)


def _coarse_side(ratio: np.ndarray, judged: np.ndarray, centres: np.ndarray, sides: np.ndarray, half_angle: float
                 ) -> tuple[float, tuple[float, float], np.ndarray] | None:
    """The candidate side whose open window (within half_angle of it) best separates the wall ratio over the
    judged sectors (mean outside minus mean inside; ties: the smallest turn), the range of sides tied with it,
    and its outside mask; None when no candidate has judged sectors both inside and outside its window.
    Every candidate at once: (candidates, sectors) masks."""
    distance = np.abs(_wrapped(centres[None, :] - sides[:, None]))
    inside = judged[None, :] & (distance < half_angle)
    outside = judged[None, :] & ~(distance < half_angle)
    count_in, count_out = inside.sum(axis=1), outside.sum(axis=1)
    valid = (count_in > 0) & (count_out > 0)
    if not np.any(valid):
        return None
    score = (outside @ ratio) / np.maximum(count_out, 1) - (inside @ ratio) / np.maximum(count_in, 1)
    score = np.where(valid, score, -np.inf)
    best = np.flatnonzero(score >= score.max() - 1e-12)
    chosen = best[np.argmin(np.abs(sides[best]))]
    return float(sides[chosen]), (float(sides[best].min()), float(sides[best].max())), outside[chosen]


def _window_edges(ratio: np.ndarray, seen: np.ndarray, centres: np.ndarray, width: float, side: float,
                  half_angle: float, outside: np.ndarray) -> list[float]:
    """The side the window's two edges put the notches at, when each falls between two seen neighbouring
    sectors, one mostly open and one mostly walled (their ratios either side of half the median outside the
    window): a sector holds as much wall as the share of it outside the window, which places the edge within
    them. Near an edge the matcher thins the wall as much on one side of the window as on the other, so only
    both edges together (their mean) place it; an empty list when one is not seen so. Sectors at the border
    of what is seen are left out: grazing views thin the wall there unevenly, which would read as an edge."""
    sectors = len(ratio)
    usable = seen & np.roll(seen, 1) & np.roll(seen, -1)
    if not np.any(usable & outside):
        return []
    level = float(median(ratio[usable & outside]))
    share = np.clip(ratio / max(level, 1e-12), 0.0, 1.0)
    found = []
    for sign in (1, -1):  # the edge at side + half_angle (wall beyond it at larger angles), at side - half_angle
        edge = side + sign * half_angle
        nearest = int(np.argmin(np.abs(_wrapped(centres - edge))))
        for step in (0, -1, 1, -2):
            open_, walled = (nearest + sign * step) % sectors, (nearest + sign * (step + 1)) % sectors
            if usable[open_] and usable[walled] and share[open_] < 0.5 <= share[walled]:
                boundary = centres[open_] + sign * width / 2
                located = boundary - sign * share[open_] * width + sign * (1.0 - share[walled]) * width
                found.append(float(_wrapped(located - sign * half_angle)))
                break
    return found if len(found) == 2 else []


def _wrapped(angle):
    """Angles wrapped into [-pi, pi) (a fifth of the cost of np.angle(np.exp(1j * angle)))."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def face_view_tangent(centerline: Centerline, s: np.ndarray, camera_origins: np.ndarray,
                      facing: float | np.ndarray) -> np.ndarray:
    """Per cut face at arc lengths s (outward normal `facing` x the tangent: +1 a notch's start face, -1 its end
    face; one for all, or one per face), how much of it the cameras see beside its rim: the mean over the cameras
    of the tangent of the angle between the view and the face's plane where the face turns towards the camera,
    0 where it turns away."""
    position, tangent, _, _ = centerline.frames_at(np.asarray(s, dtype=float))
    view = camera_origins[None, :, :] - position[:, None, :]
    facing = np.asarray(facing, dtype=float)[..., None]
    cosine = facing * np.einsum("nj,ncj->nc", tangent, view) / np.linalg.norm(view, axis=2)
    cosine = np.clip(cosine, 0.0, 1.0 - 1e-9)
    return np.mean(cosine / np.sqrt(1.0 - cosine * cosine), axis=1)
