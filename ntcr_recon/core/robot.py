"""The parametric notched tubular continuum robot (NTCR): its geometry and its bent shape.

Kinematics of asymmetric-notch wrists (York et al. 2015; Swaney et al. 2017). A notch cut to depth g
from the outer surface leaves a backbone whose cross-section is the part of the annulus on the far side
of the chord at distance d = g - r_o from the axis. The backbone's neutral axis sits at ybar from the
tube's axis (away from the notches). A notch bends as a constant-curvature arc whose neutral axis keeps
its length h; the tube's geometric centreline therefore has arc length s = h / (1 + ybar kappa) and
turns by theta = kappa s. Spines (the uncut tube between notches) stay straight. A notch closes when
its two cut faces touch on the outer surface, at theta_max = h / (r_o + ybar).

Frames: the robot base pose (``base_position``, ``base_orientation``) is given in the base frame and
its +z is the robot's axis. Along the centreline the moving frame has x towards the notch side, y = z
cross x and z the tangent; the robot bends towards its notches (about the frame's y axis).

Units: metres and radians throughout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.transforms import quaternion_to_matrix

# Surface parts of a sampled robot (SurfaceSample.part).
PART_OUTER_WALL = 0
PART_INNER_WALL = 1  # the bore; seen through the notches and at the tip
PART_NOTCH_FLOOR = 2  # the cut plane of the backbone at the bottom of a notch
PART_CUT_FACE = 3  # the spines' faces that bound a notch
PART_END_CAP = 4  # the annular ends of the tube (base and tip)

# Sample spacing of the dense surface that surface_distance measures against.
DISTANCE_SAMPLE_SPACING = 0.04e-3


def _segment_area_and_centroid(radius: float, chord_offset: float) -> tuple[float, float, float]:
    """Angle phi, area and centroid distance of the circular segment beyond a chord at chord_offset.

    The segment is the part of the disc on the far side (from the notches) of the chord x = -d, i.e.
    phi = 2 acos(d / r), A = r^2 (phi - sin phi) / 2, ybar = 4 r sin^3(phi / 2) / (3 (phi - sin phi)).
    A chord that misses the disc leaves all of it (phi = 2 pi) or none of it (phi = 0).
    """
    phi = 2.0 * math.acos(min(1.0, max(-1.0, chord_offset / radius)))
    area = radius**2 * (phi - math.sin(phi)) / 2.0
    if phi - math.sin(phi) <= 0.0:
        return phi, 0.0, 0.0
    centroid = 4.0 * radius * math.sin(phi / 2.0) ** 3 / (3.0 * (phi - math.sin(phi)))
    return phi, area, centroid


@dataclass(frozen=True)
class TubeGeometry:
    """The robot description (the rig configuration's ``robot`` section); metres and radians."""

    outer_diameter: float = 3.5e-3
    inner_diameter: float = 2.5e-3
    notch_count: int = 16
    notch_width: float = 1.5e-3  # h: along the axis, undeformed
    notch_pitch: float = 3.0e-3  # centre to centre
    notch_depth: float | None = None  # g: cut depth from the outer surface; None -> 0.7 * outer_diameter
    notch_side: float = 0.0  # angle about the axis of the direction the notches open to, +x towards +y
    proximal_length: float = 5.0e-3  # base to the first notch's proximal edge
    distal_length: float = 1.5e-3  # last notch's distal edge to the tip
    base_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)  # x, y, z, w

    def __post_init__(self) -> None:
        # Lists from YAML/JSON become tuples so the dataclass stays hashable and immutable.
        object.__setattr__(self, "base_position", tuple(float(v) for v in self.base_position))
        object.__setattr__(self, "base_orientation", tuple(float(v) for v in self.base_orientation))

    # ----------------------------------------------------------------------------------- validation
    def validate(self) -> None:
        """Raise ValueError naming the field when the description is not a buildable robot."""
        for name in ("outer_diameter", "inner_diameter", "notch_width", "notch_pitch", "notch_side",
                     "proximal_length", "distal_length"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"robot.{name} must be a finite number, got {value!r}")
        if isinstance(self.notch_count, bool) or not isinstance(self.notch_count, int):
            raise ValueError(f"robot.notch_count must be an integer, got {self.notch_count!r}")
        if self.notch_count < 1:
            raise ValueError(f"robot.notch_count must be >= 1, got {self.notch_count}")
        if self.outer_diameter <= 0:
            raise ValueError(f"robot.outer_diameter must be > 0, got {self.outer_diameter}")
        if not 0 < self.inner_diameter < self.outer_diameter:
            raise ValueError(
                f"robot.inner_diameter must be > 0 and < outer_diameter ({self.outer_diameter}), "
                f"got {self.inner_diameter}")
        if self.notch_width <= 0:
            raise ValueError(f"robot.notch_width must be > 0, got {self.notch_width}")
        if self.notch_pitch <= self.notch_width:
            raise ValueError(
                f"robot.notch_pitch ({self.notch_pitch}) must exceed robot.notch_width ({self.notch_width}): "
                "the notches would overlap")
        if self.notch_depth is not None:
            g = self.notch_depth
            if isinstance(g, bool) or not isinstance(g, int | float) or not math.isfinite(g):
                raise ValueError(f"robot.notch_depth must be a finite number or null, got {g!r}")
            if g <= 0:
                raise ValueError(f"robot.notch_depth must be > 0, got {g}")
            if g >= self.outer_diameter:
                raise ValueError(
                    f"robot.notch_depth ({g}) must be less than robot.outer_diameter ({self.outer_diameter}): "
                    "the cut would sever the tube")
        if self.proximal_length < 0:
            raise ValueError(f"robot.proximal_length must be >= 0, got {self.proximal_length}")
        if self.distal_length < 0:
            raise ValueError(f"robot.distal_length must be >= 0, got {self.distal_length}")
        if len(self.base_position) != 3 or not all(math.isfinite(v) for v in self.base_position):
            raise ValueError(f"robot.base_position must be 3 finite numbers, got {self.base_position!r}")
        try:
            quaternion_to_matrix(self.base_orientation)
        except ValueError as error:
            raise ValueError(f"robot.base_orientation: {error}") from None

    @classmethod
    def from_mapping(cls, mapping: Mapping) -> TubeGeometry:
        """Build from a mapping whose keys are field names; refuses unknown keys and bad values."""
        if not isinstance(mapping, Mapping):
            raise ValueError(f"robot must be a mapping of geometry fields, got {type(mapping).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(mapping) - known)
        if unknown:
            raise ValueError(f"robot.{unknown[0]} is not a robot geometry field (known: {', '.join(sorted(known))})")
        values = dict(mapping)
        for name in ("base_position", "base_orientation"):
            if name in values:
                value = values[name]
                if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
                    raise ValueError(f"robot.{name} must be a list of numbers, got {value!r}")
                try:
                    values[name] = tuple(float(v) for v in value)
                except (TypeError, ValueError):
                    raise ValueError(f"robot.{name} must be a list of numbers, got {value!r}") from None
        for name, value in values.items():
            if name in ("base_position", "base_orientation", "notch_count") or value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"robot.{name} must be a number, got {value!r}")
            values[name] = float(value)
        if "notch_count" in values:
            count = values["notch_count"]
            if isinstance(count, float) and count.is_integer():
                count = int(count)
            values["notch_count"] = count
        geometry = cls(**values)
        geometry.validate()
        return geometry

    def to_dict(self) -> dict:
        """The fields as plain JSON/YAML values (tuples as lists)."""
        result = {}
        for f in fields(self):
            value = getattr(self, f.name)
            result[f.name] = list(value) if isinstance(value, tuple) else value
        return result

    # -------------------------------------------------------------------------------------- derived
    @property
    def outer_radius(self) -> float:
        return self.outer_diameter / 2.0

    @property
    def inner_radius(self) -> float:
        return self.inner_diameter / 2.0

    @property
    def cut_depth(self) -> float:
        """g, with the default (70 % of the outer diameter) resolved."""
        return 0.7 * self.outer_diameter if self.notch_depth is None else float(self.notch_depth)

    @property
    def chord_offset(self) -> float:
        """d = g - r_o: the cut plane lies at x = -d in the notch-side frame."""
        return self.cut_depth - self.outer_radius

    @property
    def length(self) -> float:
        """Undeformed length, base to tip."""
        return (self.proximal_length + (self.notch_count - 1) * self.notch_pitch + self.notch_width
                + self.distal_length)

    @property
    def notch_centers_s(self) -> np.ndarray:
        """Undeformed arc length of each notch's centre."""
        return self.proximal_length + self.notch_width / 2.0 + self.notch_pitch * np.arange(self.notch_count)

    @property
    def neutral_axis_offset(self) -> float:
        """ybar: distance from the tube axis to the backbone's neutral axis (away from the notches)."""
        d = self.chord_offset
        _, area_o, ybar_o = _segment_area_and_centroid(self.outer_radius, d)
        _, area_i, ybar_i = _segment_area_and_centroid(self.inner_radius, d)
        return (ybar_o * area_o - ybar_i * area_i) / (area_o - area_i)

    @property
    def max_notch_bend(self) -> float:
        """theta_max = h / (r_o + ybar): the bend at which a notch's faces meet on the outer surface."""
        return self.notch_width / (self.outer_radius + self.neutral_axis_offset)

    @property
    def gap_half_angle(self) -> float:
        """Half the angle about the axis over which a notch is open on the outer surface: acos(-d / r_o)."""
        return math.acos(-self.chord_offset / self.outer_radius)

    @cached_property
    def base_rotation(self) -> np.ndarray:
        """Rotation of the robot base pose (its +z = the robot's axis) in the base frame (computed once: every
        frame asks; read-only, as it is shared)."""
        rotation = quaternion_to_matrix(self.base_orientation)
        rotation.flags.writeable = False
        return rotation


@dataclass
class SurfaceSample:
    """A dense sample of the true surface; base frame."""

    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3) unit, outward from the material
    part: np.ndarray  # (N,) PART_* code
    s: np.ndarray  # (N,) centreline arc length of the cross-section the point belongs to
    angle: np.ndarray  # (N,) angle about the axis from the notch side (radians, -pi..pi)
    radius: np.ndarray  # (N,) distance from the centreline in the cross-section plane


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
        self._seg_length = np.array(lengths)
        self._seg_kappa = np.array(curvatures)
        self._seg_start = np.concatenate([[0.0], np.cumsum(self._seg_length)[:-1]])
        self.length = float(np.sum(self._seg_length))
        notch_side = np.array([[math.cos(g.notch_side), -math.sin(g.notch_side), 0.0],
                               [math.sin(g.notch_side), math.cos(g.notch_side), 0.0],
                               [0.0, 0.0, 1.0]])
        position = np.asarray(g.base_position, dtype=float)
        rotation = g.base_rotation @ notch_side
        starts_p, starts_r = [], []
        for length, kappa in zip(self._seg_length, self._seg_kappa, strict=True):
            starts_p.append(position)
            starts_r.append(rotation)
            offset, turn = _arc(np.array([length]), np.array([kappa]))
            position = position + rotation @ offset[0]
            rotation = rotation @ turn[0]
        self._seg_position = np.array(starts_p)
        self._seg_rotation = np.array(starts_r)

    def centerline(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) and frames (N, 3, 3) at centreline arc lengths s (0 = base, length = tip).

        Frame columns: x towards the notch side, y = z cross x, z = tangent; all in the base frame.
        """
        s = np.atleast_1d(np.asarray(s, dtype=float))
        tolerance = 1e-9
        if s.size and (s.min() < -tolerance or s.max() > self.length + tolerance):
            raise ValueError(f"arc length outside the robot [0, {self.length:.6g}] m: {s.min():.6g}..{s.max():.6g}")
        s = np.clip(s, 0.0, self.length)
        index = np.clip(np.searchsorted(self._seg_start, s, side="right") - 1, 0, len(self._seg_start) - 1)
        offset, turn = _arc(s - self._seg_start[index], self._seg_kappa[index])
        start_rotation = self._seg_rotation[index]
        positions = self._seg_position[index] + np.einsum("nij,nj->ni", start_rotation, offset)
        return positions, start_rotation @ turn

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
        starts = self._seg_start[1::2][: self.geometry.notch_count]
        arcs = self.notch_arc_length
        widths = arcs * (1.0 - self.notch_curvature * r_o)
        return [
            {"index": i, "center_s": float(starts[i] + arcs[i] / 2.0), "width": float(max(widths[i], 0.0)),
             "bend": float(self.notch_bend[i]), "start_s": float(starts[i]), "end_s": float(starts[i] + arcs[i])}
            for i in range(self.geometry.notch_count)
        ]

    # -------------------------------------------------------------------------------------- surface
    def sample_surface_parts(self, spacing: float) -> SurfaceSample:
        """Dense sample of the true surface, at most `spacing` apart, with each point's part and coordinates.

        Spines: outer wall and bore. Notches: the backbone's outer wall and bore (the bore is what one
        sees through the cut), the cut plane between them (notch floor), and the two faces of the
        neighbouring spines that bound the gap. Ends: annular caps at base and tip.
        """
        if not spacing > 0:
            raise ValueError(f"spacing must be > 0, got {spacing}")
        g = self.geometry
        r_o, r_i, d = g.outer_radius, g.inner_radius, g.chord_offset
        pieces: list[tuple] = []  # (s, angle, radius, normal_local (N,3), part)

        def wall(s_values, radius, angle_limit, part, outward):
            # angle_limit: the material spans |angle| >= angle_limit (0: the whole ring)
            span = 2.0 * math.pi - 2.0 * angle_limit
            if span <= 0:
                return
            count = max(int(math.ceil(span * radius / spacing)), 3)
            if angle_limit == 0:
                angles = np.arange(count) * (span / count)
            else:
                angles = angle_limit + np.linspace(0.0, span, count + 1)
            angles = np.angle(np.exp(1j * angles))
            ss, aa = (a.ravel() for a in np.meshgrid(s_values, angles, indexing="ij"))
            sign = 1.0 if outward else -1.0
            normal = sign * np.stack([np.cos(aa), np.sin(aa), np.zeros_like(aa)], axis=1)
            pieces.append((ss, aa, np.full(ss.shape, radius), normal, part))

        def annulus(s_value, normal_z, only_removed, part):
            # the annular cross-section at s_value; only_removed: the part cut away by a notch (x > -d)
            radii = np.linspace(r_i, r_o, max(int(math.ceil((r_o - r_i) / spacing)) + 1, 2))
            for radius in radii:
                half = math.acos(min(1.0, max(-1.0, -d / radius))) if only_removed else math.pi
                if half <= 0:
                    continue
                count = 2 * max(int(math.ceil(half * radius / spacing)), 1)  # even: angle 0 is sampled
                angles = np.linspace(-half, half, count + 1) if half < math.pi else np.arange(count) * (2 * math.pi
                                                                                                        / count)
                angles = np.angle(np.exp(1j * angles))
                normal = np.tile([0.0, 0.0, normal_z], (angles.size, 1))
                pieces.append((np.full(angles.size, s_value), angles, np.full(angles.size, radius), normal, part))

        def grid(start, length, stretch, closed):
            count = max(int(math.ceil(length * stretch / spacing)), 1)
            return start + np.linspace(0.0, length, count + 1)[: None if closed else -1]

        outer_limit = g.gap_half_angle
        inner_limit = math.acos(min(1.0, max(-1.0, -d / r_i)))
        last = len(self._seg_start) - 1
        for k, (start, length, kappa) in enumerate(zip(self._seg_start, self._seg_length, self._seg_kappa,
                                                       strict=True)):
            if length <= 0:
                continue
            is_notch = k % 2 == 1
            s_values = grid(start, length, 1.0 + kappa * r_o, closed=k == last)
            if not is_notch:
                wall(s_values, r_o, 0.0, PART_OUTER_WALL, True)
                wall(s_values, r_i, 0.0, PART_INNER_WALL, False)
                continue
            wall(s_values, r_o, outer_limit, PART_OUTER_WALL, True)
            wall(s_values, r_i, inner_limit, PART_INNER_WALL, False)
            # notch floor: the chord x = -d between the outer circle and the bore
            half_o = math.sqrt(max(r_o**2 - d**2, 0.0))
            half_i = math.sqrt(max(r_i**2 - d**2, 0.0)) if abs(d) < r_i else 0.0
            count = max(int(math.ceil((half_o - half_i) / spacing)), 1)
            ys = np.linspace(half_i, half_o, count + 1)
            ys = np.concatenate([-ys[::-1], ys]) if half_i > 0 else np.linspace(-half_o, half_o, 2 * count + 1)
            ss, yy = (a.ravel() for a in np.meshgrid(s_values, ys, indexing="ij"))
            xx = np.full(ss.shape, -d)
            normal = np.tile([1.0, 0.0, 0.0], (ss.size, 1))
            pieces.append((ss, np.arctan2(yy, xx), np.hypot(xx, yy), normal, PART_NOTCH_FLOOR))
            annulus(start, 1.0, True, PART_CUT_FACE)
            annulus(start + length, -1.0, True, PART_CUT_FACE)
        annulus(0.0, -1.0, False, PART_END_CAP)
        annulus(self.length, 1.0, False, PART_END_CAP)

        s = np.concatenate([p[0] for p in pieces])
        angle = np.concatenate([p[1] for p in pieces])
        radius = np.concatenate([p[2] for p in pieces])
        normal_local = np.concatenate([p[3] for p in pieces])
        part = np.concatenate([np.full(p[0].size, p[4], dtype=np.uint8) for p in pieces])
        centre, frame = self.centerline(s)
        local = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(s)], axis=1)
        points = centre + np.einsum("nij,nj->ni", frame, local)
        normals = np.einsum("nij,nj->ni", frame, normal_local)
        return SurfaceSample(points, normals, part, s, angle, radius)

    def sample_surface(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (N, 3) and outward unit normals (N, 3) of the true surface, at most `spacing` apart."""
        sample = self.sample_surface_parts(spacing)
        return sample.points, sample.normals

    @cached_property
    def _distance_index(self) -> tuple[cKDTree, np.ndarray, np.ndarray]:
        points, normals = self.sample_surface(DISTANCE_SAMPLE_SPACING)
        return cKDTree(points), points, normals

    def surface_distance(self, points) -> np.ndarray:
        """Unsigned distance of each point (N, 3) to the true surface.

        Over the k nearest samples of a dense surface sample: the distance to a sample's tangent plane
        when the point lies over that sample (so the result does not carry the sampling step), else the
        distance to the sample itself (beyond an edge). Accurate to about a micrometre.
        """
        query = np.asarray(points, dtype=float).reshape(-1, 3)
        tree, samples, normals = self._distance_index
        _, nearest = tree.query(query, k=8, workers=-1)
        delta = query[:, None, :] - samples[nearest]
        along_normal = np.abs(np.einsum("nkj,nkj->nk", delta, normals[nearest]))
        squared = np.einsum("nkj,nkj->nk", delta, delta)
        lateral = np.sqrt(np.maximum(squared - along_normal**2, 0.0))
        distance = np.where(lateral <= DISTANCE_SAMPLE_SPACING, along_normal, np.sqrt(squared))
        return distance.min(axis=1)


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
