"""The reconstruction core on depth rendered by the tests' own splatting renderer (synthetic_views), not by
the package's simulator: robots of other sizes, notch counts, bends and camera distances than the sample
bags, so nothing can be tuned to those. Each number asserted is printed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from support.synthetic_views import make_config, render_pair

from ntcr_recon.core.cloud.fusion import FramePair
from ntcr_recon.core.quality.metrics import centerline_rmse
from ntcr_recon.core.reconstruction.mesh import poisson_mesh
from ntcr_recon.core.reconstruction.reconstructor import ReconstructionError, Reconstructor
from ntcr_recon.core.robot.kinematics import TubeShape

SCENES = {
    # name: (robot mapping, total bend in degrees or each notch's, camera distance m, camera height m)
    "default_bend30": ({}, 30.0, 0.09, 0.025),
    # a tendon's friction: the notches bend less the farther they lie from the base (9 to 2 deg)
    "default_bends_falling": ({}, tuple(np.linspace(9.0, 2.0, 16)), 0.09, 0.025),
    "thin_robot_bend60_near": ({"outer_diameter": 2.8e-3, "inner_diameter": 2.0e-3, "notch_count": 10,
                                "notch_width": 1.2e-3, "notch_pitch": 2.6e-3, "proximal_length": 4e-3,
                                "distal_length": 2e-3}, 60.0, 0.07, 0.02),
}


@pytest.fixture(scope="module", params=list(SCENES))
def scene(request):
    robot, bend_deg, distance, height = SCENES[request.param]
    config = make_config(robot, distance=distance, height=height)
    shape = (TubeShape.from_notch_bends(config.robot, np.radians(bend_deg)) if isinstance(bend_deg, tuple)
             else TubeShape.from_bend_angle(config.robot, np.radians(bend_deg)))
    pair = render_pair(shape, config, seed=7)
    reconstructor = Reconstructor(config)
    result = reconstructor.process(pair, with_mesh=True)
    return request.param, config, shape, pair, reconstructor, result


def test_every_notch_found_and_measured(scene):
    name, config, shape, _, _, result = scene
    truth = shape.notch_table()
    notches = result.relocation.notches
    errors = np.array([n.width - truth[n.index]["width"] for n in notches])
    bend_errors = np.degrees([n.bend - truth[n.index]["bend"] for n in notches])
    print(f"\n{name}: {len(notches)}/{config.robot.notch_count} notches, width MAE "
          f"{np.abs(errors).mean() * 1e3:.3f} mm, bend MAE {np.abs(bend_errors).mean():.2f} deg")
    assert sorted(n.index for n in notches) == list(range(config.robot.notch_count))
    assert np.abs(errors).mean() <= 0.10e-3
    assert np.abs(bend_errors).mean() <= 1.0


def test_centerline_and_tip(scene):
    name, _, shape, _, _, result = scene
    s = np.linspace(0.0, shape.length, 4000)
    truth, _ = shape.centerline(s)
    rmse = centerline_rmse(result.relocation.centerline.points, truth)
    tip_error = np.linalg.norm(result.relocation.tip - shape.tip_pose()[0])
    print(f"\n{name}: centreline RMSE {rmse * 1e3:.3f} mm, tip error {tip_error * 1e3:.3f} mm")
    assert rmse <= 0.15e-3
    assert tip_error <= 0.30e-3


def test_relocation_brings_points_onto_the_surface(scene):
    name, _, shape, _, _, result = scene
    raw = shape.surface_distance(result.fused.xyz).mean()
    relocated = shape.surface_distance(result.relocation.relocated.xyz).mean()
    rejected = result.relocation.rejected / len(result.filtered)
    print(f"\n{name}: surface error raw {raw * 1e3:.3f} mm, relocated {relocated * 1e3:.3f} mm, "
          f"rejected {rejected:.1%}")
    assert relocated <= 0.5 * raw
    assert rejected < 0.1
    normals = result.relocation.normals
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_meshes_lie_on_the_true_surface(scene):
    name, config, shape, _, _, result = scene
    tube = result.mesh  # the default mesher
    poisson = poisson_mesh(result.relocation.relocated.xyz, result.relocation.normals, config.mesh)
    for kind, mesh in (("tube", tube), ("poisson", poisson)):
        distance = shape.surface_distance(mesh.vertices)
        print(f"\n{name}: {kind} mesh {len(mesh.triangles)} triangles, "
              f"median vertex-to-surface {np.median(distance) * 1e3:.3f} mm")
        assert len(mesh.triangles) > 1000
        assert np.median(distance) < 0.02 * config.robot.outer_diameter
    v, t = tube.vertices, tube.triangles
    facing = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    assert np.all(np.einsum("ij,ij->i", facing, tube.normals[t[:, 0]]) > 0)  # wound outward


def test_warm_start_and_one_camera_alone(scene):
    name, config, shape, pair, reconstructor, result = scene
    again = reconstructor.process(pair)
    assert again.relocation.iterations <= 3
    lone = FramePair(pair.stamp_ns, {"cam_a": pair.frames["cam_a"]})
    reconstructor.reset()
    alone = reconstructor.process(lone).relocation
    s = np.linspace(0.0, shape.length, 4000)
    rmse = centerline_rmse(alone.centerline.points, shape.centerline(s)[0])
    print(f"\n{name}: one camera: {len(alone.notches)} notches, centreline RMSE {rmse * 1e3:.3f} mm")
    assert rmse < 0.5e-3
    assert len(alone.notches) >= config.robot.notch_count - 2


def test_a_frame_without_the_robot_is_refused():
    config = make_config({})
    empty = FramePair(0, {})
    with pytest.raises(ReconstructionError, match="points left"):
        Reconstructor(config).process(empty)


def test_a_frame_after_one_that_saw_part_of_the_robot_is_not_cut_to_that_part():
    """The next frame is fused around the robot's last box; where the last frame saw only part of the robot (the
    rest hidden, say by a hand), the robot found reaches that box's side, and the frame is done again whole."""
    config = make_config({})
    shape = TubeShape.from_bend_angle(config.robot, np.radians(40.0))
    pair = render_pair(shape, config, seed=3)
    hidden_rows = 200  # the image rows above it (the robot's distal part) return no depth
    half = FramePair(pair.stamp_ns, {name: replace(frame, depth=np.where(
        np.arange(frame.depth.shape[0])[:, None] < hidden_rows, 0, frame.depth).astype(frame.depth.dtype))
        for name, frame in pair.frames.items()})
    true_tip = shape.tip_pose()[0]
    reconstructor = Reconstructor(config)
    part = reconstructor.process(half).relocation
    whole = reconstructor.process(pair).relocation
    cold = Reconstructor(config).process(pair).relocation
    errors = [np.linalg.norm(result.tip - true_tip) for result in (part, whole, cold)]
    print(f"\ntip error: part seen {errors[0] * 1e3:.2f} mm, whole after it {errors[1] * 1e3:.3f}, "
          f"whole cold {errors[2] * 1e3:.3f}")
    assert errors[0] > 5e-3  # the hidden frame did lose the distal part
    assert errors[1] < 0.15e-3
    assert abs(whole.quality["tip_s_mm"] - cold.quality["tip_s_mm"]) < 0.05


def test_a_region_of_interest_that_no_longer_holds_the_robot_never_fails_a_frame():
    """The robot's last box set beside it (as if it had swung away and back between frames, and as many points
    in the box as before, so that the count does not give it away): no robot is found there, and the frame is done
    again over the whole crop box."""
    config = make_config({})
    shape = TubeShape.from_bend_angle(config.robot, np.radians(30.0))
    pair = render_pair(shape, config, seed=4)
    reconstructor = Reconstructor(config)
    cold = reconstructor.process(pair).relocation
    reconstructor._roi = (np.array([0.03, 0.03, 0.0]), np.array([0.05, 0.05, 0.02]))  # holds nothing of the robot
    reconstructor._roi_count = 0
    again = reconstructor.process(pair).relocation
    print(f"\ntip after a region of interest beside the robot: {np.linalg.norm(again.tip - cold.tip) * 1e3:.3f} mm "
          "from the cold start's")
    assert np.linalg.norm(again.tip - cold.tip) < 0.02e-3


def test_the_robots_own_model_fitted_places_the_axis(scene):
    """relocation.model_fit: the robot's roll and bends fitted to the points (core.fit.robot_fit) place the axis the
    notches, the tip and the relocation work about; the fit is kept for the next frame's warm start."""
    name, config, shape, pair, _, free = scene
    reconstructor = Reconstructor(replace(config, relocation=replace(config.relocation, model_fit=True)))
    result = reconstructor.process(pair)
    s = np.linspace(0.0, shape.length, 4000)
    truth, _ = shape.centerline(s)
    rmse = centerline_rmse(result.relocation.centerline.points, truth)
    free_rmse = centerline_rmse(free.relocation.centerline.points, truth)
    tip_error = np.linalg.norm(result.relocation.tip - shape.tip_pose()[0])
    print(f"\n{name}: model fit centreline RMSE {rmse * 1e3:.3f} mm (free {free_rmse * 1e3:.3f}), tip error "
          f"{tip_error * 1e3:.3f} mm, {len(result.relocation.notches)} notches")
    assert rmse <= 0.03e-3 and tip_error <= 0.08e-3
    assert len(result.relocation.notches) == config.robot.notch_count
    figures = result.relocation.quality["model_fit"]
    assert len(figures["bends_deg"]) == config.robot.notch_count and set(figures["residual_mm"]) <= set(
        config.camera_names)
    assert abs(np.sum(figures["bends_deg"]) - np.degrees(np.sum(shape.notch_bend))) < 2.0
    assert "model_fit" not in free.relocation.quality
    reconstructor.relocator.reset()
    assert reconstructor.relocator.fit is None
