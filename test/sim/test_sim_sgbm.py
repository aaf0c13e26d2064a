"""`simulate --matcher sgbm`: the D405's two imagers rendered and matched by OpenCV's StereoSGBM; the default
`--matcher emulated` as it was."""

import argparse
import math
import subprocess
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.ndimage import binary_dilation, binary_erosion

from ntcr_recon import cli
from ntcr_recon.cli import simulate as simulate_command
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.core.robot.surface import PART_OUTER_WALL
from ntcr_recon.sim.bag import topic_name
from ntcr_recon.sim.camera import D405Intrinsics, deproject
from ntcr_recon.sim.imagers import right_imager, robot_material_points, sensor_image, solid_texture
from ntcr_recon.sim.scene import LABEL_CAMERA_BODY, LABEL_POST, LABEL_ROBOT
from ntcr_recon.sim.sgbm import disparity_range, match_disparity
from ntcr_recon.sim.simulate import STAMP_JITTER_NS, Simulation
from ntcr_recon.sim.stereo import emulate_depth

SEED = 5


@pytest.fixture(scope="module")
def bent():
    """The sample robot bent 45 deg, both cameras at 90 mm, one frame matched by SGBM (~8 s)."""
    simulation = Simulation(TubeShape.from_bend_angle(TubeGeometry(), math.radians(45)), frame_count=1, seed=SEED,
                            matcher="sgbm")
    return simulation, list(simulation.frames())


def spine_core(simulation, camera, exact) -> np.ndarray:
    """Pixels of the outer wall of a spine, 3 px inside the silhouette and 1 mm from any notch centre."""
    shape = simulation.shape
    points, index = deproject(exact.depth, simulation.intrinsics)
    s_along = camera.to_base(points)[:, 2]  # the bend is gentle near the base; this only screens notches
    centres = shape.geometry.notch_centers_s
    near_notch = np.min(np.abs(s_along[:, None] - centres[None, :]), axis=1) < 1.0e-3
    mask = np.zeros(exact.depth.size, dtype=bool)
    mask[index[~near_notch]] = True
    inside = binary_erosion(exact.label == LABEL_ROBOT, iterations=3)
    return mask.reshape(exact.depth.shape) & inside & (exact.robot_part == PART_OUTER_WALL)


def test_the_search_covers_the_d405s_minimum_depth():
    assert disparity_range(D405Intrinsics()) == (0, 112)  # 421.61 px x 18 mm / 70 mm = 108.4 px
    assert disparity_range(D405Intrinsics(width=640, height=480, fx=318.0, fy=318.0, cx=322, cy=241)) == (0, 96)


def test_sgbm_depth_of_the_tube_in_its_middle_is_within_a_third_of_a_millimetre(bent):
    simulation, frames = bent
    for frame in frames:
        exact = simulation.exact[frame.camera.name]
        core = spine_core(simulation, frame.camera, exact)
        depth = frame.depth_raw * simulation.intrinsics.depth_unit
        valid = core & (depth > 0)
        error = (depth - exact.depth)[valid]
        assert core.sum() > 500
        assert valid.sum() >= 0.95 * core.sum(), frame.camera.name
        assert abs(np.median(error)) < 0.3e-3, (frame.camera.name, np.median(error))
        assert np.mean(np.abs(error) < 0.5e-3) > 0.8, (frame.camera.name, np.mean(np.abs(error) < 0.5e-3))


def test_valid_depth_covers_the_robot_and_spreads_little_beyond_it(bent):
    simulation, frames = bent
    for frame in frames:
        exact = simulation.exact[frame.camera.name]
        robot = exact.label == LABEL_ROBOT
        depth = frame.depth_raw * simulation.intrinsics.depth_unit
        valid = depth > 0
        assert 0.9 <= (valid & robot).sum() / robot.sum() <= 1.0, frame.camera.name
        # the robot's depth read where the robot is not (a matcher's fattened silhouette), post aside
        robot_depths = exact.depth[robot]
        at_robot_depth = valid & (depth > robot_depths.min() - 2e-3) & (depth < robot_depths.max() + 2e-3)
        beyond = at_robot_depth & ~robot & ~binary_dilation(exact.label == LABEL_POST, iterations=12)
        assert beyond.sum() < 0.5 * robot.sum(), (frame.camera.name, beyond.sum(), robot.sum())
        assert beyond.sum() > 0.02 * robot.sum()  # a real matcher does fatten (the emulation's scale of it)


def test_a_plane_reads_its_distance_within_the_matchers_pixel_locking(bent):
    """The opposite camera's housing: its front face a plane 180 mm away, facing the camera."""
    simulation, frames = bent
    frame = frames[0]
    exact = simulation.exact[frame.camera.name]
    face = binary_erosion(exact.label == LABEL_CAMERA_BODY, iterations=8) & ~binary_dilation(
        exact.label == LABEL_ROBOT, iterations=8)
    depth = frame.depth_raw * simulation.intrinsics.depth_unit
    valid = face & (depth > 0)
    assert face.sum() > 3000 and valid.sum() > 0.6 * face.sum()  # dark, faintly textured: a quarter reads nothing
    assert np.median(exact.depth[face]) == pytest.approx(0.180, abs=1e-3)  # its optical centre's plane
    # 0.25 px of disparity (SGBM's pixel-locking) is 1.07 mm at 180 mm
    error = (depth - exact.depth)[valid]
    assert abs(np.median(error)) < 1.0e-3, np.median(error)
    print(f"plane: {valid.sum()}/{face.sum()} valid, median error {np.median(error) * 1e3:+.2f} mm")


def test_the_left_imagers_exposure_is_the_colour_written(bent, tmp_path):
    simulation, frames = bent
    for i, frame in enumerate(frames):
        rng = np.random.default_rng([SEED, i, 0])
        rng.integers(-STAMP_JITTER_NS, STAMP_JITTER_NS + 1)  # the stamp's jitter, drawn first
        left = sensor_image(simulation.imager_pairs[frame.camera.name][0], simulation.imagers.sensor_noise, rng)
        assert np.array_equal(frame.color, left)
        right = sensor_image(simulation.imager_pairs[frame.camera.name][1], simulation.imagers.sensor_noise, rng)
        assert np.mean(frame.color != right) > 0.5
        assert match_disparity(left, right, simulation.intrinsics, simulation.sgbm).max() > 0
    path = simulation.write_bag(tmp_path / "sgbm", progress=False)  # the imagers are rendered already
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        messages = {c.topic: reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()}
    for frame in frames:
        color = messages[topic_name(simulation.namespace, frame.camera.name, "color")]
        depth = messages[topic_name(simulation.namespace, frame.camera.name, "depth")]
        assert color.encoding == "rgb8" and depth.encoding == "16UC1"
        assert np.array_equal(np.frombuffer(color.data, np.uint8).reshape(frame.color.shape), frame.color)
        assert np.array_equal(np.frombuffer(depth.data, np.uint16).reshape(frame.depth_raw.shape), frame.depth_raw)


def test_the_texture_is_bound_to_the_material(bent):
    """Both imagers see the same texture on the same material point: it is a function of the tube coordinates,
    which a surface sample's own position gives back exactly."""
    simulation, _ = bent
    surface = simulation.scene.surface
    index = np.random.default_rng(0).choice(len(surface.s), 500, replace=False)
    material = robot_material_points(simulation.scene, index, surface.points[index])
    expected = np.column_stack([surface.radius[index] * np.cos(surface.angle[index]),
                                surface.radius[index] * np.sin(surface.angle[index]), surface.s[index]])
    assert np.abs(material - expected).max() < 1e-9
    texture = solid_texture(material, simulation.imagers.texture_wavelength)
    assert 0.5 < texture.std() < 1.5 and np.array_equal(texture, solid_texture(expected, (0.4e-3, 1.6e-3)))
    camera = simulation.cameras[0]
    right = right_imager(camera, simulation.intrinsics.baseline)
    assert np.allclose(right.to_camera(camera.to_base(np.array([[0.0, 0.0, 0.1]]))), [[-0.018, 0.0, 0.1]])


def test_matcher_emulated_is_the_emulation_as_before(tmp_path):
    """The default and `--matcher emulated` give the frames the emulation always gave: its depth of the exact
    rendering and the exact colour with its noise, drawn from the same generator in the same order."""
    parser = argparse.ArgumentParser()
    simulate_command.add_arguments(parser)
    arguments = [str(tmp_path / "unused"), "--bend-deg", "30", "--frames", "1", "--seed", "3"]
    built = [parser.parse_args(arguments + extra) for extra in ([], ["--matcher", "emulated"])]
    simulations = [simulate_command.build_simulation(args) for args in built]
    assert all(s.matcher == "emulated" for s in simulations)
    frames = [list(s.frames()) for s in simulations]
    reference = simulations[0]
    for i, (default, explicit) in enumerate(zip(*frames, strict=True)):
        exact = reference.exact[default.camera.name]
        rng = np.random.default_rng([3, i, 0])
        rng.integers(-STAMP_JITTER_NS, STAMP_JITTER_NS + 1)
        depth = emulate_depth(exact.depth, exact.normal, reference.intrinsics, reference.emulation, rng)
        color = np.clip(np.rint(exact.color + rng.normal(0.0, reference.color_noise, exact.color.shape)), 0,
                        255).astype(np.uint8)
        for frame in (default, explicit):
            assert np.array_equal(frame.depth_raw, depth) and np.array_equal(frame.color, color)
            assert frame.stamp_ns == default.stamp_ns
    assert "matcher" not in reference.truth()


def test_a_bad_matcher_is_refused_by_the_parser(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["simulate", str(tmp_path / "x"), "--matcher", "bm"])
    assert exit_.value.code == 2
    assert "invalid choice: 'bm'" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "y"), "--matcher", "sgbm", "--no-flying-pixels",
                     "--no-progress"]) == 2
    assert "--no-flying-pixels" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "z"), "--matcher", "sgbm", "--window", "8", "--no-progress"]) == 2
    assert "block size" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_cv2_is_imported_only_by_the_real_matcher():
    probe = ("import math, sys\nfrom ntcr_recon.cli import simulate\nfrom ntcr_recon.core.robot.geometry import "
             "TubeGeometry\nfrom ntcr_recon.core.robot.kinematics import TubeShape\nfrom ntcr_recon.sim.simulate "
             "import Simulation\nfrom ntcr_recon.sim import sgbm, imagers\n"
             "list(Simulation(TubeShape.from_bend_angle(TubeGeometry(), 0.5), frame_count=1).frames())\n"
             "print('cv2' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
