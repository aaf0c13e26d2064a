"""The emulated D405: exact depth of the scene, and what the stereo artefacts do to it."""

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.core.robot.surface import PART_OUTER_WALL
from ntcr_recon.sim.camera import D405Intrinsics, deproject, facing_pair
from ntcr_recon.sim.scene import LABEL_BACKDROP, LABEL_ROBOT, Scene
from ntcr_recon.sim.stereo import StereoEmulation, emulate_depth, occluded_in_right_imager

GEOMETRY = TubeGeometry()
INTRINSICS = D405Intrinsics()


@pytest.fixture(scope="module")
def straight_view():
    """The straight robot seen side-on by the first camera: scene, camera, exact frame."""
    shape = TubeShape.straight(GEOMETRY)
    cameras = facing_pair(0.09)
    scene = Scene(shape, cameras)
    return shape, cameras[0], scene.render_exact(cameras[0])


@pytest.fixture(scope="module")
def bent_scene():
    shape = TubeShape.from_bend_angle(TubeGeometry(notch_side=0.3), math.radians(60))
    cameras = facing_pair(0.09)
    scene = Scene(shape, cameras)
    return shape, cameras, {c.name: scene.render_exact(c) for c in cameras}


def spine_pixels(shape, camera, exact):
    """Pixels whose exact hit is the outer wall of a spine, away from the notch edges and the ends."""
    points, index = deproject(exact.depth, INTRINSICS)
    z = camera.to_base(points)[:, 2]
    away = np.min(np.abs(z[:, None] - shape.geometry.notch_centers_s[None, :]), axis=1) > 0.95e-3
    keep = away & (z > 0.5e-3) & (z < shape.length - 0.5e-3) & (exact.robot_part.ravel()[index] == PART_OUTER_WALL)
    return index[keep]


def test_exact_depth_of_a_straight_tube_matches_analytic_ray_casting(straight_view):
    shape, camera, exact = straight_view
    rays = INTRINSICS.pixel_rays().reshape(-1, 3) @ camera.rotation.T
    origin = camera.translation
    a = rays[:, 0] ** 2 + rays[:, 1] ** 2
    b = rays[:, :2] @ origin[:2]
    c = origin[:2] @ origin[:2] - GEOMETRY.outer_radius**2
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = np.where(disc >= 0, (-b - np.sqrt(disc)) / a, np.inf)
    hit_z = origin[2] + t * rays[:, 2]
    from_notch = np.min(np.abs(hit_z[:, None] - GEOMETRY.notch_centers_s[None, :]), axis=1)
    on_spine = np.isfinite(t) & (from_notch > 0.95e-3) & (hit_z > 0.3e-3) & (hit_z < shape.length - 0.3e-3)
    label = exact.label.ravel()
    assert on_spine.sum() > 1000
    # same silhouette: every pixel the analytic tube covers is the robot, and the robot is nowhere else
    assert np.all(label[on_spine] == LABEL_ROBOT)
    assert np.sum((label == LABEL_ROBOT) & ~np.isfinite(t)) == 0
    error = np.abs(exact.depth.ravel()[on_spine] - t[on_spine])
    assert error.max() < 10e-6  # grazing rows included; a pixel's footprint here is ~210 um


def test_noiseless_points_lie_on_the_true_surface(bent_scene):
    shape, cameras, exact = bent_scene
    for camera in cameras:
        frame = exact[camera.name]
        raw = emulate_depth(frame.depth, frame.normal, INTRINSICS, StereoEmulation.ideal(), np.random.default_rng(0))
        points, index = deproject(raw * INTRINSICS.depth_unit, INTRINSICS)
        robot = frame.label.ravel()[index] == LABEL_ROBOT
        assert robot.sum() > 2000
        distance = shape.surface_distance(camera.to_base(points[robot]))
        footprint = 0.09 / INTRINSICS.fx
        assert distance.max() < INTRINSICS.depth_unit + footprint
        # quantisation to 0.1 mm is all that is left: half a unit along the ray at most
        assert np.percentile(distance, 99.5) < 0.5 * INTRINSICS.depth_unit * 1.1
        assert np.mean(distance) < 0.3 * INTRINSICS.depth_unit


def fit_circle(xy):
    centre = xy.mean(axis=0)
    solution = least_squares(lambda p: np.linalg.norm(xy - p[:2], axis=1) - p[2],
                             [centre[0], centre[1], np.linalg.norm(xy - centre, axis=1).mean()])
    return solution.x[2], math.sqrt(np.mean(solution.fun**2))


def spine_cross_section_fit(shape, camera, exact, emulation, seed):
    raw = emulate_depth(exact.depth, exact.normal, INTRINSICS, emulation, np.random.default_rng(seed))
    pixels = spine_pixels(shape, camera, exact)
    measured = raw.ravel()[pixels] > 0
    rays = INTRINSICS.pixel_rays().reshape(-1, 3)[pixels[measured]]
    points = camera.to_base(rays * (raw.ravel()[pixels[measured]] * INTRINSICS.depth_unit)[:, None])
    return fit_circle(points[:, :2])  # the straight robot's axis is base z


def test_stereo_window_flattens_one_cameras_view_of_the_tube(straight_view):
    shape, camera, exact = straight_view
    ideal_radius, ideal_rms = spine_cross_section_fit(shape, camera, exact, StereoEmulation.ideal(), 0)
    assert ideal_radius == pytest.approx(GEOMETRY.outer_radius, abs=0.05e-3)
    assert ideal_rms < 0.04e-3
    window_only = StereoEmulation(disparity_noise=0.0, dropout=0.0, grazing_dropout=0.0, silhouette_invalid=0.0,
                                  silhouette_mixing=0.0)
    for emulation in (window_only, StereoEmulation()):
        radius, rms = spine_cross_section_fit(shape, camera, exact, emulation, 1)
        assert radius - GEOMETRY.outer_radius > 0.1e-3  # flatter than the tube: a larger circle
        assert rms > 2.5 * ideal_rms


def test_disparity_noise_grows_as_z_squared_on_the_backdrop(straight_view):
    _, _, exact = straight_view
    noise_only = StereoEmulation(window=1, silhouette_band=0, dropout=0.0, grazing_dropout=0.0,
                                 occlusion_check=False)
    first, second = (emulate_depth(exact.depth, exact.normal, INTRINSICS, noise_only, np.random.default_rng(k))
                     for k in (1, 2))
    backdrop = (exact.label == LABEL_BACKDROP) & (first > 0) & (second > 0)
    z = exact.depth[backdrop]
    difference = (first[backdrop].astype(float) - second[backdrop]) * INTRINSICS.depth_unit
    expected = np.mean(z) ** 2 * 0.08 / INTRINSICS.focal_baseline
    assert np.std(difference) / math.sqrt(2) == pytest.approx(expected, rel=0.1)


def test_artefacts_are_deterministic_per_seed_and_independent_per_frame(straight_view):
    _, _, exact = straight_view
    frames = [emulate_depth(exact.depth, exact.normal, INTRINSICS, StereoEmulation(), np.random.default_rng(seed))
              for seed in (5, 5, 6)]
    assert np.array_equal(frames[0], frames[1])
    assert not np.array_equal(frames[0], frames[2])
    assert frames[0].dtype == np.uint16


def test_right_imager_occlusion_band_is_as_wide_as_the_disparity_step():
    disparity = np.full((4, 200), 20.0)
    disparity[:, 100:120] = 50.0  # a near object: 30 px more disparity than the wall behind it
    occluded = occluded_in_right_imager(disparity)
    columns = np.flatnonzero(occluded[0])
    assert columns.max() == 99 and len(columns) in (29, 30)  # ~30 px left of the object's left edge (70: a tie)
    assert not occluded[:, 100:].any()


def test_depth_outside_the_d405_range_is_invalid():
    depth = np.full((INTRINSICS.height, INTRINSICS.width), 0.06)  # nearer than the 848x480 minimum
    depth[:, 400:] = 0.2
    normals = np.zeros(depth.shape + (3,))
    normals[..., 2] = -1
    raw = emulate_depth(depth, normals, INTRINSICS, StereoEmulation.ideal(), np.random.default_rng(0))
    assert np.all(raw[:, :400] == 0)
    assert np.all(raw[:, 400:] == 2000)


@pytest.mark.parametrize("bend_deg", [0.0, 90.0])
def test_the_whole_robot_is_in_view_and_in_range_of_both_cameras(bend_deg):
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(bend_deg))
    points, _ = shape.sample_surface(0.5e-3)
    for camera in facing_pair(0.09):
        in_camera = camera.to_camera(points)
        u = INTRINSICS.fx * in_camera[:, 0] / in_camera[:, 2] + INTRINSICS.cx
        v = INTRINSICS.fy * in_camera[:, 1] / in_camera[:, 2] + INTRINSICS.cy
        assert np.all((u > 0) & (u < INTRINSICS.width - 1) & (v > 0) & (v < INTRINSICS.height - 1))
        assert np.all((in_camera[:, 2] > INTRINSICS.min_depth) & (in_camera[:, 2] < 0.1))
        # the robot's length runs along the image's long side; side-on, its bend stays in the image plane
        base_u, tip_u = (INTRINSICS.fx * p[0] / p[2] + INTRINSICS.cx
                         for p in camera.to_camera(shape.centerline([0.0, shape.length])[0]))
        assert tip_u - base_u > (240 if bend_deg == 0 else 150)
        assert np.ptp(in_camera[:, 2]) < GEOMETRY.outer_diameter + 1e-6


def test_notches_facing_a_camera_show_it_their_cuts():
    from ntcr_recon.sim.simulate import notch_side_angle

    shape = TubeShape.from_bend_angle(TubeGeometry(notch_side=notch_side_angle("facing")), math.radians(45))
    cameras = facing_pair(0.09)
    scene = Scene(shape, cameras)
    frames = {c.name: scene.render_exact(c) for c in cameras}
    inside_cut = {name: np.sum((f.robot_part != PART_OUTER_WALL) & (f.label == LABEL_ROBOT))
                  for name, f in frames.items()}
    assert inside_cut["cam_a"] > 300
    assert inside_cut["cam_a"] > 5 * inside_cut["cam_b"]


def test_a_robot_curled_into_its_clamp_post_is_refused():
    from ntcr_recon.sim.simulate import Simulation

    # 280 deg curls the tip down beside the 4 mm post; 300 deg drives it through the post
    clearance, _ = Scene(TubeShape.from_bend_angle(GEOMETRY, math.radians(280)), []).props_clearance()
    assert 0 < clearance < GEOMETRY.outer_radius
    through, where = Scene(TubeShape.from_bend_angle(GEOMETRY, math.radians(300)), []).props_clearance()
    assert through < -1e-3 and where > 0.8 * GEOMETRY.length
    with pytest.raises(ValueError, match=r"passes 2\.\d\d mm into its clamp post .*bend it less"):
        Simulation(TubeShape.from_bend_angle(GEOMETRY, math.radians(300)))
    # straight up, the nearest the robot comes is its own base just above the post's top
    straight, _ = Scene(TubeShape.straight(GEOMETRY), []).props_clearance()
    assert straight == pytest.approx(GEOMETRY.outer_diameter - GEOMETRY.outer_radius, abs=1e-9)
