"""The README's panel pictures (``showcase/ui_panels.py``): the recorder runs each feature's real panels over a
scene made with the add-on's operators and finds their property labels and operator names; a layout call
it cannot draw raises instead of being left out."""

from __future__ import annotations

import pytest
from PIL import Image

from material_structures.showcase import ui_panels as ui

EXPECTED = {
    "fabric": (
        ["Material Structures", "Viewport Samples", "Pile Fabric", "New Fabric Material", "Import Fitted Fabric Maps",
         "Sync Lights", "Fit BTF", "Brush", "Mode", "Comb", "Radius", "Strength", "Brush Fabric"],
        ["SGGX Fabric", "Tint", "Roughness Scale", "Anisotropy", "Parameter maps", "Save Fabric Maps"],
    ),
    "scratch": (
        ["Scratches", "Generate Scratches", "Draw Scratches", "Import Scratch Set", "Export Scratch Set"],
        ["Scratched Metal", "Base Color", "Edge Tint", "Roughness", "Scratch Intensity", "World Lights",
         "Sync Scratch Lights"],
    ),
    "teeth": (
        ["Teeth", "Add Tooth", "From Mesh", "Import Teeth Scene", "Buccal", "Proximal", "Occlusal",
         "Apply Fitted Coefficients", "Fit to capture", "Read Capture Teeth", "Iterations",
         "Fit Teeth to Capture", "Apply Fit Result"],
        [],
    ),
}


@pytest.fixture(scope="module")
def recorded(addon_module):
    out = {}
    for feature in ui.FEATURES:
        context = ui.build_scene(feature, scratches=40)
        out[feature] = ui.record_feature(addon_module, feature, context)
    return out


@pytest.mark.parametrize("feature", ui.FEATURES)
def test_panels_show_their_labels_and_operators(recorded, feature):
    sidebar, material = recorded[feature]
    side_texts = [t for p in sidebar for t in p.texts()]
    mat_texts = [t for p in material for t in p.texts()]
    want_side, want_mat = EXPECTED[feature]
    assert not [t for t in want_side if t not in side_texts], side_texts
    assert not [t for t in want_mat if t not in mat_texts], mat_texts
    if want_mat:  # the material panels say which path renders here (exact, closures, viewport look)
        assert any(t.startswith(("Exact shader", "Closure path", "EEVEE")) for t in mat_texts), mat_texts
    # the feature's own panel is open; the other features' panels are listed closed
    top = {p.idname: p for p in sidebar}
    assert [p.label for p in sidebar] == ["Material Structures", "Teeth", "Scratches"]
    assert all(p.is_open == (p.idname in ui.OPEN_PANELS[feature]) for p in sidebar)
    assert top["VIEW3D_PT_material_structures"].children[0].label == "Pile Fabric"


def test_props_read_the_live_rna(recorded):
    sidebar, _ = recorded["fabric"]
    items = {it.identifier: it for p in sidebar for q in p.walk() for it in q.body.items()}
    assert items["radius"].style == "number" and items["radius"].data_type == "MS_FabricBrushSettings"
    assert items["use_pressure"].style == "checkbox"
    assert items["mode"].style == "dropdown" and items["mode"].value == "Comb"
    assert items["material_structures.fabric_new_material"].kind == "menu"
    teeth = {it.identifier: it for p in recorded["teeth"][0] for q in p.walk() for it in q.body.items()}
    assert teeth["buccal"].style == "slider" and teeth["buccal"].value == "0.250"
    assert teeth["capture_dir"].style == "path"
    add = [it for p in recorded["teeth"][0] for q in p.walk() for it in q.body.items()
           if it.identifier == "material_structures.teeth_add_tooth"]
    assert [it.op_props.get("source") for it in add] == ["TEMPLATE", "MESH"]


def _skip_painting_on_45():
    import bpy

    if bpy.app.version < (5, 0, 0):
        pytest.skip("the pictures are painted in Blender 5's theme (4.5 keeps panel colours per editor)")


def test_painting_every_feature(recorded, tmp_path):
    _skip_painting_on_45()
    for feature, (sidebar, material) in recorded.items():
        path = ui.paint_feature(sidebar, material, str(tmp_path / f"ui-{feature}.png"), scale=1.0)
        with Image.open(path) as im:
            assert im.width >= 300 and im.height > 200


class _Panel:
    """A panel whose ``draw`` runs ``_Panel.body(layout, context)``."""

    bl_label = "Probe"
    bl_idname = "VIEW3D_PT_probe"
    body = None

    def draw(self, context):
        _Panel.body(self.layout, context)


@pytest.mark.parametrize("body, error", [
    (lambda layout, ctx: layout.template_not_in_blender(), ui.UnknownLayoutCall),
    (lambda layout, ctx: layout.row().some_future_call(text="x"), ui.UnknownLayoutCall),
    (lambda layout, ctx: setattr(layout, "emboss_everything", True), ui.UnknownLayoutCall),
    (lambda layout, ctx: layout.prop(ctx.scene, "no_such_property"), AttributeError),
    (lambda layout, ctx: layout.operator("material_structures.no_such_operator"), ValueError),
    (lambda layout, ctx: setattr(layout.operator("material_structures.teeth_add_tooth"), "nope", 1), AttributeError),
])
def test_unknown_layout_calls_raise(addon_module, body, error):
    _Panel.body = staticmethod(body)
    with pytest.raises(error):
        ui.record_panel(_Panel, ui.PanelContext())


def test_known_templates_are_placeholders(addon_module):
    _Panel.body = staticmethod(lambda layout, ctx: layout.template_icon(icon_value=0, scale=4.0))
    body = ui.record_panel(_Panel, ui.PanelContext())
    assert [(it.kind, it.size) for it in body.items()] == [("template", 4.0)]


def test_every_recorded_call_paints(addon_module, tmp_path):
    """The calls our panels do not use yet record and paint too (split layouts, flows, menus, enums, ...)."""
    _skip_painting_on_45()
    def body(layout, ctx):
        layout.use_property_split = True
        layout.prop(ctx.scene.render, "resolution_x")
        layout.prop(ctx.scene.render, "engine", expand=True)
        layout.use_property_split = False
        col = layout.column(heading="Heading")
        col.enabled = False
        col.enabled = True  # the layout's own flag can be set back; a parent's cannot be overridden
        col.prop(ctx.scene.cursor, "location")
        col.prop(ctx.scene.render, "film_transparent", toggle=1)
        grid = layout.grid_flow(columns=2, align=True)
        grid.operator("material_structures.teeth_add_tooth", depress=True)
        grid.menu("VIEW3D_MT_add")
        layout.column_flow(columns=2).separator()
        layout.progress(factor=0.4, text="Fitting")
        row = layout.row()
        row.alert = True
        row.scale_y = 1.5
        row.prop_search(ctx.scene, "camera", ctx.scene, "objects")
        sub = layout.row()
        sub.active = False
        sub.row().active = True
        layout.template_icon(icon_value=0, scale=2.0)

    _Panel.body = staticmethod(body)
    rec = ui.RecordedPanel("VIEW3D_PT_probe", "Probe", True, None, ui.record_panel(_Panel, ui.PanelContext()))
    items = rec.body.items()
    assert [it.kind for it in items] == ["prop", "prop", "prop", "prop", "operator", "menu", "separator",
                                         "progress", "prop", "template"]
    assert items[0].split and items[1].style == "expand" and items[2].style == "vector"
    assert items[2].enabled and items[8].alert and items[8].scale_y == 1.5
    assert rec.body.children[-2].children[0].active is False
    ui.paint_feature([rec], [rec], str(tmp_path / "probe.png"), scale=1.0)
