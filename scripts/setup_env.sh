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
