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
from .material import (
    create_fabric_material,
    fabric_group_node,
    fit_closure_images,
    link_closure_images,
    sync_fabric_lamps,
)
from .presets import tilted_quat

__all__ = ["hdri_world", "render_hdri_patch_vs_core", "render_maps_vs_core", "render_patch_vs_core", "tilted_quat"]


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
    fitted_closures=False,
):
    """Render the patch and return ``(rendered_rgb, reference_rgb, mask)`` for its pixels.

    ``view`` = (theta, phi) of the direction towards the camera in degrees. ``fitted_closures``: the
    material reads its fitted closure maps (1 x 1 images) instead of the fixed closure approximation
    (what Fast Preview and world light see).
    """
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=samples, seed=seed)
    dark_world(scene)
    mat = create_fabric_material("Patch", kd=kd, ks=ks, sigma=sigma, quat=quat, scene=scene)
    if fitted_closures:
        from ...core.fabric.parameter_maps import make_maps

        one = make_maps(kd=np.reshape(kd, (1, 1, 3)), ks=np.reshape(ks, (1, 1, 3)), sigma=np.reshape(sigma, (1, 1, 2)),
                        basis=np.reshape(quat, (1, 1, 4)))
        link_closure_images(mat, fit_closure_images(one, "Patch"))
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


def hdri_world(scene, env, path: str, rotation_z_deg: float = 0.0):
    """A world lit only by the environment ``env`` (core.fabric.closure_accuracy convention, (H, W, 3)),
    written to ``path`` as an EXR in Blender's equirect layout and read through an Environment Texture
    with closest-texel lookup (so Cycles integrates the same piecewise-constant radiance as the core
    quadrature). ``rotation_z_deg``: turned by a Mapping node (Texture Coordinate Generated -> Mapping
    rotation about Z), the way artists turn an HDRI."""
    import bpy

    from ...core.exr_io import write_exr
    from ...core.fabric.closure_accuracy import to_blender_equirect

    write_exr(path, to_blender_equirect(np.asarray(env, np.float32))[::-1])  # file row 0 = top
    world = dark_world(scene, strength=1.0)
    tree = world.node_tree
    bg = next(n for n in tree.nodes if n.type == "BACKGROUND")
    tex = tree.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(path, check_existing=False)
    tex.image.colorspace_settings.name = "Non-Color"  # the stored floats are the radiance
    tex.interpolation = "Closest"
    tree.links.new(tex.outputs["Color"], bg.inputs["Color"])
    if rotation_z_deg:
        coord = tree.nodes.new("ShaderNodeTexCoord")
        mapping = tree.nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(rotation_z_deg))
        tree.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    return world


def hdri_references(env, views, kd, ks, sigma, quat, fit, supersample: int = 4):
    """Numpy references for a flat patch under ``env`` seen along each of ``views`` (V, 3): eq. 3.9 and
    the fitted closure model (``closure_fit.closure_eval``), both as the quadrature of f cos_i times the
    environment's radiance over the upper hemisphere, the environment's texels split ``supersample``^2
    times (it is piecewise constant, as the render reads it). Returns (eq39 (V, 3), closures (V, 3))."""
    from ...core.fabric import closure_accuracy as A
    from ...core.fabric.closure_fit import closure_eval

    fine = np.repeat(np.repeat(np.asarray(env), supersample, axis=0), supersample, axis=1)
    lights = A.env_lights(fine)
    kd, ks, sigma, quat = (np.asarray(v, float) for v in (kd, ks, sigma, quat))
    ref = A.env_radiance(A.reference_eval(kd, ks, sigma, quat), views, lights)
    model = A.env_radiance(lambda wi, wo: closure_eval(wi, wo, kd, ks, sigma, quat, fit), views, lights)
    return ref, model


def render_hdri_patch_vs_core(
    env,
    env_path: str,
    views,
    kd=(0.05, 0.03, 0.02),
    ks=(0.7, 0.4, 0.3),
    sigma=(0.3, 0.8),
    quat=(1.0, 0.0, 0.0, 0.0),
    resolution=(8, 8),
    samples=256,
    seed=0,
    exact_world: bool = True,
    rotation_z_deg: float = 0.0,
):
    """A flat fabric patch with fitted closures (uniform 4 x 4 maps), lit only by the world ``env``,
    rendered by Cycles along each view direction (V, 3) with an orthographic camera; every pixel of a
    view sees the same radiance, so the mean over the patch's pixels is the view's value.
    ``exact_world``: the material's exact world light (the default) or, off, its fitted closures.
    ``rotation_z_deg`` turns the world with a Mapping node (a multiple of 360 / width degrees); the
    references use the turned environment, E'(d) = E(R_z d).

    Returns ``(rendered (V, 3), eq39 (V, 3), closure_model (V, 3))``.
    """
    from ...core.fabric.closure_fit import fit_closure_maps
    from ...core.fabric.parameter_maps import make_maps

    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=samples, seed=seed)
    hdri_world(scene, env, env_path, rotation_z_deg)
    n = 4
    maps = make_maps(kd=np.broadcast_to(kd, (n, n, 3)), ks=np.broadcast_to(ks, (n, n, 3)),
                     sigma=np.broadcast_to(sigma, (n, n, 2)), basis=np.broadcast_to(quat, (n, n, 4)))
    images = maps_to_images(maps, "HDRI patch", btf_frame=False)
    closures = fit_closure_images(maps, "HDRI patch")
    mat = create_fabric_material("HDRI Patch", maps=images, scene=scene, closures=closures)
    fabric_group_node(mat).inputs["ExactWorld"].default_value = int(exact_world)
    add_textured_plane(scene, 1.0, mat)
    sync_fabric_lamps(scene)  # no lamps; hands the world's environment to the shader
    cam = add_orthographic_camera(scene, ortho_scale=0.25)  # inside the patch for views up to 75 degrees
    out = []
    for wo in np.asarray(views, float):
        if wo[2] < 0.26:
            raise ValueError("views must be within 75 degrees of the normal (the patch fills the frame)")
        look_from(cam, wo)
        out.append(render_to_array(scene)[..., :3].reshape(-1, 3).mean(axis=0))
    cm = fit_closure_maps(np.asarray(sigma, float)[None, None], np.asarray(quat, float)[None, None])
    fit = (cm.weights[0, 0], cm.shape[0, 0], cm.ggx_scale[0, 0])
    shift = rotation_z_deg / 360.0 * np.shape(env)[1]
    if abs(shift - round(shift)) > 1e-9:
        raise ValueError("rotation_z_deg must be a multiple of 360 / the environment's width")
    turned = np.roll(np.asarray(env), -round(shift), axis=1)  # column j sees azimuth phi_j + rotation
    ref, model = hdri_references(turned, np.asarray(views, float), kd, ks, sigma, quat, fit)
    return np.asarray(out), ref, model
