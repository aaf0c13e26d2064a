#!/usr/bin/env bash
# Create (or reuse) the project's virtual environment and install everything into it:
# system libraries a dependency needs, the Python dependencies, rclpy and its message
# packages from PyPI wheels, and this package in editable mode. Safe to run again.
#   NTCR_VENV   where the environment lives (default: .venv in the checkout)
#   NTCR_EXTRAS "test" to add the test tools (pytest, ruff, colcon)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${NTCR_VENV:-$root/.venv}"

# open3d links against libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "[setup] installing libusb-1.0-0 (needed by open3d)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "[setup] error: open3d needs the system library libusb-1.0-0; install it with" >&2
    echo "        sudo apt-get install libusb-1.0-0" >&2
    exit 1
  fi
fi

if [ ! -x "$venv/bin/python" ]; then
  python=""
  # quiet: a pyenv shim for a version it does not have active complains, and is simply not taken
  for candidate in python3.12 python3.11 python3; do
    if command -v "$candidate" >/dev/null \
       && "$candidate" -c 'import sys; sys.exit(not (3, 11) <= sys.version_info[:2] <= (3, 12))' 2>/dev/null; then
      python="$candidate"; break
    fi
  done
  if [ -z "$python" ]; then
    echo "[setup] error: Python 3.11 or 3.12 is needed (the ROS 2 Jazzy wheels are built for them)" >&2
    exit 1
  fi
  echo "[setup] creating $venv with $python"
  "$python" -m venv "$venv" || { echo "[setup] error: venv failed; on Debian/Ubuntu: apt-get install python3-venv" >&2; exit 1; }
fi

requirements="$root/requirements.txt"
[ "${NTCR_EXTRAS:-}" = test ] && requirements="$root/requirements-test.txt"
stamp="$venv/.ntcr-installed-$(cat "$requirements" "$root/requirements.txt" "$root/setup.py" | sha1sum | cut -c1-12)"
if [ ! -e "$stamp" ]; then
  echo "[setup] installing dependencies into $venv (the first time takes a few minutes)"
  log="$venv/pip-install.log"
  # pip's chatter goes to a log, shown only when something fails.
  if ! { "$venv/bin/python" -m pip install --upgrade pip \
         && "$venv/bin/python" -m pip install -r "$requirements" \
         && "$venv/bin/python" -m pip install --no-deps -e "$root"; } >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "[setup] error: pip install failed (full log: $log)" >&2
    exit 1
  fi
  touch "$stamp"
fi

# The test tools: ROS 2's launch system (launch, launch_ros, launch_testing, launch_testing_ros, ros2launch) for
# the launch tests. On a rig it comes with ROS; elsewhere from the jazzy sources beside the checkout
# (../shared/ros2-launch-jazzy, or NTCR_ROS2_LAUNCH_SRC), installed from a writable copy (shared/ may be
# read-only). Without either, the launch tests are skipped and say so.
if [ "${NTCR_EXTRAS:-}" = test ] \
   && ! "$venv/bin/python" -c 'import launch, launch_ros, launch_testing, launch_testing_ros, ros2launch' 2>/dev/null; then
  launch_src="${NTCR_ROS2_LAUNCH_SRC:-$root/../shared/ros2-launch-jazzy}"
  if [ -d "$launch_src/launch/launch" ]; then
    echo "[setup] installing ROS 2 launch (jazzy) from $launch_src into $venv"
    copy="$(mktemp -d)/ros2-launch" && cp -r "$launch_src" "$copy" && chmod -R u+w "$copy"
    log="$venv/pip-install-launch.log"
    if ! { "$venv/bin/python" -m pip install osrf-pycommon PyYAML importlib-metadata \
           && "$venv/bin/python" -m pip install --no-deps "$copy"/launch/launch "$copy"/launch/launch_xml \
                "$copy"/launch/launch_yaml "$copy"/launch/launch_testing "$copy"/launch_ros/launch_ros \
                "$copy"/launch_ros/ros2launch "$copy"/launch_ros/launch_testing_ros \
           && cp -r "$copy"/stand-ins/composition_interfaces \
                "$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/"; } \
         >"$log" 2>&1; then
      tail -n 40 "$log" >&2
      echo "[setup] error: installing ROS 2 launch failed (full log: $log)" >&2
      exit 1
    fi
    rm -rf "$(dirname "$copy")"
  else
    echo "[setup] ROS 2 launch is not installed and $launch_src is not there: the launch tests will be skipped"
  fi
fi

# The numba kernels compiled now rather than in a node's first start (a few seconds when they already are).
"$venv/bin/python" -m ntcr_recon.sim.warm_up
