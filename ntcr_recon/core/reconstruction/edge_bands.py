"""Each camera's edge band: the band its stereo matcher spoils at depth edges (`core.relocation.tip.edge_band_angle`,
an angle: the band in metres at any distance), measured on one of its first depth images that shows one.

One measure for the graph and the offline path: camera_node measures its camera's band on each frame until one
shows it; the Relocator (offline) measures, when the tip first needs a band, the latest depth image noted until
then. Either way a camera's images are tried at most EDGE_BAND_ATTEMPTS times (a scene without a far background
shows none).

    bands = EdgeBands()
    if bands.wants(name):
        bands.note_image(name, depth, unit, focal)    # the image to measure, replacing one noted before
    angle = bands.measure(name)                       # rad; NaN while no image of it showed one
    bands.angles                                      # the bands measured (or set), by camera, in that order
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.relocation.tip import EDGE_BAND_ATTEMPTS, edge_band_angle


class EdgeBands:
    """The cameras' edge bands (rad, by name) and the depth images noted to measure them on."""

    def __init__(self) -> None:
        self.angles: dict[str, float] = {}  # measured (or set), in the order they came
        self._images: dict[str, tuple[np.ndarray, float, float]] = {}  # per camera, (depth, unit, focal length)
        self._attempts: dict[str, int] = {}  # images measured per camera, at most EDGE_BAND_ATTEMPTS

    def attempts(self, name: str) -> int:
        """How many of the camera's images were measured."""
        return self._attempts.get(name, 0)

    def wants(self, name: str) -> bool:
        """Whether the camera's band is still to be measured (not known, and attempts left)."""
        return name not in self.angles and self.attempts(name) < EDGE_BAND_ATTEMPTS

    def note_image(self, name: str, depth: np.ndarray, unit: float, focal: float) -> None:
        """The depth image (raw units, `unit` m each; focal length in pixels) to measure the camera's band on."""
        self._images[name] = (depth, unit, focal)

    def measure(self, name: str) -> float:
        """The camera's edge band as an angle (rad): measured on the image noted if it is not known yet (an
        attempt); NaN while no depth image of it showed one."""
        if name not in self.angles and name in self._images:
            self._attempts[name] = self.attempts(name) + 1
            angle = edge_band_angle(*self._images.pop(name))
            if angle is not None:
                self.angles[name] = angle
        return self.angles.get(name, np.nan)

    def set(self, name: str, angle: float) -> None:
        """A band measured elsewhere (in the graph, by camera_node)."""
        self.angles[name] = float(angle)
