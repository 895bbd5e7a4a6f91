#!/usr/bin/env bash
# Tests the Blender add-on with bpy from PyPI (a large download, ~400 MB):
# makes a venv (target/bpy-venv at the repository's root, or
# $SYLVA_BPY_VENV) with Python 3.11 (bpy 4.5 is built for it), installs
# bpy, the Python client (for its build of the gRPC stubs), pytest, numpy
# and OpenEXR, builds the add-on's zip and runs blender/tests/ against the
# `sylva` binary ($SYLVA_BIN, default target/release/sylva: build it
# first). Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${SYLVA_BPY_VENV:-$root/target/bpy-venv}"
python="${PYTHON:-python3.11}"
bpy_version="${SYLVA_BPY_VERSION:-4.5.4}"

if [ -e "$venv" ] && ! "$venv/bin/python" -c "" >/dev/null 2>&1; then
  rm -rf "$venv"
fi
[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
pip=("$venv/bin/python" -m pip install -q --disable-pip-version-check)
"$venv/bin/python" -c "import bpy, sys; sys.exit(bpy.app.version_string.split()[0] != '$bpy_version')" \
  >/dev/null 2>&1 || "${pip[@]}" "bpy==$bpy_version"
"${pip[@]}" pytest numpy OpenEXR "$root/python"

export SYLVA_BIN="${SYLVA_BIN:-$root/target/release/sylva}"
export SYLVA_BLENDER_ZIP="${SYLVA_BLENDER_ZIP:-$root/target/sylva_blender.zip}"
PYTHON="$venv/bin/python" "$root/blender/build-zip.sh" "$SYLVA_BLENDER_ZIP"
cd "$root/blender/tests"
exec "$venv/bin/pytest" -q -p no:cacheprovider "$@"
