"""`ntcr-recon run`: start the whole graph without `ros2 launch`, every node in its own process.

    ntcr-recon run --config config/sim_rig.yaml --bag bags/bend45 [--rate 1] [--loop] [--use-sim-time]
    ntcr-recon run --config my_rig.yaml                      # live D405s (camera_node's realsense source)

One camera_node per camera of the configuration (node name `camera_<cam>`), then fusion_node, filter_node,
relocation_node and mesh_node; every process gets the rig configuration as its ROS parameter file. Ctrl-C
(or SIGTERM, or `--duration`) stops them all: SIGINT to each, then a kill for any still alive after a grace
period. If one node exits on its own (e.g. it refused a parameter), the others are stopped too and the
command exits non-zero, naming it.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

STAGE_NODES = ("fusion_node", "filter_node", "relocation_node", "mesh_node")
GRACE_S = 10.0
START_DELAY_S = 3.0  # s for the node processes to start before a replay's first frame is due


@dataclass
class NodeCommand:
    name: str
    argv: list[str]
    parameters: dict[str, object] = field(default_factory=dict)


def node_commands(args: argparse.Namespace, camera_names: list[str]) -> list[NodeCommand]:
    """The processes of the graph, with their command lines (python -m <node module> --ros-args ...)."""
    files = {}
    for item in args.file:
        camera, sep, path = item.partition("=")
        if not sep or camera not in camera_names:
            raise ValueError(f"--file {item!r}: expected CAM=PATH with CAM one of {camera_names}")
        files[camera] = path
    if args.file and set(files) != set(camera_names):
        raise ValueError(f"--file needs a recording for every camera {camera_names}, got {sorted(files)}")
    commands = []
    # The camera nodes replay in step: the bag's first frame is due at the same wall-clock instant for all
    # (after the nodes' start-up), so frames of one instant reach fusion together.
    start_time = round(time.time() + START_DELAY_S, 3)
    for index, camera in enumerate(camera_names):
        parameters: dict[str, object] = {"camera": camera, "loop": args.loop}
        if args.bag is not None:
            parameters.update(source="bag", bag_path=str(args.bag.resolve()), rate=float(args.rate),
                              publish_clock=bool(args.use_sim_time and index == 0), start_time=start_time)
        elif files:
            parameters.update(source="file", file_path=str(Path(files[camera]).resolve()), rate=float(args.rate),
                              publish_clock=bool(args.use_sim_time and index == 0), start_time=start_time)
        else:
            parameters.update(source="realsense")
        commands.append(NodeCommand(f"camera_{camera}", _argv("camera_node", f"camera_{camera}", args.config,
                                                               parameters), parameters))
    extra = _extra_parameters(args.param)
    for node in STAGE_NODES:
        if node == "mesh_node" and args.no_mesh:
            continue
        parameters = {"use_sim_time": True} if args.use_sim_time else {}
        if node in ("mesh_node", "relocation_node") and args.output is not None:
            parameters["output_dir"] = str(args.output.resolve())
        parameters.update(extra.pop(node, {}))
        commands.append(NodeCommand(node, _argv(node, node, args.config, parameters), parameters))
    if extra:
        raise ValueError(f"--param names unknown node(s) {sorted(extra)}; nodes: {[c.name for c in commands]}")
    return commands


def _extra_parameters(items: list[str]) -> dict[str, dict[str, str]]:
    extra: dict[str, dict[str, str]] = {}
    for item in items:
        node, sep, assignment = item.partition(":")
        name, sep2, value = assignment.partition(":=")
        if not (sep and sep2 and node and name):
            raise ValueError(f"--param {item!r}: expected NODE:NAME:=VALUE")
        extra.setdefault(node, {})[name] = value
    return extra


def _argv(executable: str, node_name: str, config: Path, parameters: dict[str, object]) -> list[str]:
    def ros_value(value: object) -> str:
        return str(value).lower() if isinstance(value, bool) else str(value)

    argv = [sys.executable, "-m", f"ntcr_recon.ros.{executable}", "--ros-args", "-r", f"__node:={node_name}",
            "--params-file", str(config.resolve())]
    for name, value in parameters.items():
        argv += ["-p", f"{name}:={ros_value(value)}"]
    return argv


def main(args: argparse.Namespace) -> int:
    from ntcr_recon.core.config import ConfigError, load_rig_config

    try:
        config = load_rig_config(args.config)
        if args.bag is not None and not args.bag.exists():
            raise ValueError(f"bag {args.bag} does not exist")
        commands = node_commands(args, list(config.camera_names))
    except (ConfigError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.output is not None:
        args.output.mkdir(parents=True, exist_ok=True)
    return run_processes(commands, args.duration)


def run_processes(commands: list[NodeCommand], duration: float = 0.0) -> int:
    """Start every command, wait for Ctrl-C / SIGTERM / `duration` or a node's exit, then stop them all."""
    stop_requested = []

    def request_stop(signum, _frame) -> None:
        stop_requested.append(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    processes: list[tuple[NodeCommand, subprocess.Popen]] = []
    exit_code = 0
    try:
        for command in commands:
            # Own process group: a terminal's Ctrl-C reaches this command only, which stops the nodes in order.
            processes.append((command, subprocess.Popen(command.argv, start_new_session=True)))
        print(f"started {', '.join(c.name for c in commands)}; Ctrl-C stops them", file=sys.stderr)
        deadline = time.monotonic() + duration if duration > 0 else None
        while not stop_requested and (deadline is None or time.monotonic() < deadline):
            exited = [(c, p) for c, p in processes if p.poll() is not None]
            if exited:
                command, process = exited[0]
                print(f"error: {command.name} exited with code {process.returncode}; stopping the graph",
                      file=sys.stderr)
                exit_code = 1
                break
            time.sleep(0.1)
    finally:
        stop_all(processes)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return exit_code


def stop_all(processes: list[tuple[NodeCommand, subprocess.Popen]]) -> None:
    for _, process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + GRACE_S
    for command, process in processes:
        try:
            process.wait(timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            print(f"warning: {command.name} ignored SIGINT for {GRACE_S:.0f} s; killing it", file=sys.stderr)
            process.kill()
            process.wait()
