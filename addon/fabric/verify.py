"""Render-side verification of the fabric shader against ``core.fabric`` (tests and benchmarks).

Builds a flat fabric patch seen by an orthographic camera under one lamp, renders it, renders the
shading positions, and evaluates eq. 3.9 in numpy at the same points with the same lamp.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.fabric import sggx_brdf
from ...render import (
    add_lamp,
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
from .maps import maps_to_images
from .material import create_fabric_material, fabric_group_node, sync_fabric_lamps
from .presets import tilted_quat

__all__ = ["render_maps_vs_core", "render_patch_vs_core", "tilted_quat"]


def render_patch_vs_core(
    kd=(0.05, 0.03, 0.02),
    ks=(0.7, 0.4, 0.3),
    sigma=(0.3, 0.8),
    quat=(1.0, 0.0, 0.0, 0.0),
    view=(30.0, 200.0),
    lamp_position=(0.4, -0.3, 1.2),
    lamp_power=50.0,
    lamp_type="POINT",
    area_shape="RECTANGLE",
    area_size=(0.6, 0.3),
    resolution=(24, 24),
    samples=1,
    fast_preview=False,
    seed=0,
):
    """Render the patch and return ``(rendered_rgb, reference_rgb, mask)`` for its pixels.

    ``view`` = (theta, phi) of the direction towards the camera in degrees.
    """
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=samples, seed=seed)
    dark_world(scene)
    mat = create_fabric_material("Patch", kd=kd, ks=ks, sigma=sigma, quat=quat, scene=scene)
    fabric_group_node(mat).inputs["FastPreview"].default_value = 1 if fast_preview else 0
    plane = add_textured_plane(scene, 1.0, mat)
    wo = view_direction(*view)
    look_from(add_orthographic_camera(scene, ortho_scale=0.7), wo)
    facing = (0.0, 0.0, 0.0) if lamp_type in {"SUN", "AREA"} else None  # facing the patch centre
    lamp = add_lamp(scene, lamp_type, lamp_position, lamp_power, "Lamp", size=area_size, shape=area_shape,
                    target=facing)
    light = lamp.data
    if not fast_preview:
        sync_fabric_lamps(scene)
    rgb = render_to_array(scene)[..., :3]

    pos_rgba = render_positions(scene, plane)  # shading positions of the same pixels
    mask = pos_rgba[..., 3] > 0.999
    pos = pos_rgba[..., :3].astype(np.float64)
    wo_px = np.broadcast_to(wo, pos.shape)
    params = (np.asarray(kd), np.asarray(ks), np.asarray(sigma), np.asarray(quat))
    if lamp_type == "AREA":
        ref = _area_lamp_reference(pos, wo_px, params, lamp, light, lamp_power)
        return rgb, ref, mask
    if lamp_type == "SUN":
        wi = np.broadcast_to(np.asarray(lamp_position) / np.linalg.norm(lamp_position), pos.shape)
        irradiance = lamp_power
    else:
        d = np.asarray(lamp_position)[None, None, :] - pos
        dist2 = np.sum(d * d, axis=-1, keepdims=True)
        wi = d / np.sqrt(dist2)
        irradiance = lamp_power / (4.0 * math.pi) / dist2
    f = sggx_brdf(wi, wo_px, *params)
    ref = f * np.maximum(wi[..., 2:3], 0.0) * irradiance
    return rgb, ref, mask


def _area_lamp_reference(pos, wo, params, lamp_obj, light, power, n: int = 48):
    """Eq. 3.9 integrated over an area lamp by an n x n midpoint rule (independent of the shader's
    jittered sampling): L_o = int f cos_i cos_l L_e / d^2 dA with L_e = P / (pi A)."""
    mw = np.array(lamp_obj.matrix_world)
    centre, ex, ey, normal = mw[:3, 3], mw[:3, 0], mw[:3, 1], -mw[:3, 2]
    hu = light.size / 2.0
    hv = (light.size_y if light.shape in {"RECTANGLE", "ELLIPSE"} else light.size) / 2.0
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(g, g, indexing="ij")
    keep = np.ones_like(x, bool) if light.shape in {"SQUARE", "RECTANGLE"} else (x * x + y * y <= 1.0)
    pts = centre + (x[keep, None] * hu) * ex + (y[keep, None] * hv) * ey  # (M, 3)
    area = (4.0 if light.shape in {"SQUARE", "RECTANGLE"} else math.pi) * hu * hv
    d_a = 4.0 * hu * hv / (n * n)
    radiance = power / (math.pi * area)
    d = pts[None, None, :, :] - pos[:, :, None, :]
    dist2 = np.sum(d * d, axis=-1, keepdims=True)
    wi = d / np.sqrt(dist2)
    cos_l = np.maximum(-np.sum(wi * normal, axis=-1, keepdims=True), 0.0)
    f = sggx_brdf(wi, wo[:, :, None, :], *params)
    integrand = f * np.maximum(wi[..., 2:3], 0.0) * cos_l / dist2
    return radiance * d_a * np.sum(integrand, axis=2)


def render_maps_vs_core(
    maps,
    view=(35.0, 210.0),
    lamp_position=(0.3, -0.4, 1.1),
    lamp_power=40.0,
    resolution=(32, 32),
):
    """Render a 1 x 1 patch textured with ``maps`` (core FabricMaps, BTF frame, row 0 = top) and
    evaluate eq. 3.9 in numpy at each pixel's texel with the directions expressed in the BTF frame.

    Returns ``(rendered_rgb, reference_rgb, mask)``.
    """
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=1, seed=0)
    dark_world(scene)
    images = maps_to_images(maps, "Verify")
    mat = create_fabric_material("Mapped", maps=images, scene=scene)
    plane = add_textured_plane(scene, 1.0, mat)
    wo = view_direction(*view)
    look_from(add_orthographic_camera(scene, ortho_scale=0.7), wo)
    add_lamp(scene, "POINT", lamp_position, lamp_power, "Lamp")
    sync_fabric_lamps(scene)
    rgb = render_to_array(scene)[..., :3]

    pos_rgba = render_positions(scene, plane)
    pos = pos_rgba[..., :3].astype(np.float64)
    h, w = maps.shape
    u, v = pos[..., 0] + 0.5, pos[..., 1] + 0.5
    col = np.clip(np.floor(u * w).astype(int), 0, w - 1)
    row = np.clip(h - 1 - np.floor(v * h).astype(int), 0, h - 1)
    # Stay away from texel borders, where a pixel may straddle two texels.
    fu, fv = u * w - np.floor(u * w), v * h - np.floor(v * h)
    mask = (pos_rgba[..., 3] > 0.999) & (np.minimum(fu, 1 - fu) > 0.02) & (np.minimum(fv, 1 - fv) > 0.02)

    d = np.asarray(lamp_position)[None, None, :] - pos
    dist2 = np.sum(d * d, axis=-1, keepdims=True)
    wi = d / np.sqrt(dist2)
    flip = np.array([1.0, -1.0, 1.0])  # mesh frame (y up the image) -> BTF frame (y down)
    wi_btf, wo_btf = wi * flip, np.broadcast_to(wo * flip, pos.shape)
    f = sggx_brdf(
        wi_btf,
        wo_btf,
        maps.kd[row, col].astype(np.float64),
        maps.ks[row, col].astype(np.float64),
        maps.sigma[row, col].astype(np.float64),
        maps.basis[row, col].astype(np.float64),
    )
    ref = f * np.maximum(wi[..., 2:3], 0.0) * lamp_power / (4.0 * math.pi) / dist2
    return rgb, ref, mask
