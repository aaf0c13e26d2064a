"""Tip: where the tube seen in the cloud ends, judged by what the cameras can see there.

The end is where the outer wall stops: per slab of arc length (one pixel footprint), the angular sectors
about the axis holding wall points. Which sectors a camera can see at all follows from its pose and the
local tangent (a sector whose outward direction turns more than `grazing` from the camera is not seen),
so occupancy is counted over the visible sectors only: a distal part pointing at one camera, which the
other hardly sees, still counts as tube. Where no sector is visible (the tube points straight at a camera)
the wall showing in a few sectors counts. The search never runs past the robot's known length plus a margin.

The end is then refined below a slab, per camera: where the density of its wall points along s falls to half
its plateau (`half_density_end`; pixels sample the image uniformly, so the crossing is the end whatever the
pixel phase). A stereo matcher spoils the pixels next to a depth edge: where the tip is seen against a far
background, a band of pixels either side of the end's outline in the image reads no depth or a depth mixed
between tube and background. That band is measured in the depth images themselves (`edge_band`: the pixels
between a clean near surface and a clean far background at depth edges, half of them on each side), and
what it takes off each camera's end along s follows from the end's outline in that camera's image
(`rim_erosion`). Without depth images (a node that receives clouds only) the erosion measured on each
camera's silhouettes of plain tube is given back instead (`silhouette_erosion`), which reads less than the
tip loses (a silhouette's mixed pixels move along the wall, not off it).

The robot's own length is a measurement of the tip too: the reference the cloud is relocated onto is the
configured robot, its centreline as long as the notch layout makes it, shortened by the bend
(`TubeGeometry.bent_length`). `with_known_length` puts the tip between the end seen and that length, each
weighed by its uncertainty, where the two agree within their uncertainties; where they do not, the end seen
stands (a tube cut short by the view is not stretched, a mis-configured length does not move the tip) and the
result says so. An end cap's plane only bounds the tip from below (the matcher moves the cap's points towards
the base only): a length beyond it is the tip.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.robust import median, quantile, robust_spread
from ntcr_recon.core.relocation.profile import coverage_profile
from ntcr_recon.core.relocation.wall import surface_band

if TYPE_CHECKING:  # centerline.py imports this module
    from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates

# The end seen and the robot's length agree when they lie within this many of their combined uncertainties.
LENGTH_AGREEMENT_SIGMAS = 3.0
GRAZING = np.radians(80.0)  # a surface turned further than this from a camera gives it (almost) no depth
MIN_SECTORS_WHEN_UNSEEN = 3  # of the ring's sectors, holding wall points where no sector faces a camera
# A depth edge whose far side lies at least this factor further than its near side is an edge against a
# background (the tip's, in any rig: the tube is millimetres thick, its background centimetres behind it).
FAR_BACKGROUND_RATIO = 1.2
# A gap of spoiled pixels wider than this between a near and a far surface is no matcher band (which spans at
# most its matching window, 7-17 px on a D405) but an occlusion shadow or a surface missing for another reason.
MAX_EDGE_GAP_PX = 16
EDGE_NOISE_SIGMAS = 3.0  # a pixel off its surface's linear continuation by more than this many sigma is spoiled
MIN_EDGES = 20  # edges needed to measure a band
MAX_EDGE_BAND_RAD = 0.1  # an edge band wider than this angle is no camera's (half MAX_EDGE_GAP_PX over a focal
                         # length of 80 px)
EDGE_BAND_ATTEMPTS = 3  # depth images of a camera tried for its band (a scene without a far background shows none)
# The sector at this angle from the one facing a camera holds the median of that camera's wall points at an
# end (sectors weigh by their width in the image, cos psi; half the weight lies within sin psi = 1/2).
MEDIAN_SECTOR = np.radians(30.0)


def visible_sectors(centerline: Centerline, s: np.ndarray, viewpoints: np.ndarray, sectors: int,
                    grazing: float = GRAZING) -> np.ndarray:
    """(len(s), sectors) bool: some camera (optical centres `viewpoints` (C, 3)) sees the sector's wall."""
    position, _, normal, binormal = centerline.frames_at(s)
    angles = -np.pi + (np.arange(sectors) + 0.5) * (2 * np.pi / sectors)
    return _visible_kernel(position, normal, binormal, np.cos(angles), np.sin(angles),
                           np.atleast_2d(viewpoints).astype(float), np.cos(grazing))


@jit
def _visible_kernel(position, normal, binormal, cos_angles, sin_angles, viewpoints, least_cosine):
    """Per slab (its frame) and sector (its angle), whether the sector's outward direction
    cos normal + sin binormal is within acos(least_cosine) of the direction to some viewpoint."""
    seen = np.zeros((position.shape[0], cos_angles.shape[0]), np.bool_)
    for i in range(position.shape[0]):
        for origin in viewpoints:
            v0, v1, v2 = origin[0] - position[i, 0], origin[1] - position[i, 1], origin[2] - position[i, 2]
            length = max(np.sqrt(v0 * v0 + v1 * v1 + v2 * v2), 1e-12)
            along_normal = (v0 * normal[i, 0] + v1 * normal[i, 1] + v2 * normal[i, 2]) / length
            along_binormal = (v0 * binormal[i, 0] + v1 * binormal[i, 1] + v2 * binormal[i, 2]) / length
            for k in range(cos_angles.shape[0]):
                seen[i, k] |= cos_angles[k] * along_normal + sin_angles[k] * along_binormal > least_cosine
    return seen


def tube_end(coords: TubeCoordinates, radius: float, gate: float, cell: float, sectors: int = 24,
             max_s: float = np.inf, centerline: Centerline | None = None, viewpoints: np.ndarray | None = None,
             spine: np.ndarray | None = None, band: tuple[float, float] | None = None) -> float:
    """Arc length where the tube seen in the cloud ends, to a fraction of `cell` (see the module docstring).

    Without `centerline` and `viewpoints` every sector counts as visible. spine: points to measure the wall
    band on (see wall.surface_band); band: that band (level, spread) when the caller has it already.
    """
    offset = coords.radius - radius
    level, spread = surface_band(offset, gate, spine) if band is None else band
    on_wall = (np.abs(offset - level) <= spread) & (coords.s >= 0) & (coords.s <= max_s)
    if np.count_nonzero(on_wall) < 8:
        return float(min(coords.s.max(initial=0.0), max_s))
    s_wall = coords.s[on_wall]
    slab = (s_wall / cell).astype(np.intp)
    sector = ((coords.angle[on_wall] + np.pi) / (2 * np.pi) * sectors).astype(np.intp) % sectors
    grid = np.zeros((slab.max() + 2, sectors), dtype=bool)
    grid[slab, sector] = True
    if centerline is not None and viewpoints is not None:
        visible = visible_sectors(centerline, (np.arange(len(grid)) + 0.5) * cell, viewpoints, sectors)
        seen = np.count_nonzero(grid & visible, axis=1)
        count = np.count_nonzero(visible, axis=1)
        # sectors visible to no camera say nothing; a slab with few visible (under a quarter of the ring: the
        # tube points at a camera) is tube where its wall shows in a few sectors at least (a stray flying
        # pixel is not)
        some = (np.count_nonzero(grid, axis=1) >= MIN_SECTORS_WHEN_UNSEEN).astype(float)
        occupied = np.where(count >= sectors // 4, seen / np.maximum(count, 1), some)
    else:
        occupied = np.count_nonzero(grid, axis=1) / float(sectors)
    occupied = np.convolve(occupied, np.ones(3) / 3.0, mode="same")
    half = 0.5 * float(median(occupied[occupied > 0]))
    above = np.flatnonzero(occupied >= half)
    last = int(above[-1])
    a, b = occupied[last] - half, occupied[last + 1] - half if last + 1 < len(occupied) else -half
    fraction = a / (a - b) if a != b else 0.5
    coarse = (last + 0.5 + float(np.clip(fraction, 0.0, 1.0))) * cell
    return float(min(coarse, max_s))


def silhouette_erosion(coords: TubeCoordinates, frames: tuple, camera: np.ndarray, origins: np.ndarray,
                       radius: float, usable: np.ndarray, quantile: float = 0.98) -> float:
    """How much of the tube's rim each camera loses at a depth edge (m), measured on its silhouettes.

    A stereo matcher drops or smears the pixels next to a depth edge. The tube's true half-width across
    each camera's view is its outer radius, and depth pixels sample the lateral coordinate uniformly, so
    the rim lost is r_o - q-quantile(|lateral|) / q over the camera's points on plain tube (usable: not in
    a notch, not at the ends). The median over cameras is returned; 0 when it cannot be measured.
    """
    position, _, normal, binormal = frames
    estimates = []
    for index in np.unique(camera):
        mine = usable & (camera == index)
        if np.count_nonzero(mine) < 50:
            continue
        view = origins[index] - position[mine]
        view_x = (view * normal[mine]).sum(axis=1)
        view_y = (view * binormal[mine]).sum(axis=1)
        length = np.hypot(view_x, view_y)
        lateral = (view_x * coords.y[mine] - view_y * coords.x[mine]) / np.maximum(length, 1e-12)
        estimates.append(radius - float(np.quantile(np.abs(lateral), quantile)) / quantile)
    return max(float(np.median(estimates)), 0.0) if estimates else 0.0


def give_back_erosion(tip_s: float, coords: TubeCoordinates, frames: tuple, camera: np.ndarray, origins: np.ndarray,
                      radius: float, gate: float, notch_intervals: list[tuple[float, float]], cell: float) -> float:
    """The tip moved out by the rim erosion measured on plain tube (away from the base, the tip and notches).

    The tip's rim, an edge seen against the background, loses what the tube's silhouettes lose to the
    stereo matcher.
    """
    plain = (coords.s > 2 * radius) & (coords.s < tip_s - 2 * radius)
    for start, end in notch_intervals:
        plain &= (coords.s < start - 2 * cell) | (coords.s > end + 2 * cell)
    offset = coords.radius - radius
    level, spread = surface_band(offset, gate, plain)
    plain &= np.abs(offset - level) <= spread
    return tip_s + silhouette_erosion(coords, frames, camera, origins, radius, plain)


def cap_faces_a_camera(centerline: Centerline, tip_s: float, viewpoints: np.ndarray, least_sine: float) -> bool:
    """Some camera looks onto the tip's end cap: the tangent at the tip turned towards it by at least
    asin(least_sine) from across its view (the cap's diameter then shows foreshortened by that sine)."""
    position, tangent, _, _ = centerline.frames_at(np.array([tip_s]))
    view = np.atleast_2d(viewpoints) - position
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return bool(np.any(view @ tangent[0] > least_sine))


def end_cap_plane(coords: TubeCoordinates, inner_radius: float, outer_radius: float, coarse_end: float,
                  reach: float, cell: float, after: float = -np.inf) -> tuple[float, float] | None:
    """Arc length of the end cap where a camera looks onto it, and how far its points smear away from it.

    The cap is a disc of the tube's cross-section, so its points pile up at one s (a peak of the points'
    density along s within the annulus), while the wall near a tube pointing at the camera is seen thinly and
    flying pixels trail behind the cap. A stereo matcher's window over the cap's ring reaches the bore behind
    it and only ever pulls the ring's depth away from the camera: the cap lies on the near (camera) side of the
    peak, where the points' density falls to half of it (on a cap the matcher resolves, about a kernel width of
    cell / 8 past the cap). The smear - that plane less the peak points' median - tells how much the matcher
    mixed in. None when no such peak stands out within `reach` of the coarse end and past `after`, or when the
    peak's points lie on the wall rather than across the annulus.

    after: where the cap may begin (m of s). A notch's cut face turned to the camera is a part of a disc too, and
    piles its points up at one s: where the tube beyond the last notches is hidden (nearer the camera than its
    depth range), that face's pile-up is the last one left, and would be taken for the cap (3 mm short in the
    sweeps); the cap lies the distal ring's length past the last notch.
    """
    near = (np.abs(coords.s - coarse_end) < reach) & (coords.radius > 0.5 * inner_radius)
    near &= coords.radius < outer_radius + cell
    if np.count_nonzero(near) < 20:
        return None
    s = coords.s[near]
    edges = np.arange(coarse_end - reach, coarse_end + reach + cell, cell)
    counts, _ = np.histogram(s, bins=edges)
    # the highest bin past `after` (the median over them all says what stands out)
    peak = int(np.argmax(np.where(edges[:-1] >= after, counts, -1)))
    if edges[peak] < after or counts[peak] < max(10, 4.0 * float(np.median(counts))):
        return None
    in_peak = (s >= edges[max(peak - 1, 0)]) & (s < edges[min(peak + 2, len(edges) - 1)])
    # a disc's points fill the annulus (uniform over it, half lie within sqrt((r_i^2 + r_o^2) / 2)); a pile-up on
    # the wall's radius is the wall cut off - nearer a camera than its depth range, or where a camera's view of it
    # ends - not a cap
    annulus_median = np.sqrt((inner_radius**2 + outer_radius**2) / 2.0)
    if np.median(coords.radius[near][in_peak]) > (annulus_median + outer_radius) / 2.0:
        return None
    kernel = cell / 8.0
    fine = np.arange(edges[max(peak - 4, 0)], edges[min(peak + 5, len(edges) - 1)] + kernel, kernel / 2)
    density = gaussian_filter1d(np.histogram(s, bins=fine)[0].astype(float), 2.0)
    centres = (fine[:-1] + fine[1:]) / 2
    top = int(np.argmax(density))
    beyond = np.flatnonzero(density[top:] < density[top] / 2)
    if not len(beyond):
        plane = float(centres[-1])
    else:  # linear between the last sample above half the peak and the first below
        after = top + int(beyond[0])
        high, low = density[after - 1], density[after]
        share = (high - density[top] / 2) / max(high - low, 1e-12)
        plane = float(centres[after - 1] + share * (centres[after] - centres[after - 1]))
    return plane, plane - float(np.median(s[in_peak]))


def edge_band(depth: np.ndarray, unit: float, sigmas: float = EDGE_NOISE_SIGMAS,
              far_ratio: float = FAR_BACKGROUND_RATIO, max_gap: int = MAX_EDGE_GAP_PX,
              least: int = MIN_EDGES) -> float | None:
    """Pixels (per side) a stereo matcher spoils at a depth edge against a far background, measured in a raw
    depth image (`depth` in device units of `unit` metres, 0 = none).

    Along each image column (across the stereo baseline: the left-right occlusion shadow lies along the rows),
    a pixel is clean where its inverse depth (the matcher's disparity, up to a constant) continues its
    neighbours on one side (their line, or their quadratic) to within `sigmas` of the matcher's noise per
    pixel (measured on the image) and the depth quantisation. At every edge between a clean near surface and a clean
    surface at least `far_ratio` further, the pixels between them are spoiled: dropped, or mixed between the
    two depths. A matcher's window straddles the edge symmetrically, so half the median gap is what each side
    loses. None when fewer than `least` such edges are seen (no far background, e.g. a renderer with none).
    """
    z = np.asarray(depth, dtype=float).T * unit  # columns as lines
    valid = z > 0
    q = np.where(valid, 1.0 / np.where(valid, z, 1.0), 0.0)
    if q.shape[1] < 5:
        return None
    # a surface's continuation from either side: the line through a pixel's two neighbours, or - a tube's
    # profile curves towards its silhouette, where a line would call its last clean pixels spoiled - the
    # quadratic through three
    three = valid[:, 2:] & valid[:, 1:-1] & valid[:, :-2]
    four = three[:, 1:] & valid[:, :-3]
    if np.count_nonzero(three) < least:
        return None
    predictions = np.full((4, *q.shape), np.inf)
    predictions[0, :, 2:] = np.where(three, 2.0 * q[:, 1:-1] - q[:, :-2], np.inf)
    predictions[1, :, :-2] = np.where(three, 2.0 * q[:, 1:-1] - q[:, 2:], np.inf)
    predictions[2, :, 3:] = np.where(four, 3.0 * q[:, 2:-1] - 3.0 * q[:, 1:-2] + q[:, :-3], np.inf)
    predictions[3, :, :-3] = np.where(four, 3.0 * q[:, 1:-2] - 3.0 * q[:, 2:-1] + q[:, 3:], np.inf)
    # the matcher's noise per pixel: the spread of the line's residual (robust, not across edges) over the
    # line's noise gain sqrt(1 + 4 + 1)
    residual = (q[:, 2:] - predictions[0, :, 2:])[three]
    residual = residual[np.abs(residual) < 0.05 * float(np.median(q[valid]))]
    centre = float(np.median(residual)) if residual.size else 0.0
    sigma = robust_spread(residual, centre) / np.sqrt(6.0)
    # clean: within `sigmas` of that noise of the surface's continuation (as a point within its wall band:
    # a mixed pixel's own error, not the prediction's, decides), and the worst rounding of the quadratic's
    # prediction, (3 + 3 + 1 + 1) half depth units
    tolerance = sigmas * sigma + 4.0 * unit * q * q
    clean = valid & np.any(np.abs(q[None] - predictions) <= tolerance[None], axis=0)
    line, column = np.nonzero(clean)
    same = line[1:] == line[:-1]
    first, second, line = column[:-1][same], column[1:][same], line[:-1][same]
    gap = second - first - 1
    q_first, q_second = q[line, first], q[line, second]
    edge = ((q_first > far_ratio * q_second) | (q_second > far_ratio * q_first)) & (gap <= max_gap)
    if np.count_nonzero(edge) < least:
        return None
    return float(np.median(gap[edge])) / 2.0


def edge_band_angle(depth: np.ndarray, unit: float, focal: float) -> float | None:
    """A camera's edge band (`edge_band`, pixels) over its focal length (pixels): an angle, so the band in
    metres at any distance is that distance times it. None when the image shows no band."""
    band = edge_band(depth, unit)
    return None if band is None else band / focal


def rim_erosion(band: float, cos_view: float, radius: float) -> float:
    """How far (along s) the half-density end of one camera's wall points falls short of the tube's end.

    band: what the matcher spoils either side of an edge, in metres at the tip's distance. cos_view: the
    cosine between the end tangent and the direction to the camera (> 0: the end turns towards it).
    In the camera's image the end's outline is the rim, an ellipse of semi-axes r (across) and r |cos_view|
    (along the axis). The wall sector at psi from the one facing the camera ends on that outline where the end
    turns away, and 2 r cos_view cos psi inside it where it turns towards (the end cap then makes the
    outline). The band, perpendicular to the outline, reaches band sqrt(cos^2 psi + cos_view^2 sin^2 psi) /
    cos psi along the sector's line in the image; the half-density end is that of the median sector
    (MEDIAN_SECTOR); along s the image is foreshortened by the sine of the view angle.
    """
    c = float(np.clip(cos_view, -1.0, 1.0))
    psi = MEDIAN_SECTOR
    reach = band * np.sqrt(np.cos(psi) ** 2 + c * c * np.sin(psi) ** 2) / np.cos(psi)
    inside = 2.0 * radius * c * np.cos(psi) if c > 0 else 0.0
    return max(reach - inside, 0.0) / max(np.sqrt(1.0 - c * c), 1e-6)


def half_density_end(s: np.ndarray, coarse: float, cell: float, kernel: float, before: float,
                     after: float) -> float | None:
    """Where the density of wall points along s (smoothed by a Gaussian of width `kernel`) last falls to half
    its plateau (the upper quartile over [coarse - before, coarse - 3 cell]), searched up to coarse + after.
    None when there is no plateau or no crossing."""
    step = cell / 8.0
    grid, density = coverage_profile(s, coarse - before, coarse + after, step, kernel)
    plateau_zone = grid < coarse - 3.0 * cell
    if not np.any(plateau_zone):
        return None
    half = 0.5 * float(quantile(density[plateau_zone], 0.75))
    above = np.flatnonzero(density >= half)
    if half <= 0 or above.size == 0 or above[-1] + 1 >= len(grid):
        return None
    last = int(above[-1])
    a, b = density[last] - half, density[last + 1] - half
    return float(grid[last] + step * (a / (a - b) if a != b else 0.5))


class RimViews(NamedTuple):
    """How the cameras saw a rim: which camera saw each point, where the cameras are (base frame, m), and per
    camera index the band `edge_band` measured, as an angle (px / focal length; NaN: not measured)."""

    camera: np.ndarray
    origins: np.ndarray
    bands: np.ndarray


def rim_tip(coords: TubeCoordinates, views: RimViews, centerline: Centerline, coarse: float, radius: float,
            gate: float, cell: float, kernel: float, spine: np.ndarray, reach: float, least: int = 50,
            last_notch_s: float = -np.inf) -> tuple[float, float, float] | None:
    """The tip from each camera's rim: its half-density end plus the matcher's erosion there.

    spine: points to measure the wall band on (away from notches). reach: how far before the coarse end the
    density plateau is taken (over spines and notches alike: a notch takes the same share of the ring there).
    Cameras are weighed by sin^2 of their view angle to the tangent (an image error becomes that much less
    along s). Returns (the measured ends' mean, the tip, how well the tip is known along s), or None when a
    camera seeing the end has no band or none sees enough of it. The uncertainty: half a pixel for the end
    (a pixel's phase), and half a pixel for the band where one was spoiled (read as whole pixels, halved), each
    along s (a pixel footprint `cell` over the view angle's sine). last_notch_s: the centre of the robot's last
    notch; a camera whose wall ends before it saw the cut's edge, not the tube's end (a camera facing the notch
    side loses the short ring beyond the last notch to the matcher's erosion from both its edges), and is not
    heard while another camera saw past it.
    """
    camera, origins, bands = views
    offset = coords.radius - radius
    level, spread = surface_band(offset, gate, spine)
    wall = (np.abs(offset - level) <= max(spread, cell / 2)) & (coords.s > coarse - reach)
    wall &= coords.s < coarse + 2 * radius
    position, tangent, _, _ = centerline.frames_at(np.array([coarse]))
    ends, tips, weights, uncertainties, past_last_notch = [], [], [], [], []
    for index in np.unique(camera[wall]):
        mine = wall & (camera == index)
        if np.count_nonzero(mine) < least:
            continue
        end = half_density_end(coords.s[mine], coarse, cell, kernel, reach, 2 * radius)
        if end is None:
            continue
        if not np.isfinite(bands[index]):
            return None
        view = origins[index] - position[0]
        distance = float(np.linalg.norm(view))
        cos_view = float(view @ tangent[0]) / max(distance, 1e-12)
        ends.append(end)
        tips.append(end + rim_erosion(bands[index] * distance, cos_view, radius))
        weights.append(max(1.0 - cos_view * cos_view, 1e-6))
        pixels = 0.5 + (0.5 if bands[index] > 0 else 0.0)
        uncertainties.append(pixels * cell / np.sqrt(weights[-1]))
        past_last_notch.append(end >= last_notch_s)
    if any(past_last_notch):  # the cameras that saw the tube's end, not the last cut's edge
        ends, tips, weights, uncertainties = ([value for value, past in zip(values, past_last_notch, strict=True)
                                               if past] for values in (ends, tips, weights, uncertainties))
    if not ends:
        return None
    return (float(np.average(ends, weights=weights)), float(np.average(tips, weights=weights)),
            float(np.average(uncertainties, weights=weights)))


@dataclass(frozen=True)
class TipAlongTube:
    """Where the tip lies along the centreline (m of arc length) and how well it is known, from the end the
    cameras saw and the robot's known length."""

    s: float
    uncertainty: float
    seen_s: float               # the end as the cameras saw it (refined)
    seen_uncertainty: float
    expected_s: float           # the robot's length at its bend
    tolerance: float | None     # how well that length is known (None: not known)
    length_weighed: bool = False  # the robot's length was weighed in (the two agreed)
    beyond_seen: bool = False     # the end seen bounds the tip from below, and the tip is the robot's length beyond it
    # carried to the length past an end every camera was kept from seeing (carried_to_length): how far across the
    # tube a straight hidden part would leave the tip (m); None: not carried
    hidden_across: float | None = None

    @property
    def disagreement(self) -> float:
        """The robot's length less the end seen (m; + the end seen short of it), in combined uncertainties."""
        if self.tolerance is None:
            return 0.0
        return (self.expected_s - self.seen_s) / float(np.hypot(self.seen_uncertainty, self.tolerance))


def with_known_length(seen_s: float, seen_uncertainty: float, expected_s: float,
                      tolerance: float | None, lower_bound: bool = False) -> TipAlongTube:
    """The tip along the tube: the end seen and the robot's length at its bend (`expected_s`, known to
    `tolerance`) weighed by their inverse variances, where they agree within LENGTH_AGREEMENT_SIGMAS of their
    combined uncertainty; else (or with no tolerance) the end seen.

    lower_bound: the end seen is one the matcher only ever moved towards the base (an end cap whose ring it mixed
    with the bore behind: end_cap_plane), so it says the tip lies no nearer the base; a length beyond it that
    agrees is the tip, known as well as the length (the end seen says nothing more of it)."""
    seen = TipAlongTube(seen_s, seen_uncertainty, seen_s, seen_uncertainty, expected_s, tolerance)
    if tolerance is None or abs(seen.disagreement) > LENGTH_AGREEMENT_SIGMAS or seen_uncertainty <= 0.0:
        return seen
    if lower_bound and expected_s >= seen_s:
        return TipAlongTube(expected_s, tolerance, seen_s, seen_uncertainty, expected_s, tolerance,
                            length_weighed=True, beyond_seen=True)
    weight_seen, weight_length = 1.0 / seen_uncertainty**2, 1.0 / tolerance**2
    s = (weight_seen * seen_s + weight_length * expected_s) / (weight_seen + weight_length)
    return TipAlongTube(float(s), float(1.0 / np.sqrt(weight_seen + weight_length)), seen_s, seen_uncertainty,
                        expected_s, tolerance, length_weighed=True)


def carried_to_length(along: TipAlongTube, centerline: Centerline) -> TipAlongTube:
    """The tip carried past the end seen to the robot's length along `centerline`, carried on bending there as the
    notches before it bent (bends.continued_bend): for a tube whose rest every camera was kept from seeing
    (nearer than its depth range, pointing at it), so that the robot goes on where nothing was measured.

    How well it is known there: along the tube, as well as the length and as far as a straight hidden part would
    leave it ahead or short; across it, as far as that straight part would leave it off (hidden_across) - the
    hidden notches may bend less or more than the ones seen, and no camera says which."""
    (seen_position, position), (seen_tangent, tangent) = centerline.frames_at(
        np.array([along.seen_s, along.expected_s]))[:2]
    off = seen_position + (along.expected_s - along.seen_s) * seen_tangent - position
    ahead = float(off @ tangent)
    return replace(along, s=along.expected_s, uncertainty=float(np.hypot(along.tolerance or 0.0, ahead)),
                   beyond_seen=True, hidden_across=float(np.linalg.norm(off - ahead * tangent)))
