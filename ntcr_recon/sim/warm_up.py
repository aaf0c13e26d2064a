"""The numba kernels compiled ahead of the frames: a small rendered scene run through the whole chain.

`python -m ntcr_recon.sim.warm_up` compiles (or, when cached, checks) every kernel the nodes and the offline
command use, as scripts/setup_env.sh does at install; a node does the same at its start through
`core.base.compiled.ensure_compiled(workload)` before it subscribes to anything. The workload is the reconstruction
of one rendered frame pair (a 45-degree bend seen by the two cameras), fused, filtered, relocated and meshed by
the same `Reconstructor` the nodes wrap, so each kernel is compiled for the argument types the frames give it.
"""

from __future__ import annotations

import math
import sys
import time

WARM_UP_SEED = 7


def workload() -> None:
    """Reconstruct one rendered frame pair (every stage, the mesh too): compiles each kernel the chain calls."""
    import yaml

    from ntcr_recon.core.cloud.deproject import Intrinsics
    from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair
    from ntcr_recon.core.config.rig import rig_config_from_mapping
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor
    from ntcr_recon.core.robot.geometry import TubeGeometry
    from ntcr_recon.core.robot.kinematics import TubeShape
    from ntcr_recon.sim.simulate import Simulation

    simulation = Simulation(TubeShape.from_bend_angle(TubeGeometry(), math.radians(45.0)), frame_count=1,
                            seed=WARM_UP_SEED, color_noise=0.0)
    document = yaml.safe_load(yaml.safe_dump(simulation.rig_parameters()))  # as the rig file holds it
    config = rig_config_from_mapping(next(v["ros__parameters"] for v in document.values()
                                          if isinstance(v, dict) and "ros__parameters" in v))
    i = simulation.intrinsics
    intrinsics = Intrinsics(width=i.width, height=i.height, fx=i.fx, fy=i.fy, cx=i.cx, cy=i.cy)
    frames = {frame.camera.name: CameraFrame(frame.camera.name, frame.stamp_ns, depth=frame.depth_raw,
                                             intrinsics=intrinsics, color=frame.color)
              for frame in simulation.frames()}
    reconstructor = Reconstructor(config)
    reconstructor.process(FramePair(min(f.stamp_ns for f in frames.values()), frames), with_mesh=True)


def ready_kernels(log) -> None:
    """Before a node subscribes: the kernels compiled (when this install's cache is not complete; one log
    line) and the cached ones this process uses loaded."""
    from ntcr_recon.core.base import compiled

    compiled.ensure_compiled(workload, lambda line: log(f"{line}, before subscribing"))
    compiled.load_cached()


def main() -> int:
    import numba

    from ntcr_recon.core.base import compiled

    started = time.monotonic()
    spent = compiled.ensure_compiled(workload, log=lambda line: print(f"[warm-up] {line}", flush=True))
    state = "compiled" if spent is not None else "already compiled"
    print(f"[warm-up] the numba kernels are {state} in {numba.config.CACHE_DIR} "
          f"({time.monotonic() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
