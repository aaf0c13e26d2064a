"""The layer rule: the core library and the ROS-free I/O load neither ntcr_recon.ros nor any ROS package."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import ntcr_recon.core
import ntcr_recon.io
import ntcr_recon.sim

ROS_MODULES = ("ntcr_recon.ros", "rclpy", "rosidl_runtime_py", "sensor_msgs", "std_msgs", "builtin_interfaces")


def _modules(package) -> list[str]:
    return [f"{package.__name__}.{info.name}" for info in pkgutil.iter_modules(package.__path__)]


def test_core_io_and_sim_import_no_ros_module():
    modules = _modules(ntcr_recon.core) + _modules(ntcr_recon.io) + _modules(ntcr_recon.sim)
    assert "ntcr_recon.core.pipeline" in modules and "ntcr_recon.io.pointcloud" in modules
    probe = (f"import importlib, sys\nfor name in {modules!r}:\n    importlib.import_module(name)\n"
             f"loaded = sorted(m for m in sys.modules if m.split('.')[0] in {ROS_MODULES!r} "
             f"or m.startswith('ntcr_recon.ros'))\nprint(','.join(loaded))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"ROS modules loaded by the core/io/sim: {result.stdout.strip()}"
