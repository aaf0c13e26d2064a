"""The package as a rig builds it: `colcon build` of an ament_python package, and its manifest."""

from __future__ import annotations

import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from support import NODE_EXECUTABLES, REPO

COLCON = Path(sys.executable).parent / "colcon"


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory) -> Path:
    workspace = tmp_path_factory.mktemp("colcon_ws")
    tracked = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                             check=True, capture_output=True, text=True).stdout.split()
    for relative in tracked:
        if (REPO / relative).is_file():
            target = workspace / "src" / "ntcr_recon" / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / relative, target)
    result = subprocess.run([str(COLCON), "build", "--event-handlers", "console_direct-"], cwd=workspace,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / "install"


def test_colcon_build_gives_the_layout_a_rig_expects(colcon_install):
    prefix = colcon_install / "ntcr_recon"
    for executable in NODE_EXECUTABLES + ("ntcr-recon",):
        assert (prefix / "lib" / "ntcr_recon" / executable).is_file(), executable
    assert (prefix / "share" / "ntcr_recon" / "package.xml").is_file()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "ntcr_recon").is_file()
    for folder, pattern in (("launch", "*.launch.py"), ("config", "*.yaml")):
        sources = sorted(p.name for p in (REPO / folder).glob(pattern))
        assert sources, f"the package ships no {folder}/{pattern}"
        installed = sorted(p.name for p in (prefix / "share" / "ntcr_recon" / folder).glob(pattern))
        assert installed == sources


def test_colcon_installs_every_module_of_the_package(colcon_install):
    # a folder of modules without __init__.py imports from a checkout but is left out by find_packages
    sources = sorted(str(p.relative_to(REPO)) for p in (REPO / "ntcr_recon").rglob("*.py"))
    site = next(colcon_install.glob("ntcr_recon/lib/python3*/site-packages"))
    installed = sorted(str(p.relative_to(site)) for p in (site / "ntcr_recon").rglob("*.py"))
    assert installed == sources


def test_colcon_installed_command_runs(colcon_install):
    # As on a rig: source the workspace, then the installed entry point imports the installed package.
    result = subprocess.run(["bash", "-c", f"source {colcon_install}/setup.bash && "
                             f"{colcon_install}/ntcr_recon/lib/ntcr_recon/ntcr-recon --help"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    for subcommand in ("simulate", "reconstruct", "run"):
        assert subcommand in result.stdout


def test_package_xml_names_every_dependency():
    manifest = ET.parse(REPO / "package.xml").getroot()
    assert manifest.get("format") == "3"
    assert manifest.findtext("export/build_type") == "ament_python"
    depends = {element.text for element in manifest if element.tag in ("exec_depend", "depend", "test_depend")}
    required = {"rclpy", "sensor_msgs", "std_msgs", "geometry_msgs", "nav_msgs", "visualization_msgs",
                "shape_msgs", "diagnostic_msgs", "python3-numpy", "python3-scipy", "python3-open3d-pip",
                "python3-pyrealsense2-pip", "python3-rosbags-pip", "python3-mcap-pip", "python3-pytest"}
    assert required <= depends, required - depends


def test_package_xml_names_every_ros_package_the_code_imports():
    # review: camera_node imports rosgraph_msgs (Clock), which package.xml did not name
    import re

    manifest = ET.parse(REPO / "package.xml").getroot()
    depends = {element.text for element in manifest if element.tag in ("exec_depend", "depend")}
    pattern = re.compile(r"^\s*(?:from|import)\s+(rclpy|\w+_msgs|\w+_interfaces)\b", re.MULTILINE)
    imported = {name for path in (REPO / "ntcr_recon").rglob("*.py") for name in pattern.findall(path.read_text())}
    assert {"rclpy", "sensor_msgs", "rosgraph_msgs"} <= imported
    assert imported <= depends, imported - depends


def test_cli_lists_its_subcommands():
    result = subprocess.run([str(Path(sys.executable).parent / "ntcr-recon"), "--help"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    assert all(name in result.stdout for name in ("simulate", "render", "reconstruct", "run"))


def test_the_rosdep_source_the_readme_registers_resolves_every_pip_key_of_package_xml():
    """rosdistro's database lacks python3-rosbags-pip, -mcap-pip, -pyrealsense2-pip and -ruff-pip (and has
    python3-numba for Ubuntu up to 20.04 only): rosdep install would stop at them. The package's own source
    defines each for Debian and Ubuntu, by the PyPI name requirements*.txt pins, and the README registers it."""
    import re

    import yaml

    manifest = ET.parse(REPO / "package.xml").getroot()
    pip_keys = {element.text for element in manifest if element.text and element.text.endswith("-pip")}
    source = yaml.safe_load((REPO / "rosdep" / "ntcr_recon.yaml").read_text())
    assert pip_keys | {"python3-numba"} <= set(source), (pip_keys | {"python3-numba"}) - set(source)
    requirements = {re.split(r"[<>=\s#]", line, maxsplit=1)[0].lower()
                    for name in ("requirements.txt", "requirements-test.txt")
                    for line in (REPO / name).read_text().splitlines() if line and line[0].isalpha()}
    for key in pip_keys:
        for platform in ("debian", "ubuntu"):
            (package,) = source[key][platform]["pip"]["packages"]
            assert package.lower() in requirements, (key, package)
    assert "rosdep/ntcr_recon.yaml" in (REPO / "README.md").read_text()
