"""A simulated dual-D405 recording: the scene, its frames, the rig configuration and the ground truth.

Public API:
    Simulation(shape, camera_distance=0.09, ...)    # everything a scene needs; deterministic from `seed`
    Simulation.frames(progress=False) -> iterator of bag.CameraFrame (camera by camera, frame by frame)
    Simulation.rig_parameters() -> dict             # the ROS parameter file written as <bag>/rig.yaml
    Simulation.truth() -> dict                      # the ground-truth document (<bag>/ground_truth.json)
    Simulation.nearest_approach() -> (camera, depth, s)  # where the robot comes nearest a camera
    Simulation.write_bag(out_dir, overwrite=False, progress=True) -> Path
    notch_side_angle("side-on" | "facing" | degrees) -> radians
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import yaml

from ntcr_recon.core.quality.measures import surface_depth
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.sim.bag import BagContents, CameraFrame, write_rig_bag
from ntcr_recon.sim.camera import CameraPose, D405Intrinsics, facing_pair
from ntcr_recon.sim.imagers import ImagerModel
from ntcr_recon.sim.scene import ExactFrame, RigProps, Scene
from ntcr_recon.sim.sgbm import SgbmParameters
from ntcr_recon.sim.stereo import StereoEmulation, emulate_depth
from ntcr_recon.sim.truth import TRUTH_FILE, truth_document

RIG_FILE = "rig.yaml"
START_STAMP_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z: fixed, so a seed gives the same bag
CAMERA_STAGGER_NS = 4_300_000  # no hardware sync: each further camera's frames come this much later
STAMP_JITTER_NS = 300_000  # +- per frame, from the seed
CLAMP_EDGE_MARGIN = 1.0e-3  # filters.clamp_radius: the post's radius and this (depth edges fly)
MAX_FRAMES = 10_000  # frames per camera: 5.5 min at 30 Hz; a bag longer than that is not a test scene
DISK_RESERVE_BYTES = 64 * 2**20  # left free on the output's file system beyond the bag's estimate
MATCHERS = ("emulated", "sgbm")  # depth from the emulation of an exact image, or OpenCV's SGBM on rendered imagers


def _size(count: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if count < 1000:
            return f"{count:.1f} {unit}"
        count /= 1000
    return f"{count:.1f} TB"


def estimated_bag_bytes(intrinsics: D405Intrinsics, frames: int, cameras: int, with_points: bool) -> int:
    """The most a bag can take (its messages before compression: depth 2 bytes, colour 3 a pixel, the cloud 16
    a point, every camera's every frame)."""
    per_frame = intrinsics.width * intrinsics.height * (2 + 3 + (16 if with_points else 0)) + 4096  # + headers
    return per_frame * frames * cameras


def check_bag_space(out_dir: str | Path, intrinsics: D405Intrinsics, frames: int, cameras: int,
                    with_points: bool) -> None:
    """ValueError naming the bag's estimate and the free space when the one may exceed the other, and when
    `frames` exceeds MAX_FRAMES (with both figures too)."""
    where = _existing_ancestor(Path(out_dir).parent)
    free = shutil.disk_usage(where).free
    needed = estimated_bag_bytes(intrinsics, frames, cameras, with_points)
    sizes = (f"{frames} frames x {cameras} cameras at {intrinsics.width}x{intrinsics.height} may take up to "
             f"{_size(needed)} and {where} has {_size(free)} free")
    if frames > MAX_FRAMES:
        raise ValueError(f"--frames {frames}: at most {MAX_FRAMES} frames per camera ({MAX_FRAMES / 30 / 60:.1f} min "
                         f"at 30 Hz) are rendered; {sizes}")
    if needed + DISK_RESERVE_BYTES > free:
        raise ValueError(f"--frames {frames}: {sizes} (keeping {_size(DISK_RESERVE_BYTES)}): render fewer frames "
                         "or write elsewhere")


def _existing_ancestor(path: Path) -> Path:
    path = Path(path).absolute()
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


def notch_side_angle(value: str) -> float:
    """The notch side in the robot base pose (radians) for the rig of `facing_pair`.

    "side-on": the notches open towards +x, so the robot bends in the x-z plane, perpendicular to the
    cameras' viewing axis (y); "facing": the notches face the first camera (at -y); a number: degrees.
    """
    if value == "side-on":
        return 0.0
    if value == "facing":
        return -math.pi / 2
    try:
        return math.radians(float(value))
    except ValueError:
        raise ValueError(f"notch side must be 'side-on', 'facing' or an angle in degrees, got {value!r}") from None


@dataclass
class Simulation:
    shape: TubeShape
    scene_name: str = "scene"
    camera_distance: float = 0.09
    camera_names: tuple[str, ...] = ("cam_a", "cam_b")
    namespace: str = "/ntcr"
    base_frame: str = "ntcr_base"
    frame_count: int = 3
    seed: int = 1
    emulation: StereoEmulation = field(default_factory=StereoEmulation)
    color_noise: float = 1.0  # 8-bit levels, sigma of the colour imager's noise
    with_points: bool = False
    intrinsics: D405Intrinsics = field(default_factory=D405Intrinsics)
    props: RigProps = field(default_factory=RigProps)
    camera_distances: tuple[float, float] | None = None  # per camera, overrides camera_distance (asymmetric rig)
    camera_yaw_deg: tuple[float, float] = (0.0, 0.0)     # per camera, turned about its image's down axis
    camera_pitch_deg: tuple[float, float] = (0.0, 0.0)   # per camera, turned about its image's right axis
    matcher: str = "emulated"  # MATCHERS; sgbm renders the imagers (`imagers`) and matches them (`sgbm`)
    imagers: ImagerModel = field(default_factory=ImagerModel)
    sgbm: SgbmParameters = field(default_factory=SgbmParameters)

    def __post_init__(self) -> None:
        if not 1 <= self.frame_count <= MAX_FRAMES:
            raise ValueError(f"frames must be 1 to {MAX_FRAMES} per camera, got {self.frame_count}")
        if len(self.camera_names) != 2 or len(set(self.camera_names)) != 2 or not all(self.camera_names):
            raise ValueError(f"the rig has two cameras with distinct names, got {self.camera_names}")
        if not (math.isfinite(self.color_noise) and self.color_noise >= 0):
            raise ValueError(f"colour noise must be finite and >= 0, got {self.color_noise}")
        self.emulation.validate()
        if self.matcher not in MATCHERS:
            raise ValueError(f"matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        if self.matcher == "sgbm":
            self.imagers.validate()
            self.sgbm.validate()
        self.cameras: list[CameraPose] = facing_pair(self.camera_distance, names=self.camera_names,
                                                     distances=self.camera_distances, yaw_deg=self.camera_yaw_deg,
                                                     pitch_deg=self.camera_pitch_deg)
        self.scene = Scene(self.shape, self.cameras, self.intrinsics, self.props)
        self._check_rig()
        clearance, where = self.scene.props_clearance()
        if clearance < 0:
            raise ValueError(f"the robot passes {-clearance * 1e3:.2f} mm into its clamp post or the table at "
                             f"{where * 1e3:.1f} mm along it: no rig holds this pose (bend it less)")

    def _check_rig(self) -> None:
        """The rig.yaml this scene writes, checked by the rig schema before anything is rendered: a value its
        loader refuses (a depth unit of 0, say) made a bag that no reader could use."""
        from ntcr_recon.core.config.rig import ConfigError, rig_config_from_mapping

        try:
            rig_config_from_mapping(self.rig_parameters()["/**"]["ros__parameters"])
        except ConfigError as error:
            raise ValueError(f"the bag's rig configuration would be refused: {error}") from error

    @cached_property
    def exact(self) -> dict[str, ExactFrame]:
        """The artefact-free rendering of each camera (the scene is static)."""
        return {camera.name: self.scene.render_exact(camera) for camera in self.cameras}

    @cached_property
    def imager_pairs(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each camera's left and right imagers' clean images (the scene is static; each frame exposes them)."""
        from ntcr_recon.sim.imagers import render_pair

        return {camera.name: render_pair(self.scene, camera, self.imagers) for camera in self.cameras}

    def _depth_and_color(self, camera: CameraPose, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One frame of a camera: raw depth and colour, by the emulation or by the real matcher."""
        if self.matcher == "sgbm":
            from ntcr_recon.sim.sgbm import matched_frame

            return matched_frame(self.imager_pairs[camera.name], self.intrinsics, self.sgbm,
                                 self.imagers.sensor_noise, rng)
        exact = self.exact[camera.name]
        depth = emulate_depth(exact.depth, exact.normal, self.intrinsics, self.emulation, rng)
        color = exact.color
        if self.color_noise > 0:
            noisy = exact.color + rng.normal(0.0, self.color_noise, exact.color.shape)
            color = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        return depth, color

    def frames(self, progress: bool = False) -> Iterator[CameraFrame]:
        from tqdm import tqdm

        period_ns = round(1e9 / self.intrinsics.fps)
        steps = [(k, i) for k in range(self.frame_count) for i in range(len(self.cameras))]
        for k, i in tqdm(steps, desc=f"rendering {self.scene_name}", unit="frame", disable=not progress):
            camera = self.cameras[i]
            rng = np.random.default_rng([self.seed, i, k])  # independent per camera and frame
            jitter = int(rng.integers(-STAMP_JITTER_NS, STAMP_JITTER_NS + 1))
            stamp = START_STAMP_NS + k * period_ns + i * CAMERA_STAGGER_NS + jitter
            depth, color = self._depth_and_color(camera, rng)
            yield CameraFrame(camera, stamp, depth, color)

    def rig_parameters(self) -> dict:
        """The rig configuration (ROS 2 parameter file) of this scene: cameras, topics, robot, and the post of a
        robot reaching below its base plane."""
        parameters: dict = {"base_frame": self.base_frame, "camera_names": list(self.camera_names),
                            "topics": {"namespace": self.namespace}}
        for camera in self.cameras:
            parameters[camera.name] = {
                "serial_number": "", "width": self.intrinsics.width, "height": self.intrinsics.height,
                "fps": self.intrinsics.fps, "depth_unit": self.intrinsics.depth_unit, "frame_id": camera.frame_id,
                "translation": [float(v) for v in camera.translation],
                "rotation": [float(v) for v in camera.quaternion]}
        robot = self.shape.geometry.to_dict()
        robot["notch_depth"] = self.shape.geometry.cut_depth  # ROS parameters have no null
        parameters["robot"] = robot
        # a robot whose wall reaches below its base plane needs the crop box to reach there, less the post it
        # stands on (its radius, with a millimetre for the flying pixels at its edges): as its user would set it
        radius = self.shape.geometry.outer_radius
        s = np.linspace(2 * radius, self.shape.length, 512)  # past the base, which stands on the plane
        if self.shape.centerline(s)[0][:, 2].min() < radius:
            parameters["filters"] = {"clamp_radius": self.props.post_radius + CLAMP_EDGE_MARGIN}
        return {"/**": {"ros__parameters": parameters}}

    def nearest_approach(self) -> tuple[str, float, float]:
        """The camera the robot comes nearest, the depth (m, along its optical axis) of the robot's surface
        nearest it, and where along the robot (s, m): bent, a robot may come nearer a camera than it stands."""
        s = np.linspace(0.0, self.shape.length, 1024)
        positions, frames = self.shape.centerline(s)
        nearest = []
        for camera in self.cameras:
            depth = surface_depth(positions, frames[:, :, 2], camera.extrinsic, self.shape.geometry.outer_radius)
            nearest.append((float(depth.min()), camera.name, float(s[np.argmin(depth)])))
        depth, name, where = min(nearest)
        return name, depth, where

    def truth(self) -> dict:
        extra = {"emulation": {**self.emulation.to_dict(), "color_noise": self.color_noise,
                               "baseline": self.intrinsics.baseline, "min_depth": self.intrinsics.min_depth,
                               "max_depth": self.intrinsics.max_depth},
                 "camera_distance_m": self.camera_distance,
                 "camera_distances_m": list(self.camera_distances or (self.camera_distance,) * 2),
                 "camera_yaw_deg": list(self.camera_yaw_deg), "camera_pitch_deg": list(self.camera_pitch_deg),
                 "frames": self.frame_count,
                 "namespace": self.namespace}
        if self.matcher == "sgbm":  # (an emulated bag's truth is as it was)
            extra["matcher"] = {"name": "sgbm", "sgbm": self.sgbm.to_dict(), "imagers": self.imagers.to_dict()}
        return truth_document(self.shape, self.cameras, self.intrinsics, self.scene_name, self.seed,
                              self.base_frame, extra)

    def check_space(self, out_dir: str | Path) -> None:
        """ValueError naming both figures when the bag may not fit the free space where it goes: rendering
        then fails after minutes or hours, having filled the disk first (issue 66)."""
        check_bag_space(out_dir, self.intrinsics, self.frame_count, len(self.cameras), self.with_points)

    def write_bag(self, out_dir: str | Path, overwrite: bool = False, progress: bool = True) -> Path:
        import json

        self.check_space(out_dir)

        header = (f"# Rig configuration of the simulated scene '{self.scene_name}' (written by ntcr-recon simulate).\n"
                  "# Camera poses are exact; stage sections (fusion, filters, ...) take their defaults, but for a\n"
                  "# robot reaching below its base plane filters.clamp_radius (its post's).\n")
        rig_text = header + yaml.safe_dump(self.rig_parameters(), sort_keys=False, default_flow_style=None)
        files = {TRUTH_FILE: json.dumps(self.truth(), indent=1) + "\n", RIG_FILE: rig_text}
        contents = BagContents(self.namespace, self.intrinsics, self.frames(progress), self.with_points)
        return write_rig_bag(out_dir, contents, files, overwrite=overwrite)
