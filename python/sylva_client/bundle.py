"""Scene bundles, packed byte for byte as `sylva submit` packs them.

A bundle is one content-addressed blob that holds a scene file and the
model files it names, so that workers cache it by hash
(shared/scene/src/bundle.rs, `pack_with`, is the reference). Its layout:

* the magic ``SYLVABN1``;
* the manifest's length, u64 little endian;
* the manifest, JSON: ``{"scene": SCENE, "blobs": [{"name": N, "len": L}, ...]}``
  where SCENE is the scene file's JSON as written, except that each
  model's ``gltf`` path is replaced by its blob's name ``m{i}/{file name}``
  (``i`` counts every model, in sorted-name order), and an ``import``
  (a glTF scene the file takes its models, placements, camera and sun
  from) by ``i/{file name}``;
* the blobs, in the manifest's order: each model's, then the import's. A
  ``.gltf`` file's external buffers and images (relative URIs, not
  ``data:``) come first, as ``m{i}/{uri, percent-decoded}``, then the
  glTF file itself.

The hash is BLAKE3 of the whole bundle, in hex. The Python and Rust
packers must agree to the byte: the same scene packed by either is the
same job to the farm's caches, so the manifest is written as serde_json
writes it (see `sylva_client._json`).

Every file read must lie inside the scene file's folder, checked as the
Rust side's `FileAccess::Inside` does (shared/scene/src/sandbox.rs):
relative paths without ``..``, and their real locations (symbolic links
followed) inside the folder too.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import blake3

from . import _json

__all__ = ["MAGIC", "Bundle", "BundleError", "hash_of", "pack"]

#: The first eight bytes of every bundle.
MAGIC = b"SYLVABN1"


class BundleError(ValueError):
    """A scene that cannot be packed: unreadable, not JSON as serde_json
    reads it, or naming files outside its folder. The message names the
    scene and the field, as `sylva submit` does."""


@dataclass(frozen=True)
class Bundle:
    """A packed scene: its bytes and the hash the farm knows it by."""

    #: The bundle's bytes.
    bytes: bytes
    #: BLAKE3 of the bytes, hex.
    hash: str

    def __len__(self) -> int:
        return len(self.bytes)


def hash_of(data: bytes) -> str:
    """The hash a bundle of `data` is known by: BLAKE3, hex."""
    return blake3.blake3(data).hexdigest()


def _debug(s: str) -> str:
    """`s` quoted as Rust's `{:?}` writes a string (for error messages that
    read as the CLI's)."""
    out = ['"']
    for c in s:
        if c in '"\\':
            out.append("\\" + c)
        elif c == "\n":
            out.append("\\n")
        elif c == "\r":
            out.append("\\r")
        elif c == "\t":
            out.append("\\t")
        elif c == "\0":
            out.append("\\0")
        elif ord(c) < 0x20 or 0x7F <= ord(c) < 0xA0:
            out.append(f"\\u{{{ord(c):x}}}")
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def _lossy(name: str) -> str:
    """A file name as Rust's `to_string_lossy` shows it: bytes that are
    not UTF-8 (kept by Python as surrogate escapes) become U+FFFD."""
    return os.fsencode(name).decode("utf-8", "replace")


class _Inside:
    """Reads files inside one folder only: `FileAccess::Inside`."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def resolve(self, base: Path, rel: str) -> Path:
        """The real path of `rel` (relative to `base`, a folder inside the
        root), or `BundleError` with one message for every refusal, so it
        tells nothing of what lies outside."""
        outside = BundleError(
            f"{_debug(rel)} is not a file inside the scene's folder "
            '(scenes name files by relative paths, without "..")'
        )
        # Lexically first: no absolute paths, no "..".
        if not rel or rel.startswith("/") or ".." in rel.split("/"):
            raise outside
        try:
            full = Path(os.path.realpath(base / rel, strict=True))
            root = Path(os.path.realpath(self.root, strict=True))
        except (OSError, ValueError):  # missing, a loop, a NUL byte
            raise outside from None
        # Then by real location: a symbolic link cannot lead out either.
        if not full.is_relative_to(root) or not full.is_file():
            raise outside
        return full

    def resolve_uri(self, base: Path, uri: str) -> Path | None:
        """The file a glTF buffer or image URI names, relative to the glTF
        file's folder `base`: None for a ``data:`` URI, else the checked
        path. Other schemes are refused; ``%XX`` escapes are decoded."""
        if uri.startswith("data:"):
            return None
        if ":" in uri:
            raise BundleError(
                f"URI {_debug(_clip(uri))} has a scheme other than data: "
                "(only relative paths and data: URIs are read)"
            )
        decoded = _percent_decode(uri)
        if decoded is None:
            raise BundleError(f"URI {_debug(_clip(uri))} is not valid percent-encoded UTF-8")
        return self.resolve(base, decoded)


def _clip(s: str, most: int = 80) -> str:
    """At most `most` characters of `s`, an ellipsis marking a cut."""
    return s if len(s) <= most else s[:most] + "…"


# Rust's `to_ascii_lowercase`: only A-Z change.
_ASCII_LOWER = str.maketrans("ABCDEFGHIJKLMNOPQRSTUVWXYZ", "abcdefghijklmnopqrstuvwxyz")

_HEX = frozenset(b"0123456789abcdefABCDEF")


def _percent_decode(s: str) -> str | None:
    """`%XX` escapes decoded as the glTF loader does; None if a `%` is not
    followed by two hex digits or the result is not UTF-8."""
    b = s.encode("utf-8")
    out = bytearray()
    i = 0
    while i < len(b):
        if b[i] == 0x25:  # '%'
            h = b[i + 1 : i + 3]
            if len(h) != 2 or not all(c in _HEX for c in h):
                return None
            out.append(int(h, 16))
            i += 3
        else:
            out.append(b[i])
            i += 1
    try:
        return out.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _external_uris(gltf_json: bytes) -> list[str]:
    """Relative URIs of a ``.gltf`` file's buffers, then its images."""
    try:
        v = _json.loads(gltf_json.decode("utf-8"))
    except (UnicodeDecodeError, _json.JsonError) as e:
        raise ValueError(str(e)) from None
    out: list[str] = []
    for key in ("buffers", "images"):
        items = v.get(key) if isinstance(v, dict) else None
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                out.append(uri)
    return out


def _pack_gltf(
    access: _Inside, folder: Path, rel: str, dir_name: str, field: str, blobs: list[tuple[str, bytes]]
) -> str:
    """Packs the glTF file `rel` (named by the scene's `field`) into `blobs`
    under `dir_name`, after the files a ``.gltf`` names (as the reader
    finds them: their URIs percent-decoded); returns the blob name the
    scene's field becomes."""
    try:
        full = access.resolve(folder, rel)
    except BundleError as e:
        raise BundleError(f"{field}: {e}") from None
    try:
        data = full.read_bytes()
    except OSError:
        raise BundleError(f"{field}: cannot read {rel}") from None
    # The real file's name: a symbolic link inside the folder is packed
    # under its target's name, as Rust's canonical path gives it.
    file = _lossy(full.name) or "model.glb"
    if file[-5:].translate(_ASCII_LOWER) == ".gltf":
        try:
            uris = _external_uris(data)
        except ValueError as e:
            raise BundleError(f"{rel}: not glTF JSON: {e}") from None
        for uri in uris:
            try:
                dep = access.resolve_uri(full.parent, uri)
            except BundleError as e:
                raise BundleError(f"{rel}: {e}") from None
            assert dep is not None, "data: URIs are not external"
            decoded = _percent_decode(uri)
            assert decoded is not None, "resolve_uri decoded it"
            try:
                blobs.append((f"{dir_name}/{decoded}", dep.read_bytes()))
            except OSError:
                raise BundleError(f"{rel}: cannot read {uri}") from None
    blobs.append((f"{dir_name}/{file}", data))
    return f"{dir_name}/{file}"


def pack(scene_path: str | os.PathLike[str]) -> Bundle:
    """Packs the scene file at `scene_path` and the glTF files it names
    (with the buffers and images a ``.gltf`` refers to by relative path),
    all of which must lie inside the scene file's folder: the bundle that
    `sylva submit` sends, to the byte.

    Raises `BundleError` for a scene that cannot be packed. The scene's
    fields are not checked here beyond what packing needs: the
    coordinator checks them when the job is submitted.
    """
    path = Path(scene_path)
    label = os.fspath(scene_path)
    # The scene's folder; a bare file name's is the current one.
    folder = path.parent
    access = _Inside(folder)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as e:
        raise BundleError(f"{label}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise BundleError(f"{label}: stream did not contain valid UTF-8") from None
    try:
        written: Any = _json.loads(text)
    except _json.JsonError as e:
        raise BundleError(f"{label}: {e}") from None
    if not isinstance(written, dict):
        raise BundleError(f"{label}: a scene file is a JSON object")
    models = written.get("models", {})
    if not isinstance(models, dict) or ("models" not in written and "import" not in written):
        raise BundleError(f"{label}: models: missing, or not an object of models by name")

    blobs: list[tuple[str, bytes]] = []
    # The Rust packer walks its models BTreeMap: sorted names, every model
    # counted, with a glTF file or not.
    for i, name in enumerate(sorted(models)):
        spec = models[name]
        if not isinstance(spec, dict):
            raise BundleError(f"{label}: models.{name}: not an object")
        rel = spec.get("gltf")
        if rel is None:
            continue
        if not isinstance(rel, str):
            raise BundleError(f"{label}: models.{name}.gltf: not a path")
        spec["gltf"] = _pack_gltf(access, folder, rel, f"m{i}", f"{label}: models.{name}.gltf", blobs)
    # A glTF scene the scene file imports (its meshes, placements, camera
    # and sun): packed under "i/".
    if "import" in written:
        rel = written["import"]
        if not isinstance(rel, str):
            raise BundleError(f"{label}: import: a path to a glTF scene (.glb or .gltf)")
        written["import"] = _pack_gltf(access, folder, rel, "i", f"{label}: import", blobs)

    # The manifest's own two levels are Rust structs: their fields in
    # declaration order ("scene", "blobs"; "name", "len"), not sorted.
    entries = ",".join(
        '{"name":' + _json.dumps(n) + ',"len":' + str(len(b)) + "}" for n, b in blobs
    )
    manifest = ('{"scene":' + _json.dumps(written) + ',"blobs":[' + entries + "]}").encode()
    out = bytearray(MAGIC)
    out += struct.pack("<Q", len(manifest))
    out += manifest
    for _, b in blobs:
        out += b
    data = bytes(out)
    return Bundle(bytes=data, hash=hash_of(data))
