"""A rig file with its cameras' poses replaced, every other key, comment and blank line kept as they were.

The rig file is a ROS 2 parameter file a person wrote (config/rig_template.yaml): a YAML round trip would drop its
comments, so the poses are replaced in the text. Each camera's block (`<camera>:` and the lines indented deeper) must
hold one `translation: [x, y, z]` and one `rotation: [x, y, z, w]` line, flow lists as the template writes them; the
comment after a value stays. The file is written whole or not at all (io.files.write_atomically).

    write_poses(source, target, {"cam_a": extrinsic_4x4, ...})
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ntcr_recon.core.base.transforms import matrix_to_quaternion
from ntcr_recon.io.files import write_atomically

_KEY = re.compile(r"^(?P<indent>\s*)(?P<key>[A-Za-z_][\w]*)\s*:(?P<rest>.*)$")
_FLOW_LIST = re.compile(r"^(?P<head>\s*)\[[^\]]*\](?P<tail>.*)$")


class RigFileError(ValueError):
    """The rig file cannot take the poses; the message names the camera and the key."""


def pose_values(extrinsic: np.ndarray) -> dict[str, list[float]]:
    """A 4x4 optical-frame-to-base transform as the rig file's translation (m) and rotation (quaternion x, y, z, w,
    w >= 0)."""
    quaternion = matrix_to_quaternion(np.asarray(extrinsic, float)[:3, :3])
    if quaternion[3] < 0:
        quaternion = -quaternion
    return {"translation": [float(v) for v in extrinsic[:3, 3]], "rotation": [float(v) for v in quaternion]}


def replace_poses(text: str, extrinsics: dict[str, np.ndarray]) -> str:
    """The rig file's text with each named camera's translation and rotation replaced."""
    lines = text.splitlines(keepends=True)
    for camera, extrinsic in extrinsics.items():
        start, indent = _block(lines, camera)
        for key, values in pose_values(extrinsic).items():
            row = _key_line(lines, start, indent, camera, key)
            match = _KEY.match(lines[row].rstrip("\n"))
            rest = _FLOW_LIST.match(match["rest"])
            if rest is None:
                raise RigFileError(f"{camera}.{key} is not written as a flow list [..] on one line (line {row + 1})")
            numbers = ", ".join(f"{v:.9g}" for v in values)
            ending = lines[row][len(lines[row].rstrip("\r\n")):]
            lines[row] = f"{match['indent']}{key}:{rest['head']}[{numbers}]{rest['tail']}{ending}"
    return "".join(lines)


def write_poses(source: str | Path, target: str | Path, extrinsics: dict[str, np.ndarray]) -> None:
    """Write `source` with the poses replaced to `target`, atomically."""
    text = replace_poses(Path(source).read_text(), extrinsics)
    write_atomically(target, lambda temp: Path(temp).write_text(text))


def _block(lines: list[str], camera: str) -> tuple[int, int]:
    """The line after `<camera>:` (a mapping key with nothing after it) and that key's indent."""
    for number, line in enumerate(lines):
        match = _KEY.match(line.rstrip("\n"))
        if match and match["key"] == camera and not match["rest"].split("#")[0].strip():
            return number + 1, len(match["indent"])
    raise RigFileError(f"no block '{camera}:' in the rig file")


def _key_line(lines: list[str], start: int, indent: int, camera: str, key: str) -> int:
    """The line of `key:` among the block's own keys (one level in, before the block ends)."""
    found = []
    for number in range(start, len(lines)):
        stripped = lines[number].strip()
        if not stripped or stripped.startswith("#"):
            continue
        match = _KEY.match(lines[number].rstrip("\n"))
        if match is None or len(match["indent"]) <= indent:
            if len(lines[number]) - len(lines[number].lstrip()) <= indent:
                break  # the block ended
            continue
        if match["key"] == key:
            found.append(number)
    if len(found) != 1:
        raise RigFileError(f"{camera}.{key}: expected one such line in the camera's block, found {len(found)}")
    return found[0]
