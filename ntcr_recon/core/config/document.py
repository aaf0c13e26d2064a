"""The documented rig configuration file, written from the schema: every key with its value and, above it, its
description, unit and range, so the file's comments cannot drift from what the loader accepts.

config/sim_rig.yaml is such a file (a test checks it is exactly what this module writes from its values).
After a change to the schema, regenerate it (its values and its leading comment block are kept):

    python -m ntcr_recon.core.config.document config/sim_rig.yaml
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path
from typing import Any

import yaml

from ntcr_recon.core.base.schema import Key, keys_of
from ntcr_recon.core.config.rig import STAGE_SECTIONS, CameraConfig, RigConfig, load_rig_config

WIDTH = 116  # comment lines wrap here


def document_rig_config(config: RigConfig, header: str = "") -> str:
    """The ROS 2 parameter file of `config`, every key documented from the schema; `header`: leading comments."""
    lines = [header.rstrip("\n")] if header.strip() else []
    lines += ["/**:", "  ros__parameters:"]
    indent = " " * 4
    top = keys_of(RigConfig)
    for name in ("base_frame", "camera_names"):
        lines += _key_lines(indent, top[name], getattr(config, name))
    lines += _section_lines(indent, "topics", config.topics)
    for index, camera in enumerate(config.camera_names):
        if index == 0:
            lines += _section_lines(indent, camera, config.cameras[camera])
        else:  # the same keys: documented once, above
            lines += [f"{indent}# {camera}: the keys of {config.camera_names[0]}", f"{indent}{camera}:"]
            lines += [f"{indent}  {key}: {_value(getattr(config.cameras[camera], key))}"
                      for key in keys_of(CameraConfig)]
    lines += _section_lines(indent, "robot", config.robot)
    for name in STAGE_SECTIONS:
        if name != "topics":
            lines += _section_lines(indent, name, getattr(config, name))
    return "\n".join(lines) + "\n"


def _section_lines(indent: str, name: str, section: Any) -> list[str]:
    doc = " ".join((type(section).__doc__ or "").split())
    lines = [f"{indent}# {line}" for line in textwrap.wrap(doc, WIDTH - len(indent) - 2)]
    lines.append(f"{indent}{name}:")
    for key in keys_of(type(section)).values():
        value = getattr(section, key.name)
        if value is None:  # a null key (notch_depth: its derived default) is left out: ROS parameters have no null
            continue
        lines += _key_lines(indent + "  ", key, value)
    return lines


def _key_lines(indent: str, key: Key, value: Any) -> list[str]:
    setting = key.setting
    limits = setting.range_text() or (setting.unit if setting.unit else "")
    text = setting.description + (f"; {limits}" if limits else "")
    comment = [f"{indent}# {line}" for line in textwrap.wrap(text, WIDTH - len(indent) - 2)]
    return [*comment, f"{indent}{key.name}: {_value(value)}"]


def _value(value: Any) -> str:
    """A value as flow-style YAML that ROS 2 and the loader read back unchanged (`5.0e-05`, not `5e-05`)."""
    plain = list(value) if isinstance(value, tuple) else value
    text = yaml.safe_dump(plain, default_flow_style=True, width=10_000).strip()
    return text.removesuffix("...").strip()


def main(argv: list[str] | None = None) -> int:
    """Rewrite each given rig file as its documented form (same values, same leading comment block)."""
    paths = [Path(arg) for arg in (sys.argv[1:] if argv is None else argv)]
    if not paths:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    for path in paths:
        text = path.read_text()
        header = text[: text.index("/**:")] if "/**:" in text else ""
        path.write_text(document_rig_config(load_rig_config(path), header))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
