"""The ways to start the graph: launch files (checked as Python and against the package: executables,
configuration files; run under ROS 2's own launch in test_launch_files.py), the RViz configuration (the topics
the nodes publish), and `ntcr-recon run`'s command lines and refusals."""

from __future__ import annotations

import argparse
import ast
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from support import REPO

from ntcr_recon.cli import run as run_command
from ntcr_recon.core.config.rig import TopicConfig
from ntcr_recon.ros import graph
from ntcr_recon.ros.topics import stage_topic

LAUNCH_FILES = sorted((REPO / "launch").glob("*.launch.py"))
RUN = Path(sys.executable).parent / "ntcr-recon"


def console_scripts() -> set[str]:
    setup = ast.parse((REPO / "setup.py").read_text())
    nodes = next(n.value for n in ast.walk(setup) if isinstance(n, ast.Assign)
                 and any(getattr(t, "id", None) == "NODES" for t in n.targets))
    return set(ast.literal_eval(nodes))


@pytest.mark.parametrize("path", [p for p in LAUNCH_FILES if p.name in ("rig.launch.py", "replay.launch.py")],
                         ids=lambda p: p.name)
def test_launch_file_is_python_naming_existing_executables_and_config(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    source = (REPO / "launch" / "rig.launch.py").read_text()  # replay reuses rig.launch.py's graph
    executables = set(re.findall(r'executable="(\w+)"', source))
    # the stage nodes are `ntcr-recon run`'s, imported rather than copied
    assert re.search(r"from ntcr_recon\.ros\.graph import .*\bSTAGE_NODES\b", source)
    assert (executables - {"rviz2"}) | set(graph.STAGE_NODES) <= console_scripts() | {"executable"}
    assert {"camera_node"} <= executables
    for config in re.findall(r'"config", "([\w.]+)"', path.read_text()):
        assert (REPO / "config" / config).is_file(), config


def test_rviz_config_shows_what_the_nodes_publish():
    document = yaml.safe_load((REPO / "config" / "ntcr.rviz").read_text())
    displays = document["Visualization Manager"]["Displays"]
    topics = {d["Topic"]["Value"]: d for d in displays if "Topic" in d}
    expected = {stage_topic(TopicConfig(), name) for name in ("fused/points", "relocated/points", "mesh",
                                                              "centerline", "tip", "notches/markers")}
    assert set(topics) == expected
    assert topics["/ntcr/mesh"]["Topic"]["Durability Policy"] == "Transient Local"
    assert document["Visualization Manager"]["Global Options"]["Fixed Frame"] == "ntcr_base"


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    run_command.add_arguments(parser)
    return parser.parse_args(argv)


def test_run_starts_one_camera_node_per_camera_and_every_stage(tmp_path):
    args = parse(["--config", "config/sim_rig.yaml", "--bag", str(tmp_path), "--rate", "0.5", "--use-sim-time",
                  "--param", "mesh_node:rate:=2.0"])
    commands = graph.node_commands(args, ["cam_a", "cam_b"])
    assert [c.name for c in commands] == ["camera_cam_a", "camera_cam_b", *graph.STAGE_NODES]
    first, second = commands[0].parameters, commands[1].parameters
    assert first["source"] == "bag" and first["publish_clock"] and not second["publish_clock"]
    assert first["start_time"] == second["start_time"] > 0  # the cameras replay in step
    assert all(c.parameters.get("use_sim_time") for c in commands[2:])
    assert commands[-1].parameters["rate"] == "2.0"
    for command in commands:
        assert command.argv[1:3] == ["-m", f"ntcr_recon.ros.{command.argv[2].rsplit('.', 1)[-1]}"]
        assert "--params-file" in command.argv and f"__node:={command.name}" in command.argv
    live = graph.node_commands(parse(["--config", "config/sim_rig.yaml", "--no-mesh"]), ["cam_a", "cam_b"])
    assert live[0].parameters["source"] == "realsense" and "mesh_node" not in [c.name for c in live]


@pytest.mark.parametrize("argv, message", [
    (["--config", "/nonexistent.yaml"], "cannot read rig configuration"),
    (["--config", "config/sim_rig.yaml", "--bag", "/nonexistent/bag"], "bag /nonexistent/bag does not exist"),
    (["--config", "config/sim_rig.yaml", "--file", "cam_z=/x.bag"], "CAM one of ['cam_a', 'cam_b']"),
    (["--config", "config/sim_rig.yaml", "--param", "nope_node:rate:=1"], "unknown node(s) ['nope_node']"),
    # review: a bad --output was a traceback (README.md is a file, not a folder)
    (["--config", "config/sim_rig.yaml", "--output", "README.md/out"], "--output README.md/out: Not a directory"),
])
def test_run_refuses_bad_arguments_by_name(argv, message):
    result = subprocess.run([str(RUN), "run", *argv], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert result.returncode == 2
    assert message in result.stderr, result.stderr


def test_run_stops_the_graph_when_a_node_fails(tmp_path):
    # A node that refuses its parameters exits; `run` says which and stops the rest.
    result = subprocess.run([str(RUN), "run", "--config", "config/sim_rig.yaml", "--bag", "bags/bend45",
                             "--param", "mesh_node:rate:=-1.0", "--duration", "60"],
                            capture_output=True, text=True, cwd=REPO, timeout=90)
    assert result.returncode == 1
    assert "mesh_node exited with code" in result.stderr, result.stderr


def run_bend45_in_a_loop(graph, log, *options: str) -> subprocess.Popen:
    """`ntcr-recon run` replaying bags/bend45 in a loop (for two minutes at most) in `graph`'s DDS domain, its
    output into the open file `log`."""
    return subprocess.Popen([str(RUN), "run", "--config", "bags/bend45/rig.yaml", "--bag", "bags/bend45", "--loop",
                             *options, "--duration", "120"], cwd=REPO, env=graph.env, stdout=log,
                            stderr=subprocess.STDOUT)


STEADY_CLOUDS = 30  # fused clouds before a node is killed: about a second of the graph running


def test_run_respawns_a_node_that_dies_and_the_graph_goes_on(tmp_path):
    # issue 11: a killed node (here SIGKILL, as the OOM killer would) is started again with a log line, and
    # the fused clouds flow again; the other nodes were never stopped.
    from sensor_msgs.msg import PointCloud2
    from support.ros_graph import RosGraph
    from support.stage_probe import COLLECT_RELIABLE

    log_path = tmp_path / "run.log"
    with RosGraph() as graph:
        fused = []
        graph.node.create_subscription(PointCloud2, "/ntcr/fused/points", fused.append, COLLECT_RELIABLE)
        with log_path.open("w") as log:
            run = run_bend45_in_a_loop(graph, log, "--no-mesh")
        try:
            # a node of a graph that has run a while, as the OOM killer meets one: killed at the first fused cloud,
            # while the others were still discovering it, the respawned reader heard nothing for 60 s in 2 of 7
            # full CI runs, over UDP as over shared memory (not reproduced alone; issue 11's note)
            assert graph.spin_until(lambda: len(fused) >= STEADY_CLOUDS, 60), log_path.read_text()
            children = {name: pid for pid, name in node_names(run.pid).items()}
            os.kill(children["fusion_node"], signal.SIGKILL)
            assert graph.spin_until(lambda: "fusion_node started again" in log_path.read_text(), 30), \
                log_path.read_text()
            count = len(fused)
            assert graph.spin_until(lambda: len(fused) > count, 60), log_path.read_text()
            after = node_names(run.pid)
            assert sorted(after.values()) == sorted(children)  # every node there, fusion_node a new process
            assert {pid for pid, name in after.items() if name == "fusion_node"} != {children["fusion_node"]}
            assert all(children[name] in after for name in children if name != "fusion_node")
            # over UDP, not shared memory: a respawned reader there may hear nothing (ros.graph.NODE_TRANSPORTS)
            assert all(environment_of(pid)["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4" for pid in after)
        finally:
            run.send_signal(signal.SIGINT)
            code = run.wait(timeout=60)
    text = log_path.read_text()
    assert "fusion_node exited with code -9; starting it again in 1 s" in text, text
    assert code == 0, text


def environment_of(pid: int) -> dict[str, str]:
    entries = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace").split("\0")
    return dict(entry.split("=", 1) for entry in entries if "=" in entry)


def test_nodes_take_udp_unless_the_environment_chooses_the_transports():
    assert graph.node_environment({"PATH": "/bin"}) == {"PATH": "/bin", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    chosen = {"FASTDDS_BUILTIN_TRANSPORTS": "SHM"}
    assert graph.node_environment(chosen) == chosen


def test_nodes_end_when_run_is_killed(tmp_path):
    # review: the nodes run in their own sessions; a SIGKILLed `ntcr-recon run` left them orphaned, running
    from support.ros_graph import RosGraph

    log_path = tmp_path / "run.log"
    with RosGraph() as ros, log_path.open("w") as log:
        run = run_bend45_in_a_loop(ros, log, "--no-mesh")
        try:
            assert ros.spin_until(lambda: len(node_names(run.pid)) == 5, 60), log_path.read_text()
            children = list(node_names(run.pid))
        finally:
            run.kill()
            run.wait(timeout=30)
        try:
            assert ros.spin_until(lambda: not any(Path(f"/proc/{pid}").exists() and not _zombie(pid)
                                                  for pid in children), 30), log_path.read_text()
        finally:
            for pid in children:  # never leave them behind, even when the test fails
                if Path(f"/proc/{pid}").exists():
                    os.kill(pid, signal.SIGKILL)


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True


def node_names(run_pid: int) -> dict[int, str]:
    """pid -> node name of the children of `ntcr-recon run`."""
    pids = [int(p) for p in subprocess.run(["pgrep", "-P", str(run_pid)], capture_output=True,
                                           text=True).stdout.split()]
    names = {}
    for pid in pids:
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        name = next((a.decode().split(":=")[1] for a in argv if a.startswith(b"__node:=")), None)
        if name is not None:  # None: forked, not yet exec'd (still the runner's command line)
            names[pid] = name
    return names


def test_readme_replay_example_loops():
    # issue 11: the sample bags are 0.1 s long; the README's replay example without loop gave a handful of tips.
    readme = (REPO / "README.md").read_text()
    example = next(line for line in readme.splitlines() if "replay.launch.py" in line)
    assert "loop:=true" in example, example


def test_run_single_process_hosts_every_node_in_one_process(tmp_path):
    # --single-process: the same separate nodes (names, topics) on one executor in one process.
    from geometry_msgs.msg import PoseStamped
    from support.ros_graph import RosGraph
    from support.stage_probe import COLLECT_RELIABLE

    log_path = tmp_path / "run.log"
    with RosGraph() as ros:
        tips = []
        ros.node.create_subscription(PoseStamped, "/ntcr/tip", tips.append, COLLECT_RELIABLE)
        with log_path.open("w") as log:
            run = run_bend45_in_a_loop(ros, log, "--single-process", "--param", "mesh_node:rate:=2.0")
        try:
            assert ros.spin_until(lambda: len(tips) >= 3, 90), log_path.read_text()
            # node names travel on their own discovery topic (ros_discovery_info), which can reach the probe after
            # the data does (CI: tips received while only the probe's own name was known): wait for them as well
            expected = {"camera_cam_a", "camera_cam_b", *graph.STAGE_NODES}
            ros.spin_until(lambda: expected <= set(ros.node.get_node_names()), 30)
            names = set(ros.node.get_node_names())
            children = subprocess.run(["pgrep", "-P", str(run.pid)], capture_output=True, text=True).stdout.split()
        finally:
            run.send_signal(signal.SIGINT)
            code = run.wait(timeout=60)
    assert expected <= names, names
    assert len(children) == 1
    assert code == 0, log_path.read_text()
    assert "Traceback" not in log_path.read_text()



@pytest.mark.parametrize("value", ["1_000", "1:30", "~", "1e3", "yes", "[1.0, 2.5]"])
def test_single_process_types_a_param_as_a_process_per_node_does(tmp_path, value):
    # review: --single-process re-parsed --param values with PyYAML (YAML 1.1: '1_000' 1000, '1:30' 90, '~' null)
    # while a process per node hands them to rcl's `-p`; both now go through rcl's parser
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    def parsed(ros_args: list[str]):
        context = Context()
        rclpy.init(context=context, args=["node", "--ros-args", *ros_args])
        try:
            node = Node("mesh_node", context=context, automatically_declare_parameters_from_overrides=True)
            result = node.get_parameter("rate").value
            node.destroy_node()
            return result
        finally:
            rclpy.shutdown(context=context)

    args = parse(["--config", "config/sim_rig.yaml", "--bag", "bags/bend45", "--param", f"mesh_node:rate:={value}"])
    commands = graph.node_commands(args, ["cam_a", "cam_b"])
    per_process = next(c for c in commands if c.name == "mesh_node").argv
    host = graph.single_process_command(commands, Path("config/sim_rig.yaml"), tmp_path / "nodes.yaml")
    node_file = host.argv[host.argv.index("--params-file", host.argv.index("--params-file") + 1) + 1]
    expected = parsed(["-p", f"rate:={value}"])
    assert f"-p rate:={value}" in " ".join(per_process)
    got = parsed(["--params-file", node_file])
    assert got == expected and type(got) is type(expected)
