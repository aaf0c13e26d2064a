"""The rig calibrated from the robot it watches (issue 62): both cameras' poses in the robot's base frame.

The robot defines the base frame (DESIGN.md): its proximal segment's axis is z, its base end cap z = 0, the notch
side x, as the rig file's `robot` section places it. Over every recording at once, one robust least-squares
problem (scipy.optimize.least_squares, Cauchy loss) fits each camera's pose (a turn and a shift about the robot's
middle, applied to the rig file's pose) and each recording's bend of every notch (the robot's kinematics,
core.robot.kinematics; a recording holds the robot still) so that every point the cameras saw lies on the robot's
tube (core.calibration.tube_distance). The loss's scale narrows over rounds (SCALES_M), so a start a few
millimetres and degrees off is pulled in before the wall's tenth of a millimetre decides; each round restarts the
turn from the pose the last one reached, where its Jacobian is exact.

What a recording cannot fix is refused by name: a straight tube is a cylinder, so neither camera's turn about the
robot's axis is determined until the robot bends (CalibrationError says so and what to record). The uncertainty of
each pose parameter comes from the fit's covariance, the residual's robust spread scaled up by the points a stereo
matcher's window correlates (CORRELATED_PIXELS, of those the fit kept); a depth bias common to a camera's whole
view is not in it (along its view it moves the camera's pose alike).

    fit = fit_rig(recordings, geometry, start_extrinsics)     # RigFit: extrinsics, uncertainties, residuals, bends
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ntcr_recon.core.calibration.tube_distance import bend_jacobian, tube_distance
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

# The robust loss's scale per round (m): from the rough pose's millimetres to the wall's depth noise.
SCALES_M = (2.0e-3, 5.0e-4, 1.5e-4, 1.0e-4)
# Uniform bends tried for each recording's start (fractions of the notches' closing angle).
START_BENDS = np.linspace(0.0, 1.0, 11)
# Pixels a stereo matcher's window (the D405's is about 9 x 9) makes err together: the covariance counts them once.
CORRELATED_PIXELS = 81
# How much neighbouring notches' bends differ (rad): one tendon bends identical notches alike (York et al. 2015),
# friction a little less distally. Without it a shift along the robot would trade against bends moved a notch over.
BEND_STEP_SIGMA = np.radians(0.3)
# A pose parameter whose 1-sigma exceeds this (deg or mm) is not determined by the recordings: refused.
UNDETERMINED = 1.0
# A recording whose total bend stays below this (rad) leaves the tube a cylinder about its axis.
STRAIGHT_RAD = np.radians(5.0)
AXES = ("x", "y", "z")


class CalibrationError(ValueError):
    """The recordings cannot give the poses asked for; the message names the parameter and what to record."""


@dataclass(frozen=True)
class Recording:
    """One still pose of the robot: each camera's points of it in its own optical frame (m), and how many pixels
    those points were taken from (for the covariance's correlation)."""

    name: str
    points: dict[str, np.ndarray]
    pixels: dict[str, int]


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


def pivot_of(geometry: TubeGeometry) -> np.ndarray:
    """The straight robot's middle in the base frame: the turns' centre (a turn about a camera's own origin, 90 mm
    away, would move the robot as much as a shift and condition the fit badly)."""
    axis = geometry.base_rotation[:, 2]
    return np.asarray(geometry.base_position, float) + axis * geometry.length / 2.0


class _Problem:
    """The residuals and Jacobian over [turn, shift] per camera and the bends per recording."""

    def __init__(self, recordings: list[Recording], geometry: TubeGeometry, cameras: tuple[str, ...],
                 extrinsics: dict[str, np.ndarray]):
        self.recordings, self.geometry, self.cameras = recordings, geometry, cameras
        self.pivot = pivot_of(geometry)
        self.notches = geometry.notch_count
        self.prior_scale = SCALES_M[0]
        self.set_start(extrinsics)
        self._cache: tuple[bytes, list] | None = None

    def set_start(self, extrinsics: dict[str, np.ndarray]) -> None:
        self.start = {name: matrix.copy() for name, matrix in extrinsics.items()}
        self.centred = [{name: (points @ self.start[name][:3, :3].T + self.start[name][:3, 3]) - self.pivot
                         for name, points in recording.points.items()} for recording in self.recordings]
        self._cache = None

    @property
    def size(self) -> int:
        return 6 * len(self.cameras) + self.notches * len(self.recordings)

    def bends(self, x: np.ndarray, index: int) -> np.ndarray:
        start = 6 * len(self.cameras) + self.notches * index
        return x[start:start + self.notches]

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
        parts = []
        for index, centred in enumerate(self.centred):
            shape = TubeShape(self.geometry, np.clip(self.bends(x, index), 0.0, self.geometry.max_notch_bend))
            for c, name in enumerate(self.cameras):
                if name not in centred:
                    continue
                turn = Rotation.from_rotvec(x[6 * c:6 * c + 3]).as_matrix()
                moved = centred[name] @ turn.T + x[6 * c + 3:6 * c + 6]
                origin = turn @ (self.start[name][:3, 3] - self.pivot) + self.pivot + x[6 * c + 3:6 * c + 6]
                measured = tube_distance(shape, moved + self.pivot, origin)
                # What lies past the base plane is the clamp or its post: as far off as the loss's tail, whatever
                # the pose, so it neither pulls nor pushes.
                measured.distance[measured.below_base] = 3 * self.prior_scale
                measured.direction[measured.below_base] = 0.0
                parts.append((index, c, moved, shape, measured))
        self._cache = (key, parts)
        return parts

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([part[4].distance for part in self._evaluate(x)] + [self.prior @ x])

    @property
    def prior(self) -> np.ndarray:
        """Rows of the bends' prior: each neighbour's difference in units of BEND_STEP_SIGMA, times the loss's scale
        (so that a difference of one sigma weighs as a point one scale off the tube)."""
        rows = []
        for index in range(len(self.recordings)):
            start = 6 * len(self.cameras) + self.notches * index
            for notch in range(self.notches - 1):
                row = np.zeros(self.size)
                row[start + notch], row[start + notch + 1] = -1.0, 1.0
                rows.append(row * self.prior_scale / BEND_STEP_SIGMA)
        return np.array(rows).reshape(-1, self.size)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        parts = self._evaluate(x)
        prior = self.prior
        rows = sum(len(part[4].distance) for part in parts)
        jac = np.zeros((rows + len(prior), self.size))
        jac[rows:] = prior
        row = 0
        for index, c, moved, shape, measured in parts:
            block = slice(row, row + len(measured.distance))
            # d distance / d turn: the gradient against the point's move (turn x its offset from the pivot).
            jac[block, 6 * c:6 * c + 3] = np.cross(moved, measured.direction)
            jac[block, 6 * c + 3:6 * c + 6] = measured.direction
            start = 6 * len(self.cameras) + self.notches * index
            jac[block, start:start + self.notches] = bend_jacobian(shape, measured)
            row += len(measured.distance)
        return jac

    def camera_rows(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """Each camera's residuals (m), over all recordings."""
        found: dict[str, list] = {name: [] for name in self.cameras}
        for _, c, _, _, measured in self._evaluate(x):
            found[self.cameras[c]].append(measured.distance)
        return {name: np.concatenate(values) if values else np.empty(0) for name, values in found.items()}


def _robust_rms(residuals: np.ndarray, scale: float) -> tuple[float, float]:
    """The RMS (m) of residuals within 3 scales, and their share."""
    inside = np.abs(residuals) <= 3 * scale
    if not inside.any():
        return float("nan"), 0.0
    return float(np.sqrt(np.mean(residuals[inside] ** 2))), float(inside.mean())


def _start_bends(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """Each recording's bends started where a uniform bend fits the start poses best (Cauchy cost, first scale)."""
    x = x.copy()
    for index in range(len(problem.recordings)):
        costs = []
        for fraction in START_BENDS:
            trial = x.copy()
            start = 6 * len(problem.cameras) + problem.notches * index
            trial[start:start + problem.notches] = fraction * problem.geometry.max_notch_bend
            residual = problem.residuals(trial) / SCALES_M[0]
            costs.append(np.sum(np.log1p(residual**2)))
        best = START_BENDS[int(np.argmin(costs))] * problem.geometry.max_notch_bend
        x[6 * len(problem.cameras) + problem.notches * index:][:problem.notches] = best
    return x


def fit_rig(recordings: list[Recording], geometry: TubeGeometry, start: dict[str, np.ndarray],
            progress: Callable[[str], None] | None = None) -> RigFit:
    """Both cameras' poses (base frame) and every recording's bends fitted to what the cameras saw."""
    cameras = tuple(start)
    if not recordings:
        raise CalibrationError("no recording to calibrate from")
    for name in cameras:
        if not any(len(r.points.get(name, ())) for r in recordings):
            raise CalibrationError(f"{name} saw none of the robot in any recording: check its rough pose and "
                                   "that the robot is in its view")
    problem = _Problem(recordings, geometry, cameras, start)
    x = _start_bends(problem, np.zeros(problem.size))
    start_rows = problem.camera_rows(x)
    upper = np.full(problem.size, np.inf)
    upper[6 * len(cameras):] = geometry.max_notch_bend
    lower = np.where(np.isinf(upper), -np.inf, 0.0)
    for round_index, scale in enumerate(SCALES_M):
        if progress:
            progress(f"round {round_index + 1}/{len(SCALES_M)}: loss scale {scale * 1e3:.2f} mm")
        problem.prior_scale = scale
        solved = least_squares(problem.residuals, np.clip(x, lower, upper), jac=problem.jacobian,
                               bounds=(lower, upper), loss="cauchy", f_scale=scale, x_scale="jac", max_nfev=60)
        x = solved.x
        problem.set_start(problem.extrinsics(x))  # the turns restart from zero, where their Jacobian is exact
        x[:6 * len(cameras)] = 0.0
    return _result(problem, x, start_rows)


def _covariance(problem: _Problem, x: np.ndarray, scale: float) -> np.ndarray:
    """The camera parameters' covariance, the bends marginalised: the Cauchy loss's weights, the residuals' robust
    variance, and the points a matcher's window correlates counted once."""
    residuals = problem.residuals(x)
    jac = problem.jacobian(x)
    prior_rows = len(problem.prior)
    data = slice(0, len(residuals) - prior_rows)
    weights = 1.0 / (1.0 + (residuals[data] / scale) ** 2)
    variance = np.sum(weights * residuals[data] ** 2) / max(np.sum(weights) - problem.size, 1.0)
    pixels = sum(sum(r.pixels.values()) for r in problem.recordings)
    correlated = max(1.0, CORRELATED_PIXELS * (len(residuals) - prior_rows) / max(pixels, 1))
    prior = jac[len(residuals) - prior_rows:]
    # The prior's rows weigh a bend step of BEND_STEP_SIGMA as one scale: in units of the data's variance.
    normal = jac[data].T @ (weights[:, None] * jac[data]) / correlated + prior.T @ prior * variance / scale**2
    covariance = np.linalg.pinv(normal, rcond=1e-12, hermitian=True) * variance
    undetermined = np.diag(normal) <= 0
    covariance[undetermined, undetermined] = np.inf
    return covariance[:6 * len(problem.cameras), :6 * len(problem.cameras)]


def _in_report_units(sigma: np.ndarray) -> np.ndarray:
    """Turns (rad) to degrees and shifts (m) to millimetres."""
    return np.concatenate([np.degrees(sigma[:3]), sigma[3:] * 1e3])


def _result(problem: _Problem, x: np.ndarray, start_rows: dict[str, np.ndarray]) -> RigFit:
    cameras = problem.cameras
    covariance = _covariance(problem, x, SCALES_M[-1])
    # A cylinder's turn about its own axis leaves it in place: the covariance there is numerical noise.
    sigma = {name: _in_report_units(np.sqrt(np.abs(np.diag(covariance))[6 * c:6 * c + 6]))
             for c, name in enumerate(cameras)}
    first, second = slice(0, 6), slice(6, 12)
    relative = (covariance[first, first] + covariance[second, second] - covariance[first, second]
                - covariance[second, first])
    relative_sigma = _in_report_units(np.sqrt(np.abs(np.diag(relative)))) if len(cameras) > 1 else np.zeros(6)
    bends = {r.name: np.clip(problem.bends(x, i), 0.0, problem.geometry.max_notch_bend)
             for i, r in enumerate(problem.recordings)}
    _refuse_undetermined(sigma, bends)
    rows = problem.camera_rows(x)
    fits = {name: _robust_rms(rows[name], SCALES_M[-1]) for name in cameras}
    starts = {name: _robust_rms(start_rows[name], SCALES_M[0])[0] for name in cameras}
    return RigFit(problem.extrinsics(x), sigma, relative_sigma,
                  {name: fits[name][0] * 1e3 for name in cameras}, {name: fits[name][1] for name in cameras},
                  bends, {name: value * 1e3 for name, value in starts.items()})


def _refuse_undetermined(sigma: dict[str, np.ndarray], bends: dict[str, np.ndarray]) -> None:
    """CalibrationError naming each pose parameter the recordings leave free, and what to record instead."""
    loose = [f"{name}'s {'turn about' if k < 3 else 'position along'} {AXES[k % 3]}"
             f" (±{values[k]:.2g} {'deg' if k < 3 else 'mm'})"
             for name, values in sigma.items() for k in range(6) if not values[k] <= UNDETERMINED]
    if not loose:
        return
    straight = all(np.sum(b) < STRAIGHT_RAD for b in bends.values())
    advice = ("the robot was straight in every recording, a cylinder that may turn about its own axis unseen: "
              "record it bent as well (a total bend of 30 deg or more)" if straight else
              "record the robot in more poses, bent in other directions")
    raise CalibrationError(f"the recordings do not determine {', '.join(loose)}: {advice}")
