"""Coded warnings and a result's status: what a control node acts on without parsing text.

Every doubt a reconstruction raises is a `Finding`: a stable `code` (listed once in CODES, with its severity,
meaning and what to do; the README's table is written from it), the sentence for people, and the figures it
rests on (units in their names). The severity says what it does to the result:

- `info`: a note that does not lower the result's trustworthiness (frames left out, the robot moved and its
  still stretch was kept), or one that explains an uncertainty the result already states (the tolerance check
  of `status` judges that figure, not the note);
- `warn`: something the stated uncertainties do not cover (a part no camera measured, a rig file that
  disagrees with the data, notches missing);
- `error`: the result rests on a broken rig (a camera that gave nothing).

`result_status` is `ok` only when every expected notch was found, every stated uncertainty (`uncertainty_mm`: 90 %
bounds) lies within the rig's `quality` tolerances and no finding is `warn` or `error`; `error` when a finding
is `error`; `warn` otherwise.

Public API:
    CODES, Finding, finding(code, message, **figures), sort_by_severity(findings)
    notch_width_uncertainties(width_vs_bend, indices, limit, misread), every_notch_factor(count)
    uncertainty_mm(quality, notch_uncertainties_mm) -> {"centerline", "tip", "notch_width"}
    result_status(findings, quality, tolerance) -> "ok" | "warn" | "error"
    codes_table() -> str  (the README's table)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any, NamedTuple

from ntcr_recon.core.relocation.notch_widths import MIN_CHECKED_NOTCHES, Weighing

SEVERITIES = ("info", "warn", "error")


class Code(NamedTuple):
    severity: str
    meaning: str
    action: str


CODES: dict[str, Code] = {
    # the input
    "CAMERA_NO_FRAMES": Code("error", "a camera gave no frame: the result rests on the others alone",
                             "check the camera's topics (--topic), cable and serial number"),
    "CAMERA_NO_POINTS": Code("error", "a camera's points all fell outside the crop box: the result rests on the "
                             "others alone", "check its depth_unit and pose (translation, rotation)"),
    "CAMERA_FEW_POINTS": Code("warn", "a camera gave under a quarter of the other's points: the result leans on "
                              "one view", "check its pose, depth_unit and view of the robot"),
    "DEPTH_BIG_ENDIAN": Code("warn", "depth images flagged big-endian (read byte-swapped as flagged)",
                             "check the recording tool: D405 drivers write little-endian"),
    "DEPTH_COARSER_THAN_UNIT": Code("warn", "raw depth comes in steps coarser than its depth_unit (a coarser "
                                    "recording rescaled)", "record at the D405's 0.1 mm depth unit"),
    "DEPTH_QUANTISED": Code("warn", "a camera's depth step is too coarse for the tube's roundness",
                            "record at the D405's 0.1 mm depth unit (realsense-ros forces 1 mm)"),
    "PIXEL_FOOTPRINT_COARSE": Code("info", "few depth pixels across the tube (the stated uncertainties carry it)",
                                   "a higher resolution, or cameras closer (down to the D405's 70 mm minimum depth)"),
    "FRAMES_BEFORE_CAMERA_INFO": Code("info", "depth images with no camera_info to deproject them were skipped",
                                      "none: record camera_info with the depth images"),
    "PAIRS_ONE_CAMERA": Code("info", "some frame pairs had one camera only (stamps further apart than "
                             "fusion.slop)", "none, unless many: check the cameras' clocks and fusion.slop"),
    "FRAMES_LEFT_OUT": Code("info", "frame pairs that gave no result (the robot out of view) were left out",
                            "none"),
    "ROBOT_MOVED": Code("info", "the robot moved during the recording: the longest still stretch was combined",
                        "none; relocation_node gives a result per frame"),
    # the notches
    "NOTCHES_MISSING": Code("warn", "expected notches were not found: their widths are unknown (figures: where "
                            "each missing one lies)", "see where they lie: beyond the end seen, unseen by a camera, "
                            "or unmarked in the wall (a matcher's window wider than the cut)"),
    "NOTCH_WIDTH_FROM_BEND": Code("info", "notches only a dip of the wall or the tube's outline in a colour image "
                                  "marks (slots the matcher filled): their widths are what their bends imply, as "
                                  "stated in their uncertainty", "none"),
    "NOTCH_WIDTH_MISREAD": Code("info", "notches whose rims read a width their bends rule out: their widths are "
                                "what their bends imply, as stated in their uncertainty",
                                "check the robot's cut widths if it recurs"),
    "NOTCH_WIDTH_UNCHECKED": Code("warn", "widths nothing could check against their bends (the tube seen ends "
                                  "within a pitch of them)", "none; a view of the next notch checks it"),
    "NOTCH_SIDE_UNSETTLED": Code("warn", "the notches' side could not be measured consistently: the configured "
                                 "side is kept", "check the robot's roll in its clamp (robot.notch_side)"),
    "NOTCH_SIDE_RULED_OUT": Code("info", "the notches' edges put their side off the configured robot.notch_side "
                                 "by a roll the plane the robot bends in rules out: the configured side is kept",
                                 "none; if it recurs, check the notches' edges (a matcher smearing them)"),
    "ROBOT_ROLLED": Code("info", "the notches open away from the configured robot.notch_side beyond what the "
                         "measured side is known to: the robot is rolled in its clamp, or the rig file is off (the "
                         "measured side is used, and the result stands)",
                         "correct robot.notch_side, or the robot's roll in its clamp"),
    "NOTCH_SIDE_OFF": Code("info", "the notches open away from the configured robot.notch_side, by no more than "
                           "the measured side is known to (the measured side is used)",
                           "none; if it recurs, check robot.notch_side"),
    "BEND_PLANE_TURNED": Code("info", "the robot bends in a plane turned from the configured robot.notch_side "
                              "beyond robot.roll_tolerance: the axis is held to the plane its points show (its roll's "
                              "SD counts in the centreline's bound, and the result stands)",
                              "correct robot.notch_side or recalibrate; check the robot's roll in its clamp"),
    # the centreline
    "CENTERLINE_UNCERTAIN": Code("info", "the centreline's stated uncertainty exceeds the floor, and why",
                                 "see the figures: cameras closer, or a camera facing the backbone"),
    "SLOTS_LEAN": Code("info", "a camera looks into the notches' slots and reads the wall between them deep: the "
                       "centreline may lean, as its uncertainty states", "none"),
    "ALIGNMENT_ASTRAY": Code("info", "the alignment followed a wall stereo moved across the views: across them "
                             "the axis is the fit's", "none"),
    "OUTLINE_UNCHECKED": Code("warn", "no camera's view showed the tube's outline whole: the centreline was not "
                              "checked across the views", "a camera further from the backdrop, or a sharper "
                              "matcher"),
    "CENTERLINE_UNSUPPORTED": Code("warn", "stretches where no camera saw the wall facing it: the centreline "
                                   "there was not measured", "a camera facing that stretch"),
    "DISTAL_END_ON": Code("warn", "a distal stretch every camera sees nearly end-on: the axis and tip there were "
                          "not placed across the tube", "a camera seeing the distal part side-on"),
    "DISTAL_ONE_CAMERA": Code("info", "a distal stretch seen by one camera alone: its far side is inferred, and the "
                              "axis there rests on the one wall's level, which the centreline's and the tip's bounds "
                              "carry",
                              "a pose both cameras see, or cameras further back (70 mm minimum depth)"),
    "COLOUR_VIEW_MISSING": Code("info", "a camera's colour image did not come with its depth (relocation.limbs): "
                                "across its view the axis was placed by depth alone (the stated bounds carry it)",
                                "check the camera streams colour aligned with depth (camera_node's colour topic)"),
    "CAMERA_SHORT_VIEW": Code("warn", "a camera saw under half of the robot's length", "check its view of "
                              "the robot"),
    "EXTRINSICS_DISAGREE": Code("warn", "the cameras place the axis apart across their views alike all along the "
                                "tube: their poses in the rig file disagree (figures: the offset, as a turn; "
                                "by_outlines: read from the cameras' whole outlines, a pose a millimetre or more "
                                "off, the centreline then up to all of it off)",
                                "recalibrate with `ntcr-recon calibrate` (README: Calibrating the rig); check the "
                                "cameras' mounts"),
    # the tip
    "TIP_ON_ERODED_RIM": Code("info", "the tip rests on a stereo-eroded rim, uncertain as stated", "none"),
    "TIP_ON_END_CAP": Code("info", "the tip is the end cap's plane (the tube points at a camera), uncertain as "
                           "stated", "none"),
    "TIP_OFF_LENGTH": Code("warn", "the end seen lies off the robot's length at the bend measured, beyond both "
                           "uncertainties: the end seen is kept", "check the robot's notch layout, its base "
                           "position and robot.length_tolerance"),
    "TUBE_ENDS_SHORT": Code("warn", "the tube seen ends off the robot's length: the rest is unseen (figures: "
                            "where, and whether the crop box cut it)", "see the message: crop box, or a camera "
                            "too near"),
    "TIP_CARRIED": Code("warn", "the tip was carried over a part no camera saw, bending as the notches seen did",
                        "a pose the cameras see whole"),
    "ICP_MOVED_REFERENCE": Code("warn", "relocation.method icp moved the reference further than the centreline is "
                                "known to: the two relocations disagree", "use relocation.method centerline"),
}


@dataclass(frozen=True)
class Finding:
    """One coded doubt about a result. str() is its sentence, so it reads as the warning it was."""

    code: str
    message: str
    figures: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.code not in CODES:
            raise ValueError(f"unknown warning code {self.code!r} (core.quality.findings.CODES lists them)")

    @property
    def severity(self) -> str:
        return CODES[self.code].severity

    def as_dict(self) -> dict:
        """The record result.json carries: code, severity, message, then the figures."""
        return {"code": self.code, "severity": self.severity, "message": self.message, **self.figures}

    def __str__(self) -> str:
        return self.message


def finding(code: str, message: str, **figures) -> Finding:
    return Finding(code, message, figures)


def sort_by_severity(findings: Iterable[Finding]) -> list[Finding]:
    """Errors first, then warnings, then notes (stable within each)."""
    return sorted(findings, key=lambda f: -SEVERITIES.index(f.severity))


# A 90 % bound of a normal error is this many of its standard deviations.
Z90 = 1.645


def notch_width_uncertainties(width_vs_bend: Mapping[int, float], indices: Iterable[int], limit: float,
                              misread: Iterable[int] = (), weighed: Mapping[int, float] | None = None,
                              weighing: Weighing | None = None) -> dict[int, float]:
    """Per notch a 90 % bound of its width's error (m), from how the widths read disagree with the widths their bends
    imply (notch_widths.calibrate_and_check's two independent measurements of each notch): the disagreement's
    variance is the sum of both errors' variances, so Z90 times its RMS over the notches bounds either; a notch
    whose own disagreement is larger is known no better than that. With fewer than MIN_CHECKED_NOTCHES checked
    (notch_widths'), `limit` (what the check lets pass). The `misread` notches are left out of the RMS (their
    disagreement is a misread rim's): each was given the width its steady bend implies, as a dip is, and is known as
    a dip is, to the spread, which bounds the implied widths' error as well as the read ones' - not as far off as
    its rims read (on the matrix's rows and the three random sweeps, 1 of 229 misread notches' widths was off by
    more than 0.15 mm, where their rims had read 0.14-0.77 mm off, 10th to 90th percentile).

    The `weighed` notches' widths are the two measurements weighed by their errors (notch_widths.weighing: its
    error's SD, from the disagreements and the chords' scatter, Z90 times; None: not known, and the spread, which
    bounds either measurement, bounds them weighed). `weighed`: by index, how far off its own chord's bend, where it
    stands out of its neighbours', puts a weighed notch's width (m): known no better than that, nor than the read
    width's weight times its own disagreement (a rim read off moves it that far)."""
    left_out = set(misread)
    checked = [d for i, d in width_vs_bend.items() if i not in left_out]
    known = len(checked) >= MIN_CHECKED_NOTCHES
    spread = Z90 * math.sqrt(sum(d * d for d in checked) / len(checked)) if known else limit
    sd = weighing.error_sd if known and weighing is not None else None
    weighed = (weighed or {}) if sd is not None else {}
    return {i: spread if i in left_out
            else max(Z90 * sd, weighing.read * abs(width_vs_bend.get(i, 0.0)), weighed[i]) if i in weighed
            else max(spread, abs(width_vs_bend.get(i, 0.0))) for i in indices}


def every_notch_factor(count: int) -> float:
    """What turns per-notch 90 % bounds into a bound every one of `count` notches stays within 90 % of the time:
    each must then hold with probability p = 0.9 ** (1 / count) (their errors independent): |error| within the
    normal quantile of (1 + p) / 2, as Z90 is of (1 + 0.9) / 2 (an error may fall on either side)."""
    return float(NormalDist().inv_cdf((1.0 + 0.9 ** (1.0 / count)) / 2.0)) / Z90 if count > 1 else 1.0


def uncertainty_mm(quality: Mapping[str, Any], notch_uncertainties_mm: Iterable[float]) -> dict[str, float | None]:
    """The result's three 90 % bounds (mm): the centreline's RMS error, the tip's distance from the true tip (its
    along- and across-tube bounds in quadrature), and the notch widths' largest error (the largest per-notch bound
    widened by every_notch_factor: 16 notches each within its own 90 % bound all are only 19 % of the time).
    None: not measured."""
    along, across = quality.get("tip_uncertainty_mm"), quality.get("tip_across_uncertainty_mm")
    widths = list(notch_uncertainties_mm)
    return {"centerline": quality.get("centerline_uncertainty_mm"),
            "tip": None if along is None else math.hypot(along, across or 0.0),
            "notch_width": max(widths) * every_notch_factor(len(widths)) if widths else None}


def result_status(findings: Iterable[Finding], quality: Mapping[str, Any], tolerance) -> str:
    """ok / warn / error (module docstring) of a result's findings and its `quality` (its uncertainty_mm,
    notches_found and notches_expected). tolerance: config.rig.QualityConfig (m)."""
    severities = {f.severity for f in findings}
    if "error" in severities:
        return "error"
    uncertainty, expected = quality["uncertainty_mm"], quality["notches_expected"]
    limits_mm = {"centerline": tolerance.centerline_tolerance * 1e3, "tip": tolerance.tip_tolerance * 1e3,
                 "notch_width": tolerance.notch_width_tolerance * 1e3}
    within = all(uncertainty.get(name) is not None and uncertainty[name] <= limit
                 for name, limit in limits_mm.items() if name != "notch_width" or expected)
    return "ok" if within and quality["notches_found"] >= expected and "warn" not in severities else "warn"


def codes_table() -> str:
    """The README's table of codes (test_findings checks the README holds it as written here)."""
    lines = ["| code | severity | meaning | what to do |", "|---|---|---|---|"]
    lines += [f"| `{code}` | {c.severity} | {c.meaning} | {c.action} |" for code, c in CODES.items()]
    return "\n".join(lines)
