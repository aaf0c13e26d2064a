"""Shared fixtures, and the tiers. ROS graphs get their own DDS domain and localhost-only discovery, so tests never
hear each other (nor another test run on the same machine).

Every test is in one tier, by the folder it sits in (TIERS; a folder's tier holds for the folders under it, and
every other test is `unit`): `unit` (the core, the CLI, the simulator, message conversion: seconds to a few minutes),
`graph` (test/ros/graph: nodes on real rclpy, as processes), `packaging` (test/packaging: a colcon build), `launch`
(test/launch: the launch files under ROS 2 launch) and `matrix` (test/benchmarks: rows of the accuracy matrix). While
working: `.venv/bin/python -m pytest -m unit`; the README's test command runs every tier.

The tests mirror the code (test/core/<sub-package>, test/io, test/ros, test/cli, test/sim); their helpers are in
test/support (`from support import tiny_rig`: this folder is on sys.path, as the rootdir conftest's)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from support import BAGS, REPO

# Keep every DDS participant of the test run on this machine.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")


# folder under test/ -> the tier of every test in it (and in the folders under it); no folder here lies in another
TIERS = {
    "ros/graph": "graph",
    "packaging": "packaging",
    "launch": "launch",
    "benchmarks": "matrix",
}
DEFAULT_TIER = "unit"


def tier_of(path: Path) -> str:
    """The tier of the test module at `path`: that of the TIERS folder holding it, else `unit`."""
    relative = Path(path).resolve().relative_to(REPO / "test")
    return next((tier for folder, tier in TIERS.items() if relative.is_relative_to(folder)), DEFAULT_TIER)


def pytest_collection_modifyitems(items) -> None:
    """Mark each test with its folder's tier (`pytest -m unit` runs the fast ones)."""
    for item in items:
        item.add_marker(getattr(pytest.mark, tier_of(item.path)))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def bags_dir() -> Path:
    return BAGS
