"""The rig fitted to the robot's tube: on exact points of the true surface, what each camera sees of it."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.tube_views import GEOMETRY, TRUE_POSES
from support.tube_views import recording as _recording

from ntcr_recon.core.base.transforms import invert_transform, transform_points
from ntcr_recon.core.calibration.rig_fit import CalibrationError, Recording, fit_rig, pivot_of, slots_in_view


def _moved(pose, turn_deg, shift_mm, rng):
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    moved = pose.copy()
    moved[:3, :3] = Rotation.from_rotvec(np.radians(turn_deg) * axis / np.linalg.norm(axis)).as_matrix() @ pose[:3, :3]
    moved[:3, 3] += direction / np.linalg.norm(direction) * shift_mm * 1e-3
    return moved


def _error(estimate, truth):
    """The turn left (deg) and the robot's middle moved (mm)."""
    change = estimate @ invert_transform(truth)
    pivot = pivot_of(GEOMETRY)
    return (np.degrees(np.linalg.norm(Rotation.from_matrix(change[:3, :3]).as_rotvec())),
            np.linalg.norm(change[:3, :3] @ pivot + change[:3, 3] - pivot) * 1e3)


@pytest.fixture(scope="module")
def recordings():
    rng = np.random.default_rng(7)
    bent = np.linspace(0.06, 0.045, GEOMETRY.notch_count)  # 3.4 deg at the base to 2.6 at the tip
    return [_recording("straight", np.zeros(GEOMETRY.notch_count), rng, straight=True),
            _recording("bent", bent, rng)], bent


def test_poses_two_degrees_and_millimetres_off_come_back_from_a_straight_and_a_bent_recording(recordings):
    found, bent = recordings
    rng = np.random.default_rng(11)
    start = {camera: _moved(pose, 2.0, 2.0, rng) for camera, pose in TRUE_POSES.items()}
    fit = fit_rig(found, GEOMETRY, start)
    for camera, pose in TRUE_POSES.items():
        turn, shift = _error(fit.extrinsics[camera], pose)
        assert turn < 0.01 and shift < 0.01, (camera, turn, shift)
        assert fit.residual_mm[camera] < 0.02 and fit.inliers[camera] > 0.95
        assert fit.start_residual_mm[camera] > 0.3  # two millimetres off, the tube was far from the points
    relative = invert_transform(fit.extrinsics["cam_a"]) @ fit.extrinsics["cam_b"]
    turn, shift = _error(TRUE_POSES["cam_a"] @ relative, TRUE_POSES["cam_b"])
    assert turn < 0.01 and shift < 0.01
    np.testing.assert_allclose(fit.bends["bent"], bent, atol=np.radians(0.1))
    np.testing.assert_array_equal(fit.bends["straight"], 0.0)
    assert np.all(np.isfinite(fit.relative_uncertainty)) and np.all(fit.relative_uncertainty < [0.05] * 3 + [0.05] * 3)


def test_a_robot_straight_in_every_recording_leaves_each_cameras_turn_about_its_axis_free(recordings):
    found, _ = recordings
    with pytest.raises(CalibrationError) as refused:
        fit_rig([found[0]], GEOMETRY, dict(TRUE_POSES))
    assert {"cam_a.turn_z", "cam_b.turn_z"} <= set(refused.value.free)
    assert not {"cam_a.shift_x", "cam_b.shift_x"} & set(refused.value.free)  # across the views: seen


def test_a_camera_that_saw_nothing_is_refused_by_name(recordings):
    found, _ = recordings
    blind = [Recording(r.name, {"cam_a": r.points["cam_a"], "cam_b": np.empty((0, 3))}, r.pixels, r.straight)
             for r in found]
    with pytest.raises(CalibrationError, match="cam_b saw none of the robot"):
        fit_rig(blind, GEOMETRY, dict(TRUE_POSES))


def test_a_camera_the_notches_open_towards_is_named_with_its_angle():
    import dataclasses

    assert slots_in_view(GEOMETRY, TRUE_POSES) == {}  # notches towards +x: side-on to both
    towards_cam_a = dataclasses.replace(GEOMETRY, notch_side=np.radians(-80.0))  # cam_a sits at -y
    facing = slots_in_view(towards_cam_a, TRUE_POSES)
    assert list(facing) == ["cam_a"] and 2.0 < facing["cam_a"] < 8.0  # 10 deg off -y, cam_a 6 deg off it in x


def _hull_target(points):
    from scipy.spatial import ConvexHull

    from ntcr_recon.core.calibration.target import RigidTarget

    hull = ConvexHull(points)
    return RigidTarget.from_mesh(points, hull.simplices)


def _seen_target(target, camera, rng, count=4000, noise=20e-6):
    """The target's faces that face the camera (a convex target hides nothing else), optical frame, with depth
    noise along each pixel's ray."""
    outward = np.sign(np.einsum("ij,ij->i", target.samples - target.centre, target.normals))[:, None] * target.normals
    origin = TRUE_POSES[camera][:3, 3]
    facing = np.einsum("ij,ij->i", outward, target.samples - origin) < 0
    optical = transform_points(invert_transform(TRUE_POSES[camera]), target.samples[facing])
    optical = optical[rng.choice(len(optical), min(count, len(optical)), replace=False)]
    return optical * (1 + rng.normal(0, noise, len(optical)) / optical[:, 2])[:, None]


def test_a_rigid_target_mesh_gives_the_poses_in_its_own_frame():
    rng = np.random.default_rng(5)
    corners = np.array([[0, -6, 0], [14, -5, 2], [12, 7, -1], [-1, 6, 3], [1, -4, 20], [11, -6, 17], [9, 5, 24],
                        [-2, 4, 16], [5, 0, 30]], float) * 1e-3  # an irregular solid about 15 x 13 x 30 mm
    target = _hull_target(corners)
    points = {camera: _seen_target(target, camera, rng) for camera in TRUE_POSES}
    recording = Recording("block", points, {camera: len(p) for camera, p in points.items()}, straight=True)
    start = {camera: _moved(pose, 2.0, 2.0, rng) for camera, pose in TRUE_POSES.items()}
    fit = fit_rig([recording], GEOMETRY, start, target=target)
    for camera, pose in TRUE_POSES.items():
        change = fit.extrinsics[camera] @ invert_transform(pose)
        turn = np.degrees(np.linalg.norm(Rotation.from_matrix(change[:3, :3]).as_rotvec()))
        shift = np.linalg.norm(change[:3, :3] @ target.centre + change[:3, 3] - target.centre) * 1e3
        assert turn < 0.02 and shift < 0.01, (camera, turn, shift)
    assert fit.facing_slots == {}


def test_a_ball_leaves_every_turn_about_its_centre_free():
    rng = np.random.default_rng(6)
    directions = rng.normal(size=(3000, 3))
    ball = _hull_target(directions / np.linalg.norm(directions, axis=1)[:, None] * 8e-3 + [0.01, 0.0, 0.022])
    points = {camera: _seen_target(ball, camera, rng) for camera in TRUE_POSES}
    with pytest.raises(CalibrationError, match="symmetric") as refused:
        fit_rig([Recording("ball", points, {c: len(p) for c, p in points.items()}, straight=True)], GEOMETRY,
                dict(TRUE_POSES), target=ball)
    assert {"cam_a.turn_x", "cam_a.turn_y", "cam_a.turn_z"} <= set(refused.value.free)
