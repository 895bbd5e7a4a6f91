#!/usr/bin/env bash
# Every check: formatting, lints, the docs (warnings are errors), the fuzz
# targets built, then every test on the machine's real GPU adapter
# (lavapipe on a machine without a GPU). Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --test
. scripts/env.sh
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked
# Built, not run: a fuzz target that no longer compiles is found here, not
# by the next person to fuzz (docs/fuzzing.md).
cargo build --locked --manifest-path fuzz/Cargo.toml
cargo test --workspace --locked "$@"
