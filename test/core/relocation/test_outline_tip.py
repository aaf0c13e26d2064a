"""The tube's end in the colour images (core.relocation.outline_tip), in the simulator's renders (the left imager's
image: shaded, blurred, noisy) of a straight and a bent robot, read about the true axis from where a matcher's depth
put the end, short of it or past it."""

import argparse
import math

import numpy as np
import pytest

from ntcr_recon.cli import simulate as simulate_command
from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.config.rig import rig_config_from_mapping
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limbs import CameraView
from ntcr_recon.core.relocation.outline_tip import OutlineEnd, end_in_outline

pytestmark = pytest.mark.unit


def rendered(tmp_path, bend_deg: float):
    """The true axis (run on past the tip), the robot's geometry and length, both cameras' views and the pixel
    footprint at the robot."""
    parser = argparse.ArgumentParser()
    simulate_command.add_arguments(parser)
    simulation = simulate_command.build_simulation(parser.parse_args(
        [str(tmp_path / "scene"), "--bend-deg", str(bend_deg), "--frames", "1", "--no-progress"]))
    shape = simulation.shape
    s = np.linspace(0.0, shape.length, 2001)
    points, frames = shape.centerline(s)
    beyond = points[-1] + np.outer(np.linspace(0.0, 2e-3, 21)[1:], frames[-1, :, 2])
    axis = Centerline.from_points(np.concatenate([points, beyond]), frames[0, :, 1], 1e-4)
    config = rig_config_from_mapping(simulation.rig_parameters()["/**"]["ros__parameters"])
    k = simulation.intrinsics
    intrinsics = Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    views = {frame.camera.name: CameraView(frame.color, intrinsics, config.cameras[frame.camera.name].extrinsic)
             for frame in simulation.frames()}
    return axis, shape.geometry, shape.length, views, simulation.camera_distance / k.fx


@pytest.mark.parametrize("bend_deg, within_px", [(0.0, 0.1), (45.0, 0.4)])
def test_the_end_of_the_outline_places_the_tip_where_depth_smeared_it(tmp_path, bend_deg, within_px):
    """Wherever a matcher's half window put depth's end (0.3 mm short or past), the outline ends at the tip: to a
    tenth of a pixel on a straight robot, within half a pixel bent 45 deg, in both cameras, and says how well."""
    axis, geometry, length, views, footprint = rendered(tmp_path, bend_deg)
    for off in (-0.3e-3, 0.0, 0.3e-3):
        seen = end_in_outline(axis, length + off, views, geometry, footprint)
        assert set(seen.by_camera) == {"cam_a", "cam_b"}
        assert seen.s == pytest.approx(length, abs=within_px * footprint)
        assert seen.uncertainty <= math.hypot(within_px * footprint, footprint / 2)


def test_no_end_where_no_camera_sees_it(tmp_path):
    axis, geometry, length, views, footprint = rendered(tmp_path, 0.0)
    assert end_in_outline(axis, length, {}, geometry, footprint) is None
    moved = {}
    for name, view in views.items():  # the cameras 200 mm further along the tube: its end lies outside their images
        extrinsic = view.extrinsic.copy()
        extrinsic[2, 3] += 0.2
        moved[name] = CameraView(view.color, view.intrinsics, extrinsic)
    assert end_in_outline(axis, length, moved, geometry, footprint) is None


def test_depth_s_end_is_weighed_in_where_it_agrees_and_left_out_where_its_matcher_moved_it():
    seen = OutlineEnd(50.0e-3, 0.05e-3, {"cam_a": 50.0e-3})
    s, known = seen.with_depth(50.05e-3, 0.05e-3)  # agreeing: halfway, known better than either
    assert s == pytest.approx(50.025e-3) and known == pytest.approx(0.05e-3 / math.sqrt(2))
    assert seen.with_depth(50.3e-3, 0.05e-3) == (50.0e-3, 0.05e-3)  # a matcher's fattened end: the outline's
    assert seen.with_depth(50.05e-3, None) == (50.0e-3, 0.05e-3)
