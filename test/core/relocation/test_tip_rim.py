"""The tip's refinement (relocation.tip) on known inputs: the band a stereo matcher spoils at a depth edge, measured
in a depth image; how much of an end that band takes in a camera's image; the half-density end; and the tip
from analytic wall points cut short by a known band. Then the whole reconstruction on the tests' own renderer
(not the package's simulator) given a backdrop, whose blur spoils edges differently from the simulator's
matcher. Each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.synthetic_views import posed_scene, render_pair

from ntcr_recon.core.quality.checks import assess
from ntcr_recon.core.quality.trace import Trace
from ntcr_recon.core.reconstruction.reconstructor import Reconstructor
from ntcr_recon.core.reconstruction.relocate import Relocator
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.tip import (
    RimViews,
    edge_band,
    half_density_end,
    rim_erosion,
    rim_tip,
    with_known_length,
)
from ntcr_recon.core.robot.geometry import TubeGeometry

UNIT = 1e-4
R_O = 1.75e-3
FOOTPRINT = 0.2e-3


def _depth_image(band: int, shadow: int = 0, background: bool = True, seed: int = 0,
                 noise_at_90mm: float = 2e-5) -> np.ndarray:
    """A near block (90 mm) on a far wall (300 mm), `band` pixels spoiled either side of every edge (dropped or
    mixed), and `shadow` pixels of no depth left of the block (a stereo pair's occlusion shadow, along rows).
    Depth noise grows with z^2 (a matcher's is constant in disparity)."""
    rng = np.random.default_rng(seed)
    height, width = 120, 200
    near = np.zeros((height, width), bool)
    near[40:80, 60:150] = True
    depth = np.where(near, 0.090, 0.300)
    depth = depth + rng.normal(0.0, 1.0, (height, width)) * noise_at_90mm * (depth / 0.09) ** 2
    if band:
        # pixels within `band` of the other surface (Chebyshev distance), either side of the edge
        from scipy.ndimage import binary_dilation
        structure = np.ones((2 * band + 1, 2 * band + 1), bool)
        spoiled = binary_dilation(near, structure) & binary_dilation(~near, structure)
        mixed = rng.uniform(0.1, 0.9, (height, width))
        depth = np.where(spoiled, np.where(rng.random((height, width)) < 0.5, 0.0,
                                           0.090 * mixed + 0.300 * (1 - mixed)), depth)
    if shadow:
        depth[40:80, 60 - band - shadow:60 - band] = 0.0
    if not background:
        depth = np.where(near, depth, 0.0)
    return np.rint(depth / UNIT).astype(np.uint16)


@pytest.mark.parametrize("noise_at_90mm", [2e-5, 1.7e-4])  # the tests' renderer's; twice a D405's
@pytest.mark.parametrize("band", [0, 1, 2, 3])
def test_edge_band_is_read_off_the_depth_image(band, noise_at_90mm):
    measured = edge_band(_depth_image(band, shadow=25, noise_at_90mm=noise_at_90mm), UNIT)
    print(f"\n{band} px spoiled either side of the edges, noise {noise_at_90mm * 1e3:.2f} mm at 90 mm: "
          f"measured {measured} px")
    assert measured == pytest.approx(band, abs=0.5)


def test_edge_band_needs_a_far_background():
    assert edge_band(_depth_image(2, background=False), UNIT) is None


def test_rim_erosion_follows_the_ends_outline_in_the_image():
    band = 0.4e-3
    side_on = rim_erosion(band, 0.0, R_O)
    print(f"\nband {band * 1e3:.2f} mm: side-on {side_on * 1e3:.3f} mm, turned away 45 deg "
          f"{rim_erosion(band, -math.sqrt(0.5), R_O) * 1e3:.3f} mm, turned towards 45 deg "
          f"{rim_erosion(band, math.sqrt(0.5), R_O) * 1e3:.3f} mm")
    assert side_on == pytest.approx(band)
    # turned away: the facing wall's rim is the outline, the band bites along the foreshortened axis
    c = -math.sqrt(0.5)
    psi = math.radians(30.0)
    expected = band * math.sqrt(math.cos(psi) ** 2 + c * c * math.sin(psi) ** 2) / math.cos(psi) / math.sqrt(0.5)
    assert rim_erosion(band, c, R_O) == pytest.approx(expected)
    assert rim_erosion(band, c, R_O) > side_on
    # turned towards: the cap makes the outline and the facing wall ends well inside it
    assert rim_erosion(band, math.sqrt(0.5), R_O) == 0.0
    assert 0.0 < rim_erosion(band, 0.05, R_O) < side_on
    assert rim_erosion(0.0, -0.3, R_O) == 0.0


def _seen_wall(end: float, facing_y: float, rng, start: float = 10e-3) -> np.ndarray:
    """Wall points a camera on the `facing_y` side sees of a straight tube along z: lateral positions uniform
    (pixel columns across the tube), each line of pixels along the axis with its own phase, up to `end`."""
    points = []
    for x in np.arange(-0.95 * R_O, 0.95 * R_O, FOOTPRINT / 2):
        s = np.arange(start + rng.uniform(0, FOOTPRINT), end, FOOTPRINT)
        y = facing_y * math.sqrt(R_O**2 - x**2)
        points.append(np.stack([np.full_like(s, x), np.full_like(s, y), s], axis=1))
    return np.concatenate(points)


def test_half_density_end_is_the_end_whatever_the_pixel_phase():
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(20):
        end = 30e-3 + rng.uniform(0, FOOTPRINT)
        s = _seen_wall(end, -1.0, rng)[:, 2]
        errors.append(half_density_end(s, end + 0.3e-3, FOOTPRINT, 2 * FOOTPRINT, 6e-3, 3.5e-3) - end)
    errors = np.array(errors)
    print(f"\nhalf-density end: mean {errors.mean() * 1e3:+.3f} mm, worst {np.abs(errors).max() * 1e3:.3f} mm")
    assert abs(errors.mean()) < FOOTPRINT / 4
    assert np.abs(errors).max() < FOOTPRINT / 2
    assert half_density_end(np.zeros(0), 30e-3, FOOTPRINT, 2 * FOOTPRINT, 6e-3, 3.5e-3) is None


def test_tip_of_a_tube_whose_rim_lost_a_known_band_in_each_camera():
    """Two cameras side-on at -y and +y; each lost a different band at the end (what its depth images show)."""
    length = 30e-3
    rng = np.random.default_rng(5)
    s = np.linspace(0.0, length + 5e-3, 351)
    centerline = Centerline.from_points(np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=1),
                                        np.array([0.0, 1.0, 0.0]), 0.1e-3)
    origins = np.array([[0.0, -0.09, 0.0], [0.0, 0.09, 0.0]])
    lost = [0.4e-3, 0.25e-3]  # m at 90 mm
    a, b = _seen_wall(length - lost[0], -1.0, rng), _seen_wall(length - lost[1], 1.0, rng)
    coords = centerline.project(np.concatenate([a, b]))
    camera = np.concatenate([np.zeros(len(a), np.int8), np.ones(len(b), np.int8)])
    spine = np.ones(len(camera), bool)
    bands = np.array(lost) / 0.09  # angles
    coarse = length - 0.3e-3  # as a slab-wise coarse end might read it
    ends, tip, uncertainty = rim_tip(coords, RimViews(camera, origins, bands), centerline, coarse, R_O,
                                     0.8e-3, FOOTPRINT, 2 * FOOTPRINT, spine, 6e-3)
    print(f"\nrims lost {lost[0] * 1e3:.2f} / {lost[1] * 1e3:.2f} mm: ends {(ends - length) * 1e3:+.3f} mm, "
          f"tip {(tip - length) * 1e3:+.3f} mm")
    assert ends == pytest.approx(length - np.mean(lost), abs=FOOTPRINT / 2)
    assert tip == pytest.approx(length, abs=FOOTPRINT / 2)
    # half a pixel for the end, half for a band of whole pixels: a footprint along s, over the view's sine
    assert uncertainty == pytest.approx(FOOTPRINT * math.hypot(0.09, coarse) / 0.09)
    # a camera seeing the end without a measured band: no refined tip (the caller falls back)
    assert rim_tip(coords, RimViews(camera, origins, np.array([bands[0], np.nan])), centerline, coarse, R_O,
                   0.8e-3, FOOTPRINT, 2 * FOOTPRINT, spine, 6e-3) is None


def test_a_camera_whose_wall_stops_at_the_last_notch_is_not_heard_on_the_tip():
    """The short ring beyond the last notch, eroded by the matcher from both its edges, is lost to the camera
    facing the notch side: its wall stops where the last cut begins, 1.5 mm before the end. The other camera saw
    the end; the tip is its (a mean of both was 0.75 mm short). A camera alone with such a wall is still heard."""
    length, last_notch_s = 30e-3, 29e-3
    rng = np.random.default_rng(6)
    s = np.linspace(0.0, length + 5e-3, 351)
    centerline = Centerline.from_points(np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=1),
                                        np.array([0.0, 1.0, 0.0]), 0.1e-3)
    origins = np.array([[0.0, -0.09, 0.0], [0.0, 0.09, 0.0]])
    band = 0.3e-3
    a, b = _seen_wall(length - band, -1.0, rng), _seen_wall(length - 1.5e-3, 1.0, rng)
    coords = centerline.project(np.concatenate([a, b]))
    camera = np.concatenate([np.zeros(len(a), np.int8), np.ones(len(b), np.int8)])
    spine = np.ones(len(camera), bool)
    bands = np.full(2, band / 0.09)

    def tip(keep=slice(None)):
        return rim_tip(type(coords)(coords.s[keep], coords.x[keep], coords.y[keep]),
                       RimViews(camera[keep], origins, bands), centerline, length - 0.3e-3, R_O, 0.8e-3,
                       FOOTPRINT, 2 * FOOTPRINT, spine[keep], 6e-3, last_notch_s=last_notch_s)[1]

    both = tip()
    print(f"\ntip {(both - length) * 1e3:+.3f} mm from the end")
    assert both == pytest.approx(length, abs=FOOTPRINT / 2)
    alone = tip(camera == 1)
    assert alone == pytest.approx(length - 1.5e-3 + band, abs=FOOTPRINT / 2)


def test_the_tip_weighs_the_end_seen_against_the_robots_known_length():
    """The end seen 0.2 mm past the robot's length, known to 0.2 and 0.1 mm: the tip lies between them, by their
    inverse variances (30.04 mm), known better than either (0.089 mm). 1 mm short, 4.5 combined uncertainties
    off: they disagree, the end seen stands and the result says so; with no tolerance the length is not used.
    An end cap's points, which only ever lie short of the cap, are a lower bound: the length beyond them is the
    tip."""
    agreed = with_known_length(30.2e-3, 0.2e-3, 30.0e-3, 0.1e-3)
    assert agreed.length_weighed
    assert agreed.s == pytest.approx(30.04e-3) and agreed.uncertainty == pytest.approx(1 / math.sqrt(125) * 1e-3)
    assert agreed.seen_s == 30.2e-3 and agreed.disagreement == pytest.approx(-0.2 / math.hypot(0.2, 0.1))
    apart = with_known_length(29.0e-3, 0.2e-3, 30.0e-3, 0.1e-3)
    assert not apart.length_weighed and apart.s == 29.0e-3 and apart.uncertainty == 0.2e-3
    assert apart.disagreement == pytest.approx(1.0 / math.hypot(0.2, 0.1))
    unknown = with_known_length(29.9e-3, 0.2e-3, 30.0e-3, None)
    assert not unknown.length_weighed and unknown.s == 29.9e-3
    # an end cap's points the matcher only ever moved towards the base bound the tip from below: a length 0.3 mm
    # beyond them is the tip, known as well as the length; a length short of them is weighed as any end seen
    bounded = with_known_length(29.7e-3, 0.2e-3, 30.0e-3, 0.1e-3, lower_bound=True)
    assert bounded.beyond_seen and bounded.length_weighed
    assert bounded.s == 30.0e-3 and bounded.uncertainty == 0.1e-3 and bounded.seen_s == 29.7e-3
    past = with_known_length(30.2e-3, 0.2e-3, 30.0e-3, 0.1e-3, lower_bound=True)
    assert not past.beyond_seen and past.s == pytest.approx(agreed.s)
    assert not with_known_length(29.0e-3, 0.2e-3, 30.0e-3, 0.1e-3, lower_bound=True).length_weighed  # disagree

    geometry = TubeGeometry()  # 53 mm straight

    def warnings_for(along, **more):
        return assess(Trace(geometry=geometry, camera_names=("cam_a", "cam_b"), notches=[],
                      coords_s=np.linspace(0.0, along.s, 100), camera=np.arange(100) % 2, tip_s=along.s,
                      total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
                      bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, tip_uncertainty=along.seen_uncertainty,
                      tip_along=along, outline_offset=0.02e-3, **more))  # (the outline checked the axis)

    quality, warnings = warnings_for(with_known_length(52.0e-3, 0.2e-3, geometry.length, 0.1e-3))
    print("\n" + "\n".join(map(str, warnings)))
    off = [w for w in warnings if w.code == "TIP_OFF_LENGTH"]
    assert [round(w.figures["short_of_length_mm"], 2) for w in off] == [1.00]  # the end seen lies 1.00 mm short
    assert quality["tip_seen_s_mm"] == pytest.approx(52.0) and not quality["tip_length_weighed"]
    quality, warnings = warnings_for(with_known_length(53.1e-3, 0.12e-3, geometry.length, 0.1e-3))
    assert quality["tip_length_weighed"] and quality["tip_s_mm"] == pytest.approx(53.041, abs=1e-3)
    assert not {w.code for w in warnings} & {"TIP_OFF_LENGTH", "TIP_ON_ERODED_RIM", "TIP_ON_END_CAP"}
    # the tip the robot's length beyond the cap's points: said so (0.1 mm along, with the centreline's 0.1 mm
    # at the free end across, is over the tip's floor)
    _, warnings = warnings_for(with_known_length(52.7e-3, 0.2e-3, geometry.length, 0.1e-3, lower_bound=True),
                               tip_from_cap=True, cross_view_spread=0.1e-3)
    print("\n".join(map(str, warnings)))
    cap = [w.figures for w in warnings if w.code == "TIP_ON_END_CAP"]
    assert [round(f["short_of_length_mm"], 2) for f in cap] == [0.30]  # the cap's points stop that short
    assert round(cap[0]["smeared_mm"], 2) == 0.20 and round(cap[0]["along_mm"], 2) == 0.10  # the tip: that length


@pytest.mark.parametrize("bend_deg, notch_side_deg, noise_at_90mm", [(30.0, 0.0, 2e-5), (40.0, 90.0, 2e-5),
                                                                    (30.0, 0.0, 1.7e-4)])
def test_tip_on_the_test_renderer_with_a_backdrop(bend_deg, notch_side_deg, noise_at_90mm):
    """The tests' renderer with a wall 300 mm from each camera: its 3 px blur mixes the wall's depth into the
    robot's edge pixels (and back), a band of one pixel each side the reconstruction must measure and give
    back. (Turned towards a camera by the bend at notch side 90 deg, the end's own outline matters; the noise
    twice a D405's must not hide the band.)"""
    config, shape, _ = posed_scene({}, bend_deg, notch_side_deg, seed=2)
    pair = render_pair(shape, config, seed=2, backdrop=0.3, noise_at_90mm=noise_at_90mm)
    reconstructor = Reconstructor(config)
    relocation = reconstructor.process(pair).relocation
    true_tip, tip_frame = shape.tip_pose()
    along = float((relocation.tip - true_tip) @ tip_frame[:, 2])
    error = float(np.linalg.norm(relocation.tip - true_tip))
    fx = pair.frames["cam_a"].intrinsics.fx
    bands = {name: round(band * fx, 2) for name, band in reconstructor.relocator.edge_bands.angles.items()}  # px
    print(f"\nbend {bend_deg:.0f} deg, notches at {notch_side_deg:.0f} deg, noise {noise_at_90mm * 1e3:.2f} mm, "
          f"backdrop: bands {bands} px, tip error "
          f"{error * 1e3:.3f} mm ({along * 1e3:+.3f} along the tube)")
    assert all(band == pytest.approx(1.0, abs=0.5) for band in bands.values())
    assert "edge band" in relocation.quality["tip_refinement"]
    assert set(relocation.quality["edge_band_mrad"]) == {"cam_a", "cam_b"}
    assert abs(along) <= 0.1e-3
    assert error <= 0.15e-3


def test_without_a_far_background_the_tip_falls_back_to_the_silhouettes_and_says_so():
    """The test renderer without a backdrop: nothing but the robot has depth, no edge band can be read."""
    config, shape, pair = posed_scene({}, 30.0, 0.0, seed=2)
    relocation = Reconstructor(config).process(pair).relocation
    error = float(np.linalg.norm(relocation.tip - shape.tip_pose()[0]))
    print(f"\nno backdrop: tip by {relocation.quality['tip_refinement']!r}, error {error * 1e3:.3f} mm")
    assert "silhouette" in relocation.quality["tip_refinement"]
    assert relocation.quality["edge_band_mrad"] == {}
    assert error <= 0.30e-3


def test_a_camera_without_a_far_background_is_tried_a_few_frames_then_left_alone(monkeypatch):
    """Measuring a band costs most of a frame: a scene that shows none is not measured on every frame."""
    import ntcr_recon.core.reconstruction.edge_bands as edge_bands

    config, _, pair = posed_scene({}, 30.0, 0.0, seed=2)
    measured = []
    monkeypatch.setattr(edge_bands, "edge_band_angle", lambda *image: measured.append(image) and None)
    reconstructor = Reconstructor(config)
    for _ in range(edge_bands.EDGE_BAND_ATTEMPTS + 3):
        reconstructor.process(pair)
    print(f"\n{len(measured)} images measured in {edge_bands.EDGE_BAND_ATTEMPTS + 3} frames of two cameras")
    assert len(measured) == edge_bands.EDGE_BAND_ATTEMPTS * len(config.camera_names)


def test_an_edge_band_measured_elsewhere_places_the_tip_and_a_wrong_one_is_refused():
    """The graph's relocation node sees clouds only: camera_node's band, handed over, places the tip as the
    depth images would."""
    config, shape, _ = posed_scene({}, 30.0, 0.0, seed=2)
    pair = render_pair(shape, config, seed=2, backdrop=0.3)
    offline = Reconstructor(config).process(pair)
    relocation = offline.relocation
    bands = {name: mrad * 1e-3 for name, mrad in relocation.quality["edge_band_mrad"].items()}
    assert set(bands) == set(config.camera_names)
    assert "silhouette" in Reconstructor(config).relocate(offline.filtered).quality["tip_refinement"]
    clouds_only = Relocator(config)  # relocates the filtered cloud, never sees a depth image (relocation_node)
    for name, band in bands.items():
        clouds_only.note_edge_band(name, band)
    handed_over = clouds_only.relocate(offline.filtered)
    print(f"\nbands {bands} rad; tip {np.linalg.norm(handed_over.tip - relocation.tip) * 1e6:.2f} um apart")
    assert handed_over.quality["tip_refinement"] == relocation.quality["tip_refinement"]
    assert np.linalg.norm(handed_over.tip - relocation.tip) < 1e-9
    with pytest.raises(ValueError, match="cam_z"):
        clouds_only.note_edge_band("cam_z", 0.004)
    with pytest.raises(ValueError, match="not in"):
        clouds_only.note_edge_band(config.camera_names[0], float("nan"))


@pytest.mark.parametrize("erosion, uncertainty, warned", [
    (0.45e-3, None, 0.55),     # uncertain by about 0.55 mm: the silhouette give-back, the erosion itself doubtful
    (0.45e-3, 0.22e-3, 0.22),  # uncertain by about 0.22 mm: measured in the depth images, to a pixel
    (0.0, 0.10e-3, None),                               # nothing given back, the end placed to half a pixel
])
def test_tip_warning_states_how_well_the_erosion_is_known(erosion, uncertainty, warned):
    from ntcr_recon.core.robot.geometry import TubeGeometry
    geometry = TubeGeometry()
    s = np.linspace(0.0, geometry.length, 2000)
    _, warnings = assess(Trace(
        geometry=geometry, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s,
        camera=(np.arange(len(s)) % 2).astype(np.int8), tip_s=geometry.length, total_bend=0.0, footprint=0.2e-3,
        wall_residual=0.05e-3, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
        depth_steps={}, tip_erosion=erosion, tip_uncertainty=uncertainty, outline_offset=0.02e-3))  # (checked)
    tip = [w for w in warnings if w.code == "TIP_ON_ERODED_RIM"]
    print(f"\ngiven back {erosion * 1e3:.2f} mm, uncertainty {uncertainty}: {tip}")
    if warned is None:
        assert not tip
    else:
        assert len(tip) == 1 and tip[0].figures["along_mm"] == pytest.approx(warned, abs=0.005)
        assert tip[0].figures["erosion_mm"] == pytest.approx(erosion * 1e3)
        assert tip[0].figures["edge_band_measured"] == (uncertainty is not None)  # measured in the depth images
