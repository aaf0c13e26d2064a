"""The rig configuration: a ROS 2 parameter file read by the CLI, the benchmark and every node.

Layout (config/sim_rig.yaml is the documented example, generated from this schema by `config.document`)::

    /**:
      ros__parameters:
        base_frame: ntcr_base
        camera_names: [cam_a, cam_b]
        cam_a: {CameraConfig keys}
        cam_b: {...}
        robot: {TubeGeometry keys}
        topics: {...}  fusion: {...}  filters: {...}  relocation: {...}  mesh: {...}  metrics: {...}
        quality: {...}  calibration: {...}

Every key is declared once, below (and TubeGeometry's in `geometry`), with its default, unit, range and
description (`schema.setting`); loading, the nodes' parameter descriptors and the documented file all read
those declarations. The camera and robot sections are required; every key of the stage sections has a default,
so a real rig's file needs only what differs. Nothing robot-specific is a default in millimetres: gates, bins and
smoothing lengths are fractions of the robot's outer radius or multiples of the camera's pixel footprint (the
size of one depth pixel on the robot, measured from the data).

    load_rig_config(path) -> RigConfig            # ConfigError (a ValueError) naming the file and dotted key
    rig_config_from_mapping(mapping) -> RigConfig # the same from the `ros__parameters` mapping (nested or dotted)
    load_robot_geometry(path) -> TubeGeometry     # a robot description file, or a rig file's robot section
    flatten_parameters(RigConfig | dict) -> dict  # dotted names -> value, for nodes to declare (config.parameters)
    unflatten_parameters(dict) -> dict            # the inverse, for nodes that read declared parameters
    rig_parameter_keys(camera_names) -> dict      # dotted name -> schema Key, the nodes' descriptors (parameters)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ntcr_recon.core.base.schema import (
    ConfigError,
    Key,
    build_section,
    convert,
    excerpt,
    keys_of,
    setting,
    unknown_key_error,
)
from ntcr_recon.core.base.transforms import rigid_transform
from ntcr_recon.core.config.reader import read_config_document
from ntcr_recon.core.robot.geometry import TubeGeometry

__all__ = ["CameraConfig", "ConfigError", "FilterConfig", "FusionConfig", "MeshConfig", "MetricsConfig",
           "RelocationConfig", "RigConfig", "TopicConfig", "load_rig_config", "load_robot_geometry",
           "rig_config_from_mapping", "unflatten_parameters"]

_WITHIN_A_LAB = {"minimum": -10.0, "maximum": 10.0}  # m: positions in the base frame


@dataclass(frozen=True)
class CameraConfig:
    """One depth camera, in a section named after it in camera_names: its stream profile and the pose of its
    optical frame in the base frame."""

    name: str
    serial_number: str = setting("", "serial number of the D405 (rs-enumerate-devices); '' = the only one "
                                 "connected", max_length=64)
    width: int = setting(848, "depth stream width", unit="px", minimum=1, maximum=4096)
    height: int = setting(480, "depth stream height", unit="px", minimum=1, maximum=4096)
    fps: float = setting(30.0, "depth stream frame rate", unit="Hz", minimum=0.0, maximum=1000.0,
                         exclusive_minimum=True)
    depth_unit: float = setting(1e-4, "metres per raw 16UC1 depth unit (D405 default 0.0001; realsense-ros "
                                "recordings: 0.001)", unit="m", minimum=0.0, maximum=1.0, exclusive_minimum=True,
                                required=True)
    frame_id: str = setting("", "frame of the camera's clouds; '' = <camera>_optical_frame")
    translation: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), "position of the optical frame in the base frame (p_base = R p_cam + t)", unit="m",
        required=True, **_WITHIN_A_LAB)
    rotation: tuple[float, float, float, float] = setting(
        (0.0, 0.0, 0.0, 1.0), "orientation of the optical frame in the base frame, a unit quaternion (x, y, z, w)",
        required=True)

    @cached_property
    def extrinsic(self) -> np.ndarray:
        """4x4 transform taking points of the optical frame into the base frame (Eq. 9); computed once, as
        fusion asks every frame (read-only, as it is shared)."""
        matrix = rigid_transform(self.translation, self.rotation)
        matrix.flags.writeable = False
        return matrix


@dataclass(frozen=True)
class TopicConfig:
    """Topic names: <namespace>/<camera>/<kind>, the realsense-ros layout."""

    namespace: str = setting("/ntcr", "namespace of every topic")
    depth: str = setting("depth/image_rect_raw", "depth image (16UC1 raw units or 32FC1 metres)")
    depth_info: str = setting("depth/camera_info", "depth camera intrinsics")
    color: str = setting("color/image_rect_raw", "colour image")
    color_info: str = setting("color/camera_info", "colour camera intrinsics (camera_node: of the window it publishes)")
    points: str = setting("depth/color/points", "a camera's coloured cloud")

    def camera_topic(self, camera: str, kind: str) -> str:
        parts = (part.strip("/") for part in (self.namespace, camera, getattr(self, kind)))
        return "/" + "/".join(part for part in parts if part)


@dataclass(frozen=True)
class FusionConfig:
    """Pairing the two cameras' frames by stamp."""

    slop: float = setting(0.015, "two cameras' frames pair when their stamps differ by at most this", unit="s",
                          minimum=0.0, maximum=1.0, exclusive_minimum=True)
    camera_timeout: float = setting(0.5, "fusion_node publishes one camera alone after the other is silent this "
                                    "long", unit="s", minimum=0.0, maximum=3600.0, exclusive_minimum=True)


@dataclass(frozen=True)
class FilterConfig:
    """Conditional filters on space and colour, statistical outlier removal, moving least squares, voxels."""

    crop_box_auto: bool = setting(True, "crop to the robot's reach on its side of the base (no per-rig tuning); "
                                  "false: crop_box_min / crop_box_max")
    crop_box_min: tuple[float, float, float] = setting((0.0, 0.0, 0.0), "crop box corner, base frame", unit="m",
                                                       **_WITHIN_A_LAB)
    crop_box_max: tuple[float, float, float] = setting((0.0, 0.0, 0.0), "crop box corner, base frame", unit="m",
                                                       **_WITHIN_A_LAB)
    clamp_radius: float = setting(0.0, "> 0: the automatic crop box reaches below the robot's base plane too (a "
                                  "robot bent past 90 deg), and a cylinder of this radius about the base's axis "
                                  "below that plane is kept out, with what it hides from each camera - the clamp "
                                  "or post the robot stands on, with a millimetre for the flying pixels at its "
                                  "edges; 0: the box starts at the base plane", unit="m", minimum=0.0, maximum=1.0)
    flying_pixels: bool = setting(True, "drop the flying pixels of depth images: a pixel stepping by more than the "
                                  "robot's outer radius to both neighbours along its row or column, the same way "
                                  "(a stereo matcher's mix of the robot with the background behind it)")
    color_filter: bool = setting(False, "keep only points whose 8-bit R, G, B lie within [color_min, color_max]")
    color_min: tuple[int, int, int] = setting((0, 0, 0), "lowest R, G, B kept", minimum=0, maximum=255)
    color_max: tuple[int, int, int] = setting((255, 255, 255), "highest R, G, B kept", minimum=0, maximum=255)
    sor: bool = setting(True, "statistical outlier removal (paper Eq. 5)")
    sor_neighbors: int = setting(12, "neighbours of a point's mean neighbour distance", minimum=2, maximum=100)
    sor_alpha: float = setting(2.0, "drop points whose mean neighbour distance exceeds mu + alpha sigma",
                               minimum=0.0, maximum=100.0, exclusive_minimum=True)
    mls: bool = setting(True, "moving least squares smoothing (paper Eq. 6)")
    mls_order: int = setting(2, "1 = local plane, 2 = local quadric", choices=(1, 2))
    mls_neighbors: int = setting(12, "neighbours of the local fit (at least 3 mls_order + 1)", minimum=1,
                                 maximum=200)
    mls_radius_px: float = setting(0.0, "> 0: only neighbours within this many pixel footprints; 0 = any",
                                   unit="px", minimum=0.0, maximum=1000.0)
    voxel_size: float = setting(0.0, "voxel downsampling; 0 = none", unit="m", minimum=1e-5, maximum=0.1, off=0.0)


@dataclass(frozen=True)
class RelocationConfig:
    """Reference-guided relocation; lengths relative to the outer radius r_o or to the pixel footprint. gate =
    gate_radius_fraction r_o + gate_pixels footprints: a point this close to the reference surface is relocated."""

    method: str = setting("centerline", "how observed points reach the reference surface: centerline (the "
                          "tube's own coordinates, each point along its viewing ray onto the wall) or icp (the "
                          "paper's KD-tree + ICP of a reference, then each point onto its nearest reference point)",
                          choices=("centerline", "icp"))
    reference_mesh: str = setting("", "method icp: a PLY/STL of the robot in the base frame ('' = the configured "
                                  "robot posed by the estimated centreline)", max_length=4096)
    limbs: bool = setting(True, "place the axis across each camera's view by the tube's limbs in its colour image "
                          "(core.relocation.limbs; camera_node then publishes the colour about the robot, and "
                          "relocation_node waits for it); false: by depth alone")
    model_fit: bool = setting(False, "fit the robot's own model (its roll and a bend per notch: core.fit.robot_fit) "
                              "to the points and limbs, and relocate about its axis; false: the free centreline's")
    gate_radius_fraction: float = setting(0.35, "gate, in outer radii", minimum=0.0, maximum=10.0,
                                          exclusive_minimum=True)
    gate_pixels: float = setting(2.0, "gate, in pixel footprints (added)", unit="px", minimum=0.0, maximum=100.0)
    bin_radius_fraction: float = setting(0.25, "centreline slab length, in outer radii (at least 2 footprints)",
                                         minimum=0.0, maximum=10.0, exclusive_minimum=True)
    smoothing_radius_fraction: float = setting(1.0, "centreline smoothing length along s, in outer radii",
                                               minimum=0.0, maximum=100.0, exclusive_minimum=True)
    max_iterations: int = setting(12, "centreline iterations at most", minimum=1, maximum=1000)
    tolerance_radius_fraction: float = setting(0.01, "stop when the centreline moves less than this (RMS), in "
                                               "outer radii", minimum=0.0, maximum=1.0, exclusive_minimum=True)
    notch_kernel_px: float = setting(0.5, "kernel of the notch coverage profile along s", unit="px", minimum=0.0,
                                     maximum=100.0, exclusive_minimum=True)
    min_notch_width_fraction: float = setting(0.25, "coverage gaps narrower than this * notch_width are not "
                                              "notches", minimum=0.0, maximum=1.0)
    roi_margin_fraction: float = setting(0.1, "next frame: deproject only around the robot's last box grown by "
                                         "this fraction of its length (the whole crop box when the robot is not "
                                         "found there, or reaches its side)", minimum=0.0, maximum=10.0,
                                         exclusive_minimum=True)
    icp_iterations: int = setting(20, "method icp: ICP iterations at most (the paper's Eq. 10-11)", minimum=1,
                                  maximum=1000)


@dataclass(frozen=True)
class MeshConfig:
    """Meshing the relocated cloud."""

    method: str = setting("tube", "tube: the relocated outer wall meshed on the tube's (s, angle) grid, notches "
                          "open (ms); poisson: open3d screened Poisson, paper Eq. 7-8 (slower)",
                          choices=("tube", "poisson"))
    poisson_depth: int = setting(8, "octree depth of the Poisson solve (memory grows 8x a level)", minimum=1,
                                 maximum=12)
    density_quantile: float = setting(0.04, "trim the vertices of the lowest Poisson density quantile",
                                      minimum=0.0, maximum=1.0, exclusive_maximum=True)
    max_points: int = setting(60000, "voxel-thin the cloud to about this many points before meshing", minimum=1,
                              maximum=5_000_000)


@dataclass(frozen=True)
class MetricsConfig:
    """Analysis."""

    pdc_voxel: float = setting(0.5e-3, "voxel of the point density consistency (paper Table I)", unit="m",
                               minimum=1e-5, maximum=0.1)


@dataclass(frozen=True)
class QualityConfig:
    """What a result must be good to for its status to be ok (result.json `status`, /diagnostics level)."""

    centerline_tolerance: float = setting(0.08e-3, "the centreline's stated uncertainty (a 90 % bound on its RMS "
                                          "error) must not exceed this for status ok", unit="m", minimum=0.0,
                                          maximum=0.1, exclusive_minimum=True)
    tip_tolerance: float = setting(0.15e-3, "the tip's stated uncertainty (a 90 % bound on its distance from the "
                                   "true tip) must not exceed this for status ok", unit="m", minimum=0.0, maximum=0.1,
                                   exclusive_minimum=True)
    notch_width_tolerance: float = setting(0.20e-3, "every notch width's stated uncertainty (a 90 % bound) must not "
                                           "exceed this for status ok", unit="m", minimum=0.0, maximum=0.1,
                                           exclusive_minimum=True)


@dataclass(frozen=True)
class CalibrationConfig:
    """Refining the second camera's pose relative to the first from the robot as the graph runs (relocation_node;
    core.calibration.refine)."""

    refine: bool = setting(False, "relocation_node refines the second camera's pose relative to the first from the "
                           "robot (the model fit of `ntcr-recon calibrate`, the first camera held), reports it on "
                           "/diagnostics and writes it on request (service ~/write_calibration); needs the robot bent "
                           "30 deg or more in some frames")
    refine_frames: int = setting(4, "frames each refinement fits at once, spread over refine_period", minimum=1,
                                 maximum=50)
    refine_period: float = setting(30.0, "a refinement at most this often, over the frames of the last period",
                                   unit="s", minimum=1.0, maximum=86400.0)


@dataclass(frozen=True)
class RigConfig:
    """The whole rig: its frames and cameras, the robot, and the stages' parameters."""

    base_frame: str = setting("ntcr_base", "frame of the fused cloud and every later output; its +z is the "
                              "robot's unbent axis")
    camera_names: tuple[str, ...] = setting(("cam_a", "cam_b"), "the cameras, each with a section of camera keys "
                                            "named after it", required=True, max_length=64)
    cameras: dict[str, CameraConfig] = field(default_factory=dict)
    robot: TubeGeometry = field(default_factory=TubeGeometry)
    topics: TopicConfig = field(default_factory=TopicConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    filters: FilterConfig = field(default_factory=FilterConfig)
    relocation: RelocationConfig = field(default_factory=RelocationConfig)
    mesh: MeshConfig = field(default_factory=MeshConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    quality: QualityConfig = field(default_factory=QualityConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)

    @property
    def flying_pixel_step(self) -> float:
        """depth_to_points' ramp_step (m): the robot's outer radius, the whole relief its wall can show a
        camera (0: filters.flying_pixels off)."""
        return self.robot.outer_radius if self.filters.flying_pixels else 0.0

    @cached_property
    def camera_origins(self) -> np.ndarray:
        """(C, 3) each camera's optical centre in the base frame, in camera_names' order (read-only)."""
        origins = np.array([self.cameras[name].translation for name in self.camera_names], float)
        origins.flags.writeable = False
        return origins

    def crop_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The crop box (min, max) in the base frame, resolving `crop_box_auto` from the robot.

        Automatic: what the robot can reach - within its length (plus a diameter) of the base on the side its
        axis points to, starting at the base, so the clamp or post it stands on stays out; with
        `filters.clamp_radius` on both sides of the base plane (filters.crop_mask keeps the clamp out).
        """
        return self._crop_box

    @cached_property
    def _crop_box(self) -> tuple[np.ndarray, np.ndarray]:
        """crop_box(), computed once (each stage asks every frame; read-only, as it is shared)."""
        if not self.filters.crop_box_auto:
            low, high = np.array(self.filters.crop_box_min, float), np.array(self.filters.crop_box_max, float)
        else:
            reach = self.robot.reach
            below = -reach if self.filters.clamp_radius > 0 else 0.0
            corners = np.array(np.meshgrid([-reach, reach], [-reach, reach], [below, reach],
                                           indexing="ij")).reshape(3, -1)
            corners = (self.robot.base_rotation @ corners).T + np.asarray(self.robot.base_position, float)
            low, high = corners.min(axis=0), corners.max(axis=0)
        low.flags.writeable = high.flags.writeable = False
        return low, high


# Sections with defaults, in the order of the documented file (the cameras' and the robot's come before).
STAGE_SECTIONS = {
    "topics": TopicConfig,
    "fusion": FusionConfig,
    "filters": FilterConfig,
    "relocation": RelocationConfig,
    "mesh": MeshConfig,
    "metrics": MetricsConfig,
    "quality": QualityConfig,
    "calibration": CalibrationConfig,
}


def load_rig_config(path) -> RigConfig:
    """Read a ROS 2 parameter file (or a plain mapping file) and validate it."""
    path = Path(path)
    parameters = _read_parameters(path, "rig configuration")
    try:
        return rig_config_from_mapping(parameters)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def load_robot_geometry(path) -> TubeGeometry:
    """The robot of a YAML file: a rig configuration (its `robot` section) or a mapping of TubeGeometry
    fields alone. ConfigError names the file and the field."""
    path = Path(path)
    parameters = _read_parameters(path, "robot description")
    try:
        return TubeGeometry.from_mapping(parameters.get("robot", parameters))
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def _read_parameters(path: Path, what: str) -> Mapping:
    """The `ros__parameters` mapping of a parameter file (first node entry), or the document itself."""
    document = read_config_document(path, what, _is_text)
    if not isinstance(document, Mapping):
        kind = "an empty file" if document is None else f"a {type(document).__name__}"
        raise ConfigError(f"{path}: the {what} must be a mapping of keys, got {kind}")
    for value in document.values():
        if isinstance(value, Mapping) and "ros__parameters" in value:
            parameters = value["ros__parameters"]
            if not isinstance(parameters, Mapping):
                raise ConfigError(f"{path}: ros__parameters must be a mapping of keys, got {excerpt(parameters)}")
            return parameters
    return document


def _is_text(path: tuple[str, ...]) -> bool:
    """Whether the schema types the value at a key path as text (so the YAML reader keeps it as written).

    Paths start at the file's root; a parameter file's `<node>: ros__parameters:` prefix is skipped.
    """
    if "ros__parameters" in path:
        path = path[path.index("ros__parameters") + 1:]
    if path in (("base_frame",), ("camera_names", "[]")):
        return True
    if len(path) != 2 or path[0] == "robot":
        return False
    key = keys_of(STAGE_SECTIONS.get(path[0], CameraConfig)).get(path[1])
    return key is not None and key.scalar is str


def rig_config_from_mapping(parameters: Mapping) -> RigConfig:
    """Build and validate a RigConfig from nested (or dotted) parameters; ConfigError names the key."""
    if not isinstance(parameters, Mapping):
        raise ConfigError(f"the rig configuration must be a mapping of keys, got {excerpt(parameters)}")
    if any("." in str(key) for key in parameters):
        parameters = unflatten_parameters(parameters)
    top = keys_of(RigConfig)
    camera_names = _camera_names(parameters, top["camera_names"])
    known = {*top, *camera_names, "robot", *STAGE_SECTIONS}
    for key in parameters:
        if key not in known:
            raise unknown_key_error("", key, known)
    base_frame = convert("base_frame", top["base_frame"], parameters.get("base_frame", top["base_frame"].default))
    cameras = {name: _camera(name, _require(parameters, name)) for name in camera_names}
    robot = TubeGeometry.from_mapping(_require(parameters, "robot"))
    sections = {name: build_section(cls, _optional(parameters, name), name) for name, cls in STAGE_SECTIONS.items()}
    config = RigConfig(base_frame=base_frame, camera_names=camera_names, cameras=cameras, robot=robot, **sections)
    _check_consistency(config)
    return config


def _require(mapping: Mapping, key: str) -> Any:
    if mapping.get(key) is None:
        raise ConfigError(f"missing key {key!r}")
    return mapping[key]


def _optional(mapping: Mapping, key: str) -> Any:
    value = mapping.get(key)
    return {} if value is None else value


def _camera_names(parameters: Mapping, key: Key) -> tuple[str, ...]:
    names = _require(parameters, "camera_names")
    if not isinstance(names, list | tuple) or not names or not all(isinstance(n, str) and n for n in names):
        raise ConfigError(f"camera_names must be a non-empty list of camera names, got {excerpt(names)}")
    names = tuple(convert("camera_names", dataclasses.replace(key, length=len(names)), names))
    if len(set(names)) != len(names):
        raise ConfigError("camera_names has duplicates")
    clash = [name for name in names if name in keys_of(RigConfig) or name in STAGE_SECTIONS or name == "robot"]
    if clash:
        raise ConfigError(f"camera_names: {clash[0]!r} is the name of a section, not of a camera")
    return names


def _camera(name: str, mapping: Any) -> CameraConfig:
    camera = build_section(CameraConfig, mapping, name, name=name)
    try:
        camera.extrinsic  # noqa: B018 - validates translation and quaternion
    except ValueError as error:
        raise ConfigError(f"{name}.translation/rotation: {error}") from error
    if not camera.frame_id:
        camera = dataclasses.replace(camera, frame_id=f"{name}_optical_frame")
    return camera


def _check_consistency(config: RigConfig) -> None:
    """What the per-key ranges cannot say: how the keys of a rig fit together."""
    f = config.filters
    if f.mls_neighbors < 3 * f.mls_order + 1:
        raise ConfigError(f"filters.mls_neighbors must be >= {3 * f.mls_order + 1} for order {f.mls_order}")
    box_min, box_max = config.crop_box()
    if np.any(box_max <= box_min):
        raise ConfigError(f"filters.crop_box_max {tuple(box_max)} must exceed crop_box_min {tuple(box_min)} "
                          "on every axis: the crop box excludes everything")
    base = np.asarray(config.robot.base_position, float)
    if np.any(base < box_min - 1e-9) or np.any(base > box_max + 1e-9):
        raise ConfigError(f"filters.crop_box {tuple(box_min)}..{tuple(box_max)} does not contain the robot base "
                          f"{tuple(base)}: it would exclude the robot")


def unflatten_parameters(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted names -> the nested mapping `rig_config_from_mapping` reads."""
    nested: dict[str, Any] = {}
    for dotted, value in flat.items():
        node = nested
        *parents, leaf = str(dotted).split(".")
        for depth, part in enumerate(parents):
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{'.'.join(parents[:depth + 1])} is given both as a value and as a section")
        if isinstance(node.get(leaf), dict):
            raise ConfigError(f"{excerpt(str(dotted))[1:-1]} is given both as a value and as a section")
        node[leaf] = value
    return nested
