"""`ntcr-recon calibrate --straight BAG BAG [BAG ...] --config ROUGH.yaml --out RIG.yaml`: the rig calibrated from
the robot.

Each bag is one still pose of the robot, a few seconds of it: at rest and straight (--straight: its bends are held
at zero, so its axis fixes the base frame's z), and bent (its bends fitted, a linear profile from base to tip);
`ntcr-recon simulate` writes such bags for the simulated rig. Every camera's depth frames are deprojected with the
rough rig file's intrinsics and cropped round the robot's reach, grown for poses a few millimetres off
(core.calibration.recordings); at most --max-points of each camera's points per bag go into one fit of both
cameras' poses and every bent bag's notch bends (core.calibration.rig_fit). Out come:

    RIG.yaml                the rough file with each camera's translation and rotation replaced, all else kept
    RIG.calibration.json    per camera: the pose, how far it moved, its uncertainty (1-sigma, turns about and shifts
                            along the base frame's axes through the robot's middle), the residual off the tube; the
                            second camera relative to the first; per bag the fitted bends; warnings (code
                            CAMERA_FACES_SLOTS: a camera looks into the notches' slots, its pose along its view
                            suspect)
    RIG.calibration.png     both cameras' points over the fitted robot, with the rough poses and the calibrated ones

`--target MESH` calibrates from a rigid object instead (a machined block, balls on a post: for a rig without a
robot mounted yet): every BAG is a view of it, its mesh's frame is the base frame, and the fit has no bends and no
limbs (core.calibration.target).

Recordings that leave a pose parameter free are refused by name (e.g. a robot straight in every bag cannot fix the
cameras' turn about its axis). Exit status: 0 done, 2 refused (one message on stderr naming the cause).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

# Points per camera and recording the figure draws, and how near the fitted tube (m) they must lie to be drawn.
FIGURE_POINTS = 4000
FIGURE_BAND_M = 1.0e-3

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", type=Path, nargs="*", metavar="BAG",
                        help="rosbag2 directories, one still pose of the robot each, bent (30 deg or more)")
    parser.add_argument("--straight", type=Path, action="append", default=[], metavar="BAG",
                        help="a bag of the robot at rest, straight (its axis then is the base frame's z); repeatable")
    parser.add_argument("--config", type=Path, required=True,
                        help="the rig file with hand-measured poses (within about 3 deg and 3 mm)")
    parser.add_argument("--out", type=Path, required=True, help="the calibrated rig file to write")
    parser.add_argument("--target", type=Path, default=None, metavar="MESH",
                        help="calibrate from a rigid object instead of the robot (a machined block, balls on a post): "
                             "its mesh (.ply, .stl, .obj) in the base frame; every BAG a view of it")
    parser.add_argument("--target-unit", choices=("m", "mm"), default="m", help="the mesh's length unit (default m)")
    parser.add_argument("--overwrite", action="store_true", help="replace --out (and its report) when they exist")
    parser.add_argument("--max-points", type=int, default=None, metavar="N",
                        help="points per camera and bag the fit takes (default: "
                             "core.calibration.recordings.MAX_POINTS)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


class CalibrateCommandError(Exception):
    """Stops the command with one message."""


def main(args: argparse.Namespace) -> int:
    try:
        report = run(args)
    except CalibrateCommandError as failure:
        print(f"ntcr-recon calibrate: error: {failure}", file=sys.stderr)
        return 2
    for name, camera in report["cameras"].items():
        sigma = camera["uncertainty"]
        print(f"ntcr-recon calibrate: {name} moved {camera['moved']['turn_deg']:.3f} deg, "
              f"{camera['moved']['shift_mm']:.3f} mm; uncertain by {_largest(sigma['turn_deg']):.3f} deg, "
              f"{_largest(sigma['shift_mm']):.3f} mm (1-sigma, largest axis); off the tube "
              f"{camera['residual_mm']:.3f} mm RMS", file=sys.stderr)
    relative = report["relative"]
    if relative:
        print(f"ntcr-recon calibrate: {relative['camera']} relative to {relative['to']}: uncertain by "
              f"{_largest(relative['uncertainty']['turn_deg']):.3f} deg, "
              f"{_largest(relative['uncertainty']['shift_mm']):.3f} mm", file=sys.stderr)
    for warning in report["warnings"]:
        print(f"ntcr-recon calibrate: warn: [{warning['code']}] {warning['message']}", file=sys.stderr)
    print(f"ntcr-recon calibrate: wrote {args.out} and its report", file=sys.stderr)
    return 0


def _largest(by_axis: dict[str, float]) -> float:
    return max(by_axis.values())


def report_paths(out: Path) -> tuple[Path, Path]:
    """The report's JSON and figure beside the calibrated rig file."""
    stem = out.with_suffix("")
    return stem.with_name(stem.name + ".calibration.json"), stem.with_name(stem.name + ".calibration.png")


def run(args: argparse.Namespace) -> dict:
    """The whole command; raises CalibrateCommandError with the cause. Returns the report."""
    from ntcr_recon.core.calibration.rig_fit import CalibrationError
    from ntcr_recon.core.config.rig import ConfigError, load_rig_config
    from ntcr_recon.io.bag import bag_problem
    from ntcr_recon.io.rig_file import RigFileError, replace_poses

    if args.max_points is not None and args.max_points < 100:
        raise CalibrateCommandError(f"--max-points must be at least 100, got {args.max_points}")
    outputs = (args.out, *report_paths(args.out))
    if not args.overwrite and any(path.exists() for path in outputs):
        raise CalibrateCommandError(f"{args.out} or its report exists: pass --overwrite to replace them")
    if not args.bags and not args.straight:
        raise CalibrateCommandError("no bag given: record the robot straight (--straight BAG) and bent (BAG), or "
                                    "views of the --target")
    for bag in [*args.straight, *args.bags]:
        problem = bag_problem(bag)
        if problem:
            raise CalibrateCommandError(problem)
    try:
        config = load_rig_config(args.config)
        rough_text = args.config.read_text()
        replace_poses(rough_text, {name: np.eye(4) for name in config.camera_names})  # refuses a file it cannot edit
    except (ConfigError, RigFileError, OSError) as error:
        raise CalibrateCommandError(f"bad rig configuration {args.config}: {error}") from error
    target = _target(args) if args.target is not None else None
    recordings = _recordings(args, config, target)
    start = {name: config.cameras[name].extrinsic for name in config.camera_names}
    try:
        fit = _fitted(recordings, config, start, args.no_progress, target)
    except CalibrationError as error:
        raise CalibrateCommandError(str(error)) from error
    report = _report(args, recordings, start, fit, config, target)
    _write(args, rough_text, fit, report, recordings, config, target)
    return report


def _target(args: argparse.Namespace):
    """The --target mesh, sampled (core.calibration.target.RigidTarget); a file open3d cannot read, or one without
    triangles, is refused."""
    import open3d as o3d

    from ntcr_recon.core.calibration.target import RigidTarget

    if not args.target.is_file():
        raise CalibrateCommandError(f"no target mesh at {args.target}")
    mesh = o3d.io.read_triangle_mesh(str(args.target))
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    if not len(triangles):
        raise CalibrateCommandError(f"the target {args.target} has no triangles (a .ply, .stl or .obj mesh is needed)")
    try:
        return RigidTarget.from_mesh(vertices * (1e-3 if args.target_unit == "mm" else 1.0), triangles)
    except ValueError as error:
        raise CalibrateCommandError(f"the target {args.target}: {error}") from error


def _recordings(args: argparse.Namespace, config, target=None) -> list:
    """Each bag's recording (core.calibration.recordings), with a progress bar over the frames read."""
    from tqdm import tqdm

    from ntcr_recon.core.calibration.recordings import MAX_POINTS, recording_from_frames
    from ntcr_recon.io.bag import BagError, iter_camera_frames

    rng = np.random.default_rng(0)
    recordings = []
    box = None if target is None else (target.samples.min(axis=0), target.samples.max(axis=0))
    with tqdm(desc="frames read", unit="frame", disable=args.no_progress) as bar:
        for bag, straight in [*((bag, True) for bag in args.straight), *((bag, False) for bag in args.bags)]:
            frames = iter_camera_frames(bag, config, source="depth")
            try:
                recordings.append(recording_from_frames(str(bag), _counted(frames, bar), config, rng,
                                                        args.max_points or MAX_POINTS, straight, box))
            except BagError as error:
                raise CalibrateCommandError(str(error)) from error
    return recordings


def _counted(items, bar):
    """The items, the progress bar moved on by each."""
    for item in items:
        bar.update()
        yield item


def _fitted(recordings: list, config, start: dict, no_progress: bool, target=None):
    from tqdm import tqdm

    from ntcr_recon.core.calibration.rig_fit import SCALES_M, fit_rig

    with tqdm(total=len(SCALES_M), desc="fitting rounds", unit="round", disable=no_progress) as bar:
        return fit_rig(recordings, config.robot, start, progress=lambda _: bar.update(), target=target)


def _by_axis(values: np.ndarray) -> dict[str, float]:
    return {axis: round(float(v), 5) for axis, v in zip("xyz", values, strict=True)}


def _moved(start: np.ndarray, end: np.ndarray, pivot: np.ndarray) -> dict[str, float]:
    """How far a pose moved: the turn's angle (deg) and the shift of the robot's middle (mm) as the camera saw it."""
    from ntcr_recon.core.calibration.rig_fit import pose_change

    change = pose_change(start, end, pivot)
    return {"turn_deg": round(float(np.linalg.norm(change[:3])), 5),
            "shift_mm": round(float(np.linalg.norm(change[3:])), 5)}


def _report(args: argparse.Namespace, recordings: list, start: dict, fit, config, target=None) -> dict:
    from ntcr_recon.core.calibration.rig_fit import pivot_of
    from ntcr_recon.io.rig_file import pose_values

    pivot = pivot_of(config.robot) if target is None else target.centre  # what the turns are about
    cameras = {}
    for name, extrinsic in fit.extrinsics.items():
        sigma = fit.uncertainty[name]
        cameras[name] = {**pose_values(extrinsic), "start": pose_values(start[name]),
                         "moved": _moved(start[name], extrinsic, pivot),
                         "uncertainty": {"turn_deg": _by_axis(sigma[:3]), "shift_mm": _by_axis(sigma[3:])},
                         "residual_mm": round(fit.residual_mm[name], 5),
                         "start_residual_mm": round(fit.start_residual_mm[name], 5),
                         "inliers": round(fit.inliers[name], 4)}
    names = list(fit.extrinsics)
    relative = {"camera": names[1], "to": names[0],
                "uncertainty": {"turn_deg": _by_axis(fit.relative_uncertainty[:3]),
                                "shift_mm": _by_axis(fit.relative_uncertainty[3:])}} if len(names) > 1 else None
    bags = [{"bag": r.name, "points": {n: len(p) for n, p in r.points.items()}, "pixels": r.pixels,
             "bends_deg": [round(float(b), 4) for b in np.degrees(fit.bends[r.name])],
             "total_bend_deg": round(float(np.degrees(np.sum(fit.bends[r.name]))), 3), "straight": r.straight}
            for r in recordings]
    warnings = [{"code": "CAMERA_FACES_SLOTS", "camera": name, "angle_deg": round(angle, 2),
                 "message": f"{name} looks into the notches' slots ({angle:.0f} deg off the side they open to): its "
                            "depth there reads the slots' floors smeared into the spines, and its pose along its "
                            "view may be off by a millimetre; record the robot turned in its clamp so that the "
                            "notches open sideways to both cameras"}
                for name, angle in fit.facing_slots.items()]
    return {"config": str(args.config), "target": None if args.target is None else str(args.target),
            "pivot_m": [float(v) for v in pivot], "cameras": cameras,
            "relative": relative, "recordings": bags, "warnings": warnings,
            "uncertainty_is": "1-sigma, from the fit's covariance; "
                              "without a matcher's depth bias along each camera's view"}


def _write(args: argparse.Namespace, rough_text: str, fit, report: dict, recordings: list, config,
           target=None) -> None:
    from ntcr_recon.core.base.transforms import transform_points
    from ntcr_recon.core.calibration.tube_distance import tube_distance
    from ntcr_recon.core.robot.kinematics import TubeShape
    from ntcr_recon.io.figures import calibration_views
    from ntcr_recon.io.files import write_atomically
    from ntcr_recon.io.rig_file import replace_poses

    json_path, figure_path = report_paths(args.out)
    text = replace_poses(rough_text, fit.extrinsics)
    write_atomically(json_path, lambda temp: Path(temp).write_text(json.dumps(report, indent=1) + "\n"))
    centerlines, before, after = [], {name: [] for name in config.camera_names}, {name: [] for name in
                                                                               config.camera_names}
    for recording in recordings:
        shape = TubeShape(config.robot, fit.bends[recording.name])
        centerlines.append(shape.centerline(np.linspace(0.0, shape.length, 200))[0] if target is None
                           else target.samples[::max(len(target.samples) // 2000, 1)])
        for name, optical in recording.points.items():
            fitted = transform_points(fit.extrinsics[name], optical[:FIGURE_POINTS])
            # the robot's (the target's) points only, as the fit placed them: the post and the backdrop would hide it
            model = tube_distance(shape, fitted) if target is None else target.distance(fitted)
            robot = np.abs(model.distance) < FIGURE_BAND_M
            before[name].append(transform_points(config.cameras[name].extrinsic, optical[:FIGURE_POINTS][robot]))
            after[name].append(fitted[robot])
    before = {name: np.concatenate(parts) for name, parts in before.items()}
    after = {name: np.concatenate(parts) for name, parts in after.items()}
    calibration_views(figure_path, before, after, centerlines, as_points=target is not None)
    write_atomically(args.out, lambda temp: Path(temp).write_text(text))  # last: the rig file means "done"
