"""`ntcr-recon run`: start the whole graph without `ros2 launch`, a process per node (or one, `--single-process`).

    ntcr-recon run --config config/sim_rig.yaml --bag bags/bend45 [--rate 1] [--loop] [--use-sim-time]
    ntcr-recon run --config my_rig.yaml                      # live D405s (camera_node's realsense source)

One camera_node per camera of the configuration (node name `camera_<cam>`), then fusion_node, filter_node,
relocation_node and mesh_node; every process gets the rig configuration as its ROS parameter file. Ctrl-C
(or SIGTERM, or `--duration`) stops them all: SIGINT to each, then a kill for any still alive after a grace
period. A node that dies (a crash, a kill, the OOM killer) is started again after a backoff (1 s, doubling up
to 30 s while it keeps dying within a minute), with a log line, and the rest of the graph runs on; a node that
refuses its configuration (exit code 2) would only refuse it again, so the others are stopped and the command
exits non-zero, naming it. `--no-respawn` stops the graph at any node's exit instead.

`--single-process` hosts every node in one process on one executor (ros/single_process.py; still separate
nodes exchanging PointCloud2 over the middleware): one Python interpreter instead of six, which a machine with
fewer cores than nodes may prefer; one process per node (the default) lets a many-core rig run the stages in
parallel. bench_graph.py measures both.

The nodes talk over UDP on the loopback (NODE_TRANSPORTS), not Fast DDS's shared memory, unless the environment
chooses the transports itself: a reader SIGKILLed on shared memory leaves its port behind, and the node started
again in its place is matched yet hears nothing (eProsima/Fast-DDS#5053, #5469; in a CI run here, a respawned
fusion_node heard 0 Hz for 40 s while the cameras published at 29 Hz). rig.launch.py sets the same.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

STAGE_NODES = ("fusion_node", "filter_node", "relocation_node", "mesh_node")
GRACE_S = 10.0
START_DELAY_S = 3.0  # s for the node processes to start before a replay's first frame is due
CONFIG_REFUSED = 2   # a node's exit code when it refuses its parameters: respawning would not help
RESPAWN_DELAY_S = 1.0
RESPAWN_MAX_DELAY_S = 30.0
STABLE_S = 60.0      # a node that ran this long before dying starts again from the shortest delay
# The DDS transports of the nodes, where the environment does not set them (the module docstring says why).
NODE_TRANSPORTS = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}


def node_environment(environ=None) -> dict[str, str]:
    """The environment a node process starts with: this one's (os.environ), NODE_TRANSPORTS where it has none."""
    return {**NODE_TRANSPORTS, **(os.environ if environ is None else environ)}


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
        if node == "relocation_node":  # calibration.refine's ~/write_calibration edits this file
            parameters["rig_file"] = str(Path(args.config).resolve())
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


def ros_value(value: object) -> str:
    """A parameter value as rcl reads it from `-p name:=VALUE` (or a parameter file's plain scalar)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def _argv(executable: str, node_name: str, config: Path, parameters: dict[str, object]) -> list[str]:
    argv = [sys.executable, "-m", f"ntcr_recon.ros.{executable}", "--ros-args", "-r", f"__node:={node_name}",
            "--params-file", str(config.resolve())]
    for name, value in parameters.items():
        argv += ["-p", f"{name}:={ros_value(value)}"]
    return argv


def main(args: argparse.Namespace) -> int:
    from ntcr_recon.core.config.rig import ConfigError, load_rig_config
    from ntcr_recon.io.bag import bag_problem

    try:
        config = load_rig_config(args.config)
        if args.bag is not None and (problem := bag_problem(args.bag)):
            raise ValueError(problem)
        commands = node_commands(args, list(config.camera_names))
    except (ConfigError, ValueError) as error:
        print(f"ntcr-recon run: error: {error}", file=sys.stderr)
        return 2
    if args.output is not None:
        try:
            args.output.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # an --output that cannot be a folder (a file on the way, no permission)
            print(f"ntcr-recon run: error: --output {args.output}: {error.strerror or error}", file=sys.stderr)
            return 2
    if args.single_process:
        with tempfile.TemporaryDirectory(prefix="ntcr-run-") as folder:
            host = single_process_command(commands, args.config, Path(folder) / "nodes.yaml")
            return run_processes([host], args.duration, respawn=not args.no_respawn)
    return run_processes(commands, args.duration, respawn=not args.no_respawn)


def single_process_command(commands: list[NodeCommand], config: Path, parameters_file: Path) -> NodeCommand:
    """One process hosting every node of `commands`: each node's own parameters go to a parameter file section
    under its name (a global `-p` would reach every node of the process), the rig configuration as it is.

    Each value is written as the plain scalar `-p name:=VALUE` would give rcl, so that rcl's parser types it in
    both modes alike (PyYAML's YAML 1.1 rules differ from rcl's: `1e3` is a string to PyYAML, 1000.0 to rcl)."""
    lines = []
    for command in (c for c in commands if c.parameters):  # rcl refuses an empty ros__parameters
        lines += [f"{command.name}:", "  ros__parameters:"]
        for name, value in command.parameters.items():
            text = ros_value(value)
            if "\n" in text or "\r" in text:
                raise ValueError(f"parameter {command.name}:{name}: a value must be one line, got {text!r}")
            lines.append(f"    {name}: {text}")
    parameters_file.write_text("\n".join(lines) + "\n")
    specs = [f"{_executable(command)}={command.name}" for command in commands]
    argv = [sys.executable, "-m", "ntcr_recon.ros.single_process", *specs, "--ros-args",
            "--params-file", str(config.resolve()), "--params-file", str(parameters_file)]
    return NodeCommand("graph", argv)


def _executable(command: NodeCommand) -> str:
    return command.argv[command.argv.index("-m") + 1].rsplit(".", 1)[-1]


@dataclass
class _Running:
    command: NodeCommand
    process: subprocess.Popen
    started: float
    deaths: int = 0               # deaths in a row, each within STABLE_S of its start
    restart_at: float | None = None


def run_processes(commands: list[NodeCommand], duration: float = 0.0, respawn: bool = True) -> int:
    """Start every command, wait for Ctrl-C / SIGTERM / `duration`, respawning a node that dies (unless it
    refused its configuration, or `respawn` is off: then the graph stops), then stop them all."""
    stop_requested = []

    def request_stop(signum, _frame) -> None:
        stop_requested.append(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    running: list[_Running] = []
    exit_code = 0
    try:
        for command in commands:
            running.append(_Running(command, _start(command), time.monotonic()))
        print(f"started {', '.join(c.name for c in commands)}; Ctrl-C stops them", file=sys.stderr)
        deadline = time.monotonic() + duration if duration > 0 else None
        while not stop_requested and (deadline is None or time.monotonic() < deadline):
            if not _supervise(running, respawn):
                exit_code = 1
                break
            time.sleep(0.1)
    finally:
        stop_all([(r.command, r.process) for r in running])
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return exit_code


def _start(command: NodeCommand) -> subprocess.Popen:
    # Own process group: a terminal's Ctrl-C reaches this command only, which stops the nodes in order. Out of
    # our group, a node would outlive a SIGKILLed runner: the kernel sends it SIGTERM then (Linux).
    return subprocess.Popen(command.argv, start_new_session=True, preexec_fn=_terminate_with_parent(),
                            env=node_environment())


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _terminate_with_parent():
    """A preexec_fn asking the kernel to SIGTERM the child when this process dies, however it dies (Linux
    prctl PR_SET_PDEATHSIG); None elsewhere, where the child is left as before."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import os

    libc = ctypes.CDLL(None, use_errno=True)
    parent = os.getpid()

    def preexec() -> None:
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != parent:  # the runner died before the prctl: nobody would send the signal
            os._exit(1)

    return preexec


def _supervise(running: list[_Running], respawn: bool) -> bool:
    """Respawn what died and is due; False when the graph must stop (a refused configuration, or no respawn)."""
    now = time.monotonic()
    for node in running:
        if node.restart_at is not None:
            if now >= node.restart_at:
                node.process, node.started, node.restart_at = _start(node.command), now, None
                print(f"{node.command.name} started again", file=sys.stderr)
            continue
        code = node.process.poll()
        if code is None:
            continue
        if code == CONFIG_REFUSED or not respawn:
            print(f"ntcr-recon run: error: {node.command.name} exited with code {code}; stopping the graph",
                  file=sys.stderr)
            return False
        node.deaths = node.deaths + 1 if now - node.started < STABLE_S else 1
        delay = min(RESPAWN_DELAY_S * 2 ** (node.deaths - 1), RESPAWN_MAX_DELAY_S)
        node.restart_at = now + delay
        print(f"warning: {node.command.name} exited with code {code}; starting it again in {delay:.0f} s "
              f"(death {node.deaths} in a row)", file=sys.stderr)
    return True


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
