"""Pictures of the add-on's sidebar panels for the README (``docs/ui-fabric.png``, ``ui-scratch.png``,
``ui-teeth.png``).

These are **not screen captures**: a headless ``bpy`` module has no window to capture. Each picture is
drawn from the panels' own ``draw()`` code, run against a recording stand-in for ``bpy.types.UILayout``
over a real scene made with the add-on's own operators, and from the live properties (each ``prop`` reads
the property's RNA: its type, name, current value, enum item names, subtype, unit). The recorded widget
tree is then painted with Pillow in Blender's look: colours from the current theme
(``preferences.themes[0]``: widget colours, panel header and back, sidebar), Blender's own UI font
(Inter, from the wheel's ``datafiles/fonts``) and Blender's widget proportions (20 px rows at 1x UI
scale), at 2x. Icons are drawn only where a simple shape says the same (a tick, a plus, a cross, ...);
others are left out. A layout call the recorder does not know raises :class:`UnknownLayoutCall` rather
than being skipped, so a picture never silently leaves out part of a panel.

Regenerate (a few seconds)::

    .venv/bin/python -m material_structures.showcase.ui_panels [OUT_DIR]   # default: docs/
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
from dataclasses import dataclass, field
from typing import Any

from ..render.session import prepare_user_resources

if "bpy" not in sys.modules:  # Blender's user resources go to a temporary folder (before the first import)
    prepare_user_resources()
import bpy  # noqa: E402

FEATURES = ("fabric", "scratch", "teeth")
#: the sidebar panels (by ``bl_idname``) shown open in each feature's picture; the others are drawn closed
OPEN_PANELS = {
    "fabric": {"VIEW3D_PT_material_structures", "VIEW3D_PT_material_structures_fabric"},
    "scratch": {"VIEW3D_PT_material_structures", "VIEW3D_PT_material_structures_scratch"},
    "teeth": {"VIEW3D_PT_material_structures", "VIEW3D_PT_material_structures_teeth"},
}
#: the Material Properties panel (by ``bl_idname``) drawn beside the sidebar, where the feature has one
MATERIAL_PANELS = {
    "fabric": "MATERIAL_PT_material_structures_fabric",
    "scratch": "MATERIAL_PT_material_structures_scratch",
}
ADDON_ID = "material_structures"


class UnknownLayoutCall(NotImplementedError):
    """A panel called a ``UILayout`` method or set an attribute the recorder does not draw."""


# -- the recorded tree ----------------------------------------------------------------------------------
@dataclass
class Item:
    """One widget of a panel, as ``draw()`` asked for it.

    ``kind``: ``label``, ``prop``, ``operator``, ``menu`` (a menu or an operator's enum menu),
    ``separator``, ``progress`` or ``template`` (drawn as a placeholder box). ``style`` (props): how Blender
    draws it: ``checkbox``, ``toggle``, ``number``, ``slider``, ``dropdown``, ``expand``, ``text``,
    ``path``, ``pointer``, ``color`` or ``vector``."""

    kind: str
    text: str = ""
    icon: str = "NONE"
    style: str = ""
    value: str = ""  # the value as Blender shows it
    fraction: float = 0.0  # sliders and progress bars: how full
    checked: bool = False
    options: list[tuple[str, bool]] = field(default_factory=list)  # expanded enums: (item name, selected)
    values: list[str] = field(default_factory=list)  # vectors: one text per component
    color: tuple[float, ...] = ()
    identifier: str = ""  # the property's or operator's identifier
    data_type: str = ""  # RNA type of the property's owner
    op_props: dict[str, Any] = field(default_factory=dict)  # properties set on an operator button
    enabled: bool = True
    active: bool = True
    alert: bool = False
    emboss: bool = True
    scale_y: float = 1.0
    size: float = 0.0  # templates: side in UI units
    split: bool = False  # drawn with use_property_split: the label in a column of its own at the left

    def texts(self) -> list[str]:
        return [t for t in (self.text, self.value, *self.values, *(o for o, _ in self.options)) if t]


_LAYOUT_ATTRS = {
    "enabled": True, "active": True, "alert": False, "scale_x": 1.0, "scale_y": 1.0,
    "use_property_split": False, "use_property_decorate": True, "alignment": "EXPAND", "emboss": "NORMAL",
    "operator_context": "INVOKE_DEFAULT", "active_default": False, "activate_init": False,
    "ui_units_x": 0.0, "ui_units_y": 0.0,
}
_TEMPLATE_NAMES = frozenset(f.identifier for f in bpy.types.UILayout.bl_rna.functions
                            if f.identifier.startswith("template_"))


class OperatorButton:
    """What ``layout.operator()`` returns: setting one of the operator's properties is recorded (an unknown
    one raises, as Blender does)."""

    def __init__(self, rna, store: dict[str, Any]):
        object.__setattr__(self, "_rna", rna)
        object.__setattr__(self, "_store", store)

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in self._rna.properties:
            raise AttributeError(f"operator {self._rna.identifier} has no property {name!r}")
        self._store[name] = value

    def __getattr__(self, name: str) -> Any:
        if name in self._store:
            return self._store[name]
        raise AttributeError(name)


class Layout:
    """Recording stand-in for ``bpy.types.UILayout``: the layout calls of a ``draw()`` build a tree of
    :class:`Layout` (``kind``: ``column``, ``row``, ``box``, ``split``, ``grid``) and :class:`Item`."""

    def __init__(self, kind: str = "column", align: bool = False, parent: Layout | None = None,
                 factor: float = 0.0, columns: int = 0, heading: str = ""):
        d = self.__dict__
        d["kind"], d["align"], d["factor"], d["columns"], d["heading"] = kind, align, factor, columns, heading
        d["children"] = []
        d["_attrs"] = dict(parent._attrs if parent is not None else _LAYOUT_ATTRS)  # a sub-layout inherits
        d["_parent_flags"] = {k: d["_attrs"][k] for k in ("enabled", "active")}

    # attributes ---------------------------------------------------------------------------------------
    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        attrs = self.__dict__.get("_attrs", {})
        if name in attrs:
            return attrs[name]
        if name in _TEMPLATE_NAMES:
            return lambda *args, **kw: self._template(name, **kw)
        raise UnknownLayoutCall(f"UILayout.{name} is not drawn by the recorder (showcase/ui_panels.py)")

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in _LAYOUT_ATTRS:
            raise UnknownLayoutCall(f"setting UILayout.{name} is not drawn by the recorder")
        if name in ("enabled", "active"):  # combined with the parent's: a sub-layout cannot re-enable
            value = bool(value) and self._parent_flags[name]
        self._attrs[name] = value

    # sub-layouts ----------------------------------------------------------------------------------------
    def _sub(self, kind: str, **kw) -> Layout:
        sub = Layout(kind, parent=self, **kw)
        self.children.append(sub)
        return sub

    def row(self, align: bool = False, heading: str = "", heading_ctxt: str = "", translate: bool = True) -> Layout:
        return self._sub("row", align=align, heading=heading)

    def column(self, align: bool = False, heading: str = "", heading_ctxt: str = "",
               translate: bool = True) -> Layout:
        return self._sub("column", align=align, heading=heading)

    def box(self) -> Layout:
        return self._sub("box")

    def split(self, factor: float = 0.0, align: bool = False) -> Layout:
        return self._sub("split", align=align, factor=factor)

    def grid_flow(self, row_major: bool = False, columns: int = 0, even_columns: bool = False,
                  even_rows: bool = False, align: bool = False) -> Layout:
        return self._sub("grid", align=align, columns=columns)

    def column_flow(self, columns: int = 0, align: bool = False) -> Layout:
        return self._sub("grid", align=align, columns=columns)

    # items ------------------------------------------------------------------------------------------------
    def _add(self, item: Item) -> Item:
        item.enabled, item.active, item.alert = self.enabled, self.active, self.alert
        item.scale_y = self.scale_y
        if self.emboss in ("NONE", "NONE_OR_STATUS"):
            item.emboss = False
        self.children.append(item)
        return item

    def label(self, text: str = "", text_ctxt: str = "", translate: bool = True, icon: str = "NONE",
              icon_value: int = 0) -> None:
        self._add(Item("label", text=text, icon=icon))

    def separator(self, factor: float = 1.0, type: str = "AUTO") -> None:
        self._add(Item("separator", fraction=factor))

    def separator_spacer(self) -> None:
        self._add(Item("separator", fraction=0.0))

    def progress(self, factor: float = 0.0, type: str = "BAR", text: str = "") -> None:
        self._add(Item("progress", text=text, fraction=float(factor)))

    def prop(self, data, property: str, text: str | None = None, text_ctxt: str = "", translate: bool = True,
             icon: str = "NONE", placeholder: str = "", expand: bool = False, slider: bool = False,
             toggle: int = -1, icon_only: bool = False, event: bool = False, full_event: bool = False,
             emboss: bool = True, index: int = -1, icon_value: int = 0, invert_checkbox: bool = False) -> None:
        item = describe_prop(data, property, text, expand=expand, slider=slider, toggle=toggle,
                             icon_only=icon_only, index=index)
        item.icon = icon
        self._add(item)
        item.emboss = emboss and item.emboss
        item.split = bool(self.use_property_split)

    def prop_search(self, data, property: str, search_data, search_property: str, text: str | None = None,
                    text_ctxt: str = "", translate: bool = True, icon: str = "NONE",
                    results_are_suggestions: bool = False, item_search_property: str = "") -> None:
        item = describe_prop(data, property, text)
        item.style = "pointer"
        item.icon = icon
        self._add(item)

    def operator(self, operator: str, text: str | None = None, text_ctxt: str = "", translate: bool = True,
                 icon: str = "NONE", emboss: bool = True, depress: bool = False, icon_value: int = 0,
                 search_weight: float = 0.0) -> OperatorButton:
        rna = operator_rna(operator)
        item = self._add(Item("operator", text=rna.name if text is None else text, icon=icon,
                              identifier=operator, checked=depress))
        item.emboss = emboss and item.emboss
        return OperatorButton(rna, item.op_props)

    def operator_menu_enum(self, operator: str, property: str, text: str | None = None, text_ctxt: str = "",
                           translate: bool = True, icon: str = "NONE") -> None:
        rna = operator_rna(operator)
        if property not in rna.properties or rna.properties[property].type != "ENUM":
            raise ValueError(f"{operator} has no enum property {property!r}")
        self._add(Item("menu", text=rna.name if text is None else text, icon=icon, identifier=operator))

    def menu(self, menu: str, text: str | None = None, text_ctxt: str = "", translate: bool = True,
             icon: str = "NONE", icon_value: int = 0) -> None:
        cls = getattr(bpy.types, menu, None)
        if cls is None:
            raise ValueError(f"unknown menu {menu!r}")
        self._add(Item("menu", text=cls.bl_label if text is None else text, icon=icon, identifier=menu))

    def _template(self, name: str, **kw) -> None:
        size = float(kw.get("scale", 0.0) or 0.0) or 5.0
        self._add(Item("template", text=name, identifier=name, size=size))

    # reading the tree ----------------------------------------------------------------------------------
    def items(self) -> list[Item]:
        """Every item of this layout and its sub-layouts, in drawing order."""
        out: list[Item] = []
        for child in self.children:
            out.extend(child.items() if isinstance(child, Layout) else [child])
        return out

    def texts(self) -> list[str]:
        """Every text the items show (labels, property names and values, button texts)."""
        return [t for it in self.items() for t in it.texts()]


def operator_rna(idname: str):
    """The RNA type of the operator ``idname`` (``module.name``); raises ValueError for an unknown one."""
    module, _, name = idname.partition(".")
    try:
        return getattr(getattr(bpy.ops, module), name).get_rna_type()
    except (AttributeError, KeyError) as exc:
        raise ValueError(f"unknown operator {idname!r}") from exc


def _format_number(value: float, prop) -> str:
    if prop.type == "INT":
        text = str(int(value))
    else:
        subtype = prop.subtype
        if subtype == "ANGLE":
            return f"{math.degrees(value):.{max(0, prop.precision - 2)}f}\N{DEGREE SIGN}"
        precision = prop.precision if prop.precision >= 0 else 3
        if subtype == "PERCENTAGE":
            return f"{value:.{max(0, precision - 2)}f}%"
        text = f"{value:.{precision}f}"
        if subtype == "DISTANCE" and prop.unit == "LENGTH":
            text += " m"
    if prop.subtype == "PIXEL":
        text += " px"
    return text


def describe_prop(data, identifier: str, text: str | None = None, expand: bool = False, slider: bool = False,
                  toggle: int = -1, icon_only: bool = False, index: int = -1) -> Item:
    """The :class:`Item` Blender draws for ``layout.prop(data, identifier, ...)``, read from the property's
    RNA and its current value. Raises AttributeError for a property ``data`` does not have."""
    props = data.bl_rna.properties
    if identifier not in props:
        raise AttributeError(f"{data.bl_rna.identifier} has no property {identifier!r}")
    prop = props[identifier]
    value = getattr(data, identifier)
    name = prop.name if text is None else text
    item = Item("prop", text=name, identifier=identifier, data_type=data.bl_rna.identifier)
    length = getattr(prop, "array_length", 0)
    if prop.type == "BOOLEAN" and length == 0:
        item.checked = bool(value)
        item.style = "toggle" if (toggle == 1 or icon_only) else "checkbox"
    elif prop.type in ("INT", "FLOAT") and length > 0 and index < 0:
        values = list(value)
        if prop.subtype in ("COLOR", "COLOR_GAMMA"):
            item.style, item.color = "color", tuple(float(v) for v in values)
        else:
            item.style = "vector"
            labels = "XYZW" if prop.subtype in ("XYZ", "TRANSLATION", "DIRECTION", "EULER", "VELOCITY",
                                                 "ACCELERATION", "COORDINATES", "XYZ_LENGTH") else "RGBA"
            item.values = [f"{labels[i] if prop.subtype not in ('NONE', '') else ''}"
                           f"{':  ' if prop.subtype not in ('NONE', '') else ''}{_format_number(v, prop)}"
                           for i, v in enumerate(values)]
    elif prop.type in ("INT", "FLOAT"):
        v = value[index] if length > 0 else value
        item.value = _format_number(v, prop)
        lo, hi = prop.soft_min, prop.soft_max
        is_slider = slider or prop.subtype in ("FACTOR", "PERCENTAGE")
        item.style = "slider" if is_slider else "number"
        if is_slider and hi > lo:
            item.fraction = min(1.0, max(0.0, (v - lo) / (hi - lo)))
    elif prop.type == "ENUM":
        ids = sorted(value) if isinstance(value, set) else [value]
        names = [bpy.types.UILayout.enum_item_name(data, identifier, i) or i for i in ids]
        if expand or prop.is_enum_flag:
            item.style = "expand"
            every = [it.identifier for it in prop.enum_items] or ids
            item.options = [(bpy.types.UILayout.enum_item_name(data, identifier, i) or i, i in ids) for i in every]
        else:
            item.style, item.value = "dropdown", ", ".join(names)
    elif prop.type == "STRING":
        item.value = str(value)
        item.style = "path" if prop.subtype in ("DIR_PATH", "FILE_PATH", "FILE_NAME") else "text"
    elif prop.type == "POINTER":
        item.style = "pointer"
        item.value = getattr(value, "name", "") if value is not None else ""
    else:
        raise UnknownLayoutCall(f"cannot draw {data.bl_rna.identifier}.{identifier} (a {prop.type} property)")
    return item


# -- running the panels -----------------------------------------------------------------------------------
class PanelContext:
    """The ``context`` a panel's ``poll``/``draw`` sees: the scene, view layer, active object and its active
    material, and anything else from ``bpy.context``."""

    def __init__(self, scene=None, obj=None):
        self.scene = scene or bpy.context.scene
        self.view_layer = self.scene.view_layers[0]
        self.active_object = self.object = obj if obj is not None else self.view_layer.objects.active
        self.material = self.active_object.active_material if self.active_object is not None else None
        self.collection = self.scene.collection
        self.space_data = None
        self.region = None

    def __getattr__(self, name: str) -> Any:
        return getattr(bpy.context, name)


@dataclass
class RecordedPanel:
    """One panel as it would be drawn: its title, open or closed, its recorded header and body, its
    sub-panels."""

    idname: str
    label: str
    is_open: bool
    header: Layout | None
    body: Layout
    children: list[RecordedPanel] = field(default_factory=list)

    def walk(self):
        yield self
        for c in self.children:
            yield from c.walk()

    def texts(self) -> list[str]:
        return [t for p in self.walk() for t in (p.label, *p.body.texts(), *(p.header.texts() if p.header else []))]


def panel_classes(addon_module: str) -> list[type]:
    """The registered panel classes of the enabled add-on ``addon_module`` (``bl_ext.<repo>.<id>``) in
    registration order (the order Blender lists them in)."""
    import sys as _sys

    pkg = _sys.modules[f"{addon_module}.addon"]
    return [c for c in pkg.CLASSES if issubclass(c, bpy.types.Panel)]


def record_panel(cls: type, context, is_open: bool = True) -> Layout:
    """Run ``cls.draw`` with a recording layout; returns the recorded body."""
    layout = Layout()
    stand_in = type("PanelStandIn", (), {"layout": layout, "bl_label": cls.bl_label, "bl_idname": cls.bl_idname})()
    if is_open:
        cls.draw(stand_in, context)
    return layout


def record_stack(classes: list[type], context, open_panels: set[str] | None = None,
                 space: str = "VIEW_3D", region: str = "UI") -> list[RecordedPanel]:
    """Record every panel of ``classes`` in ``space``/``region`` that polls true for ``context``, nested by
    ``bl_parent_id``. ``open_panels``: the ``bl_idname``s drawn open (None: all)."""
    mine = [c for c in classes if c.bl_space_type == space and c.bl_region_type == region]
    by_parent: dict[str, list[type]] = {}
    for c in mine:
        by_parent.setdefault(getattr(c, "bl_parent_id", "") or "", []).append(c)

    def build(cls: type) -> RecordedPanel | None:
        poll = getattr(cls, "poll", None)
        if poll is not None and not poll(context):
            return None
        is_open = open_panels is None or cls.bl_idname in open_panels
        header = None
        if hasattr(cls, "draw_header"):
            header = Layout("row")
            stand_in = type("PanelStandIn", (), {"layout": header})()
            cls.draw_header(stand_in, context)
        rec = RecordedPanel(cls.bl_idname, cls.bl_label, is_open, header, record_panel(cls, context, is_open))
        if is_open:
            rec.children = [p for child in by_parent.get(cls.bl_idname, []) if (p := build(child)) is not None]
        return rec

    return [p for c in by_parent.get("", []) if (p := build(c)) is not None]


# -- the scenes -------------------------------------------------------------------------------------------
def enable_addon(repo: str = "ui_docs") -> str:
    """Enable this checkout as the extension ``bl_ext.<repo>.material_structures`` (a temporary extension
    repository); returns the module name. Call after ``prepare_user_resources()``."""
    import addon_utils

    module = f"bl_ext.{repo}.{ADDON_ID}"
    if module in {m.module for m in bpy.context.preferences.addons}:
        return module
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    repo_dir = tempfile.mkdtemp(prefix="ms-ui-docs-")
    os.symlink(root, os.path.join(repo_dir, ADDON_ID))
    bpy.context.preferences.extensions.repos.new(name=repo, module=repo, custom_directory=repo_dir, source="USER")

    def _raise(exc):
        raise exc

    if addon_utils.enable(module, default_set=True, handle_error=_raise) is None:
        raise RuntimeError(f"could not enable {module}")
    return module


def _select_only(obj) -> None:
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def build_scene(feature: str, scratches: int = 300):
    """A new scene for ``feature``, made as a user would with the add-on's operators; returns its
    :class:`PanelContext`. fabric: a plane with a new Velvet fabric material; scratch: a plane with
    generated wear scratches (``scratches`` of them); teeth: an incisor from the tooth template."""
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    bpy.ops.material_structures.setup_cycles_osl()
    if feature == "fabric":
        bpy.ops.mesh.primitive_plane_add(size=2.0)
        _select_only(bpy.context.active_object)
        _check(bpy.ops.material_structures.fabric_new_material(preset="VELVET"))
    elif feature == "scratch":
        bpy.ops.mesh.primitive_plane_add(size=2.0)
        _select_only(bpy.context.active_object)
        _check(bpy.ops.material_structures.scratch_generate("EXEC_DEFAULT", pattern="WEAR", count=scratches))
    elif feature == "teeth":
        _check(bpy.ops.material_structures.teeth_add_tooth("EXEC_DEFAULT", source="TEMPLATE"))
        tooth = bpy.context.view_layer.objects.active
        tooth.ms_tooth.buccal, tooth.ms_tooth.occlusal = 0.25, -0.1
        # a capture's scene description (two teeth) read with Read Capture Teeth; its first tooth's fit is
        # then given to this incisor, as a user picks it in the list
        fs = scene.ms_teeth_fit
        fs.capture_dir = _capture_scene_json()
        _check(bpy.ops.material_structures.teeth_read_capture_teeth())
        fs.tooth_map[0].enamel = tooth
    else:
        raise ValueError(f"unknown feature {feature!r}; one of {FEATURES}")
    return PanelContext(scene, bpy.context.view_layer.objects.active)


def _capture_scene_json() -> str:
    """A folder holding a capture's ``scene.json`` (two synthetic teeth, written by the core; no images:
    reading the capture's teeth needs only this)."""
    import json

    from ..core.teeth.synthetic import make_scene

    # one fixed folder (the same content every run): the path shows in the picture, which then stays the same
    folder = os.path.join(tempfile.gettempdir(), "ms-ui-docs", "capture") + os.sep
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "scene.json"), "w", encoding="utf-8") as f:
        json.dump(make_scene(n_teeth=2, resolution=8).to_dict(), f)
    return folder


def _check(result: set[str]) -> None:
    if "FINISHED" not in result:
        raise RuntimeError(f"the operator did not finish: {result}")


def record_feature(addon_module: str, feature: str, context) -> tuple[list[RecordedPanel], list[RecordedPanel]]:
    """The sidebar stack (the feature's panels open, the others closed) and the feature's Material
    Properties panel (an empty list where it has none) as recorded over ``context``."""
    classes = panel_classes(addon_module)
    sidebar = record_stack(classes, context, OPEN_PANELS[feature])
    material: list[RecordedPanel] = []
    if feature in MATERIAL_PANELS:
        mine = [c for c in classes if c.bl_idname == MATERIAL_PANELS[feature]]
        material = record_stack(mine, context, None, space="PROPERTIES", region="WINDOW")
    return sidebar, material


# -- painting -------------------------------------------------------------------------------------------
UNIT = 20  # Blender's widget unit at 1x UI scale: one row
HEADER = 24  # panel header (1.2 units)
SPACE_Y = 2  # between the rows of a column
SPACE_X = 4  # between the items of a row
BOX_PAD = 5
PANEL_PAD_X = 8
PANEL_PAD_TOP = 6
PANEL_PAD_BOTTOM = 8
PANEL_GAP = 4
REGION_PAD = 6
TAB_WIDTH = 22
OVERSAMPLE = 2  # drawn at 2x this, then reduced (smooth edges)


def _rgba(c, alpha: float | None = None) -> tuple[int, int, int, int]:
    c = tuple(c)
    a = c[3] if len(c) > 3 and alpha is None else (1.0 if alpha is None else alpha)
    return tuple(int(round(255 * min(1.0, max(0.0, v)))) for v in (*c[:3], a))


def _srgb(v: float) -> float:
    v = max(0.0, v)
    return 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055


class Theme:
    """The colours of ``preferences.themes[0]`` the pictures use (sRGB bytes)."""

    def __init__(self):
        t = bpy.context.preferences.themes[0]
        ui = t.user_interface
        if not hasattr(ui, "panel_header"):
            raise RuntimeError(f"the panel pictures are painted in Blender 5's theme; Blender "
                               f"{bpy.app.version_string} keeps panel colours per editor")
        self.wcol = {name: getattr(ui, f"wcol_{name}") for name in (
            "regular", "tool", "toggle", "option", "num", "numslider", "menu", "text", "box", "progress",
            "pulldown")}
        self.panel_header = _rgba(ui.panel_header)
        self.panel_back = _rgba(ui.panel_back)
        self.panel_sub_back = _rgba(ui.panel_sub_back)
        self.panel_outline = _rgba(ui.panel_outline)
        self.panel_title = _rgba(ui.panel_title)
        self.panel_text = _rgba(ui.panel_text)
        self.emboss = _rgba(ui.widget_emboss)
        self.region_back = _rgba(t.regions.sidebars.back, 1.0)  # drawn opaque: no viewport behind it here
        self.tab_back = _rgba(t.regions.sidebars.tab_back, 1.0)
        self.properties_back = _rgba(t.properties.space.back, 1.0)
        self.editor_border = _rgba(ui.editor_border, 1.0)
        self.error = _rgba(ui.wcol_state.error)
        self.roundness = ui.wcol_regular.roundness
        self.panel_roundness = ui.panel_roundness

    def w(self, name: str, key: str) -> tuple[int, int, int, int]:
        return _rgba(getattr(self.wcol[name], key))


def _font_path() -> str:
    fonts = os.path.join(bpy.utils.resource_path("LOCAL"), "datafiles", "fonts")
    for name in ("Inter.woff2", "Inter.ttf", "DejaVuSans.woff2", "DejaVuSans.ttf"):
        if os.path.exists(os.path.join(fonts, name)):
            return os.path.join(fonts, name)
    raise FileNotFoundError(f"no Blender UI font in {fonts}")


class Painter:
    """Paints recorded panels at ``scale`` x Blender's 1x sizes."""

    def __init__(self, scale: float = 2.0):
        from PIL import ImageFont

        self.s = scale * OVERSAMPLE
        self.out_scale = scale
        self.theme = Theme()
        points = bpy.context.preferences.ui_styles[0].widget.points
        size = points * self.s
        self.font = ImageFont.truetype(_font_path(), round(size))
        title_points = bpy.context.preferences.ui_styles[0].panel_title.points
        self.title_font = ImageFont.truetype(_font_path(), round(title_points * self.s))
        try:  # Inter is a variable font: the style's weight
            self.title_font.set_variation_by_axes(
                [14, bpy.context.preferences.ui_styles[0].panel_title.character_weight])
            self.font.set_variation_by_axes([14, bpy.context.preferences.ui_styles[0].widget.character_weight])
        except (OSError, AttributeError):
            pass
        self.draw = None

    # geometry helpers (1x units in, pixels out) --------------------------------------------------------
    def px(self, v: float) -> int:
        return int(round(v * self.s))

    def text_w(self, text: str, font=None) -> float:
        return (font or self.font).getlength(text) / self.s

    # measuring -------------------------------------------------------------------------------------------
    def item_height(self, item: Item) -> float:
        if item.kind == "separator":
            return 0.4 * UNIT * item.fraction
        if item.kind == "template":
            return UNIT * item.size
        label_row = 1 if item.text and not item.split else 0  # split layouts put the label beside it
        if item.style == "vector":
            return UNIT * (len(item.values) + label_row)
        if item.style == "expand":
            return UNIT * (1 + label_row)
        return UNIT * item.scale_y

    def item_width(self, item: Item) -> float:
        """Estimated width (Blender sizes the items of a row by these, then scales them to fit)."""
        pad = 2 * 6
        icon = UNIT if item.icon not in ("NONE", "") else 0
        if item.kind == "label":
            return self.text_w(item.text) + pad + icon
        if item.kind == "separator":
            return 0.4 * UNIT * item.fraction
        if item.style == "checkbox":
            return UNIT + self.text_w(item.text) + pad
        if item.style == "color" and not item.text:
            return 3 * UNIT
        return max(3 * UNIT, self.text_w(item.text) + self.text_w(item.value) + pad + icon)

    def layout_height(self, lay: Layout, w: float) -> float:
        return self.place(lay, 0, 0, w, paint=False)

    # placing and painting ----------------------------------------------------------------------------
    def place(self, node, x: float, y: float, w: float, paint: bool = True, pos: tuple[bool, bool] = (True, True),
              in_align: bool = False) -> float:
        """Place ``node`` (a Layout or an Item) at (x, y) with width w; paint it if ``paint``; returns its
        height. ``pos``: whether it is first / last in an aligned group (its rounded corners)."""
        if isinstance(node, Item):
            h = self.item_height(node)
            if paint:
                self.paint_item(node, x, y, w, h, pos if in_align else (True, True), in_align)
            return h
        kids = node.children
        if node.kind == "box":
            inner_h = self._column(kids, 0, 0, w - 2 * BOX_PAD, False, False)
            h = inner_h + 2 * BOX_PAD
            if paint:
                wb = self.theme.wcol["box"]
                self.rrect(x, y, w, h, 5, _rgba(wb.inner), _rgba(wb.outline))
                self._column(kids, x + BOX_PAD, y + BOX_PAD, w - 2 * BOX_PAD, False, True)
            return h
        if node.kind == "column":
            return self._column(kids, x, y, w, node.align, paint, node.heading)
        if node.kind == "row":
            return self._row(kids, x, y, w, node.align, paint, node.heading)
        if node.kind == "split":
            n = len(kids)
            if n == 0:
                return 0.0
            gap = 0 if node.align else SPACE_X
            first = node.factor if node.factor > 0 else 1.0 / n
            widths = [first * (w - gap * (n - 1))] + [(1 - first) * (w - gap * (n - 1)) / max(1, n - 1)] * (n - 1)
            h, cx = 0.0, x
            for i, (kid, kw) in enumerate(zip(kids, widths, strict=True)):
                h = max(h, self.place(kid, cx, y, kw, paint, (i == 0, i == n - 1), node.align))
                cx += kw + gap
            return h
        if node.kind == "grid":
            cols = node.columns if node.columns > 0 else max(1, int(w // (8 * UNIT)))
            rows = math.ceil(len(kids) / cols) if kids else 0
            gap = 0 if node.align else SPACE_X
            cw = (w - gap * (cols - 1)) / cols
            h = 0.0
            for c in range(cols):
                col = kids[c * rows:(c + 1) * rows]
                h = max(h, self._column(col, x + c * (cw + gap), y, cw, node.align, paint))
            return h
        raise UnknownLayoutCall(f"layout kind {node.kind!r}")

    def _column(self, kids, x, y, w, align, paint, heading: str = "") -> float:
        cy = y
        if heading:
            if paint:
                self.text(heading, x + 6, cy, UNIT, self.theme.panel_text)
            cy += UNIT + SPACE_Y
        for i, kid in enumerate(kids):
            if i:
                cy += 0 if align else SPACE_Y
            cy += self.place(kid, x, cy, w, paint, (i == 0, i == len(kids) - 1), align)
        return cy - y

    def _row(self, kids, x, y, w, align, paint, heading: str = "") -> float:
        if not kids:
            return 0.0
        gap = 0 if align else SPACE_X
        est = [self._estimate(k) for k in kids]
        total = w - gap * (len(kids) - 1)
        widths = [total * e / sum(est) for e in est]
        h, cx = 0.0, x
        for i, (kid, kw) in enumerate(zip(kids, widths, strict=True)):
            h = max(h, self.place(kid, cx, y, kw, paint, (i == 0, i == len(kids) - 1), align))
            cx += kw + gap
        return h

    def _estimate(self, node) -> float:
        if isinstance(node, Item):
            return self.item_width(node)
        if node.kind == "row":
            return sum(self._estimate(k) for k in node.children) or UNIT
        return max((self._estimate(k) for k in node.children), default=UNIT)

    # primitives ------------------------------------------------------------------------------------------
    def rrect(self, x, y, w, h, r, fill, outline=None, corners=(True, True, True, True)) -> None:
        box = (self.px(x), self.px(y), self.px(x + w) - 1, self.px(y + h) - 1)
        rad = self.px(min(r, h / 2, w / 2))
        self.draw.rounded_rectangle(box, rad, fill=fill, outline=outline, width=max(1, self.px(0.5)) if outline
                                    else 0, corners=corners)

    def text(self, text: str, x, y, h, color, align: str = "left", w: float | None = None, font=None,
             middle: bool = False) -> None:
        font = font or self.font
        if w is not None:
            text = self.clip(text, w, font, middle)
        ty = self.px(y + h / 2)
        if align == "center":
            self.draw.text((self.px(x + (w or 0) / 2), ty), text, font=font, fill=color, anchor="mm")
        elif align == "right":
            self.draw.text((self.px(x + (w or 0)), ty), text, font=font, fill=color, anchor="rm")
        else:
            self.draw.text((self.px(x), ty), text, font=font, fill=color, anchor="lm")

    def clip(self, text: str, w: float, font=None, middle: bool = False) -> str:
        """``text`` shortened with an ellipsis to fit ``w`` (at its end, or in its middle as Blender clips
        button texts)."""
        if self.text_w(text, font) <= w:
            return text
        dots = "\N{HORIZONTAL ELLIPSIS}"
        if middle:
            head, tail = text[: (len(text) + 1) // 2], text[(len(text) + 1) // 2:]
            while (head or tail) and self.text_w(head + dots + tail, font) > w:
                if len(head) >= len(tail):
                    head = head[:-1]
                else:
                    tail = tail[1:]
            return head.rstrip() + dots + tail.lstrip()
        while text and self.text_w(text + dots, font) > w:
            text = text[:-1]
        return text + dots if text else ""

    def icon(self, name: str, x, y, color) -> bool:
        """Draw icon ``name`` as a simple shape in the 16 px square at (x, y); False where there is none."""
        d, s = self.draw, self.s
        cx, cy = (x + 8) * s, (y + 8) * s
        lw = max(1, round(1.3 * s))
        if name == "CHECKMARK":
            d.line([(cx - 5 * s, cy), (cx - 1.5 * s, cy + 3.5 * s), (cx + 5 * s, cy - 4 * s)], fill=color, width=lw,
                   joint="curve")
        elif name == "ADD":
            d.line([(cx - 5 * s, cy), (cx + 5 * s, cy)], fill=color, width=lw)
            d.line([(cx, cy - 5 * s), (cx, cy + 5 * s)], fill=color, width=lw)
        elif name == "CANCEL":
            d.ellipse([cx - 6 * s, cy - 6 * s, cx + 6 * s, cy + 6 * s], outline=color, width=lw)
            d.line([(cx - 3 * s, cy - 3 * s), (cx + 3 * s, cy + 3 * s)], fill=color, width=lw)
            d.line([(cx - 3 * s, cy + 3 * s), (cx + 3 * s, cy - 3 * s)], fill=color, width=lw)
        elif name == "PLAY":
            d.polygon([(cx - 4 * s, cy - 5 * s), (cx + 5 * s, cy), (cx - 4 * s, cy + 5 * s)], fill=color)
        elif name == "FORWARD":
            d.line([(cx - 2 * s, cy - 5 * s), (cx + 3 * s, cy), (cx - 2 * s, cy + 5 * s)], fill=color, width=lw,
                   joint="curve")
        elif name in ("INFO", "ERROR"):
            if name == "INFO":
                d.ellipse([cx - 6 * s, cy - 6 * s, cx + 6 * s, cy + 6 * s], outline=color, width=lw)
            else:
                d.polygon([(cx, cy - 6.5 * s), (cx + 7 * s, cy + 5.5 * s), (cx - 7 * s, cy + 5.5 * s)],
                          outline=color, width=lw)
            top, bottom = (cy - 1 * s, cy + 3.5 * s) if name == "INFO" else (cy - 3 * s, cy + 1.5 * s)
            d.line([(cx, top), (cx, bottom)], fill=color, width=lw)
            dot = cy - 3.5 * s if name == "INFO" else cy + 3.5 * s
            d.ellipse([cx - 0.8 * s, dot - 0.8 * s, cx + 0.8 * s, dot + 0.8 * s], fill=color)
        elif name == "LOOP_BACK":
            d.arc([cx - 5 * s, cy - 4 * s, cx + 5 * s, cy + 5 * s], 180, 90, fill=color, width=lw)
            d.polygon([(cx - 7.5 * s, cy - 0.5 * s), (cx - 2.5 * s, cy - 0.5 * s), (cx - 5 * s, cy + 3 * s)],
                      fill=color)
        elif name in ("IMPORT", "EXPORT"):
            d.line([(cx - 6 * s, cy + 2 * s), (cx - 6 * s, cy + 6 * s), (cx + 6 * s, cy + 6 * s),
                    (cx + 6 * s, cy + 2 * s)], fill=color, width=lw)
            d.line([(cx, cy - 6 * s), (cx, cy + 2.5 * s)], fill=color, width=lw)
            tip, base = (cy + 3.5 * s, cy - 0.5 * s) if name == "IMPORT" else (cy - 7 * s, cy - 3 * s)
            d.polygon([(cx - 3.5 * s, base), (cx + 3.5 * s, base), (cx, tip)], fill=color)
        else:
            return False
        return True

    # widgets ---------------------------------------------------------------------------------------------
    def _fade(self, c, item: Item):
        if item.enabled and item.active:
            return c
        return (*c[:3], int(c[3] * 0.5))

    def widget(self, kind: str, x, y, w, h, item: Item, pos=(True, True), aligned=False, horizontal=True,
               selected=False) -> None:
        """The rounded widget body in colour set ``kind`` (aligned groups keep round only their outer corners)."""
        wc = self.theme.wcol[kind]
        inner = _rgba(wc.inner_sel if selected else wc.inner)
        if item.alert:
            inner = self.theme.error
        r = self.theme.roundness * UNIT * 0.5
        first, last = pos
        if aligned:
            corners = (first, last, last, first) if horizontal else (first, first, last, last)
        else:
            corners = (True, True, True, True)
        # emboss: a faint line below the widget
        self.rrect(x, y + 1, w, h - 1, r, self._fade(self.theme.emboss, item), corners=corners)
        self.rrect(x, y, w, h - 1, r, self._fade(inner, item), self._fade(_rgba(wc.outline), item), corners=corners)

    def paint_item(self, item: Item, x, y, w, h, pos, aligned) -> None:
        th = self.theme
        text_col = self._fade(th.panel_text, item)
        horizontal = True
        if item.kind == "separator":
            return
        if item.kind == "label":
            tx = x + 4
            if item.icon not in ("NONE", "") and self.icon(item.icon, x + 2, y + 2, text_col):
                tx = x + 22
            self.text(item.text, tx, y, h, text_col, w=w - (tx - x) - 2)
            return
        if item.kind == "template":
            wc = th.wcol["box"]
            self.rrect(x, y, w, h - 2, 4, _rgba(wc.inner), _rgba(wc.outline))
            self.text(f"({item.identifier}: not drawn here)", x, y, h, self._fade(th.panel_text, item), "center", w)
            return
        if item.kind == "progress":
            self.widget("progress", x, y, w, h, item, pos, aligned)
            wc = th.wcol["progress"]
            if item.fraction > 0:
                self.rrect(x, y, w * item.fraction, h - 1, th.roundness * UNIT * 0.5, self._fade(_rgba(wc.item), item))
            self.text(item.text, x, y, h, text_col, "center", w)
            return
        if item.kind in ("operator", "menu"):
            kind = "menu" if item.kind == "menu" else ("toggle" if item.checked else "tool")
            wtext = self._fade(_rgba(th.wcol[kind].text), item)
            if item.emboss:
                self.widget(kind, x, y, w, h, item, pos, aligned, horizontal, selected=item.checked)
            if item.kind == "menu":
                self._chevron(x + w - 12, y, h, self._fade(_rgba(th.wcol["menu"].item), item))
                tx = x + 6
                if item.icon not in ("NONE", "") and self.icon(item.icon, x + 3, y + 2, wtext):
                    tx = x + 22
                self.text(item.text, tx, y, h, wtext, w=w - (tx - x) - 16)
                return
            tw = self.text_w(item.text)
            has_icon = item.icon not in ("NONE", "")
            total = tw + (20 if has_icon else 0)
            sx = x + max(4, (w - total) / 2)
            if has_icon and self.icon(item.icon, sx, y + 2, wtext):
                sx += 20
            self.text(item.text, sx, y, h, wtext, w=x + w - sx - 4, middle=True)
            return
        if item.kind == "prop":
            if item.split and item.text and item.style != "checkbox":
                lw = w * 0.4
                self.text(item.text, x, y, UNIT, text_col, "right", lw - 6)
                item = Item(**{**item.__dict__, "text": ""})
                x, w = x + lw, w - lw
            self.paint_prop(item, x, y, w, h, pos, aligned)
            return
        raise UnknownLayoutCall(f"cannot paint a {item.kind!r} item")

    def _chevron(self, x, y, h, color) -> None:
        s, cy = self.s, y + h / 2
        self.draw.line([((x - 3) * s, (cy - 1.5) * s), (x * s, (cy + 1.5) * s), ((x + 3) * s, (cy - 1.5) * s)],
                       fill=color, width=max(1, round(1.2 * s)), joint="curve")

    def _with_label(self, item: Item, x, w) -> tuple[float, float]:
        """Blender's separate label of enum, text and pointer props: the label left, the widget right."""
        if not item.text:
            return x, w
        lw = min(self.text_w(item.text) + 14, w * 0.45)
        return x + lw, w - lw

    def paint_prop(self, item: Item, x, y, w, h, pos, aligned) -> None:
        th = self.theme
        text_col = self._fade(th.panel_text, item)
        st = item.style
        if st == "checkbox":
            box = 14
            wc = th.wcol["option"]
            bx, by = x + 2, y + (UNIT - box) / 2 - 0.5
            inner = _rgba(wc.inner_sel if item.checked else wc.inner)
            self.rrect(bx, by + 1, box, box, 3, self._fade(th.emboss, item))
            self.rrect(bx, by, box, box, 3, self._fade(inner, item), self._fade(_rgba(wc.outline), item))
            if item.checked:
                s = self.s
                pts = [((bx + 3.2) * s, (by + 7.2) * s), ((bx + 6) * s, (by + 10) * s), ((bx + 11) * s, (by + 4) * s)]
                self.draw.line(pts, fill=self._fade(_rgba(wc.item), item), width=max(1, round(1.5 * s)),
                               joint="curve")
            if item.text:
                self.text(item.text, bx + box + 5, y, UNIT, text_col, w=w - box - 9)
            return
        if st in ("number", "slider"):
            kind = "numslider" if st == "slider" else "num"
            wc = th.wcol[kind]
            self.widget(kind, x, y, w, h, item, pos, aligned)
            if st == "slider" and item.fraction > 0:
                r = th.roundness * UNIT * 0.5
                fw = max(2 * r if item.fraction > 0.02 else 0, w * item.fraction)
                first, last = pos if aligned else (True, True)
                full = item.fraction > 0.99
                self.rrect(x, y, fw, h - 1, r, self._fade(_rgba(wc.item), item),
                           corners=(first or not aligned, full and (last or not aligned),
                                    full and (last or not aligned), first or not aligned) if aligned
                           else (True, full, full, True))
            wtext = self._fade(_rgba(wc.text), item)
            if item.text:
                vw = self.text_w(item.value)
                self.text(item.text, x + 8, y, h, wtext, w=w - vw - 20)
                self.text(item.value, x, y, h, wtext, "right", w - 8)
            else:
                self.text(item.value, x, y, h, wtext, "center", w)
            return
        if st == "toggle":
            self.widget("toggle", x, y, w, h, item, pos, aligned, selected=item.checked)
            self.text(item.text, x, y, h, self._fade(_rgba(th.wcol["toggle"].text), item), "center", w)
            return
        if st == "expand":
            cy = y
            if item.text:
                self.text(item.text, x + 4, cy, UNIT, text_col, w=w)
                cy += UNIT
            n = len(item.options)
            ow = w / max(1, n)
            for i, (name, sel) in enumerate(item.options):
                self.widget("toggle", x + i * ow, cy, ow, UNIT, item, (i == 0, i == n - 1), True, selected=sel)
                self.text(name, x + i * ow, cy, UNIT, self._fade(_rgba(th.wcol["toggle"].text), item), "center", ow)
            return
        if st == "vector":
            cy = y
            if item.text:
                self.text(item.text + ":", x + 4, cy, UNIT, text_col, w=w)
                cy += UNIT
            n = len(item.values)
            for i, v in enumerate(item.values):
                self.widget("num", x, cy + i * UNIT, w, UNIT, item, (i == 0, i == n - 1), True, horizontal=False)
                self.text(v, x, cy + i * UNIT, UNIT, self._fade(_rgba(th.wcol["num"].text), item), "center", w)
            return
        # the props with a separate label
        if item.text:
            self.text(item.text, x + 4, y, UNIT, text_col, w=w * 0.45 - 6)
        fx, fw = self._with_label(item, x, w)
        if st == "dropdown":
            self.widget("menu", fx, y, fw, h, item, pos, aligned)
            self._chevron(fx + fw - 12, y, h, self._fade(_rgba(th.wcol["menu"].item), item))
            self.text(item.value, fx + 6, y, h, self._fade(_rgba(th.wcol["menu"].text), item), w=fw - 22)
        elif st in ("text", "path", "pointer"):
            self.widget("text", fx, y, fw, h, item, pos, aligned)
            tcol = self._fade(_rgba(th.wcol["text"].text), item)
            bw = 0
            if st == "path":  # the file browser button at the right end
                bw = UNIT
                self.rrect(fx + fw - bw, y, bw, h - 1, th.roundness * UNIT * 0.5,
                           self._fade(_rgba(th.wcol["tool"].inner), item), corners=(False, True, True, False))
                self._folder(fx + fw - bw + 3, y + 3, tcol)
            self.text(item.value, fx + 6, y, h, tcol, w=fw - bw - 10, middle=st == "path")
        elif st == "color":
            srgb = tuple(_srgb(c) for c in item.color[:3])
            self.widget("regular", fx, y, fw, h, item, pos, aligned)
            self.rrect(fx + 1, y + 1, fw - 2, h - 3, th.roundness * UNIT * 0.5 - 1, self._fade(_rgba(srgb, 1.0), item))
        else:
            raise UnknownLayoutCall(f"cannot paint a {st!r} property")

    def _folder(self, x, y, color) -> None:
        s = self.s
        self.draw.polygon([((x + 1) * s, (y + 3) * s), ((x + 5) * s, (y + 3) * s), ((x + 6.5) * s, (y + 4.5) * s),
                           ((x + 13) * s, (y + 4.5) * s), ((x + 13) * s, (y + 12) * s), ((x + 1) * s, (y + 12) * s)],
                          outline=color, width=max(1, round(1.2 * s)))

    # panels ------------------------------------------------------------------------------------------------
    def panel_height(self, panel: RecordedPanel, w: float) -> float:
        return self.paint_panel(panel, 0, 0, w, paint=False)

    def paint_panel(self, panel: RecordedPanel, x, y, w, paint: bool = True, sub: bool = False) -> float:
        th = self.theme
        r = th.panel_roundness * UNIT * 0.5 if not sub else 3
        body_w = w - 2 * PANEL_PAD_X
        if panel.is_open:
            content = self.place(panel.body, 0, 0, body_w, paint=False) if panel.body.children else 0.0
            kids_h = sum(self.panel_height_sub(c, w) + PANEL_GAP for c in panel.children)
            body_h = (PANEL_PAD_TOP + content + PANEL_PAD_BOTTOM if panel.body.children else 0) + kids_h
            if panel.body.children and panel.children:
                body_h -= PANEL_PAD_BOTTOM / 2
        else:
            body_h = 0.0
        h = HEADER + body_h
        if not paint:
            return h
        if sub:
            self.rrect(x, y, w, h, r, th.panel_sub_back)
            self.rrect(x, y, w, HEADER, r, th.panel_sub_back, corners=(True, True, not panel.is_open,
                                                                       not panel.is_open))
        else:
            self.rrect(x, y, w, h, r, th.panel_back, th.panel_outline)
            self.rrect(x, y, w, HEADER, r, th.panel_header, th.panel_outline,
                       corners=(True, True, not panel.is_open, not panel.is_open))
        self._disclosure(x + 12, y + HEADER / 2, panel.is_open, th.panel_title)
        self.text(panel.label, x + 24, y, HEADER, th.panel_title, w=w - 30, font=self.title_font)
        if panel.header is not None and panel.header.children:
            tw = self.text_w(panel.label, self.title_font)
            self.place(panel.header, x + 30 + tw, y + (HEADER - UNIT) / 2, w - tw - 40)
        if panel.is_open:
            cy = y + HEADER
            if panel.body.children:
                cy += PANEL_PAD_TOP
                cy += self.place(panel.body, x + PANEL_PAD_X, cy, body_w)
                cy += PANEL_PAD_BOTTOM if not panel.children else PANEL_PAD_BOTTOM / 2
            for child in panel.children:
                cy += self.paint_panel(child, x + PANEL_GAP, cy, w - 2 * PANEL_GAP, sub=True) + PANEL_GAP
        return h

    def panel_height_sub(self, panel: RecordedPanel, w: float) -> float:
        return self.paint_panel(panel, 0, 0, w - 2 * PANEL_GAP, paint=False, sub=True)

    def _disclosure(self, cx, cy, is_open: bool, color) -> None:
        s = self.s
        if is_open:
            pts = [(cx - 3.5, cy - 1.8), (cx + 3.5, cy - 1.8), (cx, cy + 2.2)]
        else:
            pts = [(cx - 1.8, cy - 3.5), (cx - 1.8, cy + 3.5), (cx + 2.2, cy)]
        self.draw.polygon([(px * s, py * s) for px, py in pts], fill=color)

    # a region --------------------------------------------------------------------------------------------
    def stack_height(self, panels: list[RecordedPanel], w: float) -> float:
        return REGION_PAD + sum(self.paint_panel(p, 0, 0, w, paint=False) + PANEL_GAP for p in panels) + REGION_PAD

    def paint_region(self, panels: list[RecordedPanel], x, y, w, h, back, tabs: list[tuple[str, bool]] = ()) -> None:
        self.rrect(x, y, w, h, 0, back)
        pw = w - 2 * REGION_PAD - (TAB_WIDTH if tabs else 0)
        cy = y + REGION_PAD
        for p in panels:
            cy += self.paint_panel(p, x + REGION_PAD, cy, pw) + PANEL_GAP
        if tabs:
            self.paint_tabs(tabs, x + w - TAB_WIDTH, y, h)

    def paint_tabs(self, tabs: list[tuple[str, bool]], x, y, h) -> None:
        """The sidebar's category tabs on its right edge, text running top to bottom."""
        from PIL import Image, ImageDraw

        th = self.theme
        self.rrect(x, y, TAB_WIDTH, h, 0, th.tab_back)
        cy = y + REGION_PAD
        for name, active in tabs:
            tw = self.text_w(name) + 16
            fill = th.region_back if active else _rgba(th.wcol["regular"].inner)
            self.rrect(x, cy, TAB_WIDTH - 2, tw, 4, fill, corners=(False, True, True, False))
            img = Image.new("RGBA", (self.px(tw), self.px(TAB_WIDTH - 2)), (0, 0, 0, 0))
            ImageDraw.Draw(img).text((self.px(tw / 2), self.px((TAB_WIDTH - 2) / 2)), name, font=self.font,
                                     fill=th.panel_text if active else _rgba(th.wcol["regular"].text), anchor="mm")
            img = img.rotate(-90, expand=True)
            self.canvas.paste(img, (self.px(x), self.px(cy)), img)
            cy += tw + 2


def paint_feature(sidebar: list[RecordedPanel], material: list[RecordedPanel], out_png: str,
                  scale: float = 2.0, sidebar_width: float = 320, properties_width: float = 320) -> str:
    """Paint the sidebar stack (and, beside it, the Material Properties panels, when there are any) into
    ``out_png`` at ``scale`` x 1x UI sizes."""
    from PIL import Image, ImageDraw

    p = Painter(scale)
    th = p.theme
    tabs = [("Item", False), ("Tool", False), ("View", False), ("Material Structures", True)]
    side_h = p.stack_height(sidebar, sidebar_width - 2 * REGION_PAD - TAB_WIDTH)
    tabs_h = REGION_PAD + sum(p.text_w(n) + 18 for n, _ in tabs)
    title = UNIT + 4
    prop_h = p.stack_height(material, properties_width - 2 * REGION_PAD) if material else 0.0
    h = max(side_h, tabs_h, prop_h) + title
    gap = 2 if material else 0
    w = sidebar_width + (gap + properties_width if material else 0)
    canvas = Image.new("RGB", (p.px(w), p.px(h)), th.editor_border[:3])
    p.canvas = canvas
    p.draw = ImageDraw.Draw(canvas, "RGBA")  # blends: the theme's translucent colours over what is below
    p.rrect(0, 0, sidebar_width, title, 0, th.tab_back)
    p.text("3D Viewport \N{RIGHTWARDS ARROW} Sidebar (N)", 8, 0, title, th.panel_text, w=sidebar_width - 16)
    p.paint_region(sidebar, 0, title, sidebar_width, h - title, th.region_back, tabs)
    if material:
        x0 = sidebar_width + gap
        p.rrect(x0, 0, properties_width, title, 0, th.tab_back)
        p.text("Properties \N{RIGHTWARDS ARROW} Material", x0 + 8, 0, title, th.panel_text, w=properties_width - 16)
        p.paint_region(material, x0, title, properties_width, h - title, th.properties_back)
    out = canvas.resize((round(w * scale), round(h * scale)), Image.Resampling.LANCZOS)
    out = out.quantize(colors=128, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    os.makedirs(os.path.dirname(os.path.abspath(out_png)), exist_ok=True)
    out.save(out_png, optimize=True)
    return out_png


def render_docs(out_dir: str = "docs", features: tuple[str, ...] = FEATURES, scale: float = 2.0) -> list[str]:
    """Build each feature's scene, record its panels and write ``<out_dir>/ui-<feature>.png``. Call after
    ``prepare_user_resources()``."""
    module = enable_addon()
    paths = []
    for feature in features:
        context = build_scene(feature)
        sidebar, material = record_feature(module, feature, context)
        paths.append(paint_feature(sidebar, material, os.path.join(out_dir, f"ui-{feature}.png"), scale))
    return paths


if __name__ == "__main__":
    import time

    start = time.monotonic()
    for path in render_docs(sys.argv[1] if len(sys.argv) > 1 else "docs"):
        print(f"{path}: {os.path.getsize(path) / 1000:.0f} kB")
    print(f"in {time.monotonic() - start:.0f} s")
