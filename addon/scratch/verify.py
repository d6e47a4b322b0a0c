"""Render-side verification of the scratched-metal shader against ``core.scratch`` (tests, bench).

Footprint: Cycles keeps compact (isotropic) ray differentials, so Dx/Dy of the UV map are two
orthogonal vectors as long as the pixel's width on the surface, not the pixel's projected
parallelogram. The reference uses the footprint the shader derived (read back through its debug
outputs); ``footprint_pass`` is checked against the camera geometry separately.

A flat 1 x 1 plate (UV = [0, 1]^2, scratch patch mapped once onto it) under an orthographic camera
and a few lamps is rendered with the shader's debug outputs (scratch colour alone, or rho_P), the
shading positions are rendered too, and ``scratch_radiance`` is evaluated at the same points with the
same footprint (finite differences of the position pass = the camera's ray differentials on a plane)
and the same lamps, on the set the shader reads (the float32 EXR cache).
"""

from __future__ import annotations

import math

import numpy as np

from ... import render
from ...core.scratch import scratch_io
from ...core.scratch.light_integration import DirectionalLight, PointLight, PolygonLight, SphereLight
from ...core.scratch.scratch_radiance import scratch_radiance
from ...render import (
    add_orthographic_camera,
    add_textured_plane,
    configure_cycles,
    dark_world,
    look_from,
    render_positions,
    render_to_array,
    reset_scene,
    view_direction,
)
from .material import create_scratched_metal, group_node, script_node, sync_scratch_lamps


def test_scratch_set(n: int = 60, patch_um: float = 2000.0, seed: int = 3, sigma_um: float = 60.0):
    """The known plate set: uniform wear plus a fan of straight scratches through the centre."""
    from ...core.scratch.scratch_generators import from_curves, uniform_wear
    from ...core.scratch.scratch_set import make_scratch_set

    a = uniform_wear(n, (patch_um, patch_um), length_um=(200.0, 1500.0), seed=seed, sigma_um=sigma_um,
                     max_footprint_um=200.0)
    c = patch_um / 2
    fan = [np.array([[c - 800 * math.cos(t), c - 800 * math.sin(t)], [c + 800 * math.cos(t), c + 800 * math.sin(t)]])
           for t in np.linspace(0, math.pi, 12, endpoint=False)]
    b = from_curves(fan, (patch_um, patch_um), seed=seed + 1, sigma_um=sigma_um, max_footprint_um=200.0)
    seg = np.concatenate([a.segments, b.segments])
    return make_scratch_set(
        seg, np.concatenate([a.width_um, b.width_um]), np.concatenate([a.depth_um, b.depth_um]),
        (patch_um, patch_um), scratch_id=np.concatenate([a.scratch_id, b.scratch_id + a.n_scratches]),
        sigma_um=sigma_um, max_footprint_um=200.0,
    )


def add_lamp(scene, kind: str, location, power: float, radius: float = 0.0, size=(0.3, 0.2), shape="RECTANGLE"):
    """A lamp "Lamp <kind>" of the plate test: point/spot of ``radius``, hard sun, area lamp of ``size``;
    suns and area lamps face the plate's centre."""
    facing = (0.0, 0.0, 0.0) if kind in {"SUN", "AREA"} else None
    return render.add_lamp(scene, kind, location, power, f"Lamp {kind}", radius=0.0 if kind == "SUN" else radius,
                           size=size, shape=shape, target=facing)


def core_light(obj, pos: np.ndarray):
    """The core light standing for Blender lamp ``obj`` seen from world points ``pos`` (N, 3)."""
    data = obj.data
    mw = np.array(obj.matrix_world)
    centre = mw[:3, 3]
    if data.type == "SUN":
        return DirectionalLight(-mw[:3, 2] * -1.0, data.energy)
    if data.type == "POINT":
        intensity = data.energy / (4 * math.pi)
        if data.shadow_soft_size > 0:
            r = data.shadow_soft_size
            return SphereLight(centre[None] - pos, r, intensity / (math.pi * r * r))
        return PointLight(centre[None] - pos, intensity)
    if data.type == "AREA":
        hu = data.size / 2
        hv = (data.size_y if data.shape in {"RECTANGLE", "ELLIPSE"} else data.size) / 2
        ex, ey = mw[:3, 0] * hu, mw[:3, 1] * hv
        if data.shape in {"SQUARE", "RECTANGLE"}:
            verts = np.array([centre - ex - ey, centre + ex - ey, centre + ex + ey, centre - ex + ey])
            area = 4 * hu * hv
        else:
            nv = 16
            f = math.sqrt(math.pi / (0.5 * nv * math.sin(2 * math.pi / nv)))
            a = 2 * math.pi * np.arange(nv) / nv
            verts = centre + f * (np.cos(a)[:, None] * ex + np.sin(a)[:, None] * ey)
            area = math.pi * hu * hv
        return PolygonLight(verts[None] - pos[:, None], data.energy / (math.pi * area))
    raise ValueError(f"unsupported lamp {data.type}")


def render_plate_vs_core(
    lamps=(("POINT", (0.5, 0.3, 1.2), 200.0, 0.08),),
    view=(25.0, 200.0),
    resolution=(24, 24),
    debug: int = 1,
    scratch_set=None,
    spectral: bool = False,
    ortho_scale: float = 0.9,
    footprint_scale: float = 0.5,
):
    """Render the plate and return ``(rendered (H, W, 3), reference (H, W, 3), mask (H, W))``.

    ``lamps``: (type, location, power, radius) tuples (area: radius = (size_x, size_y)).
    ``debug`` 1: scratch colour vs ``rgb``; 2: rho_P (grey) vs ``rho_p``.
    """
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=1, seed=0)
    dark_world(scene)
    s = scratch_set if scratch_set is not None else test_scratch_set()
    mat = create_scratched_metal("Plate", s, "plate", spectral=spectral, scene=scene)
    g = group_node(mat)
    g.inputs["Debug"].default_value = debug
    g.inputs["FootprintScale"].default_value = footprint_scale
    plane = add_textured_plane(scene, 1.0, mat)
    wo = view_direction(*view)
    look_from(add_orthographic_camera(scene, ortho_scale=ortho_scale), wo)
    objs = []
    for kind, loc, power, extra in lamps:
        if kind == "AREA":
            objs.append(add_lamp(scene, kind, loc, power, size=extra))
        else:
            objs.append(add_lamp(scene, kind, loc, power, radius=extra or 0.0))
    sync_scratch_lamps(scene)
    rgb = render_to_rgb(scene)
    shader_footprint = footprint_pass(scene, g)
    folder = script_node(g.node_tree).inputs["TableDir"].default_value

    pos_rgba = render_positions(scene, plane)
    mask = pos_rgba[..., 3] > 0.999
    pos = pos_rgba[..., :3].astype(np.float64)
    h, w = mask.shape
    ps = s.patch_size_um
    uv = pos[..., :2] + 0.5
    xum = uv * ps
    J = shader_footprint[mask]
    pts = pos[mask]
    s_ref = scratch_io.load_scratch_set(folder)  # exactly what the shader reads (float32 tables)
    total = np.zeros((pts.shape[0], 3))
    rho = None
    for obj in objs:
        sh = scratch_radiance(xum[mask], J, wo, core_light(obj, pts), s_ref, "16" if spectral else "rgb")
        total += sh.rgb
        rho = sh.rho_p
    ref = np.zeros((h, w, 3))
    ref[mask] = total if debug == 1 else np.repeat(rho[:, None], 3, axis=1)
    return rgb, ref, mask


def footprint_pass(scene, gnode) -> np.ndarray:
    """The footprint matrix J (H, W, 2, 2) (columns = semi-diameters, um) the shader derived from
    Cycles' ray differentials, read back through its debug outputs 3 and 4."""
    old = gnode.inputs["Debug"].default_value
    gnode.inputs["Debug"].default_value = 3
    a = render_to_rgb(scene)
    gnode.inputs["Debug"].default_value = 4
    b = render_to_rgb(scene)
    gnode.inputs["Debug"].default_value = old
    J = np.empty(a.shape[:2] + (2, 2))
    J[..., 0, 0], J[..., 1, 0], J[..., 0, 1], J[..., 1, 1] = a[..., 0], a[..., 1], a[..., 2], b[..., 0]
    return J


def render_to_rgb(scene) -> np.ndarray:
    return render_to_array(scene)[..., :3].astype(np.float64)


def relative_errors(rgb: np.ndarray, ref: np.ndarray, mask: np.ndarray, floor_frac: float = 0.01) -> np.ndarray:
    """Per-pixel relative error |r - ref| / |ref| (summed over channels) over the pixels whose
    reference exceeds ``floor_frac`` x its 99th percentile (dark pixels have no meaningful ratio)."""
    a = np.abs(rgb[mask] - ref[mask]).sum(-1)
    b = np.abs(ref[mask]).sum(-1)
    if not np.any(b > 0):
        return np.zeros(0)
    keep = b > floor_frac * np.percentile(b[b > 0], 99)
    return a[keep] / b[keep]
