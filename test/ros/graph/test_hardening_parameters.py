"""Issue 66: a `-p` override is checked as the rig file's values are (exit 2 naming the key) whether or not the
key is also in the parameter file, and one of a name no node declares is refused with the nearest suggested."""

from __future__ import annotations

import subprocess

import pytest
from rcl_interfaces.srv import GetParameters
from support.ros_graph import VENV_BIN, RosGraph

from ntcr_recon.ros.node_support import command_line_overrides, ros_argument_value


def start(node: str, rig, *overrides: str) -> subprocess.CompletedProcess:
    argv = [str(VENV_BIN / node), "--ros-args", "--params-file", str(rig)]
    for override in overrides:
        argv += ["-p", override]
    with RosGraph() as graph:  # its own domain: a node that did start hears nothing
        return subprocess.run(argv, capture_output=True, text=True, timeout=60, env=graph.env)


@pytest.mark.parametrize("override, expected", [
    ("robot.notch_count:=abc", "robot.notch_count must be of type int, got 'abc'"),  # 16 in the file
    ("robot.notch_count:=16.5", "robot.notch_count must be of type int, got 16.5"),
    ("cam_a.fps:=abc", "cam_a.fps must be of type float"),
    ("filters.voxel_sise:=0.001", "did you mean 'filters.voxel_size'?"),
    ("max_point:=5", "did you mean 'max_points'?"),
])
def test_a_bad_override_of_a_key_in_the_file_is_refused_naming_it(bags_dir, override, expected):
    result = start("filter_node", bags_dir / "bend45" / "rig.yaml", override)
    assert result.returncode == 2, result.stderr
    assert expected in result.stderr


@pytest.mark.parametrize("override, expected", [
    ("max_points:=abc", "-p max_points:=abc: Wrong parameter type"),  # the node's own parameter, in the file too
    ("max_points:=16.5", "-p max_points:=16.5: Wrong parameter type"),
])
def test_a_bad_override_of_a_nodes_own_parameter_in_the_file_is_refused(bags_dir, tmp_path, override, expected):
    own = tmp_path / "own.yaml"
    own.write_text("/**:\n  ros__parameters:\n    max_points: 60000\n")
    argv = [str(VENV_BIN / "filter_node"), "--ros-args", "--params-file", str(bags_dir / "bend45" / "rig.yaml"),
            "--params-file", str(own), "-p", override]
    with RosGraph() as graph:
        result = subprocess.run(argv, capture_output=True, text=True, timeout=60, env=graph.env)
    assert result.returncode == 2 and expected in result.stderr


def test_an_override_of_another_type_than_the_files_value_is_applied(bags_dir):
    # rcl kept the file's 16 for `-p robot.notch_count:=12.0` (a double for an integer) without a word
    with RosGraph() as graph:
        process = graph.start("filter_node", "--params-file", str(bags_dir / "bend45" / "rig.yaml"),
                              "-p", "robot.notch_count:=12.0", "-p", "cam_a.fps:=15")
        response = graph.call(GetParameters, "/filter_node/get_parameters",
                              GetParameters.Request(names=["robot.notch_count", "cam_a.fps"]))
        count, fps = response.values
        assert count.integer_value == 12
        assert (fps.double_value or fps.integer_value) == 15
        assert process.poll() is None


def test_command_line_overrides_are_read_as_rcl_types_them():
    argv = ["node", "--ros-args", "-r", "__node:=x", "-p", "a.b:=abc", "--param", "x:c:=1", "-p", "d:=[1, 2.5]"]
    assert command_line_overrides(argv) == [(None, "a.b", "abc"), ("x", "c", "1"), (None, "d", "[1, 2.5]")]
    assert [ros_argument_value(t) for t in ("16", "16.5", "1e3", "true", "[1, 2.5]", "abc")] == \
        [16, 16.5, 1000.0, True, [1, 2.5], "abc"]
