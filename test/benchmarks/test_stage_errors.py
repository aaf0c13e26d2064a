"""benchmarks/stage_errors.py: the centreline's error after each step of the alignment, on a row of the accuracy
matrix (emulated depth), adds up to the matrix's figures for the result and shows each step's part."""

from __future__ import annotations

import argparse
import sys

import pytest
from support import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import accuracy_matrix  # noqa: E402
import stage_errors  # noqa: E402

ROWS = {row.name: row for row in accuracy_matrix.ROWS}


def test_each_step_s_error_on_a_robot_bent_along_the_views():
    """side90_bend30: the robot bends along the cameras' views, towards the notch side. The trusted wall leaves the
    axis along the views where the slot-side camera's deep wall puts it; the camera facing the backbone levels it
    (emulated depth: 0.030 -> 0.017 mm); the limbs place it across the views; the result is what the matrix
    measures."""
    row = ROWS["side90_bend30"]
    errors = stage_errors.stage_errors(row)
    print("\n" + stage_errors.format_errors(row.name, errors))
    assert list(errors) == ["fit", "trusted wall", "backbone", "limbs", "bend plane", "result"]
    along = {step: error[0] * 1e3 for step, error in errors.items()}
    across = {step: error[1] * 1e3 for step, error in errors.items()}
    assert along["backbone"] < along["trusted wall"] - 0.005
    assert across["result"] < across["fit"] / 2
    figures = accuracy_matrix.run_row(row)
    assert along["result"] == pytest.approx(figures["centerline_along_views"] * 1e3, abs=1e-6)
    assert across["result"] == pytest.approx(figures["centerline_across_views"] * 1e3, abs=1e-6)


def test_changes_count_a_step_against_the_one_before_it_that_ran():
    """A step that did not run is skipped: the next one is judged against the axis the last one that ran left."""
    errors = {"fit": (0.05e-3, 0.10e-3), "trusted wall": (0.05e-3, 0.02e-3), "limbs": (0.05e-3, 0.021e-3),
              "bend plane": (0.0, 0.02e-3), "result": (0.0, 0.02e-3)}
    assert stage_errors.changes([errors], "trusted wall") == (0, 1)
    assert stage_errors.changes([errors], "limbs") == (0, 0)       # 0.001 mm: within CHANGED_MM
    assert stage_errors.changes([errors], "backbone") == (0, 0)    # did not run
    assert stage_errors.changes([errors], "bend plane") == (0, 1)
    worse = dict(errors, limbs=(0.05e-3, 0.05e-3))
    assert stage_errors.changes([worse], "limbs") == (1, 0)


def test_a_sweep_scene_by_the_tests_own_renderer():
    """--sweep --renderer views: accuracy_sweep's scene 1001 as the second renderer draws it (no colour images: the
    limbs do not run), named as the sweep names it; its result's errors are the sweep's."""
    import accuracy_sweep

    args = argparse.Namespace(sweep=1, renderer="views", seed=1001, frames=2, simulate="", rows="", matcher="both")
    [(source, measure)] = list(stage_errors.scenes(args))
    name, errors = measure()
    print("\n" + stage_errors.format_errors(name, errors))
    assert source == "views"
    assert "limbs" not in errors and list(errors)[0] == "fit" and list(errors)[-1] == "result"
    figures = accuracy_sweep.run_views_scene(1001)
    assert name == figures["row"]
    assert errors["result"][0] == pytest.approx(figures["centerline_along_views"], abs=1e-9)
    assert errors["result"][1] == pytest.approx(figures["centerline_across_views"], abs=1e-9)
