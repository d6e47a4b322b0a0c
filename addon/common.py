"""What the features of the add-on share: the material skeleton, panel and operator bases, mesh and UV
checks, stroke points, float images.

A feature (``fabric/``, ``scratch/``, ``teeth/``) imports from here, never from another feature.
"""

from __future__ import annotations

import os

import bpy
import numpy as np
from bpy_extras.io_utils import ExportHelper, ImportHelper
from mathutils import Vector
from mathutils.bvhtree import BVHTree
from mathutils.geometry import barycentric_transform

from ..render import ensure_node_tree
from . import background_job

CATEGORY = "Material Structures"  # the 3D viewport sidebar tab


# -- panels -------------------------------------------------------------------------------------------
class Panel:
    """Base of every panel of the add-on (``SidebarPanel``, ``MaterialPanel``; mix in before
    ``bpy.types.Panel``): what all of them share."""

    bl_translation_context = "*"


class SidebarPanel(Panel):
    """Base of the panels in the 3D viewport's sidebar tab "Material Structures" (mix in before
    ``bpy.types.Panel``)."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY


class MaterialPanel(Panel):
    """Base of a Material Properties panel shown for the materials a feature made (``marker``: the ID
    property it sets on them)."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    marker = ""

    @classmethod
    def poll(cls, context):
        mat = getattr(context, "material", None)
        return mat is not None and bool(mat.get(cls.marker))


def shader_path(scene) -> tuple[str, str]:
    """Which of a material's paths the scene renders, in words: (what renders, how to get the exact shader or
    "" when it renders). Cycles runs the OSL scripts on the CPU (and on OptiX GPUs); its SVM (OSL off, CUDA,
    HIP, Metal, oneAPI) renders the closure path built from Cycles' own nodes; EEVEE the viewport look."""
    if scene.render.engine != "CYCLES":
        return ("EEVEE / Workbench: the viewport look (an approximation)",
                "The exact shader renders in Cycles with Open Shading Language")
    cyc = scene.cycles
    if not cyc.shading_system:
        return ("Closure path (Open Shading Language is off): no exact lamps, world light or scratches",
                "Turn on Open Shading Language (Render Properties) for the exact shader")
    if cyc.device == "GPU":
        if gpu_backend() == "OPTIX":
            return ("OptiX runs the shader without trace() or table textures: fabric lamps unshadowed, no exact "
                    "world light, no scratches", "Render on the CPU for the exact shader")
        return ("Closure path (OSL runs on the CPU and OptiX only, not on this GPU backend)",
                "Render on the CPU (or OptiX) for the exact shader")
    return "Exact shader (Cycles + Open Shading Language, CPU)", ""


def gpu_backend() -> str:
    """Cycles' compute device type in the preferences (OPTIX, CUDA, HIP, METAL, ONEAPI; NONE without one)."""
    addon = bpy.context.preferences.addons.get("cycles")
    return getattr(addon.preferences, "compute_device_type", "NONE") if addon is not None else "NONE"


def draw_shader_path(layout, scene) -> None:
    """The line every material panel shows: which path renders here, and a button to the exact one."""
    what, how = shader_path(scene)
    box = layout.box()
    box.label(text=what, icon="CHECKMARK" if not how else "INFO")
    if how:
        box.label(text=how)
        box.operator("material_structures.setup_cycles_osl", icon="SHADING_RENDERED")


def draw_group_inputs(layout, node, controls, linked: str = "linked") -> None:
    """One row per ``(socket name, label)`` of a group node: its value, or ``linked`` when a link drives it."""
    col = layout.column()
    for name, label in controls:
        sock = node.inputs[name]
        if sock.is_linked:
            col.label(text=f"{label}: {linked}")
        else:
            col.prop(sock, "default_value", text=label)


# -- materials ----------------------------------------------------------------------------------------
def group_material(name: str, group, marker: str, marker_value=1, label: str | None = None,
                   surface: str | None = "Shader", volume: str | None = None):
    """The skeleton of every material the add-on makes: one node of ``group`` (named and labelled
    ``label``) feeding a material output (its ``surface`` and ``volume`` outputs), the material marked
    ``mat[marker] = marker_value`` and its emission not sampled as a light (the shaders return the
    lamps' exact terms through ``emission()``). Returns ``(material, group node, output node)``."""
    mat = bpy.data.materials.new(name)
    tree = ensure_node_tree(mat)
    mat[marker] = marker_value
    mat.cycles.emission_sampling = "NONE"
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    gnode = tree.nodes.new("ShaderNodeGroup")
    gnode.node_tree = group
    gnode.name = gnode.label = label or group.name
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (400, 100)
    if surface is not None:
        tree.links.new(gnode.outputs[surface], out.inputs["Surface"])
    if volume is not None:
        tree.links.new(gnode.outputs[volume], out.inputs["Volume"])
    return mat, gnode, out


class NodeMath:
    """Math-node arithmetic inside a node tree: operands are sockets or numbers; each operation adds a node
    below the previous one, starting at ``(x, y)``."""

    def __init__(self, tree, x: float, y: float):
        self.tree, self.x, self.y = tree, x, y

    def _node(self, kind: str, op: str, *args):
        node = self.tree.nodes.new(kind)
        node.operation = op
        node.location = (self.x, self.y)
        self.y -= 40
        for i, a in enumerate(args):
            if isinstance(a, (int, float)):
                node.inputs[i].default_value = a if kind == "ShaderNodeMath" else (a, a, a)
            else:
                self.tree.links.new(a, node.inputs[i])
        return node

    def f(self, op: str, *args):
        return self._node("ShaderNodeMath", op, *args).outputs[0]

    def v(self, op: str, *args):
        node = self._node("ShaderNodeVectorMath", op, *args)
        return node.outputs["Value" if op in {"DOT_PRODUCT", "LENGTH"} else "Vector"]

    def scale(self, vec, factor):
        node = self._node("ShaderNodeVectorMath", "SCALE", vec)
        if isinstance(factor, (int, float)):
            node.inputs["Scale"].default_value = factor
        else:
            self.tree.links.new(factor, node.inputs["Scale"])
        return node.outputs["Vector"]


def add_eevee_fallback(mat, cycles_output, shader, location=(400, -350), name: str | None = None):
    """Make ``cycles_output`` Cycles-only (and keep it active) and give EEVEE / Material Preview an output
    of its own fed by ``shader`` (the OSL shaders are Cycles-only). Returns the EEVEE output node."""
    tree = mat.node_tree
    cycles_output.target = "CYCLES"
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.target = "EEVEE"
    if name:
        out.name = out.label = name
    tree.links.new(shader, out.inputs["Surface"])
    out.location = location
    cycles_output.is_active_output = True
    return out


def add_group_input(group, name: str, socket_type: str, default, lo=None, hi=None, description: str = ""):
    """A new input socket ``name`` of node group ``group`` with its default, unless ``lo`` is None its range
    [lo, hi], and its tooltip ``description`` (the ``(name, socket_type, default, lo, hi, description)`` specs
    of the features' groups; on/off inputs are ``NodeSocketBool`` with no range)."""
    sock = group.interface.new_socket(name, in_out="INPUT", socket_type=socket_type)
    sock.default_value = default
    if lo is not None:
        sock.min_value, sock.max_value = lo, hi
    if description:
        sock.description = description
    return sock


def describe_group_sockets(group, specs, outputs: dict[str, str] | None = None) -> None:
    """Give the sockets of ``group`` (from a file made before they had tooltips) the descriptions of its input
    ``specs`` and of ``outputs`` (name -> description) where they have none. An input's type stays as the
    file has it: an on/off input that was an integer 0/1 renders the same as a boolean, and changing its type
    would reset the value every material set."""
    words = {spec[0]: spec[5] for spec in specs if len(spec) > 5}
    words.update(outputs or {})
    for item in group.interface.items_tree:
        if item.item_type == "SOCKET" and not item.description and item.name in words:
            item.description = words[item.name]


def wire_lamp_shader_group(group, gin, script, gout, input_names, lamp_term: str):
    """Wire an OSL ``script`` node that returns a BSDF and a term it evaluates per lamp itself (fabric, scratch)
    inside ``group``: each of ``input_names`` from the group input ``gin`` to the script's input of that name,
    a UV-map tangent into its "Tangent", and its "BSDF" plus its ``lamp_term`` output summed into the group
    output ``gout``'s "Shader". Returns the (tangent, add shader) nodes it made, for placing."""
    nodes, links = group.nodes, group.links
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    add = nodes.new("ShaderNodeAddShader")
    for name in input_names:
        links.new(gin.outputs[name], script.inputs[name])
    links.new(tangent.outputs["Tangent"], script.inputs["Tangent"])
    links.new(script.outputs["BSDF"], add.inputs[0])
    links.new(script.outputs[lamp_term], add.inputs[1])
    links.new(add.outputs[0], gout.inputs["Shader"])
    return tangent, add


OSL_SWITCH = "Shader Path"  # the Mix Shader that picks the OSL script's shader or the closures without it
OSL_ACTIVE = "OSLActive"  # the scripts' float output: 1 wherever the script runs


def add_osl_switch(group, script, native_shader) -> None:
    """End ``group`` in a Mix Shader (``OSL_SWITCH``) between ``native_shader`` (Cycles' own closures) and
    what fed the group output's "Shader" so far (the OSL ``script``'s terms).

    Its factor is linked from the script's ``OSLActive`` output and defaults to 0. Cycles without Open
    Shading Language drops script nodes and every input linked from one takes its default value, so the
    factor is 1 where the script runs (Cycles with OSL) and 0 everywhere else (Cycles' SVM, its GPUs but
    OptiX): never the black of a script that did not run."""
    gout = next(n for n in group.nodes if n.type == "GROUP_OUTPUT")
    target = gout.inputs["Shader"]
    osl_side = target.links[0].from_socket if target.is_linked else None
    mix = group.nodes.new("ShaderNodeMixShader")
    mix.name = mix.label = OSL_SWITCH
    mix.location = (gout.location.x - 150, gout.location.y - 150)
    mix.inputs[0].default_value = 0.0
    if OSL_ACTIVE in script.outputs:
        group.links.new(script.outputs[OSL_ACTIVE], mix.inputs[0])
    group.links.new(native_shader, mix.inputs[1])
    if osl_side is not None:
        group.links.new(osl_side, mix.inputs[2])
    group.links.new(mix.outputs[0], target)


def osl_switch(group):
    """The group's ``OSL_SWITCH`` node (None in a group made before it)."""
    return group.nodes.get(OSL_SWITCH)


def relink_osl_switch(group, script) -> None:
    """Link a recompiled ``script``'s ``OSLActive`` output to the group's switch (a script node from an older
    file gets the output when its shader is refreshed)."""
    mix = osl_switch(group)
    if mix is not None and OSL_ACTIVE in script.outputs and not mix.inputs[0].is_linked:
        group.links.new(script.outputs[OSL_ACTIVE], mix.inputs[0])


def group_node(mat, marker: str):
    """The node of ``mat`` whose node group carries the ID property ``marker`` (None if it has none)."""
    if mat is None or mat.node_tree is None:
        return None
    return next((n for n in mat.node_tree.nodes if n.type == "GROUP" and n.node_tree is not None
                 and n.node_tree.get(marker)), None)


def local_node_group(name: str, marker: str):
    """This file's own node group ``name`` carrying the ID property ``marker`` (None if it has none). A group of the
    same name linked from a library file is not it: a new material built on that one would break when the other
    file moves, and changes to it are never saved."""
    return next((g for g in bpy.data.node_groups if g.name == name and g.library is None and g.get(marker)), None)


def target_collection(context):
    """Where new objects go, as Blender's Add menu puts them: the active collection, or the scene's own when the
    active one is linked from a library file (read-only here)."""
    coll = context.collection
    if coll is None or coll.library is not None:
        return context.scene.collection
    return coll


def linked_slot_reason(obj) -> str:
    """Why a material cannot be put into ``obj``'s active slot ("" when it can): the object, or the mesh that holds
    the slot, is linked from a library file and read-only here."""
    if obj.library is not None:
        return f"'{obj.name}' is linked from {obj.library.filepath}: make it local (Object > Relations > Make Local)"
    on_data = not obj.material_slots or obj.material_slots[obj.active_material_index].link == "DATA"
    if on_data and obj.data is not None and obj.data.library is not None:
        return (f"the mesh of '{obj.name}' is linked from {obj.data.library.filepath}: make it local "
                "(Object > Relations > Make Local > Selected Objects and Data)")
    return ""


def assign_material(obj, mat) -> None:
    """Put ``mat`` into the object's active material slot (a new slot when it has none)."""
    if obj.material_slots:
        obj.material_slots[obj.active_material_index].material = mat
    else:
        obj.data.materials.append(mat)


class AddGroupNode:
    """Base of the node editor operators that add one of the add-on's node groups to the edited material
    (mix in before ``bpy.types.Operator``). Subclasses give :meth:`group` and ``marker``."""

    bl_options = {"REGISTER", "UNDO"}
    marker = ""  # ID property set on the edited material: its panel shows
    marker_value = 1

    @classmethod
    def poll(cls, context):
        space = context.space_data
        return space is not None and space.type == "NODE_EDITOR" and space.edit_tree is not None

    def group(self, context):
        raise NotImplementedError

    def execute(self, context):
        tree = context.space_data.edit_tree
        group = self.group(context)
        for node in tree.nodes:
            node.select = False
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        node.label = self.bl_label
        node.select = True
        tree.nodes.active = node
        if context.space_data.id is not None and hasattr(context.space_data.id, "keys"):
            context.space_data.id[self.marker] = self.marker_value
        return {"FINISHED"}


# path properties of operators: "//" is beside the saved .blend, as in every Blender file field (the
# operators resolve it with bpy.path.abspath; Blender 4.5+ warns about "//" on a property without it)
BLEND_RELATIVE = {"PATH_SUPPORTS_BLEND_RELATIVE"}


class FilePicker(ImportHelper):
    """Base of the operators that read a file (``filepath``; subclasses may set ``filter_glob``): INVOKE opens
    Blender's file browser, EXEC does the work (scripts and tests call EXEC with the path)."""


class FolderPicker(ImportHelper):
    """Base of the operators that read or write a folder (``directory``): INVOKE opens Blender's file browser
    showing folders only, EXEC does the work."""

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH", options=BLEND_RELATIVE)
    filter_folder: bpy.props.BoolProperty(default=True, options={"HIDDEN"})


class FileSaver(ExportHelper):
    """Base of the operators that write a file (``filepath``, ``filename_ext``): INVOKE opens Blender's file
    browser with a file name, EXEC does the work."""


class SyncLamps:
    """Base of a feature's "Sync Lamps" operator: copy the scene's lamps into its shaders now (normally the
    handlers do). Subclasses give ``sync`` (scene -> number of lamps, a staticmethod) and ``evaluated_by``."""

    bl_options = {"REGISTER", "UNDO"}
    evaluated_by = ""

    def execute(self, context):
        n = self.sync(context.scene)
        self.report({"INFO"}, f"{n} light(s) evaluated {self.evaluated_by}")
        return {"FINISHED"}


class CancelBackgroundJob:
    """Base of a feature's "Cancel Fit" operator: cancel this session's running ``background_job`` of
    ``job_kind``; with none running, report ``nothing_running`` as a warning (nothing of a job is stored in the
    file: nothing can be stuck)."""

    job_kind = ""
    nothing_running = ""

    def execute(self, context):
        job = background_job.current_job(self.job_kind)
        if job is None or not background_job.job_running(self.job_kind):
            self.report({"WARNING"}, self.nothing_running)
            return {"CANCELLED"}
        job.cancel()
        return {"FINISHED"}


# -- undo ------------------------------------------------------------------------------------------------
REVISION_PROP = "material_structures_revision"  # on images the add-on writes: counts its packed writes
_WRITTEN: dict[int, int] = {}  # image session_uid -> the revision its pixels hold in this Blender session


def mark_written(image) -> None:
    """Record that ``image``'s pixels were written and packed: its revision (an ID property, so the .blend
    and Blender's undo keep it) goes up and this session remembers that its pixels hold that revision."""
    revision = int(image.get(REVISION_PROP, 0)) + 1
    image[REVISION_PROP] = revision
    _WRITTEN[image.session_uid] = revision


def reload_stale_images() -> list[str]:
    """After a global undo or redo: reload every image the add-on wrote in this session whose packed data
    (restored by the undo) holds another revision than its pixels (Blender keeps image buffers across undo),
    so what the viewport shows and renders is what is stored. Returns the names of the reloaded images."""
    reloaded = []
    for image in bpy.data.images:
        uid = image.session_uid
        if uid not in _WRITTEN or image.packed_file is None:
            continue
        revision = int(image.get(REVISION_PROP, 0))
        if _WRITTEN[uid] != revision:
            image.reload()
            _WRITTEN[uid] = revision
            reloaded.append(image.name)
    return reloaded


def push_undo(message: str) -> bool:
    """Make what was just done one step of Blender's undo (Ctrl+Z, Edit > Undo History), for work that is
    not an operator's own step (a stroke inside the modal brush). Whether a step was pushed: False where
    Blender has no undo stack (undo steps 0, or no window)."""
    if not bpy.ops.ed.undo_push.poll():
        return False
    return bpy.ops.ed.undo_push(message=message) == {"FINISHED"}


# -- float images ---------------------------------------------------------------------------------------
def array_to_image(array: np.ndarray, name: str, pack: bool = True, replace: bool = True):
    """A float, Non-Color, channel-packed image holding ``array`` (H, W, C<=4), row 0 = top.

    ``replace``: overwrite the image called ``name`` if there is one; else always a new image (Blender
    makes its name unique), so no other material's image changes."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim != 3 or not 1 <= a.shape[2] <= 4:
        raise ValueError(f"{name}: expected an (H, W, C<=4) map, got shape {a.shape}")
    h, w, c = a.shape
    rgba = np.zeros((h, w, 4), dtype=np.float32)
    rgba[..., 3] = 1.0
    rgba[..., :c] = a
    image = bpy.data.images.get(name) if replace else None
    if image is None or tuple(image.size) != (w, h) or not image.is_float:
        if image is not None:
            bpy.data.images.remove(image)
        image = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    image.alpha_mode = "CHANNEL_PACKED"
    image.pixels.foreach_set(rgba[::-1].ravel())
    image.update()
    if pack:
        image.pack()
        mark_written(image)
    return image


def image_to_array(image, channels: int) -> np.ndarray:
    """Inverse of :func:`array_to_image`: (H, W, channels) float32, row 0 = top."""
    w, h = image.size
    buf = np.empty(w * h * 4, dtype=np.float32)
    image.pixels.foreach_get(buf)
    return buf.reshape(h, w, 4)[::-1, :, :channels].copy()


# -- meshes, UVs and strokes ------------------------------------------------------------------------------
def require_uv_mesh(op, obj) -> bool:
    """Whether ``obj`` is a mesh with a UV map (the materials' maps and frames need one) whose active material slot
    can be set; else the operator ``op`` reports why not."""
    if obj is None or obj.type != "MESH":
        op.report({"ERROR"}, "Select a mesh object")
        return False
    if not obj.data.uv_layers:
        op.report({"ERROR"}, f"'{obj.name}' has no UV map: the material's maps and frame need one (UV > Unwrap)")
        return False
    reason = linked_slot_reason(obj)
    if reason:  # checked before anything is made: a material and its images would be left behind
        op.report({"ERROR"}, f"Cannot give it a material: {reason}")
        return False
    return True


class MeshUVLookup:
    """World-space BVH over an object's (evaluated) loop triangles with their UVs: from points on the mesh
    (ray hits, recorded 3D strokes) to UV coordinates."""

    def __init__(self, obj, depsgraph=None):
        if obj.type != "MESH":
            raise ValueError(f"'{obj.name}' is not a mesh")
        source = obj.evaluated_get(depsgraph) if depsgraph is not None else obj
        mesh = source.to_mesh()
        try:
            if not mesh.uv_layers:
                raise ValueError(f"'{obj.name}' has no UV map")
            uv_layer = mesh.uv_layers.active or mesh.uv_layers[0]
            mesh.calc_loop_triangles()
            mw = obj.matrix_world
            self.verts = [mw @ v.co for v in mesh.vertices]
            self.tris = [tuple(t.vertices) for t in mesh.loop_triangles]
            self.tri_uvs = [
                tuple(Vector((*uv_layer.data[li].uv, 0.0)) for li in t.loops) for t in mesh.loop_triangles
            ]
        finally:
            source.to_mesh_clear()
        if not self.tris:
            raise ValueError(f"'{obj.name}' has no faces")
        self.bvh = BVHTree.FromPolygons(self.verts, self.tris)

    def _uv(self, location, index):
        a, b, c = (self.verts[i] for i in self.tris[index])
        ua, ub, uc = self.tri_uvs[index]
        uv = barycentric_transform(location, a, b, c, ua, ub, uc)
        return (uv.x, uv.y)

    def ray_cast(self, origin, direction):
        """UV of the first hit along the ray, or None."""
        location, _normal, index, _dist = self.bvh.ray_cast(Vector(origin), Vector(direction))
        return None if index is None else self._uv(location, index)

    def under_mouse(self, context, event):
        """UV under the mouse cursor of a 3D viewport event, or None."""
        from bpy_extras import view3d_utils

        region, rv3d = context.region, context.region_data
        coord = (event.mouse_region_x, event.mouse_region_y)
        origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, coord)
        direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, coord)
        return self.ray_cast(origin, direction)

    def nearest(self, point, max_distance: float = 1e30):
        """UV of the closest surface point to ``point``, or None."""
        location, _normal, index, _dist = self.bvh.find_nearest(Vector(point), max_distance)
        return None if index is None else self._uv(location, index)

    def diagonal(self) -> float:
        """Length of the diagonal of the mesh's world-space bounding box."""
        lo = [min(v[i] for v in self.verts) for i in range(3)]
        hi = [max(v[i] for v in self.verts) for i in range(3)]
        return sum((b - a) ** 2 for a, b in zip(lo, hi, strict=True)) ** 0.5


class MS_StrokePoint(bpy.types.PropertyGroup):
    """One point of a recorded stroke: what the stroke tools' EXEC path replays (scripts, tests)."""

    location: bpy.props.FloatVectorProperty(name="Location", size=3, description="World-space point (3D strokes)")
    uv: bpy.props.FloatVectorProperty(name="UV", size=2, description="UV point (UV strokes)")
    pressure: bpy.props.FloatProperty(name="Pressure", default=1.0, min=0.0, max=1.0, subtype="FACTOR",
                                      description="Tablet pressure at the point (0-1; 1 without a tablet)")


def stroke_property():
    """The ``stroke`` property of a stroke tool: the points its EXEC path replays."""
    return bpy.props.CollectionProperty(type=MS_StrokePoint, options={"SKIP_SAVE"}, name="Stroke",
                                        description="The points of a recorded stroke (for scripts; empty when "
                                        "drawing with the mouse)")


def stroke_space_property():
    """The ``stroke_space`` property of a stroke tool: whether the points are UVs or 3D points."""
    return bpy.props.EnumProperty(
        name="Stroke Space",
        description="Whether the stroke's points are UV coordinates or 3D points on the surface",
        items=[("UV", "UV", "Stroke points are UV coordinates"), ("WORLD", "World", "3D points on the surface")],
        default="UV",
        options={"SKIP_SAVE"},
    )


def stroke_uvs(stroke, space: str, obj, depsgraph, tolerance: float | None = None) -> list:
    """``[(uv, pressure), ...]`` of a recorded stroke on ``obj``: UV points as they are, 3D points mapped to
    the nearest surface point's UV (``tolerance``: points farther from the surface than this fraction of the
    object's size are dropped). Raises ValueError for fewer than 2 points on the mesh."""
    if len(stroke) < 2:
        raise ValueError("a stroke needs at least 2 points")
    if space == "UV":
        return [((p.uv[0], p.uv[1]), p.pressure) for p in stroke]
    lookup = MeshUVLookup(obj, depsgraph)
    reach = 1e30 if tolerance is None else max(1e-6, tolerance * lookup.diagonal())
    out = [(uv, p.pressure) for p in stroke if (uv := lookup.nearest(p.location, reach)) is not None]
    if len(out) < 2:
        raise ValueError(f"the stroke does not touch the mesh of '{obj.name}'")
    return out


def end_modal_progress(context, timer) -> None:
    """The end of a modal operator that showed progress: its timer removed, the progress bar and the status
    bar text cleared."""
    wm = context.window_manager
    if timer is not None:
        wm.event_timer_remove(timer)
    wm.progress_end()
    if context.workspace is not None:
        context.workspace.status_text_set(None)


CLASSES: list[type] = [MS_StrokePoint]


# -- caches in the temporary folder -----------------------------------------------------------------------
CACHE_UNUSED_S = 14 * 24 * 3600  # cache folders no session has used for this long are removed


def user_cache_root(name: str) -> str:
    """``<tempdir>/<name>-<user>``: a cache of this user's (another user's folder of the name may not be
    writable here)."""
    import tempfile

    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return os.path.join(tempfile.gettempdir(), f"{name}-{user}")


def prune_cache(root: str, keep: str, now: float | None = None) -> None:
    """Remove the folders under ``root`` unused (not touched) for ``CACHE_UNUSED_S``: every HDRI ever lit with and
    every scratch set ever rendered leaves one. ``keep`` and anything that cannot be removed stay."""
    import shutil
    import time

    now = time.time() if now is None else now
    try:
        entries = list(os.scandir(root))
    except OSError:
        return
    for entry in entries:
        try:
            if entry.path != keep and entry.is_dir(follow_symlinks=False) and \
                    now - entry.stat(follow_symlinks=False).st_mtime > CACHE_UNUSED_S:
                shutil.rmtree(entry.path, ignore_errors=True)
        except OSError:
            continue
