"""Shared fixtures, and the tiers. ROS graphs get their own DDS domain and localhost-only discovery, so tests never
hear each other (nor another test run on the same machine).

Every test is in one tier, by its module (TIERS; the rest are `unit`): `unit` (the core, the CLI, the simulator,
message conversion: seconds to a few minutes), `graph` (nodes on real rclpy, as processes), `packaging` (a colcon
build), `launch` (the launch files under ROS 2 launch) and `matrix` (rows of the accuracy matrix). While working:
`.venv/bin/python -m pytest -m unit`; the README's test command runs every tier."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / "bags"

# Keep every DDS participant of the test run on this machine.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")


TIERS = {
    "graph": {"test_graph_launch", "test_graph_replay", "test_graph_soak", "test_hardening_graph",
              "test_hardening_parameters", "test_node_camera", "test_node_fusion", "test_node_parameters",
              "test_node_realsense", "test_node_run", "test_node_stages", "test_transform_node"},
    "packaging": {"test_packaging"},
    "launch": {"test_launch_files"},
    "matrix": {"test_accuracy_matrix"},
}


def pytest_collection_modifyitems(items) -> None:
    """Mark each test with its module's tier (`pytest -m unit` runs the fast ones)."""
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1]
        tier = next((name for name, modules in TIERS.items() if module in modules), "unit")
        item.add_marker(getattr(pytest.mark, tier))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def bags_dir() -> Path:
    return BAGS
