"""Issue 9's floors on a few rows of the accuracy matrix (benchmarks/accuracy_matrix.py: the whole grid is a
benchmark, too long for CI). Rendered by the simulator as `ntcr-recon simulate` renders them, 2 frames each."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from support import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import accuracy_matrix  # noqa: E402

from ntcr_recon.core.quality.findings import finding  # noqa: E402

ROWS = {row.name: row for row in accuracy_matrix.ROWS}


def _listed(warnings) -> str:
    """A result's warnings (core.quality.findings.Finding), one a line, as --warnings prints them."""
    return "\n".join(f"[{w.code}] {w}" for w in warnings)


def _found(figures: dict, code: str) -> list:
    """The figures of each of a result's warnings of `code`."""
    return [w.figures for w in figures["warnings"] if w.code == code]


# rows that meet every floor on seed 1 and on five noise seeds too (`accuracy_matrix.py --seeds 5`; bend_kink's
# kinked notch, taken for misread on seed 5 while each of its neighbours' chords had to hold 0.35 of its excess,
# keeps its width on all five since their mean has to). Not bend_largest: its tip misses its floor on four seeds of
# five, 0.19-0.24 mm off, as its warning of the alignment's shift held to the tip says.
@pytest.mark.parametrize("name", ["side45_bend30", "cameras75", "bend90", "bends_falling", "bend_kink"])
def test_rows_meet_the_floors(name):
    figures = accuracy_matrix.run_row(ROWS[name], frames=2)
    print("\n" + accuracy_matrix.HEADER + "\n" + accuracy_matrix.format_row(figures))
    assert figures["floors_apply"]
    assert figures["misses"] == []
    # the centreline's error split along and across the cameras' views adds up to it (what is left lies along the
    # tube: up to a tenth where the axis was held to the bend plane, which shortens a wavy curve)
    split = np.hypot(figures["centerline_along_views"], figures["centerline_across_views"])
    assert split == pytest.approx(figures["centerline"], rel=0.1)


def test_extra_simulate_options_render_a_row_under_another_matcher():
    """--simulate='--no-left-right-check' keeps the row's own options and takes the matcher's left-right check
    away: the occlusion shadows beside the robot, invalid on a D405, then read a depth."""
    own = ROWS["straight"]
    row = accuracy_matrix.with_simulate_options(own, "--no-left-right-check")
    assert row.name == own.name and row.args == (*own.args, "--no-left-right-check")
    checked, unchecked = (accuracy_matrix.simulation_for(r, seed=1, frames=1) for r in (own, row))
    assert checked.emulation.occlusion_check and not unchecked.emulation.occlusion_check
    valid = [np.count_nonzero(next(iter(simulation.frames())).depth_raw) for simulation in (checked, unchecked)]
    assert valid[1] > valid[0], valid


def test_a_row_renders_without_flying_pixels():
    """--simulate='--no-flying-pixels' keeps the matcher's other artefacts but mixes no pixel at a depth edge with
    the surface behind: far fewer of the robot's pixels read a millimetre or more off its surface."""
    from ntcr_recon.sim.scene import LABEL_ROBOT

    own = ROWS["straight"]
    flying = []
    for row in (own, accuracy_matrix.with_simulate_options(own, "--no-flying-pixels")):
        simulation = accuracy_matrix.simulation_for(row, seed=1, frames=1)
        frame = next(iter(simulation.frames()))
        exact = simulation.exact[frame.camera.name]
        depth = frame.depth_raw * simulation.intrinsics.depth_unit
        off_surface = (depth > 0) & (np.abs(depth - exact.depth) > 1e-3)
        flying.append(np.count_nonzero(off_surface & (exact.label == LABEL_ROBOT)))
    assert flying[1] < 0.3 * flying[0], flying


def test_depth_in_1mm_steps_is_warned_and_the_centreline_stays_within_what_the_result_states():
    """1 mm depth steps (realsense-ros recordings) flatten the tube's depth profile: the result warns about them.
    (Held to the robot's bend plane, the centreline now meets its floor here: 0.03 mm, 0.10 before.)"""
    figures = accuracy_matrix.run_row(ROWS["depth_unit_1mm"], frames=2)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    assert any(f["depth_step_mm"] == pytest.approx(1.0, abs=0.05) for f in _found(figures, "DEPTH_QUANTISED"))
    # the alignment followed the quantised wall across the views (0.41 mm off); the fit, which the outline bears
    # out, places the axis across them instead (0.20 mm off), and the error stays within what the result states
    moved = _found(figures, "ALIGNMENT_ASTRAY")
    assert moved, "the alignment was expected to go astray from the outline here"
    astray = moved[0]["aligned_offset_mm"] * 1e-3
    assert figures["centerline"] < 0.6 * astray
    assert figures["centerline"] <= figures["stated"]["centerline"]


def test_an_icp_relocation_says_how_far_it_moved_the_reference_off_the_centreline():
    """relocation.method icp on side90_bend30: ICP slides the posed reference 0.14 mm along the tube, and the tip with
    it, past its floor. The result says how far ICP moved the reference and the tip off where the centreline placed
    them, states the tip that uncertain, and so no floor it misses goes unsaid."""
    figures = accuracy_matrix.run_row(ROWS["side90_bend30"], frames=2, method="icp")
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    assert "tip" in figures["misses"], "ICP was expected to miss the tip's floor here; if it no longer does, say so"
    assert _found(figures, "ICP_MOVED_REFERENCE")
    assert accuracy_matrix.unwarned(figures) == []
    assert abs(figures["tip_along"]) <= figures["stated"]["tip_along"]


def test_a_tip_the_cameras_could_not_see_is_carried_on_to_the_robots_length():
    """Bent 90 deg towards cam_a of a 90 mm rig, the distal part comes nearer cam_a than the D405's 70 mm and points
    away from cam_b along its line of sight: the tube seen ends 11 mm short of the robot (its tip was placed there,
    12.0 mm off). Carried on to the robot's length as the notches seen bent, the tip lands within 0.6 mm (0.40-0.58
    over five noise seeds: 11 mm carried at the direction the end seen has), within what the result states along
    the tube and across it, and the warning says it was carried; the hidden notches are reported missing, not
    guessed."""
    figures = accuracy_matrix.run_row(ROWS["bend90_toward_cam_a_90mm"], frames=2)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + accuracy_matrix.format_stated(figures) + "\n"
          + _listed(figures["warnings"]))
    assert _found(figures, "TIP_CARRIED")  # the rest hidden, the tip carried on there
    assert figures["tip"] < 0.6e-3
    assert accuracy_matrix.within_stated(figures, "tip_along") and accuracy_matrix.within_stated(figures, "tip_across")
    assert figures["centerline"] <= figures["stated"]["centerline"]
    assert figures["found"] < figures["expected"] and "notches" in figures["misses"]


def test_an_alignment_that_moved_the_curled_end_more_than_the_rest_says_the_centreline_is_uncertain():
    """bend_largest on noise seed 4: over the last 8 mm, where the tube curls back, both cameras' facing wall reads
    0.1 mm off the axis the same way, and the alignment moved the axis 0.1-0.18 mm there against 0.02 elsewhere.
    The cameras agree, so their spread did not show it: the result stated 0.060 mm, was 0.081 off and said
    nothing of the centreline (a silent miss). The correction's scatter along the tube is stated too."""
    figures = accuracy_matrix.run_row(ROWS["bend_largest"], frames=2, seed=4)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + accuracy_matrix.format_stated(figures))
    assert accuracy_matrix.unwarned(figures) == []
    assert accuracy_matrix.within_stated(figures, "centerline")
    assert any(f["alignment_scatter_mm"] > 0 for f in _found(figures, "CENTERLINE_UNCERTAIN"))


def test_a_camera_looking_into_the_notches_from_afar_is_overruled_by_the_one_facing_the_backbone():
    """From 110 mm the spines facing cam_a are narrower than its matcher's window, which averages them with the
    slot floors: cam_a reads the wall between the notches deep, and says so; cam_b, facing the backbone, places
    the axis along its line of sight by its own level on the plain tube, and the centreline meets its floor
    (0.26 mm off when the two cameras' levels were split between them)."""
    figures = accuracy_matrix.run_row(ROWS["side-90_bend30_cameras110"], frames=2)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    # cam_a looks into the slots; a camera facing the backbone placed the axis along its line of sight instead
    assert any("cam_a" in f["cameras"] and f["levelled"] for f in _found(figures, "SLOTS_LEAN"))
    assert figures["centerline"] <= accuracy_matrix.FLOORS["centerline"]


def test_a_centreline_off_its_floor_says_how_uncertain_it_is():
    """The notches open towards cam_a, so the robot bends along the cameras' views, where only depth places it (the
    bend plane holds nothing there), and a real stereo matcher reads the wall between the notches that cam_a looks
    into 0.1 mm deep: the centreline misses its floor, and the result's own uncertainty (the walls' levels apart,
    the slots' lean) says so - at least as large as the error it made. (The emulated depth's rows that missed it
    here - the tube bent towards cam_a from 110 mm, 1 mm depth steps - meet it since the axis is held to the bend
    plane.)"""
    figures = accuracy_matrix.run_row(accuracy_matrix.with_matcher(ROWS["side-90_bend30"], "sgbm", False), frames=2)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    assert "centerline" in figures["misses"], "this row was expected to miss; if it no longer does, pick another"
    stated = _found(figures, "CENTERLINE_UNCERTAIN")
    assert stated and round(stated[0]["uncertainty_mm"], 2) * 1e-3 >= figures["centerline"]


def test_a_rig_file_rolled_20_degrees_off_reports_the_side_the_notches_open_to():
    """The robot's roll in its clamp is never exact: with the rig file's notch_side 20 deg off, every notch is
    still found, and the side reported is the true one (0 deg) within half of the 10 deg sectors it is measured in
    and within the uncertainty the result states for it."""
    figures = accuracy_matrix.run_row(ROWS["side_off20"], frames=2)
    print("\n" + accuracy_matrix.HEADER + "\n" + accuracy_matrix.format_row(figures)
          + f"\nside uncertainty stated: {figures['side_uncertainty_deg']:.1f} deg")
    assert figures["found"] == figures["expected"] and figures["spurious"] == 0
    assert abs(figures["side_deg"] - 0.0) <= min(5.0, figures["side_uncertainty_deg"])


def test_a_last_notch_beyond_where_the_coarse_end_stopped_is_found_once_the_end_is_refined():
    """1.8 mm notches on a robot bent 84 degrees: the distal spines are thinly seen, and the ring the last cut
    leaves is too little for the coarse end's sector count, which stops at that cut (51.5 of 54.6 mm). The end
    refined on each camera's rim reaches past it, and the notches are looked for again up to there (notch 15 was
    reported missing when only the coarse end bounded the search)."""
    row = accuracy_matrix.Row("last_notch_past_the_coarse_end",
                              ("--bend-deg", "83.7", "--notch-side", "133.4", "--camera-distance", "0.090"),
                              robot={"notch_width": 0.0018, "notch_pitch": 0.0032})
    figures = accuracy_matrix.run_row(row, frames=2, seed=3016)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    assert (figures["found"], figures["spurious"]) == (figures["expected"], 0) == (16, 0)
    assert not _found(figures, "NOTCHES_MISSING")


def test_the_backbone_across_the_cuts_is_trusted_wall_for_the_alignment():
    """Cameras 102 mm away, the notches opening 135 deg round from cam_b: the wall cam_b faces across each cut is
    the backbone, which the cut leaves whole. Left out with the cuts' whole length, the alignment rested on half
    the wall points it has, and the centreline missed its floor (0.122 mm); trusted, it meets it."""
    row = accuracy_matrix.Row("backbone_across_the_cuts",
                              ("--bend-deg", "40.4", "--notch-side", "-134.9", "--camera-distance", "0.102"))
    figures = accuracy_matrix.run_row(row, frames=2, seed=4011)
    print("\n" + accuracy_matrix.format_row(figures) + "\n" + _listed(figures["warnings"]))
    assert figures["centerline"] <= accuracy_matrix.FLOORS["centerline"]
    assert figures["misses"] == []


def test_a_side_that_one_edge_of_the_notches_window_placed_is_stated_as_uncertain_as_the_matcher_smears_it():
    """A rig file rolled 15 deg off, notches opening 45 deg towards cam_a from 104 mm: neither camera sees both
    edges of the notches' open window, and the matcher smears the one edge seen by its edge band (0.5 mm round
    a 1.75 mm radius: 16 deg), which no second edge cancels. The side the result states must say so (it claimed
    +-8 deg while 13 deg off); the plane the robot bends in, 88 deg, places it to a fraction of a degree."""
    row = accuracy_matrix.Row("side_by_one_edge",
                              ("--bend-deg", "87.6", "--notch-side", "-44.6", "--camera-distance", "0.104",
                               "--camera-yaw-deg=-1.3,2.0", "--camera-pitch-deg=-1.1,-0.9"), side_error_deg=-15.0)
    figures = accuracy_matrix.run_row(row, frames=2, seed=4026)
    error = abs((figures["side_deg"] + 44.6 + 180.0) % 360.0 - 180.0)
    print(f"\nside {figures['side_deg']:.1f} deg (true -44.6): {error:.1f} deg off, stated "
          f"+-{figures['side_uncertainty_deg']:.1f}")
    assert error <= figures["side_uncertainty_deg"]


def test_the_summary_counts_the_errors_within_the_uncertainty_each_result_stated():
    """A result's stated uncertainty is judged against its error, figure by figure; a tube the result says ends
    short is judged too (it states its tip as far off as the rest of the robot may reach); a failed one is not."""
    def result(centerline, along, across, stated, warnings=()):
        return {"centerline": centerline, "tip_along": along, "tip_across": across, "warnings": list(warnings),
                "stated": dict(zip(("centerline", "tip_along", "tip_across"), stated, strict=True))}

    results = [result(0.05e-3, -0.08e-3, 0.1e-3, (0.06e-3, 0.1e-3, 0.2e-3)),  # all within
               result(0.2e-3, 0.12e-3, 0.3e-3, (0.1e-3, 0.1e-3, 0.15e-3)),    # all understated
               result(0.05e-3, -8e-3, 2e-3, (0.06e-3, 9e-3, 9e-3),
                      [finding("TUBE_ENDS_SHORT", "the tube ends 9.0 mm short of ...", short_of_length_mm=9.0,
                               at_crop_box=False)]),
               {"row": "failed", "error": "too few points", "warnings": ["too few points"]}]
    judged, bounded = accuracy_matrix.bounded_by_stated(results)
    assert judged == 3
    assert bounded == {"centerline": 2, "tip_along": 2, "tip_across": 2}
    figures = accuracy_matrix.run_row(ROWS["cameras75"], frames=2)
    print(f"\nstated {figures['stated']}")
    assert figures["stated"]["tip_along"] > 0  # the tip is always known only so well: the key is read


def test_a_run_over_several_seeds_names_the_rows_that_meet_their_floors_on_some_seeds_only(capsys):
    """--seeds: a row meeting its floors on one noise seed and missing them on another met them by luck."""
    results = [{"row": "steady#1", "misses": []}, {"row": "steady#2", "misses": []},
               {"row": "lucky#1", "misses": []}, {"row": "lucky#2", "misses": ["tip"]},
               {"row": "never#1", "misses": ["centerline"]}, {"row": "never#2", "misses": ["tip"]}]
    accuracy_matrix.print_rows_by_seed(results, seeds=2)
    line = capsys.readouterr().out.strip()
    print("\n" + line)
    assert line == "rows meeting every floor on all 2 seeds: 1/3; on some only: lucky 1/2"


def test_stated_detail_names_each_figure_whose_error_exceeds_what_its_result_stated():
    """--stated prints each row's errors against its stated uncertainties (mm), OVER where one understates."""
    figures = {"centerline": 0.034e-3, "tip_along": -0.024e-3, "tip_across": 0.160e-3, "warnings": [],
               "stated": {"centerline": 0.026e-3, "tip_along": 0.092e-3, "tip_across": 0.137e-3}}
    line = accuracy_matrix.format_stated(figures)
    print("\n" + line)
    assert line == ("centerline 0.034/0.026 OVER, tip_along 0.024/0.092, tip_across 0.160/0.137 OVER")


def test_the_sweep_renders_its_scenes_by_the_tests_own_renderer_too():
    """`accuracy_sweep.py --renderer views` draws the scene the simulator renders (robot, bend, notch side, camera
    distance and tilts, rig-file roll) and renders it with test/support/synthetic_views.py instead. Its scene 3018 -
    ten notches bent 18 deg towards cam_b at 75 mm, 640x480, the end cap and the bore seen through the open end -
    put the tip 0.56 mm off while stating 0.1: the centreline fit had kept the end its cold-start march bent back at
    the cap."""
    import accuracy_sweep

    scene, row = accuracy_sweep.draw_scene(3018), accuracy_sweep.random_row(3018)
    assert row.name == scene.name and row.robot == accuracy_sweep.ROBOTS[scene.robot]
    assert row.args[:2] == ("--bend-deg", f"{scene.bend_deg:.1f}")
    figures = accuracy_sweep.run_views_scene(3018)
    print("\n" + accuracy_matrix.HEADER + "\n" + accuracy_matrix.format_row(figures))
    assert figures["row"].startswith(scene.name)
    assert figures["misses"] == []
    assert figures["tip"] < 0.1e-3 and figures["centerline"] < 0.02e-3  # before the fix: 0.56 and 0.075 mm


def test_stated_detail_gives_where_the_notches_were_placed_along_the_tube(capsys):
    """--stated also prints the notch centres' error along the tube (not a floor, but /ntcr/notches publishes
    them): their mean and the worst, signed."""
    import argparse

    figures = {"centerline": 0.03e-3, "tip_along": 0.02e-3, "tip_across": 0.04e-3, "warnings": [],
               "stated": {"centerline": 0.05e-3, "tip_along": 0.1e-3, "tip_across": 0.1e-3},
               "centre_errors": [-0.05e-3, 0.02e-3, -0.12e-3]}
    accuracy_matrix.print_details(figures, argparse.Namespace(warnings=False, stated=True))
    assert "notch centres along the tube: mean -0.050, worst -0.120 (mm, + towards the tip)" in capsys.readouterr().out
