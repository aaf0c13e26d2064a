#!/usr/bin/env bash
# The whole test suite: set up the environment, lint, then pytest (nodes run with real rclpy over Fast DDS).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
NTCR_EXTRAS=test "$root/scripts/setup_env.sh"
venv="${NTCR_VENV:-$root/.venv}"
cd "$root"
echo "[test] ruff"
"$venv/bin/ruff" check .
echo "[test] pytest"
"$venv/bin/python" -m pytest test "$@"
