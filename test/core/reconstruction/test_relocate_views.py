"""The Relocator takes each camera's colour image (the limbs there place the axis across its view)."""

import numpy as np
import pytest
from support.tiny_rig import rig_parameters

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import rig_config_from_mapping
from ntcr_recon.core.reconstruction.relocate import Relocator
from ntcr_recon.core.relocation.limbs import WINDOW_MARGIN_PX

INTRINSICS = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)


def test_note_view_keeps_the_latest_image_per_camera_and_names_a_bad_one():
    config = rig_config_from_mapping(rig_parameters(relocation={"limbs": True}))
    relocator = Relocator(config)
    camera = config.camera_names[0]
    intrinsics = INTRINSICS
    relocator.note_view(camera, np.zeros((48, 64, 3), np.uint8), intrinsics)
    relocator.note_view(camera, np.full((48, 64, 3), 7, np.uint8), intrinsics)
    assert list(relocator.views) == [camera] and relocator.views[camera].color[0, 0, 0] == 7
    np.testing.assert_array_equal(relocator.views[camera].extrinsic, config.cameras[camera].extrinsic)
    with pytest.raises(ValueError, match="cam_x"):
        relocator.note_view("cam_x", np.zeros((48, 64, 3), np.uint8), intrinsics)
    with pytest.raises(ValueError, match="64x48"):
        relocator.note_view(camera, np.zeros((48, 64), np.uint8), intrinsics)


def fused_over(pixels_by_camera: dict[int, np.ndarray]) -> Cloud:
    """A fused cloud whose points each camera saw at these pixels."""
    pixel = np.concatenate(list(pixels_by_camera.values())).astype(np.int32)
    camera = np.concatenate([np.full(len(p), index, np.int8) for index, p in pixels_by_camera.items()])
    return Cloud(np.zeros((len(pixel), 3)), None, camera, 0, 0.0, pixel)


def frame_of(camera: str, stamp: int, color_shape=(48, 64, 3)) -> CameraFrame:
    return CameraFrame(camera, stamp, depth=np.full((48, 64), 900, np.uint16), intrinsics=INTRINSICS,
                       color=np.arange(np.prod(color_shape), dtype=np.uint32).reshape(color_shape).astype(np.uint8))


def test_the_views_are_the_pairs_colour_cut_about_each_cameras_pixels_in_the_fused_cloud():
    config = rig_config_from_mapping(rig_parameters(relocation={"limbs": True}))
    relocator = Relocator(config)
    cam_a, cam_b = config.camera_names[:2]
    pair = FramePair(0, {cam_a: frame_of(cam_a, 0), cam_b: frame_of(cam_b, 0)})
    relocator.note_views(pair, fused_over({0: np.array([[30, 20], [34, 26]]), 1: np.array([[5, 5]])}))
    view = relocator.views[cam_a]
    low = (30 - WINDOW_MARGIN_PX, 20 - WINDOW_MARGIN_PX)  # about cam_a's pixels, as camera_node cuts it
    assert (view.intrinsics.cx, view.intrinsics.cy) == (INTRINSICS.cx - low[0], INTRINSICS.cy - low[1])
    np.testing.assert_array_equal(view.color, pair.frames[cam_a].color[low[1]:26 + WINDOW_MARGIN_PX + 1,
                                                                       low[0]:34 + WINDOW_MARGIN_PX + 1])
    assert relocator.views[cam_b].color.shape[:2] == (5 + WINDOW_MARGIN_PX + 1, 5 + WINDOW_MARGIN_PX + 1)
    # the next pair lacks cam_b (dropped) and cam_a saw nothing of the robot: no view of another instant is kept
    relocator.note_views(FramePair(1, {cam_a: frame_of(cam_a, 1)}), fused_over({1: np.array([[5, 5]])}))
    assert relocator.views == {}


def test_a_colour_image_of_another_size_than_the_depth_is_not_used():
    """A colour stream registered to depth only by scaling places no edge to a pixel: that view is placed by depth
    alone."""
    config = rig_config_from_mapping(rig_parameters(relocation={"limbs": True}))
    relocator = Relocator(config)
    camera = config.camera_names[0]
    pair = FramePair(0, {camera: frame_of(camera, 0, color_shape=(96, 128, 3))})
    relocator.note_views(pair, fused_over({0: np.array([[30, 20]])}))
    assert relocator.views == {}


def test_without_relocation_limbs_no_view_is_kept():
    relocator = Relocator(rig_config_from_mapping(rig_parameters(relocation={"limbs": False})))
    camera = relocator.config.camera_names[0]
    relocator.note_views(FramePair(0, {camera: frame_of(camera, 0)}), fused_over({0: np.array([[30, 20]])}))
    assert relocator.views == {}


def test_a_camera_in_the_cloud_without_its_colour_image_is_said_by_code():
    """relocation.limbs on and a camera's colour image missing (a window late in the graph, a recording without
    colour): across its view the axis is placed by depth alone, and the result says which camera (info: its bounds
    carry it)."""
    from support import BAGS, tiny_rig

    from ntcr_recon.core.config.rig import load_rig_config
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    config = load_rig_config(BAGS / "bend45" / "rig.yaml")
    assert config.relocation.limbs
    reconstructor = Reconstructor(config)
    pair = tiny_rig.bag_frame_pairs(BAGS / "bend45", config)[0]
    cloud = reconstructor.filter(reconstructor.fuse(pair))
    views = dict(reconstructor.relocator.views)
    assert set(views) == set(config.camera_names)
    relocator = Relocator(config)
    relocator.views = views
    whole = relocator.relocate(cloud, warm_start=False)
    cam_a, cam_b = config.camera_names
    relocator.views = {cam_a: views[cam_a]}
    half = relocator.relocate(cloud, warm_start=False)
    missing = next(w for w in half.warnings if w.code == "COLOUR_VIEW_MISSING")
    assert "COLOUR_VIEW_MISSING" not in {w.code for w in whole.warnings}
    assert missing.severity == "info" and missing.figures["cameras"] == [cam_b]
    # a camera with no point in the cloud needs no image
    alone = cloud.subset(np.flatnonzero(cloud.camera == 0))
    assert "COLOUR_VIEW_MISSING" not in {w.code for w in relocator.relocate(alone, warm_start=False).warnings}
