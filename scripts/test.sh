#!/usr/bin/env bash
# Every check: formatting, lints, then every test on the machine's real GPU
# adapter (lavapipe on a machine without a GPU). Extra arguments go to
# `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --test
. scripts/env.sh
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo test --workspace --locked "$@"
