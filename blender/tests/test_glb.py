"""The add-on's glTF fix-ups (glb.py), on hand-made documents."""

from __future__ import annotations

import struct
from pathlib import Path


def doc_with(meshes: list[tuple[str, bytes]]) -> tuple[dict, bytes]:
    """A document of one-primitive meshes, each (name, position bytes)."""
    blob, views, accessors, out = b"", [], [], []
    for i, (name, data) in enumerate(meshes):
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        accessors.append({"bufferView": i, "componentType": 5126, "count": len(data) // 12,
                          "type": "VEC3"})
        blob += data
        out.append({"name": name, "primitives": [{"attributes": {"POSITION": i}}]})
    doc = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(blob)}],
           "bufferViews": views, "accessors": accessors, "meshes": out,
           "nodes": [{"mesh": i, "name": f"n{i}"} for i in range(len(meshes))],
           "extensionsRequired": ["KHR_lights_punctual", "KHR_texture_transform"],
           "extensionsUsed": ["KHR_lights_punctual", "KHR_texture_transform"]}
    return doc, blob


def test_identical_meshes_merge_and_others_get_unique_names(addon, tmp_path: Path) -> None:
    glb = addon.glb
    a = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    b = struct.pack("<9f", 0, 0, 0, 2, 0, 0, 0, 2, 0)
    doc, blob = doc_with([("Tree", a), ("Tree", a), ("Tree", b), ("Rock", b)])
    path = tmp_path / "x.glb"
    glb.write_glb(path, doc, blob)
    assert glb.fix_glb(path) == {"merged": 1, "renamed": 1, "cameras_dropped": 0}
    doc, _ = glb.read_glb(path)
    assert [m["name"] for m in doc["meshes"]] == ["Tree", "Tree.1", "Rock"]
    assert [n["mesh"] for n in doc["nodes"]] == [0, 0, 1, 2]
    # The rest of the document is left as the exporter wrote it.
    assert doc["extensionsRequired"] == ["KHR_lights_punctual", "KHR_texture_transform"]


def test_only_the_active_camera_is_kept(addon) -> None:
    doc = {"nodes": [{"name": "A", "camera": 0}, {"name": "B", "camera": 1}, {"name": "C"}]}
    assert addon.glb.keep_camera(doc, "B") == 1
    assert [("camera" in n) for n in doc["nodes"]] == [False, True, False]
    assert addon.glb.keep_camera(doc, "missing") == 0
