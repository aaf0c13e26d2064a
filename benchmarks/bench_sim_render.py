"""How long the synthetic rig takes to render (target: a frame in at most a second or two on 2 cores).

Prints seconds per step and, to compare machines, each step's ratio to a baseline measured in the same run:
one 9x9 box filter (scipy.ndimage.uniform_filter) of a 848x480 float image.

    .venv/bin/python benchmarks/bench_sim_render.py
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.ndimage import uniform_filter

from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.sim.simulate import Simulation
from ntcr_recon.sim.stereo import StereoEmulation, emulate_depth


def best_of(function, repeats=3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    image = np.random.default_rng(0).random((480, 848))
    baseline = best_of(lambda: uniform_filter(image, 9), 10)
    shape = TubeShape.from_bend_angle(TubeGeometry(), math.radians(90))
    simulation = Simulation(shape, frame_count=1)
    sample = best_of(lambda: shape.sample_surface_parts(simulation.scene.surface_spacing), 2)
    _ = simulation.scene.surface
    camera = simulation.cameras[0]
    exact_time = best_of(lambda: simulation.scene.render_exact(camera), 2)
    exact = simulation.exact[camera.name]
    rng = np.random.default_rng(0)
    emulate = best_of(lambda: emulate_depth(exact.depth, exact.normal, simulation.intrinsics, StereoEmulation(), rng))
    frame = best_of(lambda: list(simulation.frames()), 2) / len(simulation.cameras)
    print(f"baseline (9x9 box filter of one 848x480 image): {baseline * 1e3:.2f} ms")
    for name, seconds in (("surface sample (once per scene)", sample),
                          ("exact render, one camera (once per scene)", exact_time),
                          ("stereo artefacts, one frame", emulate),
                          ("frame after the first (artefacts + colour)", frame)):
        print(f"{name:45s} {seconds * 1e3:8.1f} ms   x{seconds / baseline:7.0f} baseline")
    first_frame = sample + exact_time + emulate
    print(f"first frame of a camera, all included: {first_frame:.2f} s (target <= 2 s)")


if __name__ == "__main__":
    main()
