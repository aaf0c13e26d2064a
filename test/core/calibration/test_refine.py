"""The second camera refined against the first from the graph's own frames (calibration.refine)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.tube_views import GEOMETRY, TRUE_POSES, recording

from ntcr_recon.core.base.transforms import matrix_to_quaternion, transform_points
from ntcr_recon.core.calibration.refine import RefineWindow, recording_from_cloud, refine_relative
from ntcr_recon.core.calibration.rig_fit import CalibrationError, Recording, pivot_of, pose_change
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import CalibrationConfig, CameraConfig, RigConfig

BENT = np.linspace(0.06, 0.045, GEOMETRY.notch_count)


def _config(poses: dict) -> RigConfig:
    cameras = {name: CameraConfig(name, translation=tuple(pose[:3, 3]),
                                  rotation=tuple(matrix_to_quaternion(pose[:3, :3])))
               for name, pose in poses.items()}
    return RigConfig(camera_names=tuple(poses), cameras=cameras, robot=GEOMETRY)


def _knocked(turn_deg: float, shift_mm: float) -> np.ndarray:
    """cam_b turned about a tilted axis through its optical centre and shifted along a slanted direction."""
    pose = TRUE_POSES["cam_b"].copy()
    pose[:3, :3] = Rotation.from_rotvec(np.radians(turn_deg) * np.array([0.6, 0.48, 0.64])).as_matrix() @ pose[:3, :3]
    pose[:3, 3] += np.array([0.36, 0.48, -0.8]) * shift_mm * 1e-3
    return pose


@pytest.fixture(scope="module")
def bent_frames():
    rng = np.random.default_rng(5)
    return [recording(f"frame {k}", BENT * (1 - 0.2 * k), rng) for k in range(2)]


def test_a_second_camera_knocked_by_a_degree_and_a_millimetre_comes_back_against_the_first(bent_frames):
    knocked = _config({"cam_a": TRUE_POSES["cam_a"], "cam_b": _knocked(1.0, 1.0)})
    refined = refine_relative(bent_frames, knocked)
    error = pose_change(TRUE_POSES["cam_b"], refined.extrinsic, pivot_of(GEOMETRY))
    assert np.all(np.abs(error[:3]) < 0.02) and np.all(np.abs(error[3:]) < 0.02), error
    # the change undoes the knock, and it is beyond what the refinement resolves: significant
    expected = pose_change(knocked.cameras["cam_b"].extrinsic, TRUE_POSES["cam_b"], pivot_of(GEOMETRY))
    np.testing.assert_allclose(refined.change, expected, atol=0.02)
    assert refined.significant and refined.frames == 2
    assert (refined.camera, refined.reference) == ("cam_b", "cam_a")
    assert np.all(refined.uncertainty > 0) and np.all(refined.uncertainty < 0.05)


def test_an_exact_rig_is_left_as_it_is(bent_frames):
    refined = refine_relative(bent_frames, _config(TRUE_POSES))
    assert np.all(np.abs(refined.change) < 0.02) and not refined.significant
    figures = refined.as_dict()
    assert figures["significant"] is False and len(figures["turn_deg"]) == 3


def test_a_straight_robot_gives_no_refinement_and_says_which_turn_it_leaves_free():
    rng = np.random.default_rng(9)
    straight = [recording("straight", np.zeros(GEOMETRY.notch_count), rng)]
    knocked = _config({"cam_a": TRUE_POSES["cam_a"], "cam_b": _knocked(0.0, 0.5)})
    with pytest.raises(CalibrationError) as refused:
        refine_relative(straight, knocked)
    assert "cam_b.turn_z" in refused.value.free and not any(code.startswith("cam_a") for code in refused.value.free)


def test_a_fused_cloud_goes_back_into_each_cameras_optical_frame():
    rng = np.random.default_rng(1)
    optical = {name: rng.normal([0, 0, 0.09], 0.002, size=(50, 3)) for name in TRUE_POSES}
    config = _config(TRUE_POSES)
    xyz = np.concatenate([transform_points(TRUE_POSES[name], points) for name, points in optical.items()])
    cloud = Cloud(xyz, camera=np.repeat(np.arange(2, dtype=np.int8), 50), stamp_ns=5, pixel_footprint=2e-4)
    found = recording_from_cloud("frame", cloud, config, max_points=30)
    for name, points in optical.items():
        assert found.pixels[name] == 50 and len(found.points[name]) == 30
        distances = np.linalg.norm(found.points[name][:, None] - points[None], axis=2).min(axis=1)
        assert distances.max() < 1e-12
    assert found.footprint == 2e-4 and not found.straight
    with pytest.raises(ValueError, match="which camera"):
        recording_from_cloud("frame", Cloud(xyz), config)


def test_the_window_keeps_frames_spread_over_the_period_and_refines_once_a_period():
    window = RefineWindow(CalibrationConfig(refine=True, refine_frames=3, refine_period=6.0))
    kept = [window.offer(stamp, _named(stamp)) for stamp in (0.0, 1.0, 2.0, 3.5, 4.0, 5.0)]
    assert kept == [True, False, True, False, True, False]
    assert window.due(4.0)
    assert [r.name for r in window.take(4.0)] == ["0.0", "2.0", "4.0"]
    assert not window.due(8.0) and window.offer(8.0, _named(8.0))
    assert window.due(10.0)
    # a replay looping back starts afresh
    assert window.offer(1.0, _named(1.0)) and len(window.frames) == 1 and window.last_refined is None


def _named(stamp: float) -> Recording:
    return Recording(str(stamp), {}, {})
