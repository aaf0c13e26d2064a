"""Notches the tube's outline in the colour images shows (core.relocation.outline_notches)."""

import numpy as np
import pytest
from scipy import ndimage

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limbs import CameraView
from ntcr_recon.core.relocation.outline_notches import (
    comb_shift_in_outline,
    least_recession,
    limb_fall,
    notches_in_outline,
)
from ntcr_recon.core.robot.geometry import TubeGeometry

GEOMETRY = TubeGeometry()
RADIUS, CUT = GEOMETRY.outer_radius, GEOMETRY.chord_offset
DEPTH = 0.09
INTRINSICS = Intrinsics(848, 480, 421.6, 421.6, 424.0, 240.0)
LENGTH = 0.055
CENTRES = GEOMETRY.proximal_length + GEOMETRY.notch_width / 2 + GEOMETRY.notch_pitch * np.arange(GEOMETRY.notch_count)


def opposed_cameras() -> dict[str, np.ndarray]:
    """Two cameras facing each other across the tube's middle along z (optical frames in the base frame)."""
    cam_a = np.eye(4)
    cam_a[:3, 3] = (LENGTH / 2, 0.0, -DEPTH)
    cam_b = np.diag([-1.0, 1.0, -1.0, 1.0])  # turned half a turn about y
    cam_b[:3, 3] = (LENGTH / 2, 0.0, DEPTH)
    return {"cam_a": cam_a, "cam_b": cam_b}


def notched_tube_image(extrinsic: np.ndarray, cut: set[int], facing: bool, seed: int = 0,
                       blotches: float = 0.0) -> np.ndarray:
    """A straight tube along the base x axis from 0 to LENGTH, its notches `cut` (the robot's comb) opening across
    the view (one limb falls to the backbone's edge, `facing` False) or towards the camera (both limbs fall to the
    backbone's chord, the least a cut recedes them), against a woven cloth (with light and dark patches a few pixels
    across, their contrast `blotches` of the cloth's colour), through a blurring lens."""
    rng = np.random.default_rng(seed)
    rotation, origin = extrinsic[:3, :3], extrinsic[:3, 3]
    v, u = np.mgrid[0:INTRINSICS.height, 0:INTRINSICS.width].astype(float)
    rays = np.stack([(u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy, np.ones_like(u)], -1)
    rays = rays @ rotation.T  # in the base frame
    along = origin[0] - origin[2] * rays[..., 0] / rays[..., 2]  # x where the ray crosses the tube's plane z = 0
    signed = origin[1] - origin[2] * rays[..., 1] / rays[..., 2]  # and y there (the view is square to the tube)
    inside = (np.abs(signed) < RADIUS) & (along > 0) & (along < LENGTH)
    in_cut = np.zeros_like(inside)
    for index in cut:
        in_cut |= np.abs(along - CENTRES[index]) < GEOMETRY.notch_width / 2
    chord = np.sqrt(RADIUS**2 - CUT**2)
    backbone = np.abs(signed) < chord if facing else (signed > -RADIUS) & (signed < -CUT)
    inside &= ~in_cut | backbone
    # across the view: shaded darker towards the limbs; facing, an evenly lit matte tube (a limb shaded dark reads
    # up to a pixel inward, as far as the least recession: outline_notches' docstring)
    shade = np.full(u.shape, 150.0) if facing else 40.0 + 170.0 * np.sqrt(1.0 - np.clip(signed / RADIUS, -1, 1) ** 2)
    patches = ndimage.gaussian_filter(rng.standard_normal(u.shape), 2.5)
    weave = 1.0 + 0.15 * rng.standard_normal(u.shape) + blotches * patches / patches.std()
    image = np.array([40.0, 60.0, 160.0]) * weave[..., None]
    image[inside] = shade[inside][:, None] * np.array([1.0, 1.0, 1.05])
    image = ndimage.gaussian_filter(image, (0.8, 0.8, 0)) + rng.normal(0.0, 2.0, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def centerline(facing: bool = False) -> Centerline:
    """The tube's axis; its frame's normal (the notch side) across the cameras' views (+y), or `facing` them (z)."""
    points = np.stack([np.linspace(0.0, LENGTH, 551), np.zeros(551), np.zeros(551)], axis=1)
    return Centerline.from_points(points, np.array([0.0, -1.0, 0.0] if facing else [0.0, 0.0, 1.0]), 1e-4)


@pytest.mark.parametrize("facing", [False, True])
def test_the_outline_shows_the_notches_cut_and_not_the_others(facing):
    cut = set(range(GEOMETRY.notch_count)) - {3, 7, 12}
    views = {name: CameraView(notched_tube_image(pose, cut, facing, seed=i), INTRINSICS, pose)
             for i, (name, pose) in enumerate(opposed_cameras().items())}
    found = notches_in_outline(centerline(), views, GEOMETRY, CENTRES, list(range(GEOMETRY.notch_count)), LENGTH)
    assert set(found) == cut
    # facing a camera both limbs fall to the backbone's chord, 0.15 mm in; across the view one falls past the search
    least = least_recession(GEOMETRY)
    assert least == pytest.approx(RADIUS - np.sqrt(RADIUS**2 - CUT**2))
    recessions = np.array(list(found.values()))
    if facing:
        assert np.all(np.abs(recessions - least) < 0.5 * least)
    else:
        assert np.all(recessions > 4 * least)


def test_a_slot_seen_side_on_shows_the_background_whose_shades_are_no_limb():
    # the real matcher's scenes: a blotchy cloth behind the slot, whose light and dark patches the limbs' kernel
    # reads as a crossing where the limb was (found outward of it, not receded)
    cut = set(range(GEOMETRY.notch_count)) - {3, 7, 12}
    views = {name: CameraView(notched_tube_image(pose, cut, False, seed=i, blotches=0.4), INTRINSICS, pose)
             for i, (name, pose) in enumerate(opposed_cameras().items())}
    found = notches_in_outline(centerline(), views, GEOMETRY, CENTRES, list(range(GEOMETRY.notch_count)), LENGTH)
    assert set(found) == cut


def test_only_the_notches_asked_about_and_seen_whole_with_their_spines():
    views = {name: CameraView(notched_tube_image(pose, set(range(16)), False, seed=i), INTRINSICS, pose)
             for i, (name, pose) in enumerate(opposed_cameras().items())}
    found = notches_in_outline(centerline(), views, GEOMETRY, CENTRES, [0, 5, 15], end_s=CENTRES[15])
    assert set(found) == {0, 5}  # the last one's distal spine lies past the end seen
    assert notches_in_outline(centerline(), {}, GEOMETRY, CENTRES, [0, 5], LENGTH) == {}
    # a cut short of the axis leaves a camera looking along the notch side both limbs: no least recession to look for
    assert least_recession(TubeGeometry(notch_depth=1.5e-3)) == 0.0


@pytest.mark.parametrize("off_mm", [0.4, -0.25, 0.0])
def test_the_comb_slides_to_where_the_outline_shows_its_notches(off_mm):
    # a matcher's fattened spines shift the slots depth sees; the outline places the comb (to a step of 0.075 mm)
    views = {name: CameraView(notched_tube_image(pose, set(range(16)), False, seed=i, blotches=0.4), INTRINSICS, pose)
             for i, (name, pose) in enumerate(opposed_cameras().items())}
    shift = comb_shift_in_outline(centerline(), views, GEOMETRY, CENTRES + off_mm * 1e-3, LENGTH)
    assert shift == pytest.approx(-off_mm * 1e-3, abs=0.05e-3)


def test_the_comb_is_left_to_depth_where_the_cameras_look_along_the_notch_side():
    # seen along the notch side the limbs fall by the chord's least only: no view to slide the comb by
    views = {name: CameraView(notched_tube_image(pose, set(range(16)), True, seed=i), INTRINSICS, pose)
             for i, (name, pose) in enumerate(opposed_cameras().items())}
    assert comb_shift_in_outline(centerline(facing=True), views, GEOMETRY, CENTRES, LENGTH) is None
    assert limb_fall(centerline(facing=True), views["cam_a"], GEOMETRY, CENTRES) == pytest.approx(
        least_recession(GEOMETRY))
    # side on, the cut limb falls past the axis to the backbone's chord
    assert limb_fall(centerline(), views["cam_a"], GEOMETRY, CENTRES) == pytest.approx(RADIUS + CUT)
