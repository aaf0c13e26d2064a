"""Which frames of a recording show the robot still: only those are combined into one result.

A bag's frames combined into one relocated cloud give a better-sampled robot - if it held one pose. Frames of a
robot that moved would blend its poses into one it never held, and the relocation cannot tell (the blend is a
thicker tube). So the frames are taken as they stream by (StillStretch) and grouped into stretches over which
each frame's tip stays where the stretch's first frames put it, within what the frames' results state of it;
the result combines the longest stretch (the latest of equals), and says that the robot moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ntcr_recon.core.quality.findings import Finding, finding

# A tip further off the stretch's than this many of the two tips' combined stated uncertainties has moved.
MOVE_SIGMAS = 3.0

# The stretch's tip is the median of its first frames' tips, fixed once this many have come: a robot creeping
# a little each frame moves off it as far as it crept (a median over the latest frames would follow it).
ANCHOR_FRAMES = 16


class EvenlySpread:
    """At most `limit` items of a stream of unknown length, evenly spread over it (every item while there
    are no more than `limit`; then every 2nd, 4th, ... as it grows), so memory stays bounded."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.stride = 1
        self.seen = 0
        self.kept: list[tuple[int, object]] = []

    def offer(self, item) -> None:
        if self.seen % self.stride == 0:
            self.kept.append((self.seen, item))
            if len(self.kept) > self.limit:
                self.stride *= 2
                self.kept = [(index, kept) for index, kept in self.kept if index % self.stride == 0]
        self.seen += 1

    def items(self) -> list:
        return [item for _, item in self.kept]


def stated_tip_uncertainty(quality: dict) -> float:
    """How well one frame's result places its tip (m): its stated uncertainty along the tube and across it (the
    along one again where it states none across), never under a pixel footprint, which no frame resolves."""
    along = quality["tip_uncertainty_mm"]
    across = quality.get("tip_across_uncertainty_mm")
    across = along if across is None else across
    return 1e-3 * max(math.hypot(along, across), quality.get("pixel_footprint_mm") or 0.0)


@dataclass(frozen=True)
class Move:
    """The robot moved: the first frame whose tip left the stretch before it, and how far (m)."""
    frame: int
    distance: float


@dataclass
class _Stretch:
    """Frames over which the robot stood still: the first and last, the items kept of them, and the tip of its
    first ANCHOR_FRAMES frames (with how well each placed it) that the later ones are held to."""
    first: int
    last: int
    kept: EvenlySpread
    anchor_tips: list = field(default_factory=list)
    anchor_uncertainties: list = field(default_factory=list)

    @property
    def frames(self) -> int:
        """How many frames it holds (each was offered to `kept`)."""
        return self.kept.seen


class StillStretch:
    """The longest stretch of frames over which the robot stood still (the latest of equally long ones), as the
    frames stream by.

    offer(frame, tip, uncertainty, item): a frame's index (increasing; frames without a result are not offered), its
    tip (m, (3,)) and how well its result places it (m, e.g. stated_tip_uncertainty); a tip off the current
    stretch's (ANCHOR_FRAMES) by more than MOVE_SIGMAS of the two's combined uncertainty starts a new stretch. The
    items of the current stretch and of the longest before it are kept, as EvenlySpread(limit) each: a frame that
    misplaced its tip (a stretch of one) does not outweigh the frames before it.
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.moves: list[Move] = []
        self._current: _Stretch | None = None
        self._longest: _Stretch | None = None  # the longest stretch before the current one

    def offer(self, frame: int, tip: np.ndarray, uncertainty: float, item) -> None:
        tip = np.asarray(tip, dtype=float)
        current = self._current
        if current is not None:
            distance = float(np.linalg.norm(tip - np.median(current.anchor_tips, axis=0)))
            if distance > MOVE_SIGMAS * math.hypot(uncertainty, float(np.median(current.anchor_uncertainties))):
                self.moves.append(Move(frame, distance))
                if self._longest is None or current.frames >= self._longest.frames:
                    self._longest = current
                current = None
        if current is None:
            current = self._current = _Stretch(frame, frame, EvenlySpread(self.limit))
        current.last = frame
        if len(current.anchor_tips) < ANCHOR_FRAMES:
            current.anchor_tips.append(tip)
            current.anchor_uncertainties.append(float(uncertainty))
        current.kept.offer(item)

    @property
    def _chosen(self) -> _Stretch | None:
        if self._longest is not None and self._current is not None and self._longest.frames > self._current.frames:
            return self._longest
        return self._current

    @property
    def first(self) -> int | None:
        """The chosen stretch's first frame (None: no frame offered)."""
        return None if self._chosen is None else self._chosen.first

    @property
    def last(self) -> int | None:
        """The chosen stretch's last frame (None: no frame offered)."""
        return None if self._chosen is None else self._chosen.last

    def items(self) -> list:
        """The chosen stretch's kept items, in order."""
        return [] if self._chosen is None else self._chosen.kept.items()

    def warning(self, name: str = "frame") -> Finding | None:
        """What a result combining the chosen stretch should say of the frames it left out (None: none); frames
        are named `name` and numbered from 1."""
        if not self.moves:
            return None
        largest = max(self.moves, key=lambda move: move.distance)
        times = "once" if len(self.moves) == 1 else f"{len(self.moves)} times"
        return finding("ROBOT_MOVED", f"the robot moved during the recording ({times}; its tip by "
                       f"{'up to ' * (len(self.moves) > 1)}{largest.distance * 1e3:.2f} mm at {name} "
                       f"{largest.frame + 1}): the result combines {name}s {self.first + 1}-{self.last + 1} only, the "
                       "longest stretch over which it stood still; a result of every frame is relocation_node's "
                       "(`ntcr-recon run`)", moves=len(self.moves), largest_move_mm=largest.distance * 1e3,
                       combined=[self.first + 1, self.last + 1])
