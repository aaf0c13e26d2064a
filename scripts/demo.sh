#!/usr/bin/env bash
# The demo: reconstruct the bundled 45-degree sample bag and leave the mesh, the relocated cloud,
# result.json and the figures in out/demo (or the folder given as the first argument).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/setup_env.sh"
venv="${NTCR_VENV:-$root/.venv}"
out="${1:-$root/out/demo}"
bag="$root/bags/bend45"
"$venv/bin/ntcr-recon" reconstruct "$bag" --config "$bag/rig.yaml" --out "$out"
echo "[demo] results in $out:"
ls -1 "$out"
