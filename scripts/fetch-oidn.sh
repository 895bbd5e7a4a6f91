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
# The wheel's SHA-256, pinned here: the index (or a mirror of it) is not
# what vouches for a library the coordinator loads.
sha256=32ad13368f8de1ef63001942ad05b02a00cd732d1206d97f352d3a3f606d823e
echo "installing Open Image Denoise (pyoidn $version from PyPI) into $dir" >&2
python3 - "$version" "$dir" "$sha256" <<'PY'
import hashlib, io, json, os, shutil, sys, tempfile, urllib.parse, urllib.request, zipfile
version, dest, pinned = sys.argv[1], sys.argv[2], sys.argv[3]
index = "https://pypi.org/pypi/pyoidn/json"
meta = json.load(urllib.request.urlopen(index))
wheel = next(u for u in meta["releases"][version] if u["filename"].endswith("manylinux2014_x86_64.whl"))
# (a mirror of the index may answer with addresses relative to it)
data = urllib.request.urlopen(urllib.parse.urljoin(index, wheel["url"])).read()
if hashlib.sha256(data).hexdigest() != pinned:
    sys.exit(f"{wheel['filename']}: its SHA-256 is not the one pinned in fetch-oidn.sh")
keep = ("libOpenImageDenoise.so", "libOpenImageDenoise_core.so", "libOpenImageDenoise_device_cpu.so", "libtbb.so")
# Unpacked beside DIR and moved into place whole: an interrupted run
# leaves no half a library that the next run would take for installed.
os.makedirs(os.path.dirname(os.path.abspath(dest)), exist_ok=True)
tmp = tempfile.mkdtemp(prefix=".oidn-", dir=os.path.dirname(os.path.abspath(dest)))
os.makedirs(os.path.join(tmp, "lib"))
z = zipfile.ZipFile(io.BytesIO(data))
for name in z.namelist():
    base = os.path.basename(name)
    if name.startswith("pyoidn/oidn/lib/") and base.startswith(keep):
        with open(os.path.join(tmp, "lib", base), "wb") as f:
            f.write(z.read(name))
shutil.rmtree(dest, ignore_errors=True)
os.rename(tmp, dest)
PY
