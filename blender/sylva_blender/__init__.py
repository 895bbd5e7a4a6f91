"""Sylva for Blender: render the open scene on a Sylva render farm.

"Render on Sylva" (Properties > Render > Sylva) exports the scene as glTF
with its instancing kept (geometry-node scatters as EXT_mesh_gpu_instancing,
collection instances as nodes sharing a mesh), submits it to the farm's
coordinator with the vendored Python client, follows the job and loads the
result, a multi-layer OpenEXR with the render passes, as an image.
With Render Engine set to "Sylva", F12 renders the frame on the farm
into Blender's render window (`engine.py`).
"""

bl_info = {
    "name": "Sylva Render Farm",
    "author": "Sylva",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Render > Sylva",
    "description": "Render the scene on a Sylva render farm (instanced forests), with its passes",
    "category": "Render",
    "doc_url": "",
}

from . import deps, engine, ops, props, ui  # noqa: E402

_MODULES = (props, ops, ui, engine)


def register() -> None:
    deps.add_to_path()
    for m in _MODULES:
        m.register()


def unregister() -> None:
    for m in reversed(_MODULES):
        m.unregister()
