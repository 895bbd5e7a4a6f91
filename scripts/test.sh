#!/usr/bin/env bash
# Every test, on the machine's real GPU adapter (lavapipe on a machine
# without a GPU). Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
. scripts/env.sh
cargo test --workspace --locked "$@"
