#!/usr/bin/env bash
# The layer rules (docs/architecture.md, issue 36), checked with grep:
# prints each violation with its rule and exits non-zero if there is any.
# Comment lines are not code: only code that names a layer breaks a rule.
#   a. the store never imports the service: JobState lives below both
#      (coordinator/src/job_state.rs);
#   b. the service never starts the dashboard: the binary starts it beside
#      the service (coordinator/cli/src/coordinator.rs);
#   c. worker/src/gpu.rs never imports trace/ (the GPU context knows no
#      renderer);
#   d. product commands never import lab/: only lab/ itself, main.rs and
#      flags/ may;
#   e. no import circle of more than two files in the worker
#      (scripts/import-cycles.py).
# The wgpu rule (the coordinator links no GPU stack) is cargo tree's, in
# scripts/test.sh.
set -uo pipefail
# `report` runs at the end of pipes and must set `failed` here.
shopt -s lastpipe
cd "$(dirname "$0")/.."

failed=0

# Lines of code (not comments) under PATHS that match the regex PATTERN,
# as FILE:LINE: TEXT.
code_matching() {
  local pattern=$1
  shift
  grep -rHnE --include='*.rs' "$pattern" "$@" 2>/dev/null | grep -vE '^[^:]+:[0-9]+:[[:space:]]*//'
}

# Reports a broken rule RULE (its lines on stdin, if any); NOTE says more.
report() {
  local rule=$1 note=${2:-}
  local lines
  lines=$(cat)
  if [ -n "$lines" ]; then
    echo "layer rule broken: $rule${note:+ ($note)}" >&2
    printf '%s\n' "$lines" | sed 's/^/  /' >&2
    failed=1
  fi
}

code_matching '(crate::service|service::)' coordinator/src/store \
  | report "a. coordinator/src/store/ must not import the service (use crate::job_state)"

code_matching 'dashboard' coordinator/src/service \
  | report "b. coordinator/src/service/ must not start or name the dashboard (the binary starts it)"

code_matching '(crate::trace|super::trace|\btrace::)' worker/src/gpu.rs \
  | report "c. worker/src/gpu.rs must not import trace/"

find coordinator/cli/src -name '*.rs' \
  ! -path 'coordinator/cli/src/lab/*' ! -path 'coordinator/cli/src/flags/*' \
  ! -path 'coordinator/cli/src/main.rs' -print0 \
  | xargs -0 grep -HnE '(crate::lab|super::lab|\blab::)' 2>/dev/null \
  | grep -vE '^[^:]+:[0-9]+:[[:space:]]*//' \
  | report "d. product code in coordinator/cli/src must not import lab/ (only lab/, main.rs and flags/ may)"

# e. No import circle of more than two files inside the worker (pbrt-v4's
#    CPURender names its one circle; ours is the ambient match, inside
#    worker/src/frame/, which imports the renderer without it importing back).
if ! out=$(python3 scripts/import-cycles.py worker/src); then
  printf '%s\n' "$out" | grep 'TOO LARGE' | report "e. worker/src/ must hold no import circle of more than two files"
fi

if [ "$failed" -ne 0 ]; then
  exit 1
fi
echo "layer rules hold"
