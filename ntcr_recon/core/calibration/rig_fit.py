"""The rig calibrated from the robot it watches (issue 62): both cameras' poses in the robot's base frame.

The robot defines the base frame (DESIGN.md): its proximal segment's axis is z, its base end cap z = 0, the notch
side x, as the rig file's `robot` section places it. Over every recording at once, one robust least-squares
problem (scipy.optimize.least_squares, Cauchy loss) fits each camera's pose (a turn and a shift about the robot's
middle, applied to the rig file's pose) and each bent recording's bends (a linear profile from the first notch to
the last, core.robot.kinematics; a straight recording's are zero, so its axis is z) so that every point the
cameras saw lies on the robot's tube as its camera sees it (core.calibration.tube_distance) and, once the fit is
within a pixel, the tube's axis lies midway between its limbs in each colour image (core.calibration.limb_rows).
The loss's scale narrows over rounds (SCALES_M), so a start a few millimetres and degrees off is pulled in before
the wall's tenth of a millimetre decides; each round restarts the turns from the pose the last one reached, where
their Jacobian is exact.

What the recordings cannot fix is refused by name: a straight tube is a cylinder, so neither camera's turn about
the robot's axis is determined until the robot bends (CalibrationError says so and what to record). The uncertainty
of each pose parameter comes from the fit's covariance with the points of each stretch of tube a matcher's window
covers counted once (its depth errs alike over its window). It does not hold a matcher's bias of depth that varies
along the tube (the notches smeared into its window, a highlight), which moves the cameras along their views and
turns them about the axes across them: benchmarks/calibration_matrix.py measures by how much.

With a rigid `target` instead (core.calibration.target: a mesh, for a rig without a robot), the same fit has no
bends and no limbs, and the mesh's frame is the base frame.

    fit = fit_rig(recordings, geometry, start_extrinsics)     # RigFit: extrinsics, uncertainties, residuals, bends
    fit = fit_rig(recordings, geometry, start_extrinsics, target=RigidTarget.from_mesh(vertices, triangles))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ntcr_recon.core.calibration.limb_rows import LimbRows, limb_rows
from ntcr_recon.core.calibration.target import RigidTarget
from ntcr_recon.core.calibration.tube_distance import TubeDistance, bend_jacobian, tube_distance
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

# The robust loss's scale per round (m): from the rough pose's millimetres to the wall's depth noise.
SCALES_M = (2.0e-3, 5.0e-4, 1.5e-4, 1.0e-4)
# Uniform bends tried for each recording's start (fractions of the notches' closing angle).
START_BENDS = np.linspace(0.0, 1.0, 11)
# Pixels across a stereo matcher's window (a D405's is about 9): its depth errs alike over so many footprints.
WINDOW_PX = 9
# A camera within this angle of the side the notches open to looks into their slots (rad).
SLOTS_FACING = np.radians(45.0)
# An eigenvalue of the Gauss-Newton matrix this small against the largest leaves its direction free.
FREE = 1e-9
# A pose parameter whose 1-sigma exceeds this (deg or mm) is not determined by the recordings: refused.
UNDETERMINED = 1.0
# A recording whose total bend stays below this (rad) leaves the tube a cylinder about its axis.
STRAIGHT_RAD = np.radians(5.0)
# The limbs are read from the round whose loss scale is this small (m) on: the pose then puts each limb within the
# pixels their search spans (core.relocation.limb_profile.SEARCH_PX).
LIMBS_FROM_SCALE_M = 1.5e-4
# A camera's limb stations count together as much as its points, each at most this many times one point.
LIMB_WEIGHT_MAX = 3.0
# Parameters of a recording's bend profile: the first notch's bend and the last's.
PROFILE = 2
AXES = ("x", "y", "z")


class CalibrationError(ValueError):
    """The recordings cannot give the poses asked for; the message names the parameter and what to record.
    `free`: the parameters left free, as "<camera>.turn_<axis>" or "<camera>.shift_<axis>" (base-frame axes)."""

    def __init__(self, message: str, free: tuple[str, ...] = ()):
        super().__init__(message)
        self.free = free


@dataclass(frozen=True)
class Recording:
    """One still pose of the robot: each camera's points of it in its own optical frame (m), and how many pixels
    those points were sampled from."""

    name: str
    points: dict[str, np.ndarray]
    pixels: dict[str, int]
    straight: bool = False      # the robot at rest, straight (its bends held at zero): its axis is the base's z
    footprint: float = 2.0e-4   # a pixel's size at the robot (m): the stretch a matcher's window errs alike over
    views: dict = field(default_factory=dict)   # camera -> (colour image (H, W, 3), Intrinsics) aligned with depth


@dataclass(frozen=True)
class RigFit:
    """The calibrated poses and what they rest on. Uncertainties are 1-sigma, per parameter: a turn about the base
    frame's x, y, z through the robot's middle (deg) and a shift along them (mm), each camera's in the base frame
    and the second camera's relative to the first."""

    extrinsics: dict[str, np.ndarray]
    uncertainty: dict[str, np.ndarray]
    relative_uncertainty: np.ndarray
    residual_mm: dict[str, float]          # robust RMS of each camera's points off the fitted tube
    inliers: dict[str, float]              # share of each camera's points within 3 loss scales of the tube
    bends: dict[str, np.ndarray]           # per recording, each notch's fitted bend (rad)
    start_residual_mm: dict[str, float]
    facing_slots: dict[str, float] = field(default_factory=dict)   # camera -> deg off the slots (slots_in_view)


def slots_in_view(geometry: TubeGeometry, extrinsics: dict[str, np.ndarray]) -> dict[str, float]:
    """The cameras that look into the notches' slots (within SLOTS_FACING of the side they open to), each with the
    angle (deg) between its direction from the robot and that side. A matcher's window there averages the slots'
    floors with the spines: its depth reads deep in a pattern along the tube the fit takes for the camera's pose
    (with the notches towards cam_a, cam_a came out 1 mm nearer along its view)."""
    side = geometry.base_rotation @ np.array([np.cos(geometry.notch_side), np.sin(geometry.notch_side), 0.0])
    facing = {}
    for name, extrinsic in extrinsics.items():
        towards = extrinsic[:3, 3] - pivot_of(geometry)
        angle = float(np.degrees(np.arccos(np.clip(side @ towards / np.linalg.norm(towards), -1.0, 1.0))))
        if angle < np.degrees(SLOTS_FACING):
            facing[name] = angle
    return facing


def pivot_of(geometry: TubeGeometry) -> np.ndarray:
    """The straight robot's middle in the base frame: the turns' centre (a turn about a camera's own origin, 90 mm
    away, would move the robot as much as a shift and condition the fit badly)."""
    axis = geometry.base_rotation[:, 2]
    return np.asarray(geometry.base_position, float) + axis * geometry.length / 2.0


def pose_change(start: np.ndarray, end: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """How a pose (4x4, base frame) moved from `start` to `end`, per base-frame axis: the turn (rotation vector,
    deg) and where it moved the point `pivot` (the robot's middle) as the camera sees it (mm)."""
    change = end @ np.linalg.inv(start)
    turn = np.degrees(Rotation.from_matrix(change[:3, :3]).as_rotvec())
    return np.concatenate([turn, (change[:3, :3] @ pivot + change[:3, 3] - pivot) * 1e3])


class _Problem:
    """The residuals and Jacobian over [turn, shift] per camera and the bends per recording."""

    def __init__(self, recordings: list[Recording], geometry: TubeGeometry, cameras: tuple[str, ...],
                 extrinsics: dict[str, np.ndarray], target: RigidTarget | None = None, held: tuple[str, ...] = ()):
        self.recordings, self.geometry, self.cameras, self.target = recordings, geometry, cameras, target
        self.pivot = pivot_of(geometry) if target is None else target.centre
        self.notches = geometry.notch_count
        # A recording's bends vary linearly from the first notch's to the last's: one tendon bends identical notches
        # alike, friction a little less distally (York et al. 2015). Both ends within what a notch can bend keep
        # every notch there.
        place = np.linspace(0.0, 1.0, self.notches)
        self.profile = np.stack([1.0 - place, place])
        self.outlier = 3 * SCALES_M[0]
        self.limbs: list[tuple[LimbRows, np.ndarray, np.ndarray, float]] = []
        self.set_start(extrinsics)
        self._cache: tuple[bytes, list] | None = None
        # the parameters fitted: all but the held cameras' poses
        self.varied = np.ones(self.size, bool)
        for c, name in enumerate(cameras):
            self.varied[6 * c:6 * c + 6] = name not in held

    def measure_limbs(self, x: np.ndarray) -> None:
        """Read every camera's limbs about the robot as x poses it (core.calibration.limb_rows), each camera's
        stations weighted to count together as much as its points do (at most LIMB_WEIGHT_MAX each)."""
        self.limbs = []
        if self.target is not None:
            return  # a target's edges are not read
        poses = self.extrinsics(x)
        for index, recording in enumerate(self.recordings):
            shape = TubeShape(self.geometry, self.bends(x, index))
            for c, name in enumerate(self.cameras):
                if name not in recording.views or not len(recording.points.get(name, ())):
                    continue
                rows = limb_rows(index, c, shape, *recording.views[name], poses[name])
                if rows is None:
                    continue
                start = self.start[name]
                centred = rows.points @ start[:3, :3].T + start[:3, 3] - self.pivot
                across = rows.across @ start[:3, :3].T
                weight = min(np.sqrt(len(recording.points[name]) / len(rows.s)), LIMB_WEIGHT_MAX)
                self.limbs.append((rows, centred, across, weight))
        self._cache = None

    def set_start(self, extrinsics: dict[str, np.ndarray]) -> None:
        """The poses the turns and shifts start from (the limbs read so far are forgotten)."""
        self.start = {name: matrix.copy() for name, matrix in extrinsics.items()}
        self.limbs = []
        self.centred = [{name: (points @ self.start[name][:3, :3].T + self.start[name][:3, 3]) - self.pivot
                         for name, points in recording.points.items()} for recording in self.recordings]
        self._cache = None

    @property
    def size(self) -> int:
        return 6 * len(self.cameras) + PROFILE * sum(not r.straight for r in self.recordings)

    def profile_at(self, index: int) -> int | None:
        """Where the recording's bend profile sits in x (None: a straight recording has none)."""
        if self.recordings[index].straight or self.target is not None:
            return None
        return 6 * len(self.cameras) + PROFILE * sum(not r.straight for r in self.recordings[:index])

    def bends(self, x: np.ndarray, index: int) -> np.ndarray:
        """The recording's bend of every notch (rad), kept within what a notch can bend."""
        start = self.profile_at(index)
        if start is None:
            return np.zeros(self.notches)
        return np.clip(x[start:start + PROFILE] @ self.profile, 0.0, self.geometry.max_notch_bend)  # rounding

    def extrinsics(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The camera poses x describes (turns and shifts about the pivot, on the start poses)."""
        result = {}
        for c, name in enumerate(self.cameras):
            turn = Rotation.from_rotvec(x[6 * c:6 * c + 3]).as_matrix()
            matrix = np.eye(4)
            matrix[:3, :3] = turn @ self.start[name][:3, :3]
            matrix[:3, 3] = turn @ (self.start[name][:3, 3] - self.pivot) + self.pivot + x[6 * c + 3:6 * c + 6]
            result[name] = matrix
        return result

    def _evaluate(self, x: np.ndarray) -> list:
        key = x.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        parts, shapes = [], []
        for index, centred in enumerate(self.centred):
            shape = TubeShape(self.geometry, self.bends(x, index)) if self.target is None else None
            shapes.append(shape)
            for c, name in enumerate(self.cameras):
                if name not in centred:
                    continue
                turn = Rotation.from_rotvec(x[6 * c:6 * c + 3]).as_matrix()
                moved = centred[name] @ turn.T + x[6 * c + 3:6 * c + 6]
                if self.target is not None:
                    parts.append((index, c, moved, shape, self.target.distance(moved + self.pivot), False))
                    continue
                origin = turn @ (self.start[name][:3, 3] - self.pivot) + self.pivot + x[6 * c + 3:6 * c + 6]
                measured = tube_distance(shape, moved + self.pivot, origin)
                # What lies past the base plane is the clamp or its post: as far off as the loss's tail, whatever
                # the pose, so it neither pulls nor pushes.
                measured.distance[measured.below_base] = self.outlier
                measured.direction[measured.below_base] = 0.0
                parts.append((index, c, moved, shape, measured, False))
        for rows, centred, across, weight in self.limbs:
            c = rows.camera
            turn = Rotation.from_rotvec(x[6 * c:6 * c + 3]).as_matrix()
            moved, direction = centred @ turn.T + x[6 * c + 3:6 * c + 6], across @ turn.T * weight
            shape = shapes[rows.recording]
            gap = np.einsum("ij,ij->i", direction, moved + self.pivot - shape.centerline_points(rows.s))
            parts.append((rows.recording, c, moved, shape,
                          TubeDistance(gap, direction, rows.s, np.zeros(len(gap), bool)), True))
        self._cache = (key, parts)
        return parts

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([part[4].distance for part in self._evaluate(x)])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        parts = self._evaluate(x)
        jac = np.zeros((sum(len(part[4].distance) for part in parts), self.size))
        row = 0
        rows_of: dict[int, list] = {}
        for index, c, moved, shape, measured, _ in parts:
            block = slice(row, row + len(measured.distance))
            # d distance / d turn: the gradient against the point's move (turn x its offset from the pivot).
            jac[block, 6 * c:6 * c + 3] = np.cross(moved, measured.direction)
            jac[block, 6 * c + 3:6 * c + 6] = measured.direction
            rows_of.setdefault(index, []).append((block, shape, measured))
            row += len(measured.distance)
        for index, blocks in rows_of.items():  # the bend profile's columns, by finite differences
            start = self.profile_at(index)
            if start is None:
                continue
            columns = bend_jacobian(blocks[0][1], np.concatenate([m.foot_s for _, _, m in blocks]),
                                    np.concatenate([m.direction for _, _, m in blocks]), self.profile)
            offset = 0
            for block, _, measured in blocks:
                jac[block, start:start + PROFILE] = columns[offset:offset + len(measured.distance)]
                offset += len(measured.distance)
        return jac

    def camera_rows(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """Each camera's residuals (m), over all recordings."""
        found: dict[str, list] = {name: [] for name in self.cameras}
        for _, c, _, _, measured, limbs in self._evaluate(x):
            if not limbs:
                found[self.cameras[c]].append(measured.distance)
        return {name: np.concatenate(values) if values else np.empty(0) for name, values in found.items()}


def robust_rms(residuals: np.ndarray, scale: float) -> tuple[float, float]:
    """The RMS (m) of residuals within 3 scales, and their share."""
    inside = np.abs(residuals) <= 3 * scale
    if not inside.any():
        return float("nan"), 0.0
    return float(np.sqrt(np.mean(residuals[inside] ** 2))), float(inside.mean())


def _start_bends(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """Each recording's bend started where a uniform bend fits the start poses best (Cauchy cost, first scale)."""
    x = x.copy()
    for index in range(len(problem.recordings)):
        start = problem.profile_at(index)
        if start is None:
            continue
        ends = slice(start, start + PROFILE)
        costs = []
        for fraction in START_BENDS:
            x[ends] = fraction * problem.geometry.max_notch_bend
            costs.append(np.sum(np.log1p((problem.residuals(x) / SCALES_M[0]) ** 2)))
        x[ends] = START_BENDS[int(np.argmin(costs))] * problem.geometry.max_notch_bend
    return x


def fit_rig(recordings: list[Recording], geometry: TubeGeometry, start: dict[str, np.ndarray],
            progress: Callable[[str], None] | None = None, target: RigidTarget | None = None,
            held: tuple[str, ...] = ()) -> RigFit:
    """Both cameras' poses (base frame) and every recording's bends fitted to what the cameras saw; with a
    `target`, the cameras' poses in its frame, fitted to its surface (every recording a view of it). `held`: the
    cameras whose start pose is kept (core.calibration.refine holds the first and refines the second against it):
    their uncertainty is zero, the others' is then relative to them."""
    cameras = tuple(start)
    if not recordings:
        raise CalibrationError("no recording to calibrate from")
    for name in cameras:
        if not any(len(r.points.get(name, ())) for r in recordings):
            raise CalibrationError(f"{name} saw none of the robot in any recording: check its rough pose and "
                                   "that the robot is in its view")
    problem = _Problem(recordings, geometry, cameras, start, target, held)
    x = _start_bends(problem, np.zeros(problem.size))
    start_rows = problem.camera_rows(x)
    lower, upper = np.full(problem.size, -np.inf), np.full(problem.size, np.inf)
    lower[6 * len(cameras):], upper[6 * len(cameras):] = 0.0, geometry.max_notch_bend
    varied = problem.varied
    lower, upper = lower[varied], upper[varied]

    def full(values: np.ndarray) -> np.ndarray:
        whole = np.zeros(problem.size)
        whole[varied] = values
        return whole

    for round_index, scale in enumerate(SCALES_M):
        if progress:
            progress(f"round {round_index + 1}/{len(SCALES_M)}: loss scale {scale * 1e3:.2f} mm")
        problem.outlier = 3 * scale
        if scale <= LIMBS_FROM_SCALE_M:
            problem.measure_limbs(x)
        solved = least_squares(lambda v: problem.residuals(full(v)), np.clip(x[varied], lower, upper),
                               jac=lambda v: problem.jacobian(full(v))[:, varied], bounds=(lower, upper),
                               loss="cauchy", f_scale=scale, x_scale="jac", max_nfev=60)
        x = full(solved.x)
        problem.set_start(problem.extrinsics(x))  # the turns restart from zero, where their Jacobian is exact
        x[:6 * len(cameras)] = 0.0
    if SCALES_M[-1] <= LIMBS_FROM_SCALE_M:
        problem.measure_limbs(x)  # read where the fit left the robot, for its residuals and covariance
    return _result(problem, x, start_rows)


def _covariance(problem: _Problem, x: np.ndarray, scale: float) -> np.ndarray:
    """The camera parameters' covariance, the bends marginalised: the inverse of the Cauchy loss's Gauss-Newton
    matrix times the residuals' robust variance, with the points of one camera and recording counted as the
    stretches of the tube they cover, each a stereo matcher's window long (WINDOW_PX pixel footprints): a matcher
    errs alike over its window (a wall read deeper beside a slot, under a highlight, towards a limb), so its
    points there are one measurement, not dozens. Directions the recordings leave free (an eigenvalue below FREE of
    the largest) are infinitely uncertain in every parameter they move."""
    residuals = problem.residuals(x)
    whole = problem.jacobian(x)
    seen = np.any(whole[:, :6 * len(problem.cameras)] != 0, axis=1)  # not the clamp past the base
    jac = whole[:, problem.varied]  # a held camera's pose is certain
    weights = np.where(seen, 1.0 / (1.0 + (residuals / scale) ** 2), 0.0)
    variance = np.sum(weights * residuals**2) / max(np.sum(weights), 1.0)
    stretches = 0.0
    for index, _, _, _, measured, limbs in problem._evaluate(x):
        if limbs:
            continue
        inside = np.abs(measured.distance) <= 3 * scale
        if inside.any():
            extent = np.ptp(measured.foot_s[inside])
            stretches += max(extent / (WINDOW_PX * problem.recordings[index].footprint), 1.0)
    values, vectors = np.linalg.eigh(jac.T @ (weights[:, None] * jac))
    free = values <= FREE * values.max()
    fitted = (vectors[:, ~free] / values[~free]) @ vectors[:, ~free].T * variance * seen.sum() / max(stretches, 1)
    loose = np.sum(vectors[:, free] ** 2, axis=1) > 1e-3
    fitted[loose, loose] = np.inf
    covariance = np.zeros((problem.size, problem.size))
    covariance[np.ix_(problem.varied, problem.varied)] = fitted
    return covariance[:6 * len(problem.cameras), :6 * len(problem.cameras)]


def _in_report_units(sigma: np.ndarray) -> np.ndarray:
    """Turns (rad) to degrees and shifts (m) to millimetres."""
    return np.concatenate([np.degrees(sigma[:3]), sigma[3:] * 1e3])


def _result(problem: _Problem, x: np.ndarray, start_rows: dict[str, np.ndarray]) -> RigFit:
    cameras = problem.cameras
    covariance = _covariance(problem, x, SCALES_M[-1])
    sigma = {name: _in_report_units(np.sqrt(np.abs(np.diag(covariance))[6 * c:6 * c + 6]))
             for c, name in enumerate(cameras)}
    relative_sigma = np.zeros(6)
    if len(cameras) > 1:  # the second camera relative to the first
        first, second = slice(0, 6), slice(6, 12)
        relative = (covariance[first, first] + covariance[second, second] - covariance[first, second]
                    - covariance[second, first])
        relative_sigma = _in_report_units(np.sqrt(np.abs(np.diag(relative))))
    bends = {r.name: problem.bends(x, i) for i, r in enumerate(problem.recordings)}
    _refuse_undetermined(sigma, bends, problem.target is not None)
    rows = problem.camera_rows(x)
    fits = {name: robust_rms(rows[name], SCALES_M[-1]) for name in cameras}
    starts = {name: robust_rms(start_rows[name], SCALES_M[0])[0] for name in cameras}
    extrinsics = problem.extrinsics(x)
    return RigFit(extrinsics, sigma, relative_sigma,
                  {name: fits[name][0] * 1e3 for name in cameras}, {name: fits[name][1] for name in cameras},
                  bends, {name: value * 1e3 for name, value in starts.items()},
                  slots_in_view(problem.geometry, extrinsics) if problem.target is None else {})


def _refuse_undetermined(sigma: dict[str, np.ndarray], bends: dict[str, np.ndarray], target: bool = False) -> None:
    """CalibrationError naming each pose parameter the recordings leave free, and what to record instead."""
    free = [(name, k, values[k]) for name, values in sigma.items() for k in range(6) if not values[k] <= UNDETERMINED]
    if not free:
        return
    named = [f"{name}'s {'turn about' if k < 3 else 'position along'} {AXES[k % 3]} ("
             + (f"±{value:.2g} {'deg' if k < 3 else 'mm'})" if np.isfinite(value) else "free)")
             for name, k, value in free]
    straight = all(np.sum(b) < STRAIGHT_RAD for b in bends.values())
    advice = ("the target is symmetric where the cameras see it: use one that is not (a block with a step, balls "
              "of different sizes)" if target else
              "the robot was straight in every recording, a cylinder that may turn about its own axis unseen: "
              "record it bent as well (a total bend of 30 deg or more)" if straight else
              "record the robot in more poses, bent in other directions")
    raise CalibrationError(f"the recordings do not determine {', '.join(named)}: {advice}",
                           tuple(f"{name}.{'turn' if k < 3 else 'shift'}_{AXES[k % 3]}" for name, k, _ in free))
