"""The tube's end in each camera's colour image: the tip along the tube where depth smears it (issue 61, part 1).

A stereo matcher moves a depth edge by up to half its window, so the end of the wall in depth lies tenths of a
millimetre off the tip, one way or the other as the matcher goes (the package's emulation erodes it, a semi-global
matcher fattens it). The left imager's colour image shows the end sharp. Seen across the tube, the end of its
outline is the end cap's rim, whose outline reaches past the tip's centre by r |cot a| along the tube (a the angle
between the tangent and the line of sight; an ellipse r wide), at u r beside the axis by that times sqrt(1 - u^2).
Per camera, profiles along the projected axis at LATERAL_OFFSETS are read for the crossing half-way from the tube to
the background (limb_profile.limb_crossings, as the limbs are, not shaded), each placing the tip's centre (their
median). Unlike a limb, which shading darkens as the wall turns away, the end's wall faces the camera up to the rim:
read about the true axis, the end lies within 0.005 mm of the tip on a straight robot and 0.02-0.07 mm past it bent
45 deg (rendered with the package's emulation or a real matcher's left image alike). The cameras' tips are averaged;
how far apart they lie, and half a pixel (EDGE_PX), is how well it is known; weighed with depth's end where the two
agree (OutlineEnd.with_depth), else taken for it. The end is looked for within the limbs' search
(limb_profile.SEARCH_PX) of the end depth saw, which a matcher leaves within a pixel or two: further back, a slot
seen side on shows the background too.

    seen = end_in_outline(centerline, end_s, views, geometry, footprint)   # OutlineEnd, or None
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limb_profile import BACKGROUND_PX, SEARCH_PX, limb_crossings
from ntcr_recon.core.relocation.limbs import CameraView, stations_in_view
from ntcr_recon.core.relocation.outline import LEAST_CROSSING
from ntcr_recon.core.robot.geometry import TubeGeometry

# Where beside the axis the end is read (fractions of the tube's radius in the image): the rim's outline is
# sharpest where it crosses the axis, and three profiles outvote a speck of the background.
LATERAL_OFFSETS = (-0.4, 0.0, 0.4)
# Readings per camera, each about where the last put the end.
READS = 2
# How well one image places the end beyond the cameras' disagreement (px): a rendered edge lands on the renderer's
# sub-pixel grid (half a pixel at 2 rays a side), the rim's own shading is unknown, and nothing else averages it
# out (the limbs' stations do).
EDGE_PX = 0.5


# Depth's end and the outline's agree within this many of their combined uncertainties, or depth's was moved by its
# matcher and the outline's is taken.
AGREEMENT_SIGMAS = 2.0


@dataclass(frozen=True)
class OutlineEnd:
    """The tip's arc length the colour images place (m), how well (m), and per camera its own (m)."""

    s: float
    uncertainty: float
    by_camera: dict[str, float]

    def with_depth(self, depth_s: float, depth_uncertainty: float | None) -> tuple[float, float]:
        """The end (m of arc length) and how well it is known (m): the outline's and depth's weighed by their
        inverse variances where they agree within AGREEMENT_SIGMAS; else (or with depth's unknown) the outline's,
        which no matcher moved."""
        if depth_uncertainty is None or depth_uncertainty <= 0.0:
            return self.s, self.uncertainty
        if abs(depth_s - self.s) > AGREEMENT_SIGMAS * math.hypot(depth_uncertainty, self.uncertainty):
            return self.s, self.uncertainty
        weight_depth, weight_outline = depth_uncertainty**-2, self.uncertainty**-2
        return ((weight_depth * depth_s + weight_outline * self.s) / (weight_depth + weight_outline),
                (weight_depth + weight_outline) ** -0.5)


def end_in_outline(centerline: Centerline, end_s: float, views: dict[str, CameraView], geometry: TubeGeometry,
                   footprint: float) -> OutlineEnd | None:
    """The tip's arc length where the colour images show the tube's outline ending, read about `end_s` (the end
    depth saw, within the limbs' search of it); None where no camera sees the end across the tube."""
    by_camera = {}
    for name, view in views.items():
        s = _camera_end(centerline, end_s, view, geometry)
        if s is not None:
            by_camera[name] = s
    if not by_camera:
        return None
    values = np.array(list(by_camera.values()))
    apart = float(np.ptp(values)) / 2 if len(values) > 1 else footprint / 2
    return OutlineEnd(float(np.mean(values)), math.hypot(apart, EDGE_PX * footprint), by_camera)


def _camera_end(centerline: Centerline, end_s: float, view: CameraView, geometry: TubeGeometry) -> float | None:
    """One camera's tip (m of arc length), read READS times, each about where the last put it (the tube and the
    background are sampled a pixel and a half either side of the expected end: a start a pixel off mixes them);
    None where it sees the end along its line of sight, outside its image, or with no crossing."""
    for _ in range(READS):
        end_s = _read_end(centerline, end_s, view, geometry)
        if end_s is None:
            return None
    return end_s


def _read_end(centerline: Centerline, end_s: float, view: CameraView, geometry: TubeGeometry) -> float | None:
    """One reading of _camera_end about end_s."""
    radius, k = geometry.outer_radius, view.intrinsics
    seen = stations_in_view(centerline, np.array([end_s]), view, radius)
    if not seen.in_front[0]:
        return None
    heading, sight = seen.heading[0], seen.sight[0]
    sine = float(np.linalg.norm(np.cross(heading, sight)))
    if sine <= math.cos(LEAST_CROSSING):
        return None
    pixel, half_width, along = seen.pixel[0], float(seen.half_width[0]), seen.image_heading[0]  # along: px per m of s
    px_per_m = float(np.linalg.norm(along))
    direction = along / px_per_m
    sideways = np.array([-direction[1], direction[0]])
    reach = radius * abs(float(heading @ sight)) / sine * px_per_m  # the rim's outline past the centre (px)
    offsets = np.array(LATERAL_OFFSETS)
    starts = pixel + np.outer(offsets * half_width, sideways)
    expected = reach * np.sqrt(1.0 - offsets**2)
    reaches = expected.max() + SEARCH_PX + BACKGROUND_PX[1] + 1.0  # how far a profile reads (and interpolates)
    if np.any(starts < reaches) or np.any(starts > np.array([k.width, k.height]) - 1.0 - reaches):
        return None
    crossings, _ = limb_crossings(view.color, starts, np.tile(direction, (len(offsets), 1)),
                                  np.maximum(expected, 0.0))
    found = crossings[:, 1] - expected  # the far crossing: past the end, into the background
    if not np.any(np.isfinite(found)):
        return None
    return end_s + float(np.nanmedian(found)) / px_per_m
