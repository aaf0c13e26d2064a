"""The ways to start the graph: launch files (`launch` is not on PyPI, so they are checked as Python and against
the package: executables, configuration files), the RViz configuration (the topics the nodes publish), and
`ntcr-recon run`'s command lines and refusals."""

from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ntcr_recon.cli import run as run_command
from ntcr_recon.core.config import TopicConfig
from ntcr_recon.ros import graph
from ntcr_recon.ros.topics import stage_topic

REPO = Path(__file__).resolve().parents[1]
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
    stage_nodes = set(ast.literal_eval(re.search(r"STAGE_NODES = (\(.*?\))", source).group(1)))
    assert stage_nodes == set(graph.STAGE_NODES)
    assert (executables - {"rviz2"}) | stage_nodes <= console_scripts() | {"executable"}
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
