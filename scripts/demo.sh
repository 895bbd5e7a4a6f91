#!/usr/bin/env bash
# The main job: write the forest paper's Table 2 forest (at scale 0.05 by
# default: 48 trees, 13.6 M instanced triangles, 1.3 M unique) and render
# it with LB indirect light on the GPU (lavapipe when there is no GPU),
# through a coordinator and two worker processes started on loopback. Writes sylva-out/forest.png and forest.stats.json.
# Extra arguments go to `sylva render` (e.g. --spp 4 --accel kd);
# SYLVA_SCALE=1 renders all 962 trees.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
. scripts/env.sh
cargo build --release --locked -p sylva
mkdir -p sylva-out
./target/release/sylva scene forest --scale "${SYLVA_SCALE:-0.05}" -o sylva-out/forest.json
./target/release/sylva render sylva-out/forest.json -o sylva-out/forest.png "$@"
