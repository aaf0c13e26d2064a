"""The Relocator takes each camera's colour image (the limbs there place the axis across its view)."""

import numpy as np
import pytest
from support.tiny_rig import rig_parameters

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair
from ntcr_recon.core.config.rig import rig_config_from_mapping
from ntcr_recon.core.reconstruction.relocate import Relocator


def test_note_view_keeps_the_latest_image_per_camera_and_names_a_bad_one():
    config = rig_config_from_mapping(rig_parameters())
    relocator = Relocator(config)
    camera = config.camera_names[0]
    intrinsics = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    relocator.note_view(camera, np.zeros((48, 64, 3), np.uint8), intrinsics)
    relocator.note_view(camera, np.full((48, 64, 3), 7, np.uint8), intrinsics)
    assert list(relocator.views) == [camera] and relocator.views[camera].color[0, 0, 0] == 7
    np.testing.assert_array_equal(relocator.views[camera].extrinsic, config.cameras[camera].extrinsic)
    with pytest.raises(ValueError, match="cam_x"):
        relocator.note_view("cam_x", np.zeros((48, 64, 3), np.uint8), intrinsics)
    with pytest.raises(ValueError, match="64x48"):
        relocator.note_view(camera, np.zeros((48, 64), np.uint8), intrinsics)


def test_a_colour_image_of_another_size_than_the_depth_is_not_used():
    """A colour stream registered to depth only by scaling places no edge to a pixel: the frames are fused as
    before (the cloud's colours scaled), the relocation places that view by depth alone."""
    config = rig_config_from_mapping(rig_parameters())
    relocator = Relocator(config)
    camera = config.camera_names[0]
    intrinsics = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    depth = np.full((48, 64), 900, np.uint16)
    pair = FramePair(0, {camera: CameraFrame(camera, 0, depth=depth, intrinsics=intrinsics,
                                             color=np.zeros((96, 128, 3), np.uint8))})
    relocator.note_frames(pair)
    assert relocator.views == {}
    aligned = FramePair(1, {camera: CameraFrame(camera, 1, depth=depth, intrinsics=intrinsics,
                                                color=np.zeros((48, 64, 3), np.uint8))})
    relocator.note_frames(aligned)
    assert list(relocator.views) == [camera]


def test_a_pair_without_a_camera_leaves_no_view_of_another_instant():
    config = rig_config_from_mapping(rig_parameters())
    relocator = Relocator(config)
    cam_a, cam_b = config.camera_names[:2]
    intrinsics = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)

    def frame(camera, stamp):
        return CameraFrame(camera, stamp, depth=np.full((48, 64), 900, np.uint16), intrinsics=intrinsics,
                           color=np.zeros((48, 64, 3), np.uint8))

    relocator.note_frames(FramePair(0, {cam_a: frame(cam_a, 0), cam_b: frame(cam_b, 0)}))
    assert set(relocator.views) == {cam_a, cam_b}
    relocator.note_frames(FramePair(1, {cam_a: frame(cam_a, 1)}))  # cam_b dropped this frame
    assert list(relocator.views) == [cam_a]
