"""The robot's own model fitted to one frame's points (core.fit.robot_fit): exact walls of a known robot, as two
opposed cameras see them, give back its roll, bends and the depth bias both cameras share."""

from dataclasses import replace

import numpy as np
import pytest
from support.tube_views import GEOMETRY, TRUE_POSES, seen_wall

from ntcr_recon.core.base.transforms import transform_points
from ntcr_recon.core.config.rig import RelocationConfig
from ntcr_recon.core.fit.robot_fit import fit_robot, model_axis
from ntcr_recon.core.quality.metrics import centerline_rmse
from ntcr_recon.core.relocation.centerline_fit import estimate_centerline, settings_for
from ntcr_recon.core.robot.kinematics import TubeShape

ROLL = 0.3  # rad: the robot turned in its clamp off the configured side (0)
BENDS = np.radians(np.linspace(4.0, 1.5, GEOMETRY.notch_count))  # a tendon's falling profile


def _frame(shape: TubeShape, rng, bias=(0.0, 0.0)):
    """Both cameras' wall points in the base frame (camera index per point), each camera's read `bias` (m) too
    deep."""
    points, camera = [], []
    for index, (name, pose) in enumerate(TRUE_POSES.items()):
        seen = transform_points(pose, seen_wall(shape, name, rng, count=2000))
        ray = seen - pose[:3, 3]
        points.append(seen + bias[index] * ray / np.linalg.norm(ray, axis=1)[:, None])
        camera.append(np.full(len(seen), index))
    return np.concatenate(points), np.concatenate(camera)


@pytest.fixture(scope="module")
def truth() -> TubeShape:
    return TubeShape(replace(GEOMETRY, notch_side=ROLL), BENDS)


@pytest.fixture(scope="module")
def origins() -> np.ndarray:
    return np.array([pose[:3, 3] for pose in TRUE_POSES.values()])


def _fit(shape: TubeShape, rng, origins, bias=(0.0, 0.0), start=None):
    """The model fitted to the shape's walls, cold-started from the centreline fitted freely to them (configured
    roll 0: the robot is turned in its clamp by ROLL)."""
    points, camera = _frame(shape, rng, bias)
    guide, _, _ = estimate_centerline(points, GEOMETRY, settings_for(GEOMETRY, 0.2e-3, RelocationConfig()), None,
                                      origins)
    return fit_robot(points, camera, origins, GEOMETRY, {}, guide, start)


def _centerline_error(fit, truth: TubeShape) -> float:
    samples = fit.shape.centerline_points(np.linspace(0.0, fit.shape.length, 500))
    return centerline_rmse(samples, truth.centerline_points(np.linspace(0.0, truth.length, 4000)))


def test_the_fit_gives_back_the_roll_the_bends_and_the_depth_bias_both_cameras_share(truth, origins):
    fit = _fit(truth, np.random.default_rng(3), origins, bias=(60e-6, 60e-6))
    assert abs(fit.roll - ROLL) < np.radians(1.0)
    assert abs(fit.bias - 60e-6) < 10e-6
    assert np.degrees(np.abs(fit.shape.notch_bend - BENDS)).max() < 0.5
    assert _centerline_error(fit, truth) < 10e-6
    assert np.linalg.norm(fit.shape.tip_pose()[0] - truth.tip_pose()[0]) < 30e-6
    assert max(fit.residual_mm.values()) < 0.02


def test_a_warm_start_stays_where_the_robot_is_and_follows_it(truth, origins):
    rng = np.random.default_rng(4)
    cold = _fit(truth, rng, origins)
    moved = TubeShape(truth.geometry, BENDS * 1.05)  # the next frame: the tendon pulled a little further
    warm = _fit(moved, rng, origins, start=cold)
    assert _centerline_error(warm, moved) < 15e-6
    assert _centerline_error(cold, moved) > 3 * _centerline_error(warm, moved)
    # the next frame: the robot still (only the last round runs), its points as far off the fit as before
    still = _fit(moved, rng, origins, start=warm)
    assert _centerline_error(still, moved) < 15e-6
    assert still.loss_per_point < 1.3 * warm.loss_per_point


def test_the_model_axis_runs_from_the_base_past_the_tip_to_the_robots_reach(truth, origins):
    fit = _fit(truth, np.random.default_rng(5), origins)
    axis = model_axis(fit, GEOMETRY, 0.4e-3)
    assert axis.length == pytest.approx(GEOMETRY.reach, abs=0.4e-3)
    position, tangent, _, _ = axis.frames_at(np.array([fit.shape.length]))
    tip, frame = fit.shape.tip_pose()
    assert np.linalg.norm(position[0] - tip) < 5e-6 and tangent[0] @ frame[:, 2] > 0.9999
