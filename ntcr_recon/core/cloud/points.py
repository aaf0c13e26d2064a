"""The point cloud every stage passes on: positions, packed colours and which camera saw each point.

Colours travel packed as uint32 0x00RRGGBB, the bits of PointCloud2's `rgb` float32 (`pack_rgb` / `unpack_rgb`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class Cloud:
    """Points in one frame (the base frame after fusion), with optional per-point attributes.

    xyz: (N, 3) float64 metres. rgb: (N,) uint32 0x00RRGGBB or None. camera: (N,) int8 index into the rig's
    camera_names, or None. stamp_ns: the source frames' stamp (the earliest of a pair). pixel_footprint: the
    size in metres of one depth pixel on the robot (median depth / focal length), 0 when unknown.
    pixel: (N, 2) int32 (u, v) image coordinates in the camera that saw the point, or None (e.g. an
    unorganised PointCloud2); it lets the filters find neighbours in the image instead of a KD-tree.
    """

    xyz: np.ndarray
    rgb: np.ndarray | None = None
    camera: np.ndarray | None = None
    stamp_ns: int = 0
    pixel_footprint: float = 0.0
    pixel: np.ndarray | None = None

    def __post_init__(self):
        xyz = np.asarray(self.xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"cloud points must have shape (N, 3), got {xyz.shape}")
        object.__setattr__(self, "xyz", xyz)
        for name in ("rgb", "camera", "pixel"):
            value = getattr(self, name)
            if value is not None and len(value) != len(xyz):
                raise ValueError(f"cloud {name} has {len(value)} entries for {len(xyz)} points")

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, selection: np.ndarray, xyz: np.ndarray | None = None) -> Cloud:
        """The points picked by a boolean mask or an index array, attributes alike; xyz: the picked points
        moved there instead (same count)."""
        if np.asarray(selection).dtype == bool and len(selection) != len(self):
            raise ValueError(f"a mask of {len(selection)} entries for a cloud of {len(self)} points")
        index = rows(selection)
        return replace(self, xyz=np.take(self.xyz, index, axis=0) if xyz is None else xyz,
                       rgb=None if self.rgb is None else np.take(self.rgb, index, axis=0),
                       camera=None if self.camera is None else np.take(self.camera, index, axis=0),
                       pixel=None if self.pixel is None else np.take(self.pixel, index, axis=0))

    def cameras_in(self, camera_names) -> list[str]:
        """The names (of the rig's camera_names, which `camera` indexes) of the cameras with points in the cloud;
        none without per-point cameras (fusion publishes a camera's frame alone when the other is late)."""
        seen = () if self.camera is None else np.unique(self.camera).tolist()
        return [camera_names[index] for index in seen]

    def with_points(self, xyz: np.ndarray) -> Cloud:
        """The same points moved (same count and attributes)."""
        return replace(self, xyz=xyz)

    @staticmethod
    def concatenate(clouds: list[Cloud]) -> Cloud:
        """One cloud of several (e.g. frames of a still robot); attributes kept when all have them."""
        if not clouds:
            return Cloud(np.empty((0, 3)))
        rgb = None if any(c.rgb is None for c in clouds) else np.concatenate([c.rgb for c in clouds])
        camera = None if any(c.camera is None for c in clouds) else np.concatenate([c.camera for c in clouds])
        # pixel coordinates of different frames collide, so a combination has none
        footprints = [c.pixel_footprint for c in clouds if c.pixel_footprint > 0]
        return Cloud(np.concatenate([c.xyz for c in clouds]), rgb, camera, min(c.stamp_ns for c in clouds),
                     float(np.median(footprints)) if footprints else 0.0)


def rows(selection: np.ndarray) -> np.ndarray:
    """The row indices a boolean mask (or an index array) picks, for np.take(array, rows(mask), axis=0):
    numpy's boolean indexing of an (N, k) array costs five to eight times more than taking its rows."""
    selection = np.asarray(selection)
    return np.flatnonzero(selection) if selection.dtype == bool else selection


def finite_rows(xyz: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows of an (N, 3) array whose coordinates are all finite (a column at a time:
    np.isfinite(xyz).all(axis=1) reduces over the short axis, at ten times the cost)."""
    return np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1]) & np.isfinite(xyz[:, 2])


def pack_rgb(rgb_u8: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours -> (N,) uint32 0x00RRGGBB."""
    rgb = np.asarray(rgb_u8, dtype=np.uint32)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 0x00RRGGBB -> (N, 3) uint8 colours."""
    packed = np.asarray(packed, dtype=np.uint32)
    return np.stack([(packed >> 16) & 0xFF, (packed >> 8) & 0xFF, packed & 0xFF], axis=-1).astype(np.uint8)
