"""Loading OSL shaders into script nodes, headless."""

from __future__ import annotations

from collections.abc import Iterable

from .session import ensure_bundled_paths, osl_shader_path


class OslScriptError(RuntimeError):
    """An OSL script node did not get the sockets its shader declares (compile error or no oslquery)."""


def load_osl_script(
    node_tree,
    shader: str,
    scene=None,
    inputs: Iterable[str] = (),
    outputs: Iterable[str] = (),
    name: str | None = None,
):
    """Add a ``ShaderNodeScript`` running ``shader`` (a name in ``cycles_osl/`` or a path).

    Sets the engine to Cycles and enables OSL on ``scene`` (default: the context scene) *before*
    assigning the file (and, for the compile, on the context scene too), calls ``node.update()``
    and asserts that ``inputs`` and ``outputs`` exist.
    """
    import os

    import bpy

    ensure_bundled_paths()
    scene = scene or bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.shading_system = True
    path = shader if os.path.isabs(shader) else osl_shader_path(shader)
    node = node_tree.nodes.new("ShaderNodeScript")
    if name:
        node.name = node.label = name
    node.mode = "EXTERNAL"
    # Script nodes compile against the *context* scene's engine: lend it Cycles + OSL meanwhile.
    ctx = bpy.context.scene
    saved = (ctx.render.engine, ctx.cycles.shading_system) if ctx is not None else None
    if ctx is not None:
        ctx.render.engine = "CYCLES"
        ctx.cycles.shading_system = True
    try:
        node.filepath = path
        node.update()
    finally:
        if ctx is not None and ctx != scene:
            ctx.render.engine, ctx.cycles.shading_system = saved
    have_in = {s.name for s in node.inputs}
    have_out = {s.name for s in node.outputs}
    missing = [s for s in inputs if s not in have_in] + [s for s in outputs if s not in have_out]
    if missing or not (have_in or have_out):
        raise OslScriptError(
            f"OSL script {path} is missing sockets {missing or '(all)'}; it has inputs {sorted(have_in)} "
            f"and outputs {sorted(have_out)} (does it compile? is oslquery importable?)"
        )
    return node


def link_uv(node_tree, script_node, socket: str = "UV"):
    """Feed the UV map into ``script_node.inputs[socket]`` through a Texture Coordinate node."""
    texco = next((n for n in node_tree.nodes if n.type == "TEX_COORD"), None)
    if texco is None:
        texco = node_tree.nodes.new("ShaderNodeTexCoord")
    node_tree.links.new(texco.outputs["UV"], script_node.inputs[socket])
    return texco
