"""The reconstruction chain on a frame pair: one object the CLI and the benchmark call, the frame loop.

    reconstructor = Reconstructor(config)              # a RigConfig (core.config.rig.load_rig_config)
    result = reconstructor.process(frame_pair)          # fuse -> filter -> relocate (-> mesh if asked)

Each stage is a function of its own, which the ROS nodes call without a Reconstructor:

    cloud = fuse(frame_pair, config)                    # core.cloud.fusion: Cloud in the base frame (Eq. 9)
    cloud = filter_cloud(cloud, config)                 # core.cloud.filters: crop, colour, SOR, MLS, voxel (Sec. II-B)
    relocation = relocator.relocate(cloud)              # core.reconstruction.relocate.Relocator: centreline,
                                                        # notches, tip, relocated cloud (Sec. IV)
    mesh = mesh_relocation(relocation, config)          # core.reconstruction.mesh: the configured mesher, tube
                                                        # (default) or Poisson (Eq. 7-8)

The Reconstructor's stages (`fuse`, `filter`, `relocate`, `mesh`) call those, timing themselves into
`timings_ms`. `relocate` warm-starts from the previous call's centreline (a still or slowly moving robot
converges in one or two iterations) and `fuse` then deprojects only the pixels that can see a region of interest
around the robot found last (its bounding box grown by `relocation.roi_margin_fraction` of the robot's length
on every side); a frame whose robot is not found whole there is fused again from the full crop box.
`reset()` forgets both. Several frames of a still robot are combined by relocating
`Cloud.concatenate(filtered clouds)`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ntcr_recon.core.cloud.filters import filter_cloud
from ntcr_recon.core.cloud.fusion import FramePair, fuse
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.reconstruction.relocate import ReconstructionError, RelocationResult, Relocator

__all__ = ["FrameResult", "ReconstructionError", "Reconstructor", "RelocationResult"]


@dataclass
class FrameResult:
    fused: Cloud
    filtered: Cloud
    relocation: RelocationResult
    mesh: object | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


class Reconstructor:
    def __init__(self, config: RigConfig):
        self.config = config
        self.geometry = config.robot
        self.relocator = Relocator(config)  # the relocation and what it keeps between frames
        self._roi: tuple[np.ndarray, np.ndarray] | None = None
        self._roi_count = 0
        self._fused_within: tuple[np.ndarray, np.ndarray] | None = None  # the region the last fuse kept to
        self.timings_ms: dict[str, float] = {}

    def reset(self) -> None:
        """Forget the previous centreline and region of interest (the next frame starts cold)."""
        self.relocator.reset()
        self._roi = None

    def _timed(self, stage: str, start: float) -> None:
        self.timings_ms[stage] = (time.perf_counter() - start) * 1e3

    def fuse(self, pair: FramePair) -> Cloud:
        start = time.perf_counter()
        self.relocator.note_frames(pair)  # the depth images' step and edge band, for the relocation
        cloud, self._fused_within = None, self._roi
        if self._roi is not None:
            cloud = fuse(pair, self.config, self._roi)
            if len(cloud) < 0.8 * self._roi_count:  # the robot moved out of the region: look everywhere
                cloud = None
        if cloud is None:
            cloud, self._fused_within = fuse(pair, self.config), None
        self.relocator.note_views(pair, cloud)  # the colour windows about the robot's pixels, for the limbs
        self._timed("fuse", start)
        return cloud

    def filter(self, cloud: Cloud) -> Cloud:
        start = time.perf_counter()
        cloud = filter_cloud(cloud, self.config)
        self._timed("filter", start)
        return cloud

    def relocate(self, cloud: Cloud, warm_start: bool = True) -> RelocationResult:
        """Reference-guided relocation (paper Sec. IV, Relocator.relocate); the robot's box is the next frame's
        region of interest."""
        start = time.perf_counter()
        relocation = self.relocator.relocate(cloud, warm_start)
        self._update_roi(relocation.relocated)
        self._timed("relocate", start)
        return relocation

    def _update_roi(self, relocated: Cloud) -> None:
        """Region of interest for the next frame: the robot's bounding box, grown, inside the crop box."""
        if len(relocated) < 32:
            self._roi = None
            return
        margin = self.config.relocation.roi_margin_fraction * self.geometry.length + self.geometry.outer_diameter
        box_min, box_max = self.config.crop_box()
        low, high = _bounds(relocated.xyz)
        self._roi = (np.maximum(low - margin, box_min), np.minimum(high + margin, box_max))
        self._roi_count = len(relocated)

    def mesh(self, relocation: RelocationResult):
        """The configured mesher (core.reconstruction.mesh.mesh_relocation)."""
        from ntcr_recon.core.reconstruction.mesh import mesh_relocation

        start = time.perf_counter()
        mesh = mesh_relocation(relocation, self.config)
        self._timed("mesh", start)
        return mesh

    def process(self, pair: FramePair, with_mesh: bool = False) -> FrameResult:
        """fuse -> filter -> relocate (-> mesh) on one frame pair.

        The frame is fused around the robot's last box (the region of interest) when there is one; where the
        robot found reaches that box's side, or none is found in it, the box may have cut it (the robot moved, or
        the last frame saw only part of it), and the frame is done again over the whole crop box, warm-started as
        the first pass was (timings_ms: the two passes' sums)."""
        self.timings_ms = {}
        prior = self.relocator.prior

        def chain() -> tuple[Cloud, Cloud, RelocationResult]:
            fused = self.fuse(pair)
            filtered = self.filter(fused)
            return fused, filtered, self.relocate(filtered)

        try:
            fused, filtered, relocation = chain()
            again = self._fused_within is not None and _reaches_side(
                relocation.relocated.xyz, self._fused_within, self.config.crop_box(), self.geometry.outer_diameter)
        except ReconstructionError:
            if self._fused_within is None:
                raise
            again = True
        if again:
            first, self._roi, self.relocator.prior = self.timings_ms, None, prior
            self.timings_ms = {}
            fused, filtered, relocation = chain()
            self.timings_ms = {stage: first.get(stage, 0.0) + ms for stage, ms in self.timings_ms.items()}
        mesh = self.mesh(relocation) if with_mesh else None
        return FrameResult(fused, filtered, relocation, mesh, dict(self.timings_ms))


def _reaches_side(xyz: np.ndarray, box: tuple[np.ndarray, np.ndarray], crop: tuple[np.ndarray, np.ndarray],
                  distance: float) -> bool:
    """Whether points come within `distance` of a side of `box` that lies inside the crop box (a side on the
    crop box's own cuts nothing the crop box would not)."""
    if not len(xyz):
        return False
    low, high = _bounds(xyz)
    inside_low, inside_high = box[0] > crop[0], box[1] < crop[1]
    return bool(np.any(inside_low & (low - box[0] < distance)) or np.any(inside_high & (box[1] - high < distance)))


def _bounds(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (N, 3) points' axis-aligned bounds (low, high)."""
    # a column at a time: min/max over the long axis of an (N, 3) array cost ten times more
    columns = xyz.T
    return np.array([c.min() for c in columns]), np.array([c.max() for c in columns])
