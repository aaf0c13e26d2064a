"""The rig configuration as flat ROS 2 parameters: dotted names to schema keys (what a node declares), a
configuration or mapping flattened to them, and a configuration as its nested mapping (config_to_mapping). The
inverse of the flattening, unflatten_parameters, is the loader's (config.rig)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ntcr_recon.core.base.schema import (
    Key,
    keys_of,
    section_mapping,
)
from ntcr_recon.core.config.rig import STAGE_SECTIONS, CameraConfig, RigConfig
from ntcr_recon.core.robot.geometry import TubeGeometry


def rig_parameter_keys(camera_names) -> dict[str, Key]:
    """Dotted rig parameter name -> its schema Key, for every key a node declares (`camera_names` aside)."""
    keys = {"base_frame": keys_of(RigConfig)["base_frame"]}
    for name in camera_names:
        keys.update({f"{name}.{key}": value for key, value in keys_of(CameraConfig).items()})
    for section, cls in {"robot": TubeGeometry, **STAGE_SECTIONS}.items():
        keys.update({f"{section}.{key}": value for key, value in keys_of(cls).items()})
    return keys


def parameter_key(dotted: str, camera_names) -> Key | None:
    """The schema Key of a dotted rig parameter name, None when it is not one."""
    section, _, key = dotted.partition(".")
    if not key:
        return keys_of(RigConfig).get(section)
    cls = CameraConfig if section in camera_names else {"robot": TubeGeometry, **STAGE_SECTIONS}.get(section)
    return keys_of(cls).get(key) if cls is not None else None


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


def config_to_mapping(config: RigConfig) -> dict[str, Any]:
    """The nested `ros__parameters` mapping of a RigConfig (round-trips through rig_config_from_mapping)."""
    mapping: dict[str, Any] = {"base_frame": config.base_frame, "camera_names": list(config.camera_names)}
    for name in config.camera_names:
        mapping[name] = section_mapping(config.cameras[name])
    mapping["robot"] = {k: v for k, v in config.robot.to_dict().items() if v is not None}
    for name in STAGE_SECTIONS:
        mapping[name] = section_mapping(getattr(config, name))
    return mapping
