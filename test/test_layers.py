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


# The core's layers, lowest first: a module imports from its own layer and those below it, never above.
CORE_LAYERS = ("base", "robot", "config", "cloud", "relocation", "calibration", "fit", "quality", "reconstruction")



def _imports(path) -> set[str]:
    """Every ntcr_recon module a source file imports, at any depth (function bodies and TYPE_CHECKING too)."""
    import ast

    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name for name in found if name.startswith("ntcr_recon.")}


def _package_modules() -> dict[str, object]:
    from conftest import REPO

    root = REPO / "ntcr_recon"
    return {".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__"): path
            for path in sorted(root.rglob("*.py"))}


def _core_layer(module: str) -> int | None:
    parts = module.split(".")
    return CORE_LAYERS.index(parts[2]) if len(parts) > 2 and parts[1] == "core" and parts[2] in CORE_LAYERS \
        else None


def test_every_core_module_sits_in_a_layer():
    modules = _package_modules()
    loose = [name for name in modules if name.startswith("ntcr_recon.core.") and _core_layer(name) is None]
    assert not loose, f"core modules outside the layer packages {CORE_LAYERS}: {loose}"


def test_no_core_layer_imports_a_higher_one():
    modules = _package_modules()
    upward = []
    for name, path in modules.items():
        layer = _core_layer(name)
        if layer is None:
            continue
        for imported in _imports(path):
            if imported.startswith("ntcr_recon.") and not imported.startswith("ntcr_recon.core."):
                upward.append(f"{name} -> {imported} (core imports nothing outside core)")
            elif (other := _core_layer(imported)) is not None and other > layer:
                upward.append(f"{name} -> {imported}")
    assert not upward, "imports from a higher layer:\n" + "\n".join(upward)


def test_no_import_cycle_among_the_package_modules():
    modules = _package_modules()
    graph = {name: {imported for imported in _imports(path) if imported in modules and imported != name
                    and not name.startswith(imported + ".")}  # a package's own __init__ is not a cycle
             for name, path in modules.items()}
    cycles, state = [], {}

    def visit(name, stack):
        state[name] = "open"
        for imported in sorted(graph[name]):
            if state.get(imported) == "open":
                cycles.append(" -> ".join(stack[stack.index(imported):] + [imported]))
            elif imported not in state:
                visit(imported, stack + [imported])
        state[name] = "done"

    for name in modules:
        if name not in state:
            visit(name, [name])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


# Limits that keep modules and functions readable; numba kernels (arrays in, arrays out) take many parameters.
MODULE_LINES, FUNCTION_LINES, FUNCTION_PARAMETERS = 450, 80, 12


def _over_limits(path) -> list[str]:
    import ast

    source = path.read_text()
    over = [f"{path.name}: {len(source.splitlines())} lines"] if len(source.splitlines()) > MODULE_LINES else []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        if any("jit" in ast.unparse(decorator) for decorator in node.decorator_list):
            continue
        args = node.args
        parameters = [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]
        count = sum(arg is not None and arg.arg not in ("self", "cls") for arg in parameters)
        length = node.end_lineno - node.lineno + 1
        if length > FUNCTION_LINES or count > FUNCTION_PARAMETERS:
            over.append(f"{path.name}:{node.lineno} {node.name}: {length} lines, {count} parameters")
    return over


def test_the_limit_rule_catches_a_long_module_and_a_wide_function(tmp_path):
    wide = tmp_path / "wide.py"
    wide.write_text("def f(" + ", ".join(f"a{i}" for i in range(13)) + "):\n    pass\n" + "\n" * MODULE_LINES)
    assert len(_over_limits(wide)) == 2


def test_modules_and_functions_keep_within_the_limits():
    over = [line for path in _package_modules().values() for line in _over_limits(path)]
    assert not over, "over the limits:\n" + "\n".join(over)
