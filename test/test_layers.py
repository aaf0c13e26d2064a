"""The layer rule: the core library and the ROS-free I/O load neither ntcr_recon.ros nor any ROS package (any
message package, rcl*, rosidl*, rmw*: a family, not a fixed list)."""

from __future__ import annotations

import pkgutil
import re
import subprocess
import sys

import ntcr_recon.core
import ntcr_recon.io
import ntcr_recon.sim

# Any message package (*_msgs, *_interfaces), rcl* (rclpy, rcl_interfaces), rosidl*, rmw*, and the adapters.
ROS_PATTERN = r"^(ntcr_recon\.ros($|\.)|\w+_msgs($|\.)|\w+_interfaces($|\.)|rcl|rosidl|rmw)"


def is_ros_module(name: str) -> bool:
    return re.match(ROS_PATTERN, name) is not None


def test_the_ros_module_rule_flags_every_ros_family():
    assert all(is_ros_module(name) for name in ("rclpy", "rclpy.node", "rcl_interfaces.msg", "rosidl_parser",
                                                "rmw_fastrtps_cpp", "geometry_msgs.msg", "nav_msgs",
                                                "builtin_interfaces", "ntcr_recon.ros", "ntcr_recon.ros.cdr"))
    assert not any(is_ros_module(name) for name in ("numpy", "rosbags", "rosbags.typesys", "ntcr_recon.rosette",
                                                    "ntcr_recon.core", "scipy"))


def _modules(package) -> list[str]:
    return [info.name for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}.")]


def test_core_io_and_sim_import_no_ros_module():
    modules = _modules(ntcr_recon.core) + _modules(ntcr_recon.io) + _modules(ntcr_recon.sim)
    assert "ntcr_recon.core.reconstruction.reconstructor" in modules and "ntcr_recon.io.pointcloud" in modules
    probe = (f"import importlib, re, sys\nfor name in {modules!r}:\n    importlib.import_module(name)\n"
             f"loaded = sorted(m for m in sys.modules if re.match({ROS_PATTERN!r}, m))\nprint(','.join(loaded))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"ROS modules loaded by the core/io/sim: {result.stdout.strip()}"


def test_every_test_module_is_in_exactly_one_tier():
    import configparser
    from pathlib import PurePosixPath

    from conftest import DEFAULT_TIER, REPO, TIERS, tier_of

    tests = REPO / "test"
    folders = [PurePosixPath(folder) for folder in TIERS]
    # a tier's folder holds test modules; none lies in another's, so the folder rule gives each test one tier
    assert folders and all(any((tests / folder).rglob("test_*.py")) for folder in folders), sorted(
        str(folder) for folder in folders if not any((tests / folder).rglob("test_*.py")))
    assert not [(a, b) for a in folders for b in folders if a != b and a.is_relative_to(b)]
    # the tiers are pytest.ini's markers, and every one holds a test module
    ini = configparser.ConfigParser()
    ini.read(REPO / "pytest.ini")
    markers = {line.split(":")[0].strip() for line in ini["pytest"]["markers"].splitlines() if line.strip()}
    assert {DEFAULT_TIER, *TIERS.values()} == markers
    assert {tier_of(path) for path in tests.rglob("test_*.py")} == markers
