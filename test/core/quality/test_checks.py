"""quality.checks: what the result says is doubtful (assess on a Trace of the relocation's steps), each finding from
what the quality measures found. Points are drawn analytically on the true surface (no renderer), so every figure is
known exactly; each number asserted is printed."""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT, GEOMETRY, R_O, true_centerline

from ntcr_recon.core.quality.checks import assess
from ntcr_recon.core.quality.measures import (
    camera_coverage,
    camera_reach,
    centerline_uncertainty,
    notched_thinning,
    unmeasured_share,
    where_notches_went_unseen,
)
from ntcr_recon.core.quality.trace import Trace, derive, extrinsics_apart
from ntcr_recon.core.relocation.bend_plane import held_to_bend_plane
from ntcr_recon.core.relocation.bends import continued_bend
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.notches import Notch
from ntcr_recon.core.relocation.outline import OUTLINE_TOLERANCE_PX
from ntcr_recon.core.relocation.tip import TipAlongTube, carried_to_length
from ntcr_recon.core.robot.comb import expected_centres
from ntcr_recon.core.robot.kinematics import TubeShape

# the findings (core.quality.findings) that state how well the tip is placed, along the tube and across it
TIP_CODES = {"TIP_ON_ERODED_RIM", "TIP_ON_END_CAP"}


def _by_code(warnings) -> dict:
    """The findings by code (core.quality.findings), each code's in the order raised."""
    found: dict = {}
    for warning in warnings:
        found.setdefault(warning.code, []).append(warning)
    return found


def _tip_findings(warnings) -> list:
    return [w for w in warnings if w.code in TIP_CODES]


def _text(by_code: dict) -> str:
    return "\n".join(f"[{code}] {w}" for code, found in by_code.items() for w in found)


def test_quality_says_what_is_doubtful():
    notches = []
    s = np.linspace(0.0, 50e-3, 5000)
    camera = np.where(s < 40e-3, np.arange(len(s)) % 2, 1).astype(np.int8)  # cam_b alone past 40 mm
    share, alone = camera_coverage(s, camera, ("cam_a", "cam_b"), 50e-3, 0.25e-3, pool=3.5e-3)
    assert alone["cam_b"] == pytest.approx(10e-3, abs=0.5e-3) and alone["cam_a"] == 0.0
    assert share["cam_a"] == pytest.approx(0.8, abs=0.02)
    # a stray cam_a point every 0.7 mm past 40 mm (a twentieth of its density before) is no view of the tube
    stray = (s >= 40e-3) & (np.arange(len(s)) % 70 == 0)
    share_stray, alone_stray = camera_coverage(s, np.where(stray, 0, camera).astype(np.int8), ("cam_a", "cam_b"),
                                               50e-3, 0.25e-3, pool=3.5e-3)
    assert alone_stray["cam_b"] == pytest.approx(10e-3, abs=1e-3)
    assert share_stray["cam_a"] == pytest.approx(0.8, abs=0.04)
    quality, warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=notches, coords_s=s,
        camera=camera, tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.05e-3,
        notch_side=math.radians(20), configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
        depth_steps={"cam_a": 1e-3, "cam_b": 1e-4}))
    print("\n" + "\n".join(map(str, warnings)))
    said = _by_code(warnings)
    assert said["NOTCHES_MISSING"][0].figures["missing"] == list(range(16))
    assert [(w.figures["camera"], round(w.figures["length_mm"])) for w in said["DISTAL_ONE_CAMERA"]] == [("cam_b", 10)]
    (short,) = said["TUBE_ENDS_SHORT"]
    assert short.figures["short_of_length_mm"] > 0
    (rolled,) = said["ROBOT_ROLLED"]
    assert rolled.figures["side_off_deg"] == pytest.approx(20.0)
    assert [(w.figures["camera"], w.figures["depth_step_mm"]) for w in said["DEPTH_QUANTISED"]] == [
        ("cam_a", pytest.approx(1.0))]
    assert quality["notches_found"] == 0 and quality["notch_side_deg"] == pytest.approx(20.0)
    assert not short.figures["at_crop_box"]
    # no uncertainty stated for the side: the offset is a roll
    assert rolled.figures["side_uncertainty_deg"] is None
    # a side measured +20 deg off yet known only to +-25 deg (one edge of the window placed it) is no proof of a roll
    for known_deg, rolled_beyond in ((5.0, True), (25.0, False)):  # is rolled / may be rolled
        side_warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=notches, coords_s=s, camera=camera,
            tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.05e-3, notch_side=math.radians(20),
            configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
            side_uncertainty=math.radians(known_deg)))[1]
        (side,) = _by_code(side_warnings)["ROBOT_ROLLED" if rolled_beyond else "NOTCH_SIDE_OFF"]
        assert side.severity == "info"  # the measured side is used either way: the result stands
        assert side.figures["side_uncertainty_deg"] == pytest.approx(known_deg)
        assert (abs(side.figures["side_off_deg"]) > side.figures["side_uncertainty_deg"]) == rolled_beyond
    cap_warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a",), notches=[], coords_s=s,
        camera=np.zeros(len(s), np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        tip_uncertainty=0.26e-3, tip_from_cap=True))[1]
    (cap,) = _by_code(cap_warnings)["TIP_ON_END_CAP"]
    assert cap.figures["along_mm"] == pytest.approx(0.26)  # the cap's points smeared over that much
    assert "TIP_ON_ERODED_RIM" not in _by_code(cap_warnings)


def test_a_robot_bending_in_a_plane_turned_beyond_its_roll_tolerance_is_noted_and_its_plane_reported():
    s = np.linspace(0.0, 50e-3, 2000)
    truth = TubeShape.from_bend_angle(GEOMETRY, math.radians(45.0))
    points, frames = truth.centerline(s)
    axis = Centerline.from_frames(s, points, frames)
    turned = dataclasses.replace(GEOMETRY, notch_side=math.radians(-8.0))  # the rig file's side, 8 deg off

    def assessed(configured):
        plane = held_to_bend_plane(axis, configured, truth.length)
        return assess(Trace(geometry=configured, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s,
                            camera=(np.arange(len(s)) % 2).astype(np.int8), tip_s=truth.length, total_bend=0.0,
                            footprint=FOOTPRINT, wall_residual=0.0, notch_side=configured.notch_side,
                            configured_side=configured.notch_side, bias_notch_side=0.0, bias_binormal=0.0,
                            depth_steps={}, bend_plane=plane))

    quality, warnings = assessed(turned)
    (said,) = _by_code(warnings)["BEND_PLANE_TURNED"]
    assert said.severity == "info" and said.figures["roll_deg"] == pytest.approx(8.0, abs=0.1)
    assert quality["bend_plane"]["roll_measured"]
    quality, warnings = assessed(GEOMETRY)
    assert "BEND_PLANE_TURNED" not in _by_code(warnings)
    assert quality["bend_plane"]["roll_deg"] == 0.0 and quality["bend_plane"]["off_plane_mm"] < 0.001


def test_quality_tells_a_tube_cut_short_by_the_crop_box_from_one_that_ends_inside_it():
    box = (np.array([-0.05, -0.05, 0.0]), np.array([0.05, 0.05, 0.06]))
    s = np.linspace(0.0, 30e-3, 3000)

    def warnings_for(tip):
        return _by_code(assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a",), notches=[], coords_s=s,
            camera=np.zeros(len(s), np.int8), tip_s=30e-3, total_bend=0.0, footprint=FOOTPRINT,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, tip_position=np.array(tip), crop_box=box))[1])

    (on_face,) = warnings_for([0.02, 0.0, 0.5e-3])["TUBE_ENDS_SHORT"]    # the robot curled down to the base plane
    print("\n" + str(on_face))
    assert on_face.figures["short_of_length_mm"] > 0 and on_face.figures["at_crop_box"]
    assert on_face.figures["crop_box_face"] == "z" and on_face.figures["crop_box_face_mm"] == pytest.approx(0.0)
    (inside,) = warnings_for([0.0, 0.0, 0.03])["TUBE_ENDS_SHORT"]
    assert inside.figures["short_of_length_mm"] > 0 and not inside.figures["at_crop_box"]
    assert inside.figures["crop_box_face"] is None


def test_quality_says_when_no_camera_showed_the_tubes_outline_whole():
    """The outline check runs on points that carry their camera: where no window's outline spanned the tube's
    diameter (outline_offset None) the centreline went unchecked across the views, and the result says so, and
    states it, and the tip at its free end, as uncertain as the pixel footprint the check resolves at least (the
    cameras' spread said 0.02 mm); an outline measured, or clouds without cameras (no check to run), say nothing of
    it and state the spread."""
    s = np.linspace(0.0, 30e-3, 3000)

    def assessed(camera, outline_offset):
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s, camera=camera,
            tip_s=30e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
            bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, outline_offset=outline_offset,
            cross_view_spread=0.02e-3))
        return quality, _by_code(warnings)

    cameras = (np.arange(len(s)) % 2).astype(np.int8)
    quality, unchecked = assessed(cameras, None)
    print("\n" + " ".join(map(str, unchecked.get("OUTLINE_UNCHECKED", []))))
    (outline,) = unchecked["OUTLINE_UNCHECKED"]
    assert outline.figures["pixel_footprint_mm"] == pytest.approx(0.20)  # stated at least that uncertain
    # the tip across the tube is the centreline's free end
    assert [w.figures["across_because"] for w in unchecked["TIP_ON_ERODED_RIM"]] == ["free_end"]
    assert quality["centerline_uncertainty_mm"] == pytest.approx(FOOTPRINT * 1e3)
    assert quality["tip_across_uncertainty_mm"] >= FOOTPRINT * 1e3
    for camera, offset in ((cameras, 0.02e-3), (None, None)):
        quality, checked = assessed(camera, offset)
        assert "OUTLINE_UNCHECKED" not in checked and quality["centerline_uncertainty_mm"] == pytest.approx(0.02)


def test_a_camera_that_missed_a_stretch_is_named_with_why_too_near_or_end_on():
    """A robot bent 90 deg towards cam_a of a 90 mm rig (matrix row bend90_toward_cam_a_90mm): its distal part
    comes within 60 mm of cam_a, which sees nothing nearer than 70 mm (here, than 70.5). Seen by cam_b alone
    there, or cut short where cam_a's view ends, the warning says why; bent away from cam_a along its line of
    sight, it names that; bent side-on, it gives no reason. Bent 90 deg along the cameras' lines of sight, its
    distal part points within 30 deg of both: every camera sees that wall edge-on, and the result says so."""
    from ntcr_recon.sim.camera import facing_pair

    cameras = facing_pair(0.09)
    extrinsics = {pose.name: pose.extrinsic for pose in cameras}

    def warned(towards_deg, tip_s=None, unsupported=(), carry=False):
        """The warnings of a robot bent 90 deg towards the camera at towards_deg (-90: cam_a, 90: cam_b) seen
        up to tip_s, cam_a's points only where the tube is 70 mm from it or more and short of 40 mm along it."""
        shape = TubeShape.from_bend_angle(dataclasses.replace(GEOMETRY, notch_side=math.radians(towards_deg)),
                                          math.radians(90.0))
        tip_s = shape.length if tip_s is None else tip_s
        sample = shape.sample_surface_parts(0.2e-3)
        by_a = (cameras[0].to_camera(sample.points)[:, 2] >= 0.07) & (sample.s < 40e-3)
        xyz = np.concatenate([sample.points[by_a], sample.points])
        camera = np.concatenate([np.zeros(np.count_nonzero(by_a)), np.ones(len(sample.points))]).astype(int)
        centres = expected_centres(shape.geometry, true_centerline(shape))
        carried = continued_bend(true_centerline(shape).up_to(tip_s), shape.length, centres, GEOMETRY)
        reach = camera_reach(carried, tip_s, shape.length, R_O, FOOTPRINT, extrinsics, xyz, camera)
        s = np.concatenate([sample.s[by_a], sample.s])
        total_bend, tip_along = math.radians(90.0 * tip_s / shape.length), None
        if carry:  # to the robot's length, as the pipeline does where the rest is hidden
            tip_along = carried_to_length(TipAlongTube(tip_s, 0.1e-3, tip_s, 0.1e-3, shape.length, 0.1e-3),
                                          continued_bend(true_centerline(shape).up_to(tip_s), GEOMETRY.reach,
                                                         centres, GEOMETRY))
            tip_s, total_bend = tip_along.s, math.radians(90.0)
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s, camera=camera,
            tip_s=tip_s, total_bend=total_bend, footprint=FOOTPRINT, tip_along=tip_along,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, reach=reach, notch_centres=expected_centres(shape.geometry, true_centerline(shape)),
            unsupported=unsupported))
        return quality, _by_code(warnings)

    quality, seen_alone = warned(-90.0)
    print(f"\n{_text(seen_alone)}\nnearest returned {quality['camera_nearest_depth_mm']}, "
          f"tube's nearest {quality['tube_nearest_depth_mm']}")
    (alone,) = seen_alone["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b"
    assert alone.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)} and alone.figures["end_on_deg"] == {}
    assert quality["camera_nearest_depth_mm"]["cam_a"] == pytest.approx(70.5, abs=0.3)
    assert quality["tube_nearest_depth_mm"]["cam_a"] == pytest.approx(59.9, abs=0.3)
    # no notch was found (none given): those past 40 mm, where cam_a's points stop, are named with why
    (missing,) = seen_alone["NOTCHES_MISSING"]
    assert missing.figures["unseen_by"] == {"cam_a": [12, 13, 14, 15]}
    assert 60.0 <= quality["tube_nearest_depth_mm"]["cam_a"] + 0.5 < 70.0  # (it comes within 6x mm of cam_a)
    short_quality, cut_short = warned(-90.0, tip_s=38e-3)  # the tube's end found where cam_a stops seeing it
    print(_text(cut_short))
    (ends,) = cut_short["TUBE_ENDS_SHORT"]  # not carried on
    assert "TIP_CARRIED" not in cut_short
    assert ends.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)}  # continued at its last bend
    (missing,) = cut_short["NOTCHES_MISSING"]
    assert missing.figures["beyond_end"] == [12, 13, 14, 15] and short_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    shortfall = ends.figures["short_of_length_mm"]
    assert 10.0 <= shortfall < 20.0
    # left at the end seen, the tip may lie as far off as the rest of the robot reaches, and its figures say so (a
    # controller reads those, not the warning): the shortfall along the tube and across it
    assert short_quality["tip_uncertainty_mm"] == pytest.approx(shortfall, abs=0.05)
    assert short_quality["tip_across_uncertainty_mm"] == pytest.approx(shortfall, abs=0.05)
    # carried on to the robot's length past where cam_a was too near to see: the tip and the centreline's stated
    # uncertainty count what a straight hidden part would leave them off, and the warning says where the tip is
    carried_quality, carried = warned(-90.0, tip_s=38e-3, carry=True)
    print(_text(carried))
    (carried_on,) = carried["TIP_CARRIED"]
    assert 10.0 <= carried_on.figures["short_of_length_mm"] < 20.0
    assert carried_on.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)}
    assert carried["NOTCHES_MISSING"][0].figures["beyond_end"] == [12, 13, 14, 15]
    assert carried_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    assert "TIP_ON_ERODED_RIM" not in carried  # (the tip is not where the end was seen)
    assert carried_quality["tip_across_uncertainty_mm"] > 1.0 and carried_quality["tip_uncertainty_mm"] > 0.1
    assert carried_quality["centerline_uncertainty_mm"] > 0.3
    assert carried_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    assert carried_quality["tip_hidden_mm"] == pytest.approx(carried_quality["tip_s_mm"] - 38.0)
    assert carried_quality["tip_hidden_mm"] > 10.0
    assert quality["tip_hidden_mm"] == 0.0
    # bent towards cam_b, away from cam_a along its line of sight: cam_a sees the distal wall nearly edge-on
    _, away = warned(90.0)
    print(_text(away))
    (alone,) = away["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b" and alone.figures["too_near_mm"] == {}
    assert set(alone.figures["end_on_deg"]) == {"cam_a"}
    # bent side-on, whatever hid the distal part from cam_a, it was neither: no reason given
    side_on_quality, side_on = warned(0.0)
    print(_text(side_on))
    (alone,) = side_on["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b"
    assert alone.figures["too_near_mm"] == {} and alone.figures["end_on_deg"] == {}  # no reason given
    # along the lines of sight, the last ~20 deg of the bend lie within 30 deg of both (notch pitch 3.2 mm)
    assert 8.0 < quality["distal_end_on_mm"] < 16.0 and side_on_quality["distal_end_on_mm"] == 0.0
    (end_on,) = seen_alone["DISTAL_END_ON"]
    assert end_on.figures["length_mm"] == pytest.approx(quality["distal_end_on_mm"])
    assert set(end_on.figures["angles_deg"]) == {"cam_a", "cam_b"}
    assert "DISTAL_END_ON" not in side_on
    # where a stretch without trusted wall reaches the tip, its warning says as much: not said twice
    _, unsupported = warned(-90.0, unsupported=((42e-3, 50e-3),))
    (stretch,) = unsupported["CENTERLINE_UNSUPPORTED"]
    assert stretch.figures["to_tip"] and stretch.figures["stretches_mm"] == [[pytest.approx(42.0), pytest.approx(50.0)]]
    assert "DISTAL_END_ON" not in unsupported


def test_missing_notches_are_placed_beyond_the_end_seen_or_where_a_camera_did_not_see_the_tube():
    """Both cameras see the tube to 40 mm, cam_b alone beyond; the end is seen at 45 mm. Of the notches missing,
    one both cameras saw is named unmarked, with what a depth pixel is against its cut; those past 40 mm are where
    cam_a did not see the tube (the one whose cut straddles the end seen too); those whose cut lies past 45 mm are
    beyond the end seen."""
    s = np.linspace(0.0, 50e-3, 5000)
    camera = np.where(s < 40e-3, np.arange(len(s)) % 2, 1).astype(np.int8)
    centres = GEOMETRY.notch_centers_s  # 5.75, 8.75, ..., 41.75, 44.75, 47.75, 50.75 mm
    missing = [3, 12, 13, 14, 15]
    beyond, unseen = where_notches_went_unseen(missing, centres, GEOMETRY.notch_width / 2, s, camera,
                                               ("cam_a", "cam_b"), 45e-3, 0.25e-3, pool=3.5e-3)
    assert beyond == [14, 15] and unseen == {"cam_a": [12, 13]}
    width = GEOMETRY.notch_width
    found = [Notch(i, c, c - width / 2, c + width / 2, width, 0.0) for i, c in enumerate(centres) if i not in missing]
    quality, warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=found,
        coords_s=s, camera=camera, tip_s=45e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        notch_centres=centres))
    print("\n" + str(warnings[0]))
    assert warnings[0].code == "NOTCHES_MISSING" and warnings[0].severity == "warn"
    assert dict(warnings[0].figures) == {"missing": [3, 12, 13, 14, 15], "beyond_end": [14, 15],
                                         "unseen_by": {"cam_a": [12, 13]}, "unmarked": [3]}
    assert quality["notches_found"] == 11 and quality["tip_seen_s_mm"] == pytest.approx(45.0)
    assert quality["notches_missing_beyond_end"] == [14, 15] and quality["notches_missing_unmarked"] == [3]
    assert quality["notches_missing_unseen_by"] == {"cam_a": [12, 13]}


def test_quality_measures_a_wall_that_reads_deeper_between_the_notches_than_on_the_plain_tube():
    """Spines averaged with the slot floors behind them read deep; the plain tube beyond the notches does not.
    The figure does not depend on the pooled level's common part (where the axis was put), and above half a
    footprint it is a warning."""
    rng = np.random.default_rng(3)
    s = rng.uniform(0.0, 50e-3, 20000)
    cuts = np.array([(c - GEOMETRY.notch_width / 2, c + GEOMETRY.notch_width / 2) for c in GEOMETRY.notch_centers_s])
    between = (s > cuts[0, 0]) & (s < cuts[-1, 1])
    noise = rng.normal(0.0, 0.02e-3, len(s))

    def thinning(deep, common=0.0):
        offset = common - 0.1e-3 - np.where(between, deep, 0.0) + noise
        return notched_thinning(offset, s, cuts, 50e-3, gate=0.6e-3, margin=2 * FOOTPRINT)

    assert thinning(0.3e-3) == pytest.approx(0.3e-3, abs=0.02e-3)
    assert thinning(0.3e-3, common=0.1e-3) == pytest.approx(0.3e-3, abs=0.02e-3)
    assert abs(thinning(0.0)) < 0.02e-3
    assert notched_thinning(np.zeros(len(s)), s, cuts[:0], 50e-3, 0.6e-3, FOOTPRINT) is None

    def warnings_for(deep, looking=("cam_a",)):
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s,
            camera=np.zeros(len(s), np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, notched_thinning=thinning(deep), looking_into_slots=looking))
        return quality, _by_code(warnings)

    quality, text = warnings_for(0.3e-3)
    assert quality["notched_thinning_mm"] == pytest.approx(0.3, abs=0.02)
    assert quality["cameras_looking_into_slots"] == ["cam_a"]
    (slots,) = text["SLOTS_LEAN"]
    assert slots.figures["cameras"] == ["cam_a"] and not slots.figures["levelled"]
    assert f"{slots.figures['notched_thinning_mm']:.2f}" == "0.30"
    assert f"{slots.figures['lean_mm']:.2f}" == "0.60"  # may lean up to that, away from cam_a
    # shared by cameras that see the slots edge-on (through them), a thinner wall between the notches does not
    # move the axis; and a deficit a quarter of a footprint below the floor stays quiet
    assert "SLOTS_LEAN" not in warnings_for(0.3e-3, looking=())[1]
    assert "SLOTS_LEAN" not in warnings_for(0.2 * FOOTPRINT)[1]


def test_a_centreline_over_stretches_nothing_measured_is_stated_as_uncertain_as_a_pixel_footprint_there():
    """Where no camera saw the wall facing it, nothing measured how far off the axis is: over that share of the
    length it is known no better than a pixel footprint, weighed into the stated RMS (overlapping stretches once)."""
    assert unmeasured_share((), 0.0, 50e-3) == 0.0
    assert unmeasured_share(((40e-3, 50e-3), (45e-3, 52e-3)), 0.0, 50e-3) == pytest.approx(0.2)
    assert unmeasured_share(((30e-3, 35e-3),), 8e-3, 50e-3) == pytest.approx(0.26)  # and a distal end-on stretch

    def stated(unsupported):
        quality, warnings = assess(Trace(
            geometry=dataclasses.replace(GEOMETRY, proximal_length=GEOMETRY.proximal_length - 3e-3),
            camera_names=("cam_a", "cam_b"), notches=[], coords_s=np.linspace(0.0, 50e-3, 1000),
            camera=np.zeros(1000, np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
            notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
            cross_view_spread=0.03e-3, notched_thinning=0.04e-3, outline_offset=0.02e-3, unsupported=unsupported,
            notch_centres=GEOMETRY.notch_centers_s))
        return quality["centerline_uncertainty_mm"], _by_code(warnings)

    measured, quiet = stated(())
    assert measured == pytest.approx(0.05) and "CENTERLINE_UNSUPPORTED" not in quiet
    unmeasured, said = stated(((40e-3, 50e-3),))
    assert [w.figures["stretches_mm"] for w in said["CENTERLINE_UNSUPPORTED"]] == [[[pytest.approx(40.0),
                                                                                      pytest.approx(50.0)]]]
    assert unmeasured == pytest.approx(math.sqrt(0.05**2 + 0.2 * (FOOTPRINT * 1e3) ** 2))


def test_quality_gives_the_centreline_an_uncertainty_and_warns_above_its_floor():
    """The cameras' spread across their views and the lean along them (the wall's deficit between the notches,
    twice it for a camera looking into the slots) add in quadrature: 0.06 and 0.08 mm make 0.1 mm, over the
    0.08 mm floor, a warning; 0.03 and 0.04 mm make 0.05 mm, quiet."""
    assert centerline_uncertainty(0.06e-3, 0.08e-3) == pytest.approx(0.1e-3)
    assert centerline_uncertainty(None, 0.05e-3) == pytest.approx(0.05e-3)
    assert centerline_uncertainty(0.06e-3, 0.04e-3, ("cam_a",)) == pytest.approx(0.1e-3)
    assert centerline_uncertainty(None, None) is None
    # an axis the outline check found astray is known no better than its offset from the outlines' middles
    assert centerline_uncertainty(0.06e-3, 0.08e-3, astray=0.5e-3) == pytest.approx(0.5e-3)
    assert centerline_uncertainty(None, None, astray=0.5e-3) == pytest.approx(0.5e-3)
    # an alignment whose correction varies along the tube: that much again, in quadrature
    assert centerline_uncertainty(0.03e-3, 0.0, varying_lean=0.04e-3) == pytest.approx(0.05e-3)
    # across the views the limbs' disagreement where they placed the axis (Z90 times it), depth's spread over the
    # rest; along them Z90 times how much the walls apart vary, with the slots' lean only where a camera looks in
    z = 1.645
    assert centerline_uncertainty(0.08e-3, 0.03e-3, limbs=(0.01e-3, 1.0, None), level_scatter=0.02e-3) == pytest.approx(
        math.hypot(z * 0.01e-3, z * 0.02e-3))
    assert centerline_uncertainty(0.08e-3, 0.03e-3, ("cam_a",), limbs=(0.01e-3, 0.5, None),
                                  level_scatter=0.02e-3) == pytest.approx(
        math.sqrt(0.5 * (z * 0.01e-3) ** 2 + 0.5 * 0.08e-3**2 + (z * 0.02e-3) ** 2 + (2 * 0.03e-3) ** 2))
    # the windows they did not place took the move interpolated from the others: off by what that misses where
    # they can be checked (Z90 times it), not by depth's spread
    assert centerline_uncertainty(0.08e-3, 0.03e-3, ("cam_a",), limbs=(0.01e-3, 0.5, 0.02e-3),
                                  level_scatter=0.02e-3) == pytest.approx(
        math.sqrt(0.5 * (z * 0.01e-3) ** 2 + 0.5 * (z * 0.02e-3) ** 2 + (z * 0.02e-3) ** 2 + (2 * 0.03e-3) ** 2))
    # the axis held to the robot's bend plane: what lies along the views only as far as the hold left it (a tenth,
    # seen nearly square to the plane), the plane's own uncertainty added
    plane = types.SimpleNamespace(along_views_kept=0.1, plane_uncertainty=0.01e-3)
    assert centerline_uncertainty(0.08e-3, 0.03e-3, limbs=(0.01e-3, 1.0, None), level_scatter=0.2e-3,
                                  bend_plane=plane) == pytest.approx(
        math.sqrt((z * 0.01e-3) ** 2 + (0.1 * z * 0.2e-3) ** 2 + 0.01e-3**2))

    # a robot 50 mm long, seen to its tip (one ending short of its length states its tip as far off)
    seen_to_tip = dataclasses.replace(GEOMETRY, proximal_length=GEOMETRY.proximal_length - 3e-3)

    def assessed(spread, thinning, looking=(), at_end=None, held=None, cam_b_up_to=None, wall_level=None,
                 outline=0.02e-3, across_from_fit=None, fitted_end=None):  # (outline: checked, a sound axis's)
        s, seen_by = np.linspace(0.0, 50e-3, 1000), np.zeros(1000, np.int8)
        if cam_b_up_to is not None:  # cam_a sees the whole tube, cam_b up to there
            s = np.concatenate([s, np.linspace(0.0, cam_b_up_to, 750)])
            seen_by = np.concatenate([seen_by, np.ones(750, np.int8)])
        return assess(Trace(geometry=seen_to_tip, camera_names=("cam_a", "cam_b"), notches=[],
                      coords_s=s, camera=seen_by, tip_s=50e-3, wall_level=wall_level,
                      total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
                      bias_notch_side=0.1e-3, bias_binormal=0.0, depth_steps={}, notched_thinning=thinning,
                      looking_into_slots=looking, cross_view_spread=spread, distal_cross_view=at_end,
                      held_shift=held, outline_offset=outline, across_from_fit=across_from_fit,
                      fitted_end=fitted_end, notch_centres=GEOMETRY.notch_centers_s))

    quality, warnings = assessed(0.06e-3, 0.08e-3)
    print("\n" + "\n".join(map(str, warnings)))
    assert quality["centerline_uncertainty_mm"] == pytest.approx(0.1)
    assert quality["centerline_cross_view_mm"] == pytest.approx(0.06)
    (uncertain,) = _by_code(warnings)["CENTERLINE_UNCERTAIN"]
    assert uncertain.figures["uncertainty_mm"] == pytest.approx(0.1)
    assert uncertain.figures["cross_view_mm"] == pytest.approx(0.06)  # the cameras' axes that far apart
    quiet_quality, quiet = assessed(0.03e-3, 0.04e-3)
    assert quiet_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    assert "CENTERLINE_UNCERTAIN" not in _by_code(quiet)
    # the tip sits on the centreline's free end, sqrt(3) x its uncertainty across: with half a footprint along
    # the tube, 0.05 mm of centreline keep the tip within its floor, 0.1 mm do not
    assert not _by_code(quiet).keys() & TIP_CODES
    (tip,) = _tip_findings(warnings)
    assert tip.figures["across_mm"] == pytest.approx(math.sqrt(3) * 0.1)
    assert tip.figures["across_because"] == "free_end"  # the centreline's, at its free end
    assert quality["tip_across_uncertainty_mm"] == pytest.approx(math.sqrt(3) * 0.1)
    assert assessed(None, None)[0]["tip_across_uncertainty_mm"] is None  # nothing measured the centreline
    # where the cameras disagree more at the end than over the length, the tip is known no better than their axes
    # there lie apart, 2 x their RMS about the fused one: 0.05 mm over the length, 0.08 mm at the end make 0.16 mm
    ends_apart = assessed(0.03e-3, 0.04e-3, at_end=0.08e-3)
    assert ends_apart[0]["tip_across_uncertainty_mm"] == pytest.approx(0.16)
    assert ends_apart[0]["centerline_cross_view_at_tip_mm"] == pytest.approx(0.08)
    (tip,) = _tip_findings(ends_apart[1])
    assert tip.figures["across_mm"] == pytest.approx(0.16) and tip.figures["across_because"] == "cameras_apart"
    # the alignment's shift at the last wall it trusted, held unchecked to the tip, adds in quadrature to the free
    # end's: 0.05 x sqrt(3) and 0.12 mm make 0.15 mm
    held_quality, held = assessed(0.03e-3, 0.04e-3, held=(0.12e-3, 46e-3))
    assert held_quality["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.12))
    assert held_quality["tip_held_shift_mm"] == pytest.approx(0.12)
    assert held_quality["tip_held_over_mm"] == pytest.approx(4.0)
    (tip,) = _tip_findings(held)  # the shift held unchecked over the tip_held_over_mm to the tip
    assert tip.figures["across_mm"] == pytest.approx(held_quality["tip_across_uncertainty_mm"])
    assert tip.figures["across_because"] == "held_shift"
    # the fit ended short of the tip (50 mm) and the centreline was carried on bending over the notches past its end
    # (centres 44.75 and 47.75 mm, 1.5 mm wide): each one's bend known as well as the turn over a pitch (0.05 / 3 mm),
    # its lever the rest to the tip: ended at 47.5 mm, two thirds of notch 14 at 2.25 mm add 0.025 mm in quadrature;
    # ended at 44 mm, notch 13 too (5.25 mm) makes 0.125 mm, over the free end's and said
    assert assessed(0.03e-3, 0.04e-3, fitted_end=50e-3)[0]["tip_carried_mm"] == 0.0
    near, _ = assessed(0.03e-3, 0.04e-3, fitted_end=47.5e-3)
    assert near["tip_carried_mm"] == pytest.approx(2.5)
    assert near["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.05 / 3 * 1.5))
    short_quality, short = assessed(0.03e-3, 0.04e-3, fitted_end=44e-3)
    assert short_quality["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.125))
    assert short_quality["tip_carried_mm"] == pytest.approx(6.0)
    assert [w.figures["across_because"] for w in _tip_findings(short)] == ["carried"]
    # looking into the slots, the deficit may lean the axis by twice it: 0.03 and 2 x 0.04 mm make 0.085 mm
    looking_quality, looking = assessed(0.03e-3, 0.04e-3, looking=("cam_a",))
    assert looking_quality["centerline_uncertainty_mm"] == pytest.approx(math.hypot(0.03, 0.08))
    assert [round(w.figures["uncertainty_mm"], 2) for w in _by_code(looking)["CENTERLINE_UNCERTAIN"]] == [0.09]
    # over a distal stretch one camera alone saw, the axis along its view rests on the wall's level, which no
    # second view checks: a quarter of the length at -0.16 mm adds 0.08 mm in quadrature (as an RMS over the
    # length), and 0.05 mm become 0.094 mm, over the floor
    assert centerline_uncertainty(0.03e-3, 0.04e-3, one_sided=(0.25, -0.16e-3)) == pytest.approx(
        math.sqrt(0.03 ** 2 + 0.04 ** 2 + 0.25 * 0.16 ** 2) * 1e-3)
    one_quality, one = assessed(0.03e-3, 0.04e-3, cam_b_up_to=37.5e-3, wall_level=-0.16e-3)
    alone = one_quality["distal_one_camera_mm"]["cam_a"] / 50.0
    assert alone == pytest.approx(0.25, abs=0.02) and one_quality["wall_level_mm"] == pytest.approx(-0.16)
    assert one_quality["centerline_uncertainty_mm"] == pytest.approx(math.sqrt(0.05 ** 2 + alone * 0.16 ** 2))
    (uncertain,) = _by_code(one)["CENTERLINE_UNCERTAIN"]
    assert round(uncertain.figures["uncertainty_mm"], 2) == 0.09
    assert uncertain.figures["one_camera_wall_level_mm"] == pytest.approx(-0.16)  # seen by one camera alone
    # both cameras seeing the whole tube, the level adds nothing
    both_quality, _ = assessed(0.03e-3, 0.04e-3, cam_b_up_to=50e-3, wall_level=-0.16e-3)
    assert both_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    # the axis 1.25 footprints from the middle of the tube's outline is within what a sound one shows: reported, no
    # more; 2.5 footprints (0.5 mm) away it went astray with the wall it rests on, and is known no better than that
    sound_quality, sound = assessed(0.03e-3, 0.04e-3, outline=0.25e-3)
    assert sound_quality["centerline_outline_offset_mm"] == pytest.approx(0.25)
    assert sound_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    assert "CENTERLINE_UNCERTAIN" not in _by_code(sound)
    astray_quality, astray = assessed(0.03e-3, 0.04e-3, outline=0.5e-3)
    print("\n".join(str(w) for w in astray if w.code == "CENTERLINE_UNCERTAIN"))
    assert astray_quality["centerline_uncertainty_mm"] == pytest.approx(0.5)
    (uncertain,) = _by_code(astray)["CENTERLINE_UNCERTAIN"]
    assert uncertain.figures["uncertainty_mm"] == pytest.approx(0.5)
    assert uncertain.figures["outline_offset_mm"] == pytest.approx(0.5)  # from the outline's middle
    assert uncertain.figures["outline_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(2.5)  # px
    # the alignment astray (2.5 px) and the fit not (0.5 px): the fit placed the axis across the views, and the
    # result says so; the axis it gave (0.25 mm from the outline) is within what a sound one shows
    replaced_quality, replaced = assessed(0.03e-3, 0.04e-3, outline=0.25e-3, across_from_fit=(0.5e-3, 0.1e-3))
    assert replaced_quality["centerline_aligned_outline_offset_mm"] == pytest.approx(0.5)
    assert sound_quality["centerline_aligned_outline_offset_mm"] is None
    assert replaced_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    (moved,) = _by_code(replaced)["ALIGNMENT_ASTRAY"]
    assert moved.figures["aligned_offset_mm"] == pytest.approx(0.5)
    assert moved.figures["aligned_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(2.5)  # px, over OUTLINE_TOLERANCE_PX
    assert moved.figures["aligned_offset_mm"] / (FOOTPRINT * 1e3) > OUTLINE_TOLERANCE_PX
    assert moved.figures["fit_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(0.5)  # the fit's axis, in px
    assert "ALIGNMENT_ASTRAY" not in _by_code(sound)


def test_cameras_whose_poses_disagree_widen_the_stated_centreline_and_tip_by_half_their_offset():
    """cam_b's pose turned 0.3 deg in the rig file: the two cameras place the axis 0.266 mm apart across their
    views, alike all along the tube, and the fused axis lies half of that off (the matrix's straight row read a
    centreline error of 0.269 mm). Where EXTRINSICS_DISAGREE is raised, the stated centreline and tip bounds carry
    that half; where the offset is within the windows' noise, nothing changes."""
    s = np.linspace(0.0, 50e-3, 5000)
    camera = (np.arange(len(s)) % 2).astype(np.int8)

    def assessed(offsets):
        trace = Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s, camera=camera, tip_s=50e-3,
            total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.05e-3, notch_side=0.0, configured_side=0.0,
            bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, cross_view_spread=0.03e-3,
            cross_view_offsets=offsets, centerline_tolerance=0.08e-3)
        quality, warnings = assess(trace)
        return quality, _by_code(warnings), derive(trace).tip

    exact, _, exact_tip = assessed(((-0.007e-3, 0.005e-3), (-0.009e-3, 0.004e-3)))
    turned, said, turned_tip = assessed(((0.138e-3, 0.005e-3), (0.128e-3, 0.006e-3)))
    noisy, noisy_said, noisy_tip = assessed(((0.138e-3, 0.07e-3), (0.128e-3, 0.08e-3)))
    half = 0.133e-3
    print(f"\ncentreline {exact['centerline_uncertainty_mm']:.3f} -> {turned['centerline_uncertainty_mm']:.3f} mm, "
          f"tip across {exact_tip.across * 1e3:.3f} -> {turned_tip.across * 1e3:.3f} mm")
    assert "EXTRINSICS_DISAGREE" in said
    assert turned["centerline_uncertainty_mm"] == pytest.approx(math.hypot(exact["centerline_uncertainty_mm"],
                                                                           half * 1e3))
    assert turned_tip.across == pytest.approx(math.hypot(exact_tip.across, half))
    assert "EXTRINSICS_DISAGREE" not in noisy_said
    assert noisy["centerline_uncertainty_mm"] == pytest.approx(exact["centerline_uncertainty_mm"])
    assert noisy_tip.across == pytest.approx(exact_tip.across)


def _offsets_trace(**measured) -> Trace:
    """A straight tube's trace whose depth places both cameras' axes alike (0.01 mm apart across their views), with
    what the limbs and the outlines measured."""
    s = np.linspace(0.0, 50e-3, 5000)
    return Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s,
        camera=(np.arange(len(s)) % 2).astype(np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT,
        wall_residual=0.05e-3, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
        depth_steps={}, cross_view_spread=0.03e-3, cross_view_offsets=((0.005e-3, 0.005e-3), (0.006e-3, 0.004e-3)),
        centerline_tolerance=0.08e-3, **measured)


@pytest.mark.parametrize(("limbs_rigid", "warned"), [((0.104e-3, 0.004e-3), True),    # 0.1 deg, straight row
                                                     ((0.049e-3, 0.004e-3), False),   # 0.05 deg: within a tolerance
                                                     ((0.104e-3, 0.05e-3), False)])   # within the limbs' noise
def test_the_limbs_tell_a_pose_off_by_a_tenth_of_a_degree_that_depth_cannot(limbs_rigid, warned):
    """Depth reads exact rigs 0.10-0.12 mm apart beside slots at +-45 deg, so it warns only beyond two tolerances;
    the limbs read them 0.002-0.02 mm apart and a pose 0.1 deg off 0.08-0.13 mm (the emulated matrix), which moves
    the centreline about as far: theirs warns beyond one, and wins over depth's where both measured."""
    trace = _offsets_trace(limbs_rigid=limbs_rigid)
    quality, warnings = assess(trace)
    assert quality["cameras_across_view_offset_mm"] == pytest.approx(limbs_rigid[0] * 1e3)
    assert ("EXTRINSICS_DISAGREE" in _by_code(warnings)) == warned
    assert extrinsics_apart(trace) == (pytest.approx(limbs_rigid[0] / 2) if warned else 0.0)


@pytest.mark.parametrize(("outlines", "limbs", "warned", "expected_mm"), [
    ((1.58e-3, 0.04e-3), None, True, 1.58),                  # 1 deg about z at 90 mm: 1.6 mm, past the limbs
    ((0.09e-3, 0.04e-3), None, False, 0.011),                # within the wall's gate: depth decides
    ((1.58e-3, 0.7e-3), None, False, 0.011),                 # within the outlines' own noise
    ((0.85e-3, 0.09e-3), (0.01e-3, 0.004e-3), False, 0.01)])  # limbs found in both views: a fattened outline
def test_a_pose_a_millimetre_off_is_told_by_the_outlines_where_the_limbs_no_longer_reach(outlines, limbs, warned,
                                                                                        expected_mm):
    """A camera whose pose is a millimetre off has its whole tube beyond the limbs' search and the trusted wall's
    gate: the limbs place nothing in its view, depth reads nothing amiss (here 0.011 mm), the outlines read the
    offset, and the fused axis may lie up to all of it off (the fit follows either camera). Where the limbs were
    found in both views, theirs decides: a matcher fattens both opposed outlines on the same side, which the
    outlines read as an offset (0.85 mm with the real matcher, an exact rig)."""
    trace = _offsets_trace(outline_rigid=outlines, limbs_rigid=limbs)
    quality, warnings = assess(trace)
    said = _by_code(warnings)
    assert ("EXTRINSICS_DISAGREE" in said) == warned
    assert quality["cameras_across_view_offset_mm"] == pytest.approx(expected_mm)
    if warned:
        assert said["EXTRINSICS_DISAGREE"][0].figures["by_outlines"] is True
        assert extrinsics_apart(trace) == pytest.approx(1.58e-3)
        assert quality["uncertainty_mm"]["centerline"] > 1.58


def test_the_axis_off_the_base_at_the_clamp_widens_the_centreline_and_tip_bounds_and_is_said():
    """A camera's pose off along its own view moves the fused axis along the views, where the cameras cannot
    disagree (no EXTRINSICS_DISAGREE): the proximal axis off the base's measures it, and the centreline and the tip
    are known no better, all along the tube. Where the cameras' disagreement says more, it decides (not both: one
    rigid error measured twice)."""
    exact, _ = assess(_offsets_trace())
    moved, warnings = assess(_offsets_trace(base_offset=0.1e-3))
    said = _by_code(warnings)
    assert "EXTRINSICS_DISAGREE" not in said
    assert moved["centerline_base_offset_mm"] == pytest.approx(0.1)
    assert moved["centerline_uncertainty_mm"] == pytest.approx(math.hypot(exact["centerline_uncertainty_mm"], 0.1))
    exact_across, moved_across = (derive(_offsets_trace(base_offset=off)).tip.across for off in (None, 0.1e-3))
    assert moved_across == pytest.approx(math.hypot(exact_across, 0.1e-3))
    assert said["CENTERLINE_UNCERTAIN"][0].figures["base_offset_mm"] == pytest.approx(0.1)
    turned, _ = assess(_offsets_trace(limbs_rigid=(0.2e-3, 0.004e-3), base_offset=0.05e-3))
    assert turned["centerline_uncertainty_mm"] == pytest.approx(math.hypot(exact["centerline_uncertainty_mm"], 0.1))


def test_notches_only_a_dip_or_the_outline_marks_are_named_with_their_widths_from_their_bends():
    """NOTCH_WIDTH_FROM_BEND lists the dips and the notches only a colour image's outline showed (their signal
    "outline"), the latter also on their own; a notch measured by its edges is in neither."""
    s = np.linspace(0.0, 50e-3, 2000)
    notches = [Notch(i, c, c - 0.75e-3, c + 0.75e-3, 1.5e-3, 0.0, signal)
               for i, (c, signal) in enumerate(zip(GEOMETRY.notch_centers_s[:4], ("coverage", "dip", "outline",
                                                                                   "outline"), strict=True))]
    _, warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=notches, coords_s=s, camera=None, tip_s=50e-3,
        total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
        bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}))
    (from_bend,) = _by_code(warnings)["NOTCH_WIDTH_FROM_BEND"]
    assert from_bend.severity == "info"
    assert (from_bend.figures["notches"], from_bend.figures["outline"]) == ([1, 2, 3], [2, 3])
