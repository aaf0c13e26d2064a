"""`ntcr-recon render BAG --out PNG`: a bag's depth frames colour-mapped and its raw fused cloud from the side.

The cloud is the two cameras' depth deprojected and moved into the base frame with the rig configuration's
extrinsics (BAG/rig.yaml unless --config), cropped to the box around the robot; nothing else is done to it,
so the artefacts of the cameras (flattened faces, flying pixels) show.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory")
    parser.add_argument("--out", type=Path, required=True, help="PNG file to write")
    parser.add_argument("--config", type=Path, help="rig configuration (default: BAG/rig.yaml)")
    parser.add_argument("--frame", type=int, default=0, help="which frame of each camera (default 0)")


def _frame(bag: Path, camera: str, topics, index: int):
    from ntcr_recon.io.camera_sources import BagSource

    for i, frame in enumerate(BagSource(bag, camera, topics)):
        if i == index and frame.depth is not None:
            return frame
    raise ValueError(f"bag {bag} has no depth frame {index} of camera {camera}")


def render_bag(bag: Path, out: Path, config_path: Path | None = None, frame_index: int = 0) -> dict:
    """Draw the PNG; returns per camera the number of cloud points drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ntcr_recon.core.base.transforms import transform_points
    from ntcr_recon.core.cloud.deproject import crop_window, depth_to_points
    from ntcr_recon.core.cloud.filters import crop_mask
    from ntcr_recon.core.config.rig import load_rig_config

    config = load_rig_config(config_path or bag / "rig.yaml")
    box_min, box_max = config.crop_box()
    names = list(config.camera_names)
    figure = plt.figure(figsize=(14, 4.2 * len(names)), dpi=90)
    grid = figure.add_gridspec(len(names), 3, width_ratios=[1.6, 1, 1])
    side, end = figure.add_subplot(grid[:, 1]), figure.add_subplot(grid[:, 2])
    counts = {}
    for row, (name, color) in enumerate(zip(names, ("tab:red", "tab:blue", "tab:green", "tab:orange"),
                                             strict=False)):
        camera = config.cameras[name]
        frame = _frame(bag, name, config.topics, frame_index)
        unit = frame.depth_unit or camera.depth_unit
        depth_m = frame.depth.astype(np.float64) * unit
        xyz, *_ = depth_to_points(frame.depth, frame.intrinsics, unit,
                                 window=crop_window(frame.intrinsics, camera.extrinsic, box_min, box_max),
                                 ramp_step=config.flying_pixel_step)
        points = transform_points(camera.extrinsic, xyz)
        inside = crop_mask(points, config, viewpoints=camera.translation)
        points = points[inside]
        counts[name] = len(points)
        axis = figure.add_subplot(grid[row, 0])
        valid = depth_m > 0
        # colour range: the depths of the points around the robot
        near, far = np.percentile(xyz[inside, 2], [1, 99]) if inside.any() else (0.0, 1.0)
        shown = np.ma.masked_where(~valid, depth_m * 1e3)
        image = axis.imshow(shown, cmap="turbo", vmin=near * 1e3, vmax=max(far, near + 1e-3) * 1e3)
        axis.set_title(f"{name} depth, frame {frame_index} (mm; black = invalid)")
        axis.set_facecolor("black")
        figure.colorbar(image, ax=axis, fraction=0.025)
        side.scatter(points[:, 0] * 1e3, points[:, 2] * 1e3, s=0.2, c=color, label=f"{name} ({len(points)})")
        end.scatter(points[:, 1] * 1e3, points[:, 2] * 1e3, s=0.2, c=color)
    for axis, horizontal in ((side, "x"), (end, "y")):
        axis.set_xlabel(f"base {horizontal} (mm)")
        axis.set_ylabel("base z (mm)")
        axis.set_aspect("equal")
        axis.grid(alpha=0.3)
    side.set_title("raw fused cloud, side (along base y)")
    end.set_title("raw fused cloud, along base x")
    side.legend(markerscale=20, loc="lower right")
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    temporary = out.with_name(f".{out.name}.tmp.png")
    figure.savefig(temporary)
    plt.close(figure)
    temporary.replace(out)
    return counts


def main(args: argparse.Namespace) -> int:
    try:
        counts = render_bag(args.bag, args.out, args.config, args.frame)
    except (ValueError, OSError, RuntimeError) as error:  # RuntimeError: the bag source's SourceError
        print(f"ntcr-recon render: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: " + ", ".join(f"{name} {count} points" for name, count in counts.items()))
    return 0
