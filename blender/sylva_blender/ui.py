"""The "Sylva" panel in Properties > Render."""

import bpy

from . import deps, props


class SYLVA_PT_render(bpy.types.Panel):
    bl_label = "Sylva"
    bl_idname = "SYLVA_PT_render"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw(self, context: bpy.types.Context) -> None:
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        scene = context.scene
        s = scene.sylva_farm
        st = context.window_manager.sylva_status
        prefs = props.addon_prefs(context)

        col = layout.column(heading="Farm") if hasattr(layout, "column") else layout
        if prefs is not None:
            col.prop(prefs, "address", text="Address")
            col.prop(prefs, "token", text="Token")
        else:
            col.label(text="Farm: $SYLVA_COORDINATOR (add-on not enabled)")
        gone = deps.missing()
        if gone:
            box = layout.box()
            box.label(text=f"Missing: {', '.join(gone)}", icon="ERROR")
            box.operator("sylva.install_deps", icon="IMPORT")

        col = layout.column()
        r = scene.render
        pct = r.resolution_percentage / 100
        col.label(text=f"Resolution: {int(r.resolution_x * pct)} × {int(r.resolution_y * pct)}",
                  icon="OUTPUT")
        col.prop(s, "spp")
        col.prop(s, "seed")
        col.prop(s, "lighting")
        col.prop(s, "accel")
        col.prop(s, "all_passes")
        sub = col.column()
        sub.enabled = not s.all_passes
        sub.prop(s, "passes")
        col.prop(s, "animation")
        if s.animation:
            step = f" by {scene.frame_step}" if scene.frame_step > 1 else ""
            col.label(text=f"Frames {scene.frame_start}–{scene.frame_end}{step}", icon="RENDER_ANIMATION")
        col.prop(s, "output_dir")
        col.prop(s, "keep_export")

        layout.use_property_split = False
        row = layout.row()
        row.scale_y = 1.5
        if st.running:
            row.operator("sylva.cancel", icon="CANCEL")
        else:
            row.operator("sylva.render", icon="RENDER_STILL")
        if st.running or st.stage:
            box = layout.box()
            if st.running and hasattr(box, "progress"):  # 4.0+
                box.progress(factor=st.progress, type="BAR", text=st.stage)
            else:
                box.label(text=st.stage, icon="INFO")
                if st.running:
                    box.prop(st, "progress", slider=True)
            if st.job:
                box.label(text=f"Job {st.job}")
            if st.image:
                seq = f" ({st.frames} frames)" if st.frames else ""
                box.label(text=f"Image: {st.image}{seq}", icon="IMAGE_DATA")


CLASSES = (SYLVA_PT_render,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
