"""Depth to points (Eq. 3-4), fusion (Eq. 9) with stamp pairing, and the filters (Eq. 5-6), on small
synthetic data with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_views import INTRINSICS, make_config

from ntcr_recon.core.cloud import Cloud, pack_rgb
from ntcr_recon.core.deproject import Intrinsics, crop_window, depth_to_points
from ntcr_recon.core.filters import (
    _smallest_eigenvectors_of,
    color_mask,
    crop_box_mask,
    mls_smooth,
    nearest_neighbours,
    smallest_eigenvectors,
    statistical_outlier_mask,
    voxel_downsample,
)
from ntcr_recon.core.fusion import CameraFrame, fuse
from ntcr_recon.core.pairing import pair_frames


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
    zero = np.zeros(2)
    with np.errstate(divide="raise", invalid="raise"):
        assert np.isfinite(_smallest_eigenvectors_of(zero, zero, zero, zero, zero, zero)).all()
        assert np.isfinite(smallest_eigenvectors(np.zeros((2, 3, 3)))).all()


def test_closed_form_normals_match_eigh():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3, 3))
    matrices = a @ a.transpose(0, 2, 1)
    _, vectors = np.linalg.eigh(matrices)
    assert np.allclose(np.abs(np.einsum("ni,ni->n", smallest_eigenvectors(matrices), vectors[:, :, 0])), 1.0)


def test_image_neighbours_agree_with_a_kd_tree_on_an_organised_cloud():
    depth = np.full((30, 30), 900, np.uint16)
    intrinsics = Intrinsics(30, 30, 430.0, 430.0, 15.0, 15.0)
    xyz, _, pixel = depth_to_points(depth, intrinsics, 1e-4)
    organised = Cloud(xyz, camera=np.zeros(len(xyz), np.int8), pixel=pixel)
    image_distance, _ = nearest_neighbours(organised, 9)
    tree_distance, _ = nearest_neighbours(Cloud(xyz), 9)
    interior = (pixel[:, 0] > 2) & (pixel[:, 0] < 27) & (pixel[:, 1] > 2) & (pixel[:, 1] < 27)
    assert np.allclose(image_distance[interior], tree_distance[interior])


def test_crop_colour_and_voxel_filters():
    xyz = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.0021, 0.0, 0.0], [0.5, 0.0, 0.0]])
    assert crop_box_mask(xyz, [-0.01] * 3, [0.01] * 3).tolist() == [True, True, True, False]
    rgb = pack_rgb(np.array([[200, 10, 10], [10, 200, 10], [100, 100, 100], [0, 0, 0]]))
    assert color_mask(rgb, [50, 50, 50], [255, 255, 255]).tolist() == [False, False, True, False]
    thinned = voxel_downsample(Cloud(xyz, rgb), 0.002)
    assert len(thinned) == 3
    assert np.allclose(sorted(thinned.xyz[:, 0]), [0.0005, 0.0021, 0.5])
