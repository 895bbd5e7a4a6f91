#!/usr/bin/env bash
# The main job: light the built-in plant with the LB pre-process on the GPU
# (lavapipe when there is no GPU) and write the solved grid, a picture and a
# summary to sylva-out/plant/. Extra arguments go to `sylva lb solve`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
. scripts/env.sh
cargo build --release --locked -p sylva-coordinator
./target/release/sylva lb solve plant --grid 64 -o sylva-out/plant "$@"
