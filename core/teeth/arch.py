"""Dental arches of anatomical teeth (``anatomy``) with scalloped gums and an oral-cavity dome.

Pure numpy/scipy. Scene space: millimetres, x towards the patient's right, y out of the mouth (towards a
frontal camera), z up; upper crowns point down (incisal edges at z = ``upper_edge``), lower crowns up.

* **arch**: the labial surfaces of the crowns follow the parabola y = y0 - k x^2 (``k`` 0.0275 / mm for
  the upper, 0.034 / mm for the lower arch: canine cusp tips 31.7 / 24.2 mm apart, adults about 34 / 26
  mm; the front teeth span 48.7 / 40.5 mm); each tooth is
  placed along it with its mesiodistal axis on the tangent, labial crown inclination and mesial crown tip
  of its ``ToothSpec`` and its incisal edge / cusp tip on the smile line (``edge_level``); neighbours are
  slid together until their enamel is ``gap`` mm apart at the contact areas (the central incisors meet at
  the midline). The patient's right side (x > 0) is placed, the left side is its mirror image.
* **gums**: one closed volume per jaw, swept along the arch: the labial face lies ``thickness`` mm outside
  the teeth's labial envelope (thin at the margin, thicker over the roots: root eminences), the palatal /
  lingual face behind the teeth; the **gingival margin** follows each tooth's CEJ ``margin_above_cej`` mm
  crownward (the scalloped gum line, zenith at the labial centre) and rises between the teeth into
  pointed **interdental papillae** where the neighbouring scallops meet (near the contact areas). The teeth
  are cut out of it (``gums_around_teeth``): no root lies inside the gums' volume, every renderer sees the same
  media (Cycles sums the media where volumes overlap; this project's tracer and Mitsuba take the medium of the
  last surface crossed).
* **oral cavity**: an opaque half-ellipsoid dome behind the teeth (Sec. 5.5.3's diffuse proxy), open at
  the front.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import UserError
from .anatomy import SPECS, ToothSpec, cej_line, tooth_from_spec
from .mesh import TriMesh
from .tooth_from_surface import vertex_normals
from .tooth_mesh import ToothGeometry

UPPER_FRONT = ("upper_central", "upper_lateral", "upper_canine", "upper_premolar")
LOWER_FRONT = ("lower_central", "lower_lateral", "lower_canine", "lower_premolar")
SIDE_NAMES = {1: "right", -1: "left"}  # x > 0: the patient's right (on the left of a frontal camera's image)


@dataclass
class PlacedTooth:
    """One tooth of an arch: its template, side (+1 patient's right, x > 0), 4 x 4 placement of canonical tooth
    space into the scene (a reflection on the mirrored side) and the placed geometry."""

    template: str
    side: int
    matrix: np.ndarray
    geometry: ToothGeometry

    @property
    def name(self) -> str:
        jaw, kind = self.template.split("_", 1)
        return f"{jaw}-{SIDE_NAMES[self.side]}-{kind}"

    @property
    def spec(self) -> ToothSpec:
        return SPECS[self.template]

    def cej(self, n: int = 96) -> np.ndarray:
        """The CEJ line in scene space."""
        p = cej_line(self.spec, n)
        return p @ self.matrix[:3, :3].T + self.matrix[:3, 3]


@dataclass
class Arch:
    """A parabolic arch y = y0 - k x^2 parameterised by arc length s (s = 0 at x = 0, s > 0 for x > 0)."""

    k: float
    y0: float = 0.0
    x_max: float = 60.0

    def __post_init__(self) -> None:
        x = np.linspace(-self.x_max, self.x_max, 24001)
        y = self.y0 - self.k * x * x
        seg = np.hypot(np.diff(x), np.diff(y))
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self._x, self._y = x, y
        self._s = s - np.interp(0.0, x, s)
        self._tree = cKDTree(np.stack([x, y], axis=1))

    def point(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=np.float64)
        return np.stack([np.interp(s, self._s, self._x), np.interp(s, self._s, self._y)], axis=-1)

    def frame(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Unit tangent (towards +x) and outward (labial) normal at arc length s, in the xy plane."""
        x = np.interp(np.asarray(s, dtype=np.float64), self._s, self._x)
        t = np.stack([np.ones_like(x), -2.0 * self.k * x], axis=-1)
        t /= np.linalg.norm(t, axis=-1, keepdims=True)
        n = np.stack([-t[..., 1], t[..., 0]], axis=-1)
        return t, n

    def coords(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, n): arc length of the nearest arch point and signed labial offset of scene points (xy)."""
        _, i = self._tree.query(p[:, :2])
        s = self._s[i]
        q = self.point(s)
        _, n = self.frame(s)
        return s, np.einsum("ij,ij->i", p[:, :2] - q, n)


def _rot(axis: int, deg: float) -> np.ndarray:
    r = np.radians(deg)
    c, s = np.cos(r), np.sin(r)
    m = np.eye(4)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def place_geometry(geo: ToothGeometry, matrix: np.ndarray) -> ToothGeometry:
    """``geo`` mapped by ``matrix``; a reflection (negative determinant) reverses the faces' winding so the
    normals keep pointing outwards."""
    out = geo.transformed(matrix)
    if np.linalg.det(matrix[:3, :3]) < 0:
        e, b = out.enamel, out.dentin.base
        out.enamel = TriMesh(e.vertices, e.faces[:, [0, 2, 1]],
                             None if e.corner_uv is None else e.corner_uv[:, [0, 2, 1]])
        out.dentin.base = TriMesh(b.vertices, b.faces[:, [0, 2, 1]],
                                  None if b.corner_uv is None else b.corner_uv[:, [0, 2, 1]])
    return out


def _tooth_matrix(spec: ToothSpec, canon: np.ndarray, arch: Arch, s: float, jaw_sign: float,
                  edge_z: float) -> np.ndarray:
    """Placement of canonical tooth space at arc length s (patient's right side, x > 0)."""
    incl = _rot(0, -spec.inclination) @ _rot(1, spec.tip)  # crown tipped labially, then mesially
    v = canon @ incl[:3, :3].T
    crown = v[(canon[:, 2] > 0.3 * spec.crown) & (canon[:, 2] < 0.8 * spec.crown)]
    y_lab = crown[:, 1].max()
    top = v[:, 2].max()
    t, n = arch.frame(s)
    p = arch.point(s)
    frame = np.eye(4)
    frame[:3, 0] = [-t[0], -t[1], 0.0]  # tooth +x (mesial) points to the midline
    frame[:3, 1] = [n[0], n[1], 0.0]
    frame[:3, 2] = [0.0, 0.0, -jaw_sign]  # upper (jaw_sign 1): crown down
    origin = np.array([p[0], p[1], 0.0]) - y_lab * frame[:3, 1]
    origin[2] = edge_z + jaw_sign * top  # the incisal edge / cusp tip on the smile line
    frame[:3, 3] = origin
    return frame @ incl


def build_arch(jaw: str = "upper", templates: tuple | None = None, resolution: int = 48, gap: float = 0.3,
               edge_z: float = 0.0, k: float | None = None, y0: float = 0.0) -> tuple[list[PlacedTooth], Arch]:
    """The front teeth of ``jaw`` ("upper"/"lower"), both sides, on a parabolic arch (see the module doc).
    ``templates`` run from the midline outwards (default: central, lateral, canine, first premolar);
    ``gap``: enamel-to-enamel distance at the contact areas (mm, measured between vertices of a
    resolution-64 copy)."""
    if jaw not in ("upper", "lower"):
        raise UserError(f"jaw must be 'upper' or 'lower', got {jaw!r}")
    templates = templates or (UPPER_FRONT if jaw == "upper" else LOWER_FRONT)
    arch = Arch(k if k is not None else (0.0275 if jaw == "upper" else 0.034), y0)
    jaw_sign = 1.0 if jaw == "upper" else -1.0
    placed: list[PlacedTooth] = []
    prev_tree = None
    s = 0.0
    for name in templates:
        spec = SPECS[name]
        if spec.jaw != jaw:
            raise UserError(f"template {name!r} is not a tooth of the {jaw} jaw")
        canon = tooth_from_spec(spec, 64).enamel.vertices
        z_edge = edge_z + jaw_sign * spec.edge_level

        def verts(s_, canon=canon, spec=spec, z_edge=z_edge):
            m = _tooth_matrix(spec, canon, arch, s_, jaw_sign, z_edge)
            return canon @ m[:3, :3].T + m[:3, 3], m

        if prev_tree is None:  # central incisor: its mesial surface gap / 2 from the midline plane
            lo, hi = 0.0, spec.width
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if verts(mid)[0][:, 0].min() < 0.5 * gap else (lo, mid)
            s = hi
        else:  # slide in from the distal side until the enamel is `gap` from the previous tooth
            def clearance(s_, tree=prev_tree, verts=verts):
                return tree.query(verts(s_)[0])[0].min()

            hi = s + spec.width + 4.0
            lo = hi - 0.5
            while lo > s and clearance(lo) >= gap:  # coarse steps inwards, then bisection
                hi, lo = lo, lo - 0.5
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if clearance(mid) < gap else (lo, mid)
            s = hi
        v, m = verts(s)
        prev_tree = cKDTree(v)
        placed.append(PlacedTooth(name, 1, m, place_geometry(tooth_from_spec(spec, resolution), m)))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirrored = [PlacedTooth(p.template, -1, mirror @ p.matrix, place_geometry(p.geometry, mirror)) for p in placed]
    return mirrored[::-1] + placed, arch  # from the patient's left (x < 0) to the right


# -- gums -------------------------------------------------------------------------------------------

def margin_curve(teeth: list[PlacedTooth], arch: Arch, s: np.ndarray, margin_above_cej: float = 1.0,
                 papilla_extra: float = 1.8, ramp: float = 0.75) -> np.ndarray:
    """Scene z of the gingival margin along the arch (arc lengths ``s``). Each tooth's scallop is the labial
    half of its CEJ moved ``margin_above_cej`` mm crownward (zenith at the labial centre); past the
    proximal ends of the CEJ it keeps falling crownward (``papilla_extra`` mm over ``ramp`` mm, then
    steeply). The margin is the gum-side-most of the scallops, so neighbouring scallops meet in a pointed
    interdental papilla."""
    jaw_sign = 1.0 if teeth[0].spec.jaw == "upper" else -1.0
    g = np.full(len(s), -np.inf)  # gum-side height g = jaw_sign z (larger: further from the crowns)
    ends = []
    for t in teeth:
        cej = t.cej(192)
        sc, nc = arch.coords(cej)
        lab = nc > np.median(nc)  # the labial half of the CEJ ring
        order = np.argsort(sc[lab])
        s_l, g_l = sc[lab][order], jaw_sign * cej[lab, 2][order] - margin_above_cej
        lo, hi = s_l[0], s_l[-1]
        inside = np.interp(s, s_l, g_l)
        dist = np.where(s < lo, lo - s, np.where(s > hi, s - hi, 0.0))
        end_g = np.where(s < lo, g_l[0], g_l[-1])
        outside = end_g - papilla_extra * np.minimum(dist / ramp, 1.0) - 6.0 * np.maximum(dist - ramp, 0.0)
        g = np.maximum(g, np.where(dist > 0, outside, inside))
        ends += [g_l[0], g_l[-1]]
    g = np.maximum(g, min(ends) - papilla_extra)  # beyond the last teeth: level
    return jaw_sign * g


def _envelope(points_sn_z: np.ndarray, s_grid: np.ndarray, z_grid: np.ndarray, outward: bool) -> np.ndarray:
    """Max (or min) labial offset n of points per (s, z) cell, holes filled and smoothed."""
    from scipy.ndimage import gaussian_filter, maximum_filter, minimum_filter

    s, n, z = points_sn_z.T
    ds, dz = s_grid[1] - s_grid[0], z_grid[1] - z_grid[0]
    i = np.clip(np.round((s - s_grid[0]) / ds).astype(int), 0, len(s_grid) - 1)
    j = np.clip(np.round((z - z_grid[0]) / dz).astype(int), 0, len(z_grid) - 1)
    sign = 1.0 if outward else -1.0
    env = np.full((len(s_grid), len(z_grid)), -np.inf)
    np.maximum.at(env, (i, j), sign * n)
    filled = np.isfinite(env)
    for jj in range(len(z_grid)):  # fill along s
        col = filled[:, jj]
        if col.sum() >= 2:
            env[:, jj] = np.interp(s_grid, s_grid[col], env[col, jj])
    rows = np.where(np.isfinite(env).all(axis=0))[0]
    for jj in range(len(z_grid)):  # rows without data: the nearest row with data
        if not np.isfinite(env[:, jj]).all():
            env[:, jj] = env[:, rows[np.argmin(np.abs(rows - jj))]]
    env = maximum_filter(env, size=(5, 3))
    env = gaussian_filter(env, sigma=(4.0, 4.0), mode="nearest")
    del minimum_filter
    return sign * env


def gum_mesh(teeth: list[PlacedTooth], arch: Arch, margin_above_cej: float = 1.0, extend: float = 6.0,
             height: float | None = None, n_s: int = 240) -> TriMesh:
    """Closed gum volume of one jaw (module doc): swept along the arch, labial face over the teeth's labial
    envelope (0.6 mm at the margin, 1.6 mm over the roots), lingual face behind the teeth, scalloped
    margin with papillae (``margin_curve``). UVs: u along the arch, v around the cross-section."""
    jaw_sign = 1.0 if teeth[0].spec.jaw == "upper" else -1.0  # +1: the gum lies at +z of the margin
    allv = np.concatenate([t.geometry.enamel.vertices for t in teeth])
    s_v, n_v = arch.coords(allv)
    s_lo, s_hi = s_v.min() - extend, s_v.max() + extend
    s = np.linspace(s_lo, s_hi, n_s)
    zm = margin_curve(teeth, arch, s, margin_above_cej)
    apex = jaw_sign * (allv[:, 2] * jaw_sign).max()
    top = apex + jaw_sign * 2.0 if height is None else zm.mean() + jaw_sign * height
    # envelope grids in "gum-side height" g = jaw_sign * z
    g_lo, g_hi = (jaw_sign * zm).min() - 1.0, jaw_sign * top + 1.0
    g_grid = np.linspace(g_lo, g_hi, int((g_hi - g_lo) / 0.5) + 1)
    s_grid = np.linspace(s_lo, s_hi, int((s_hi - s_lo) / 0.4) + 1)
    pts = np.stack([s_v, n_v, jaw_sign * allv[:, 2]], axis=1)
    lab = _envelope(pts, s_grid, g_grid, True)
    pal = _envelope(pts, s_grid, g_grid, False)
    from scipy.interpolate import RegularGridInterpolator

    f_lab = RegularGridInterpolator((s_grid, g_grid), lab, bounds_error=False, fill_value=None)
    f_pal = RegularGridInterpolator((s_grid, g_grid), pal, bounds_error=False, fill_value=None)
    gm = jaw_sign * zm  # margin, gum-side height
    gt = jaw_sign * top
    n_face, n_round, n_top, n_bottom = 16, 5, 8, 6
    loops = []
    for k in range(n_s):
        g_face = gm[k] + (gt - gm[k]) * (np.linspace(0.0, 1.0, n_face) ** 1.6)
        d = g_face - gm[k]
        thick = 0.6 + 1.0 * np.clip(d / 3.0, 0.0, 1.0) ** 1.5
        nl = f_lab(np.stack([np.full(n_face, s[k]), g_face], axis=1)) + thick
        # rounded margin: a quarter circle of radius r from the labial face into the tooth
        r = 0.45
        th = np.linspace(0.0, 0.5 * np.pi, n_round + 1)[1:]
        n0 = nl[0]
        rnd_n = n0 - r + r * np.cos(th)
        rnd_g = gm[k] + r - r * np.sin(th)
        labial = np.concatenate([np.stack([rnd_n[::-1], rnd_g[::-1]], 1), np.stack([nl, g_face], 1)])
        labial[:n_round, 1] = np.maximum(labial[:n_round, 1], gm[k])
        npal = f_pal(np.stack([np.full(n_face, s[k]), g_face], axis=1)).min() - 1.2
        # over the top, from labial to palatal (a rounded vestibule-to-palate roof)
        tt = np.linspace(0.0, 1.0, n_top + 2)[1:-1]
        top_n = nl[-1] + (npal - nl[-1]) * tt
        top_g = gt + 1.5 * np.sin(np.pi * tt)
        palatal_g = g_face[::-1]
        palatal = np.stack([np.full(n_face, npal), palatal_g], 1)
        # bottom, from palatal margin back to the margin's inner end
        bb = np.linspace(0.0, 1.0, n_bottom + 2)[1:-1]
        bot_n = npal + (labial[0, 0] - npal) * bb
        bottom = np.stack([bot_n, np.full(n_bottom, gm[k])], 1)
        loop = np.concatenate([labial, np.stack([top_n, top_g], 1), palatal, bottom])
        loops.append(loop)
    loops = np.array(loops)  # (n_s, M, 2): (n, g)
    m = loops.shape[1]
    p = arch.point(s)
    _, nrm = arch.frame(s)
    xy = p[:, None, :] + loops[..., 0:1] * nrm[:, None, :]
    z = jaw_sign * loops[..., 1]
    verts = np.concatenate([xy, z[..., None]], axis=-1).reshape(-1, 3)
    idx = np.arange(n_s * m).reshape(n_s, m)
    faces, uvs = [], []
    for i in range(n_s - 1):
        u0, u1 = i / (n_s - 1), (i + 1) / (n_s - 1)
        for j in range(m):
            j1 = (j + 1) % m
            v0, v1 = j / m, (j + 1) / m
            a0, a1, b0, b1 = idx[i, j], idx[i, j1], idx[i + 1, j], idx[i + 1, j1]
            faces += [(a0, b0, b1), (a0, b1, a1)]
            uvs += [((u0, v0), (u1, v0), (u1, v1)), ((u0, v0), (u1, v1), (u0, v1))]
    caps = []
    for i, rev in ((0, True), (n_s - 1, False)):
        c = len(verts) + len(caps)
        caps.append(verts[idx[i]].mean(axis=0))
        for j in range(m):
            tri = (c, idx[i, j], idx[i, (j + 1) % m])
            faces.append(tri if rev else (tri[0], tri[2], tri[1]))
            uvs.append(((0.5, 0.5), (0.5, 0.5), (0.5, 0.5)))
    v_all = np.concatenate([verts, np.array(caps)])
    f = np.array(faces, dtype=np.int64)
    uv = np.array(uvs, dtype=np.float64)
    mesh = TriMesh(v_all, f, uv)
    if mesh.volume() < 0:
        mesh = TriMesh(v_all, f[:, [0, 2, 1]], uv[:, [0, 2, 1]])
    return gums_around_teeth(mesh, [t.geometry.enamel for t in teeth])


GUM_GAP_MM = 0.05  # the teeth are cut out of the gums this far beyond their enamel: a film of air about 500 x the
# tracer's ray offset (ray_queries.RAY_EPS) and a sixth of a smile capture's pixel, so no renderer confuses the
# two surfaces


def gums_around_teeth(gums: TriMesh, enamels: list[TriMesh], gap: float = GUM_GAP_MM) -> TriMesh:
    """The closed ``gums`` volume less every tooth (its enamel surface moved ``gap`` mm outwards along the vertex
    normals): the roots sit in holes of the gums instead of inside their medium. A mesh boolean (manifold3d, exact
    on closed meshes). The gums' per-corner UVs carry over (interpolated where a face was cut); the holes' walls get
    UV (0.5, 0.5), as the sweep's end caps."""
    import manifold3d

    if gums.corner_uv is None:
        raise ValueError("the gums need per-corner UVs")
    # manifold3d keeps properties per vertex: one property vertex per distinct (vertex, UV) corner, and the ones
    # that share a position declared merged, so the seams stay closed
    corners = gums.faces.reshape(-1)
    keys = np.concatenate([corners[:, None].astype(np.float64), gums.corner_uv.reshape(-1, 2)], axis=1)
    unique, tri = np.unique(keys, axis=0, return_inverse=True)
    vid = unique[:, 0].astype(np.int64)
    first = np.empty(len(gums.vertices), dtype=np.int64)
    _, first_of = np.unique(vid, return_index=True)
    first[vid[first_of]] = first_of
    dup = np.flatnonzero(first[vid] != np.arange(len(vid)))
    body = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(np.concatenate([gums.vertices[vid], unique[:, 1:]], axis=1)),
        tri_verts=tri.reshape(-1, 3).astype(np.uint64), merge_from_vert=dup.astype(np.uint64),
        merge_to_vert=first[vid[dup]].astype(np.uint64)))
    holes = []
    for enamel in enamels:
        grown = enamel.vertices + gap * vertex_normals(enamel.vertices, enamel.faces)
        props = np.concatenate([grown, np.full((len(grown), 2), 0.5)], axis=1)
        holes.append(manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(props),
                                                           tri_verts=enamel.faces.astype(np.uint64))))
    for part in [body, *holes]:
        if part.status() != manifold3d.Error.NoError:
            raise ValueError(f"cutting the teeth out of the gums: a mesh is not closed ({part.status()})")
    out = (body - manifold3d.Manifold.batch_boolean(holes, manifold3d.OpType.Add)).to_mesh64()
    props = np.asarray(out.vert_properties)
    faces = np.asarray(out.tri_verts).astype(np.int64)
    position = np.arange(len(props))  # property vertex -> the one that holds its position
    position[np.asarray(out.merge_from_vert).astype(np.int64)] = np.asarray(out.merge_to_vert).astype(np.int64)
    kept, vertex_of = np.unique(position, return_inverse=True)
    return TriMesh(props[kept, :3], vertex_of[faces], props[faces, 3:5])


def cavity_dome(rx: float = 46.0, ry: float = 34.0, rz: float = 34.0, centre=(0.0, -8.0, -2.0),
                y_front: float = 1.0, n: int = 48) -> TriMesh:
    """Half-ellipsoid dome behind the teeth, open at y > ``y_front``, normals facing inwards (a diffuse
    oral-cavity proxy, Sec. 5.5.3)."""
    c = np.asarray(centre, dtype=np.float64)
    th = np.linspace(0.0, np.pi, n + 1)  # polar angle from -y (the back) ...
    ph = np.linspace(0.0, 2.0 * np.pi, 2 * n, endpoint=False)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(tt) * np.cos(pp), -np.cos(tt), np.sin(tt) * np.sin(pp)], axis=-1)
    v = c + d * np.array([rx, ry, rz])
    keep_rows = np.where(v[:, 0, 1] < y_front)[0]
    v = v[keep_rows]
    rows, cols = v.shape[:2]
    verts = np.concatenate([[c + np.array([0.0, -ry, 0.0])], v[1:].reshape(-1, 3)])
    idx = np.concatenate([[0], np.arange(1, (rows - 1) * cols + 1)])
    faces = []
    for j in range(cols):
        faces.append((0, 1 + j, 1 + (j + 1) % cols))
    for r in range(rows - 2):
        for j in range(cols):
            a0, a1 = 1 + r * cols + j, 1 + r * cols + (j + 1) % cols
            b0, b1 = a0 + cols, a1 + cols
            faces += [(a0, b0, b1), (a0, b1, a1)]
    del idx
    f = np.array(faces, dtype=np.int64)
    mesh = TriMesh(verts, f)
    # inward normals: the face normals point towards the centre
    t = mesh.triangles()
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    if np.mean(np.einsum("ij,ij->i", nrm, c - t.mean(axis=1))) < 0:
        mesh = TriMesh(verts, f[:, [0, 2, 1]])
    return mesh


def merge_meshes(meshes: list[TriMesh]) -> TriMesh:
    """One TriMesh holding several (disjoint) meshes; per-corner UVs kept (zeros where a part has none)."""
    verts, faces, uvs, off = [], [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + off)
        uvs.append(m.corner_uv if m.corner_uv is not None else np.zeros((len(m.faces), 3, 2)))
        off += len(m.vertices)
    return TriMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(uvs))
