#!/usr/bin/env bash
# The demo: the offline reconstruction of the bundled 45-degree sample bag (the metrics and the paper's
# figures), then the same bag replayed through the ROS 2 graph (six nodes, each its own process, real
# rclpy over Fast DDS). Everything lands in out/demo (or the folder given as first argument):
#   graph/    mesh.ply and relocated.ply as the running graph left them
#   offline/  relocated.ply, fused_raw.ply, mesh.ply/.stl, result.json and the figures (PNG)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/setup_env.sh"
venv="${NTCR_VENV:-$root/.venv}"
out="${1:-$root/out/demo}"
bag="$root/bags/bend45"
mkdir -p "$out"
# A private, machine-local DDS domain so the demo neither hears nor disturbs another graph.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"

# The offline command first: on a machine's first run it compiles the kernels (cached on disk), which the
# graph's nodes then load instead of each compiling them while the replay runs.
echo "[demo] offline reconstruction of $bag"
rm -rf "$out/offline"
"$venv/bin/ntcr-recon" reconstruct "$bag" --config "$bag/rig.yaml" --out "$out/offline"
echo "[demo] replaying the same bag through the graph for 15 s"
"$venv/bin/ntcr-recon" run --config "$bag/rig.yaml" --bag "$bag" --loop --use-sim-time \
    --output "$out/graph" --duration 15
echo "[demo] results in $out:"
(cd "$out" && ls -1 graph/* offline/*)
"$venv/bin/python" - "$out/offline/result.json" <<'PY'
import json, sys
result = json.load(open(sys.argv[1]))
truth = result["ground_truth"] or {}
print(f"[demo] notches found {len(result['notches'])} of {result['notch_count_expected']}; "
      f"width MAE {truth.get('width_mae_mm', float('nan')):.3f} mm, "
      f"centreline RMSE {truth.get('centerline_rmse_mm', float('nan')):.3f} mm, "
      f"tip error {truth.get('tip_error_mm', float('nan')):.3f} mm")
PY
