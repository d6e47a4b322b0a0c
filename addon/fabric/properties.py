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
    mode: bpy.props.EnumProperty(name="Mode", items=BRUSH_MODE_ITEMS, default="COMB",
                                 description="What a stroke does to the fabric's parameter maps")
    radius: bpy.props.FloatProperty(
        name="Radius", default=0.03, min=0.001, max=0.5,
        description="Brush radius as a fraction of the UV map's width (UV units: 1 = the whole map)"
    )
    strength: bpy.props.FloatProperty(
        name="Strength", default=0.8, min=0.0, max=1.0,
        description="How far one stroke moves the fabric toward the brush's result at the brush centre "
        "(0: not at all, 1: all the way; a factor, no unit)",
    )
    use_pressure: bpy.props.BoolProperty(name="Pressure", default=True,
                                         description="Tablet pressure scales the strength")
    fibre_length: bpy.props.FloatProperty(
        name="Fibre Length", default=1.2, min=1.0, max=5.0,
        description="Comb: fibre length in pile heights (1 = upright pile's height); longer fibres lean further"
    )
    kd: bpy.props.FloatVectorProperty(
        name="Diffuse", subtype="COLOR", size=3, default=(0.05, 0.02, 0.02), min=0.0,
        description="Diffuse colour that Recolor paints (linear RGB albedo, 0-1 per channel)",
    )
    ks: bpy.props.FloatVectorProperty(
        name="Specular", subtype="COLOR", size=3, default=(0.6, 0.2, 0.2), min=0.0,
        description="Specular (sheen) colour that Recolor paints (linear RGB albedo, 0-1 per channel)",
    )
    recolor_diffuse: bpy.props.BoolProperty(name="Diffuse", default=True,
                                            description="Recolor paints the diffuse colour")
    recolor_specular: bpy.props.BoolProperty(name="Specular", default=True,
                                             description="Recolor paints the specular (sheen) colour")
    smooth_factor: bpy.props.FloatProperty(
        name="Smooth Factor", default=0.8, min=0.1, max=2.0,
        description="Smooth multiplies the fibre roughness (sigma) by this at full strength: below 1 smoother "
        "fibres and a sharper highlight, above 1 rougher (a multiplier, no unit)",
    )
    anisotropy_factor: bpy.props.FloatProperty(
        name="Anisotropy Factor", default=0.8, min=0.1, max=1.0,
        description="Anisotropy multiplies the smaller fibre roughness (sigma) by this at full strength: lower "
        "stretches the highlight along the fibres (a multiplier, no unit)",
    )
    states_dir: bpy.props.StringProperty(
        name="States", subtype="DIR_PATH",
        description="Data-Driven: folder with the fits of the 8 measured brushing states (state_0 ... state_7)"
    )


CLASSES: list[type] = [MS_FabricBrushSettings]
