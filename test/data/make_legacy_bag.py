"""Makes legacy_d405.bag (+ legacy_d405_frames.npz, the frames it holds): a librealsense ROS1 recording of a
software D405, for the `file` source's legacy-.bag test. pyrealsense2 >= 2.56 records .db3 only ("Output file
must have .db3 extension") but still plays .bag, so the file is made once with an older pyrealsense2:

    python3.11 -m venv /tmp/rs254 && /tmp/rs254/bin/pip install pyrealsense2==2.54.2.5684 numpy
    PYTHONPATH=test /tmp/rs254/bin/python test/data/make_legacy_bag.py
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from support.software_d405 import SoftwareD405

HERE = Path(__file__).resolve().parent
INTRINSICS = SimpleNamespace(width=48, height=36, fx=150.0, fy=150.0, cx=23.5, cy=17.5)


def legacy_frames(count: int = 3) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(raw 0.1 mm depth, RGB colour, timestamp ms): a tilted plane ~9 cm away with a hole, a gradient."""
    v, u = np.mgrid[:INTRINSICS.height, :INTRINSICS.width]
    frames = []
    for index in range(count):
        depth = (900 + u + 2 * v + 10 * index).astype(np.uint16)
        depth[15:17, 20:22] = 0
        color = np.stack([u * 5, v * 7, np.full_like(u, 40 * index)], axis=-1).astype(np.uint8)
        frames.append((depth, color, 1_700_000_000_000.0 + index * 1000.0 / 30))
    return frames


if __name__ == "__main__":
    frames = legacy_frames()
    bag = HERE / "legacy_d405.bag"
    bag.unlink(missing_ok=True)
    SoftwareD405(INTRINSICS).record(bag, frames)
    np.savez_compressed(HERE / "legacy_d405_frames.npz", depth=np.stack([f[0] for f in frames]),
                        color=np.stack([f[1] for f in frames]), timestamp_ms=np.array([f[2] for f in frames]))
    print(f"{bag}: {bag.stat().st_size} bytes")
