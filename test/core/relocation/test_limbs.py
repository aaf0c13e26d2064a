"""The tube's limbs in the cameras' colour images place the axis across their views (core.relocation.limbs)."""

import itertools

import numpy as np
import pytest
from scipy import ndimage

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limbs import (
    WINDOW_MARGIN_PX,
    CameraView,
    LimbFigures,
    interpolation_error,
    limb_edges,
    limb_offsets,
    placed_by_limbs,
)

RADIUS = 1.75e-3
DEPTH = 0.09
INTRINSICS = Intrinsics(848, 480, 421.6, 421.6, 428.7, 238.1)
BACKGROUND = np.array([40.0, 60.0, 160.0])  # a blue cloth behind the tube


def opposed_cameras(distance: float = DEPTH) -> dict[str, np.ndarray]:
    """Two cameras facing each other across the base origin along z (optical frames in the base frame)."""
    cam_a = np.eye(4)
    cam_a[2, 3] = -distance
    cam_b = np.diag([-1.0, 1.0, -1.0, 1.0])  # turned half a turn about y
    cam_b[2, 3] = distance
    return {"cam_a": cam_a, "cam_b": cam_b}


def tube_image(extrinsic: np.ndarray, axis_y: float, light: float = 0.0, seed: int = 0) -> np.ndarray:
    """A straight tube along the base x axis at y = axis_y, z = 0, seen by a camera: shaded darker towards its
    limbs (and brighter on one side by `light`), against a cloth with a weave, each pixel the mean of what it
    covers (4 x 4 samples), through a blurring lens."""
    rng = np.random.default_rng(seed)
    rotation, origin = extrinsic[:3, :3], extrinsic[:3, 3]
    point = rotation.T @ (np.array([0.0, axis_y, 0.0]) - origin)
    direction = rotation.T @ np.array([1.0, 0.0, 0.0])
    v, u = np.mgrid[0:INTRINSICS.height, 0:INTRINSICS.width].astype(float)
    cloth = BACKGROUND * (1.0 + 0.15 * rng.standard_normal(u.shape))[..., None]
    image = np.zeros_like(cloth)
    for du, dv in itertools.product((np.arange(4) + 0.5) / 4 - 0.5, repeat=2):
        rays = np.stack([(u + du - INTRINSICS.cx) / INTRINSICS.fx, (v + dv - INTRINSICS.cy) / INTRINSICS.fy,
                         np.ones_like(u)], -1)
        normal = np.cross(rays, direction)
        signed = normal @ point / np.linalg.norm(normal, axis=-1)  # the ray's distance from the axis, by side
        inside = (np.abs(signed) < RADIUS)[..., None]
        across = np.clip(signed / RADIUS, -1.0, 1.0)
        shade = (40.0 + 170.0 * np.sqrt(1.0 - across**2) + light * across)[..., None] * np.array([1.0, 1.0, 1.05])
        image += np.where(inside, shade, cloth) / 16
    image = ndimage.gaussian_filter(image, (0.8, 0.8, 0)) + rng.normal(0.0, 2.0, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def straight_centerline(axis_y: float, length: float = 0.03) -> Centerline:
    points = np.stack([np.linspace(-length / 2, length / 2, 200), np.full(200, axis_y), np.zeros(200)], axis=1)
    return Centerline.from_points(points, np.array([0.0, 0.0, 1.0]), 1e-4)


def views_of(axis_y: float, light: float = 0.0) -> dict[str, CameraView]:
    return {name: CameraView(tube_image(pose, axis_y, light, seed=i), INTRINSICS, pose)
            for i, (name, pose) in enumerate(opposed_cameras().items())}


@pytest.mark.parametrize("off", [0.0, 0.15e-3])
def test_one_camera_measures_the_axis_offset_across_its_view(off):
    views = views_of(axis_y=0.0)
    centerline = straight_centerline(off)  # the centreline given lies `off` (0.7 px) from the tube along +y
    s = np.linspace(0.002, 0.028, 40)
    placement = limb_offsets(centerline, s, views["cam_a"], RADIUS)
    measured = np.isfinite(placement.offset)
    assert measured.sum() >= 35
    # the move the limbs ask for, along y: none on the tube; off it, towards the tube, part of the way (the
    # levels the limbs are read between are sampled about where the axis puts them: placed_by_limbs measures again)
    along_y = np.median(placement.offset[measured] * placement.across[measured, 1])
    if off:
        assert -1.1 * off < along_y < -0.4 * off
    else:
        assert abs(along_y) < 0.01e-3
    # across the view and the tangent: perpendicular to both
    assert np.allclose(placement.across[measured] @ np.array([1.0, 0.0, 0.0]), 0.0, atol=1e-3)
    assert np.allclose(placement.across[measured] @ np.array([0.0, 0.0, 1.0]), 0.0, atol=3e-3)


@pytest.mark.parametrize("light", [0.0, 30.0])
def test_opposed_cameras_move_the_centreline_onto_the_tube(light):
    views = views_of(axis_y=0.0, light=light)
    centerline = straight_centerline(0.2e-3)
    moved, figures = placed_by_limbs(centerline, views, RADIUS, window=3.2e-3, end_s=centerline.length)
    assert figures.windows["cam_a"] >= 7 and figures.windows["cam_b"] >= 7
    # towards the tube across the views (y), at least 35 % of the way (see placed_by_limbs), nothing along them (z)
    # or along the tube
    assert 0.07e-3 < figures.moved_rms < 0.22e-3
    middle = (moved.s > 0.005) & (moved.s < moved.length - 0.005)
    assert np.all(moved.points[middle, 1] < 0.13e-3) and np.all(moved.points[middle, 1] > -0.03e-3)
    assert np.max(np.abs(moved.points[middle, 2])) < 1e-6
    assert moved.length == pytest.approx(centerline.length, abs=1e-5)


def test_an_image_without_contrast_moves_nothing():
    flat = {name: CameraView(np.full((INTRINSICS.height, INTRINSICS.width, 3), 180, np.uint8), INTRINSICS, pose)
            for name, pose in opposed_cameras().items()}  # as the second renderer's images
    centerline = straight_centerline(0.2e-3)
    moved, figures = placed_by_limbs(centerline, flat, RADIUS, window=3.2e-3, end_s=centerline.length)
    assert moved is centerline
    assert figures.windows == {"cam_a": 0, "cam_b": 0} and figures.moved_rms == 0.0


def test_a_window_one_camera_alone_placed_is_not_moved():
    views = views_of(axis_y=0.0)
    blank = np.full((INTRINSICS.height, INTRINSICS.width, 3), 180, np.uint8)
    one = {"cam_a": views["cam_a"], "cam_b": CameraView(blank, INTRINSICS, views["cam_b"].extrinsic)}
    centerline = straight_centerline(0.2e-3)
    moved, figures = placed_by_limbs(centerline, one, RADIUS, window=3.2e-3, end_s=centerline.length)
    assert figures.windows["cam_a"] >= 7 and figures.windows["cam_b"] == 0
    assert moved is centerline


def test_a_camera_view_names_an_image_that_does_not_fit_its_intrinsics():
    with pytest.raises(ValueError, match="848x480"):
        CameraView(np.zeros((240, 424, 3), np.uint8), INTRINSICS, np.eye(4))


def test_a_view_cut_around_the_robots_pixels_reads_the_limbs_as_the_whole_image():
    pose = opposed_cameras()["cam_a"]
    view = CameraView(tube_image(pose, 0.0), INTRINSICS, pose)
    centerline = straight_centerline(0.1e-3, length=0.02)
    # the robot's pixels as depth keeps them: its silhouette between 2 mm either side of the middle of the image
    rows = np.arange(int(INTRINSICS.cy - 7), int(INTRINSICS.cy + 8))
    columns = np.arange(int(INTRINSICS.cx - 47), int(INTRINSICS.cx + 48))
    pixels = np.stack(np.meshgrid(columns, rows), axis=-1).reshape(-1, 2)
    cut = view.around(pixels)
    k, c = view.intrinsics, cut.intrinsics
    u0, v0 = round(k.cx - c.cx), round(k.cy - c.cy)
    assert (u0, v0) == (columns[0] - WINDOW_MARGIN_PX, rows[0] - WINDOW_MARGIN_PX) and (c.fx, c.fy) == (k.fx, k.fy)
    assert (c.width, c.height) == (len(columns) + 2 * WINDOW_MARGIN_PX, len(rows) + 2 * WINDOW_MARGIN_PX)
    np.testing.assert_array_equal(cut.color, view.color[v0:v0 + c.height, u0:u0 + c.width])
    # the limbs read the same off the window as off the whole image, wherever the robot's pixels are
    s = np.linspace(0.0085, 0.0115, 7)  # stations within the pixels' 4 mm
    whole, window = (limb_offsets(centerline, s, v, RADIUS).offset for v in (view, cut))
    assert np.all(np.isfinite(whole))
    np.testing.assert_allclose(window, whole, rtol=0, atol=1e-15)  # the window shifts the pixel coordinates
    assert view.around(np.zeros((0, 2), int)) is None  # a camera that does not see the robot: no view


def test_a_shift_counts_unmeasured_only_off_the_directions_the_limbs_placed_the_axis_along():
    """Opposed cameras share one direction across their views (x here, the views along y): the limbs measured a
    shift along x, not along the views, and nothing where their last window falls short of the stretch asked."""
    figures = LimbFigures({"cam_a": 5, "cam_b": 5}, 1e-5, 2e-6, reach=0.04,
                          distal_across=np.array([[1.0, 0.0, 0.0], [-0.999, 0.045, 0.0]]))
    shift = np.array([3e-5, 4e-5, 0.0])
    assert figures.unchecked(shift, reaching=0.035) == pytest.approx(4e-5, rel=0.05)
    assert figures.unchecked(shift, reaching=0.045) == pytest.approx(5e-5)
    assert LimbFigures({}, 0.0).unchecked(shift, reaching=0.0) == pytest.approx(5e-5)


def test_the_limbs_are_read_up_to_the_end_seen_less_the_end_discs_reach():
    """Side on, the end disc reaches nothing along the axis in the image: the limbs are read right up to the end
    seen and the last window is placed (the tip's across bound then rests on them); none past that end."""
    views = views_of(axis_y=0.0)
    centerline = straight_centerline(0.0)
    end_s = 0.0201
    s = np.linspace(0.015, 0.025, 41)
    placement = limb_offsets(centerline, s, views["cam_a"], RADIUS, end_s=end_s)
    measured = np.isfinite(placement.offset)
    assert not np.any(measured[s > end_s])
    assert np.count_nonzero(measured[(s <= end_s) & (s > end_s - RADIUS)]) >= 6
    _, figures = placed_by_limbs(centerline, views, RADIUS, window=3.2e-3, end_s=centerline.length)
    assert figures.reach == pytest.approx(centerline.length, abs=1e-6)
    assert figures.windows == {"cam_a": 10, "cam_b": 10}


def test_past_the_last_window_placed_the_move_is_held_to_the_free_end():
    """A centreline 0.2 mm off the tube across the views (y), its last 8 mm past the end the limbs are read up to
    (end_s): there it keeps the last window's move (the free end, where a matcher's depth smears most, lies as the
    last window placed it), not depth's; before the first window the move fades in from the base."""
    views = views_of(axis_y=0.0)
    centerline = straight_centerline(0.2e-3)
    end_s = centerline.length - 8e-3
    moved, figures = placed_by_limbs(centerline, views, RADIUS, window=3.2e-3, end_s=end_s)
    s = np.linspace(0.0, centerline.length, 301)
    shift = moved.frames_at(s)[0][:, 1] - centerline.frames_at(s)[0][:, 1]
    last_window = (s > end_s - 3.2e-3) & (s < end_s)
    free_end = s > end_s
    assert np.median(shift[last_window]) < -0.07e-3  # towards the tube
    assert np.allclose(shift[free_end], np.median(shift[last_window]), atol=0.02e-3)
    # faded in at the base: at most half (the first window's middle lies half a window out)
    assert abs(shift[0]) < 0.55 * abs(np.median(shift[last_window]))


def test_the_interpolation_error_is_each_windows_move_against_what_the_others_interpolate():
    centres = np.arange(6) * 2e-3
    # a move alike all along is interpolated exactly; one varying linearly is between windows, and held past the
    # ends the end windows miss by a step; one window 0.1 mm off misses by that, its neighbours by half of it
    assert interpolation_error(centres, np.full((6, 3), 1e-4)) == pytest.approx(0.0, abs=1e-12)
    linear = np.stack([centres * 0.01, np.zeros(6), np.zeros(6)], axis=1)
    assert interpolation_error(centres, linear) == pytest.approx(np.sqrt(2 * (0.01 * 2e-3) ** 2 / 6))
    bumped = np.zeros((6, 3))
    bumped[2, 1] = 1e-4
    assert interpolation_error(centres, bumped) == pytest.approx(np.sqrt((1e-4**2 + 2 * (0.5e-4) ** 2) / 6))
    assert interpolation_error(centres[:3], bumped[:3]) is None  # too few to leave one out of


def test_a_shaded_limb_is_read_where_the_tube_meets_the_background_not_inward():
    """The tube darkens towards its limbs: read half-way to its mean colour inside, each limb lies inward (the pair
    1.3 px narrower than the tube on this cloth); carried on to the blur's reach, within 0.8 px of its width."""
    view = views_of(axis_y=0.0)["cam_a"]
    s = np.linspace(0.002, 0.028, 40)

    def narrower(shaded: bool) -> float:
        edges = limb_edges(straight_centerline(0.0), s, view, RADIUS, shaded=shaded)
        return float(np.nanmedian(2 * edges.half_width - (edges.limbs[:, 1] - edges.limbs[:, 0])))

    assert narrower(shaded=False) > 1.2
    assert 0.0 < narrower(shaded=True) < 0.8
