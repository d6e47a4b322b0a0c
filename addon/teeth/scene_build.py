"""Core ``TeethScene`` / capture rig <-> Blender objects, and applying fit results.

Units: core millimetres; ``mm_per_unit`` = 1000 for a scene in metres, 1 when a Blender unit is a mm.
Point lights: core radiant intensity I gives irradiance I / r^2; a Blender point lamp of power P gives
P / (4 pi d^2) (measured, platform notes), so P = 4 pi I / mm_per_unit^2 (d in Blender units).
Cameras: OpenCV pinhole (K, R, t) -> perspective camera with sensor width 36, focal length
fx 36 / W, principal point as lens shift; the box pixel filter of the core -> Cycles 'BOX' filter, width 1.
"""

from __future__ import annotations

import math
import re

import bpy
import numpy as np
from mathutils import Matrix

from ...core.errors import UserError
from ...render import add_lamp, configure_cycles
from .blend_volume import ensure_blend
from .geometry import build_tooth_pair, make_mesh
from .materials import new_cavity_material, new_teeth_material, set_a_t, set_volume


def build_teeth_scene(ts, collection=None, mm_per_unit: float = 1000.0, prefix: str = "", smooth: bool = False):
    """Create the teeth (enamel + dentin pairs), gums and oral-cavity proxy of a core ``TeethScene``.

    Returns ``{"teeth": [(enamel, dentin), ...], "gums": obj | None, "cavity": obj | None}``.
    """
    collection = collection or bpy.context.scene.collection
    out = {"teeth": [], "gums": None, "cavity": None}
    s = 1.0 / mm_per_unit
    for t in ts.teeth:
        name = f"{prefix}{t.name}"
        em = new_teeth_material("Enamel", f"Enamel {name}", volume=t.enamel, a_t=t.a_t, mm_per_unit=mm_per_unit)
        em.node_tree.nodes["Enamel"].inputs["Eta"].default_value = float(t.eta)
        dm = new_teeth_material("Dentin", f"Dentin {name}", volume=t.dentin, mm_per_unit=mm_per_unit)
        pair = build_tooth_pair(name, t.enamel_mesh, t.dentin_shape, t.c, em, dm, collection, mm_per_unit,
                                kind=t.kind, tooth_name=t.name, smooth=smooth, spread=ts.blend_spread)
        out["teeth"].append(pair)
    if ts.gums is not None:
        g = ts.gums
        mat = new_teeth_material("Gingiva", f"{prefix}Gingiva", volume=g.material, a_t=g.a_t, mm_per_unit=mm_per_unit)
        mat.node_tree.nodes["Gingiva"].inputs["Eta"].default_value = float(g.eta)
        me = make_mesh(f"{prefix}Gums", g.mesh.vertices, g.mesh.faces, g.mesh.corner_uv,
                       np.zeros(len(g.mesh.faces)))
        me.materials.append(mat)
        obj = bpy.data.objects.new(f"{prefix}Gums", me)
        obj.scale = (s, s, s)
        obj.ms_tooth.role = "GUMS"
        collection.objects.link(obj)
        out["gums"] = obj
    if ts.cavity is not None:
        c = ts.cavity
        me = make_mesh(f"{prefix}Oral Cavity", c.mesh.vertices, c.mesh.faces, c.mesh.corner_uv)
        me.materials.append(new_cavity_material(c.albedo, f"{prefix}Oral Cavity"))
        obj = bpy.data.objects.new(f"{prefix}Oral Cavity", me)
        obj.scale = (s, s, s)
        obj.ms_tooth.role = "CAVITY"
        collection.objects.link(obj)
        out["cavity"] = obj
    return out


def add_camera(scene, cam, mm_per_unit: float = 1000.0, name: str = "Teeth Camera"):
    """A Blender camera matching a core ``Camera`` (OpenCV pinhole); sets the render resolution."""
    data = bpy.data.cameras.new(name)
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    w, h = cam.width, cam.height
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    if abs(fx - fy) > 1e-6 * fx:
        raise ValueError("only square pixels (fx == fy) are supported")
    data.lens = fx * 36.0 / w
    data.shift_x = -(cx - 0.5 * w) / w
    data.shift_y = (cy - 0.5 * h) / w
    data.clip_start = 1.0 / mm_per_unit
    data.clip_end = 1e5 / mm_per_unit
    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    rot = cam.R.T @ np.diag([1.0, -1.0, -1.0])  # camera-to-world, Blender camera looks down -z, y up
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = cam.center / mm_per_unit
    obj.matrix_world = Matrix(m.tolist())
    scene.camera = obj
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    return obj


def add_point_light(scene, light, mm_per_unit: float = 1000.0, name: str = "Teeth Light"):
    """A point lamp matching a core ``PointLight`` (RGB intensity -> colour x power, radius 0)."""
    inten = np.asarray(light.intensity, dtype=np.float64)
    peak = float(inten.max())
    obj = add_lamp(scene, "POINT", tuple(float(x) for x in np.asarray(light.position) / mm_per_unit),
                   4.0 * math.pi * peak / mm_per_unit**2, name, color=tuple(float(x) for x in inten / max(peak, 1e-30)))
    if hasattr(obj.data, "use_soft_falloff"):
        obj.data.use_soft_falloff = False
    return obj


def tooth_objects(scene=None) -> dict:
    """``{tooth_name: enamel object}`` for every enamel shell in the scene."""
    scene = scene or bpy.context.scene
    return {o.ms_tooth.tooth_name: o for o in scene.objects if o.ms_tooth.role == "ENAMEL"}


# Capture tooth -> tooth of the scene. A fit's teeth carry the capture's names (scene.json), which a tooth made
# with Add Tooth ("Incisor") or renamed does not share: the fit settings keep an explicit mapping
# (``Scene.ms_teeth_fit.tooth_map``), read from the capture and pre-filled where the names match.

def _capture_teeth(capture_dir: str) -> list[dict]:
    """The ``teeth`` entries of a capture folder's ``scene.json``, each with a name; a file that is not a teeth
    scene is refused in one line naming it and what is wrong (``UserError``)."""
    import json
    import os

    from ...core.errors import UserError

    path = os.path.join(capture_dir, "scene.json")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no scene.json in {capture_dir!r}")
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except ValueError as exc:  # not JSON, cut short, or not text
        raise UserError(f"{path}: not a JSON file ({exc})") from None
    teeth = d.get("teeth") if isinstance(d, dict) else None
    if not isinstance(teeth, list):
        raise UserError(f"{path}: not a teeth scene (no 'teeth' list)")
    for k, t in enumerate(teeth):
        if not isinstance(t, dict) or "name" not in t:
            raise UserError(f"{path}: tooth {k} has no 'name'")
    return teeth


def capture_tooth_names(capture_dir: str) -> list[str]:
    """The tooth names of a capture folder's ``scene.json`` (in its order)."""
    return [str(t["name"]) for t in _capture_teeth(capture_dir)]


def capture_tooth_centres(capture_dir: str) -> tuple[list[str], np.ndarray]:
    """(names, ``(n, 3)`` centres in mm) of a capture folder's teeth: each tooth's enamel vertex mean in its
    ``scene.json``."""
    teeth = _capture_teeth(capture_dir)
    names, centres = [], []
    for t in teeth:
        v = np.asarray(t["enamel_mesh"]["vertices"], dtype=np.float64).reshape(-1, 3)
        if len(v) == 0 or not np.all(np.isfinite(v)):
            raise ValueError(f"tooth {t['name']!r} has no (finite) enamel vertices")
        names.append(str(t["name"]))
        centres.append(v.mean(axis=0))
    return names, np.array(centres).reshape(-1, 3)


def scene_tooth_centre(obj, mm_per_unit: float) -> np.ndarray:
    """The world-space centre (mm) of the enamel object ``obj``: its vertex mean through its world matrix."""
    mw = np.array(obj.matrix_world, dtype=np.float64)
    n = len(obj.data.vertices)
    if n == 0:
        return mw[:3, 3] * mm_per_unit
    co = np.empty(3 * n, dtype=np.float64)
    obj.data.vertices.foreach_get("co", co)
    return (co.reshape(-1, 3).mean(axis=0) @ mw[:3, :3].T + mw[:3, 3]) * mm_per_unit


def map_teeth_by_position(scene, capture_dir: str, mm_per_unit: float) -> int:
    """Fill ``scene.ms_teeth_fit.tooth_map`` with every capture tooth mapped to the tooth of ``scene`` at its place
    (``core.teeth.tooth_matching.match_by_position``: both sets' centres of mass moved together, the least total
    distance). Replaces what the mapping held. Returns how many capture teeth are mapped."""
    from ...core.teeth.tooth_matching import match_by_position

    names, centres = capture_tooth_centres(capture_dir)
    # every enamel shell, also teeth that share a tooth name (Shift+D copies keep it)
    teeth = sorted((o for o in scene.objects if o.ms_tooth.role == "ENAMEL"), key=lambda o: o.name)
    pairing = match_by_position(centres, np.array([scene_tooth_centre(o, mm_per_unit) for o in teeth]).reshape(-1, 3))
    tm = scene.ms_teeth_fit.tooth_map
    tm.clear()
    for name, j in zip(names, pairing, strict=True):
        m = tm.add()
        m.capture_tooth = name
        m.enamel = None if j is None else teeth[j]
    return sum(j is not None for j in pairing)


def is_scene_tooth(obj, scene) -> bool:
    """``obj`` is an enamel shell (a tooth's settings owner) linked into ``scene``."""
    return (obj is not None and getattr(obj, "ms_tooth", None) is not None and obj.ms_tooth.role == "ENAMEL"
            and scene.objects.get(obj.name) == obj)


def fill_tooth_map(scene, names: list[str]) -> int:
    """Make ``scene.ms_teeth_fit.tooth_map`` list the capture teeth ``names``: a tooth the user chose stays
    (while it is a tooth of the scene), else the tooth of the same name is pre-filled. Returns how many
    capture teeth are mapped."""
    tm = scene.ms_teeth_fit.tooth_map
    chosen = {m.capture_tooth: m.enamel for m in tm if is_scene_tooth(m.enamel, scene)}
    by_name = tooth_objects(scene)
    tm.clear()
    for name in names:
        m = tm.add()
        m.capture_tooth = name
        m.enamel = chosen[name] if chosen.get(name) is not None else by_name.get(name)
    return sum(m.enamel is not None for m in tm)


def fit_targets(names: list[str], scene=None) -> dict:
    """``{capture tooth name: enamel object}`` a fit of the teeth ``names`` applies to: the mapping of the
    scene's fit settings; a name not in the mapping goes to the tooth of that name (scripts, imported
    scenes). A capture tooth mapped to nothing (or to an object no longer a tooth of the scene) gets nothing."""
    scene = scene or bpy.context.scene
    mapped = {m.capture_tooth: m.enamel for m in scene.ms_teeth_fit.tooth_map}
    by_name = tooth_objects(scene)
    out = {}
    for name in names:
        obj = mapped[name] if name in mapped else by_name.get(name)
        if is_scene_tooth(obj, scene) and all(obj != o for o in out.values()):
            out[name] = obj
    return out


def no_mapping_message(names: list[str]) -> str:
    return (f"No capture tooth is mapped to a tooth of this scene (capture teeth: {', '.join(names) or 'none'}): "
            "choose them under Fit to capture in the Teeth panel")


def _copy_name(name: str, obj) -> str:
    """The name of a tooth's own copy of ``name``: "Enamel X (Y).001" -> "Enamel X (obj)"."""
    return f"{re.sub(r' [(][^()]*[)]$', '', re.sub(r'[.][0-9]{3}$', '', name))} ({obj.name})"


def own_material(obj, copies: list | None = None):
    """``obj``'s active material, made its own first where a fit written into it would reach other objects: one
    that another object wears too (a tooth copied with Shift+D keeps its original's materials) or one linked from a
    library file becomes a copy in ``obj``'s slot (its name appended to ``copies``). Where the slot is the mesh's and
    the mesh is shared (Alt+D) or linked, the copy goes into the object's own slot (link Object), so the other
    object keeps its material. None without a material."""
    mat = obj.active_material
    if mat is None:
        return None
    shared = any(o is not obj and any(slot.material == mat for slot in o.material_slots) for o in bpy.data.objects)
    if mat.library is None and not shared:
        return mat
    own = mat.copy()
    own.name = _copy_name(mat.name, obj)
    slot = obj.material_slots[obj.active_material_index]
    if slot.link == "DATA" and (obj.data.users > 1 or obj.data.library is not None):
        slot.link = "OBJECT"
    slot.material = own
    if copies is not None:
        copies.append(own.name)
    return own


def linked_tooth_reason(enamel) -> str | None:
    """Why the tooth of ``enamel`` cannot take new values here, or None: its enamel or dentin object is linked from a
    library file (read-only in this one) or a library override (its tooth settings are not kept at a save), or the
    dentin's mesh, which holds the shape keys, is linked."""
    make_local = "make it local (Object > Relations > Make Local > Selected Objects and Data)"
    for obj in (enamel, enamel.ms_tooth.partner if enamel is not None else None):
        if obj is None:
            continue
        if obj.library is not None:
            return f"'{obj.name}' is linked from {obj.library.filepath}; {make_local}"
        if obj.override_library is not None:
            return f"'{obj.name}' is a library override, whose tooth settings a save does not keep; {make_local}"
        mesh = obj.data if obj is not enamel else None
        if mesh is not None and mesh.library is not None:
            return f"the dentin mesh '{mesh.name}' of '{obj.name}' is linked from {mesh.library.filepath}; {make_local}"
    return None


def _check_fit_targets(ts, objs: dict) -> None:
    """Refuse, before anything changes, a fit mapped onto a tooth linked from a library file (read-only here)."""
    for t in ts.teeth:
        enamel = objs.get(t.name)
        reason = linked_tooth_reason(enamel) if enamel is not None else None
        if reason is not None:
            raise UserError(f"cannot apply the fit of {t.name}: {reason}")


def own_dentin_mesh(dentin, copies: list | None = None) -> None:
    """Give ``dentin`` a mesh (with its shape keys) of its own where another object shares it (an Alt+D copy of a
    tooth): a tooth's fitted dentin shape is its own, not also its copy's. The copy's name is appended to
    ``copies``."""
    if dentin is None or dentin.data is None or dentin.data.users - dentin.data.use_fake_user <= 1:
        return
    dentin.data = dentin.data.copy()
    dentin.data.name = _copy_name(dentin.data.name, dentin)
    if copies is not None:
        copies.append(dentin.data.name)


def apply_fit(ts, scene=None, source: str = "", set_current: bool = True, targets: dict | None = None,
              copies: list | None = None) -> list[str]:
    """Write a fitted core ``TeethScene`` into the teeth it maps to (``targets``, default ``fit_targets``: the
    panel's capture-tooth mapping, else by tooth name): materials, a_t, the fitted dentin coefficients (and,
    with ``set_current``, the shape-key values), gums and cavity. A tooth whose material another object wears too
    gets its own copy first (``own_material``; its names appended to ``copies``): each fitted tooth keeps its
    own values. Returns the capture tooth names applied; when none maps to a tooth, nothing is changed and the list
    is empty."""
    scene = scene or bpy.context.scene
    objs = fit_targets([t.name for t in ts.teeth], scene) if targets is None else targets
    if not objs:
        return []
    _check_fit_targets(ts, objs)
    done = []
    for t in ts.teeth:
        enamel = objs.get(t.name)
        if enamel is None:
            continue
        st = enamel.ms_tooth
        em = own_material(enamel, copies)
        if em is not None:
            set_volume(em, t.enamel)
            set_a_t(em, t.a_t)
        dentin = st.partner
        dm = own_material(dentin, copies) if dentin is not None else None
        if dm is not None:
            set_volume(dm, t.dentin)
        for o in (enamel, dentin):
            if o is not None:
                o.ms_tooth.fitted = tuple(float(x) for x in t.c)
                o.ms_tooth.has_fit = True
                o.ms_tooth.fit_source = source
        if set_current:
            own_dentin_mesh(dentin, copies)
            st.set_coefficients(t.c)
        ensure_blend(enamel, ts.blend_spread)  # the fit's enamel/dentin blend (made for a tooth without one)
        done.append(t.name)
    if ts.gums is not None:
        gums = next((o for o in scene.objects if o.ms_tooth.role == "GUMS"), None)
        if gums is not None and gums.active_material is not None:
            set_volume(gums.active_material, ts.gums.material)
            set_a_t(gums.active_material, ts.gums.a_t)
    if ts.cavity is not None:
        cav = next((o for o in scene.objects if o.ms_tooth.role == "CAVITY"), None)
        if cav is not None and cav.active_material is not None:
            node = next((n for n in cav.active_material.node_tree.nodes if n.type == "BSDF_DIFFUSE"), None)
            if node is not None:
                node.inputs["Color"].default_value = (*(float(x) for x in ts.cavity.albedo), 1.0)
    return done


# Cycles' light-path limits under which teeth render as the core's all-bounce model: light scatters in enamel and
# dentin hundreds of times (albedos near 1) and crosses their boundaries as transmission (the enamel surface) and
# transparent (the dentin's) bounces. Blender's factory limits (Total 12, Volume 0, Transparent 8) render a tooth
# 54-65 % too dark (docs/teeth-showcase.md, "Light paths").
TEETH_LIGHT_PATHS = (("max_bounces", "Total"), ("volume_bounces", "Volume"), ("transmission_bounces", "Transmission"),
                     ("transparent_max_bounces", "Transparent"))
TEETH_MIN_BOUNCES = 256


def short_light_paths(scene) -> list[tuple[str, str, int]]:
    """The scene's Cycles light-path limits that cut the teeth's scattering short: (property, its name in Blender's
    Light Paths panel, value) for each below :data:`TEETH_MIN_BOUNCES`."""
    cyc = getattr(scene, "cycles", None)
    if cyc is None:  # Cycles not enabled: nothing to set
        return []
    return [(prop, label, int(getattr(cyc, prop))) for prop, label in TEETH_LIGHT_PATHS
            if getattr(cyc, prop) < TEETH_MIN_BOUNCES]


def raise_light_paths(scene) -> str:
    """Raise (never lower) the light-path limits :func:`short_light_paths` names to :data:`TEETH_MIN_BOUNCES`;
    returns what changed in words ("" when nothing did). Other limits (diffuse, glossy) stay the artist's."""
    short = short_light_paths(scene)
    for prop, _, _ in short:
        setattr(scene.cycles, prop, TEETH_MIN_BOUNCES)
    return ", ".join(f"{label} {old} -> {TEETH_MIN_BOUNCES}" for _, label, old in short)


def configure_teeth_cycles(scene, samples: int, seed: int = 0, bounces: int = 256) -> None:
    """Cycles settings under which the Cycles render and the core path tracer estimate the same integral:
    CPU + OSL, box pixel filter of width 1 (the core's), no clamping, no light culling, no caustic
    filtering, bounce limits high enough that truncation is negligible, denoising off."""
    configure_cycles(scene, (scene.render.resolution_x, scene.render.resolution_y), samples, seed)
    cyc = scene.cycles
    cyc.pixel_filter_type = "BOX"
    cyc.filter_width = 1.0
    cyc.max_bounces = bounces
    cyc.diffuse_bounces = bounces
    cyc.glossy_bounces = bounces
    cyc.transmission_bounces = bounces
    cyc.volume_bounces = bounces
    cyc.transparent_max_bounces = bounces
    cyc.sample_clamp_direct = 0.0
    cyc.sample_clamp_indirect = 0.0
    cyc.light_sampling_threshold = 0.0
    cyc.caustics_reflective = True
    cyc.caustics_refractive = True
    cyc.blur_glossy = 0.0
    if hasattr(cyc, "use_light_tree"):
        cyc.use_light_tree = False
