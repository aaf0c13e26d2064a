"""Every node of the graph in one process, on one executor: `ntcr-recon run --single-process` starts it.

    python -m ntcr_recon.ros.single_process camera_node=camera_cam_a fusion_node=fusion_node ... \
        --ros-args --params-file RIG.yaml --params-file NODES.yaml

Each `EXECUTABLE=NAME` becomes that node class under that name; the nodes stay separate ROS nodes exchanging
messages over the middleware, so the graph is the same one a process per node runs. The rig configuration
(`/**` section) reaches all of them; NODES.yaml holds each node's own parameters under its name.
"""

from __future__ import annotations

import functools
import importlib
import sys

from ntcr_recon.ros.node_support import run_nodes

NODE_CLASSES = {"camera_node": "CameraNode", "fusion_node": "FusionNode", "filter_node": "FilterNode",
                "relocation_node": "RelocationNode", "mesh_node": "MeshNode"}


def node_factories(specs: list[str]) -> list:
    factories = []
    for spec in specs:
        executable, _, name = spec.partition("=")
        if executable not in NODE_CLASSES or not name:
            raise ValueError(f"{spec!r}: expected EXECUTABLE=NAME with EXECUTABLE one of {sorted(NODE_CLASSES)}")
        module = importlib.import_module(f"ntcr_recon.ros.{executable}")
        factories.append(functools.partial(getattr(module, NODE_CLASSES[executable]), node_name=name))
    return factories


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    ros_start = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    try:
        factories = node_factories(argv[1:ros_start])
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return run_nodes(factories, [argv[0], *argv[ros_start:]])


if __name__ == "__main__":
    sys.exit(main())
