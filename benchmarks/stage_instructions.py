"""Fusion and filters on the sample bags' recorded stage inputs, for instruction counts (callgrind), which
a loaded machine does not disturb as it does wall-clock times.

    .venv/bin/python benchmarks/stage_instructions.py record /tmp/stage_inputs.pkl   # once (fuse's inputs as
                                                                                    # the Reconstructor makes them)
    for stage in none fuse filter; do
        valgrind --tool=callgrind --trace-children=yes --callgrind-out-file=/tmp/cg.$stage.%p \\
            .venv/bin/python benchmarks/stage_instructions.py run /tmp/stage_inputs.pkl $stage 2>&1 | grep Collected
    done

A stage's instructions per frame pair: (its largest "Collected" - none's) / the pairs printed. Both runs do
one warm-up call of each stage, so imports and first-call caches cancel. The compiled kernels (core.base.compiled)
are cached per CPU, and valgrind's simulated CPU is not the host's: the first run under valgrind compiles them
(seconds of instructions in that run only), so run the loop once before counting.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path


def record(path: Path, bags: Path) -> None:
    import ntcr_recon.core.reconstruction.reconstructor as reconstructor_module
    from ntcr_recon.core.cloud.pairing import pair_frames
    from ntcr_recon.core.config.rig import load_rig_config
    from ntcr_recon.io.bag import read_camera_frames

    calls = []
    fuse = reconstructor_module.fuse

    def recording_fuse(pair, config, box=None):
        cloud = fuse(pair, config, box)
        calls.append((pair, config, box, cloud))
        return cloud

    reconstructor_module.fuse = recording_fuse
    for bag in sorted(p for p in bags.iterdir() if (p / "metadata.yaml").exists()):
        config = load_rig_config(bag / "rig.yaml")
        reconstructor = reconstructor_module.Reconstructor(config)
        for pair in pair_frames(read_camera_frames(bag, config), int(round(config.fusion.slop * 1e9))):
            reconstructor.process(pair)
    with open(path, "wb") as f:
        pickle.dump(calls, f)
    print(f"{len(calls)} fuse calls recorded in {path}")


def run(path: Path, stage: str) -> None:
    from ntcr_recon.core.cloud.filters import filter_cloud
    from ntcr_recon.core.cloud.fusion import fuse

    with open(path, "rb") as f:
        calls = pickle.load(f)
    pair, config, box, cloud = calls[0]
    filter_cloud(cloud, config)
    fuse(pair, config, box)
    for pair, config, box, cloud in calls:
        if stage == "fuse":
            fuse(pair, config, box)
        elif stage == "filter":
            filter_cloud(cloud, config)
    print(f"{len(calls)} frame pairs")


if __name__ == "__main__":
    if sys.argv[1] == "record":
        default_bags = Path(__file__).resolve().parents[1] / "bags"
        record(Path(sys.argv[2]), Path(sys.argv[3]) if len(sys.argv) > 3 else default_bags)
    else:
        run(Path(sys.argv[2]), sys.argv[3])
