"""The fabric brush settings (``Scene.material_structures.fabric_brush``)."""

from __future__ import annotations

import bpy

BRUSH_MODE_ITEMS = [
    ("COMB", "Comb", "Rotate the fibres toward the stroke direction (slerp, tilt limited by fibre length)"),
    ("RECOLOR", "Recolor", "Blend k_d and k_s toward the brush colours"),
    ("SMOOTH", "Smooth", "Scale sigma (lower = smoother, sharper highlight)"),
    ("ANISOTROPY", "Anisotropy", "Shrink the smaller sigma axis"),
    ("DATA_DRIVEN", "Data-Driven", "Blend the 8 measured brushing states by stroke direction"),
]


class MS_FabricBrushSettings(bpy.types.PropertyGroup):
    mode: bpy.props.EnumProperty(name="Mode", items=BRUSH_MODE_ITEMS, default="COMB")
    radius: bpy.props.FloatProperty(
        name="Radius", default=0.03, min=0.001, max=0.5, description="Brush radius in UV units (fraction of the map)"
    )
    strength: bpy.props.FloatProperty(name="Strength", default=0.8, min=0.0, max=1.0)
    use_pressure: bpy.props.BoolProperty(name="Pressure", default=True, description="Tablet pressure scales strength")
    fibre_length: bpy.props.FloatProperty(
        name="Fibre Length", default=1.2, min=1.0, max=5.0, description="In pile heights; longer fibres lean further"
    )
    kd: bpy.props.FloatVectorProperty(name="Diffuse", subtype="COLOR", size=3, default=(0.05, 0.02, 0.02), min=0.0)
    ks: bpy.props.FloatVectorProperty(name="Specular", subtype="COLOR", size=3, default=(0.6, 0.2, 0.2), min=0.0)
    recolor_diffuse: bpy.props.BoolProperty(name="Diffuse", default=True)
    recolor_specular: bpy.props.BoolProperty(name="Specular", default=True)
    smooth_factor: bpy.props.FloatProperty(name="Smooth Factor", default=0.8, min=0.1, max=2.0)
    anisotropy_factor: bpy.props.FloatProperty(name="Anisotropy Factor", default=0.8, min=0.1, max=1.0)
    states_dir: bpy.props.StringProperty(
        name="States", subtype="DIR_PATH", description="Folder with state_0 ... state_7 fits (data-driven mode)"
    )


CLASSES: list[type] = [MS_FabricBrushSettings]
