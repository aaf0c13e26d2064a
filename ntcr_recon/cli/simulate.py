"""`ntcr-recon simulate`: render a synthetic dual-D405 scene into a rosbag2 (mcap) bag with ground truth."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from ntcr_recon.core.config.rig import ConfigError, load_robot_geometry
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.sim.camera import D405Intrinsics
from ntcr_recon.sim.imagers import ImagerModel
from ntcr_recon.sim.sgbm import SgbmParameters
from ntcr_recon.sim.simulate import MATCHERS, Simulation, check_bag_space, notch_side_angle
from ntcr_recon.sim.stereo import StereoEmulation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("output", type=Path, help="bag directory to create (rosbag2: metadata.yaml + .mcap, "
                        "plus ground_truth.json and rig.yaml)")
    pose = parser.add_mutually_exclusive_group()
    pose.add_argument("--bend-deg", type=float, default=0.0, help="total bend angle, shared evenly by the notches "
                      "(degrees, default 0: straight)")
    pose.add_argument("--tendon-pull-mm", type=float, help="tendon displacement per notch (mm)")
    pose.add_argument("--notch-bends-deg", type=str, help="comma-separated bend of each notch (degrees)")
    parser.add_argument("--robot", type=Path, metavar="YAML",
                        help="the robot to render: a rig configuration (its `robot` section) or a YAML mapping of "
                             "the robot's geometry fields (metres); default: the 3.5 mm, 16-notch sample robot")
    parser.add_argument("--notch-side", default=None, help="'side-on' (bending plane perpendicular to the "
                        "cameras' axis), 'facing' (notches face the first camera) or an angle in degrees about "
                        "the robot axis (default: the --robot file's notch_side, else side-on)")
    parser.add_argument("--camera-distance", type=float, default=0.09, metavar="M",
                        help="distance of each camera from the robot (metres, default 0.09)")
    parser.add_argument("--camera-distances", type=str, metavar="A,B",
                        help="distance of each camera (metres, comma-separated): an asymmetric rig")
    parser.add_argument("--camera-yaw-deg", type=str, metavar="A,B", default="0,0",
                        help="each camera turned about its image's down axis (degrees; default 0,0)")
    parser.add_argument("--camera-pitch-deg", type=str, metavar="A,B", default="0,0",
                        help="each camera turned about its image's right axis (degrees; default 0,0)")
    parser.add_argument("--intrinsics", type=str, metavar="W,H,FX,FY,CX,CY",
                        help="depth stream intrinsics (default: a D405 at 848x480)")
    parser.add_argument("--depth-unit", type=float, default=None, metavar="M",
                        help="metres per raw depth unit (default 0.0001, the D405's; realsense-ros uses 0.001)")
    parser.add_argument("--matcher", choices=MATCHERS, default="emulated",
                        help="where depth comes from: 'emulated' (default: the package's emulation of a D405's "
                        "matcher on the exact depth) or 'sgbm' (the left and right imagers rendered - shading, "
                        "highlights, a surface texture, blur, sensor noise - and matched by OpenCV's StereoSGBM; "
                        "the left image is the colour; slower); with sgbm --window is the block size (default 7), "
                        "--noise scales the sensor noise, --ideal takes it away, --color-noise does not apply")
    parser.add_argument("--window", type=int, default=None, help="stereo matching window, odd px (default 9)")
    parser.add_argument("--no-left-right-check", action="store_true",
                        help="a stereo matcher without the D405's left-right consistency check: surfaces the right "
                        "imager cannot see keep a depth instead of reading invalid (another matcher to judge the "
                        "reconstruction on than the one it was developed with)")
    parser.add_argument("--no-flying-pixels", action="store_true",
                        help="a stereo matcher whose pixels at depth edges are dropped or kept, never mixed with the "
                        "surface behind (no flying pixels): to tell what they cost the reconstruction")
    parser.add_argument("--seed", type=int, default=1, help="random seed (default 1): same seed, same bag")
    parser.add_argument("--frames", type=int, default=3, help="frames per camera (default 3)")
    parser.add_argument("--noise", type=float, default=1.0, help="stereo depth noise level: sigma_d = "
                        "0.08 px times this (default 1)")
    parser.add_argument("--color-noise", type=float, default=1.0, help="colour imager noise, sigma in 8-bit "
                        "levels (default 1; 0 keeps colour images small in a bag)")
    parser.add_argument("--ideal", action="store_true", help="no stereo artefacts at all: exact depth, quantised")
    parser.add_argument("--with-points", action="store_true", help="also write <ns>/<cam>/depth/color/points")
    parser.add_argument("--namespace", default="/ntcr", help="topic namespace (default /ntcr)")
    parser.add_argument("--cameras", default="cam_a,cam_b", help="the two camera names (default cam_a,cam_b)")
    parser.add_argument("--scene", help="scene name in the ground truth (default: the output directory's name)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def build_simulation(args: argparse.Namespace) -> Simulation:
    geometry = load_robot_geometry(args.robot) if args.robot else TubeGeometry()
    if args.notch_side is not None or args.robot is None:
        geometry = dataclasses.replace(geometry, notch_side=notch_side_angle(args.notch_side or "side-on"))
    if args.tendon_pull_mm is not None:
        shape = TubeShape.from_tendon_pull(geometry, args.tendon_pull_mm * 1e-3)
    elif args.notch_bends_deg:
        try:
            bends = [math.radians(float(v)) for v in args.notch_bends_deg.split(",")]
        except ValueError:
            raise ValueError("--notch-bends-deg must be comma-separated numbers, "
                             f"got {args.notch_bends_deg!r}") from None
        shape = TubeShape.from_notch_bends(geometry, bends)
    else:
        shape = TubeShape.from_bend_angle(geometry, math.radians(args.bend_deg))
    matcher = args.matcher
    imagers, sgbm = _real_matcher(args) if matcher == "sgbm" else (ImagerModel(), SgbmParameters())
    emulation = StereoEmulation.ideal() if args.ideal else StereoEmulation().scaled_noise(args.noise)
    if args.window is not None:
        emulation = dataclasses.replace(emulation, window=args.window)
    if args.no_left_right_check:
        emulation = dataclasses.replace(emulation, occlusion_check=False)
    if args.no_flying_pixels:
        emulation = dataclasses.replace(emulation, silhouette_mixing=0.0)
    intrinsics = D405Intrinsics()
    if args.intrinsics:
        width, height, fx, fy, cx, cy = _numbers("--intrinsics", args.intrinsics, 6)
        if not (width.is_integer() and height.is_integer()):
            raise ValueError(f"--intrinsics {args.intrinsics}: width and height are whole pixels")
        try:
            intrinsics = dataclasses.replace(intrinsics, width=int(width), height=int(height), fx=fx, fy=fy, cx=cx,
                                             cy=cy)
        except ValueError as error:
            raise ValueError(f"--intrinsics {args.intrinsics}: {error}") from None
    if args.depth_unit is not None:
        intrinsics = dataclasses.replace(intrinsics, depth_unit=args.depth_unit)
    if args.seed < 0:
        raise ValueError(f"--seed {args.seed}: must be >= 0")
    if args.frames < 1:
        raise ValueError(f"--frames {args.frames}: must be at least 1")
    # before anything is rendered or written: a bag that may not fit, or longer than a test scene needs
    check_bag_space(args.output, intrinsics, args.frames, 2, args.with_points)
    distances = tuple(_numbers("--camera-distances", args.camera_distances, 2)) if args.camera_distances else None
    return Simulation(shape, scene_name=args.scene or args.output.name, camera_distance=args.camera_distance,
                      camera_distances=distances, intrinsics=intrinsics,
                      camera_yaw_deg=tuple(_numbers("--camera-yaw-deg", args.camera_yaw_deg, 2)),
                      camera_pitch_deg=tuple(_numbers("--camera-pitch-deg", args.camera_pitch_deg, 2)),
                      camera_names=tuple(n.strip() for n in args.cameras.split(",")), namespace=args.namespace,
                      frame_count=args.frames, seed=args.seed, emulation=emulation,
                      color_noise=0.0 if args.ideal else args.color_noise, with_points=args.with_points,
                      matcher=matcher, imagers=imagers, sgbm=sgbm)


def _real_matcher(args: argparse.Namespace) -> tuple[ImagerModel, SgbmParameters]:
    """The imagers and the SGBM matcher of `--matcher sgbm`, with the options that apply to them."""
    if args.no_flying_pixels:
        raise ValueError("--no-flying-pixels is an option of the emulated matcher: a real one makes what flying "
                         "pixels it makes (drop --matcher sgbm or the option)")
    if not (math.isfinite(args.noise) and args.noise >= 0):
        raise ValueError(f"--noise {args.noise}: must be finite and >= 0")
    imagers = ImagerModel()
    imagers = dataclasses.replace(imagers, sensor_noise=0.0 if args.ideal else imagers.sensor_noise * args.noise)
    sgbm = SgbmParameters()
    if args.window is not None:
        sgbm = dataclasses.replace(sgbm, block_size=args.window)
    if args.no_left_right_check:
        sgbm = dataclasses.replace(sgbm, left_right_max_diff=-1)
    sgbm.validate()  # before Simulation validates the emulation's window: the message names the block size
    return imagers, sgbm


def _numbers(option: str, text: str, count: int) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"{option} must be {count} comma-separated numbers, got {text!r}") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{option} must be {count} comma-separated numbers, got {text!r}")
    return values


def main(args: argparse.Namespace) -> int:
    from ntcr_recon.io.staging import StagingError

    try:
        simulation = build_simulation(args)
        path = simulation.write_bag(args.output, overwrite=args.overwrite, progress=not args.no_progress)
    except (ValueError, ConfigError, FileExistsError, StagingError) as error:
        print(f"ntcr-recon simulate: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # a disk that filled up after all, a folder that became read-only: nothing was kept
        print(f"ntcr-recon simulate: error: writing {args.output}: {error.strerror or error} (nothing was written)",
              file=sys.stderr)
        return 2
    camera, near, where = simulation.nearest_approach()
    if near < simulation.intrinsics.min_depth:
        print(f"ntcr-recon simulate: warning: the robot comes within {near * 1e3:.1f} mm of {camera} (at "
              f"{where * 1e3:.1f} mm along it), nearer than the simulated D405's minimum depth "
              f"({simulation.intrinsics.min_depth * 1e3:.0f} mm): it reads no depth there", file=sys.stderr)
    tip, _ = simulation.shape.tip_pose()
    print(f"wrote {path}: {simulation.frame_count} frames x {len(simulation.cameras)} cameras, "
          f"bend {math.degrees(simulation.shape.notch_bend.sum()):.1f} deg, tip at "
          f"({', '.join(f'{v * 1e3:.2f}' for v in tip)}) mm")
    return 0
