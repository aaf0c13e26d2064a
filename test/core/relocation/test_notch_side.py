"""The notch side measured on known inputs: a straight tube whose notches open at a known angle from the
configured side (the robot rolled in its clamp), its wall drawn analytically (no renderer), so the true roll is
exact; each figure asserted is printed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support import BAGS

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.notch_side import SideMeasurement, measure_notch_side
from ntcr_recon.core.relocation.notches import Notch
from ntcr_recon.core.robot.geometry import TubeGeometry

GEOMETRY = TubeGeometry()   # 3.5 mm, 16 notches, configured to open towards +x
FOOTPRINT = 0.2e-3          # a D405 pixel at 90 mm
SPACING = FOOTPRINT / 2


def rolled_robot_wall(roll: float, seen_half_width: float = math.radians(80.0)):
    """Outer-wall points of a straight robot whose notches open at `roll` from +x, as two cameras on +-y see it
    (each the part of the ring within `seen_half_width` of its direction), and its notches."""
    length = GEOMETRY.length
    s = np.arange(0.0, length, SPACING)
    phi = np.radians(np.arange(-180.0, 180.0, 1.0))
    ss, pp = (a.ravel() for a in np.meshgrid(s, phi, indexing="ij"))
    seen = np.zeros(ss.shape, dtype=bool)
    for camera_direction in (math.pi / 2, -math.pi / 2):
        seen |= np.abs(np.angle(np.exp(1j * (pp - camera_direction)))) < seen_half_width
    notches = []
    cut = np.zeros(ss.shape, dtype=bool)
    for index, centre in enumerate(GEOMETRY.notch_centers_s):
        start, end = centre - GEOMETRY.notch_width / 2, centre + GEOMETRY.notch_width / 2
        notches.append(Notch(index, centre, start, end, GEOMETRY.notch_width, 0.0))
        opening = np.abs(np.angle(np.exp(1j * (pp - roll)))) < GEOMETRY.gap_half_angle
        cut |= (ss > start) & (ss < end) & opening
    keep = seen & ~cut
    points = np.stack([GEOMETRY.outer_radius * np.cos(pp[keep]), GEOMETRY.outer_radius * np.sin(pp[keep]),
                       ss[keep]], axis=1)
    axis = np.arange(0.0, length + 2e-3, 0.1e-3)
    centerline = Centerline.from_points(np.stack([np.zeros_like(axis), np.zeros_like(axis), axis], axis=1),
                                        np.array([0.0, 1.0, 0.0]), 0.1e-3)
    return centerline, centerline.project(points), notches


# rolls that fall between the measurement's 10-degree sectors as well as on them
@pytest.mark.parametrize("roll_deg", [-20.0, -7.3, 0.0, 4.0, 13.7])
def test_notch_side_of_a_rolled_robot_is_measured_within_a_degree(roll_deg):
    centerline, coords, notches = rolled_robot_wall(math.radians(roll_deg))
    measured = measure_notch_side(coords, notches, GEOMETRY, centerline, 0.8e-3, FOOTPRINT)
    assert measured is not None
    print(f"\nnotches open {roll_deg:+.1f} deg from the configured side: measured {math.degrees(measured.roll):+.2f} "
          f"+- {math.degrees(measured.uncertainty):.2f} deg")
    assert abs(math.degrees(measured.roll) - roll_deg) <= 1.0
    # both window edges placed it, each between two sectors' centres: known to half a 10-deg sector, not to the
    # degree this exact wall gives (on rendered scenes both edges agreed within 1-2 deg and the side was 3-4 off)
    assert measured.by_edges and math.degrees(measured.uncertainty) == pytest.approx(5.0)


def test_notch_side_is_not_claimed_when_no_notch_edge_is_seen():
    """Cameras that see only the middle of the open window cannot place its edges: no side is claimed."""
    centerline, coords, notches = rolled_robot_wall(0.0, seen_half_width=math.radians(20.0))
    measured = measure_notch_side(coords, notches, GEOMETRY, centerline, 0.8e-3, FOOTPRINT)
    print(f"\nonly +-20 deg about each camera seen: {measured}")
    assert measured is None


def test_notch_side_is_not_claimed_when_the_wall_inside_the_notches_lies_only_where_the_spines_are_unseen():
    """The spines seen all round but for 20 deg of the backbone, the wall inside the notches only there (met on sweep
    scene 5003 under a trial levelling of its axis): nothing to measure the notches' wall against, and no side
    claimed (it divided by nought, and the frame's relocation failed)."""
    centerline, coords, notches = rolled_robot_wall(0.0, seen_half_width=math.radians(100.0))  # all round
    in_notches = np.zeros(len(coords.s), dtype=bool)
    for notch in notches:
        in_notches |= (coords.s > notch.start_s) & (coords.s < notch.end_s)
    back = np.abs(np.angle(np.exp(1j * (coords.angle - np.pi)))) < math.radians(10.0)
    keep = (~in_notches & ~back) | (in_notches & back)
    kept = type(coords)(coords.s[keep], coords.x[keep], coords.y[keep])
    assert np.count_nonzero(in_notches & back) > 10
    assert measure_notch_side(kept, notches, GEOMETRY, centerline, 0.8e-3, FOOTPRINT) is None


@pytest.mark.parametrize("rolls_deg, kept", [((20.0, 1.0), False), ((29.0, 9.0), True)])
def test_a_side_that_does_not_settle_in_the_turned_frame_keeps_the_configured_one(monkeypatch, rolls_deg, kept):
    """Turned to a measured side, the notches should open there: the measurement in the turned frame then
    stays within ROLL_TO_REFRAME and the side reported is the sum. One that moves on again is no measurement:
    the configured side is kept, and the result says why. (The measurement is replaced by the given rolls, so
    only the pipeline's handling of it is under test; on the sample bag bend45, whose notches open at 0 deg, with
    no bend plane held, whose roll would rule those out: the next test.)"""

    from support import tiny_rig

    import ntcr_recon.core.reconstruction.relocation_steps as steps
    from ntcr_recon.core.config.rig import load_rig_config
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    bag = BAGS / "bend45"
    config = load_rig_config(bag / "rig.yaml")
    config = dataclasses.replace(config, robot=dataclasses.replace(config.robot, roll_tolerance=None))
    pair = tiny_rig.bag_frame_pairs(bag, config)[0]
    rolls = iter(math.radians(r) for r in rolls_deg)
    measurements = (SideMeasurement(roll, math.radians(2.0)) for roll in rolls)
    monkeypatch.setattr(steps, "measure_notch_side", lambda *args, **kwargs: next(measurements, None))
    relocation = Reconstructor(config).process(pair).relocation
    side = relocation.quality["notch_side_deg"]
    print(f"\nrolls measured {rolls_deg} deg: side reported {side:.1f} deg; warnings {list(relocation.warnings)}")
    said = {}
    for warning in relocation.warnings:
        said.setdefault(warning.code, []).append(warning.figures)
    if kept:
        assert side == pytest.approx(0.0, abs=1e-9)
        assert relocation.quality["notch_side_unsettled_deg"] == pytest.approx(list(rolls_deg))
        # measured +29 deg from the configured side, then +9 deg more
        assert [[round(a) for a in f["side_off_deg"]] for f in said["NOTCH_SIDE_UNSETTLED"]] == [[29, 9]]
        assert "ROBOT_ROLLED" not in said
    else:
        assert side == pytest.approx(sum(rolls_deg))
        assert relocation.quality["notch_side_unsettled_deg"] is None
        assert [round(f["side_off_deg"]) for f in said["ROBOT_ROLLED"]] == [21]


@pytest.mark.parametrize("roll_deg, sd_deg", [(60.0, 2.0), (6.0, 10.0)])
def test_the_plane_the_robot_bends_in_weighs_the_side_or_rules_it_out(monkeypatch, roll_deg, sd_deg):
    """The robot bends in the plane its notches open to: the roll that plane shows (to a tenth of a degree on
    bend45, bent 45 deg) is a measurement of the side too. The notches' edges measured 60 deg off (known to a few
    degrees, their reach added): ruled out, the configured side kept, and the result says so (info); 6 +- 10 deg:
    weighed with the plane's, no roll."""
    from support import tiny_rig

    import ntcr_recon.core.reconstruction.relocation_steps as steps
    from ntcr_recon.core.config.rig import load_rig_config
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    bag = BAGS / "bend45"
    config = load_rig_config(bag / "rig.yaml")
    pair = tiny_rig.bag_frame_pairs(bag, config)[0]
    measurements = iter([SideMeasurement(math.radians(roll_deg), math.radians(sd_deg))])
    monkeypatch.setattr(steps, "measure_notch_side", lambda *args, **kwargs: next(measurements, None))
    relocation = Reconstructor(config).process(pair).relocation
    said = {warning.code: warning for warning in relocation.warnings}
    plane = relocation.quality["bend_plane"]
    assert "ROBOT_ROLLED" not in said and "NOTCH_SIDE_OFF" not in said
    if sd_deg < 5.0:
        ruled_out = said["NOTCH_SIDE_RULED_OUT"]
        assert ruled_out.severity == "info"
        assert ruled_out.figures["side_off_deg"] == pytest.approx(roll_deg)
        assert abs(ruled_out.figures["plane_roll_deg"]) < 3 * ruled_out.figures["plane_roll_sd_deg"] < 2.0
        assert relocation.quality["notch_side_deg"] == pytest.approx(0.0, abs=1e-9)
        assert relocation.quality["notch_side_uncertainty_deg"] is None
    else:
        assert "NOTCH_SIDE_RULED_OUT" not in said
        assert abs(relocation.quality["notch_side_deg"]) < 1.0  # the plane's, not 6 deg
        assert relocation.quality["notch_side_uncertainty_deg"] < 1.0
    assert plane["roll_measured"] is False


def test_a_turned_frame_is_judged_by_what_depth_finds_in_it_not_by_the_outlines(monkeypatch):
    """A side measured 150 deg off (replaced, as above) turns the frame. There depth finds half the notches and the
    outlines (relocation.outline_notches, frame-blind) the rest, as many as depth found in the configured frame:
    judged by depth's, the turned frame explains the data worse, the measurement is not trusted and the configured
    side kept."""

    from support import tiny_rig

    import ntcr_recon.core.reconstruction.relocation_steps as steps
    from ntcr_recon.core.config.rig import load_rig_config
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    bag = BAGS / "bend45"
    config = load_rig_config(bag / "rig.yaml")
    config = dataclasses.replace(config, robot=dataclasses.replace(config.robot, roll_tolerance=None))  # no plane
    pair = tiny_rig.bag_frame_pairs(bag, config)[0]
    measurements = iter([SideMeasurement(math.radians(150.0), math.radians(2.0))])
    monkeypatch.setattr(steps, "measure_notch_side", lambda *args, **kwargs: next(measurements, None))
    found_in_frame, real = [], steps.find_notches

    def half_by_depth_when_turned(*args, **kwargs):
        notches = real(*args, **kwargs)
        if found_in_frame:  # the turned frame: depth missed the upper half, the outlines show them
            notches = [dataclasses.replace(n, signal="outline") if n.index >= 8 else n for n in notches]
        found_in_frame.append([n.signal for n in notches])
        return notches

    monkeypatch.setattr(steps, "find_notches", half_by_depth_when_turned)
    relocation = Reconstructor(config).process(pair).relocation
    print(f"\nsignals per frame {found_in_frame}; side {relocation.quality['notch_side_deg']:.1f} deg")
    assert len(found_in_frame[0]) == len(found_in_frame[1]) == 16
    assert relocation.quality["notch_side_deg"] == pytest.approx(0.0, abs=1e-9)
    assert relocation.quality["notch_side_uncertainty_deg"] is None
