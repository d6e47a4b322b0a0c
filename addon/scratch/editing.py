"""Scratch sets on objects: generate, merge drawn curves, find the set of a material."""

from __future__ import annotations

import numpy as np

from ...core.scratch import scratch_generators as gen
from ...core.scratch.scratch_set import ProgressFn, ScratchSet, make_scratch_set
from .material import MARKER, group_node
from .tables import PROP, load_group_set

PATTERNS = {
    "WEAR": "Random wear: uniformly placed, gently curved scratches",
    "POLISH": "Polishing circles: arcs around the patch centre",
    "HAIRLINE": "Hairline brushing: long parallel lines",
}
FINE_WEAR_SIGMA_UM = 10.0


def generate_set(
    pattern: str,
    count: int,
    patch_mm: float,
    length_um=(300.0, 4000.0),
    width_um=(0.8, 6.0),
    depth_um=(0.8, 6.0),
    seed: int = 0,
    sigma_um: float = 60.0,
    angle_deg: float = 0.0,
    max_footprint_um: float = 500.0,
    progress: ProgressFn | None = None,
) -> ScratchSet:
    """A scratch set on a square patch of ``patch_mm`` mm (core generators; ranges are uniform).
    ``progress``: called with the fraction done (increasing, last 1.0); an exception it raises cancels."""
    ps = (patch_mm * 1000.0, patch_mm * 1000.0)
    kw = {"width_um": tuple(width_um), "depth_um": tuple(depth_um), "seed": int(seed), "sigma_um": float(sigma_um),
          "max_footprint_um": float(max_footprint_um), "progress": progress}
    if pattern == "WEAR":
        return gen.uniform_wear(int(count), ps, length_um=tuple(length_um), **kw)
    if pattern == "POLISH":
        return gen.circular_polish(int(count), ps, **kw)
    if pattern == "HAIRLINE":
        return gen.hairline_brush(int(count), ps, angle_rad=np.radians(angle_deg), **kw)
    raise ValueError(f"unknown scratch pattern {pattern!r}; use one of {sorted(PATTERNS)}")


def merge_sets(a: ScratchSet | None, b: ScratchSet) -> ScratchSet:
    """Union of two sets on the same patch (b's scratch ids shifted after a's), re-indexed."""
    if a is None or a.n_segments == 0:
        return b
    if not np.allclose(a.patch_size_um, b.patch_size_um):
        raise ValueError("scratch sets on different patch sizes cannot be merged")
    shift = int(a.scratch_id.max()) + 1 if a.n_segments else 0
    return make_scratch_set(
        np.concatenate([a.segments, b.segments]),
        np.concatenate([a.width_um, b.width_um]),
        np.concatenate([a.depth_um, b.depth_um]),
        a.patch_size_um,
        scratch_id=np.concatenate([a.scratch_id, b.scratch_id + shift]),
        profile=np.concatenate([a.profile, b.profile]),
        sigma_um=a.sigma_um,
        max_footprint_um=a.query_radius_um - 3.5 * a.sigma_um,
        cell_size_um=a.cell_size_um,
    )


def curves_set(curves_uv, patch_um, width_um, depth_um, sigma_um, seed=0, max_footprint_um=500.0) -> ScratchSet:
    """Scratches along curves given in UV coordinates (one (K, 2) array per curve)."""
    return gen.from_curves(
        [np.asarray(c, dtype=np.float64) for c in curves_uv], patch_um, width_um=tuple(width_um),
        depth_um=tuple(depth_um), uv=True, seed=seed, sigma_um=sigma_um, max_footprint_um=max_footprint_um,
    )


def material_set(mat):
    """(set name, ScratchSet) of a scratched-metal material, or None."""
    group = _set_group(mat)
    return None if group is None else (str(group[PROP]["name"]), load_group_set(group))


def has_scratch_set(mat) -> bool:
    """Whether ``mat`` is a scratched metal holding a set (what :func:`material_set` reads), without reading it: an
    operator's poll runs on every redraw, and reading a 10 000-scratch set took 30 ms there (50 000: 200 ms)."""
    return _set_group(mat) is not None


def _set_group(mat):
    """The node group holding ``mat``'s scratch set (None for a material that is not a scratched metal with one)."""
    node = group_node(mat) if mat is not None and mat.get(MARKER) else None
    group = node.node_tree if node is not None else None
    return group if group is not None and group.get(PROP) is not None else None


def object_scratch_material(obj):
    """The scratched-metal material the operators work on: the object's active material when it is one (the
    material panel's), else its first slot that holds one."""
    if obj is None or obj.type != "MESH":
        return None
    active = obj.active_material
    if active is not None and active.get(MARKER):
        return active
    for slot in obj.material_slots:
        if slot.material is not None and slot.material.get(MARKER):
            return slot.material
    return None
