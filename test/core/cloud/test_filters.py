"""Depth to points (Eq. 3-4), fusion (Eq. 9) with stamp pairing, and the filters (Eq. 5-6), on small
synthetic data with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic_views import INTRINSICS, make_config

from ntcr_recon.core.cloud.deproject import Intrinsics, PixelWindow, crop_window, depth_to_points
from ntcr_recon.core.cloud.filters import (
    _image_window_neighbours,
    _mean_neighbour_distances,
    _neighbours_among_kept,
    color_mask,
    crop_box_mask,
    filter_cloud,
    nearest_neighbours,
    statistical_outlier_mask,
    voxel_downsample,
)
from ntcr_recon.core.cloud.fusion import CameraFrame, fuse
from ntcr_recon.core.cloud.mls import _quadric_height, mls_smooth, smallest_eigenvector
from ntcr_recon.core.cloud.pairing import pair_frames
from ntcr_recon.core.cloud.points import Cloud, pack_rgb


def test_depth_to_points_inverts_the_pinhole_projection():
    intrinsics = Intrinsics(8, 6, 10.0, 12.0, 3.5, 2.5)
    depth = np.full((6, 8), 500, np.uint16)  # 0.05 m at 0.1 mm per unit
    depth[0, 0] = 0                          # invalid
    colour = np.zeros((6, 8, 3), np.uint8)
    colour[2, 5] = (10, 20, 30)
    xyz, rgb, pixel = depth_to_points(depth, intrinsics, 1e-4, colour)
    assert len(xyz) == 47
    assert np.allclose(xyz[:, 2], 0.05)
    u = intrinsics.fx * xyz[:, 0] / xyz[:, 2] + intrinsics.cx
    v = intrinsics.fy * xyz[:, 1] / xyz[:, 2] + intrinsics.cy
    assert np.allclose(u, pixel[:, 0]) and np.allclose(v, pixel[:, 1])
    assert rgb[(pixel[:, 0] == 5) & (pixel[:, 1] == 2)][0] == pack_rgb(np.array([[10, 20, 30]]))[0]
    metres = np.where(depth > 0, depth * 1e-4, np.nan).astype(np.float32)   # 32FC1 with NaN holes
    xyz32, _, _ = depth_to_points(metres, intrinsics, 1.0)
    assert np.allclose(xyz32, xyz, atol=1e-7)


def test_depth_to_points_keeps_the_window_and_its_depth_range_only():
    intrinsics = Intrinsics(8, 6, 10.0, 12.0, 3.5, 2.5)
    depth = np.arange(48, dtype=np.uint16).reshape(6, 8) * 10 + 400     # 40.0 mm .. 87.0 mm at 0.1 mm
    window = PixelWindow(u0=2, u1=6, v0=1, v1=4, z_min=0.0525, z_max=0.0665)
    xyz, _, pixel = depth_to_points(depth, intrinsics, 1e-4, window=window)
    raw = depth[pixel[:, 1], pixel[:, 0]]
    assert np.all((pixel[:, 0] >= 2) & (pixel[:, 0] < 6) & (pixel[:, 1] >= 1) & (pixel[:, 1] < 4))
    assert np.all((raw * 1e-4 >= 0.0525) & (raw * 1e-4 <= 0.0665))
    inside = depth[1:4, 2:6] * 1e-4
    assert len(xyz) == np.count_nonzero((inside >= 0.0525) & (inside <= 0.0665)) == 6
    np.testing.assert_array_equal(xyz[:, 2], raw * 1e-4)
    # row by row, as the image is stored
    assert np.all(np.diff(pixel[:, 1] * 8 + pixel[:, 0]) > 0)
    # big-endian depth (a flagged sensor_msgs/Image) reads the same
    swapped, _, _ = depth_to_points(depth.astype(">u2"), intrinsics, 1e-4, window=window)
    np.testing.assert_array_equal(swapped, xyz)
    # a window reaching past the image is read within the image only
    beyond = PixelWindow(u0=-2, u1=64, v0=-1, v1=64, z_min=0.0, z_max=np.inf)
    _, _, pixel = depth_to_points(depth, intrinsics, 1e-4, window=beyond)
    assert len(pixel) == depth.size


def test_flying_pixels_ramping_to_the_background_are_dropped_and_the_tube_slots_and_backdrop_kept():
    """One row of a tube (r = 1.75 mm, 90 mm away) before a backdrop at 300 mm, as a stereo matcher leaves it:
    a ramp of mixed depths on each side, a one-pixel slot seen through to the backdrop, an invalid pixel."""
    row_mm = [300, 300, 200, 120, 91.7, 90.6, 90.0, 90.6, 91.7, 300, 91.7, 90.6, 150, 300, 0, 130, 90.2, 300]
    # between their neighbours, more than a radius from each: flying. Kept: the tube's profile (steps under its
    # radius), the slot (9: steps both ways), the backdrop's edge pixels (1, 13: one near neighbour), and 15
    # beside an invalid pixel (cannot be told from a surface)
    ramp = {2, 3, 12}
    unit = 1e-4
    row = np.round(np.array(row_mm) * 10).astype(np.uint16)
    for depth in (np.tile(row, (3, 1)), np.tile(row, (3, 1)).T.copy()):  # the ramp along a row, then a column
        height, width = depth.shape
        intrinsics = Intrinsics(width, height, 600.0, 600.0, width / 2, height / 2)
        _, _, pixel = depth_to_points(depth, intrinsics, unit, ramp_step=1.75e-3)
        along = pixel[:, 0] if width > height else pixel[:, 1]
        kept = set(along.tolist())
        assert kept == {i for i, z in enumerate(row_mm) if z > 0} - ramp
        # the step off (0): every valid pixel kept; a step above the backdrop's: none dropped either
        for step in (0.0, 0.5):
            _, _, pixel = depth_to_points(depth, intrinsics, unit, ramp_step=step)
            assert len(pixel) == np.count_nonzero(depth)


def test_crop_window_holds_every_pixel_that_sees_the_box():
    config = make_config({})
    camera = config.cameras["cam_a"]
    box_min, box_max = np.array([-0.004, -0.004, 0.01]), np.array([0.004, 0.004, 0.03])
    window = crop_window(INTRINSICS, camera.extrinsic, box_min, box_max)
    rng = np.random.default_rng(0)
    inside = box_min + rng.random((500, 3)) * (box_max - box_min)
    in_camera = (inside - camera.translation) @ camera.extrinsic[:3, :3]
    u = INTRINSICS.fx * in_camera[:, 0] / in_camera[:, 2] + INTRINSICS.cx
    v = INTRINSICS.fy * in_camera[:, 1] / in_camera[:, 2] + INTRINSICS.cy
    assert np.all((u >= window.u0 - 0.5) & (u <= window.u1) & (v >= window.v0 - 0.5) & (v <= window.v1))
    assert np.all((in_camera[:, 2] >= window.z_min) & (in_camera[:, 2] <= window.z_max))
    assert (window.u1 - window.u0) * (window.v1 - window.v0) < 0.1 * INTRINSICS.width * INTRINSICS.height
    behind = crop_window(INTRINSICS, camera.extrinsic, box_min - [0, 1.0, 0], box_max - [0, 0.5, 0])
    assert behind is None


def _frame(camera, stamp_ns, z=0.09):
    depth = np.zeros((INTRINSICS.height, INTRINSICS.width), np.uint16)
    depth[230:250, 414:434] = int(round(z / 1e-4))
    return CameraFrame(camera, stamp_ns, depth=depth, intrinsics=INTRINSICS)


def test_pairing_by_stamp_within_the_slop_and_lone_frames_kept():
    ms = 1_000_000
    streams = {"cam_a": [_frame("cam_a", t * ms) for t in (0, 33, 66, 100)],
               "cam_b": [_frame("cam_b", t * ms) for t in (2, 40, 99, 200)]}
    pairs = pair_frames(streams, slop_ns=5 * ms)
    together = [sorted(f.stamp_ns // ms for f in p.frames.values()) for p in pairs]
    assert [0, 2] in together and [99, 100] in together
    assert [33] in together and [40] in together and [66] in together and [200] in together
    assert len(pairs) == 6
    assert [p.stamp_ns for p in pairs] == sorted(p.stamp_ns for p in pairs)


def test_fusion_moves_each_camera_into_the_base_frame_and_one_camera_alone_works():
    config = make_config({})
    # a patch 90 mm in front of each camera is at the base frame's z axis (both look at x = 0, y = 0)
    pair = pair_frames({"cam_a": [_frame("cam_a", 0)], "cam_b": [_frame("cam_b", 0)]}, 1)[0]
    cloud = fuse(pair, config)
    assert set(np.unique(cloud.camera)) == {0, 1}
    assert np.allclose(cloud.xyz[:, 1], 0.0, atol=1e-4)
    assert cloud.pixel_footprint == pytest.approx(0.09 / INTRINSICS.fx, rel=1e-3)
    alone = fuse(pair_frames({"cam_b": [_frame("cam_b", 0)]}, 1)[0], config)
    assert len(alone) == np.count_nonzero(cloud.camera == 1) and np.all(alone.camera == 1)
    with pytest.raises(ValueError, match="does not list"):
        fuse(pair_frames({"cam_x": [_frame("cam_x", 0)]}, 1)[0], config)


def _noisy_sphere(count=3000, radius=0.01, noise=2e-4, seed=0):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * (radius + rng.normal(scale=noise, size=(count, 1))), radius


def test_statistical_outlier_removal_drops_planted_outliers():
    surface, _ = _noisy_sphere()
    rng = np.random.default_rng(1)
    outliers = rng.uniform(-0.03, 0.03, size=(40, 3))
    outliers = outliers[np.abs(np.linalg.norm(outliers, axis=1) - 0.01) > 0.004]
    keep = statistical_outlier_mask(np.vstack([surface, outliers]), 12, 2.0)
    assert not keep[len(surface):].any()
    assert keep[: len(surface)].mean() > 0.95


@pytest.mark.parametrize("order", [1, 2])
def test_mls_projects_noise_onto_the_local_surface(order):
    xyz, radius = _noisy_sphere(count=6000)
    before = np.abs(np.linalg.norm(xyz, axis=1) - radius)
    after = np.abs(np.linalg.norm(mls_smooth(xyz, 24, order), axis=1) - radius)
    assert after.mean() < 0.6 * before.mean()
    # on an exact plane MLS leaves the points where they are
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.random((500, 2)), np.zeros(500)])
    assert np.allclose(mls_smooth(plane, 16, order)[:, 2], 0.0, atol=1e-7)


@pytest.mark.parametrize("order", [1, 2])
def test_mls_leaves_coincident_points_finite_and_where_they_are(order):
    """A neighbourhood of coincident points (a pixel seen twice, a merged cloud) has no spread to fit: MLS must
    neither warn nor turn it into NaN."""
    rng = np.random.default_rng(4)
    plane = np.column_stack([rng.random((300, 2)) * 1e-3, np.zeros(300)])
    xyz = np.vstack([plane, np.repeat([[2e-3, 2e-3, 1e-4]], 30, axis=0)])
    with np.errstate(divide="raise", invalid="raise"):  # (float32 underflow of tiny weights is harmless)
        smoothed = mls_smooth(xyz, 12, order)
    assert np.isfinite(smoothed).all()
    np.testing.assert_allclose(smoothed[300:], xyz[300:], atol=1e-9)
    # the closed form itself, on the all-zero moments of coincident points (p = 0: its cube once underflowed)
    assert np.isfinite(smallest_eigenvector(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)).all()


def test_closed_form_normals_match_eigh():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3, 3))
    matrices = a @ a.transpose(0, 2, 1)
    _, vectors = np.linalg.eigh(matrices)
    normals = np.array([smallest_eigenvector(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]) for m in matrices])
    assert np.allclose(np.abs(np.einsum("ni,ni->n", normals, vectors[:, :, 0])), 1.0)
    # a matrix that is already diagonal: the axis of its smallest entry
    assert np.allclose(np.abs(smallest_eigenvector(3.0, 0.0, 0.0, 1.0, 0.0, 2.0)), (0.0, 1.0, 0.0))


def test_mls_moves_noisy_plane_points_onto_the_plane():
    rng = np.random.default_rng(5)
    tangent = rng.random((2000, 2)) * 4e-3
    noise = rng.normal(scale=2e-5, size=2000)
    # a tilted plane through (1, 2, 3) mm with unit normal n
    normal = np.array([1.0, -2.0, 2.0]) / 3.0
    axis_a = np.cross(normal, [0.0, 0.0, 1.0])
    axis_a /= np.linalg.norm(axis_a)
    axis_b = np.cross(normal, axis_a)
    xyz = 1e-3 * np.array([1.0, 2.0, 3.0]) + tangent[:, :1] * axis_a + tangent[:, 1:] * axis_b + noise[:, None] * normal
    # a plane averages the noise of 24 neighbours away; a quadric (6 unknowns) keeps more of it
    for order, left in ((1, 0.35), (2, 0.6)):
        height = (mls_smooth(xyz, 24, order) - 1e-3 * np.array([1.0, 2.0, 3.0])) @ normal
        assert np.abs(height).mean() < left * np.abs(noise).mean()


def test_quadric_height_is_the_fitted_constant_of_an_exact_quadric():
    rng = np.random.default_rng(6)
    a, b = rng.uniform(-1, 1, 12), rng.uniform(-1, 1, 12)
    h = 0.3 - 0.2 * a + 0.1 * b + 0.5 * a * a - 0.4 * a * b + 0.25 * b * b
    weights = rng.uniform(0.4, 1.0, 12)
    height = _quadric_height(a, b, h, weights, np.empty((6, 6)), np.empty(6))
    assert height == pytest.approx(0.3, abs=1e-5)  # (the regularisation of 1e-6 pulls the fit a little)
    # a paraboloid z = x^2 + y^2 (in mm) sampled on a grid: order 2 leaves its apex on it, a plane (order 1)
    # cuts the curvature; a point lifted off the apex is pulled most of the way back (it is its own neighbour)
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), axis=-1).reshape(-1, 2)
    xyz = 1e-3 * np.column_stack([grid, (grid ** 2).sum(axis=1)])
    apex = np.flatnonzero((grid == 0).all(axis=1))[0]
    assert mls_smooth(xyz, 25, order=2)[apex, 2] == pytest.approx(0.0, abs=1e-9)
    assert mls_smooth(xyz, 25, order=1)[apex, 2] > 1e-6
    xyz[apex, 2] = 5e-5
    assert abs(mls_smooth(xyz, 25, order=2)[apex, 2]) < 0.25 * 5e-5


def test_mean_neighbour_distances_skip_the_point_itself_and_missing_neighbours():
    inf = np.inf
    distances = np.array([[0.0, 1.0, 2.0, 3.0, 6.0],        # k = 3: the first 4 columns, the point itself out
                          [0.0, 1.0, inf, 2.0, 3.0],        # one missing: the mean of the two it has
                          [0.0, 1.0, 2.0, 3.0, inf]])
    means = _mean_neighbour_distances(distances, 3)
    assert means[0] == pytest.approx(2.0)
    assert means[1] == np.inf                               # only 2 neighbours: counted as alone
    assert means[2] == pytest.approx(2.0)
    assert _mean_neighbour_distances(distances, 4)[1] == pytest.approx(2.0)


def test_statistical_outlier_removal_drops_an_isolated_point_of_an_image():
    """On an organised cloud (neighbours from the image window), a pixel whose depth is far off its
    neighbours' is removed, and nothing else is."""
    depth = np.full((20, 20), 900, np.uint16)
    depth += np.arange(20, dtype=np.uint16)[None, :]        # a slope: not every distance alike
    depth[8, 11] = 1300                                     # 4 mm behind the surface
    intrinsics = Intrinsics(20, 20, 430.0, 430.0, 10.0, 10.0)
    xyz, _, pixel = depth_to_points(depth, intrinsics, 1e-4)
    cloud = Cloud(xyz, camera=np.zeros(len(xyz), np.int8), pixel=pixel)
    distances, _ = nearest_neighbours(cloud, 13)
    keep = statistical_outlier_mask(xyz, 12, 2.0, distances)
    outlier = np.flatnonzero((pixel == (11, 8)).all(axis=1))
    assert not keep[outlier].any()
    assert np.count_nonzero(~keep) == 1


def test_image_neighbours_agree_with_a_kd_tree_on_an_organised_cloud():
    depth = np.full((30, 30), 900, np.uint16)
    intrinsics = Intrinsics(30, 30, 430.0, 430.0, 15.0, 15.0)
    xyz, _, pixel = depth_to_points(depth, intrinsics, 1e-4)
    organised = Cloud(xyz, camera=np.zeros(len(xyz), np.int8), pixel=pixel)
    image_distance, _ = nearest_neighbours(organised, 9)
    tree_distance, _ = nearest_neighbours(Cloud(xyz), 9)
    interior = (pixel[:, 0] > 2) & (pixel[:, 0] < 27) & (pixel[:, 1] > 2) & (pixel[:, 1] < 27)
    assert np.allclose(image_distance[interior], tree_distance[interior])


def test_image_window_neighbours_are_the_nearest_of_the_window_in_order():
    """A 3x3 image of one camera and one pixel of another: the window (half 1) of the centre pixel holds the
    other eight; the nearest come first, equal distances in index order, missing ones at -1 / inf, and the
    other camera's pixel is no neighbour."""
    pixel = np.array([(u, v) for v in range(3) for u in range(3)] + [(1, 1)], dtype=np.int32)
    camera = np.array([0] * 9 + [1], np.int8)
    xyz = np.column_stack([pixel[:, 0] * 1e-4, pixel[:, 1] * 1e-4, np.zeros(10)])
    xyz[9] = xyz[4] + 1e-6                                  # close to the centre, but seen by camera 1
    distances, index = _image_window_neighbours(xyz, camera, pixel, 6, 1, 2)
    centre = 4
    assert index[centre].tolist() == [4, 1, 3, 5, 7, 0]
    np.testing.assert_allclose(distances[centre], [0.0, 1e-4, 1e-4, 1e-4, 1e-4, np.sqrt(2) * 1e-4], rtol=1e-6)
    corner = 0                                              # its window holds 4 points of its camera
    assert index[corner].tolist() == [0, 1, 3, 4, -1, -1]
    assert np.isinf(distances[corner, 4:]).all()
    assert index[9].tolist() == [9, -1, -1, -1, -1, -1]     # alone in camera 1


def test_neighbours_among_kept_renumber_and_drop():
    index = np.array([[0, 1, 2], [1, 0, 3], [2, 3, -1], [3, 2, 1]])
    keep = np.array([True, False, True, True])
    assert _neighbours_among_kept(index, keep).tolist() == [[0, -1, 1], [1, 2, -1], [2, 1, -1]]


def test_filter_chain_on_an_organised_cloud_keeps_the_surface_and_drops_the_outlier():
    config = make_config({})
    depth = np.full((INTRINSICS.height, INTRINSICS.width), 0, np.uint16)
    depth[220:260, 400:440] = 900                           # a flat patch 90 mm in front of cam_a
    depth[240, 420] = 1000                                  # one pixel 10 mm behind it
    frame = CameraFrame("cam_a", 0, depth=depth, intrinsics=INTRINSICS)
    cloud = fuse(pair_frames({"cam_a": [frame]}, 1)[0], config)
    filtered = filter_cloud(cloud, config)
    assert len(filtered) == len(cloud) - 1
    assert not ((filtered.pixel == (420, 240)).all(axis=1)).any()
    # the patch is flat: MLS leaves it flat (its distance from cam_a's plane stays 90 mm)
    camera = config.cameras["cam_a"]
    in_camera = (filtered.xyz - camera.translation) @ camera.extrinsic[:3, :3]
    np.testing.assert_allclose(in_camera[:, 2], 0.09, atol=1e-9)


def test_crop_colour_and_voxel_filters():
    xyz = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.0021, 0.0, 0.0], [0.5, 0.0, 0.0]])
    assert crop_box_mask(xyz, [-0.01] * 3, [0.01] * 3).tolist() == [True, True, True, False]
    rgb = pack_rgb(np.array([[200, 10, 10], [10, 200, 10], [100, 100, 100], [0, 0, 0]]))
    assert color_mask(rgb, [50, 50, 50], [255, 255, 255]).tolist() == [False, False, True, False]
    thinned = voxel_downsample(Cloud(xyz, rgb), 0.002)
    assert len(thinned) == 3
    assert np.allclose(sorted(thinned.xyz[:, 0]), [0.0005, 0.0021, 0.5])


def test_cloud_subset_by_mask_or_index_keeps_attributes_together_and_refuses_a_mask_of_another_length():
    rng = np.random.default_rng(5)
    xyz = rng.normal(size=(50, 3))
    cloud = Cloud(xyz, pack_rgb(rng.integers(0, 255, (50, 3))), np.arange(50, dtype=np.int8) % 2, 7, 1e-4,
                  rng.integers(0, 640, (50, 2)).astype(np.int32))
    mask = rng.random(50) > 0.5
    for selection in (mask, np.flatnonzero(mask)):
        picked = cloud.subset(selection)
        assert np.array_equal(picked.xyz, xyz[mask]) and np.array_equal(picked.pixel, cloud.pixel[mask])
        assert np.array_equal(picked.rgb, cloud.rgb[mask]) and np.array_equal(picked.camera, cloud.camera[mask])
    moved = cloud.subset(mask, xyz=np.zeros((mask.sum(), 3)))
    assert not moved.xyz.any() and np.array_equal(moved.pixel, cloud.pixel[mask])
    with pytest.raises(ValueError, match="mask of 10 entries for a cloud of 50"):
        cloud.subset(mask[:10])


def test_cloud_names_the_cameras_with_points_in_it():
    names = ("cam_a", "cam_b")
    both = Cloud(np.zeros((4, 3)), camera=np.array([1, 0, 1, 1], np.int8))
    assert both.cameras_in(names) == ["cam_a", "cam_b"]
    assert both.subset(both.camera == 1).cameras_in(names) == ["cam_b"]  # fusion published cam_b's alone
    assert Cloud(np.zeros((4, 3))).cameras_in(names) == []  # no per-point cameras
