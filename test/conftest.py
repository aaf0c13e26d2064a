"""Shared fixtures. ROS graphs get their own DDS domain and localhost-only discovery, so tests never
hear each other (nor another test run on the same machine)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / "bags"

# Keep every DDS participant of the test run on this machine.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def bags_dir() -> Path:
    return BAGS
