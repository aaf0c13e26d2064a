#!/usr/bin/env bash
# Regenerate the sample bags of bags/ (see bags/README.md). Deterministic: the same seeds give the same bags.
# Usage: bags/make_samples.sh [python]   (default: the project venv's python)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
python="${1:-$here/../.venv/bin/python}"
simulate() { "$python" -m ntcr_recon.cli simulate "$@" --frames 4 --color-noise 0 --overwrite --no-progress; }
simulate "$here/straight" --bend-deg 0 --seed 1
simulate "$here/bend45" --bend-deg 45 --seed 2
simulate "$here/bend90" --bend-deg 90 --seed 3
simulate "$here/bend45_facing" --bend-deg 45 --notch-side facing --seed 4
du -sh "$here"
