"""The launch files under ROS 2's own launch system, as a rig starts them: `launch_testing` tests (test/launch/,
with launch_testing_ros's WaitForTopics) run by `launch_test` against a `colcon build` of the package, the way
`colcon test` runs a package's launch tests.

ROS 2's launch comes with ROS on a rig; elsewhere scripts/setup_env.sh (the README's test command runs it)
installs it into the test environment from ../shared/ros2-launch-jazzy. Where neither is there, these tests
are skipped and say so. The build is made once per session, in ~/.cache/ntcr_recon/launch-tests/ws-<digest of the
sources and the test environment's path> (kept while they are unchanged, so is its kernel cache), and its kernels
compiled there before the first launch."""

from __future__ import annotations

import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support import NODE_EXECUTABLES, REPO

LAUNCH_TESTS = Path(__file__).resolve().parent  # the launch_testing files beside this one
BIN = Path(sys.executable).parent
CACHE = Path(os.environ.get("NTCR_LAUNCH_TEST_DIR", Path.home() / ".cache" / "ntcr_recon" / "launch-tests"))


try:
    import launch_testing  # noqa: F401
    import launch_testing_ros  # noqa: F401
    import ros2launch  # noqa: F401
    MISSING = None
except ImportError as error:
    MISSING = (f"ROS 2's launch is not installed ({error}): source ROS 2 Jazzy, or run scripts/setup_env.sh with "
               "NTCR_EXTRAS=test beside ../shared/ros2-launch-jazzy")


def _sources() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                            capture_output=True, check=True).stdout.decode().split("\0")
    return sorted(REPO / name for name in listed if name and not name.startswith(("bags/", "test/", "benchmarks/"))
                  and (REPO / name).is_file())


STALE_AFTER_S = 24 * 3600  # another digest's workspace unused this long is no other test run's


def _runnable(executable: Path) -> bool:
    """The script is there and so is the interpreter its #! line names (a build carried over from another
    checkout's environment names that environment's python, and spawning it fails with 'No such file')."""
    if not executable.is_file():
        return False
    with open(executable, "rb") as script:
        first = script.readline()
    return not first.startswith(b"#!") or Path(first[2:].split()[0].decode()).is_file()


def _complete(ws: Path, stamp: Path, sources: list[Path]) -> bool:
    """The build finished (its stamp), and every executable a launch file starts (with its interpreter) and every
    module of the package is in its install (a cache carried over from elsewhere can hold a stamp beside a part of
    a build, or a build for another environment)."""
    prefix = ws / "install" / "ntcr_recon"
    site = next(prefix.glob("lib/python3*/site-packages"), None)
    modules = [path.relative_to(REPO) for path in sources if path.suffix == ".py" and
               path.relative_to(REPO).parts[0] == "ntcr_recon"]
    return (stamp.exists() and site is not None and all((site / module).is_file() for module in modules)
            and all(_runnable(prefix / "lib" / "ntcr_recon" / name) for name in (*NODE_EXECUTABLES, "ntcr-recon")))


def _build(ws: Path, sources: list[Path]) -> None:
    shutil.rmtree(ws, ignore_errors=True)
    package = ws / "src" / "ntcr_recon"
    for path in sources:
        target = package / path.relative_to(REPO)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target)
    env = {**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}
    build = subprocess.run([str(BIN / "colcon"), "build", "--event-handlers", "console_direct-"], cwd=ws,
                           env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]


def _workspace(sources: list[Path]) -> Path:
    """The colcon workspace of these sources: one per digest of them, built under a lock and never deleted while
    fresh, so two test runs sharing the cache (two checkouts, two CI jobs) never build into, or delete, the
    workspace the other is launching from."""
    digest = hashlib.sha1(str(BIN).encode())  # the environment the build's scripts run in is part of what it is
    for path in sources:
        digest.update(str(path.relative_to(REPO)).encode() + b"\0" + path.read_bytes())
    CACHE.mkdir(parents=True, exist_ok=True)
    ws = CACHE / f"ws-{digest.hexdigest()[:16]}"
    stamp = ws / ".built"
    with open(CACHE / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not _complete(ws, stamp, sources):
            _build(ws, sources)
        stamp.touch()  # its time says when a run last used it
        for other in CACHE.glob("ws*"):  # and the single `ws` of earlier versions of this file
            used = other / ".built" if (other / ".built").exists() else other
            if other != ws and time.time() - used.stat().st_mtime > STALE_AFTER_S:
                shutil.rmtree(other, ignore_errors=True)
    return ws


@pytest.fixture(scope="session")
def colcon_install() -> dict[str, str]:
    """The environment of a colcon build of this checkout (`source install/setup.bash`), its kernels compiled."""
    if MISSING:
        pytest.skip(MISSING)
    if not (BIN / "colcon").exists():
        pytest.skip("colcon is not installed in the test environment (requirements-test.txt)")
    ws = _workspace(_sources())
    dump = subprocess.run(["bash", "-c", f"source {ws}/install/setup.bash && env -0"], capture_output=True,
                          check=True, env={**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}).stdout
    env = dict(line.split("=", 1) for line in dump.decode().split("\0") if "=" in line)
    # the build's kernels compiled once, before any launch (a node would do it at its first start, as on a rig)
    warm = subprocess.run([sys.executable, "-m", "ntcr_recon.sim.warm_up"], env=env, capture_output=True, text=True,
                          timeout=900, cwd=ws)
    assert warm.returncode == 0, warm.stdout + warm.stderr
    assert str(ws / "install") in warm.stdout or "ntcr_recon" in warm.stdout, warm.stdout
    print(warm.stdout.strip())
    return env


def launch_test(env: dict[str, str], name: str, domain: int, timeout: float = 420) -> str:
    """`launch_test test/launch/<name>` in the build's environment, in DDS domain `domain`; its output."""
    run_env = {**env, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
               "NTCR_TEST_BAG": str(REPO / "bags" / "bend45"), "PYTHONUNBUFFERED": "1"}
    result = subprocess.run([sys.executable, "-m", "launch_testing.launch_test", str(LAUNCH_TESTS / name)],
                            env=run_env, capture_output=True, text=True, timeout=timeout, cwd=REPO)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-6000:]
    return output


def test_replay_launch_brings_the_frame_pairs_to_the_tip(colcon_install):
    output = launch_test(colcon_install, "replay_launch.py", 71)
    assert "frame pairs reached /ntcr/tip" in output, output[-3000:]
    print(next(line for line in output.splitlines() if "frame pairs reached /ntcr/tip" in line))  # -s: the figure
    assert "compiling the numba kernels" not in output  # compiled before, never inside the frames
    assert re.search(r"test_the_nodes_talk_over_udp .*\.\.\. ok", output), output[-3000:]


def test_rig_launch_without_cameras_waits_and_ends_on_ctrl_c(colcon_install):
    output = launch_test(colcon_install, "rig_no_camera_launch.py", 72)
    assert "waiting for the device" in output and "/diagnostics" in output, output[-3000:]


def test_a_node_refusing_its_configuration_shuts_the_launch_down_with_the_reason(colcon_install):
    output = launch_test(colcon_install, "refused_config_launch.py", 73, timeout=300)
    # the reason, as the launch's own log line says it (test/launch/refused_config_launch.py logs it: launch does not)
    assert "launch shut down: mesh_node-" in output and "refused its configuration (exit code 2)" in output, \
        output[-3000:]
    assert "process has died" in output and "exit code 2" in output, output[-3000:]  # launch's line for the exit
    assert "robot.notch_count must be > 0" in output, output[-3000:]


def test_a_cached_build_whose_scripts_name_a_missing_interpreter_is_rebuilt(tmp_path):
    """A workspace built from the same sources in another checkout's environment (a cache carried over) has node
    scripts whose #! names that environment's python: launching them fails with 'No such file'. Needs no ROS."""
    ws, sources = tmp_path / "ws", [REPO / "ntcr_recon" / "__init__.py"]
    prefix = ws / "install" / "ntcr_recon"
    (prefix / "lib" / "python3.11" / "site-packages" / "ntcr_recon").mkdir(parents=True)
    (prefix / "lib" / "python3.11" / "site-packages" / "ntcr_recon" / "__init__.py").touch()
    (ws / ".built").touch()
    for interpreter, complete in ((tmp_path / "gone" / "bin" / "python", False), (Path(sys.executable), True)):
        for name in (*NODE_EXECUTABLES, "ntcr-recon"):
            (prefix / "lib" / "ntcr_recon" / name).parent.mkdir(parents=True, exist_ok=True)
            (prefix / "lib" / "ntcr_recon" / name).write_text(f"#!{interpreter}\nprint()\n")
        assert _complete(ws, ws / ".built", sources) is complete
