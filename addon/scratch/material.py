"""The "Scratched Metal" node groups and materials (thesis ch. 4 in Cycles).

One node group per scratch set, ``Scratched Metal (<set>)``, and one set per material: a new
material gets a set name no other set uses (made unique like Blender names: ``Scratches.001``), and
updating a material's set writes only that set's own images (``tables.IMAGES_PROP``). A material
that shares its group with another one (a copy of a material) gets its own copy of the group on its
first update; objects share a set only by wearing the same material. Inside the group, an OSL script node
(``cycles_osl/ms_scratch_metal.osl``) gives the base metal closure weighted by (1 - rho_P) and the
scratch term through emission; a Texture Coordinate node feeds the UV map (its ray differentials
give the pixel footprint) and a Tangent node the scratch plane's x axis. The set's tables reach the
shader as an EXR cache folder (``tables.py``) and lamps through ``Lamp<k>*`` inputs that
:func:`sync_scratch_lamps` keeps current (depsgraph/render_pre handlers). Lamps stay linked to the
object: the base closure sees them (and the world) as usual; only the scratch term is computed here.

Lamp units (``addon/lamp_sync.py``): point/spot lamps of power P give intensity P/(4 pi); with a
radius r > 0 they are sphere lights of radiance P/(4 pi^2 r^2); sun lamps give irradiance S; area
lamps (one-sided) have radiance P/(pi A), disks/ellipses as equal-area 16-gons.
"""

from __future__ import annotations

import contextlib
import os

import bpy

from ...core.errors import UserError
from ...render import load_osl_script, osl_flip_t
from ..common import (
    add_eevee_fallback,
    add_group_input,
    add_osl_switch,
    describe_group_sockets,
    group_material,
    osl_switch,
    relink_osl_switch,
    wire_lamp_shader_group,
)
from ..common import group_node as _group_node
from ..lamp_sync import scene_shader_lamps, write_lamp_inputs
from .tables import (
    IMAGES_PROP,
    PROP,
    TABLES,
    extract_tables,
    group_images,
    image_name,
    load_group_set,
    store_scratch_set,
)
from .world import world_lamps_with_radii

SHADER = "ms_scratch_metal"
SCRIPT_NODE = "Scratch Shader"
MARKER = "material_structures_scratch"
GROUP_PREFIX = "Scratched Metal"
BASE_METAL_NODE = "Base Metal Without OSL"

# (socket name, socket type, default, min, max, tooltip); the OSL input of the same name takes it. On/off inputs
# are booleans (no range): Cycles hands them to the shader's int input as 0/1.
GROUP_INPUTS = [
    ("BaseColor", "NodeSocketColor", (0.91, 0.92, 0.92, 1.0), None, None,
     "Colour of the metal seen head-on (linear RGB reflectance, 0-1)"),
    ("EdgeTint", "NodeSocketColor", (1.0, 1.0, 1.0, 1.0), None, None,
     "Colour of the metal at grazing angles (linear RGB, 0-1; the F82 tint)"),
    ("Roughness", "NodeSocketFloat", 0.08, 0.0, 1.0,
     "Roughness of the metal between the scratches (0 = mirror, 1 = matte; GGX alpha = Roughness squared)"),
    ("Coherence", "NodeSocketFloat", 60.0, 1.0, 500.0,
     "Coherence length of the light, in micrometres (um): how far apart scratches still interfere"),
    ("Intensity", "NodeSocketFloat", 1.0, 0.0, 1000.0,
     "Scratch Intensity: multiplies the light the scratches scatter (1 = physical; no unit)"),
    ("Spectral", "NodeSocketBool", False, None, None,
     "Scratch colours from 16 wavelength bands instead of 3 (slower, smoother iridescence)"),
    ("Tiling", "NodeSocketFloat", 1.0, 1e-3, 1e4,
     "Scratch patches per UV unit: the patch repeats this many times across the UV map (no unit)"),
    ("FootprintScale", "NodeSocketFloat", 0.5, 1e-3, 10.0,
     "Size of the surface area one pixel averages over, as a fraction of the pixel's footprint (no unit)"),
    ("Debug", "NodeSocketInt", 0, 0, 4,
     "What to show, for checks: 0 the material, 1 the scratch colour alone, 2 the part of the light the "
     "scratches take from the metal, 3 and 4 the pixel footprint"),
]
SHADER_OUTPUT_DESCRIPTION = ("The scratched metal for Cycles (its scratches need Open Shading Language; the plain "
                             "metal without)")


def _load_script(tree, scene):
    need = [n for n, *_ in GROUP_INPUTS] + ["UV", "Tangent", "TableDir", "Lamp1Type", "Lamp1Radius"]
    return load_osl_script(tree, SHADER, scene, inputs=need, outputs=["Scratch"], name=SCRIPT_NODE)


def group_name(set_name: str) -> str:
    return f"{GROUP_PREFIX} ({set_name})"


MAX_SET_NAME = 39  # bytes: "MS Scratch <name>.NNN segments" stays within Blender 4.5's 63-byte ID names


def _set_name_taken(name: str, exclude=None) -> bool:
    if bpy.data.node_groups.get(group_name(name)) not in (None, exclude):
        return True
    if any(bpy.data.images.get(image_name(name, t)) is not None for t in TABLES):
        return True
    return any(str(g[PROP]["name"]) == name for g in scratch_groups() if g != exclude)


def unique_set_name(base: str, exclude=None) -> str:
    """``base``, or ``base.001``, ``base.002``, ... : the first name no scratch set, group or table image
    uses (``exclude``: a group whose own name does not count)."""
    base = (base or "Scratches").strip() or "Scratches"
    raw = base.encode()[:MAX_SET_NAME]
    base = raw.decode(errors="ignore")
    if not _set_name_taken(base, exclude):
        return base
    stem, dot, num = base.rpartition(".")
    if not (dot and num.isdigit() and stem):
        stem = base
    k = 1
    while _set_name_taken(f"{stem}.{k:03d}", exclude):
        k += 1
    return f"{stem}.{k:03d}"


def _build_group(name: str, scene) -> bpy.types.ShaderNodeTree:
    group = bpy.data.node_groups.new(group_name(name), "ShaderNodeTree")
    group[MARKER] = 1
    for spec in GROUP_INPUTS:
        add_group_input(group, *spec)
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader",
                               description=SHADER_OUTPUT_DESCRIPTION)
    nodes, links = group.nodes, group.links
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    script = _load_script(group, scene)
    texco = nodes.new("ShaderNodeTexCoord")
    tangent, add = wire_lamp_shader_group(group, gin, script, gout, [name for name, *_ in GROUP_INPUTS], "Scratch")
    links.new(texco.outputs["UV"], script.inputs["UV"])
    gin.location, script.location, texco.location = (-500, 0), (-150, 0), (-500, -300)
    tangent.location, add.location, gout.location = (-500, -500), (150, 0), (350, 0)
    add_osl_switch(group, script, _base_metal(group, gin, tangent))
    return group


def _base_metal(group, gin, tangent):
    """The base metal from Cycles' own Metallic BSDF (GGX, F82 tint from BaseColor and EdgeTint, alpha =
    Roughness^2, like the script's ``microfacet_f82_tint``): what renders where OSL does not run (Cycles'
    SVM, GPUs but OptiX), the scratches left out. Returns its shader output."""
    note = group.nodes.new("NodeFrame")  # read where the extension is missing (node editor): why no scratches
    note.name = "Needs Material Structures"
    note.label = "Scratches render with the Material Structures extension (it extracts their tables)"
    note.location = (-150, 250)
    metal = group.nodes.new("ShaderNodeBsdfMetallic")
    metal.name = metal.label = BASE_METAL_NODE
    metal.distribution = "GGX"
    metal.fresnel_type = "F82"
    metal.location = (-150, -450)
    for name, socket in (("BaseColor", "Base Color"), ("EdgeTint", "Edge Tint"), ("Roughness", "Roughness")):
        group.links.new(gin.outputs[name], metal.inputs[socket])
    group.links.new(tangent.outputs["Tangent"], metal.inputs["Tangent"])
    return metal.outputs[0]


def ensure_base_metal(group) -> None:
    """Give a scratch group from an older file the base metal that renders without OSL, and link its switch
    once the script has the ``OSLActive`` output; its sockets get their tooltips."""
    describe_group_sockets(group, GROUP_INPUTS, {"Shader": SHADER_OUTPUT_DESCRIPTION})
    script = script_node(group)
    if script is None:
        return
    if osl_switch(group) is None:
        gin = next(n for n in group.nodes if n.type == "GROUP_INPUT")
        tangent = next((n for n in group.nodes if n.type == "TANGENT"), None)
        if tangent is None:
            tangent = group.nodes.new("ShaderNodeTangent")
            tangent.direction_type = "UV_MAP"
        add_osl_switch(group, script, _base_metal(group, gin, tangent))
    else:
        relink_osl_switch(group, script)


def _store(group, scratch_set, name: str, images: dict | None, folder: str | None = None) -> None:
    """Store ``scratch_set`` in ``group`` (its tables in ``folder`` where the caller extracted them)."""
    folder = folder or extract_tables(scratch_set)  # first: a cache that cannot be written changes nothing
    meta, own = store_scratch_set(scratch_set, name, images)
    group[PROP] = meta
    group[IMAGES_PROP] = own
    group.interface.items_tree["Coherence"].default_value = meta["sigma_um"]
    sync_group_tables(group, scratch_set, folder)


def new_scratch_group(scratch_set, set_name: str, scene=None) -> bpy.types.ShaderNodeTree:
    """A new node group holding ``scratch_set`` under a set name no other set uses (``set_name`` made
    unique), with its own packed table images."""
    scene = scene or bpy.context.scene
    folder = extract_tables(scratch_set)  # first: a cache that cannot be written leaves no group behind
    name = unique_set_name(set_name)
    group = _build_group(name, scene)
    _store(group, scratch_set, name, None, folder)
    return group


def _sharing(group) -> tuple[bool, bool]:
    """(set name shared, table images shared) with another scratch group."""
    mine = {img.as_pointer() for img in group_images(group).values() if img is not None}
    name = str(group[PROP]["name"])
    same_name = same_images = False
    for other in scratch_groups():
        if other == group:
            continue
        same_name |= str(other[PROP]["name"]) == name
        same_images |= any(img is not None and img.as_pointer() in mine for img in group_images(other).values())
    return same_name, same_images


def update_scratch_group(group, scratch_set, scene=None) -> bpy.types.ShaderNodeTree:
    """Write ``scratch_set`` into ``group``'s own set (its own images, rewritten in place). A group that
    shares its set name with another group (an appended material, a copied group) first gets a name of
    its own (its images renamed with it); one that shares images gets new images: no other group changes."""
    scene = scene or bpy.context.scene
    _require_script_node(group)  # before anything changes: a refused edit leaves the set as it was
    name = str(group[PROP]["name"])
    images = group_images(group)
    same_name, same_images = _sharing(group)
    if same_images:
        images = None
    if same_name or same_images:
        name = unique_set_name(name, exclude=group)
        for table, img in (images or {}).items():
            if img is not None and img.library is None:
                img.name = image_name(name, table)
    if group.name != group_name(name) and bpy.data.node_groups.get(group_name(name)) is None:
        group.name = group_name(name)
    _store(group, scratch_set, name, images)
    return group


def material_scratch_group(mat) -> bpy.types.ShaderNodeTree | None:
    """The node group of ``mat``'s scratch set, made ``mat``'s own first: when other materials use the
    same group (Blender's material copies share node groups), or the group is linked from another file (a
    material made local keeps it linked: read-only data, an edit would be lost on save), ``mat`` gets a copy
    of it (its images become its own on the next :func:`update_scratch_group`)."""
    node = group_node(mat)
    if node is None:
        return None
    group = node.node_tree
    if group is not None and group.library is not None and mat.library is None:
        copy = group.copy()
        node.node_tree = copy
        return copy
    for other in bpy.data.materials:
        if other == mat:
            continue
        o = group_node(other)
        if o is not None and o.node_tree == group:
            copy = group.copy()
            node.node_tree = copy
            return copy
    return group


def _require_script_node(group):
    """The group's script node, or a UserError that says the artist deleted it and what to do."""
    node = script_node(group)
    if node is None:
        raise UserError(f"the node group '{group.name}' has lost its scratch script node; add a new scratched "
                        "material (Generate on an object without one) or undo the node's deletion")
    return node


def script_node(group):
    """The group's scratch script node; None when the artist deleted it (that group alone renders no scratches)."""
    return next((n for n in group.nodes if n.type == "SCRIPT" and "TableDir" in n.inputs), None)


def sync_group_tables(group, scratch_set=None, folder: str | None = None) -> str:
    """Extract the group's set to the EXR cache if needed (``folder``: where the caller extracted it) and point the
    shader at it."""
    meta = group[PROP]
    if folder is None:
        folder = extract_tables(scratch_set if scratch_set is not None else load_group_set(group))
    node = _require_script_node(group)
    vals = {
        "TableDir": folder,
        "HasTables": 1,
        "GridNX": int(meta["grid_nx"]),
        "GridNY": int(meta["grid_ny"]),
        "SegRows": max(1, -(-int(meta["n_segments"]) // 1024)),
        "CellRows": max(1, -(-int(meta["n_cells_entries"]) // 1024)),
        "PatchX": float(meta["patch_size_um"][0]),
        "PatchY": float(meta["patch_size_um"][1]),
        "CellSize": float(meta["cell_size_um"]),
        "QueryRadius": float(meta["query_radius_um"]),
        "FlipT": osl_flip_t(),
        "GridAlpha": 0 if bpy.app.version[0] < 5 else 1,
    }
    for key, v in vals.items():
        if node.inputs[key].default_value != v:
            node.inputs[key].default_value = v
    return folder


def scratch_groups():
    return [g for g in bpy.data.node_groups if g.get(MARKER) and g.get(PROP) is not None]


def ensure_tables_extracted() -> int:
    """Re-extract every scratch set whose cache folder is missing (after loading a file, before a render); count.
    A folder that is there is marked as in use (kept by the cache's pruning, ``tables.extract_tables``)."""
    n = 0
    for g in scratch_groups():
        node = script_node(g)
        if node is None:
            continue
        folder = node.inputs["TableDir"].default_value
        if os.path.isfile(os.path.join(folder, "cell_params.exr")):
            with contextlib.suppress(OSError):  # another user's folder of an older version
                os.utime(folder)
        else:
            try:
                sync_group_tables(g)
            except ValueError as exc:  # a set whose images are gone: say so, extract the others
                print(f"Material Structures: {g.name}: {exc}")
                continue
            n += 1
    return n


def adopt_named_images() -> int:
    """Files from before: give each scratch group pointers to the images it found by its set's name, so
    that renaming or appending keeps them together. Returns how many groups were converted."""
    n = 0
    for g in scratch_groups():
        if g.get(IMAGES_PROP) is not None or g.library is not None:
            continue
        images = group_images(g)
        if all(img is not None for img in images.values()):
            g[IMAGES_PROP] = images
            n += 1
    return n


def create_scratched_metal(
    name: str,
    scratch_set,
    set_name: str | None = None,
    base_color=(0.91, 0.92, 0.92),
    roughness: float = 0.08,
    intensity: float = 1.0,
    spectral: bool = False,
    tiling: float = 1.0,
    scene=None,
) -> bpy.types.Material:
    """A new material with its own scratch set (``set_name`` or ``name``, made unique; see
    :func:`new_scratch_group`), with an EEVEE/viewport fallback (Principled metal)."""
    scene = scene or bpy.context.scene
    group = new_scratch_group(scratch_set, set_name or name, scene)
    mat, gnode, out_cycles = group_material(name, group, MARKER, label=GROUP_PREFIX)
    gnode.inputs["BaseColor"].default_value = (*base_color[:3], 1.0)
    gnode.inputs["Roughness"].default_value = roughness
    gnode.inputs["Intensity"].default_value = intensity
    gnode.inputs["Spectral"].default_value = 1 if spectral else 0
    gnode.inputs["Tiling"].default_value = tiling
    gnode.inputs["Coherence"].default_value = float(scratch_set.sigma_um)
    # EEVEE / viewport: a Principled metal of the same colour
    bsdf = mat.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*base_color[:3], 1.0)
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = max(roughness, 0.15)
    bsdf.location = (0, -400)
    add_eevee_fallback(mat, out_cycles, bsdf.outputs[0], location=(400, -400))
    sync_scratch_lamps(scene)
    return mat


def group_node(mat):
    """The scratched-metal group node of a material (None if it has none)."""
    return _group_node(mat, MARKER)


def scratch_script_nodes():
    for g in scratch_groups():
        node = script_node(g)
        if node is not None:
            yield node


def scene_scratch_lamps(scene):
    """ShaderLamps of the scene plus each point/spot lamp's radius (sphere lights)."""
    out = []
    for obj, lamp in scene_shader_lamps(scene):
        radius = float(getattr(obj.data, "shadow_soft_size", 0.0)) if obj.data.type in {"POINT", "SPOT"} else 0.0
        out.append((obj, lamp, radius))
    return out


def sync_scratch_lamps(scene, update_matrices: bool = True) -> int:
    """Copy the scene's lamps (and the world approximation) into every scratched-metal shader."""
    nodes = list(scratch_script_nodes())
    if not nodes:
        return 0
    if update_matrices:
        for layer in scene.view_layers:
            layer.update()
    triples = scene_scratch_lamps(scene)
    lamps = [lamp for _, lamp, _ in triples]
    radii = [r for _, _, r in triples]
    for extra, r in world_lamps_with_radii(scene, max(0, 4 - len(lamps))):
        lamps.append(extra)
        radii.append(r)
    for node in nodes:
        write_lamp_inputs(node, lamps)
        for k in range(1, 5):
            r = radii[k - 1] if k <= len(radii) else 0.0
            if node.inputs[f"Lamp{k}Radius"].default_value != r:
                node.inputs[f"Lamp{k}Radius"].default_value = r
    return len(lamps)
