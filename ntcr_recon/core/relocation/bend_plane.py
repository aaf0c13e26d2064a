"""The axis held to the plane the robot's notches bend it in, at the roll its samples show (its kinematics).

A notched tube bends about its notches' backbone only: its centreline stays in the plane through the base's axis
and the side its notches open to (robot.notch_side, the roll the rig file gives it in its clamp). What the cameras
place worst is along their lines of sight - two opposed cameras' depth biases differ by a tenth of a millimetre
on a shiny tube, and a rig file's pose along a view is known no better - and seen side on, that is just off the
plane. So the axis is moved onto the plane along its normal: its shape in the plane stays the data's (the limbs
and the walls place it), what lies off the plane is taken for depth's error, reported (`BendPlane.off_plane`).

The roll: the configured one (known to robot.roll_tolerance, one standard deviation), unless the axis's samples (one
per notch pitch, up to the end seen) show another beyond ROLL_SIGMAS of that and of their own uncertainty - the
robot turned in its clamp - whose plane is then taken, and the result says so; a robot bent less than its outer
radius away from its base's axis (RMS over the samples) shows no plane beyond its axis's own errors. The samples'
roll: their part off the configured plane regressed on their part in it (a plane turned by a puts a sample l across
it l tan(a) off; depth's error lies off the plane seen side on, and a sample's place in it is known to a hundredth
of its extent).

The roll the samples show, taken or not (`BendPlane.shown`), measures the robot's roll in its clamp as the notches'
edges do, and far more sharply on a bent robot (a tenth of a degree against ten): the side those measure is weighed
with it, and one it rules out is not taken (reconstruction.relocation_steps.notches_and_side).

    plane = held_to_bend_plane(centerline, geometry, end_s)   # BendPlane; None: robot.roll_tolerance null
    off = base_offset(centerline, seen_s, geometry)   # m, the axis off the base's at the clamp; None: unseen
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline, base_pose
from ntcr_recon.core.robot.geometry import TubeGeometry

# A roll the samples show beyond this many standard deviations of (the prior's and their own) is the robot's.
ROLL_SIGMAS = 3.0


@dataclass(frozen=True)
class BendPlane:
    """The axis held to the bend plane, the plane's roll off robot.notch_side (rad) and its standard deviation,
    whether the samples' own roll was taken (beyond the prior), and how far off the plane the axis lay (m, RMS of
    the samples: what was taken for depth's error and removed)."""

    centerline: Centerline
    roll: float
    roll_sd: float
    roll_measured: bool
    off_plane: float
    # what the hold leaves of an error along the cameras' views (RMS over them and the samples of |v x n|, v a view
    # across the tube, n the plane's normal: 0 seen square to the plane, 1 seen along it), and how far off the plane
    # itself may lie (m, RMS over the samples: its roll's SD times their distance from the base's axis)
    along_views_kept: float = 1.0
    plane_uncertainty: float = 0.0
    # the roll the samples show whether taken or not, and its SD (rad; one sample's scatter per sample, as a taken
    # roll's); None where the robot is bent too little to show a plane
    shown: tuple[float, float] | None = None

    def rules_out(self, roll: float, sd: float) -> bool:
        """Whether the robot's bend rules out a roll off robot.notch_side (rad, measured to `sd`) as its roll in
        its clamp: it lies beyond ROLL_SIGMAS of theirs combined from the roll its plane shows (a plane: modulo a
        half turn)."""
        if self.shown is None:
            return False
        shown, shown_sd = self.shown
        return abs(math.remainder(roll - shown, math.pi)) > ROLL_SIGMAS * math.hypot(sd, shown_sd)

    def weighed_with(self, roll: float, sd: float) -> tuple[float, float]:
        """A roll off robot.notch_side measured otherwise (rad, to `sd`: the notches' edges) weighed with the one
        the plane shows, by their variances; as it was where the robot shows no plane."""
        if self.shown is None:
            return roll, sd
        shown, shown_sd = self.shown
        shown = roll + math.remainder(shown - roll, math.pi)  # the plane's nearer way round
        weight = sd**2 / (sd**2 + shown_sd**2)
        return roll + weight * (shown - roll), sd * shown_sd / math.hypot(sd, shown_sd)

    def figures(self) -> dict:
        """The result's quality.bend_plane: the roll (deg) off the configured side, its SD, and the off-plane RMS
        removed (mm)."""
        return {"roll_deg": round(math.degrees(self.roll), 3), "roll_sd_deg": round(math.degrees(self.roll_sd), 3),
                "roll_measured": self.roll_measured, "off_plane_mm": round(self.off_plane * 1e3, 4)}


def held_to_bend_plane(centerline: Centerline, geometry: TubeGeometry, end_s: float,
                       origins: np.ndarray | None = None) -> BendPlane | None:
    """The centreline moved onto the robot's bend plane at the roll its samples up to `end_s` show (see the module
    docstring), and with the cameras' optical centres (`origins`, (C, 3)) what that leaves of an error along their
    views; None where robot.roll_tolerance is null or fewer than three samples lie before the end."""
    tolerance = geometry.roll_tolerance
    s = np.arange(0.5 * geometry.notch_pitch, min(end_s, centerline.length), geometry.notch_pitch)
    if tolerance is None or len(s) < 3:
        return None
    base, axis, binormal = (np.asarray(v, float) for v in base_pose(geometry))
    side = np.cross(binormal, axis)
    samples, tangents = centerline.frames_at(s)[:2]
    relative = samples - base
    lateral, off = relative @ side, relative @ binormal
    spread = max(float(lateral @ lateral), 1e-18)
    # the samples' own roll: their part off the configured plane regressed on their part in it (a turned plane puts
    # a sample lateral l off it by l tan(roll)); what depth gets wrong lies off the plane, seen side on
    own = float(off @ lateral) / spread
    scatter2 = max(float(np.sum((off - own * lateral) ** 2)) / (len(s) - 1), 1e-12)  # per sample (m^2)
    own_sd = math.sqrt(scatter2 / spread)
    # (a robot bent less than its radius away from its base's axis shows no plane: its axis's errors would)
    bent = spread > len(s) * geometry.outer_radius**2
    roll_measured = bent and abs(own) > ROLL_SIGMAS * math.hypot(math.tan(tolerance), own_sd)
    # within that, the configured roll: depth's error runs smoothly along the tube, so the samples' scatter about
    # their own plane says too little of how far that plane is off (a 0.1 mm wiggle turns it 0.3 deg)
    # (and a roll taken from the samples is known no better than one sample's scatter tells, for the same reason)
    slope, slope_sd = ((own, own_sd * math.sqrt(len(s))) if roll_measured else (0.0, math.tan(tolerance)))
    roll = math.atan(slope)
    normal = -math.sin(roll) * side + math.cos(roll) * binormal
    off_plane = float(np.sqrt(np.mean((relative @ normal) ** 2)))
    points = centerline.points - np.outer((centerline.points - base) @ normal, normal)
    step = float(np.median(np.diff(centerline.s)))
    kept = 1.0 if origins is None or not len(origins) else _along_views_kept(samples, tangents, origins, normal)
    shown = (math.atan(own), math.atan(own_sd * math.sqrt(len(s)))) if bent else None
    return BendPlane(Centerline.from_points(points, binormal, step), roll, math.atan(slope_sd), roll_measured,
                     off_plane, kept, slope_sd * float(np.sqrt(np.mean(lateral**2))), shown)


def _along_views_kept(samples: np.ndarray, tangents: np.ndarray, origins: np.ndarray, normal: np.ndarray) -> float:
    """RMS over the cameras and the samples of the share of an error along a view (across the tube) that lies in
    the plane of normal `normal`: what holding the axis to that plane leaves of it."""
    views = samples[None, :, :] - np.asarray(origins, float)[:, None, :]
    views -= np.einsum("csk,sk->cs", views, tangents)[..., None] * tangents[None]
    views /= np.maximum(np.linalg.norm(views, axis=2, keepdims=True), 1e-12)
    return float(np.sqrt(np.mean(1.0 - np.einsum("csk,k->cs", views, normal) ** 2)))


def base_offset(centerline: Centerline, seen_s: np.ndarray, geometry: TubeGeometry, minimum_points: int = 10
                ) -> float | None:
    """How far the axis lies off the base's over the proximal segment (m: the length of its mean offset across the
    base's axis, over the samples from the first point seen to half a notch width short of the first notch); None
    where fewer than `minimum_points` points were seen there.

    The base frame is the robot's own (its proximal segment's axis is z: `ntcr-recon calibrate` defines it so), so
    the axis there lies on the base's axis by definition, and how far the fused one lies off it is its error there,
    measured. A camera whose pose in the rig file is off moves its points rigidly, and the fused axis half as far
    all along the tube (its sharpest case: along the camera's view, where nothing else measures it): what the
    proximal offset then shows."""
    end = geometry.proximal_length - geometry.notch_width / 2
    seen = seen_s[seen_s < end]
    if seen.size < minimum_points:
        return None
    inside = (centerline.s >= seen.min()) & (centerline.s <= end)
    if not np.any(inside):
        return None
    position, axis, _ = base_pose(geometry)
    offsets = centerline.points[inside] - position
    offsets -= np.outer(offsets @ axis, axis)
    return float(np.linalg.norm(offsets.mean(axis=0)))
