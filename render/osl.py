"""Loading OSL shaders into script nodes, embedded in the .blend, headless."""

from __future__ import annotations

import contextlib
import glob
import hashlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterable

from .session import OSL_DIR, ensure_bundled_paths, osl_shader_path

_LOCAL_INCLUDE = re.compile(r'\s*#\s*include\s+"(ms_[A-Za-z0-9_]+\.h)"')


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

    The shader is embedded in the .blend (:func:`shader_text`): the node runs an internal text
    datablock, and Cycles keeps the compiled bytecode in the node, so the file renders wherever it
    is moved and whichever folder the extension is installed in. Compiles it with Cycles + OSL lent to
    the context scene meanwhile (:func:`compile_script_node`: the scene's render engine and shading system
    are the artist's and stay as they were), and asserts that ``inputs`` and ``outputs`` exist.
    """
    import bpy

    ensure_bundled_paths()
    scene = scene or bpy.context.scene
    node = node_tree.nodes.new("ShaderNodeScript")
    if name:
        node.name = node.label = name
    with _private_temporary_folder():  # with Cycles + OSL as the engine, setting the script compiles it
        node.mode = "INTERNAL"
        node.script = shader_text(shader)
    errors = compile_script_node(node, scene)
    have_in = {s.name for s in node.inputs}
    have_out = {s.name for s in node.outputs}
    missing = [s for s in inputs if s not in have_in] + [s for s in outputs if s not in have_out]
    if missing or not (have_in or have_out):
        raise OslScriptError(
            f"OSL script {shader} is missing sockets {missing or '(all)'}; it has inputs {sorted(have_in)} "
            f"and outputs {sorted(have_out)} ({'; '.join(errors) or 'does it compile? is oslquery importable?'})"
        )
    return node


def compile_script_node(node, scene=None) -> list[str]:
    """(Re)compile a script node: its sockets and, for internal scripts, the bytecode kept in the node.

    Calls Cycles' own compile step (``node.update()`` does not reach it in every state, e.g. from a
    load handler). Script nodes compile against the *context* scene's engine: lend it Cycles + OSL
    meanwhile. Returns the compiler's error messages (empty when it succeeded).
    """
    import bpy

    ensure_bundled_paths()
    ctx = bpy.context.scene
    saved = (ctx.render.engine, ctx.cycles.shading_system) if ctx is not None else None
    if ctx is not None:
        ctx.render.engine = "CYCLES"
        ctx.cycles.shading_system = True
    errors: list[str] = []
    try:
        try:
            from cycles import osl as cycles_osl
        except ImportError:  # Cycles' add-on missing: Blender's generic update
            node.update()
        else:
            with _private_temporary_folder():
                cycles_osl.update_script_node(node, lambda kind, msg: errors.append(msg) if "ERROR" in kind else None)
    finally:
        if ctx is not None:
            ctx.render.engine, ctx.cycles.shading_system = saved
    return errors


@contextlib.contextmanager
def _private_temporary_folder():
    """Python's temporary files inside a folder of their own, removed afterwards. Cycles compiles an internal
    script through a temporary ``.osl`` and ``.oso`` and removes only the ``.osl`` (Blender 4.5 and 5.2,
    ``cycles/osl.py``): without this, every compile left a ``tmp*.oso`` in the system's temporary folder."""
    saved = tempfile.tempdir
    folder = tempfile.mkdtemp(prefix="ms-osl-")
    tempfile.tempdir = folder
    try:
        yield folder
    finally:
        tempfile.tempdir = saved
        shutil.rmtree(folder, ignore_errors=True)


TEXT_MARKER = "material_structures_osl"  # ID property on embedded shader texts: the source's hash


def shader_source(shader: str) -> str:
    """The source of ``shader`` with this project's ``#include "ms_*.h"`` headers inlined (an
    embedded script is compiled from a temporary file, where relative includes are not found);
    Cycles' own headers (``stdcycles.h``, ``stdosl.h``) stay includes."""
    path = shader if os.path.isabs(shader) else osl_shader_path(shader)
    folder = os.path.dirname(path)
    seen = {path}

    def expand(file: str) -> list[str]:
        out = []
        with open(file, encoding="utf-8") as f:
            for line in f:
                m = _LOCAL_INCLUDE.match(line)
                header = os.path.join(folder, m.group(1)) if m else None
                if header and os.path.isfile(header):
                    if header not in seen:  # each header once, like an include guard
                        seen.add(header)
                        out += expand(header)
                    continue
                out.append(line if line.endswith("\n") else line + "\n")
        return out

    return "".join(expand(path))


def shader_text(shader: str):
    """The text datablock holding ``shader`` (created, or refreshed when the shipped source changed)."""
    import bpy

    base = os.path.basename(shader)
    name = base if base.endswith(".osl") else base + ".osl"
    text = bpy.data.texts.get(name)
    if text is None or text.library is not None:
        text = bpy.data.texts.new(name)
    _refresh_text(text, shader)
    return text


def _refresh_text(text, shader: str) -> bool:
    """Write the shipped source of ``shader`` into ``text`` unless it holds it already; whether it wrote."""
    source = shader_source(shader)
    digest = hashlib.sha1(source.encode()).hexdigest()[:16]
    if text.get(TEXT_MARKER) == digest:
        return False
    text.from_string(source)
    text[TEXT_MARKER] = digest
    return True


def refresh_embedded_scripts(scene=None) -> int:
    """After a file is loaded: bring every script node of ours to the installed extension's shaders.

    Nodes of files written before shaders were embedded (external mode, a path ending in one of the
    shipped ``cycles_osl/*.osl``) become internal; embedded texts whose source differs from the
    shipped one (the extension was updated) are refreshed and their nodes recompiled. Returns the
    number of nodes recompiled.
    """
    import bpy

    shipped = {os.path.basename(p) for p in glob.glob(os.path.join(OSL_DIR, "*.osl"))}
    stale = {t.name for t in bpy.data.texts
             if t.library is None and t.get(TEXT_MARKER) is not None and t.name in shipped and _refresh_text(t, t.name)}
    n = 0
    trees = [m.node_tree for m in bpy.data.materials if m.node_tree is not None and m.library is None]
    trees += [g for g in bpy.data.node_groups if g.library is None]
    for tree in trees:
        for node in list(tree.nodes):
            if node.type != "SCRIPT":
                continue
            external = os.path.basename(bpy.path.abspath(node.filepath)) if node.mode == "EXTERNAL" else ""
            if external in shipped:
                _embed(tree, node, external, scene)
            elif node.mode == "INTERNAL" and node.script is not None and node.script.name in stale:
                compile_script_node(node, scene)
            else:
                continue
            n += 1
    return n


def _embed(tree, node, shader: str, scene) -> None:
    """Replace an external script node by an embedded one with the same inputs, values and links (a
    node switched from external to internal mode in place gets no bytecode)."""
    new = tree.nodes.new("ShaderNodeScript")
    new.mode = "INTERNAL"
    new.script = shader_text(shader)
    compile_script_node(new, scene)
    new.location, new.label, new.parent = node.location, node.label, node.parent
    for sock in node.inputs:
        if sock.name in new.inputs and hasattr(sock, "default_value"):
            new.inputs[sock.name].default_value = sock.default_value
    links = [(link.from_socket, new.inputs[link.to_socket.name]) for link in tree.links
             if link.to_node == node and link.to_socket.name in new.inputs]
    links += [(new.outputs[link.from_socket.name], link.to_socket) for link in tree.links
              if link.from_node == node and link.from_socket.name in new.outputs]
    name = node.name
    tree.nodes.remove(node)
    new.name = name
    for a, b in links:
        tree.links.new(a, b)


def link_uv(node_tree, script_node, socket: str = "UV"):
    """Feed the UV map into ``script_node.inputs[socket]`` through a Texture Coordinate node."""
    texco = next((n for n in node_tree.nodes if n.type == "TEX_COORD"), None)
    if texco is None:
        texco = node_tree.nodes.new("ShaderNodeTexCoord")
    node_tree.links.new(texco.outputs["UV"], script_node.inputs[socket])
    return texco
