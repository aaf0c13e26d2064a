"""core.quality.findings: coded warnings, the result's status and its stated bounds (issue 63)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from support import REPO

from ntcr_recon.core.config.rig import QualityConfig
from ntcr_recon.core.quality.findings import (
    CODES,
    Z90,
    codes_table,
    every_notch_factor,
    finding,
    notch_width_uncertainties,
    result_status,
    sort_by_severity,
    uncertainty_mm,
)
from ntcr_recon.core.relocation.notch_widths import Weighing

WITHIN = {"centerline": 0.05, "tip": 0.10, "notch_width": 0.05}  # mm, within the default tolerances


def _quality(uncertainty, found: int, expected: int = 16) -> dict:
    """What result_status reads of a result's quality section."""
    return {"uncertainty_mm": uncertainty, "notches_found": found, "notches_expected": expected}


def test_a_finding_is_a_record_with_its_codes_severity():
    record = finding("ROBOT_ROLLED", "the notches open +15 deg ...", side_off_deg=15.0).as_dict()
    assert record == {"code": "ROBOT_ROLLED", "severity": "info", "message": "the notches open +15 deg ...",
                      "side_off_deg": 15.0}
    with pytest.raises(ValueError, match="NO_SUCH_CODE"):
        finding("NO_SUCH_CODE", "text")


def test_findings_sort_errors_first_then_warnings_then_notes():
    notes = [finding("FRAMES_LEFT_OUT", "a"), finding("NOTCHES_MISSING", "b"), finding("CAMERA_NO_FRAMES", "c"),
             finding("ROBOT_MOVED", "d")]
    assert [f.code for f in sort_by_severity(notes)] == ["CAMERA_NO_FRAMES", "NOTCHES_MISSING", "FRAMES_LEFT_OUT",
                                                         "ROBOT_MOVED"]


@pytest.mark.parametrize(("findings", "uncertainty", "found", "expected"), [
    ((), WITHIN, 16, "ok"),
    ((finding("FRAMES_LEFT_OUT", "1 of 4 frame pairs ..."),), WITHIN, 16, "ok"),   # a note keeps ok
    ((finding("TIP_CARRIED", "..."),), WITHIN, 16, "warn"),
    ((finding("CAMERA_NO_POINTS", "..."), finding("ROBOT_MOVED", "...")), WITHIN, 16, "error"),
    ((), WITHIN, 15, "warn"),                                                        # a notch missing
    ((), {**WITHIN, "tip": 0.151}, 16, "warn"),                                      # past the tip's tolerance
    ((), {**WITHIN, "centerline": 0.081}, 16, "warn"),
    ((), {**WITHIN, "notch_width": 0.201}, 16, "warn"),
    ((), {**WITHIN, "centerline": None}, 16, "warn"),                                # not measured is not ok
])
def test_status_is_ok_only_with_every_notch_every_bound_within_tolerance_and_no_warning(findings, uncertainty, found,
                                                                                       expected):
    assert result_status(findings, _quality(uncertainty, found), QualityConfig()) == expected


def test_status_follows_the_rigs_own_tolerance():
    strict = QualityConfig(centerline_tolerance=0.04e-3)
    assert result_status((), _quality(WITHIN, 16), QualityConfig()) == "ok"
    assert result_status((), _quality(WITHIN, 16), strict) == "warn"


def test_notch_width_bounds_come_from_the_widths_disagreement_with_their_bends():
    # read - implied per notch (m): the spread bounds every notch; one further off is known no better than that
    disagreement = {0: 0.02e-3, 1: -0.03e-3, 2: 0.01e-3, 3: 0.09e-3}
    rms = math.sqrt(sum(d * d for d in disagreement.values()) / 4)
    bounds = notch_width_uncertainties(disagreement, [0, 1, 2, 3, 4], limit=0.15e-3)
    assert bounds[0] == bounds[4] == pytest.approx(Z90 * rms)
    assert bounds[3] == pytest.approx(max(Z90 * rms, 0.09e-3))
    # too few notches checked to know the spread: the check's own limit
    assert notch_width_uncertainties({0: 0.01e-3}, [0, 1], limit=0.15e-3) == {0: 0.15e-3, 1: 0.15e-3}
    # a misread notch (given its bend's width) stays out of the spread and is known as a dip is, to the spread: its
    # 0.5 mm disagreement was its rim's error, not the width reported
    misread = notch_width_uncertainties(disagreement | {5: 0.5e-3}, [0, 5], limit=0.15e-3, misread=[5])
    assert misread == {0: pytest.approx(Z90 * rms), 5: pytest.approx(Z90 * rms)}
    # with too few notches left checked, the check's limit again
    assert notch_width_uncertainties({0: 0.01e-3, 5: 0.5e-3}, [0, 5], limit=0.15e-3, misread=[5]) == {
        0: 0.15e-3, 5: 0.15e-3}


def test_a_width_weighed_with_its_bend_is_known_as_the_weighing_says():
    # read - implied per notch (m); the weighed ones' widths are the two weighed by their errors (weighing): known to
    # Z90 times the weighing's error SD, or the read one's weight times a notch's own disagreement, or how far its own
    # chord puts it (`weighed`, by index), where larger
    disagreement = {0: 0.02e-3, 1: -0.03e-3, 2: 0.01e-3, 3: 0.09e-3}
    spread = Z90 * math.sqrt(sum(d * d for d in disagreement.values()) / 4)
    weighed = Weighing(read=0.5, error_sd=0.02e-3)
    bounds = notch_width_uncertainties(disagreement, [0, 1, 2, 3], limit=0.15e-3,
                                       weighed={0: 0.0, 1: 0.0, 2: 0.05e-3, 3: 0.0}, weighing=weighed)
    assert bounds[0] == bounds[1] == pytest.approx(Z90 * 0.02e-3) and spread > Z90 * 0.02e-3
    assert bounds[2] == pytest.approx(0.05e-3)  # its chord stands out of its neighbours'
    assert bounds[3] == pytest.approx(0.5 * 0.09e-3)  # a rim read that far off moves it half as far
    # the error not known (too few chords to scatter), or too few notches checked: as a width read
    unknown = Weighing(0.5, None)
    assert notch_width_uncertainties(disagreement, [0], limit=0.15e-3, weighed={0: 0.0}, weighing=unknown) == {
        0: pytest.approx(spread)}
    assert notch_width_uncertainties({0: 0.01e-3}, [0], limit=0.15e-3, weighed={0: 0.0}, weighing=weighed) == {
        0: 0.15e-3}


def test_a_bound_on_every_notch_is_wider_the_more_notches_there_are():
    # all of n independent errors within a bound 90 % of the time: each within it 0.9 ** (1 / n) of the time, on
    # either side (review: the one-sided quantile, 2.48 for 16 notches, bounded them 84 % of the time)
    assert every_notch_factor(1) == 1.0
    assert every_notch_factor(16) == pytest.approx(2.72 / Z90, rel=0.01)
    rng = np.random.default_rng(1)
    errors = rng.normal(size=(20000, 16))
    assert np.mean(np.abs(errors).max(axis=1) <= Z90 * every_notch_factor(16)) == pytest.approx(0.9, abs=0.01)
    assert 1.0 < every_notch_factor(10) < every_notch_factor(20)


def test_the_tips_bound_is_along_and_across_in_quadrature():
    quality = {"centerline_uncertainty_mm": 0.04, "tip_uncertainty_mm": 0.06, "tip_across_uncertainty_mm": 0.08}
    assert uncertainty_mm(quality, [0.03, 0.05]) == {"centerline": 0.04, "tip": pytest.approx(0.1),
                                                     "notch_width": pytest.approx(0.05 * every_notch_factor(2))}
    assert uncertainty_mm({"tip_uncertainty_mm": None}, []) == {"centerline": None, "tip": None, "notch_width": None}


def test_every_code_raised_is_listed_and_every_listed_code_is_raised():
    raised = set()
    for path in (REPO / "ntcr_recon").rglob("*.py"):
        raised |= set(re.findall(r'finding\(\s*"([A-Z_]+)"', path.read_text()))
        # a code chosen by a condition: finding("A" if ... else "B", ...)
        raised |= {code for pair in re.findall(r'finding\(\s*"([A-Z_]+)" if [^,]* else "([A-Z_]+)"', path.read_text())
                   for code in pair}
    assert raised == set(CODES)


def test_the_readme_lists_the_codes_as_the_module_does():
    assert codes_table() in (REPO / "README.md").read_text(), (
        "README's table of warning codes differs: paste core.quality.findings.codes_table()")


def _trace_with_offsets(offsets, reach=None):
    from ntcr_recon.core.quality.trace import Trace

    return Trace(geometry=None, camera_names=("cam_a", "cam_b"), notches=[], coords_s=None, camera=None, tip_s=0.05,
                 total_bend=0.0, footprint=0.2e-3, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
                 bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, cross_view_offsets=offsets,
                 centerline_tolerance=0.08e-3, reach=reach)


@pytest.mark.parametrize(("offsets", "warned"), [
    (((-0.007e-3, 0.005e-3), (-0.009e-3, 0.004e-3)), False),  # exact extrinsics (matrix row straight)
    (((0.138e-3, 0.005e-3), (0.128e-3, 0.006e-3)), True),     # cam_b turned 0.3 deg: 0.266 mm apart, 34 sigma
    (((0.138e-3, 0.07e-3), (0.128e-3, 0.08e-3)), False),      # as far apart, but within the windows' noise
    (((0.06e-3, 0.002e-3), (0.06e-3, 0.002e-3)), False),      # significant, the axis 0.06 mm off: within 0.08
    (((0.138e-3, 0.005e-3), None), False),                    # one camera placed too few windows
])
def test_extrinsics_disagree_where_the_cameras_shifts_are_rigid_and_matter(offsets, warned):
    from ntcr_recon.core.quality.checks import extrinsics

    figures, found = extrinsics(_trace_with_offsets(offsets), None)
    assert [f.code for f in found] == (["EXTRINSICS_DISAGREE"] if warned else [])
    if offsets[1] is not None:
        assert figures["cameras_across_view_offset_mm"] == pytest.approx(abs(offsets[0][0] + offsets[1][0]) * 1e3)
    if warned:
        assert found[0].figures["offset_mm"] == pytest.approx(0.266) and found[0].figures["turn_deg"] is None
