"""The rig configuration: a ROS 2 parameter file read by the CLI, the benchmark and every node.

Layout (see config/sim_rig.yaml for a documented example)::

    /**:
      ros__parameters:
        base_frame: ntcr_base
        camera_names: [cam_a, cam_b]
        cam_a: {serial_number, width, height, fps, depth_unit, frame_id, translation, rotation}
        cam_b: {...}
        robot: {TubeGeometry fields}
        topics: {...}  fusion: {...}  filters: {...}  relocation: {...}  mesh: {...}  metrics: {...}

The camera and robot sections are required; every key of the stage sections has a default (the
dataclasses below), so a real rig's file needs only what differs. Nothing robot-specific is a default in
millimetres: gates, bins and smoothing lengths are fractions of the robot's outer radius or multiples of
the camera's pixel footprint (the size of one depth pixel on the robot, measured from the data).

Public API:
    load_rig_config(path) -> RigConfig            # ValueError naming the dotted key on a bad value
    rig_config_from_mapping(mapping) -> RigConfig # the same from the `ros__parameters` mapping
    flatten_parameters(RigConfig | dict) -> dict  # dotted names -> value, for nodes to declare
    unflatten_parameters(dict) -> dict            # the inverse, for nodes that read declared parameters
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ntcr_recon.core.robot import TubeGeometry
from ntcr_recon.core.transforms import rigid_transform


class ConfigError(ValueError):
    """A rig configuration that cannot be used; the message names the dotted key."""


@dataclass(frozen=True)
class CameraConfig:
    """One depth camera: stream profile and the pose of its optical frame in the base frame."""

    name: str
    serial_number: str = ""
    width: int = 848
    height: int = 480
    fps: float = 30.0
    depth_unit: float = 1e-4  # metres per raw 16UC1 unit (D405 default; realsense-ros recordings: 0.001)
    frame_id: str = ""
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @cached_property
    def extrinsic(self) -> np.ndarray:
        """4x4 transform taking points of the optical frame into the base frame (Eq. 9); computed once, as
        fusion asks every frame (read-only, as it is shared)."""
        matrix = rigid_transform(self.translation, self.rotation)
        matrix.flags.writeable = False
        return matrix


@dataclass(frozen=True)
class TopicConfig:
    """Topic names under `<namespace>/<camera>/` (realsense-ros layout)."""

    namespace: str = "/ntcr"
    depth: str = "depth/image_rect_raw"
    depth_info: str = "depth/camera_info"
    color: str = "color/image_rect_raw"
    points: str = "depth/color/points"

    def camera_topic(self, camera: str, kind: str) -> str:
        parts = (part.strip("/") for part in (self.namespace, camera, getattr(self, kind)))
        return "/" + "/".join(part for part in parts if part)


@dataclass(frozen=True)
class FusionConfig:
    slop: float = 0.015            # s; two cameras' frames pair when their stamps differ by at most this
    camera_timeout: float = 0.5    # s; a node publishes one camera alone after the other is silent this long


@dataclass(frozen=True)
class FilterConfig:
    # Crop box in the base frame. auto: the robot's reach on its side of the base (no tuning per rig);
    # otherwise crop_box_min / crop_box_max in metres.
    crop_box_auto: bool = True     # see RigConfig.crop_box
    crop_box_min: tuple[float, float, float] = (0.0, 0.0, 0.0)
    crop_box_max: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color_filter: bool = False                      # keep only points whose colour lies in [min, max]
    color_min: tuple[int, int, int] = (0, 0, 0)
    color_max: tuple[int, int, int] = (255, 255, 255)
    sor: bool = True                                # statistical outlier removal, Eq. 5
    sor_neighbors: int = 12
    sor_alpha: float = 2.0
    mls: bool = True                                # moving least squares, Eq. 6
    mls_order: int = 2                              # 1 = plane, 2 = quadric
    mls_neighbors: int = 12
    mls_radius_px: float = 0.0                      # > 0: only neighbours within this many pixel footprints
    voxel_size: float = 0.0                         # m; 0 = no downsampling


@dataclass(frozen=True)
class RelocationConfig:
    # Gate: a point this close to the reference surface is relocated onto it, others are rejected.
    # gate = gate_radius_fraction * outer_radius + gate_pixels * pixel_footprint
    gate_radius_fraction: float = 0.35
    gate_pixels: float = 2.0
    # Centreline estimation: slabs along the arc length, a fixed-radius circle fit in each.
    bin_radius_fraction: float = 0.25      # slab length = this * outer_radius (at least 2 pixel footprints)
    smoothing_radius_fraction: float = 1.0  # smoothing length along s = this * outer_radius
    max_iterations: int = 12
    tolerance_radius_fraction: float = 0.01  # stop when the centreline moves less than this * r_o (RMS)
    # Notch detection: kernel width of the coverage profile along s, in pixel footprints.
    notch_kernel_px: float = 0.5
    min_notch_width_fraction: float = 0.25  # a coverage gap narrower than this * notch_width is no notch
    # Region of interest of the next frame: the robot's box grown by this fraction of its length (motion
    # allowed between frames); a frame with fewer robot points there is fused from the whole crop box.
    roi_margin_fraction: float = 0.1
    # How observed points reach the reference surface: centerline (the tube's own coordinates, each point
    # along its viewing ray onto the wall) or icp (the paper's Sec. IV: KD-tree + ICP of a reference - the
    # configured robot posed by the centreline, or reference_mesh, a PLY/STL in the base frame - then each
    # point onto its nearest reference point within the gate)
    method: str = "centerline"
    reference_mesh: str = ""
    icp_iterations: int = 20


@dataclass(frozen=True)
class MeshConfig:
    # tube: the relocated outer wall meshed on the tube's (arc length, angle) grid, holes closed where the
    # gap is below two cells, notches kept open (milliseconds); poisson: open3d's screened Poisson
    # reconstruction (paper Eq. 7-8; hundreds of milliseconds)
    method: str = "tube"
    poisson_depth: int = 8
    density_quantile: float = 0.04   # vertices of the lowest Poisson density quantile are trimmed
    max_points: int = 60000          # the cloud is voxel-thinned to about this many points before meshing


@dataclass(frozen=True)
class MetricsConfig:
    pdc_voxel: float = 0.5e-3        # m; the paper's voxel for point density consistency (Table I)


@dataclass(frozen=True)
class RigConfig:
    base_frame: str
    camera_names: tuple[str, ...]
    cameras: dict[str, CameraConfig]
    robot: TubeGeometry
    topics: TopicConfig = field(default_factory=TopicConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    filters: FilterConfig = field(default_factory=FilterConfig)
    relocation: RelocationConfig = field(default_factory=RelocationConfig)
    mesh: MeshConfig = field(default_factory=MeshConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)

    def crop_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The crop box (min, max) in the base frame, resolving `crop_box_auto` from the robot.

        Automatic: what the robot can reach - within its length (plus a diameter) of the base on the side its
        axis points to, starting at the base, so the clamp or post it stands on stays out.
        """
        if not self.filters.crop_box_auto:
            return np.asarray(self.filters.crop_box_min, float), np.asarray(self.filters.crop_box_max, float)
        reach = self.robot.length + self.robot.outer_diameter
        corners = np.array(np.meshgrid([-reach, reach], [-reach, reach], [0.0, reach], indexing="ij")).reshape(3, -1)
        corners = (self.robot.base_rotation @ corners).T + np.asarray(self.robot.base_position, float)
        return corners.min(axis=0), corners.max(axis=0)


_STAGE_SECTIONS = {
    "topics": TopicConfig,
    "fusion": FusionConfig,
    "filters": FilterConfig,
    "relocation": RelocationConfig,
    "mesh": MeshConfig,
    "metrics": MetricsConfig,
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
        return _robot(parameters.get("robot", parameters))
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def _read_parameters(path: Path, what: str) -> Mapping:
    """The parameters of a YAML file (`_parameters_of`); ConfigError naming the file when it cannot be read."""
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"cannot read {what} {path}: {error.strerror or error}") from error
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ConfigError(f"{what} {path} is not valid YAML: {error}") from error
    try:
        return _parameters_of(document)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def _robot(mapping: Mapping) -> TubeGeometry:
    """The validated robot geometry of a `robot` mapping; ConfigError names the `robot.<field>`."""
    try:
        return TubeGeometry.from_mapping(mapping)  # validates
    except (ValueError, TypeError) as error:
        message = str(error)
        raise ConfigError(message if message.startswith("robot") else f"robot.{message}") from error


def _parameters_of(document: Any) -> Mapping:
    """The `ros__parameters` mapping of a parameter file (first node entry), or the document itself."""
    if not isinstance(document, Mapping):
        raise ConfigError("the rig configuration must be a mapping")
    for value in document.values():
        if isinstance(value, Mapping) and "ros__parameters" in value:
            return value["ros__parameters"]
    return document


def rig_config_from_mapping(parameters: Mapping) -> RigConfig:
    """Build and validate a RigConfig from nested (or dotted) parameters; ConfigError names the key."""
    parameters = unflatten_parameters(parameters) if any("." in str(k) for k in parameters) else parameters
    base_frame = _require(parameters, "base_frame", str)
    camera_names = _require(parameters, "camera_names", list)
    if not camera_names or not all(isinstance(n, str) and n for n in camera_names):
        raise ConfigError("camera_names must be a non-empty list of camera names")
    if len(set(camera_names)) != len(camera_names):
        raise ConfigError("camera_names has duplicates")
    cameras = {name: _camera(name, _require(parameters, name, Mapping)) for name in camera_names}
    robot = _robot(_require(parameters, "robot", Mapping))
    sections = {name: _section(name, cls, parameters.get(name, {})) for name, cls in _STAGE_SECTIONS.items()}
    config = RigConfig(base_frame=base_frame, camera_names=tuple(camera_names), cameras=cameras, robot=robot,
                       **sections)
    _validate_stages(config)
    return config


def _require(mapping: Mapping, key: str, kind: type):
    if key not in mapping or mapping[key] is None:
        raise ConfigError(f"missing key {key!r}")
    value = mapping[key]
    if not isinstance(value, kind):
        raise ConfigError(f"{key} must be a {kind.__name__}, got {value!r}")
    return value


def _camera(name: str, mapping: Mapping) -> CameraConfig:
    known = {f.name for f in fields(CameraConfig)} - {"name"}
    for key in mapping:
        if key not in known:
            raise ConfigError(f"unknown key {name}.{key}")
    for key in ("translation", "rotation", "depth_unit"):
        if key not in mapping:
            raise ConfigError(f"missing key {name}.{key}")
    values = {key: _convert(f"{name}.{key}", CameraConfig, key, mapping[key]) for key in mapping}
    camera = CameraConfig(name=name, **values)
    if camera.depth_unit <= 0:
        raise ConfigError(f"{name}.depth_unit must be > 0, got {camera.depth_unit}")
    if camera.width <= 0 or camera.height <= 0:
        raise ConfigError(f"{name}.width and {name}.height must be > 0")
    try:
        camera.extrinsic  # noqa: B018 - validates translation and quaternion
    except ValueError as error:
        raise ConfigError(f"{name}.translation/rotation: {error}") from error
    if not camera.frame_id:
        camera = dataclasses.replace(camera, frame_id=f"{name}_optical_frame")
    return camera


def _section(name: str, cls: type, mapping: Any):
    if not isinstance(mapping, Mapping):
        raise ConfigError(f"{name} must be a mapping, got {mapping!r}")
    known = {f.name for f in fields(cls)}
    for key in mapping:
        if key not in known:
            raise ConfigError(f"unknown key {name}.{key}")
    return cls(**{key: _convert(f"{name}.{key}", cls, key, value) for key, value in mapping.items()})


def _convert(dotted: str, cls: type, key: str, value: Any):
    """Coerce a YAML value to the type of the dataclass field's default, naming the key on failure."""
    default = next(f for f in fields(cls) if f.name == key)
    template = default.default if default.default is not dataclasses.MISSING else None
    try:
        if isinstance(template, bool):
            if not isinstance(value, bool):
                raise TypeError
            return value
        if isinstance(template, tuple):
            items = tuple(value)
            if len(items) != len(template):
                raise ConfigError(f"{dotted} needs {len(template)} numbers, got {value!r}")
            converted = tuple(type(t)(v) for t, v in zip(template, items, strict=True))
            if not all(math.isfinite(v) for v in converted):
                raise ConfigError(f"{dotted} must be finite, got {value!r}")
            return converted
        if isinstance(template, int):
            if isinstance(value, bool) or float(value) != int(value):
                raise TypeError
            return int(value)
        if isinstance(template, float):
            if isinstance(value, bool):
                raise TypeError
            converted = float(value)
            if not math.isfinite(converted):
                raise ConfigError(f"{dotted} must be finite, got {value!r}")
            return converted
        if isinstance(template, str):
            # D405 serial numbers are all digits, so YAML and `-p` hand them over as integers
            if dotted.endswith("serial_number") and isinstance(value, int) and not isinstance(value, bool):
                return str(value)
            if not isinstance(value, str):
                raise TypeError
            return value
        return value
    except (TypeError, ValueError) as error:
        if isinstance(error, ConfigError):
            raise
        raise ConfigError(f"{dotted} must be of type {type(template).__name__}, got {value!r}") from error


def _validate_stages(config: RigConfig) -> None:
    f, r, m = config.filters, config.relocation, config.mesh
    positive = {
        "fusion.slop": config.fusion.slop, "fusion.camera_timeout": config.fusion.camera_timeout,
        "filters.sor_neighbors": f.sor_neighbors, "filters.sor_alpha": f.sor_alpha,
        "filters.mls_neighbors": f.mls_neighbors,
        "relocation.gate_radius_fraction": r.gate_radius_fraction,
        "relocation.bin_radius_fraction": r.bin_radius_fraction,
        "relocation.smoothing_radius_fraction": r.smoothing_radius_fraction,
        "relocation.max_iterations": r.max_iterations,
        "relocation.tolerance_radius_fraction": r.tolerance_radius_fraction,
        "relocation.notch_kernel_px": r.notch_kernel_px,
        "relocation.roi_margin_fraction": r.roi_margin_fraction,
        "mesh.poisson_depth": m.poisson_depth, "mesh.max_points": m.max_points,
        "metrics.pdc_voxel": config.metrics.pdc_voxel,
    }
    for key, value in positive.items():
        if not value > 0:
            raise ConfigError(f"{key} must be > 0, got {value}")
    non_negative = {"relocation.gate_pixels": r.gate_pixels, "filters.mls_radius_px": f.mls_radius_px,
                    "filters.voxel_size": f.voxel_size, "relocation.min_notch_width_fraction":
                    r.min_notch_width_fraction}
    for key, value in non_negative.items():
        if value < 0:
            raise ConfigError(f"{key} must be >= 0, got {value}")
    if f.sor_neighbors < 2:
        raise ConfigError(f"filters.sor_neighbors must be >= 2, got {f.sor_neighbors}")
    if f.mls_order not in (1, 2):
        raise ConfigError(f"filters.mls_order must be 1 or 2, got {f.mls_order}")
    if f.mls_neighbors < 3 * f.mls_order + 1:
        raise ConfigError(f"filters.mls_neighbors must be >= {3 * f.mls_order + 1} for order {f.mls_order}")
    if r.method not in ("centerline", "icp"):
        raise ConfigError(f"relocation.method must be 'centerline' or 'icp', got {r.method!r}")
    if r.icp_iterations < 1:
        raise ConfigError(f"relocation.icp_iterations must be >= 1, got {r.icp_iterations}")
    if m.method not in ("tube", "poisson"):
        raise ConfigError(f"mesh.method must be 'tube' or 'poisson', got {m.method!r}")
    if not 0 <= m.density_quantile < 1:
        raise ConfigError(f"mesh.density_quantile must be in [0, 1), got {m.density_quantile}")
    if any(not 0 <= c <= 255 for c in f.color_min + f.color_max):
        raise ConfigError("filters.color_min / color_max must lie in 0..255")
    box_min, box_max = config.crop_box()
    if np.any(box_max <= box_min):
        raise ConfigError(f"filters.crop_box_max {tuple(box_max)} must exceed crop_box_min {tuple(box_min)} "
                          "on every axis: the crop box excludes everything")
    base = np.asarray(config.robot.base_position, float)
    if np.any(base < box_min - 1e-9) or np.any(base > box_max + 1e-9):
        raise ConfigError(f"filters.crop_box {tuple(box_min)}..{tuple(box_max)} does not contain the robot base "
                          f"{tuple(base)}: it would exclude the robot")


def flatten_parameters(config: RigConfig | Mapping) -> dict[str, Any]:
    """Dotted parameter names -> values (lists for tuples), as a node declares them."""
    nested = config_to_mapping(config) if isinstance(config, RigConfig) else config
    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, Mapping):
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), item)
        else:
            flat[prefix] = list(value) if isinstance(value, tuple) else value

    walk("", nested)
    return flat


def unflatten_parameters(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted names -> the nested mapping `rig_config_from_mapping` reads."""
    nested: dict[str, Any] = {}
    for dotted, value in flat.items():
        node = nested
        *parents, leaf = str(dotted).split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return nested


def config_to_mapping(config: RigConfig) -> dict[str, Any]:
    """The nested `ros__parameters` mapping of a RigConfig (round-trips through rig_config_from_mapping)."""
    def plain(obj) -> dict[str, Any]:
        return {f.name: (list(v) if isinstance(v := getattr(obj, f.name), tuple) else v) for f in fields(obj)}

    mapping: dict[str, Any] = {"base_frame": config.base_frame, "camera_names": list(config.camera_names)}
    for name in config.camera_names:
        camera = plain(config.cameras[name])
        camera.pop("name")
        mapping[name] = camera
    mapping["robot"] = {k: v for k, v in config.robot.to_dict().items() if v is not None}
    for name in _STAGE_SECTIONS:
        mapping[name] = plain(getattr(config, name))
    return mapping
