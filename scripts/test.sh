#!/usr/bin/env bash
# Every check: formatting, lints, the docs (warnings are errors), the fuzz
# targets built, then every test on the machine's real GPU adapter
# (lavapipe on a machine without a GPU), the Python client's tests against
# the binary just built, and the durable queue's tests once more on a
# PostgreSQL server. Extra arguments go to `cargo test`. The Blender
# add-on's tests download Blender (`bpy`, about 400 MB): they are
# blender/run-tests.sh, not run here.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --test
. scripts/env.sh
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked
# Checked, not run: a fuzz target that no longer compiles is found here,
# not by the next person to fuzz (docs/fuzzing.md). A check finds what a
# build would in a third less time.
cargo check --locked --manifest-path fuzz/Cargo.toml
# The coordinator links no GPU stack (docs/architecture.md): keep it so.
if cargo tree --locked -p sylva-coordinator -e normal --prefix none | grep -q '^wgpu'; then
  echo "sylva-coordinator depends on wgpu; it must not (docs/architecture.md)" >&2
  exit 1
fi
# The layer rules: store/service, service/dashboard, gpu.rs/trace,
# product/lab, and no import circle of more than two worker files.
bash scripts/layers.sh
cargo test --workspace --locked "$@"
# The Python client (python/) against real processes of that binary.
SYLVA_BIN="$PWD/target/debug/sylva" bash python/run-tests.sh
# The same durable-queue tests on PostgreSQL (a throwaway local server).
bash scripts/postgres-check.sh
