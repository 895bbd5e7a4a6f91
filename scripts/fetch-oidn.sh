#!/usr/bin/env bash
# Puts Intel Open Image Denoise 2.5's shared libraries in DIR/lib, for
# `--denoise` (shared/denoise loads them at run time; docs/denoising.md).
# Debian has no OIDN package: PyPI's `pyoidn` wheel ships the libraries.
# Its SHA-256 is checked against the index's, and only the library, its
# core, its CPU device and TBB are kept (their RPATH is $ORIGIN/../lib).
# Needs python3 and the package index.
#   scripts/fetch-oidn.sh DIR      (then SYLVA_OIDN_LIB=DIR/lib/libOpenImageDenoise.so.2)
set -euo pipefail
dir="${1:?usage: fetch-oidn.sh DIR}"
version=2.5.1.0
echo "installing Open Image Denoise (pyoidn $version from PyPI) into $dir" >&2
python3 - "$version" "$dir/lib" <<'PY'
import hashlib, io, json, os, sys, urllib.parse, urllib.request, zipfile
version, out = sys.argv[1], sys.argv[2]
index = "https://pypi.org/pypi/pyoidn/json"
meta = json.load(urllib.request.urlopen(index))
wheel = next(u for u in meta["releases"][version] if u["filename"].endswith("manylinux2014_x86_64.whl"))
# (a mirror of the index may answer with addresses relative to it)
data = urllib.request.urlopen(urllib.parse.urljoin(index, wheel["url"])).read()
if hashlib.sha256(data).hexdigest() != wheel["digests"]["sha256"]:
    sys.exit(f"{wheel['filename']}: its digest is not the index's")
keep = ("libOpenImageDenoise.so", "libOpenImageDenoise_core.so", "libOpenImageDenoise_device_cpu.so", "libtbb.so")
os.makedirs(out, exist_ok=True)
z = zipfile.ZipFile(io.BytesIO(data))
for name in z.namelist():
    base = os.path.basename(name)
    if name.startswith("pyoidn/oidn/lib/") and base.startswith(keep):
        with open(os.path.join(out, base), "wb") as f:
            f.write(z.read(name))
PY
