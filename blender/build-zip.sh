#!/usr/bin/env bash
# Builds target/sylva_blender.zip, the Blender add-on ready for
# Edit > Preferences > Add-ons > Install (Blender 3.4+; in 4.2+ also
# "Install from Disk" as an extension): blender/sylva_blender/ with the
# Python client (python/, its gRPC stubs generated from proto/ as pip
# builds it) vendored in sylva_blender/_vendor/, and the client's runtime
# requirements in _vendor/requirements.txt for the add-on's "Install
# dependencies" button. Needs python3 with pip, and pip's index for the
# client's build requirements (setuptools, grpcio-tools).
#   blender/build-zip.sh [OUT.zip]     (default target/sylva_blender.zip)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$root/target/sylva_blender.zip}"
python="${PYTHON:-python3}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

mkdir -p "$tmp/pkg"
# The add-on's sources, without caches or a stale vendored copy.
(cd "$root/blender" && tar --exclude='__pycache__' --exclude='*.pyc' --exclude='sylva_blender/_vendor' \
  -cf - sylva_blender) | (cd "$tmp/pkg" && tar -xf -)

# The client, built from python/ (stubs generated), without its dependencies.
"$python" -m pip install -q --disable-pip-version-check --no-deps --no-compile \
  --target "$tmp/site" "$root/python"
vendor="$tmp/pkg/sylva_blender/_vendor"
mkdir -p "$vendor"
cp -r "$tmp/site/sylva_client" "$vendor/"
find "$vendor" -name '__pycache__' -prune -exec rm -rf {} +
cat > "$vendor/__init__.py" <<'PY'
"""The Sylva Python client (python/ of the Sylva repository, with its
generated gRPC stubs), vendored by blender/build-zip.sh: not to be edited."""
PY
# Requires-Dist of the built client: grpcio and protobuf at the versions
# its stubs need, blake3.
"$python" - "$tmp/site" "$vendor/requirements.txt" <<'PY'
import pathlib, sys
site, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
meta = next(site.glob("sylva_client-*.dist-info/METADATA")).read_text()
reqs = [l.split(":", 1)[1].strip() for l in meta.splitlines() if l.startswith("Requires-Dist:")]
reqs = [r for r in reqs if "extra ==" not in r]
out.write_text("# The vendored client's runtime requirements (blender/build-zip.sh)\n" + "\n".join(reqs) + "\n")
print("requirements:", ", ".join(reqs))
PY

mkdir -p "$(dirname "$out")"
rm -f "$out"
"$python" - "$tmp/pkg" "$out" <<'PY'
import os, sys, zipfile
src, out = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
    for d, dirs, files in os.walk(src):
        dirs.sort()
        for f in sorted(files):
            p = os.path.join(d, f)
            z.write(p, os.path.relpath(p, src))
PY
echo "wrote $out"
