"""Ground truth of a simulated scene: `<bag_dir>/ground_truth.json` (the document `truth_document` builds).

Public API:
    truth_document(shape, cameras, intrinsics, scene, seed, base_frame, extra=None) -> dict
    load_truth(path_or_bag_dir) -> (TubeShape, dict)
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ntcr_recon.core.base.transforms import matrix_to_quaternion
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.sim.camera import CameraPose, D405Intrinsics

TRUTH_FILE = "ground_truth.json"
CENTERLINE_STEP = 0.05e-3  # dense centreline: at most this far apart along the arc (contract: <= 0.1 mm)


def truth_document(shape: TubeShape, cameras: list[CameraPose], intrinsics: D405Intrinsics, scene: str, seed: int,
                   base_frame: str = "ntcr_base", extra: dict | None = None) -> dict:
    robot = shape.geometry.to_dict()
    robot["notch_depth"] = shape.geometry.cut_depth  # resolved, so the file stands alone
    count = int(math.ceil(shape.length / CENTERLINE_STEP)) + 1
    s = np.linspace(0.0, shape.length, count)
    centerline, _ = shape.centerline(s)
    tip_position, tip_frame = shape.tip_pose()
    document = {
        "scene": scene,
        "seed": int(seed),
        "base_frame": base_frame,
        "robot": robot,
        "notch_bend_rad": [float(b) for b in shape.notch_bend],
        "centerline_s_m": s.tolist(),
        "centerline_m": centerline.tolist(),
        "tip": {"position_m": tip_position.tolist(), "orientation_xyzw": matrix_to_quaternion(tip_frame).tolist()},
        "notches": [{"index": n["index"], "center_s_m": n["center_s"], "width_m": n["width"], "bend_rad": n["bend"]}
                    for n in shape.notch_table()],
        "cameras": {
            camera.name: {"frame_id": camera.frame_id, "translation": camera.translation.tolist(),
                          "rotation": camera.quaternion.tolist(), "width": intrinsics.width,
                          "height": intrinsics.height, "fx": intrinsics.fx, "fy": intrinsics.fy,
                          "cx": intrinsics.cx, "cy": intrinsics.cy, "depth_unit": intrinsics.depth_unit}
            for camera in cameras
        },
    }
    if extra:
        document.update(extra)
    return document


def load_truth(path_or_bag_dir: str | Path) -> tuple[TubeShape, dict]:
    """The posed robot and the document of a ground-truth file (or of a bag directory that holds one)."""
    path = Path(path_or_bag_dir)
    if path.is_dir():
        path = path / TRUTH_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no ground truth at {path}")
    try:
        document = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON: {error}") from error
    for key in ("robot", "notch_bend_rad"):
        if key not in document:
            raise ValueError(f"{path} has no '{key}'")
    geometry = TubeGeometry.from_mapping(document["robot"])
    return TubeShape.from_notch_bends(geometry, document["notch_bend_rad"]), document
