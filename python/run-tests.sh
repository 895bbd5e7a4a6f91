#!/usr/bin/env bash
# Tests the Python client: makes a virtual environment (target/py-venv at
# the repository's root, or $SYLVA_PY_VENV), builds the client's wheel and
# its dependencies' (python/build-wheel.sh: the gRPC stubs generated from
# ../proto into the wheel), installs them there without the package index,
# and runs pytest against the `sylva` binary ($SYLVA_BIN,
# default target/release/sylva: build it first). Extra arguments go to
# pytest. On Debian, python3-venv is installed if it is missing.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${SYLVA_PY_VENV:-$root/target/py-venv}"
python="${PYTHON:-python3}"

# Debian splits venv's pip bootstrap (ensurepip) into python3-venv.
if ! "$python" -c "import ensurepip, venv" >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1; then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "installing: python3-venv" >&2
    $sudo apt-get update -q
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends python3-venv
  else
    echo "$python cannot make virtual environments (no ensurepip): install its venv module" >&2
    exit 1
  fi
fi

# A venv whose interpreter went away (Python upgraded) is made anew.
if [ -e "$venv" ] && ! "$venv/bin/python" -c "" >/dev/null 2>&1; then
  rm -rf "$venv"
fi
[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
# The wheel and its dependencies' wheels, built anew every run (the stubs
# follow the protos as they are now), then installed as a machine without
# the package index installs them. The build must leave the checkout as it
# was (python/setup.py).
wheels="$root/target/python/wheels"
stamp="$(mktemp)"
trap 'rm -f "$stamp"' EXIT
PYTHON="$venv/bin/python" bash "$root/python/build-wheel.sh" "$wheels"
wrote="$(find "$root/python" -newer "$stamp" -not -path '*/.pytest_cache*' -not -path '*/__pycache__*')"
if [ -n "$wrote" ]; then
  echo "building the wheel wrote into the checkout:" >&2
  echo "$wrote" >&2
  exit 1
fi
"$venv/bin/python" -m pip uninstall -q -y sylva-client >/dev/null 2>&1 || true
"$venv/bin/python" -m pip install -q --disable-pip-version-check --no-index --find-links "$wheels" sylva-client
"$venv/bin/python" -m pip install -q --disable-pip-version-check "pytest>=7" "pillow>=9"

export SYLVA_BIN="${SYLVA_BIN:-$root/target/release/sylva}"
cd "$root/python"
# The pytest script, not `python -m pytest`: that would put this folder on
# sys.path and test the source tree instead of the installed package.
exec "$venv/bin/pytest" -q "$@"
