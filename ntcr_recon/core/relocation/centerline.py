"""The robot's centreline estimated from the cloud, using the known outer radius.

Each camera sees one (flattened) side of the tube, so a free circle fit of a cross-section would follow the
flattening; with the radius known, a fixed-radius fit of the arcs that both cameras see recovers the axis.
The estimate alternates, until the centreline moves less than a tolerance:

1. correspondences: every point is projected onto the current centreline (its nearest centreline sample,
   then along the local tangent) giving its arc length s and its offset in the normal plane;
2. a Gauss-Newton step of the point-to-reference objective (Eq. 10 with the reference tube swept along the
   centreline): per slab of arc length, the fixed-radius circle residual |p - c| - r_o, robustly weighted
   (points deep inside the tube are cut faces or bore, points far outside are outliers);
3. all slab updates solved jointly with a smoothness prior along s (a smoothing length relative to the outer
   radius) on the second differences' departure from the steady bend the curve holds (solved with it), and
   the base anchored at the configured base position;
4. the curve re-parametrised by arc length.

A cold start marches from the base along the base axis, fitting one slab at a time; a warm start (the
previous frame's centreline, a still or slowly moving robot) needs one or two iterations.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.relocation.tip import tube_end
from ntcr_recon.core.relocation.wall import band_gate, median, surface_band
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


@dataclass(frozen=True)
class CenterlineSettings:
    """Lengths (metres) derived from the robot and the camera (see `settings_for`)."""

    bin_length: float       # slab length along s
    smoothing_length: float
    gate: float             # a point farther than this from the reference surface is an outlier
    tolerance: float        # convergence: RMS move of the centreline's samples
    max_iterations: int
    cell: float             # resolution along s of coverage profiles (about a pixel footprint)


def settings_for(geometry: TubeGeometry, pixel_footprint: float, relocation) -> CenterlineSettings:
    """Slab length, smoothing, gate and tolerance from the robot's radius and the pixel footprint."""
    r_o = geometry.outer_radius
    footprint = geometry.pixel_footprint_or_default(pixel_footprint)
    return CenterlineSettings(
        bin_length=max(relocation.bin_radius_fraction * r_o, 2.0 * footprint),
        smoothing_length=relocation.smoothing_radius_fraction * r_o,
        gate=relocation.gate_radius_fraction * r_o + relocation.gate_pixels * footprint,
        tolerance=relocation.tolerance_radius_fraction * r_o,
        max_iterations=relocation.max_iterations,
        cell=footprint,
    )


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


def fixed_radius_circle_fit(slab: np.ndarray, x: np.ndarray, y: np.ndarray, slabs: int, radius: float,
                            gate: float, iterations: int = 5, point_weight: np.ndarray | None = None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Per slab, the centre (cx, cy) of a circle of known radius through its points (vectorised over slabs).

    Gauss-Newton on r_i = |p_i - c| - radius with a robust weight: points deeper than gate / 2 inside the
    circle (cut faces, bore) or farther than gate outside (outliers) do not count; Tukey-like taper within.
    point_weight: optional prior weight of each point (e.g. its share of two neighbouring slabs).
    Returns centres (slabs, 2) and the 2x2 information matrices (slabs, 2, 2) (zero where unobserved).
    """
    if point_weight is None:
        point_weight = np.ones(len(x))
    if len(slab) and (slab.min() < 0 or slab.max() >= slabs):  # (the kernel does not check its indices)
        raise ValueError(f"slab indices must lie in [0, {slabs}), got {slab.min()}..{slab.max()}")
    centre, sums = _circle_fit_kernel(slab, x, y, point_weight, slabs, radius, gate, iterations)
    a, b, c = sums[:, 0], sums[:, 1], sums[:, 2]
    information = np.stack([np.stack([a, b], axis=1), np.stack([b, c], axis=1)], axis=1)
    return centre, information


@jit
def _circle_fit_kernel(slab, x, y, point_weight, slabs, radius, gate, iterations):
    """fixed_radius_circle_fit's iterations: centres (slabs, 2) and the last step's weighted sums (slabs, 5) of
    nx nx, nx ny, ny ny, r nx, r ny (n: the unit offset of a point from its slab's centre, r: its residual)."""
    centre = np.zeros((slabs, 2))
    sums = np.zeros((slabs, 5))
    for _ in range(iterations):
        sums[:] = 0.0
        for i in range(x.shape[0]):
            k = slab[i]
            dx, dy = x[i] - centre[k, 0], y[i] - centre[k, 1]
            distance = max(np.sqrt(dx * dx + dy * dy), 1e-12)
            residual = distance - radius
            nx, ny = dx / distance, dy / distance
            scaled = (2.0 * residual if residual < 0 else residual) / gate
            if not abs(scaled) < 1.0:
                continue
            taper = 1.0 - scaled * scaled
            weight = taper * taper * point_weight[i]
            sums[k, 0] += weight * (nx * nx)
            sums[k, 1] += weight * (nx * ny)
            sums[k, 2] += weight * (ny * ny)
            sums[k, 3] += weight * (residual * nx)
            sums[k, 4] += weight * (residual * ny)
        largest = 0.0
        for k in range(slabs):
            a, b, c, gx, gy = sums[k, 0], sums[k, 1], sums[k, 2], sums[k, 3], sums[k, 4]
            damping = 1e-6 * (a + c) + 1e-30
            det = (a + damping) * (c + damping) - b * b
            step_x = ((c + damping) * gx - b * gy) / det
            step_y = ((a + damping) * gy - b * gx) / det
            centre[k, 0] += step_x
            centre[k, 1] += step_y
            largest = max(largest, abs(step_x), abs(step_y))
        if largest < 1e-3 * gate:
            break
    return centre, sums


@jit
def _hat_shares_kernel(s, x, y, selected, step, slabs):
    """Each selected point's shares of its two neighbouring nodes (nodes `step` apart along s, `slabs` of them;
    linear hat weights): (slab, x, y, weight) of every positive share on a node, the lower nodes' first."""
    picked = np.flatnonzero(selected)
    position_in_steps = s[picked] / step
    lower = np.floor(position_in_steps).astype(np.intp)
    share = position_in_steps - lower
    slab, weight = np.empty(2 * len(picked), np.intp), np.empty(2 * len(picked))
    slab_x, slab_y = np.empty(2 * len(picked)), np.empty(2 * len(picked))
    kept = 0
    for upper in range(2):
        for j in range(len(picked)):
            node, node_weight = lower[j] + upper, share[j] if upper else 1.0 - share[j]
            if 0 <= node < slabs and node_weight > 0:
                slab[kept], weight[kept] = node, node_weight
                slab_x[kept], slab_y[kept] = x[picked[j]], y[picked[j]]
                kept += 1
    return slab[:kept], slab_x[:kept], slab_y[:kept], weight[:kept]


@jit
def _slab_directions_kernel(slab, x, y, weight, slabs):
    """Per slab the weight of its points and the length of the weighted sum of their unit directions
    (x, y) / |(x, y)| about the axis."""
    counts, cos_sum, sin_sum = np.zeros(slabs), np.zeros(slabs), np.zeros(slabs)
    for i in range(slab.shape[0]):
        cos_angle, sin_angle = unit_direction(x[i], y[i])
        counts[slab[i]] += weight[i]
        cos_sum[slab[i]] += weight[i] * cos_angle
        sin_sum[slab[i]] += weight[i] * sin_angle
    return counts, np.hypot(cos_sum, sin_sum)


def _smooth_update(nodes: np.ndarray, tangents: np.ndarray, targets: np.ndarray, information: np.ndarray,
                   anchor: np.ndarray, smoothing_steps: float, bend_axes: np.ndarray, bend_steps: float
                   ) -> np.ndarray:
    """Positions P minimising sum (P - target)^T W (P - target) + lam |second differences of P - bend|^2
    + lam bend_steps^2 |first differences of the bend|^2 + anchor term, jointly with the bend.

    The bend is the curvature the curve holds (per node, on its normal and binormal: bend_axes (M, 2, 3)), a
    field free to follow what varies slower than `bend_steps` nodes: only departures of the curvature from it
    pay the smoothness prior. A prior on the curvature itself holds no bend at a free end (a natural end)
    and swings the end of a bent robot out of its bend; this one treats a steady bend the same at the end
    as within, and still smooths what changes within a smoothing length.
    nodes: current positions (M, 3); the data say nothing along the tangent, so each node is held at its
    place along its tangent (else the smoothness prior would let the curve stretch freely) and weakly
    everywhere. information: (M, 3, 3) data weights. lam = smoothing_steps^4 sets the cut-off length.
    """
    bands, rhs = _smoothing_system_kernel(nodes, tangents, targets, information, np.asarray(anchor, dtype=float),
                                          smoothing_steps, np.ascontiguousarray(bend_axes, dtype=float),
                                          bend_steps)
    solution = scipy.linalg.solveh_banded(bands, rhs).reshape(len(nodes), 5)
    return solution[:, :3]


@jit
def _smoothing_system_kernel(nodes, tangents, targets, information, anchor, smoothing_steps, bend_axes,
                             bend_steps):
    """_smooth_update's normal equations, in LAPACK's upper band storage (11, 5M) and their right-hand side.

    Unknowns per node m: its position (5m .. 5m + 2) and its bend on its two axes (5m + 3, 5m + 4). A second
    difference of nodes i, i+1, i+2 less the bend of i+1 couples unknowns at most 10 apart: symmetric,
    positive definite and banded: bands[10 - offset, column] = system[column - offset, column]. No dense
    matrix, no matrix product (which would wake BLAS threads for nothing).
    """
    count = nodes.shape[0]
    traces = information[:, 0, 0] + information[:, 1, 1] + information[:, 2, 2]
    observed = traces[traces > 0]
    typical = median(observed) if observed.size else 1.0
    weak = 1e-4 * typical
    lam = typical * smoothing_steps**4
    steady = lam * bend_steps**2  # the bend's own smoothness: its cut-off bend_steps nodes
    clamp = 1e3 * typical  # the base is clamped at the configured pose
    bands, rhs = np.zeros((11, 5 * count)), np.zeros(5 * count)
    for m in range(count):
        for row in range(3):
            for column in range(3):
                along = typical * (tangents[m, row] * tangents[m, column])
                rhs[5 * m + row] += information[m, row, column] * targets[m, column]
                rhs[5 * m + row] += along * nodes[m, column]
                if column >= row:
                    block = information[m, row, column] + along
                    if column == row:
                        block += weak + (clamp if m == 0 else 0.0)
                    bands[10 - (column - row), 5 * m + column] = block
            rhs[5 * m + row] += weak * nodes[m, row] + (clamp * anchor[row] if m == 0 else 0.0)
        for k in range(2):
            bands[10, 5 * m + 3 + k] += 1e-9 * lam  # a bend no difference reaches stays nought
    # lam |P_i - 2 P_{i+1} + P_{i+2} - bend_{i+1}|^2
    coefficients = (1.0, -2.0, 1.0)
    for i in range(count - 2):
        middle = i + 1
        for first in range(3):
            for second in range(first, 3):
                value = lam * coefficients[first] * coefficients[second]
                for axis in range(3):  # position pair (i + first, i + second), per axis
                    bands[10 - 5 * (second - first), 5 * (i + second) + axis] += value
        for k in range(2):
            bends_column = 5 * middle + 3 + k
            bands[10, bends_column] += lam
            for node in range(3):
                for axis in range(3):  # position against bend: -lam coefficient (bend axis k's component)
                    value = -lam * coefficients[node] * bend_axes[middle, k, axis]
                    position_column = 5 * (i + node) + axis
                    if position_column < bends_column:
                        bands[10 - (bends_column - position_column), bends_column] += value
                    else:
                        bands[10 - (position_column - bends_column), position_column] += value
    # steady |bend_{m+1} - bend_m|^2 over the bends the second differences use (nodes 1 .. M - 2)
    for m in range(1, count - 2):
        for k in range(2):
            bands[10, 5 * m + 3 + k] += steady
            bands[10, 5 * (m + 1) + 3 + k] += steady
            bands[5, 5 * (m + 1) + 3 + k] -= steady
    return bands, rhs


# A curve's bend at its free end is checked against the bend read this many notch pitches short of it (held_bend).
END_TURN_PITCHES = 2


def turn_from_base(centerline: Centerline, geometry: TubeGeometry, s: float) -> float:
    """The robot's bend from its base to arc length s (rad, + towards the notch side): the curve's turn from its
    start, plus the tilt of its start from the base axis the rig configures. A smoothed curve's end tangent leans
    with the bend beside it (the first notches' curvature spreads back over the straight proximal part), so the
    clamp's axis is the better start: on the robot's largest bend the curve's own start tilts 3 deg back."""
    _, axis, binormal = base_pose(geometry)
    start = centerline.frames_at(np.zeros(1))[1][0]
    notch_side = np.cross(binormal, axis)
    tilt = math.atan2(float(start @ notch_side), float(start @ axis))
    return float(centerline.bend_angle(0.0, s)) + tilt


def held_bend(centerline: Centerline, geometry: TubeGeometry, s: float, notch_centres: np.ndarray) -> float | None:
    """The robot's bend from its base to arc length s (rad) read END_TURN_PITCHES pitches short of s, where the
    smoothing has data on both sides, and carried over the rest at the steady bend of the pitches before
    (continued_bend); None on a curve too short for that. At a curve's free end its tangent follows only the data
    before it: on the second renderer's coarse cameras it leant up to 9 deg off, where this stayed within 2.6 (1.0
    deg RMS against 2.2 over 70 scenes); on the simulator the two do as well (1.6 and 1.8 deg RMS over 40 scenes),
    and the end tangent better over the matrix (1.2 against 1.7)."""
    held_to = s - END_TURN_PITCHES * geometry.notch_pitch
    if held_to < END_TURN_PITCHES * geometry.notch_pitch:
        return None
    return turn_from_base(continued_bend(centerline.up_to(held_to), s, notch_centres, geometry), geometry, s)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors: np.cross's broadcasting costs some 30 us a call, and continued_bend runs three
    times a frame."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def continued_bend(centerline: Centerline, to_s: float, notch_centres: np.ndarray, geometry: TubeGeometry
                   ) -> Centerline:
    """The curve carried on from its end to arc length `to_s` as the robot bends: over what of each notch lies past
    the curve's end it turns by the steady bend per notch (the curve's turn over its last two pitches, about the
    tangents' common normal, shared by the notches in them), spread over the notch's arc at that bend about its
    centre (notch_centres: the comb's); straight along the spines between and beyond the last notch. The curve
    itself is unchanged."""
    length = centerline.length
    step = float(centerline.s[1] - centerline.s[0])
    if to_s <= length + 1e-12:
        return centerline
    extra = np.arange(1, int(np.ceil((to_s - length) / step - 1e-9)) + 1) * step  # (samples stay uniform)
    start = max(length - 2 * geometry.notch_pitch, 0.0)
    position, tangents_at, normal, binormal = centerline.frames_at(np.array([start, length]))
    first_tangent, tangent = tangents_at
    position, normal, binormal = position[1], normal[1], binormal[1]
    axis = _cross(first_tangent, tangent)
    turn = math.atan2(float(np.linalg.norm(axis)), float(first_tangent @ tangent))
    axis = axis / np.linalg.norm(axis) if turn > 1e-9 else binormal
    centres = np.asarray(notch_centres, float)
    # the turn shared by the notches' arcs within it: the arc a notch spans shrinks with its bend (twice suffices)
    arc, per_notch = geometry.notch_width, 0.0
    for _ in range(2):
        spanned = float(np.sum(np.clip((np.minimum(centres + arc / 2, length) - np.maximum(centres - arc / 2, start))
                                       / arc, 0.0, 1.0)))
        per_notch = turn / spanned if spanned > 0 else 0.0
        arc = max(geometry.notch_arc_at_bend(per_notch), 1e-9)
    # the tangent's turn along the extension, integrated finely (the notches' arcs are a few samples long); each
    # notch's share of its bend past the curve's end (the curve turned through what of it lies before)
    fine = np.linspace(0.0, extra[-1], 16 * len(extra) + 1)
    arc_starts = centres[centres + arc / 2 > length] - arc / 2
    turned_by = np.clip((length - arc_starts) / arc, 0.0, 1.0)
    progress = np.clip((length + fine[:, None] - arc_starts) / arc, 0.0, 1.0) - turned_by
    angle = per_notch * progress.sum(axis=1)
    side = _cross(axis, tangent)
    directions = np.cos(angle)[:, None] * tangent + np.sin(angle)[:, None] * side
    travelled = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (directions[1:] + directions[:-1])
                                                           * np.diff(fine)[:, None], axis=0)])
    picked = np.searchsorted(fine, extra - 1e-12)
    cos_a, sin_a = np.cos(angle[picked])[:, None], np.sin(angle[picked])[:, None]

    def turned(v: np.ndarray) -> np.ndarray:  # Rodrigues about `axis`
        along = float(v @ axis) * axis
        return along + cos_a * (v - along) + sin_a * _cross(axis, v)

    return Centerline(np.concatenate([centerline.s, length + extra]),
                      np.concatenate([centerline.points, position + travelled[picked]]),
                      np.concatenate([centerline.tangents, turned(tangent)]),
                      np.concatenate([centerline.normals, turned(normal)]),
                      np.concatenate([centerline.binormals, turned(binormal)]))


def _march(xyz: np.ndarray, geometry: TubeGeometry, settings: CenterlineSettings) -> np.ndarray:
    """Cold start: from the base along its axis, fit one slab ahead at a time; returns polyline nodes."""
    base, axis, binormal = base_pose(geometry)
    r_o = geometry.outer_radius
    step = max(r_o, 2 * settings.bin_length)
    reach = 1.5 * r_o + settings.gate
    nodes = [base]
    tangent = axis
    limit = int(np.ceil(geometry.reach / step)) + 2  # never past the robot
    misses = 0
    allowed_misses = max(3, int(np.ceil(geometry.proximal_length / step)) + 1)
    for _ in range(limit):
        predicted = nodes[-1] + step * tangent
        offset = xyz - predicted
        along = np.einsum("ij,j->i", offset, tangent)  # not `@`: a BLAS product would wake its threads
        lateral = offset - along[:, None] * tangent
        near = (np.abs(along) <= step / 2) & (np.einsum("ij,ij->i", lateral, lateral) <= reach**2)
        centre = None
        if np.count_nonzero(near) >= 8:
            e2 = binormal - (binormal @ tangent) * tangent
            e2 /= np.linalg.norm(e2)
            e1 = np.cross(e2, tangent)
            local = lateral[near]
            centre, _ = fixed_radius_circle_fit(np.zeros(len(local), dtype=np.intp),
                                                np.einsum("ij,j->i", local, e1), np.einsum("ij,j->i", local, e2), 1,
                                                r_o, settings.gate, iterations=8)
            # a few points on one side let a circle of the radius sit anywhere on their far side: an axis
            # more than a radius off the straight prediction in one step is no tube the robot can bend to
            if np.hypot(centre[0, 0], centre[0, 1]) > r_o:
                centre = None
        if centre is None:
            # a stretch without data enough to place the axis (the base hidden by its clamp, an occlusion):
            # carry on straight for up to the proximal length (straight by construction) or a few steps
            misses += 1
            if misses > allowed_misses:
                break
            nodes.append(predicted)
            continue
        misses = 0
        node = predicted + centre[0, 0] * e1 + centre[0, 1] * e2
        direction = node - nodes[max(len(nodes) - 2, 0)]
        tangent = direction / np.linalg.norm(direction)
        nodes.append(node)
    while misses > 0 and len(nodes) > 2:  # drop the extrapolated nodes past the last observed slab
        nodes.pop()
        misses -= 1
    return np.array(nodes)


def _observed_end(coordinates: TubeCoordinates, geometry: TubeGeometry, settings: CenterlineSettings,
                  centerline: Centerline, viewpoints: np.ndarray | None, band: tuple[float, float]) -> float:
    """Where the tube seen ends, never past the robot's reach; band: the wall band of the coordinates."""
    return tube_end(coordinates, geometry.outer_radius, settings.gate, settings.cell, max_s=geometry.reach,
                    centerline=centerline, viewpoints=viewpoints, band=band)


def _moved(previous: Centerline, samples: np.ndarray) -> float:
    """RMS distance (m) of a new curve's `samples` from the `previous` curve (0 for none)."""
    return float(np.sqrt(np.mean(previous.project(samples).radius ** 2))) if len(samples) else 0.0


def estimate_centerline(xyz: np.ndarray, geometry: TubeGeometry, settings: CenterlineSettings,
                        prior: Centerline | None = None, viewpoints: np.ndarray | None = None
                        ) -> tuple[Centerline, int, tuple]:
    """Fit the centreline to a cloud in the base frame.

    viewpoints: (C, 3) the cameras' optical centres, so the tube's end is judged by what they can see.
    Returns the centreline (base to just past the last slab with data; the pipeline cuts it at the observed
    tip), the number of iterations run, and (coordinates, frames, exact): the points' projection onto the
    returned curve when exact, else onto the curve before it (its arc lengths a guess for projecting again).
    On convergence the curve the points were last projected onto is returned: the update beyond it moved
    less than the tolerance, and its projection is then exact for free.
    """
    base, _, binormal_hint = base_pose(geometry)
    step = settings.bin_length
    if prior is None:
        nodes = _march(xyz, geometry, settings)
        centerline = Centerline.from_points(nodes, binormal_hint, step)
    else:
        centerline = prior
    smoothing_steps = settings.smoothing_length / step
    # the robot bends at its notches: its steady bend is what holds over two notch pitches
    bend_steps = 2.0 * geometry.notch_pitch / step
    iterations = 0
    coordinates, frames = None, None
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 - reported to the caller
        coordinates, frames = centerline.project_with_frames(xyz, None if coordinates is None else coordinates.s)
        near_tube = np.abs(coordinates.radius - geometry.outer_radius) < settings.gate
        near_tube &= coordinates.s > -settings.gate
        if np.count_nonzero(near_tube) < 16:
            break
        # stereo depth puts the seen wall a little inside (flattening) or outside the true one, about equally
        # all round: the circle is fitted at the radius this cloud's wall points lie at, its centre is the axis
        band = surface_band(coordinates.radius - geometry.outer_radius, settings.gate)
        # the curve reaches as far as the tube is seen, never past the robot's own length (and a margin)
        observed_end = _observed_end(coordinates, geometry, settings, centerline, viewpoints, band)
        slabs = max(int(np.ceil(observed_end / step)) + 1, 2)
        # each point feeds its two neighbouring nodes with linear (hat) weights, so the fit changes
        # smoothly as points slide along s between iterations
        slab, x, y, weight = _hat_shares_kernel(coordinates.s, coordinates.x, coordinates.y, near_tube, step, slabs)
        # the circles rest on the wall's band: mixed pixels pull a slab's circle across the view (most where the
        # end's and the last notch's edges leave few wall points); two pixel footprints at least, as a clean wall's
        # band is thinner than its pixels
        circle_gate = band_gate(*band, settings.gate, least=2 * settings.cell)
        centre, information_2d = fixed_radius_circle_fit(slab, x, y, slabs, geometry.outer_radius + band[0],
                                                          circle_gate, iterations=3, point_weight=weight)
        s_nodes = np.arange(slabs) * step
        position, tangent, normal, binormal = centerline.frames_at(s_nodes)
        basis = np.stack([normal, binormal], axis=2)                      # (M, 3, 2)
        targets = position + np.einsum("mij,mj->mi", basis, centre)
        information = np.einsum("mia,mab,mjb->mij", basis, information_2d, basis)
        # slabs too thinly observed to place a circle are left to the smoothness prior
        counts, resultant = _slab_directions_kernel(slab, x, y, weight, slabs)
        information[counts < 6] = 0.0
        # A slab seen on one side only (e.g. across a notch, where only the spine is left) places the axis
        # through the radius alone, so any radial bias of stereo depth moves it sideways: such slabs count
        # less, by 1 - |mean direction of their points about the axis|^2, and the smoothness prior bridges.
        balance = 1.0 - (resultant / np.maximum(counts, 1e-12)) ** 2
        information *= balance[:, None, None]
        updated = _smooth_update(position, tangent, targets, information, base, smoothing_steps,
                                 np.stack([normal, binormal], axis=1), bend_steps)
        previous = centerline
        centerline = Centerline.from_points(updated, binormal_hint, step)
        # the change of the curve's shape, not of its parametrisation: distance of the new samples from
        # the previous curve, over the interior and, apart, over the free end (where the tip sits: an RMS over
        # the whole length dilutes a moved end, and a warm start's prior, settled within, came with the last
        # frame's end); and the extent, to a slab (a cold start's march runs on over what lies past the end - an
        # end cap, the bore - and bends there: the curve is settled only once the slabs the tube's end leaves
        # have been fitted again; the last slab, there or not by a point, is not judged)
        common = min(previous.length, centerline.length)
        settled = common - 2 * settings.smoothing_length - 3 * step
        if (_moved(previous, centerline.points[centerline.s < settled]) < settings.tolerance
                and _moved(previous, centerline.points[(centerline.s >= settled) & (centerline.s < common - step)])
                < settings.tolerance and abs(centerline.length - previous.length) <= step):
            return previous, iterations, (coordinates, frames, True)
    return centerline, iterations, (coordinates, frames, False)
