"""Fixes up the exporter's .glb for Sylva's importer, without bpy.

Blender's glTF exporter writes one glTF mesh per way a Blender mesh is
reached: a mesh placed both by a geometry-nodes scatter and by a
collection instance comes out as two identical meshes of the same name.
Sylva names models after meshes and refuses two meshes of one name, so:
meshes whose primitives hold the same data are merged into one (their
nodes then share it, as instances of one model), and meshes that still
share a name after that are renamed ``NAME.1``, ``NAME.2``, …
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path
from typing import Any

GLB_MAGIC = 0x46546C67
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942


def read_glb(path: str | Path) -> tuple[dict[str, Any], bytes]:
    """The JSON document and the binary chunk of a .glb file."""
    data = Path(path).read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise ValueError(f"{path}: not a glTF 2.0 binary file")
    off, doc, blob = 12, None, b""
    while off + 8 <= min(length, len(data)):
        size, kind = struct.unpack_from("<II", data, off)
        chunk = data[off + 8 : off + 8 + size]
        if kind == CHUNK_JSON and doc is None:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == CHUNK_BIN and not blob:
            blob = bytes(chunk)
        off += 8 + size
    if doc is None:
        raise ValueError(f"{path}: no JSON chunk")
    return doc, blob


def write_glb(path: str | Path, doc: dict[str, Any], blob: bytes) -> None:
    """Writes a .glb file of `doc` and `blob` (chunks padded to 4 bytes)."""
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), CHUNK_JSON) + text
    if blob:
        blob = blob + b"\0" * (-len(blob) % 4)
        chunks += struct.pack("<II", len(blob), CHUNK_BIN) + blob
    Path(path).write_bytes(struct.pack("<III", GLB_MAGIC, 2, 12 + len(chunks)) + chunks)


def _accessor_key(doc: dict[str, Any], blob: bytes, i: int, memo: dict[int, str]) -> str:
    """A digest of accessor `i`: its type and the bytes it reads."""
    if i in memo:
        return memo[i]
    a = doc["accessors"][i]
    h = hashlib.sha256(
        json.dumps({k: a.get(k) for k in ("componentType", "count", "type", "normalized",
                                          "sparse", "byteOffset")}, sort_keys=True).encode()
    )
    view_i = a.get("bufferView")
    if view_i is not None:
        v = doc["bufferViews"][view_i]
        if v.get("buffer", 0) == 0 and "uri" not in doc["buffers"][0]:
            start = v.get("byteOffset", 0)
            h.update(blob[start : start + v["byteLength"]])
            h.update(str(v.get("byteStride")).encode())
        else:
            h.update(f"view{view_i}".encode())
    memo[i] = h.hexdigest()
    return memo[i]


def _mesh_key(doc: dict[str, Any], blob: bytes, mesh: dict[str, Any], memo: dict[int, str]) -> str:
    prims = []
    for p in mesh.get("primitives", []):
        q = {k: v for k, v in p.items() if k not in ("attributes", "indices", "targets")}
        q["attributes"] = {k: _accessor_key(doc, blob, v, memo) for k, v in p.get("attributes", {}).items()}
        if "indices" in p:
            q["indices"] = _accessor_key(doc, blob, p["indices"], memo)
        q["targets"] = [{k: _accessor_key(doc, blob, v, memo) for k, v in t.items()}
                        for t in p.get("targets", [])]
        prims.append(q)
    return json.dumps([mesh.get("name"), prims, mesh.get("weights")], sort_keys=True)


def dedupe_meshes(doc: dict[str, Any], blob: bytes) -> dict[str, int]:
    """Merges identical meshes and renames the rest to unique names, in
    `doc`; returns {"merged": n, "renamed": n}."""
    meshes = doc.get("meshes", [])
    memo: dict[int, str] = {}
    first_of: dict[str, int] = {}
    remap: dict[int, int] = {}
    kept: list[dict[str, Any]] = []
    for i, m in enumerate(meshes):
        key = _mesh_key(doc, blob, m, memo)
        if key in first_of:
            remap[i] = first_of[key]
        else:
            first_of[key] = len(kept)
            remap[i] = len(kept)
            kept.append(m)
    merged = len(meshes) - len(kept)
    renamed = 0
    used: set[str] = set()
    for i, m in enumerate(kept):
        name = m.get("name") or f"mesh{i}"
        if name in used or not m.get("name"):
            n = 1
            while f"{name}.{n}" in used:
                n += 1
            name = f"{name}.{n}"
            renamed += 1
        m["name"] = name
        used.add(name)
    if meshes:
        doc["meshes"] = kept
        for node in doc.get("nodes", []):
            if "mesh" in node:
                node["mesh"] = remap[node["mesh"]]
    return {"merged": merged, "renamed": renamed}


def keep_camera(doc: dict[str, Any], name: str | None) -> int:
    """Takes the camera off every node but the one named `name` (the
    scene's active camera: Sylva's importer takes the first camera it
    meets, in an order of its own); how many it took off. Nothing where
    no node of that name has a camera."""
    nodes = doc.get("nodes", [])
    if name is None or not any(n.get("name") == name and "camera" in n for n in nodes):
        return 0
    dropped = 0
    for n in nodes:
        if "camera" in n and n.get("name") != name:
            del n["camera"]
            dropped += 1
    return dropped


def fix_glb(path: str | Path, camera: str | None = None) -> dict[str, int]:
    """Rewrites the .glb at `path` in place with `dedupe_meshes` and
    `keep_camera`."""
    doc, blob = read_glb(path)
    done = dedupe_meshes(doc, blob)
    done["cameras_dropped"] = keep_camera(doc, camera)
    if any(done.values()):
        write_glb(path, doc, blob)
    return done


def summary(path: str | Path) -> dict[str, Any]:
    """What the file places: mesh names, and per node its mesh and its
    EXT_mesh_gpu_instancing count (for the tests and the log)."""
    doc, _ = read_glb(path)
    nodes = []
    for n in doc.get("nodes", []):
        ext = n.get("extensions", {}).get("EXT_mesh_gpu_instancing")
        count = None
        if ext:
            acc = next(iter(ext["attributes"].values()))
            count = doc["accessors"][acc]["count"]
        nodes.append({"name": n.get("name"), "mesh": n.get("mesh"), "instances": count,
                      "children": n.get("children", [])})
    return {"meshes": [m.get("name") for m in doc.get("meshes", [])], "nodes": nodes,
            "extensionsUsed": doc.get("extensionsUsed", [])}
