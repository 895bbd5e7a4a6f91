#!/usr/bin/env bash
# Writes the client's wheel (its gRPC stubs generated into it from
# ../proto) and the wheels of everything it needs at run time into one
# folder, target/python/wheels by default. From there it installs without
# the package index, e.g. on a farm's machines with no way out:
#   pip install --no-index --find-links target/python/wheels sylva-client
# Building needs the index once (setuptools and grpcio-tools to build,
# grpcio, protobuf and blake3 to fetch), and writes nothing into the
# checkout (python/setup.py), so a read-only one builds too.
#   python/build-wheel.sh [DIR]     ($PYTHON: the interpreter, default python3)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$root/target/python/wheels}"
python="${PYTHON:-python3}"
mkdir -p "$out"
rm -f "$out"/sylva_client-*.whl
"$python" -m pip wheel -q --disable-pip-version-check -w "$out" "$root/python"
echo "wrote $(ls "$out"/sylva_client-*.whl) and the wheels it needs ($(ls "$out" | wc -l) in all)"
