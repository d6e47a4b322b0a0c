"""World (HDRI) approximation of the scratch term: bright regions as distant sphere lamps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from material_structures.addon.scratch import world as W

SUN = np.array([0.5, 0.3, 0.81]) / np.linalg.norm([0.5, 0.3, 0.81])


def _env():
    d, _ = W.equirect_directions()
    sky = np.clip(d[..., 2], 0, 1)[..., None] * np.array([0.3, 0.4, 0.6])
    sun = (d @ SUN > math.cos(math.radians(6)))[..., None] * np.array([40.0, 38.0, 34.0])
    return sky + sun


def env_world(scene, pack: bool = False) -> None:
    """Light the scene's world with ``_env()`` (an equirectangular float image, packed into the file with
    ``pack``) at strength 1."""
    import bpy

    env = _env()
    img = bpy.data.images.new("Env", env.shape[1], env.shape[0], float_buffer=True)
    rgba = np.concatenate([env, np.ones(env.shape[:2] + (1,))], -1)[::-1].astype(np.float32)
    img.pixels.foreach_set(rgba.ravel())
    if pack:
        img.pack()
    tree = scene.world.node_tree
    tex = tree.nodes.new("ShaderNodeTexEnvironment")
    tex.image = img
    bg = next(n for n in tree.nodes if n.type == "BACKGROUND")
    tree.links.new(tex.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 1.0


def test_the_map_of_an_environment_smaller_than_it_has_no_black_cells():
    """An image smaller than the 64 x 32 map (before: three cells of four black, the sun a quarter as bright)
    fills every cell with the texel it lies in; a larger one is box-filtered."""
    small = np.arange(16 * 32 * 3, dtype=float).reshape(16, 32, 3) + 1.0
    up = W.downsample(small)
    assert up.shape == (W.MAP_H, W.MAP_W, 3)
    np.testing.assert_array_equal(up, np.repeat(np.repeat(small, 2, axis=0), 2, axis=1))
    large = np.repeat(np.repeat(small, 4, axis=0), 4, axis=1)  # 64 x 128: each map cell averages 2 x 2 texels
    np.testing.assert_allclose(W.downsample(large), up, rtol=1e-12)


def test_bright_region_is_the_sun():
    env = _env()
    d, om = W.equirect_directions()
    reg = W.bright_regions(env, 2)
    assert len(reg) == 1  # the sky is below the threshold
    assert math.degrees(math.acos(min(1.0, reg[0]["direction"] @ SUN))) < 3.0
    sun_power = (env * om[..., None])[(d @ SUN) > math.cos(math.radians(6))].sum(0)
    np.testing.assert_allclose(reg[0]["radiance"] * reg[0]["omega"], sun_power, rtol=1e-9)


def test_world_lamps_reach_the_shader(addon_module):
    import bpy

    from material_structures.addon.scratch.material import scratch_script_nodes, sync_scratch_lamps
    from material_structures.addon.scratch.verify import render_plate_vs_core

    render_plate_vs_core(lamps=(("POINT", (0.5, 0.3, 1.2), 200.0, 0.08),), resolution=(8, 8))
    scene = bpy.context.scene
    env_world(scene)
    scene["ms_scratch_world_lamps"] = 2
    sync_scratch_lamps(scene)
    node = next(scratch_script_nodes())
    assert node.inputs["Lamp2Type"].default_value == 1
    pos = np.array(node.inputs["Lamp2Position"].default_value)
    assert math.degrees(math.acos(min(1.0, pos @ SUN / np.linalg.norm(pos)))) < 3.0
    assert node.inputs["Lamp2Radius"].default_value > 0
    assert node.inputs["Lamp3Type"].default_value == 0



def test_world_lamps_follow_a_turned_hdri_and_ignore_unused_images(addon_module):
    """The world's Mapping turns the HDRI 90 degrees about Z: the sun lamp turns with it (the world is
    read as the fabric's exact world light reads it). An Environment Texture that feeds nothing gives
    no lamps (it used to be picked up)."""
    import bpy

    from material_structures.addon.scratch.material import scratch_script_nodes, sync_scratch_lamps
    from material_structures.addon.scratch.verify import render_plate_vs_core

    render_plate_vs_core(lamps=(("POINT", (0.5, 0.3, 1.2), 200.0, 0.08),), resolution=(8, 8))
    scene = bpy.context.scene
    env_world(scene)
    tree = scene.world.node_tree
    tex = next(n for n in tree.nodes if n.type == "TEX_ENVIRONMENT")
    coord, mapping = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeMapping")
    tree.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(90.0))
    scene["ms_scratch_world_lamps"] = 1
    sync_scratch_lamps(scene)
    node = next(scratch_script_nodes())
    pos = np.array(node.inputs["Lamp2Position"].default_value)
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # M: lookup = M d, so d = M^T SUN
    assert math.degrees(math.acos(min(1.0, pos @ (rz.T @ SUN) / np.linalg.norm(pos)))) < 3.0
    bg = next(n for n in tree.nodes if n.type == "BACKGROUND")
    tree.links.remove(bg.inputs["Color"].links[0])  # the texture stays in the tree, unused
    sync_scratch_lamps(scene)
    assert node.inputs["Lamp2Type"].default_value == 0

@pytest.mark.slow
def test_world_approximation_error_is_measured():
    """Measured (64 x 32 map, sun 6 deg + sky): median ~0.26, p99 ~0.79 (K = 1 or 2). The
    approximation drops the dim sky and replaces the blocky sun region by a sphere of equal solid angle."""
    from material_structures.addon.scratch.verify import test_scratch_set

    pts = np.random.default_rng(0).uniform(300, 1700, (60, 2))
    wo = np.array([-0.4, -0.2, 0.89])
    err = W.world_approximation_error(_env(), 2, test_scratch_set(), pts, wo / np.linalg.norm(wo))
    assert err["points"] > 20
    assert err["median_rel_err"] < 0.5
    assert err["total_rel_err"] < 0.5
