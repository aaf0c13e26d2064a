"""`ntcr-recon reconstruct BAG --config RIG.yaml --out DIR`: a bag in, the reconstructed robot out.

Streams the cameras' depth images (or PointCloud2) from a rosbag2 bag: each frame is decoded, paired with
the other camera's by stamp as they come, run through fusion, filtering and relocation
(core.reconstruction.reconstructor.Reconstructor) and released, so memory does not grow with the bag's length; a
pair without a result (the robot out of view, say) is left out and named in a warning, and only a bag of which no
pair gives one is refused, with the first pair's cause. The frames over which the robot stood still longest
(reconstruction.still: all of them when it never moved, else the longest stretch, the latest of equals, and a
warning says so) are then
combined (at most COMBINED_FRAMES_MAX of them, evenly spread over the stretch) into one relocated cloud, meshed
and measured, and DIR gets:

    relocated.ply  fused_raw.ply  mesh.ply  mesh.stl  result.json
    density_heatmaps.png  notch_widths.png  side_views.png

DIR is built whole in a staging directory beside it and swapped in by one rename (io.staging), so a reader
sees the old result or the new one and a failure leaves DIR as it was. An existing DIR holding anything but
those files (not a previous result) is refused unless --overwrite: it would be replaced whole.
result.json (lengths in the unit its key names):

    {"status": "ok" | "warn" | "error"  (core.quality.findings: ok only with every notch found, every stated
                                          uncertainty within the rig's quality tolerances and no warn/error),
     "frames", "frames_combined": {"first", "last", "count"} (1-based frame pairs), "notch_count_expected",
     "notches": [{"index", "center_s_mm", "width_mm", "width_uncertainty_mm", "bend_deg"}],
     "centerline_m", "tip_m", "pdc": {"raw": {"mu", "sigma", "lambda"}, "relocated": {...}},
     "quality": {"uncertainty_mm": {"centerline", "tip", "notch_width"} (90 % bounds), notches found /
                 expected / by signal, length seen per camera, fit residual, notch side, centreline bias, depth
                 step, ...}  (core.quality.checks),
     "ground_truth": null | {"notches_detected", "width_mae_mm", "centerline_rmse_mm", "tip_error_mm",
                             "surface_error_mm": {"raw", "relocated"}},
     "timings_ms": {stage: median ms per frame pair, or ms for the combined steps},
     "warnings": [{"code", "severity": "info" | "warn" | "error", "message", ...figures}]}
        # what makes the result less trustworthy (codes: core.quality.findings.CODES, the README's table), printed on
        # stderr errors first

Ground truth comes from `ground_truth.json` inside the bag directory when there is one (simulated bags).
Exit status: 0 done, 2 bad configuration / bag / reconstruction (one message on stderr naming the cause).
"""

from __future__ import annotations

import argparse
import errno
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# Frames combined into the final relocated cloud: a still robot gains little from more, and keeping each
# frame's cloud would make memory grow with the bag. Longer bags keep this many (down to half), evenly spread.
COMBINED_FRAMES_MAX = 32

OUTPUT_FILES = ("relocated.ply", "fused_raw.ply", "mesh.ply", "mesh.stl", "result.json", "density_heatmaps.png",
                "notch_widths.png", "side_views.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory (or .mcap file)")
    parser.add_argument("--config", type=Path, default=None,
                        help="rig configuration (ROS 2 parameter file); default: rig.yaml inside the bag directory")
    parser.add_argument("--out", required=True, help="output directory (replaced whole when the run succeeds; one "
                                                     "holding other files than a previous result's is refused)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace --out even when it holds other files than a previous result's")
    parser.add_argument("--source", choices=("auto", "depth", "points"), default="auto",
                        help="read depth images or PointCloud2 (auto: depth when the bag has them)")
    parser.add_argument("--topic", action="append", default=[], metavar="CAM.KIND=TOPIC",
                        help="remap a camera topic, e.g. cam_a.depth=/cam_a/depth/image_rect_raw "
                             "(kinds: depth, depth_info, color, points); repeatable")
    parser.add_argument("--max-frames", type=_positive_int, default=None, metavar="N",
                        help="use only the first N frames of each camera (N >= 1; default: all)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace) -> int:
    try:
        result = run(args)
    except ReconstructCommandError as failure:
        print(f"ntcr-recon reconstruct: error: {failure}", file=sys.stderr)
        return 2
    quality = result.get("quality") or {}
    if quality:
        print(f"ntcr-recon reconstruct: {quality['notches_found']} of {quality['notches_expected']} notches "
              f"(by signal: {quality['notches_by_signal']}), notch side {quality['notch_side_deg']:.1f} deg "
              f"(configured {quality['notch_side_configured_deg']:.1f}), centreline bias towards the notch side "
              f"{quality['centerline_bias_mm']['notch_side']:+.3f} mm (removed), centreline uncertain by "
              f"{_millimetres(quality.get('centerline_uncertainty_mm'))}, tip by "
              f"{_millimetres(quality.get('tip_uncertainty_mm'))} along the tube and "
              f"{_millimetres(quality.get('tip_across_uncertainty_mm'))} across it; the cameras place the axis "
              f"{_millimetres(quality.get('cameras_across_view_offset_mm'))} apart across their views"
              f"{_as_turn(quality.get('cameras_across_view_turn_deg'))}", file=sys.stderr)
    for warning in result["warnings"]:  # errors first (core.quality.findings.sort_by_severity)
        print(f"ntcr-recon reconstruct: {warning['severity']}: [{warning['code']}] {warning['message']}",
              file=sys.stderr)
    print(f"ntcr-recon reconstruct: status {result['status']}", file=sys.stderr)
    return 0


def _as_turn(degrees: float | None) -> str:
    return "" if degrees is None else f" (a turn of one camera by {degrees:.3f} deg)"


def _positive_int(text: str) -> int:
    """argparse type of --max-frames: 0 read as 'all' and -3 as 'no depth frame' before (issue 66)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of frames, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (leave it out to use every frame), got {value}")
    return value


def _millimetres(value: float | None) -> str:
    return "(not measured)" if value is None else f"{value:.2f} mm"


class ReconstructCommandError(Exception):
    """Stops the command with one message."""


def run(args: argparse.Namespace) -> dict:
    """The whole command; raises ReconstructCommandError with the cause. Returns the result document."""
    from ntcr_recon.core.config.rig import ConfigError, load_rig_config
    from ntcr_recon.core.reconstruction.reconstructor import ReconstructionError
    from ntcr_recon.io.bag import BagError, bag_problem
    from ntcr_recon.io.staging import StagingError, staged_directory

    problem = bag_problem(args.bag)
    if problem:  # said before anything starts (the progress bar, the output directory)
        raise ReconstructCommandError(problem)
    config_path = args.config if args.config is not None else _bag_dir(args.bag) / "rig.yaml"
    try:
        config = load_rig_config(config_path)
    except ConfigError as error:  # an unreadable file says so itself; a bad one is named as such
        unreadable = isinstance(error.__cause__, OSError)
        raise ReconstructCommandError(str(error) if unreadable else f"bad rig configuration: {error}") from error
    overrides = _topic_overrides(args.topic, config)
    try:
        with staged_directory(args.out) as staging:  # refuses a target no directory may replace (root, ...)
            if not args.overwrite:
                _refuse_other_files(Path(args.out))
            return _reconstruct(args, config, overrides, staging)
    except StagingError as error:
        raise ReconstructCommandError(f"--out: {error}") from error
    except (BagError, ReconstructionError, ValueError) as error:
        raise ReconstructCommandError(str(error)) from error
    except OSError as error:  # a full disk, a folder made read-only meanwhile: named as --out, not its staging
        raise ReconstructCommandError(_output_error(args.out, error)) from error


def _topic_overrides(items: list[str], config) -> dict[str, str]:
    """--topic CAM.KIND=TOPIC (or OLD_TOPIC=TOPIC) items checked against the rig: a camera or kind it does not
    have, or a topic it does not read, remapped nothing and was accepted silently (issue 66)."""
    from ntcr_recon.io.bag import camera_topics

    kinds = ("depth", "depth_info", "color", "points")
    configured = {topic for name in config.camera_names for topic in camera_topics(config, name).values()}
    overrides = {}
    for item in items:
        key, sep, topic = item.partition("=")
        if not sep or not key or not topic:
            raise ReconstructCommandError(f"--topic expects CAM.KIND=TOPIC, got {item!r}")
        if key.startswith("/"):
            if key not in configured:
                raise ReconstructCommandError(f"--topic {item}: the rig reads no topic {key} "
                                              f"(it reads {', '.join(sorted(configured))})")
        else:
            camera, dot, kind = key.partition(".")
            if camera not in config.camera_names:
                raise ReconstructCommandError(f"--topic {item}: the rig has no camera {camera!r} "
                                              f"(cameras: {', '.join(config.camera_names)})")
            if not dot or kind not in kinds:
                raise ReconstructCommandError(f"--topic {item}: kind must be one of {', '.join(kinds)}, "
                                              f"got {kind!r}")
        overrides[key] = topic
    return overrides


def _output_error(out, error: OSError) -> str:
    """An output error named by --out (the files are written in a staging directory beside it, whose name
    means nothing to the user), the file being written when known; --out itself is left as it was."""
    name = Path(error.filename).name if error.filename else None
    cause = error.strerror or str(error)
    if error.errno == errno.ENOSPC:
        cause = "no space left on the device"
    return (f"--out {out}: could not write {name + ' there' if name else 'the result'}: {cause} "
            f"(--out is left as it was)")


def _refuse_other_files(out: Path) -> None:
    """ReconstructCommandError when an existing output directory holds entries a reconstruction does not write:
    the user's own files, which replacing it whole would delete."""
    others = sorted(entry.name for entry in out.iterdir() if entry.name not in OUTPUT_FILES) if out.is_dir() else []
    if others:
        shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
        raise ReconstructCommandError(f"--out: {out} holds {shown}, which this command did not write, and it would "
                                      "be replaced whole: choose another directory or pass --overwrite")


def _bag_dir(bag: Path) -> Path:
    return bag if bag.is_dir() else bag.parent


@dataclass
class _Streamed:
    """What the frame loop leaves: the frames the result combines and what the input showed."""

    combined: object  # StillStretch of (fused, filtered) clouds
    cameras: dict  # camera -> CameraInput
    pair_count: int = 0
    one_camera_pairs: int = 0
    failed: list = field(default_factory=list)  # why each frame pair without a result gave none
    timings: dict = field(default_factory=dict)  # median ms per stage


def _stream_frames(args, config, overrides: dict, reconstructor) -> _Streamed:
    """Every frame pair through the chain, keeping only the frames of the still stretch the result combines."""
    from tqdm import tqdm

    from ntcr_recon.core.cloud.pairing import pair_frame_stream
    from ntcr_recon.core.quality.inputs import input_warnings
    from ntcr_recon.core.reconstruction.reconstructor import ReconstructionError
    from ntcr_recon.core.reconstruction.still import StillStretch, stated_tip_uncertainty
    from ntcr_recon.io.bag import iter_camera_frames

    streamed = _Streamed(StillStretch(COMBINED_FRAMES_MAX), {})
    cameras = streamed.cameras  # filled as the frames stream by
    frames = iter_camera_frames(args.bag, config, args.source, overrides, args.max_frames or 0, cameras)
    pairs = pair_frame_stream(frames, int(round(config.fusion.slop * 1e9)),
                              int(round(config.fusion.camera_timeout * 1e9)))
    per_stage: dict[str, list[float]] = {}
    for pair in tqdm(pairs, desc="frame pairs", unit="pair", disable=args.no_progress):
        streamed.pair_count += 1
        streamed.one_camera_pairs += len(pair.frames) == 1
        try:
            frame = reconstructor.process(pair)
        except ReconstructionError as error:  # left out, and said so (the error itself when no pair gives one)
            streamed.failed.append(f"frame pair {streamed.pair_count} (stamp {pair.stamp_ns}): {error}")
            continue
        for index, count in zip(*np.unique(frame.fused.camera, return_counts=True), strict=True):
            cameras[config.camera_names[index]].fused_points += int(count)
        streamed.combined.offer(streamed.pair_count - 1, frame.relocation.tip,
                                stated_tip_uncertainty(frame.relocation.quality), (frame.fused, frame.filtered))
        for stage, ms in frame.timings_ms.items():
            per_stage.setdefault(stage, []).append(ms)
        del frame, pair  # the decoded images go now, not when the next pair replaces them
    failed = streamed.failed
    if failed and streamed.combined.last is None:  # say what the input showed: it often is the cause
        warnings = input_warnings(config, cameras, streamed.pair_count, streamed.one_camera_pairs)
        others = len(failed) - 1
        raise ReconstructionError(failed[0] + ("" if not others else " (and so did the other frame pair)" if others == 1
                                               else f" (and so did the other {others} frame pairs)")
                                  + "".join(f"; {w}" for w in warnings))
    streamed.timings = {stage: float(np.median(values)) for stage, values in per_stage.items()}
    return streamed


def _reconstruct(args, config, overrides: dict, staging: Path) -> dict:
    from tqdm import tqdm

    from ntcr_recon.core.cloud.points import Cloud
    from ntcr_recon.core.quality.findings import finding, result_status, sort_by_severity
    from ntcr_recon.core.quality.inputs import input_warnings
    from ntcr_recon.core.quality.metrics import pdc
    from ntcr_recon.core.reconstruction.reconstructor import ReconstructionError, Reconstructor

    started = time.perf_counter()
    reconstructor = Reconstructor(config)
    streamed = _stream_frames(args, config, overrides, reconstructor)
    combined, cameras, timings, failed = streamed.combined, streamed.cameras, streamed.timings, streamed.failed
    steps = tqdm(total=4, desc="combine, mesh, measure", disable=args.no_progress)
    raw = Cloud.concatenate([fused for fused, _ in combined.items()])
    try:
        relocation = reconstructor.relocate(Cloud.concatenate([filtered for _, filtered in combined.items()]))
        if not len(relocation.relocated):
            raise ReconstructionError(f"relocation kept none of the {len(relocation.coordinates.s)} filtered "
                                      "points (none lies near the reference surface): nothing to mesh")
    except ReconstructionError as error:  # the input's faults first: they are the likely cause
        warnings = input_warnings(config, cameras, streamed.pair_count, streamed.one_camera_pairs)
        raise ReconstructionError(str(error) + "".join(f"; {w}" for w in warnings)) from error
    for index, count in zip(*np.unique(relocation.relocated.camera, return_counts=True), strict=True):
        cameras[config.camera_names[index]].relocated_points = int(count)
    # what the input lacks, the frames left out, then what the relocation's self-check found (core.quality.checks)
    left_out = ([finding("FRAMES_LEFT_OUT", f"{len(failed)} of {streamed.pair_count} frame pairs gave no result "
                         f"and are left out; {failed[0]}", pairs=len(failed), of=streamed.pair_count)]
                if failed else [])
    moved = combined.warning("frame pair")
    warnings = sort_by_severity(input_warnings(config, cameras, streamed.pair_count, streamed.one_camera_pairs)
                                + left_out + ([moved] if moved else []) + list(relocation.warnings))
    quality = relocation.quality
    timings["relocate_combined"] = reconstructor.timings_ms["relocate"]
    steps.update()
    mesh = reconstructor.mesh(relocation)
    timings["mesh"] = reconstructor.timings_ms["mesh"]
    steps.update()

    geometry = config.robot
    voxel = config.metrics.pdc_voxel
    result = {
        "status": result_status(warnings, quality, config.quality),
        "frames": streamed.pair_count,
        "frames_combined": {"first": combined.first + 1, "last": combined.last + 1, "count": len(combined.items())},
        "notch_count_expected": geometry.notch_count,
        "notches": [{"index": n.index, "center_s_mm": n.center_s * 1e3, "width_mm": n.width * 1e3,
                     "width_uncertainty_mm": quality["notch_width_uncertainty_mm"][str(n.index)],
                     "bend_deg": None if n.bend is None else float(np.degrees(n.bend))} for n in relocation.notches],
        "centerline_m": relocation.centerline.points.tolist(),
        "tip_m": relocation.tip.tolist(),
        "pdc": {"raw": pdc(raw.xyz, voxel), "relocated": pdc(relocation.relocated.xyz, voxel)},
        "ground_truth": _ground_truth(args.bag, raw, relocation),
        "quality": quality,      # the self-check (core.quality.checks), from the data alone
        "warnings": [warning.as_dict() for warning in warnings],
    }
    steps.update()
    _write_files(staging, config, raw, relocation, mesh, result)
    steps.update()
    steps.close()
    timings["total"] = (time.perf_counter() - started) * 1e3
    result["timings_ms"] = timings
    text = json.dumps(result, indent=1)
    (staging / "result.json").write_text(text)
    return result


def _write_files(staging: Path, config, raw, relocation, mesh, result: dict) -> None:
    """The clouds, the mesh and the figures beside result.json (the ground truth's widths taken out of it)."""
    from ntcr_recon.io import figures
    from ntcr_recon.io.files import write_cloud_ply, write_mesh

    geometry, voxel = config.robot, config.metrics.pdc_voxel
    write_cloud_ply(staging / "relocated.ply", relocation.relocated.xyz, relocation.relocated.rgb,
                    relocation.normals)
    write_cloud_ply(staging / "fused_raw.ply", raw.xyz, raw.rgb)
    write_mesh(staging / "mesh.ply", mesh)
    write_mesh(staging / "mesh.stl", mesh)
    view = _view_axes(geometry)
    figures.density_heatmaps(staging / "density_heatmaps.png", raw.xyz, relocation.relocated.xyz, view, voxel,
                             VIEW_AXIS_LABELS)
    truth_widths = None
    if result["ground_truth"] is not None:
        truth_widths = result["ground_truth"].pop("_widths_mm")
    figures.notch_width_plot(staging / "notch_widths.png", [n["width_mm"] for n in result["notches"]],
                             geometry.notch_width * 1e3, truth_widths, [n["index"] for n in result["notches"]])
    mesh_title = "Poisson mesh" if config.mesh.method == "poisson" else "tube-grid mesh"
    figures.side_views(staging / "side_views.png", raw.xyz, relocation.relocated.xyz, mesh, view, mesh_title,
                       VIEW_AXIS_LABELS)


# what _view_axes' two directions are, for the figures' axes
VIEW_AXIS_LABELS = ("towards the configured notch side (mm)", "along the robot's base axis (mm)")


def _view_axes(geometry) -> np.ndarray:
    """The bending plane: the robot's notch side and its axis, in the base frame."""
    from ntcr_recon.core.relocation.centerline import base_pose

    _, axis, binormal = base_pose(geometry)
    return np.stack([np.cross(binormal, axis), axis])


def _ground_truth(bag: Path, raw, relocation) -> dict | None:
    from ntcr_recon.core.quality.metrics import centerline_rmse, notch_width_errors

    truth_file = _bag_dir(Path(bag)) / "ground_truth.json"
    if not truth_file.exists():
        return None
    from ntcr_recon.sim.truth import load_truth

    shape, document = load_truth(truth_file)
    detected, measured, true = notch_width_errors(relocation.notches, document["notches"])
    by_index = {int(n["index"]): n["width_m"] * 1e3 for n in document["notches"]}
    return {
        "notches_detected": detected,
        "width_mae_mm": float(np.mean(np.abs(measured - true))) * 1e3 if detected else None,
        "centerline_rmse_mm": centerline_rmse(relocation.centerline.points, np.asarray(document["centerline_m"])) * 1e3,
        "tip_error_mm": float(np.linalg.norm(relocation.tip - np.asarray(document["tip"]["position_m"]))) * 1e3,
        "surface_error_mm": {"raw": float(np.mean(shape.surface_distance(raw.xyz))) * 1e3,
                             "relocated": float(np.mean(shape.surface_distance(relocation.relocated.xyz))) * 1e3},
        "_widths_mm": [by_index.get(n.index) for n in relocation.notches],
    }
