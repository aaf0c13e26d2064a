"""The robot's own model fitted to one frame (issue 61, part 2): its roll in the clamp and one bend per notch.

The robot is known but for a handful of numbers (core.robot.kinematics): with its base where the rig file puts it,
its shape is its roll about the base's axis (the side its notches open to) and each notch's bend. One robust
least-squares problem (scipy.optimize.least_squares, Cauchy loss) fits them to what both cameras saw:

- every depth point lies on the tube of the robot's outer radius as its camera sees it (the half facing it; core.
  calibration.tube_distance), after a depth bias common to both cameras is taken off along its line of sight: two
  opposed cameras reading a shiny wall alike too deep see the tube fatter, not moved, and the bias is what the
  tube's known radius makes of that (a bias per camera was tried: with the base held, it traded with the bends
  along the views, and the matrix's centreline got worse on more rows than it got better);
- the model's axis lies midway between the tube's limbs in each camera's colour image (the sharp measurement:
  core.calibration.limb_rows), read about the model once the depth fit has it within a pixel.

A change of a parameter moves the model's centreline; every residual is a distance along a known direction (the
wall's normal, the direction across a view), so its Jacobian is that direction against the centreline's move at
the residual's arc length (core.robot.kinematics.TubeShape.centerline_jacobian, analytic). The loss's scale
narrows over rounds (SCALES_M), so a start some tenths of a millimetre off is pulled in before the wall's noise
decides. A cold start is the model nearest the centreline fitted freely to the same points (robust where the model
started far off would settle on a wrong roll); a warm start, the previous frame's fit.

    fit = fit_robot(points, camera, origins, geometry, views, guide)      # RobotFit; guide: the free centreline
    fit = fit_robot(..., start=previous_fit)                              # warm start: the previous frame's
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ntcr_recon.core.calibration.limb_rows import limb_rows
from ntcr_recon.core.calibration.rig_fit import robust_rms
from ntcr_recon.core.calibration.tube_distance import TubeDistance, tube_distance
from ntcr_recon.core.relocation.centerline import Centerline, base_pose
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

# The robust loss's scale per round (m): from a start's tenths of a millimetre to the wall's depth noise.
SCALES_M = (5.0e-4, 1.5e-4, 1.0e-4)
# The limbs are read from the round whose scale is this small on (the model then within a pixel or two).
LIMBS_FROM_SCALE_M = 1.5e-4
# A cold start: the rolls about the configured one it is started from (deg), and the samples of the freely fitted
# centreline it is started on.
START_ROLLS_DEG = (0.0, -90.0, 90.0, 180.0)
GUIDE_SAMPLES = 100
# Points the fit takes (an even sample): more add time, not accuracy.
MAX_POINTS = 1500
# A camera's limb stations count together as much as its points, each at most this many times one point.
LIMB_WEIGHT_MAX = 3.0
# What the parameters typically change by (the solver's scaling): roll, bends (rad), bias (m).
ROLL_SCALE_RAD, BEND_SCALE_RAD, BIAS_SCALE_M = 0.05, 0.01, 1.0e-4
# The common depth bias stays within this (m): a matcher reading a wall a millimetre off is not reading it.
MAX_BIAS_M = 1.0e-3
# How far beside a notch's opening the wall is not counted (m): about two pixels at 90 mm.
CUT_MARGIN_M = 0.4e-3
# Evaluations per round (a cold start's, a warm start's).
MAX_EVALUATIONS = 40
WARM_EVALUATIONS = 8
# A warm start whose points lie no farther off the last frame's fit than this many times its loss found them:
# the robot is still.
STILL_LOSS_RATIO = 1.3


@dataclass(frozen=True)
class RobotFit:
    """The fitted robot: its shape (roll and bends), the depth bias both cameras share (m, + read too deep), each
    camera's robust RMS off the fitted tube (mm) and its limb stations, and the robust loss reached."""

    shape: TubeShape
    roll: float
    bias: float
    residual_mm: dict[int, float]
    limb_stations: dict[int, int]
    parameters: np.ndarray      # roll, bends, bias
    loss_per_point: float       # the mean robust loss of the depth points at the last scale (_loss_per_point)

    def figures(self, camera_names: tuple[str, ...]) -> dict:
        """What the fit found, as plain numbers (the result's quality.model_fit): roll (deg), bends (deg), the
        depth bias (mm), and per camera the robust RMS off the fitted tube (mm) and the limb stations read."""
        return {"roll_deg": round(math.degrees(self.roll), 3),
                "bends_deg": [round(float(v), 4) for v in np.degrees(self.shape.notch_bend)],
                "depth_bias_mm": round(self.bias * 1e3, 4),
                "residual_mm": {camera_names[c]: round(v, 4) for c, v in self.residual_mm.items() if math.isfinite(v)},
                "limb_stations": {camera_names[c]: n for c, n in self.limb_stations.items()}}


class _Problem:
    """Residuals and Jacobian over x = [roll, bend per notch, common depth bias]."""

    def __init__(self, points: np.ndarray, camera: np.ndarray, origins: np.ndarray, geometry: TubeGeometry):
        self.points, self.camera, self.origins, self.geometry = points, camera, origins, geometry
        sight = points - origins[camera]
        self.rays = sight / np.linalg.norm(sight, axis=1)[:, None]
        self.notches = geometry.notch_count
        self.outlier = 3 * SCALES_M[0]
        self.limbs: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, float]] = []  # camera, s, middles, across, w
        self.counted = np.ones(len(points), bool)  # the depth points the fit rests on (clear_of_cuts)
        self.ignored = np.zeros(len(points), bool)  # past the base or beside a cut, as last evaluated
        self._cache: tuple[bytes, tuple] | None = None
        self._measured_at: tuple[bytes, TubeShape, TubeDistance] | None = None

    @property
    def size(self) -> int:
        return self.notches + 2

    def shape(self, x: np.ndarray) -> TubeShape:
        geometry = replace(self.geometry, notch_side=math.remainder(float(x[0]), 2 * math.pi))
        return TubeShape(geometry, np.clip(x[1:1 + self.notches], 0.0, geometry.max_notch_bend))

    def corrected(self, x: np.ndarray) -> np.ndarray:
        """The depth points with the depth bias x poses (its last parameter) taken off along their rays."""
        return self.points - x[-1] * self.rays

    def _measured(self, x: np.ndarray) -> tuple[TubeShape, TubeDistance]:
        """The shape x poses and each point's distance to its tube as its own camera sees it (the half facing it),
        the bias taken off along its ray: computed once per x (the counted points change between rounds only)."""
        key = x.tobytes()
        if self._measured_at is None or self._measured_at[0] != key:
            shape = self.shape(x)
            self._measured_at = (key, shape, tube_distance(shape, self.corrected(x), self.origins[self.camera]))
        return self._measured_at[1], self._measured_at[2]

    def _evaluate(self, x: np.ndarray) -> tuple:
        """Residuals, their directions, their arc lengths, which are depth rows, and the shape."""
        key = x.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        shape, measured = self._measured(x)
        # a wall seen edge-on is where a matcher fattens the silhouette: each point counts as its wall faces its
        # camera (the limbs place the axis across the view)
        facing = np.abs(np.einsum("ij,ij->i", measured.direction, self.rays))
        # past the base plane (the clamp or its post) or beside a cut: as far off as the loss's tail, whatever the
        # shape
        self.ignored = measured.below_base | ~self.counted
        distance = np.where(self.ignored, self.outlier, measured.distance * facing)
        direction = np.where(self.ignored[:, None], 0.0, measured.direction * facing[:, None])
        parts = [(distance, direction, measured.foot_s)]
        for _, s, middles, across, weight in self.limbs:
            s = np.minimum(s, shape.length)
            gap = np.einsum("ij,ij->i", across, middles - shape.centerline_points(s)) * weight
            parts.append((gap, across * weight, s))
        result = (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                  np.concatenate([p[2] for p in parts]), len(self.points), shape)
        self._cache = (key, result)
        return result

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self._evaluate(x)[0]

    def centerline_rates(self, shape: TubeShape, s: np.ndarray) -> np.ndarray:
        """How the shape's centreline at arc lengths s moves with the roll and each bend, (N, 1 + notches, 3): the
        roll turns the robot about its base's axis, a bend what lies past its notch (kinematics)."""
        at = np.minimum(s, shape.length)
        turn = np.cross(self.geometry.base_rotation[:, 2],
                        shape.centerline_points(at) - np.asarray(self.geometry.base_position, float))
        return np.concatenate([turn[:, None, :], shape.centerline_jacobian(at)], axis=1)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        _, direction, foot, depth_rows, shape = self._evaluate(x)
        jac = np.zeros((len(foot), self.size))
        jac[:, :-1] = -np.einsum("ij,ikj->ik", direction, self.centerline_rates(shape, foot))
        jac[:depth_rows, -1] = -np.einsum("ij,ij->i", direction[:depth_rows], self.rays)
        return jac

    def clear_of_cuts(self, x: np.ndarray, margin: float) -> None:
        """Count only the depth points clear of the notches' openings as x poses the robot (grown by `margin`
        along the tube and round it): a matcher's window reaching into a slot reads the wall beside it deep, in a
        pattern along the tube the bends would follow."""
        shape, measured = self._measured(x)
        s = measured.foot_s
        position, frames = shape.centerline(s)
        offset = self.corrected(x) - position
        angle = np.arctan2(np.einsum("ij,ij->i", offset, frames[:, :, 1]),
                           np.einsum("ij,ij->i", offset, frames[:, :, 0]))
        table = shape.notch_table()
        starts = np.array([n["start_s"] for n in table]) - margin
        ends = np.array([n["end_s"] for n in table]) + margin
        index = np.searchsorted(starts, s, side="right") - 1
        near_cut = (index >= 0) & (s <= ends[np.maximum(index, 0)])
        opening = np.abs(angle) < self.geometry.gap_half_angle + margin / self.geometry.outer_radius
        self.counted = ~(near_cut & opening)
        self._cache = None

    def read_limbs(self, x: np.ndarray, views: dict[int, object]) -> None:
        """Every camera's limbs about the robot as x poses it (core.calibration.limb_rows), in the base frame, each
        camera's stations weighted to count together as much as its points (at most LIMB_WEIGHT_MAX each)."""
        self.limbs = []
        shape = self.shape(x)
        for c, view in views.items():
            rows = limb_rows(0, c, shape, view.color, view.intrinsics, view.extrinsic)
            points = int(np.sum(self.camera == c))
            if rows is None or not points:
                continue
            rotation, origin = view.extrinsic[:3, :3], view.extrinsic[:3, 3]
            weight = min(math.sqrt(points / len(rows.s)), LIMB_WEIGHT_MAX)
            self.limbs.append((c, rows.s, rows.points @ rotation.T + origin, rows.across @ rotation.T, weight))
        self._cache = None


def _start_from(guide: Centerline, problem: _Problem) -> np.ndarray:
    """The roll and bends whose centreline lies nearest a freely fitted one (`guide`, core.relocation.centerline_fit:
    robust to where the model would start far off), started from rolls about the configured one (START_ROLLS_DEG);
    no depth bias."""
    geometry = problem.geometry
    s = np.linspace(0.0, min(guide.length, geometry.length), GUIDE_SAMPLES)
    target = guide.frames_at(s)[0]

    def residuals(x: np.ndarray) -> np.ndarray:
        shape = problem.shape(np.append(x, 0.0))
        return (shape.centerline_points(np.minimum(s, shape.length)) - target).ravel()

    def jacobian(x: np.ndarray) -> np.ndarray:
        rates = problem.centerline_rates(problem.shape(np.append(x, 0.0)), s)
        return rates.transpose(0, 2, 1).reshape(3 * len(s), -1)

    upper = np.full(problem.notches, geometry.max_notch_bend)
    best = None
    for turn in np.radians(START_ROLLS_DEG):
        start = np.concatenate([[geometry.notch_side + turn], upper * 0.1])
        solved = least_squares(residuals, start, jac=jacobian, bounds=(np.concatenate([[-np.inf], upper * 0]),
                                                                       np.concatenate([[np.inf], upper])))
        if best is None or solved.cost < best.cost:
            best = solved
    return np.append(best.x, 0.0)


def fit_robot(points: np.ndarray, camera: np.ndarray, origins: np.ndarray, geometry: TubeGeometry,
              views: dict[int, object], guide: Centerline, start: RobotFit | None = None,
              rng: np.random.Generator | None = None) -> RobotFit:
    """The robot's roll, bends and the cameras' common depth bias fitted to its points (N, 3, base frame; each
    seen by camera index `camera` from `origins` (C, 3)) and to its limbs in `views` (camera index ->
    core.relocation.limbs.CameraView). guide: the centreline fitted freely to the same points (the cold start's);
    start: a previous frame's fit (its roll and bends are the start, the guide unused)."""
    rng = np.random.default_rng(0) if rng is None else rng
    if len(points) > MAX_POINTS:
        keep = np.sort(rng.choice(len(points), MAX_POINTS, replace=False))
        points, camera = points[keep], camera[keep]
    problem = _Problem(points, camera, origins, geometry)
    x = start.parameters.copy() if start is not None else _start_from(guide, problem)
    # the roll within half a turn of its start (a straight robot leaves it free: it stays where it started)
    lower = np.concatenate([[x[0] - math.pi], np.zeros(problem.notches), [-MAX_BIAS_M]])
    upper = np.concatenate([[x[0] + math.pi], np.full(problem.notches, geometry.max_notch_bend), [MAX_BIAS_M]])
    typical = np.concatenate([[ROLL_SCALE_RAD], np.full(problem.notches, BEND_SCALE_RAD), [BIAS_SCALE_M]])
    # a warm start is near: each round converges in a few evaluations; one where the robot still lies as the last
    # frame's fit left it (its points as far off as they were then) needs the last round only, a robot that moved
    # a millimetre since the wide scales still
    scales, evaluations = SCALES_M, MAX_EVALUATIONS
    if start is not None:
        still = _loss_per_point(problem, x) <= STILL_LOSS_RATIO * start.loss_per_point
        scales, evaluations = (SCALES_M[-1:] if still else SCALES_M), WARM_EVALUATIONS
    for scale in scales:
        problem.outlier = 3 * scale
        problem.clear_of_cuts(x, CUT_MARGIN_M)
        if scale <= LIMBS_FROM_SCALE_M and views:
            problem.read_limbs(x, views)
        solved = least_squares(problem.residuals, np.clip(x, lower, upper), jac=problem.jacobian,
                               bounds=(lower, upper), loss="cauchy", f_scale=scale, x_scale=typical,
                               max_nfev=evaluations)
        x = solved.x
    loss = _loss_per_point(problem, x)
    residuals = problem.residuals(x)[:len(points)]
    residual_mm = {c: robust_rms(residuals[(camera == c) & ~problem.ignored], SCALES_M[-1])[0] * 1e3
                   for c in range(len(origins))}
    stations = {c: len(s) for c, s, *_ in problem.limbs}
    return RobotFit(problem.shape(x), math.remainder(float(x[0]), 2 * math.pi), float(x[-1]), residual_mm, stations,
                    x.copy(), loss)


def _loss_per_point(problem: _Problem, x: np.ndarray) -> float:
    """The mean Cauchy loss at the last round's scale of the depth points the fit counts about the robot as x
    poses it (the walls beside the slots as x places them)."""
    problem.outlier = 3 * SCALES_M[-1]
    problem.clear_of_cuts(x, CUT_MARGIN_M)
    residuals = problem.residuals(x)[:len(problem.points)][~problem.ignored]
    return float(np.mean(np.log1p((residuals / SCALES_M[-1]) ** 2))) if len(residuals) else math.inf


def model_axis(fit: RobotFit, configured: TubeGeometry, step: float) -> Centerline:
    """The fitted robot's centreline as the relocation's axis: samples `step` apart from the base to the robot's
    reach (core.robot.geometry.reach; past the tip it runs straight on, where the end is looked for), its frames
    untwisted about the configured robot's bend plane as the freely fitted centreline's are (the side the notches
    open to is measured against them)."""
    geometry = fit.shape.geometry
    on_robot = np.arange(0.0, fit.shape.length, step / 4)
    points, frames = fit.shape.centerline(np.append(on_robot, fit.shape.length))
    beyond = np.arange(step / 4, geometry.reach - fit.shape.length + step, step / 4)
    points = np.concatenate([points, points[-1] + beyond[:, None] * frames[-1, :, 2]])
    return Centerline.from_points(points, base_pose(configured)[2], step)
