"""A tiny two-camera rig for node tests: a rig configuration and small rosbag2 bags written with rosbags.

The scene is a straight tube (the configured robot's outer radius) along the base z axis, seen by cam_a from
-y and cam_b from +y at 90 mm, rendered by ray casting into small depth images (coarse on purpose: the node
tests check conversion and plumbing, the sample bags carry the realistic frames).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ntcr_recon.core.base.transforms import rigid_transform
from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.io.pointcloud import ROSBAGS, cloud_to_msg
from ntcr_recon.ros.messages import RCLPY

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
T = TYPESTORE.types
INTRINSICS = Intrinsics(width=96, height=72, fx=300.0, fy=300.0, cx=47.5, cy=35.5)
DEPTH_UNIT = 1e-4
OUTER_RADIUS = 1.75e-3
CAMERAS = {  # pose of the optical frame in the base frame: optical z towards the robot
    "cam_a": ([0.0, -0.09, 0.02], [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]),
    "cam_b": ([0.0, 0.09, 0.02], [0.7071067811865476, 0.0, 0.0, 0.7071067811865476]),
}


def rig_parameters(**sections) -> dict:
    params = {"base_frame": "ntcr_base", "camera_names": list(CAMERAS)}
    for name, (translation, rotation) in CAMERAS.items():
        params[name] = {"width": INTRINSICS.width, "height": INTRINSICS.height, "fps": 30, "depth_unit": DEPTH_UNIT,
                        "frame_id": f"{name}_optical_frame", "translation": translation, "rotation": rotation}
    params["robot"] = {"outer_diameter": 2 * OUTER_RADIUS, "inner_diameter": 2.5e-3, "notch_count": 16}
    params.update(sections)
    return params


def write_rig(path: Path, **sections) -> Path:
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": rig_parameters(**sections)}}))
    return path


def render_tube(camera: str, radius: float = OUTER_RADIUS, length: float = 0.05) -> np.ndarray:
    """Depth in metres (0 = no return) of the tube x^2 + y^2 = r^2, 0 <= z <= length, seen by `camera`."""
    extrinsic = rigid_transform(*CAMERAS[camera])
    u, v = np.meshgrid(np.arange(INTRINSICS.width), np.arange(INTRINSICS.height))
    rays = np.stack([(u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy,
                     np.ones_like(u, float)], axis=-1)  # z = 1: the ray parameter is the depth
    origin = extrinsic[:3, 3]
    direction = rays @ extrinsic[:3, :3].T
    a = direction[..., 0] ** 2 + direction[..., 1] ** 2
    b = 2 * (origin[0] * direction[..., 0] + origin[1] * direction[..., 1])
    c = origin[0] ** 2 + origin[1] ** 2 - radius**2
    disc = b**2 - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    z_base = origin[2] + t * direction[..., 2]
    hit = (disc > 0) & (t > 0) & (z_base >= 0) & (z_base <= length)
    return np.where(hit, t, 0.0)


def image(array: np.ndarray, encoding: str, frame_id: str, stamp_ns: int):
    channels = 1 if array.ndim == 2 else array.shape[2]
    return T["sensor_msgs/msg/Image"](
        header=_header(frame_id, stamp_ns), height=array.shape[0], width=array.shape[1], encoding=encoding,
        is_bigendian=0, step=array.shape[1] * channels * array.dtype.itemsize,
        data=np.ascontiguousarray(array).view(np.uint8).reshape(-1))


def camera_info(frame_id: str, stamp_ns: int):
    i = INTRINSICS
    return T["sensor_msgs/msg/CameraInfo"](
        header=_header(frame_id, stamp_ns), height=i.height, width=i.width, distortion_model="plumb_bob",
        d=np.zeros(5), k=np.array([i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1.0]), r=np.eye(3).reshape(-1),
        p=np.array([i.fx, 0, i.cx, 0, 0, i.fy, i.cy, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def _header(frame_id: str, stamp_ns: int):
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id)


def frame_color(camera: str, index: int) -> np.ndarray:
    color = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    color[..., 0] = 40 * index % 256
    color[..., 1] = np.arange(INTRINSICS.width, dtype=np.uint8)[None, :]
    color[..., 2] = 200 if camera == "cam_a" else 100
    return color


def write_bag(path: Path, frames: int = 10, fps: float = 30.0, encoding: str = "16UC1", cameras=tuple(CAMERAS),
              color: bool = True, points_only: bool = False, start_ns: int = 1_000_000_000,
              skew_ns: dict[str, int] | None = None, depth_unit: float = DEPTH_UNIT) -> Path:
    """A rosbag2 (mcap) bag with realsense-ros topics for `cameras`; stamps at `fps` from `start_ns`.

    16UC1 depth is in `depth_unit` (DEPTH_UNIT unless given), 32FC1 in metres. `points_only`: only
    `.../depth/color/points` per camera (the clouds a realsense-ros rig records). `skew_ns` shifts one
    camera's stamps (no hardware sync).
    """
    period = int(round(1e9 / fps))
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for camera in cameras:
            prefix = f"/ntcr/{camera}"
            kinds = {"points": ("depth/color/points", "sensor_msgs/msg/PointCloud2")} if points_only else {
                "info": ("depth/camera_info", "sensor_msgs/msg/CameraInfo"),
                "depth": ("depth/image_rect_raw", "sensor_msgs/msg/Image"),
                **({"color": ("color/image_rect_raw", "sensor_msgs/msg/Image")} if color else {})}
            for kind, (topic, msgtype) in kinds.items():
                connections[camera, kind] = writer.add_connection(f"{prefix}/{topic}", msgtype, typestore=TYPESTORE)
        for index in range(frames):
            for camera in cameras:
                stamp = start_ns + index * period + (skew_ns or {}).get(camera, 0)
                frame_id = f"{camera}_optical_frame"
                depth_m = render_tube(camera)
                messages = {}
                if points_only:
                    from ntcr_recon.core.cloud.deproject import depth_to_points
                    xyz, rgb, _ = depth_to_points(depth_m, INTRINSICS, 1.0, frame_color(camera, index))
                    messages["points"] = cloud_to_msg(xyz, rgb, frame_id=frame_id, stamp_ns=stamp, msgtypes=ROSBAGS)
                else:
                    messages["info"] = camera_info(frame_id, stamp)
                    depth = (np.round(depth_m / depth_unit).astype(np.uint16) if encoding == "16UC1"
                             else depth_m.astype(np.float32))
                    messages["depth"] = image(depth, encoding, frame_id, stamp)
                    if color:
                        messages["color"] = image(frame_color(camera, index), "rgb8", frame_id, stamp)
                for kind, msg in messages.items():
                    connection = connections[camera, kind]
                    writer.write(connection, stamp, TYPESTORE.serialize_cdr(msg, connection.msgtype))
    return path


# ---- inputs for the stage nodes (rclpy messages) --------------------------------------------------------------

MALFORMED = ("short_data", "no_z_field", "nan_only", "empty", "wrong_frame")


def malformed_cloud(defect: str, frame_id: str, stamp_ns: int):
    """A PointCloud2 with one defect; `frame_id` is the frame the node expects (wrong_frame uses another)."""
    xyz = np.random.default_rng(0).uniform(-1e-3, 1e-3, size=(50, 3))
    msg = cloud_to_msg(xyz, msgtypes=RCLPY, frame_id=frame_id, stamp_ns=stamp_ns)
    if defect == "short_data":
        msg.data = bytes(msg.data)[:100]
    elif defect == "no_z_field":
        msg.fields = [f for f in msg.fields if f.name != "z"]
    elif defect == "nan_only":
        msg = cloud_to_msg(np.full_like(xyz, np.nan), msgtypes=RCLPY, frame_id=frame_id, stamp_ns=stamp_ns)
    elif defect == "empty":
        msg = cloud_to_msg(np.empty((0, 3)), msgtypes=RCLPY, frame_id=frame_id, stamp_ns=stamp_ns)
    elif defect == "wrong_frame":
        msg.header.frame_id = "some_other_frame"
    return msg


# What a node logs for each defect.
MALFORMED_LOG = {"short_data": "width*height*point_step", "no_z_field": "no field z",
                 "wrong_frame": "in frame 'some_other_frame'", "nan_only": "no finite point",
                 "empty": "empty cloud"}


# ---- a realistic scene from the simulator, made once per test session -----------------------------------------

def simulated_bag(tmp_path_factory, frames: int = 2, bend_deg: float = 45.0) -> Path:
    """A bag of the simulated rig (848x480 D405 frames of a bent NTCR, ground truth and rig.yaml beside it),
    written once per session and shared by the test modules that need realistic frames."""
    import subprocess
    import sys

    path = tmp_path_factory.getbasetemp() / f"sim_bend{bend_deg:g}_{frames}"
    if not (path / "metadata.yaml").exists():
        subprocess.run([str(Path(sys.executable).parent / "ntcr-recon"), "simulate", str(path), "--bend-deg",
                        str(bend_deg), "--frames", str(frames), "--no-progress", "--overwrite"],
                       check=True, capture_output=True, timeout=120)
    return path


def bag_frame_pairs(bag: Path, config) -> list:
    """The bag's frame pairs as the offline command pairs them (the core's bag reader, not camera_node's)."""
    from ntcr_recon.core.cloud.pairing import pair_frames
    from ntcr_recon.io.bag import read_camera_frames

    return pair_frames(read_camera_frames(bag, config), int(config.fusion.slop * 1e9))
