#!/usr/bin/env bash
# Renders Sylva's glTF export of a scene in Blender Cycles and compares it
# with Sylva's own path-traced reference (docs/lighting.md, "One leaf BSDF"):
# the whole-image mean per channel, and every pixel against both renders'
# noise. Blender comes from PyPI (`bpy`) in its own venv, never as a
# dependency of Sylva; the first run downloads it (about 400 MB).
#
#   scripts/cycles-check.sh [SCENE] [WIDTH] [HEIGHT]
#
# Environment: SYLVA_BPY_VENV (default target/bpy-venv), CYCLES_SAMPLES
# (per render, default 512), SYLVA_TARGET_ERROR (default 0.01), OUT
# (default sylva-out/cycles-check).
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-examples/tree.json}
width=${2:-160}
height=${3:-120}
venv=${SYLVA_BPY_VENV:-target/bpy-venv}
out=${OUT:-sylva-out/cycles-check}
mkdir -p "$out"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import bpy" 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet bpy
fi
cargo build --release --locked -p sylva
sylva=target/release/sylva
"$sylva" scene export "$scene" --format gltf --out "$out/scene.glb"
# Two references with other seeds: their spread is Sylva's own noise.
for seed in 1 2; do
    "$sylva" render "$scene" --lighting reference --local-workers 0 --width "$width" \
        --height "$height" --seed "$seed" --target-error "${SYLVA_TARGET_ERROR:-0.01}" \
        --exr --out "$out/sylva-$seed.png"
done
"$venv/bin/python" scripts/cycles_check.py --glb "$out/scene.glb" \
    --sylva "$out/sylva-1.exr" "$out/sylva-2.exr" --width "$width" --height "$height" \
    --samples "${CYCLES_SAMPLES:-512}" --out "$out"
