"""What the input says about a reconstruction's trustworthiness, before any stage judges the cloud.

A result that rests on one camera, on a camera that saw next to nothing (a wrong depth_unit or pose), on
depth coarser than the configuration assumes or on a byte-order flag is not to be reported as if all were
well: each such fact becomes one coded warning (core.quality.findings) for `result.json`'s `warnings`. (The
relocation stage adds its own about the cloud it fitted.)

Public API:
    CameraInput                                   what reading and fusing saw of one camera, filled as frames pass
    input_warnings(config, cameras, pairs=0, one_camera_pairs=0) -> list[Finding]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.quality.findings import Finding, finding

# A camera giving less than this share of the other's points is reported: two opposed cameras on a rig see
# about as much of the robot each (on the simulated scenes the smaller share is above 0.7).
FEWER_POINTS_RATIO = 0.25
# Raw 16-bit depth images of each camera whose values are examined for their quantisation step.
QUANTISATION_SAMPLE_FRAMES = 3


@dataclass
class CameraInput:
    """One camera's input as the offline command saw it."""

    frames: int = 0                  # depth images or clouds read
    frames_without_info: int = 0     # depth images before any camera_info: skipped
    big_endian_frames: int = 0       # depth images flagged is_bigendian (read byte-swapped, as flagged)
    raw_step: int = 0                # gcd of the steps between distinct raw 16-bit values (0: not known)
    raw_near: float = math.nan       # the nearest valid raw values (2nd percentile) of the first depth image
    fused_points: int = 0            # points it gave inside the crop box, over all frames
    relocated_points: int = 0        # of its points, those in the combined relocated result

    def observe_depth(self, depth: np.ndarray, big_endian: bool) -> None:
        """Count one decoded depth image; sample the first few for their raw value steps."""
        self.frames += 1
        self.big_endian_frames += bool(big_endian)
        if depth.dtype != np.uint16 or self.frames > QUANTISATION_SAMPLE_FRAMES:
            return
        values = np.flatnonzero(np.bincount(depth.ravel()))  # the distinct raw values, sorted
        values = values[values > 0]  # 0 = no depth
        if len(values) > 1:
            self.raw_step = math.gcd(self.raw_step, int(np.gcd.reduce(np.diff(values))))
        if math.isnan(self.raw_near) and len(values):
            self.raw_near = float(np.percentile(depth[depth > 0], 2))  # the robot, nearest thing in view


def input_warnings(config: RigConfig, cameras: dict[str, CameraInput], pairs: int = 0,
                   one_camera_pairs: int = 0) -> list[Finding]:
    """One coded warning per fact of the input that degrades the result (empty when there is none)."""
    warnings = []
    seen = {name: facts for name, facts in cameras.items() if facts.frames}
    for name, facts in cameras.items():
        unit = config.cameras[name].depth_unit
        others = ", ".join(sorted(set(seen) - {name})) or "no camera"
        if not facts.frames:
            warnings.append(finding("CAMERA_NO_FRAMES", f"{name} has no frame in the bag: the result rests on "
                                    f"{others} alone", camera=name, rests_on=sorted(set(seen) - {name})))
            continue
        if facts.frames_without_info:
            warnings.append(finding("FRAMES_BEFORE_CAMERA_INFO", f"{name}: {facts.frames_without_info} depth "
                                    "images came before any camera_info and were skipped", camera=name,
                                    frames=facts.frames_without_info))
        if facts.big_endian_frames:
            warnings.append(finding("DEPTH_BIG_ENDIAN", f"{name}: {facts.big_endian_frames} of {facts.frames} "
                                    "depth images are flagged big-endian (read byte-swapped, as flagged; D405 drivers "
                                    "write little-endian, so a wrong flag means wrong depth)", camera=name,
                                    frames=facts.big_endian_frames))
        if facts.raw_step > 1:
            warnings.append(finding("DEPTH_COARSER_THAN_UNIT", f"{name}: raw depth comes in steps of "
                                    f"{facts.raw_step} units ({facts.raw_step * unit * 1e3:.3g} mm), coarser than its "
                                    f"depth_unit of {unit * 1e3:.3g} mm suggests (a coarser recording rescaled, e.g. "
                                    "realsense-ros's 1 mm?): depth detail below that step is lost", camera=name,
                                    depth_step_mm=facts.raw_step * unit * 1e3, step_units=facts.raw_step))
        if not facts.fused_points:
            contributing = sorted(other for other, other_facts in seen.items() if other_facts.fused_points)
            rests_on = (f"the result rests on {', '.join(contributing)} alone" if contributing
                        else "nor did any other camera")
            warnings.append(finding("CAMERA_NO_POINTS", f"{name} contributed no points inside the crop box in "
                                    f"{facts.frames} frames: {rests_on}; check {name}'s depth_unit ({unit:g} m) and "
                                    f"pose (translation, rotation){_distance_hint(config, name, facts)}",
                                    camera=name, rests_on=contributing,
                                    depth_unit_that_fits=_unit_that_fits(config, name, facts)))
    # Who the result rests on: the relocated points once relocation ran (a camera whose points land beside
    # the robot, e.g. a wrong pose, contributes little there), else the fused points per frame.
    relocated = any(facts.relocated_points for facts in seen.values())
    share = {name: facts.relocated_points if relocated else facts.fused_points / facts.frames
             for name, facts in seen.items() if facts.fused_points}
    if len(share) > 1:
        most = max(share, key=share.get)
        what = "points in the relocated result" if relocated else "points a frame inside the crop box"
        for name, count in share.items():
            if count < FEWER_POINTS_RATIO * share[most]:
                warnings.append(finding("CAMERA_FEW_POINTS", f"{name} contributed {count:.0f} {what}, "
                                        f"{count / share[most]:.0%} of {most}'s {share[most]:.0f}: the result leans on "
                                        f"{most}; check {name}'s pose (translation, rotation), depth_unit and view of "
                                        "the robot", camera=name, share_of_most=count / share[most],
                                        leans_on=most))
    if one_camera_pairs and len(seen) > 1:
        warnings.append(finding("PAIRS_ONE_CAMERA", f"{one_camera_pairs} of {pairs} frame pairs have one camera "
                                f"only (stamps further apart than fusion.slop = {config.fusion.slop * 1e3:g} ms)",
                                pairs=one_camera_pairs, of=pairs))
    return warnings


def _unit_that_fits(config: RigConfig, name: str, facts: CameraInput) -> float | None:
    """The depth unit _distance_hint names (None where it names none): a figure of CAMERA_NO_POINTS."""
    fit = _distance_fit(config, name, facts)
    return None if fit is None else fit[2]


def _distance_fit(config: RigConfig, name: str, facts: CameraInput) -> tuple[float, float, float] | None:
    """(depth read nearest, distance to the robot, the depth unit that would put it there), when the depth read
    is far from where the robot is; else None."""
    if math.isnan(facts.raw_near):
        return None
    unit = config.cameras[name].depth_unit
    box_min, box_max = config.crop_box()
    expected = float(np.linalg.norm((np.asarray(box_min) + box_max) / 2 - config.cameras[name].translation))
    measured = facts.raw_near * unit
    if expected <= 0 or 0.33 < measured / expected < 3:
        return None
    return measured, expected, 10.0 ** round(math.log10(unit * expected / measured))


def _distance_hint(config: RigConfig, name: str, facts: CameraInput) -> str:
    """When the depth read is far from where the robot is, the depth unit that would put it there."""
    fit = _distance_fit(config, name, facts)
    if fit is None:
        return ""
    measured, expected, suggested = fit
    return (f"; its nearest depth reads {measured * 1e3:.3g} mm while the robot is about {expected * 1e3:.0f} mm "
            f"away: a depth_unit of {suggested:g} would put it there")
