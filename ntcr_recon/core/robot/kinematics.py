"""How the notched tube bends: asymmetric-notch kinematics from per-notch bends to the centreline and tip.

Kinematics of asymmetric-notch wrists (York et al. 2015; Swaney et al. 2017). A notch bends as a
constant-curvature arc whose neutral axis (at ybar from the tube's axis, `TubeGeometry.neutral_axis_offset`) keeps
its length h; the tube's geometric centreline therefore has arc length s = h / (1 + ybar kappa) and turns by
theta = kappa s. Spines (the uncut tube between notches) stay straight. A notch closes when its two cut faces
touch on the outer surface, at theta_max = h / (r_o + ybar).

Along the centreline the moving frame has x towards the notch side, y = z cross x and z the tangent; the robot
bends towards its notches (about the frame's y axis). Units: metres and radians.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from ntcr_recon.core.robot import surface
from ntcr_recon.core.robot.geometry import TubeGeometry


class TubeShape:
    """A posed robot: per-notch bends on a TubeGeometry."""

    def __init__(self, geometry: TubeGeometry, notch_bend) -> None:
        geometry.validate()
        bends = np.asarray(notch_bend, dtype=float)
        if bends.shape != (geometry.notch_count,):
            raise ValueError(f"notch_bend needs {geometry.notch_count} values (one per notch), got shape {bends.shape}")
        if not np.all(np.isfinite(bends)):
            raise ValueError("notch_bend must be finite")
        theta_max = geometry.max_notch_bend
        worst = int(np.argmax(np.abs(bends)))
        if bends[worst] < 0:
            raise ValueError(
                f"notch {worst} bend {math.degrees(bends[worst]):.3f} deg is negative: a notch only bends towards "
                "its open side")
        if bends[worst] > theta_max * (1 + 1e-9):
            raise ValueError(
                f"notch {worst} bend {math.degrees(bends[worst]):.3f} deg exceeds the notch's closing angle "
                f"theta_max = h / (r_o + ybar) = {math.degrees(theta_max):.3f} deg "
                f"(total at most {math.degrees(theta_max * geometry.notch_count):.1f} deg)")
        self.geometry = geometry
        self.notch_bend = np.minimum(bends, theta_max)
        self.notch_bend.setflags(write=False)
        self._build_segments()

    # --------------------------------------------------------------------------------- constructors
    @classmethod
    def straight(cls, geometry: TubeGeometry) -> TubeShape:
        return cls(geometry, np.zeros(geometry.notch_count))

    @classmethod
    def from_bend_angle(cls, geometry: TubeGeometry, total_rad: float) -> TubeShape:
        """Uniform bending: every notch bends total_rad / notch_count."""
        geometry.validate()
        return cls(geometry, np.full(geometry.notch_count, float(total_rad) / geometry.notch_count))

    @classmethod
    def from_tendon_pull(cls, geometry: TubeGeometry, dl_per_notch) -> TubeShape:
        """Tendon displacement per notch (scalar: the same for every notch, or one per notch).

        kappa = dl / (h (r_i + ybar) - dl ybar) and theta = kappa h / (1 + ybar kappa), which
        simplifies to theta = dl / (r_i + ybar).
        """
        geometry.validate()
        dl = np.broadcast_to(np.asarray(dl_per_notch, dtype=float), (geometry.notch_count,))
        h, ybar, r_i = geometry.notch_width, geometry.neutral_axis_offset, geometry.inner_radius
        kappa = dl / (h * (r_i + ybar) - dl * ybar)
        if np.any(kappa < 0) or np.any(~np.isfinite(kappa)):
            raise ValueError(f"tendon pull per notch must be >= 0 and below h (r_i + ybar) / ybar, got {dl_per_notch}")
        return cls(geometry, kappa * h / (1.0 + ybar * kappa))

    @classmethod
    def from_notch_bends(cls, geometry: TubeGeometry, bends) -> TubeShape:
        return cls(geometry, bends)

    # ------------------------------------------------------------------------------------ kinematics
    @property
    def notch_curvature(self) -> np.ndarray:
        """kappa of each notch's centreline: theta = kappa h / (1 + ybar kappa) solved for kappa."""
        h, ybar = self.geometry.notch_width, self.geometry.neutral_axis_offset
        return self.notch_bend / (h - ybar * self.notch_bend)

    @property
    def notch_arc_length(self) -> np.ndarray:
        """s of each notch's centreline: h / (1 + ybar kappa) = h - ybar theta."""
        return self.geometry.notch_width - self.geometry.neutral_axis_offset * self.notch_bend

    @property
    def tendon_pull(self) -> np.ndarray:
        """Tendon displacement of each notch, dl = theta (r_i + ybar)."""
        return self.notch_bend * (self.geometry.inner_radius + self.geometry.neutral_axis_offset)

    def _build_segments(self) -> None:
        """Chain straight spines and constant-curvature notch arcs into a segment table."""
        g = self.geometry
        spine = g.notch_pitch - g.notch_width
        lengths, curvatures = [g.proximal_length], [0.0]
        for i, (arc, kappa) in enumerate(zip(self.notch_arc_length, self.notch_curvature, strict=True)):
            lengths.append(float(arc))
            curvatures.append(float(kappa))
            lengths.append(spine if i < g.notch_count - 1 else g.distal_length)
            curvatures.append(0.0)
        self.segment_lengths = np.array(lengths)
        self.segment_curvatures = np.array(curvatures)
        self.segment_starts = np.concatenate([[0.0], np.cumsum(self.segment_lengths)[:-1]])
        self.length = float(np.sum(self.segment_lengths))
        notch_side = np.array([[math.cos(g.notch_side), -math.sin(g.notch_side), 0.0],
                               [math.sin(g.notch_side), math.cos(g.notch_side), 0.0],
                               [0.0, 0.0, 1.0]])
        position = np.asarray(g.base_position, dtype=float)
        rotation = g.base_rotation @ notch_side
        starts_p, starts_r = [], []
        offsets, turns = _arc(self.segment_lengths, self.segment_curvatures)  # every segment's at once
        for offset, turn in zip(offsets, turns, strict=True):
            starts_p.append(position)
            starts_r.append(rotation)
            position = position + rotation @ offset
            rotation = rotation @ turn
        self._segment_positions = np.array(starts_p)
        self._segment_rotations = np.array(starts_r)

    def centerline(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) and frames (N, 3, 3) at centreline arc lengths s (0 = base, length = tip).

        Frame columns: x towards the notch side, y = z cross x, z = tangent; all in the base frame.
        """
        index, offset, turn = self._along(s)
        start_rotation = self._segment_rotations[index]
        positions = self._segment_positions[index] + np.einsum("nij,nj->ni", start_rotation, offset)
        return positions, start_rotation @ turn

    def centerline_points(self, s) -> np.ndarray:
        """The positions of `centerline` alone (N, 3): a fit that moves the centreline asks for them often."""
        index, offset, _ = self._along(s)
        return self._segment_positions[index] + np.einsum("nij,nj->ni", self._segment_rotations[index], offset)

    def centerline_jacobian(self, s) -> np.ndarray:
        """How the centreline's positions at arc lengths s move with each notch's bend: (N, notch_count, 3), m/rad.

        A notch's bend turns everything distal of it about its bend axis through the notch's end, moves that end
        along its arc, and shortens the arc by ybar per radian (so at a fixed s the point lies further along the
        chain); within the notch only the arc's curvature changes (dkappa/dtheta = h / L^2). Every notch bends about
        the same axis (the robot bends in one plane), so the turn splits into a part per notch and one per point."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.length)
        position, frames = self.centerline(s)
        g = self.geometry
        ybar, segments = g.neutral_axis_offset, 1 + 2 * np.arange(g.notch_count)
        starts, lengths = self.segment_starts[segments], self.segment_lengths[segments]
        rotations, origins = self._segment_rotations[segments], self._segment_positions[segments]
        chord, chord_rate = (np.array(v) for v in zip(*(_unit_arc_chord(t) for t in self.notch_bend), strict=True))
        ends = origins + np.einsum("kij,kj->ki", rotations, lengths[:, None] * chord)
        end_rate = np.einsum("kij,kj->ki", rotations, lengths[:, None] * chord_rate - ybar * chord)
        axis = rotations[0][:, 1]
        per_notch = end_rate - np.cross(axis, ends)
        per_point = np.cross(axis, position) + ybar * frames[:, :, 2]
        distal = s[:, None] >= (starts + lengths)[None, :]
        jacobian = np.where(distal[:, :, None], per_notch[None, :, :] + per_point[:, None, :], 0.0)
        notch = np.searchsorted(starts, s, side="right") - 1
        inside = np.flatnonzero((notch >= 0) & (s < starts[notch] + lengths[notch]))
        if len(inside):
            k = notch[inside]
            rate = _arc_curvature_rate(s[inside] - starts[k], self.notch_curvature[k])
            curvature_rate = g.notch_width / lengths[k] ** 2
            jacobian[inside, k] = np.einsum("nij,nj->ni", rotations[k], rate) * curvature_rate[:, None]
        return jacobian

    def _along(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per arc length (checked to lie on the robot): its segment, and the offset and turn within it."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        tolerance = 1e-9
        if s.size and (s.min() < -tolerance or s.max() > self.length + tolerance):
            raise ValueError(f"arc length outside the robot [0, {self.length:.6g}] m: {s.min():.6g}..{s.max():.6g}")
        s = np.clip(s, 0.0, self.length)
        index = np.clip(np.searchsorted(self.segment_starts, s, side="right") - 1, 0, len(self.segment_starts) - 1)
        offset, turn = _arc(s - self.segment_starts[index], self.segment_curvatures[index])
        return index, offset, turn

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Tip position (3,) and frame (3, 3)."""
        position, frame = self.centerline(np.array([self.length]))
        return position[0], frame[0]

    def notch_table(self) -> list[dict]:
        """Per notch, deformed: index, center_s, width (outer-surface gap facing the notches), bend, start_s, end_s.

        width = s_n (1 - kappa r_o): the arc between the two cut faces along the outer surface line at
        angle 0 about the axis; it is h on a straight robot and 0 at theta_max.
        """
        r_o = self.geometry.outer_radius
        starts = self.segment_starts[1::2][: self.geometry.notch_count]
        arcs = self.notch_arc_length
        widths = arcs * (1.0 - self.notch_curvature * r_o)
        return [
            {"index": i, "center_s": float(starts[i] + arcs[i] / 2.0), "width": float(max(widths[i], 0.0)),
             "bend": float(self.notch_bend[i]), "start_s": float(starts[i]), "end_s": float(starts[i] + arcs[i])}
            for i in range(self.geometry.notch_count)
        ]

    # -------------------------------------------------------------------------------------- surface
    def sample_surface_parts(self, spacing: float) -> surface.SurfaceSample:
        """Dense sample of the true surface, at most `spacing` apart (surface.sample_surface_parts)."""
        return surface.sample_surface_parts(self, spacing)

    def sample_surface(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (N, 3) and outward unit normals (N, 3) of the true surface, at most `spacing` apart."""
        sample = self.sample_surface_parts(spacing)
        return sample.points, sample.normals

    @cached_property
    def _surface_distance(self) -> surface.SurfaceDistance:
        return surface.SurfaceDistance(self)

    def surface_distance(self, points) -> np.ndarray:
        """Unsigned distance of each point (N, 3) to the true surface (surface.SurfaceDistance)."""
        return self._surface_distance(points)


def _arc(length: np.ndarray, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (N, 3) and rotations (N, 3, 3) of constant-curvature arcs bending towards local +x."""
    theta = kappa * length
    small = np.abs(theta) < 1e-8
    safe_kappa = np.where(small, 1.0, kappa)
    x = np.where(small, kappa * length**2 / 2.0, (1.0 - np.cos(theta)) / safe_kappa)
    z = np.where(small, length, np.sin(theta) / safe_kappa)
    offset = np.stack([x, np.zeros_like(x), z], axis=1)
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.zeros((theta.size, 3, 3))
    rotation[:, 0, 0] = c
    rotation[:, 0, 2] = s
    rotation[:, 1, 1] = 1.0
    rotation[:, 2, 0] = -s
    rotation[:, 2, 2] = c
    return offset, rotation


def _unit_arc_chord(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """The chord of an arc of unit length turning by theta towards local +x, (1 - cos) / theta and sin / theta,
    and its derivative by theta (series near straight)."""
    if abs(theta) < 1e-4:
        return (np.array([theta / 2.0, 0.0, 1.0 - theta**2 / 6.0]),
                np.array([0.5 - theta**2 / 8.0, 0.0, -theta / 3.0]))
    c, s = math.cos(theta), math.sin(theta)
    return (np.array([(1.0 - c) / theta, 0.0, s / theta]),
            np.array([(theta * s - 1.0 + c) / theta**2, 0.0, (theta * c - s) / theta**2]))


def _arc_curvature_rate(u: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """d offset / d kappa (N, 3) of points u along constant-curvature arcs (each its kappa) bending towards local
    +x (series near straight)."""
    ku = kappa * u
    small = np.abs(ku) < 1e-4
    safe = np.where(small, 1.0, kappa)
    x = np.where(small, u**2 / 2.0, (ku * np.sin(ku) - 1.0 + np.cos(ku)) / safe**2)
    z = np.where(small, -kappa * u**3 / 3.0, (ku * np.cos(ku) - np.sin(ku)) / safe**2)
    return np.stack([x, np.zeros_like(u), z], axis=1)
