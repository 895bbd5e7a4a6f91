# Imports a glTF file into Blender (the `bpy` module from PyPI, never a
# dependency of Sylva) and prints what arrived, as one JSON line:
#   python -m venv v && v/bin/pip install "bpy==4.5.*"
#   v/bin/python scripts/blender-import.py -- forest.glb
import sys, json, bpy
path = sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
res = bpy.ops.import_scene.gltf(filepath=path)
objs = bpy.data.objects
report = {
    "result": list(res),
    "objects": len(objs),
    "meshes": len(bpy.data.meshes),
    "materials": sorted(m.name for m in bpy.data.materials),
    "images": len(bpy.data.images),
    "cameras": len(bpy.data.cameras),
    "lights": [(l.name, l.type) for l in bpy.data.lights],
    "mesh_objects": sum(1 for o in objs if o.type == "MESH"),
    "triangles_per_mesh": {m.name: sum(len(p.vertices) - 2 for p in m.polygons) for m in bpy.data.meshes},
    "blend_methods": sorted({getattr(m, "blend_method", "?") for m in bpy.data.materials}),
}
print("BLENDER_REPORT " + json.dumps(report))
