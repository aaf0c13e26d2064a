"""The centreline as a curve: arc-length samples with untwisted frames (normal towards the notch side), points
projected onto it as tube coordinates (arc length s and offset in the normal plane), its bend between two arc
lengths; and the base pose the rig configures. Estimated from the cloud in centerline_fit."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.robot.geometry import TubeGeometry


def resample_polyline(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths s (uniform, at most `step` apart, from 0 to the length) and the polyline's points there
    (linear between its vertices)."""
    return _resample_kernel(np.ascontiguousarray(points, dtype=float), step)


@jit
def _resample_kernel(points, step):
    """resample_polyline's arc lengths and points."""
    arc = np.zeros(points.shape[0])
    for i in range(1, points.shape[0]):
        d0, d1, d2 = points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1], points[i, 2] - points[i - 1, 2]
        arc[i] = arc[i - 1] + np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    s = np.linspace(0.0, arc[-1], max(int(np.ceil(arc[-1] / step)), 1) + 1)
    resampled = np.empty((len(s), 3))
    for d in range(3):
        resampled[:, d] = np.interp(s, arc, points[:, d])
    return s, resampled


@jit
def _untwisted_frames_kernel(s, points, binormal_hint):
    """Tangents, normals and binormals (M, 3) of a curve sampled at increasing arc lengths s: the tangent by
    second-order differences (np.gradient's, one-sided at the ends; the chord where there are two samples),
    normalised; the binormal the hint made perpendicular to it and normalised; normal = binormal x tangent."""
    count = s.shape[0]
    tangents, normals, binormals = np.empty((count, 3)), np.empty((count, 3)), np.empty((count, 3))
    for i in range(count):
        for d in range(3):
            if count == 2:
                tangents[i, d] = points[1, d] - points[0, d]
            elif i == 0:
                tangents[i, d] = (points[1, d] - points[0, d]) / (s[1] - s[0])
            elif i == count - 1:
                tangents[i, d] = (points[i, d] - points[i - 1, d]) / (s[i] - s[i - 1])
            else:
                before, after = s[i] - s[i - 1], s[i + 1] - s[i]
                tangents[i, d] = (-after / (before * (before + after)) * points[i - 1, d]
                                  + (after - before) / (before * after) * points[i, d]
                                  + before / (after * (before + after)) * points[i + 1, d])
        t0, t1, t2 = tangents[i, 0], tangents[i, 1], tangents[i, 2]
        norm = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / norm, t1 / norm, t2 / norm
        along = t0 * binormal_hint[0] + t1 * binormal_hint[1] + t2 * binormal_hint[2]
        b0, b1, b2 = binormal_hint[0] - along * t0, binormal_hint[1] - along * t1, binormal_hint[2] - along * t2
        norm = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        b0, b1, b2 = b0 / norm, b1 / norm, b2 / norm
        tangents[i, 0], tangents[i, 1], tangents[i, 2] = t0, t1, t2
        binormals[i, 0], binormals[i, 1], binormals[i, 2] = b0, b1, b2
        normals[i, 0], normals[i, 1], normals[i, 2] = b1 * t2 - b2 * t1, b2 * t0 - b0 * t2, b0 * t1 - b1 * t0
    return tangents, normals, binormals


@jit
def _frames_kernel(samples, spacing, length, s, frames):
    """Frames of a centreline at arc lengths s into frames (4, N, 3): position, tangent, normal, binormal.

    samples (M, 9): point, tangent and normal at s = 0, spacing, ..., length. Each is interpolated linearly
    between the two samples around s; the tangent normalised, the normal made perpendicular to it and
    normalised, binormal = tangent x normal; beyond the ends the position goes on along the end tangent.
    """
    last = samples.shape[0] - 2
    for i in range(s.shape[0]):
        clipped = min(max(s[i], 0.0), length)
        position_in_steps = clipped / spacing
        index = max(min(int(position_in_steps), last), 0)
        fraction = position_in_steps - index
        for d in range(3):
            for row in range(3):  # point, tangent, normal
                low = samples[index, 3 * row + d]
                frames[row, i, d] = low + (samples[index + 1, 3 * row + d] - low) * fraction
        t0, t1, t2 = frames[1, i, 0], frames[1, i, 1], frames[1, i, 2]
        norm = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / norm, t1 / norm, t2 / norm
        beyond = s[i] - clipped
        n0, n1, n2 = frames[2, i, 0], frames[2, i, 1], frames[2, i, 2]
        along = n0 * t0 + n1 * t1 + n2 * t2
        n0, n1, n2 = n0 - along * t0, n1 - along * t1, n2 - along * t2
        norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
        frames[0, i, 0] += beyond * t0
        frames[0, i, 1] += beyond * t1
        frames[0, i, 2] += beyond * t2
        frames[1, i, 0], frames[1, i, 1], frames[1, i, 2] = t0, t1, t2
        frames[2, i, 0], frames[2, i, 1], frames[2, i, 2] = n0, n1, n2
        frames[3, i, 0] = t1 * n2 - t2 * n1
        frames[3, i, 1] = t2 * n0 - t0 * n2
        frames[3, i, 2] = t0 * n1 - t1 * n0


@jit
def _project_kernel(samples, spacing, length, xyz, s, frames):
    """Tube coordinates (s, x, y) of points xyz lying near arc lengths s of a centreline (samples as
    _frames_kernel's): the point's offset from the centreline at s, its part along the tangent added to s,
    the rest resolved on normal (x) and binormal (y). frames (4, N, 3) receives the frames at s, the position
    moved along the tangent by that part."""
    _frames_kernel(samples, spacing, length, s, frames)
    count = s.shape[0]
    new_s, x, y = np.empty(count), np.empty(count), np.empty(count)
    for i in range(count):
        t0, t1, t2 = frames[1, i, 0], frames[1, i, 1], frames[1, i, 2]
        o0, o1, o2 = xyz[i, 0] - frames[0, i, 0], xyz[i, 1] - frames[0, i, 1], xyz[i, 2] - frames[0, i, 2]
        correction = o0 * t0 + o1 * t1 + o2 * t2
        o0, o1, o2 = o0 - correction * t0, o1 - correction * t1, o2 - correction * t2
        new_s[i] = s[i] + correction
        x[i] = o0 * frames[2, i, 0] + o1 * frames[2, i, 1] + o2 * frames[2, i, 2]
        y[i] = o0 * frames[3, i, 0] + o1 * frames[3, i, 1] + o2 * frames[3, i, 2]
        frames[0, i, 0] += correction * t0
        frames[0, i, 1] += correction * t1
        frames[0, i, 2] += correction * t2
    return new_s, x, y


# Samples per bounding sphere of the nearest-sample search: about the square root of a centreline's samples
# (a hundred or a few), so that both the spheres and the samples of the few spheres searched are few.
SAMPLES_PER_BOUND = 12


@jit
def _nearest_in_run(points, first, stop, px, py, pz, best, nearest):
    """The nearest of samples first .. stop - 1 to (px, py, pz) and its squared distance, if nearer than
    `best` (squared); else best and nearest as given."""
    for j in range(first, stop):
        dx, dy, dz = px - points[j, 0], py - points[j, 1], pz - points[j, 2]
        squared = dx * dx + dy * dy + dz * dz
        if squared < best:
            best, nearest = squared, j
    return best, nearest


@jit
def _nearest_sample_arc_kernel(points, tangents, s, xyz, per_bound):
    """Arc length of each point xyz from its nearest sample (exact) of a centreline (points, tangents at s):
    that sample's s plus the point's offset from it along its tangent.

    Runs of `per_bound` consecutive samples are bounded by spheres; a run is searched only where its sphere
    comes nearer the point than the nearest sample found so far (first: the run of the previous point's
    nearest sample, a neighbour in a cloud stored in scan order).
    """
    samples = points.shape[0]
    runs = (samples + per_bound - 1) // per_bound
    centre = np.zeros((runs, 3))
    reach = np.zeros(runs)
    for run in range(runs):
        first, stop = run * per_bound, min((run + 1) * per_bound, samples)
        for j in range(first, stop):
            for d in range(3):
                centre[run, d] += points[j, d] / (stop - first)
        for j in range(first, stop):
            dx, dy, dz = points[j, 0] - centre[run, 0], points[j, 1] - centre[run, 1], points[j, 2] - centre[run, 2]
            reach[run] = max(reach[run], np.sqrt(dx * dx + dy * dy + dz * dz))
    arc = np.empty(xyz.shape[0])
    nearest = 0
    for i in range(xyz.shape[0]):
        px, py, pz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        start = nearest // per_bound
        best, nearest = _nearest_in_run(points, start * per_bound, min((start + 1) * per_bound, samples),
                                        px, py, pz, np.inf, 0)
        best_distance = np.sqrt(best)
        for run in range(runs):
            dx, dy, dz = px - centre[run, 0], py - centre[run, 1], pz - centre[run, 2]
            # a run can hold a nearer sample only where its sphere comes within the best distance
            limit = reach[run] + best_distance
            if run != start and dx * dx + dy * dy + dz * dz <= limit * limit:
                best, nearest = _nearest_in_run(points, run * per_bound, min((run + 1) * per_bound, samples),
                                                px, py, pz, best, nearest)
                best_distance = np.sqrt(best)
        arc[i] = s[nearest] + ((px - points[nearest, 0]) * tangents[nearest, 0]
                               + (py - points[nearest, 1]) * tangents[nearest, 1]
                               + (pz - points[nearest, 2]) * tangents[nearest, 2])
    return arc


@jit
def _bend_kernel(samples, spacing, length, s0, s1):
    """Signed angle between the tangents at s0 and s1 of a centreline (samples as _frames_kernel's), positive
    where the tangent at s1 leans towards the normal at s0; an array of length 1 pairs with every s of the
    other."""
    start, end = np.empty((4, s0.shape[0], 3)), np.empty((4, s1.shape[0], 3))
    _frames_kernel(samples, spacing, length, s0, start)
    _frames_kernel(samples, spacing, length, s1, end)
    angle = np.empty(max(s0.shape[0], s1.shape[0]))
    for i in range(angle.shape[0]):
        a, b = min(i, s0.shape[0] - 1), min(i, s1.shape[0] - 1)
        cosine = start[1, a, 0] * end[1, b, 0] + start[1, a, 1] * end[1, b, 1] + start[1, a, 2] * end[1, b, 2]
        towards = end[1, b, 0] * start[2, a, 0] + end[1, b, 1] * start[2, a, 1] + end[1, b, 2] * start[2, a, 2]
        angle[i] = (1.0 if towards >= 0 else -1.0) * np.arccos(min(max(cosine, -1.0), 1.0))
    return angle


@jit
def unit_direction(x, y):
    """(cos, sin) of the angle of (x, y) about the axis, without the trigonometry; (1, 0) on the axis."""
    radius = np.sqrt(x * x + y * y)
    if radius == 0.0:
        return 1.0, 0.0
    return x / radius, y / radius


def cameras_round_tube(frames: tuple, origins: np.ndarray) -> np.ndarray:
    """Each camera's direction from the axis at the frames' positions (Centerline.frames_at), round the tube:
    (K, C, 2) its components on the normal (towards the notch side) and the binormal, not normalised."""
    position, _, normal, binormal = frames
    views = np.asarray(origins, dtype=float)[None, :, :] - position[:, None, :]
    return np.stack([np.einsum("kcj,kj->kc", views, normal), np.einsum("kcj,kj->kc", views, binormal)], axis=-1)


@dataclass(frozen=True)
class TubeCoordinates:
    """Points in the tube's own coordinates: arc length s of their cross-section, offset (x towards the notch
    side, y = tangent x x) in it, radius = |(x, y)| and angle = atan2(y, x) about the axis from the notch side."""

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray

    # cached: several stages ask for them of the same coordinates
    @cached_property
    def radius(self) -> np.ndarray:
        return np.sqrt(self.x * self.x + self.y * self.y)  # np.hypot is 3x slower (overflow-safe)

    @cached_property
    def angle(self) -> np.ndarray:
        return np.arctan2(self.y, self.x)

    def rolled(self, angle: float) -> TubeCoordinates:
        """The same points in a frame turned by `angle` about the tangent (x towards a notch side at `angle`)."""
        c, s = np.cos(angle), np.sin(angle)
        return TubeCoordinates(self.s, c * self.x + s * self.y, c * self.y - s * self.x)


@dataclass(frozen=True)
class Centerline:
    """A centreline sampled uniformly in arc length from the base (s = 0) to the tip (s = length)."""

    s: np.ndarray
    points: np.ndarray
    tangents: np.ndarray
    normals: np.ndarray     # unit, towards the notch side
    binormals: np.ndarray   # tangent x normal

    def __post_init__(self):
        if len(self.s) < 2:
            raise ValueError(f"a centreline needs at least 2 samples, got {len(self.s)}")

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def tip(self) -> np.ndarray:
        return self.points[-1]

    @classmethod
    def from_frames(cls, s: np.ndarray, points: np.ndarray, frames: np.ndarray) -> Centerline:
        """A centreline from samples and their frames (N, 3, 3), columns x towards the notch side (the normal),
        y = z cross x (the binormal), z the tangent: as core.robot.kinematics.TubeShape.centerline and a Path's
        orientations give them."""
        return cls(s, points, frames[:, :, 2], frames[:, :, 0], frames[:, :, 1])

    @classmethod
    def from_points(cls, points: np.ndarray, binormal_hint: np.ndarray, step: float) -> Centerline:
        """Re-sample a polyline at uniform arc-length steps and attach frames.

        The binormal is the hint (the bend plane's normal of a robot bending towards its notches) made
        perpendicular to the tangent, so the frame does not twist and needs no sequential transport.
        """
        s, resampled = resample_polyline(points, step)
        tangents, normals, binormals = _untwisted_frames_kernel(s, resampled, np.array(binormal_hint, dtype=float))
        return cls(s, resampled, tangents, normals, binormals)

    def up_to(self, s: float) -> Centerline:
        """The curve from the base to arc length s (extended along the end tangent when s lies beyond)."""
        step = float(self.s[1] - self.s[0])  # (a Centerline has at least two samples)
        count = max(int(np.ceil(s / step)), 1) + 1
        samples = np.linspace(0.0, s, count)
        position, tangent, normal, binormal = self.frames_at(samples)
        return Centerline(samples, position, tangent, normal, binormal)

    def rolled(self, angle: float) -> Centerline:
        """The same curve with its frame turned by `angle` about the tangent (the notch side measured)."""
        c, s = np.cos(angle), np.sin(angle)
        normals = c * self.normals + s * self.binormals
        return Centerline(self.s, self.points, self.tangents, normals, np.cross(self.tangents, normals))

    @cached_property
    def _samples(self) -> np.ndarray:
        """(M, 9) points, tangents and normals side by side, what the compiled kernels interpolate."""
        return np.concatenate([self.points, self.tangents, self.normals], axis=1)

    def frames_at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, tangent, normal and binormal at arc lengths s; beyond the ends along the end tangent."""
        s = np.ascontiguousarray(s, dtype=float)
        frames = np.empty((4, len(s), 3))
        _frames_kernel(self._samples, float(self.s[1] - self.s[0]), self.length, s, frames)
        return frames[0], frames[1], frames[2], frames[3]

    def project(self, xyz: np.ndarray, s_guess: np.ndarray | None = None) -> TubeCoordinates:
        """Tube coordinates of points: nearest sample, then slid along the local tangent."""
        return self.project_with_frames(xyz, s_guess)[0]

    def project_with_frames(self, xyz: np.ndarray, s_guess: np.ndarray | None = None
                            ) -> tuple[TubeCoordinates, tuple]:
        """project(), and the centreline frames (position, tangent, normal, binormal) at each point's s.

        s_guess: arc lengths of the same points on a nearby curve (e.g. the previous iteration's), which
        replaces the search for the nearest sample by one more step along the tangent.
        """
        xyz = np.ascontiguousarray(xyz, dtype=float)
        if s_guess is None:
            s = _nearest_sample_arc_kernel(self.points, self.tangents, self.s, xyz, SAMPLES_PER_BOUND)
        else:
            s = np.ascontiguousarray(s_guess, dtype=float)
        frames = np.empty((4, len(s), 3))
        s, x, y = _project_kernel(self._samples, float(self.s[1] - self.s[0]), self.length, xyz, s, frames)
        return TubeCoordinates(s, x, y), (frames[0], frames[1], frames[2], frames[3])

    def to_points(self, s: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Base-frame points of tube coordinates (the inverse of project)."""
        position, _, normal, binormal = self.frames_at(s)
        return position + x[:, None] * normal + y[:, None] * binormal

    def bend_angle(self, s0, s1) -> np.ndarray | float:
        """Signed turn of the tangent from s0 to s1 (scalars or arrays, one of them of length 1 or both of the
        same length), positive towards the notch side; past half a turn it goes on counting (a robot curled
        through 250 deg reads 250, not the 110 between its end tangents)."""
        s0, s1 = (np.atleast_1d(np.asarray(s, dtype=float)) for s in (s0, s1))
        np.broadcast_shapes(s0.shape, s1.shape)  # refuses lengths that do not pair (the kernel would not check)
        if not s0.size or not s1.size:
            return np.empty(0)
        angle = _bend_kernel(self._samples, float(self.s[1] - self.s[0]), self.length, s0, s1)
        if self._total_turning >= 2 * np.pi / 3:  # below, no two tangents lie 120 deg apart: nothing folds
            starts, ends = np.broadcast_arrays(s0, s1)
            for start in np.unique(starts):
                pairs = starts == start
                angle[pairs] = self._unfolded(float(start), ends[pairs], angle[pairs])
        return float(angle[0]) if angle.size == 1 else angle

    @cached_property
    def _total_turning(self) -> float:
        """The angles between successive tangents summed (rad): no two tangents lie farther apart."""
        steps = np.einsum("ij,ij->i", self.tangents[1:], self.tangents[:-1])
        return float(np.sum(np.arccos(np.clip(steps, -1.0, 1.0))))

    def _unfolded(self, s0: float, s1: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """`angle` (the tangents' angle, at most pi) where the tangent turned past pi on the way from s0 to s1:
        n pi + the angle (n even) or + pi less it (n odd), n the half turns counted in the plane the tangents
        sweep (the least-squares plane through them), signed positive towards the notch side at s0."""
        low, high = np.clip([min(s0, s1.min()), max(s0, s1.max())], 0.0, self.length)
        span = (self.s >= low) & (self.s <= high)
        _, start_tangent, start_normal, _ = self.frames_at(np.array([np.clip(s0, 0.0, self.length)]))
        tangents = self.tangents[span]
        if len(tangents) < 2 or np.min(tangents @ start_tangent[0]) > -0.5:
            return angle  # the tangent never turned 120 deg from its start: no half turn to count
        plane_normal = np.linalg.eigh(tangents.T @ tangents)[1][:, 0]
        towards = np.cross(plane_normal, start_tangent[0])
        if towards @ start_normal[0] < 0:
            towards = -towards
        turn = np.unwrap(np.arctan2(tangents @ towards, tangents @ start_tangent[0]))
        turn -= np.interp(s0, self.s[span], turn)
        turn_at = np.interp(np.clip(s1, low, high), self.s[span], turn)
        half_turns = np.floor(np.abs(turn_at) / np.pi)
        folded = np.where(half_turns % 2 == 0, np.abs(angle), np.pi - np.abs(angle))
        return np.where(half_turns > 0, np.sign(turn_at) * (half_turns * np.pi + folded), angle)


@functools.lru_cache(maxsize=16)
def base_pose(geometry: TubeGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Base position, robot axis and bend-plane normal (the robot's y: axis x notch side) in the base frame.

    Cached per geometry (frozen, hashable): every frame asks, and the rotation costs more than the frame's
    use of it. The arrays are read-only, as they are shared.
    """
    rotation = geometry.base_rotation
    side = np.array([np.cos(geometry.notch_side), np.sin(geometry.notch_side), 0.0])
    notch_side = rotation @ side
    pose = np.array(geometry.base_position, float), rotation[:, 2].copy(), np.cross(rotation[:, 2], notch_side)
    for array in pose:
        array.flags.writeable = False
    return pose
