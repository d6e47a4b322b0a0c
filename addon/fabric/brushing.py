"""Brushing fabric parameter maps in Blender: strokes on packed images through ``core.fabric.brushing``.

A :class:`BrushSession` keeps a material's four maps in memory twice: as core arrays (BTF frame, row 0
= top) and as Blender RGBA pixel buffers (mesh frame, row 0 = bottom). Each stroke segment edits
only the window around its capsule (core functions on a sub-map), writes that window into both
copies and uploads the changed images once (``foreach_set``), so an update of a 2048 x 2048 map
costs a few milliseconds plus the upload. A finished stroke packs what it changed into the .blend and
is one step of Blender's undo (:meth:`BrushSession.end_stroke`): Ctrl+Z, Ctrl+Shift+Z and Edit > Undo
History take strokes back and forth, and the undo handlers (``addon/handlers.py``) reload the images
whose pixels no longer match their packed data and drop the sessions (they hold images the undo
replaced). The sessions of this Blender session are kept by material (``session_uid``: renames do not
matter, :func:`session_for`); the save handler packs them, loading another file drops them.

Materials own their images: a material whose maps another material also reads (Shift+D with a
single-user copy, Make Single User, a material copied in its slot) gets copies of them on its first
stroke (:func:`own_images`), so brushing it never changes the other one.

Fitted closure maps (what world and indirect light see, ``core.fabric.closure_fit``) follow the painted
maps segment by segment: a segment that changes sigma or the basis looks the closures of its changed
texels up in the precomputed table (``core.fabric.closure_table``, multilinear in the fibre geometry,
about 3 us per texel instead of 0.1-0.2 s per distinct geometry for the optimisation), and Blender's undo
restores them with the maps. The closure images are uploaded
with the maps at most every half second during a stroke (eight more 2048 x 2048 uploads per segment
would double an update) and at its end. Colour strokes (k_d, k_s) leave the closures as they are:
the fit is of the k_s = 1 term.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.fabric import brushing as core_brush
from ...core.fabric.closure_table import lookup_closure_texels
from ...core.fabric.parameter_maps import MAP_FILES, FabricMaps, load_params
from ..common import mark_written, push_undo
from .maps import CLOSURE_CHANNELS, CLOSURE_KEYS, WEIGHT_KEYS, btf_quat_to_mesh
from .material import CLOSURE_NODE_PREFIX, complete_closure_images, material_map_images

MODES = ("COMB", "RECOLOR", "SMOOTH", "ANISOTROPY", "DATA_DRIVEN")
CLOSURE_UPLOAD_S = 0.5  # during a stroke the closure images are uploaded at most this often


@dataclass
class BrushSettings:
    mode: str = "COMB"
    radius: float = 0.03  # in UV units (fraction of the map width)
    strength: float = 1.0
    fibre_length: float = 1.2  # pile-height units; limits the tilt (core max_tilt)
    kd: tuple[float, float, float] | None = None
    ks: tuple[float, float, float] | None = None
    smooth_factor: float = 0.8
    anisotropy_factor: float = 0.8
    states: core_brush.BrushStates | None = None


class BrushSession:
    """The maps of one material, ready for strokes. ``images``: kd/ks/sigma/basis Blender images."""

    def __init__(self, images: dict, closures: dict | None = None):
        missing = [k for k in MAP_FILES if k not in images]
        if missing:
            raise ValueError(f"the material has no {', '.join(missing)} map(s): brushing edits parameter maps")
        sizes = {tuple(images[k].size) for k in MAP_FILES}
        if len(sizes) != 1:
            raise ValueError(f"the fabric maps differ in size: {sorted(sizes)}")
        self.images = {k: images[k] for k in MAP_FILES}
        self.width, self.height = sizes.pop()
        h, w = self.height, self.width
        self.buffers: dict[str, np.ndarray] = {}
        self.top: dict[str, np.ndarray] = {}
        for key, (_, c) in MAP_FILES.items():
            buf = np.empty(h * w * 4, dtype=np.float32)
            self.images[key].pixels.foreach_get(buf)
            self.buffers[key] = buf.reshape(h, w, 4)
            top = self.buffers[key][::-1, :, :c].copy()
            if key == "basis":
                top = btf_quat_to_mesh(top)  # the reflection is its own inverse: mesh -> BTF frame
            self.top[key] = top
        self.closures: dict = {}
        self.closure_buffers: dict[str, np.ndarray] = {}
        if closures and set(closures) == set(CLOSURE_KEYS) and all(tuple(closures[k].size) == (w, h) for k in closures):
            self.closures = {k: closures[k] for k in CLOSURE_KEYS}
            for key in CLOSURE_KEYS:
                buf = np.empty(h * w * 4, dtype=np.float32)
                self.closures[key].pixels.foreach_get(buf)
                self.closure_buffers[key] = buf.reshape(h, w, 4)
        self._stroke_changed = False  # the current stroke changed a texel
        self._dirty: set[str] = set()  # changed, not uploaded to the images yet
        self._unpacked: set[str] = set()  # uploaded, not packed into the .blend yet
        self._closure_upload = 0.0  # perf_counter of the last closure upload

    # -- coordinates -------------------------------------------------------------------------
    def uv_to_pixel(self, uv) -> np.ndarray:
        """UV (v up) -> map pixel coordinates (x = column, y = row from the top), as core expects."""
        uv = np.asarray(uv, dtype=np.float64)
        return np.stack([uv[..., 0] * self.width, (1.0 - uv[..., 1]) * self.height], axis=-1)

    def maps(self) -> FabricMaps:
        """The current maps as core arrays (BTF frame, row 0 = top); shares memory with the session."""
        return FabricMaps(self.top["kd"], self.top["ks"], self.top["sigma"], self.top["basis"])

    # -- strokes -----------------------------------------------------------------------------
    def begin_stroke(self) -> None:
        self._stroke_changed = False

    def end_stroke(self) -> bool:
        """Close the stroke: upload and pack what it changed (saving is safe after it) and make it one step of
        Blender's undo. Returns whether the stroke changed any texel (a stroke that did not makes no step)."""
        changed = self._stroke_changed
        self._stroke_changed = False
        self.flush(closures=True)
        self.pack()
        if changed:
            push_undo("Fabric Stroke")
        return changed

    def segment(self, uv0, uv1, settings: BrushSettings, pressure: float = 1.0) -> bool:
        """Apply one stroke segment from ``uv0`` to ``uv1``; returns whether any texel changed."""
        p0, p1 = self.uv_to_pixel(uv0), self.uv_to_pixel(uv1)
        radius = max(settings.radius * self.width, 0.5)
        strength = float(np.clip(settings.strength * pressure, 0.0, 1.0))
        if strength <= 0.0:
            return False
        r0, r1, c0, c1 = self._window(p0, p1, radius, settings)
        if r0 >= r1 or c0 >= c1:
            return False
        sub = FabricMaps(*(self.top[k][r0:r1, c0:c1] for k in MAP_FILES))
        off = np.array([c0, r0], dtype=np.float64)
        q0, q1 = p0 - off, p1 - off
        mode = settings.mode
        if mode == "COMB":
            new = core_brush.brush_fibres(sub, q0, q1, radius, strength, settings.fibre_length)
        elif mode == "RECOLOR":
            new = core_brush.brush_edit(sub, q0, q1, radius, strength, kd=settings.kd, ks=settings.ks)
        elif mode == "SMOOTH":
            new = core_brush.brush_edit(sub, q0, q1, radius, strength, smooth_factor=settings.smooth_factor)
        elif mode == "ANISOTROPY":
            new = core_brush.brush_edit(sub, q0, q1, radius, strength, anisotropy_factor=settings.anisotropy_factor)
        elif mode == "DATA_DRIVEN":
            if settings.states is None:
                raise ValueError("the data-driven brush needs the 8 brushing states (a states folder)")
            new = core_brush.brush_data_driven(sub, q0, q1, radius, settings.states, strength)
        else:
            raise ValueError(f"unknown brush mode {mode!r}; one of {MODES}")
        changed = False
        fibres = np.zeros((r1 - r0, c1 - c0), dtype=bool)
        for key, (_, c) in MAP_FILES.items():
            old_sub, new_sub = getattr(sub, key), getattr(new, key)
            if new_sub is old_sub:
                continue
            new_sub = np.asarray(new_sub, dtype=np.float32)
            if key in ("sigma", "basis") and self.closures:
                fibres |= np.any(new_sub != old_sub, axis=-1)
            self._write(key, r0, r1, c0, c1, new_sub, c)
            changed = self._stroke_changed = True
        if fibres.any():
            self._refit_window(r0, r1, c0, c1, fibres)
        return changed

    def _refit_window(self, r0, r1, c0, c1, mask) -> None:
        """Closures of the window's texels in ``mask`` (rows from the top) from the table."""
        rows, cols = np.nonzero(mask)
        rows, cols = rows + r0, cols + c0
        wts, shp, scl = lookup_closure_texels(self.top["sigma"][rows, cols], self.top["basis"][rows, cols])
        new = {key: wts[:, j, :] for j, key in enumerate(WEIGHT_KEYS)}
        new["shape"], new["shape2"], new["ggx_scale"] = shp[:, :4], shp[:, 4:6], scl
        for key in CLOSURE_KEYS:
            self._closure_write(key, rows, cols, new[key])

    def _closure_write(self, key, rows, cols, values) -> None:
        """Write closure values of texels (rows from the top)."""
        self.closure_buffers[key][self.height - 1 - rows, cols, :CLOSURE_CHANNELS[key]] = values
        self._dirty.add("fit " + key)

    def _window(self, p0, p1, radius, settings):
        lo = np.floor(np.minimum(p0, p1) - radius - 1).astype(int)
        hi = np.ceil(np.maximum(p0, p1) + radius + 1).astype(int)
        c0, r0 = max(lo[0], 0), max(lo[1], 0)
        c1, r1 = min(hi[0], self.width), min(hi[1], self.height)
        if settings.mode == "DATA_DRIVEN" and settings.states is not None:
            th, tw = settings.states.states[0].shape  # align to the state tiles (they tile from 0, 0)
            c0, r0 = c0 - c0 % tw, r0 - r0 % th
        return r0, r1, c0, c1

    def _write(self, key, r0, r1, c0, c1, values, c) -> None:
        self.top[key][r0:r1, c0:c1] = values
        mesh = btf_quat_to_mesh(values) if key == "basis" else values
        h = self.height
        self.buffers[key][h - r1 : h - r0, c0:c1, :c] = mesh[::-1]
        self._dirty.add(key)

    def flush(self, closures: bool | None = None) -> None:
        """Upload the changed images to Blender (what the viewport and renders see). The eight closure
        images (about 10 ms each at 2048 x 2048) go up with the maps at most every
        ``CLOSURE_UPLOAD_S`` during a stroke, and always when ``closures`` is True (stroke end, undo)."""
        now = time.perf_counter()
        if closures is None:
            closures = now - self._closure_upload >= CLOSURE_UPLOAD_S
        keys = sorted(k for k in self._dirty if closures or not k.startswith("fit "))
        for key in keys:
            image = self._image(key)
            image.pixels.foreach_set(self._buffer(key).ravel())
            image.update()
        if closures and any(k.startswith("fit ") for k in keys):
            self._closure_upload = now
        self._unpacked |= set(keys)
        self._dirty -= set(keys)

    def pack(self) -> None:
        """Store the uploaded pixels of the changed maps in the .blend (packed images): what save,
        autosave and undo keep. About 0.15 s per 2048 x 2048 map, so once per stroke, not per segment."""
        for key in sorted(self._unpacked):
            image = self._image(key)
            image.pack()
            mark_written(image)
        self._unpacked.clear()

    def valid(self) -> bool:
        """Whether every image of the session still exists (an undo or a deletion removes them)."""
        try:
            for image in (*self.images.values(), *self.closures.values()):
                image.name  # noqa: B018 (raises ReferenceError for a removed image)
        except ReferenceError:
            return False
        return True

    def _image(self, key):
        return self.closures[key[4:]] if key.startswith("fit ") else self.images[key]

    def _buffer(self, key):
        return self.closure_buffers[key[4:]] if key.startswith("fit ") else self.buffers[key]


_SESSIONS: dict[int, BrushSession] = {}  # material session_uid -> its brush session, for this Blender session


def own_images(mat) -> int:
    """Give ``mat`` its own copy of every map and closure image another material also reads (copy on first
    edit: a Shift+D single-user copy, Make Single User, a material copied in its slot). Returns how many
    images it copied. Raises ValueError for a material or image linked from a library (read-only here)."""
    if mat.library is not None:
        raise ValueError(f"'{mat.name}' is linked from a library: make it local (Object > Relations > Make "
                         "Local) to brush it")
    nodes = [n for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image is not None
             and (n.name.startswith("map_") or n.name.startswith(CLOSURE_NODE_PREFIX))]
    mine = {n.image.name for n in nodes}
    shared = set()
    for other in bpy.data.materials:
        if other == mat or other.node_tree is None:
            continue
        for node in other.node_tree.nodes:
            if node.type == "TEX_IMAGE" and node.image is not None and node.image.name in mine:
                shared.add(node.image.name)
    copies: dict[str, object] = {}
    for node in nodes:
        image = node.image
        if image.library is not None or image.name in shared:
            if image.name not in copies:
                copy = image.copy()
                if copy.packed_file is None:
                    copy.pack()
                copies[image.name] = copy
            node.image = copies[image.name]
    return len(copies)


def session_for(mat) -> BrushSession:
    """The brush session of ``mat`` (rebuilt when its images changed), its images made its own first."""
    own_images(mat)
    images = material_map_images(mat)
    closures = complete_closure_images(mat)
    session = _SESSIONS.get(mat.session_uid)
    if session is not None and session.valid():
        same = all(session.images.get(k) == images.get(k) for k in session.images) and all(
            tuple(images[k].size) == (session.width, session.height) for k in images
        ) and all(session.closures.get(k) == closures.get(k) for k in set(session.closures) | set(closures))
        if same:
            return session
    session = BrushSession(images, closures)
    _SESSIONS[mat.session_uid] = session
    return session


def open_session(mat) -> BrushSession | None:
    """The session of ``mat`` if one was opened and is still valid (None otherwise)."""
    if mat is None:
        return None
    session = _SESSIONS.get(mat.session_uid)
    return session if session is not None and session.valid() else None


def drop_sessions() -> None:
    _SESSIONS.clear()


def pack_sessions() -> None:
    """Upload and pack whatever the brush sessions changed and have not packed yet."""
    for uid, session in list(_SESSIONS.items()):
        if not session.valid():
            del _SESSIONS[uid]
            continue
        session.flush(closures=True)
        session.pack()


def load_brush_states(folder: str) -> core_brush.BrushStates:
    """The data-driven mode's 8 states from ``folder/state_0`` ... ``folder/state_7`` (fit folders,
    brushed toward k * 45 degrees)."""
    states = []
    for k in range(8):
        path = os.path.join(folder, f"state_{k}")
        if not os.path.isdir(path):
            raise FileNotFoundError(f"brushing state folder missing: {path} (need state_0 ... state_7)")
        states.append(load_params(path))
    return core_brush.BrushStates(tuple(states))
