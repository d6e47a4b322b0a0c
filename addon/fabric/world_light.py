"""The fabric's exact world light: the scene's world environment handed to the fabric shader.

Cycles gives OSL no access to the world, so the add-on reads it (``addon/world_environment.py``: a
Background fed by a constant colour or by an equirectangular Environment Texture, optionally turned
by a Mapping). Its radiance
becomes the importance-sampling tables of ``core.fabric.environment_sampling`` (piecewise constant,
at most 1024 texels wide), written as two EXRs into a content-addressed folder
``<tempdir>/material_structures_world-<user>/<sha1>/`` (identical content -> identical path, so
OpenImageIO's texture cache never serves stale tables; a reopened file re-extracts them), and the
folder goes into the script nodes' ``WorldTable`` input; the Background's strength and the Mapping's
rotation go into ``WorldStrength`` and ``WorldAxis*``, so turning or dimming the world rebuilds
nothing. Any other world (a sky texture, other mappings, mixes) leaves ``WorldTable`` empty, and the
fabric takes world light through its fitted closures as before; :func:`world_light_status` says
which, for the material panel. Tables are only made where they render (Cycles with OSL).
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from ...core.exr_io import write_exr
from ...core.fabric.environment_sampling import EnvironmentMapError, build_environment_table, shader_files
from ...render import osl_flip_t
from ..common import prune_cache, user_cache_root
from ..lamp_sync import set_if_changed
from ..world_environment import world_source, world_strength

CACHE_DIR = "material_structures_world"
_cache: dict = {}  # world key -> (folder, width, height, status); folder "" when it cannot be sampled


def _write_tables(radiance: np.ndarray):
    table = build_environment_table(radiance)
    if table is None:
        return None, 0, 0
    files = shader_files(table)
    digest = hashlib.sha1()
    for name in sorted(files):
        digest.update(np.ascontiguousarray(files[name]).tobytes())
    folder = os.path.join(user_cache_root(CACHE_DIR), digest.hexdigest()[:20])
    os.makedirs(folder, exist_ok=True)
    for name, arr in files.items():
        path = os.path.join(folder, name)
        if not os.path.exists(path):
            write_exr(path, arr)  # written under a temporary name, then renamed
    os.utime(folder)  # in use: kept by prune_cache of every session
    prune_cache(os.path.dirname(folder), keep=folder)
    h, w = table.shape
    return folder, w, h


def world_light_inputs(scene, build: bool = True, tables: bool = True):
    """(folder, width, height, status, M, strength) of the scene's world, parsed once: the tables'
    folder ("" when the shader cannot sample the world, status says why, or the world is black),
    the lookup rotation M (lookup direction = M d) and the Background's strength. ``build=False``
    (panels) only reads what the last sync made; ``tables=False`` (no Cycles + OSL) makes none. A
    failure (a bad image, a full disk) is remembered for that world, so it is tried again only when
    the world changes."""
    key, load, rotation = world_source(scene)
    strength = world_strength(scene)
    if not tables:
        return "", 0, 0, "not rendered with Cycles and OSL", rotation, strength
    if key is None:
        return "", 0, 0, load, rotation, strength
    if not strength > 0:
        return "", 0, 0, "the world is black", rotation, strength
    hit = _cache.get(key)
    if hit is None and not build:
        return "", 0, 0, "tables are made at the next render", rotation, strength
    if hit is None or (hit[0] and not all(os.path.exists(os.path.join(hit[0], f))
                                          for f in ("radiance.exr", "alias.exr"))):
        try:
            folder, w, h = _write_tables(load())
            status = f"exact ({w} x {h} environment)" if folder else "the world is black"
        except EnvironmentMapError as exc:
            folder, w, h, status = None, 0, 0, str(exc)
        except (OSError, MemoryError, ValueError) as exc:  # temp folder, disk, EXR writer
            folder, w, h, status = None, 0, 0, f"the world's tables could not be written ({exc})"
        hit = (folder or "", w, h, status)
        _cache.clear()  # one world at a time is plenty
        _cache[key] = hit
    return (*hit, rotation, strength)


def world_tables(scene, build: bool = True) -> tuple[str, int, int, str]:
    """(folder, width, height, status) of :func:`world_light_inputs`."""
    return world_light_inputs(scene, build)[:4]


def write_world_inputs(node, folder: str, width: int, height: int, rotation=None, strength: float = 1.0) -> None:
    """Point a fabric script node at the world tables; ``rotation`` M (lookup direction = M d) goes in
    as its rows (an older node without the inputs is skipped); an unchanged world writes nothing
    (``lamp_sync.set_if_changed``)."""
    if "WorldTable" not in node.inputs:
        return
    m = np.eye(3) if rotation is None else np.asarray(rotation, float)
    values = {"WorldTable": folder, "WorldWidth": width, "WorldHeight": height, "FlipT": osl_flip_t(),
              "WorldStrength": float(strength),
              "WorldAxisX": tuple(m[0]), "WorldAxisY": tuple(m[1]), "WorldAxisZ": tuple(m[2])}
    for name, value in values.items():
        if name in node.inputs:
            set_if_changed(node, name, value)


def world_light_status(scene) -> str:
    """One line for the panel: how world light reaches the fabric."""
    folder, _w, _h, status = world_tables(scene, build=False)
    if not folder and status.startswith("tables are made"):
        return f"World light: exact ({status})"
    return f"World light: {status}" if folder else f"World light: fitted closures ({status})"
