"""The offline command streams the bag (issue 11): frames decoded, paired as they come, processed and released,
so memory does not grow with the bag's length; and the one depth / camera_info / colour matching that the
offline reader and camera_node's BagSource share."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.bag_edit import rewrite_bag

from ntcr_recon.cli.reconstruct import COMBINED_FRAMES_MAX
from ntcr_recon.core.cloud.fusion import CameraFrame
from ntcr_recon.core.cloud.pairing import pair_frame_stream, pair_frames
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.core.quality.inputs import CameraInput
from ntcr_recon.core.reconstruction.still import EvenlySpread, StillStretch
from ntcr_recon.io.bag import iter_camera_frames, read_camera_frames
from ntcr_recon.io.camera_sources import BagSource

PERIOD_NS = 33_333_333
SLOP_NS = 15_000_000

# Runs the command in a fresh interpreter and prints its own peak resident memory (kB) last.
PEAK_RSS_SCRIPT = """
import resource, sys
from ntcr_recon.cli import main
code = main(sys.argv[1:])
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
sys.exit(code)
"""


def _frame(camera: str, stamp: int) -> CameraFrame:
    return CameraFrame(camera, stamp, points=np.zeros((1, 3)))


def _streams(seed: int) -> dict[str, list[CameraFrame]]:
    """Two cameras at 30 Hz with jitter, dropped frames, and a stretch where cam_b is silent."""
    rng = np.random.default_rng(seed)
    streams = {}
    for index, camera in enumerate(("cam_a", "cam_b")):
        stamps = np.arange(120) * PERIOD_NS + index * 4_300_000 + rng.integers(-9_000_000, 9_000_000, 120)
        keep = rng.random(120) > 0.1
        if camera == "cam_b":
            keep[40:70] = False  # silent for a second
        streams[camera] = [_frame(camera, int(s)) for s in np.sort(stamps[keep])]
    return streams


def _in_bag_order(streams: dict[str, list[CameraFrame]]) -> list[CameraFrame]:
    return sorted((f for frames in streams.values() for f in frames), key=lambda f: f.stamp_ns)


def _key(pairs) -> list[tuple]:
    return [tuple(sorted((name, f.stamp_ns) for name, f in p.frames.items())) for p in pairs]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_streamed_pairing_gives_the_pairs_of_the_whole_bag(seed):
    streams = _streams(seed)
    streamed = list(pair_frame_stream(_in_bag_order(streams), SLOP_NS, 500_000_000))
    assert _key(streamed) == _key(pair_frames(streams, SLOP_NS))
    assert [p.stamp_ns for p in streamed] == sorted(p.stamp_ns for p in streamed)


def test_streamed_pairing_holds_only_the_frames_that_may_still_pair():
    held = []

    def frames():
        for frame in _in_bag_order(_streams(0)):
            held.append(frame.stamp_ns)
            yield frame

    pairs = pair_frame_stream(frames(), SLOP_NS, 500_000_000)
    most_waiting = 0
    for pair in pairs:
        newest = held[-1]
        oldest_frame = min(f.stamp_ns for f in pair.frames.values())
        most_waiting = max(most_waiting, newest - oldest_frame)
    # a pair leaves within a few frame periods of its stamp, and within the silence timeout while cam_b is
    # silent: never the whole 4 s recording
    assert most_waiting <= 500_000_000 + 3 * PERIOD_NS


def test_evenly_spread_keeps_a_bounded_evenly_spaced_selection():
    keeper = EvenlySpread(8)
    for item in range(5):
        keeper.offer(item)
    assert keeper.items() == [0, 1, 2, 3, 4]
    for item in range(5, 200):
        keeper.offer(item)
    kept = keeper.items()
    assert 4 <= len(kept) <= 8 and kept[0] == 0
    assert len(set(np.diff(kept))) == 1  # evenly spaced


@pytest.mark.parametrize("motion", ["still", "step", "creep", "outlier"])
def test_the_frames_combined_are_the_longest_stretch_over_which_the_robot_stood_still(motion):
    """Tips scattered as their stated uncertainty (0.1 mm): still, every frame is one stretch; a 2 mm step at frame
    30 starts a new one (as long as the first: the latest is taken); creeping 0.02 mm a frame (under a fifth of the
    scatter, a frame to the next) leaves the stretch's first frames' tip after 20-40 frames, however often it is
    asked; one last frame 3 mm off (a misplaced tip) is left out, not taken for the robot's pose."""
    rng = np.random.default_rng(7)
    uncertainty, frames = 0.1e-3, 60
    stretch = StillStretch(64)  # keeps every frame of these
    for frame in range(frames):
        along = {"still": 0.0, "step": 2e-3 * (frame >= 30), "creep": 0.02e-3 * frame,
                 "outlier": 3e-3 * (frame == frames - 1)}[motion]
        tip = np.array([0.0, 0.0, 0.05 + along]) + rng.normal(0.0, uncertainty / math.sqrt(3), 3)
        stretch.offer(frame, tip, uncertainty, frame)
    print(f"\n{motion}: moves at {[move.frame for move in stretch.moves]}, frames {stretch.first}-{stretch.last} "
          "combined")
    if motion == "still":
        assert not stretch.moves and stretch.items() == list(range(frames)) and stretch.warning() is None
    elif motion == "step":
        assert [move.frame for move in stretch.moves] == [30] and stretch.items() == list(range(30, frames))
        moved = stretch.warning("frame pair")
        assert moved.code == "ROBOT_MOVED" and moved.figures["combined"] == [31, 60]
    elif motion == "creep":
        starts = [0] + [move.frame for move in stretch.moves]
        assert len(starts) >= 3 and all(20 <= b - a <= 40 for a, b in zip(starts, starts[1:], strict=False))
        assert stretch.items() == list(range(stretch.first, stretch.last + 1)) and stretch.first in starts
        assert stretch.last - stretch.first + 1 == max(np.diff([*starts, frames]))
    else:
        assert [move.frame for move in stretch.moves] == [frames - 1] and stretch.items() == list(range(frames - 1))


def test_bag_source_and_the_offline_reader_give_the_same_frames(bags_dir):
    bag = bags_dir / "bend45"
    config = load_rig_config(bag / "rig.yaml")
    offline = read_camera_frames(bag, config)
    for camera in config.camera_names:
        source = list(BagSource(bag, camera, config.topics))
        assert [f.stamp_ns for f in source] == [f.stamp_ns for f in offline[camera]]
        for live, still in zip(source, offline[camera], strict=True):
            assert live.intrinsics == still.intrinsics
            assert np.array_equal(live.depth, still.depth) and np.array_equal(live.color, still.color)
            assert live.camera_info is not None


def test_reader_streams_and_counts_what_it_decodes(bags_dir):
    bag = bags_dir / "straight"
    config = load_rig_config(bag / "rig.yaml")
    facts: dict[str, CameraInput] = {}
    frames = iter_camera_frames(bag, config, max_frames=2, facts=facts)
    first = next(frames)  # one frame decoded, not the bag
    assert facts[first.camera].frames == 1
    rest = list(frames)
    assert len(rest) == 3 and {f.camera for f in rest} == {"cam_a", "cam_b"}
    assert all(f.frames == 2 and f.raw_step == 1 and not f.big_endian_frames for f in facts.values())


def _peak_rss_kb(bag: Path, out: Path, max_frames: int | None) -> tuple[int, dict]:
    """The command's peak resident memory (kB) and its result; max_frames None: every frame."""
    limit = [] if max_frames is None else ["--max-frames", str(max_frames)]
    result = subprocess.run([sys.executable, "-c", PEAK_RSS_SCRIPT, "reconstruct", str(bag), "--out", str(out),
                             "--no-progress", *limit],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return int(result.stdout.split()[-1]), json.loads((out / "result.json").read_text())


def test_reconstruct_memory_does_not_grow_with_the_bag(bags_dir, tmp_path):
    # 200 frames per camera: the sample bag's 4 rendered frames again and again with later stamps, the
    # images cropped to the robot's pixels so that the bag stays small (8 MB).
    bag = rewrite_bag(bags_dir / "straight", tmp_path / "long", repeat=50, crop=True)
    short_peak, short = _peak_rss_kb(bag, tmp_path / "short_out", COMBINED_FRAMES_MAX)
    long_peak, long = _peak_rss_kb(bag, tmp_path / "long_out", None)
    print(f"\npeak RSS: {short_peak / 1024:.0f} MB for {short['frames']} frame pairs, {long_peak / 1024:.0f} MB "
          f"for {long['frames']}")
    assert (short["frames"], long["frames"]) == (COMBINED_FRAMES_MAX, 200)
    # both cameras' frames all came through: no warning names a camera or a pair with one camera only
    assert not [w for w in long["warnings"] if "camera" in w or "cameras" in w or w["code"] == "PAIRS_ONE_CAMERA"]
    assert long["ground_truth"]["notches_detected"] == long["notch_count_expected"]
    # Before streaming, every frame pair stayed in memory (this bag: 1.2 GB for 200 pairs, 0.5 GB for 64);
    # now the longer bag costs what the frames combined into the result cost, no more.
    assert long_peak <= short_peak + 64 * 1024
