"""Anatomical tooth meshes (dental-atlas crowns and roots) for showcases and the add-on's Add Tooth.

Pure numpy. Each tooth is a closed, watertight enamel surface plus a dentin core B0 with the three
blend-shape modes of eq. 5.5 (``canonical_modes``), in the canonical tooth space of ``tooth_mesh``:
x mesiodistal (+x mesial), y labiolingual (+y labial/buccal), z along the tooth axis with the
cemento-enamel junction (CEJ) at z = 0 on the labial side and the crown above it. Millimetres.

Features (named as a dental atlas names them; the numbers are the table rows of ``SPECS``, typical
adult sizes after Wheeler's / Ash & Nelson's tables):

* **crown outline, labial view**: the mesiodistal half-widths flare from the **cervical width** at the
  CEJ (the **cervical constriction**, narrower than the crown) to the full ``width`` at the mesial and
  distal **contact areas** (``contact_mesial`` / ``contact_distal``, fractions of the crown height);
  above them the outline rounds into the **incisal angles** (sharper mesially, rounder distally).
* **proximal profile**: a convex **labial surface** (``1 - u^1.6``) whose height of contour sits in
  the cervical third; on the lingual side the **cingulum** (lingual height of contour) and a concave
  **lingual fossa** running up to the incisal edge.
* **incisal edge** (incisors): a straight, thin edge (``edge_thickness``, rounded with that radius)
  closed by zipping the two faces together; **canine cusp**: the edge rises to a cusp tip with a shorter
  mesial and a longer distal cusp ridge; **premolar**: a **buccal and a lingual cusp** (the lingual one
  ``lingual_cusp_drop`` shorter), **mesial and distal marginal ridges**, the cusps' triangular ridges
  falling to the **central groove** and **central fossa** (``fossa_depth`` below the buccal cusp tip).
* **CEJ**: a scalloped line that curves crownward on the proximal sides by ``cej_mesial`` /
  ``cej_distal`` (3.5 / 2.5 mm on a central incisor).
* **root**: tapering from the cervical cross-section to the apex, ``root`` mm below the CEJ.
* **dentin core**: the crown's inset (enamel ``enamel_labial`` / ``enamel_proximal`` mm thick at
  mid-crown, thinning to ``enamel_cervical`` at the CEJ) that stops ``incisal_enamel`` short of the
  incisal edge or cusp tips, so the **incisal third is enamel only** (translucent, thesis Sec. 5.1:
  enamel thicker towards the tip); on incisors the dentin's top carries three **mamelons**. A dentin
  point's mesiodistal and labiolingual offsets from the crown's axis are at most those of the enamel
  point of the same height and azimuth, which keeps it inside the enamel (tested with trimesh).

Surface parameterisation: rows from the top (incisal edge line, or the premolar's central fossa as a
pole) down the crown to the CEJ and the root to the apex (a pole); ``n_u`` azimuthal samples per row
(superellipse cross-sections). UVs: u = azimuth / 2 pi, v = row / rows (0 at the top).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import UserError
from .dentin_blend_shapes import DentinBlendShape, canonical_modes
from .mesh import TriMesh
from .tooth_mesh import ToothGeometry

ANATOMY_KINDS = ("incisor", "canine", "premolar")


@dataclass(frozen=True)
class ToothSpec:
    """Dimensions of one tooth type (mm; ``contact_*`` and ``*_contour`` are fractions of the crown
    height above the labial CEJ). ``inclination`` / ``tip``: labial crown inclination and mesial crown
    tip in the arch (degrees); ``edge_level``: how far the incisal edge / cusp tip sits from the central
    incisors' edges towards the gum (the smile line)."""

    name: str
    kind: str
    jaw: str
    crown: float
    root: float
    width: float
    cervical_width: float
    depth: float
    cervical_depth: float
    cej_mesial: float
    cej_distal: float
    contact_mesial: float
    contact_distal: float
    edge_thickness: float = 1.0
    incisal_enamel: float = 2.5
    labial_contour: float = 0.15
    lingual_contour: float = 0.2
    edge_offset: float = 0.3  # labial position of the incisal edge / cusp line over the axis
    cusp_ridge_drop: tuple = (0.3, 0.45)  # (mesial, distal) drop of the edge ends below the tip
    lingual_cusp_drop: float = 1.0
    fossa_depth: float = 2.6
    enamel_labial: float = 1.0
    enamel_proximal: float = 0.9
    enamel_lingual: float = 0.8
    enamel_cervical: float = 0.3
    inclination: float = 0.0
    tip: float = 0.0
    edge_level: float = 0.0


# Typical adult crown sizes (Wheeler's table): crown height, root length, mesiodistal width at the contact
# areas and at the CEJ, labiolingual depth at the height of contour and at the CEJ, CEJ curvature.
SPECS = {
    "upper_central": ToothSpec("upper central incisor", "incisor", "upper", 10.5, 13.0, 8.5, 7.0, 7.0, 6.0,
                               3.5, 2.5, 0.80, 0.68, 1.0, 2.6, inclination=14.0, tip=5.0, edge_level=0.0),
    "upper_lateral": ToothSpec("upper lateral incisor", "incisor", "upper", 9.0, 13.0, 6.5, 5.0, 6.0, 5.0,
                               3.0, 2.0, 0.75, 0.60, 0.9, 2.2, cusp_ridge_drop=(0.4, 0.8), inclination=11.0,
                               tip=8.0, edge_level=0.9),
    "upper_canine": ToothSpec("upper canine", "canine", "upper", 10.0, 17.0, 7.5, 5.5, 8.0, 7.0, 2.5, 1.5,
                              0.70, 0.55, 1.5, 2.4, labial_contour=0.2, lingual_contour=0.25, edge_offset=0.4,
                              cusp_ridge_drop=(2.0, 2.8), inclination=7.0, tip=10.0, edge_level=0.2),
    "upper_premolar": ToothSpec("upper first premolar", "premolar", "upper", 8.5, 14.0, 7.0, 5.0, 9.0, 8.0,
                                1.0, 0.5, 0.78, 0.72, incisal_enamel=2.0, labial_contour=0.2,
                                lingual_contour=0.5, edge_offset=0.0, cusp_ridge_drop=(1.9, 2.1),
                                lingual_cusp_drop=1.0, fossa_depth=2.6, enamel_labial=1.2, enamel_lingual=1.2,
                                inclination=4.0, tip=3.0, edge_level=0.7),
    "lower_central": ToothSpec("lower central incisor", "incisor", "lower", 9.0, 12.5, 5.0, 3.5, 6.0, 5.3,
                               3.0, 3.0, 0.85, 0.85, 0.8, 2.0, cusp_ridge_drop=(0.2, 0.25), edge_offset=0.2,
                               enamel_labial=0.8, enamel_proximal=0.7, enamel_lingual=0.6, inclination=4.0,
                               tip=1.0, edge_level=0.0),
    "lower_lateral": ToothSpec("lower lateral incisor", "incisor", "lower", 9.5, 14.0, 5.5, 4.0, 6.5, 5.8,
                               3.0, 3.0, 0.85, 0.80, 0.8, 2.0, cusp_ridge_drop=(0.2, 0.35), edge_offset=0.2,
                               enamel_labial=0.8, enamel_proximal=0.7, enamel_lingual=0.6, inclination=4.0,
                               tip=2.0, edge_level=0.0),
    "lower_canine": ToothSpec("lower canine", "canine", "lower", 11.0, 16.0, 7.0, 5.5, 7.5, 7.0, 2.5, 1.0,
                              0.78, 0.62, 1.3, 2.4, labial_contour=0.2, edge_offset=0.3,
                              cusp_ridge_drop=(1.6, 2.4), inclination=3.0, tip=5.0, edge_level=-0.3),
    "lower_premolar": ToothSpec("lower first premolar", "premolar", "lower", 8.5, 14.0, 7.0, 5.0, 7.5, 6.5,
                                1.0, 0.5, 0.75, 0.70, incisal_enamel=2.0, labial_contour=0.25,
                                lingual_contour=0.45, edge_offset=0.0, cusp_ridge_drop=(1.6, 1.9),
                                lingual_cusp_drop=2.0, fossa_depth=3.3, enamel_labial=1.2, enamel_lingual=1.0,
                                inclination=-4.0, tip=2.0, edge_level=-0.8),
}
ANATOMY_TEMPLATES = tuple(SPECS)


def _smoothstep(e0: float, e1: float, x):
    t = np.clip((np.asarray(x, dtype=np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _round_off(h, h0):
    """sqrt(1 - ((h - h0) / (1 - h0))^2) above h0, 1 below: a quarter circle that closes at h = 1."""
    u = np.clip((np.asarray(h, dtype=np.float64) - h0) / np.maximum(1.0 - h0, 1e-9), 0.0, 1.0)
    return np.sqrt(np.maximum(1.0 - u * u, 0.0))


class _Crown:
    """The enamel crown and root of one ``ToothSpec`` as functions of (h, phi): h = 0 at the CEJ, 1 at the
    incisal edge / occlusal outline; the root below uses t = 0 (CEJ) .. 1 (apex)."""

    def __init__(self, spec: ToothSpec, exponent: float = 2.6):
        self.s = spec
        self.e = 2.0 / exponent
        self.a_max = 0.5 * spec.width
        self.a_c = 0.5 * spec.cervical_width
        zip_top = spec.kind != "premolar"
        self.zip_top = zip_top
        # half-length of the incisal edge / cusp line (mesial, distal) and of the premolar's occlusal outline
        if spec.kind == "incisor":
            self.a_edge = (0.93 * self.a_max, 0.84 * self.a_max)
        elif spec.kind == "canine":
            self.a_edge = (0.86 * self.a_max, 0.84 * self.a_max)
        else:
            self.a_edge = (0.80 * self.a_max, 0.80 * self.a_max)
        self.h_round = 1.0 - 0.5 * spec.edge_thickness / spec.crown if zip_top else 1.0

    # -- cross-section directions ---------------------------------------------------------------------
    def dirs(self, phi):
        c, s = np.cos(phi), np.sin(phi)
        cx = np.sign(c) * np.abs(c) ** self.e
        cy = np.sign(s) * np.abs(s) ** self.e
        return cx, cy

    # -- heights --------------------------------------------------------------------------------------
    def cej(self, cx):
        """Height of the CEJ over the meridian with direction cx: curves crownward on the proximal sides."""
        cej = np.where(cx > 0, self.s.cej_mesial, self.s.cej_distal)
        return cej * np.abs(cx) ** 2

    def edge_height(self, x):
        """Incisal edge / cusp-ridge line height at mesiodistal position x (incisor: straight with the
        incisal angles dropping a little; canine and premolar buccal cusp: tip and two cusp ridges)."""
        sp = self.s
        drop_m, drop_d = sp.cusp_ridge_drop
        am, ad = self.a_edge
        u = np.where(x > 0, x / am, -x / ad)
        drop = np.where(x > 0, drop_m, drop_d)
        if sp.kind == "incisor":
            return sp.crown - drop * _smoothstep(0.55, 1.0, u)
        r = 0.35  # rounded cusp tip
        return sp.crown - drop * (np.sqrt(u * u + r * r) - r) / (np.sqrt(1 + r * r) - r)

    def top_height(self, cx, cy):
        """Height where the meridian (cx, cy) ends at the top: the edge line, or the premolar outline."""
        am, ad = self.a_edge
        x = np.where(cx > 0, am, ad) * cx
        z = self.edge_height(x)
        if self.s.kind == "premolar":  # lingual cusp: lower tip, same marginal ridge ends
            lc = self.s.lingual_cusp_drop
            drop_m, drop_d = self.s.cusp_ridge_drop
            end = np.where(cx > 0, drop_m, drop_d)
            zl = self.s.crown - lc - (end - lc) * np.clip(np.abs(cx), 0, 1) ** 1.3
            z = np.where(cy >= 0, z, zl)
        return z

    # -- profiles (h in [0, 1]) ----------------------------------------------------------------------
    def half_width(self, h, mesial):
        """Mesiodistal half-width: cervical constriction -> contact area -> rounded incisal angle."""
        sp = self.s
        hc = np.where(mesial, sp.contact_mesial, sp.contact_distal)
        ae = np.where(mesial, self.a_edge[0], self.a_edge[1])
        lower = self.a_c + (self.a_max - self.a_c) * np.sin(0.5 * np.pi * np.clip(h / hc, 0.0, 1.0)) ** 0.8
        upper = ae + (self.a_max - ae) * _round_off(h, hc)
        return np.where(h <= hc, lower, upper)

    def labial(self, h):
        """y of the labial (buccal) surface: convex, height of contour in the cervical third."""
        sp = self.s
        yc, ym = 0.5 * sp.cervical_depth, 0.5 * sp.depth
        ye = sp.edge_offset + 0.5 * sp.edge_thickness if self.zip_top else 0.5 * sp.depth * 0.5
        hl = sp.labial_contour
        below = yc + (ym - yc) * np.sin(0.5 * np.pi * np.clip(h / hl, 0.0, 1.0))
        u = np.clip((h - hl) / (1.0 - hl), 0.0, 1.0)
        above = ye + (ym - ye) * (1.0 - u ** 1.6)
        return np.where(h <= hl, below, above)

    def lingual(self, h):
        """y of the lingual surface: cingulum (height of contour), then the concave lingual fossa."""
        sp = self.s
        yc, ym = -0.5 * sp.cervical_depth, -0.5 * sp.depth
        ye = sp.edge_offset - 0.5 * sp.edge_thickness if self.zip_top else -0.5 * sp.depth * 0.5
        hl = sp.lingual_contour
        below = yc + (ym - yc) * np.sin(0.5 * np.pi * np.clip(h / hl, 0.0, 1.0))
        u = np.clip((h - hl) / (1.0 - hl), 0.0, 1.0)
        if self.zip_top:
            above = ye + (ym - ye) * (1.0 - u) ** 2  # concave lingual fossa
        else:
            above = ye + (ym - ye) * (1.0 - u ** 1.4)  # premolar: convex lingual cusp
        return np.where(h <= hl, below, above)

    # -- surface points -------------------------------------------------------------------------------
    def crown_point(self, h, phi, inset=None):
        """Crown surface at (h, phi); ``inset`` = (proximal, labial, lingual) thicknesses to remove along the
        segment from the axis (the dentin)."""
        cx, cy = self.dirs(phi)
        z0, z1 = self.cej(cx), self.top_height(cx, cy)
        z = z0 + h * (z1 - z0)
        a = self.half_width(h, cx > 0)
        yl, yg = self.labial(h), self.lingual(h)
        ycen = 0.5 * (yl + yg)
        bl, bg = yl - ycen, ycen - yg
        if self.zip_top:
            rho = _round_off(h, self.h_round)
            bl, bg = bl * rho, bg * rho
        if inset is not None:
            ti, tl, tg = inset
            a = a - np.minimum(ti, 0.6 * a)
            bl = bl - np.minimum(tl, 0.6 * bl)
            bg = bg - np.minimum(tg, 0.6 * bg)
        y = ycen + np.where(cy > 0, bl, bg) * cy
        return np.stack([a * cx, y, z], axis=-1)

    def h_at(self, z, phi):
        """The enamel's h at height z on meridian phi (z is linear in h along a meridian)."""
        cx, cy = self.dirs(phi)
        z0, z1 = self.cej(cx), self.top_height(cx, cy)
        return (z - z0) / (z1 - z0)

    def root_point(self, t, phi, inset: float = 0.0):
        cx, cy = self.dirs(phi)
        sp = self.s
        z = self.cej(cx) * (1.0 - t) ** 2 - sp.root * t
        taper = (1.0 - t ** 1.6) ** 0.7
        a = np.maximum(self.a_c * taper - inset, 0.05)
        yl, yg = self.labial(0.0), self.lingual(0.0)
        ycen = 0.5 * (yl + yg) * (1.0 - t)
        b = np.maximum(0.5 * (yl - yg) * taper - inset, 0.05)
        return np.stack([a * cx, ycen + b * cy, z], axis=-1)

    def premolar_cap(self, s, phi, z_fossa, outline):
        """Occlusal surface over the outline ring ``outline`` (n_u, 3): from the central fossa (s = 0) up the
        cusps' triangular ridges to the cusp ridges and marginal ridges (s = 1)."""
        cx, cy = self.dirs(phi)
        centre = np.array([0.0, 0.0, z_fossa])
        centre[1] = 0.5 * (outline[:, 1].max() + outline[:, 1].min())
        xy = centre[:2] + s[:, None, None] * (outline[None, :, :2] - centre[:2])
        f = s[:, None] ** 1.5
        groove = 0.35 * np.exp(-((xy[..., 1] - centre[1]) / 0.8) ** 2) * (1.0 - s[:, None] ** 2)
        z = z_fossa + (outline[None, :, 2] - z_fossa) * f - groove
        return np.concatenate([xy, z[..., None]], axis=-1), centre


def _rows_cos(n: int) -> np.ndarray:
    """n values in (0, 1) (exclusive), denser at both ends."""
    k = np.arange(1, n + 1) / (n + 1)
    return 0.5 * (1.0 - np.cos(np.pi * k))


def _assemble(rings: list[np.ndarray], top: str, top_point, bottom_point) -> TriMesh:
    """Closed mesh from rings (each (n_u, 3)) ordered top to bottom. ``top`` = "zip" merges ring 0's
    vertices j and n_u - j (an edge line); "pole": ``top_point`` is a vertex above ring 0. The bottom
    is the pole ``bottom_point``."""
    n_u = len(rings[0])
    n_r = len(rings)
    verts = []
    index = np.zeros((n_r, n_u), dtype=np.int64)
    off = 0
    if top == "zip":
        j = np.arange(n_u)
        m = np.minimum(j, (n_u - j) % n_u)
        uniq = np.arange(n_u // 2 + 1)
        verts.append(rings[0][uniq])
        index[0] = m
        off = len(uniq)
        first = 1
    else:
        verts.append(np.asarray(top_point, dtype=np.float64)[None])
        top_idx = 0
        off = 1
        first = 0
    for r in range(first, n_r):
        verts.append(rings[r])
        index[r] = off + np.arange(n_u)
        off += n_u
    verts.append(np.asarray(bottom_point, dtype=np.float64)[None])
    bot = off
    v_all = np.concatenate(verts)
    du = 1.0 / n_u
    rows_v = np.linspace(0.0, 1.0, n_r + 2)  # v of: top pole/edge .. rings .. apex
    faces, uvs = [], []
    if top == "pole":
        for j in range(n_u):
            faces.append((top_idx, index[0, (j + 1) % n_u], index[0, j]))
            uvs.append(((j + 0.5) * du, 0.0, (j + 1) * du, rows_v[1], j * du, rows_v[1]))
    for r in range(n_r - 1):
        v0, v1 = rows_v[r + 1], rows_v[r + 2]
        for j in range(n_u):
            a0, a1 = index[r, j], index[r, (j + 1) % n_u]
            b0, b1 = index[r + 1, j], index[r + 1, (j + 1) % n_u]
            u0, u1 = j * du, (j + 1) * du
            for tri, uv in (((a0, a1, b1), (u0, v0, u1, v0, u1, v1)), ((a0, b1, b0), (u0, v0, u1, v1, u0, v1))):
                if len(set(tri)) == 3:
                    faces.append(tri)
                    uvs.append(uv)
    vl = rows_v[n_r]
    for j in range(n_u):
        faces.append((bot, index[n_r - 1, j], index[n_r - 1, (j + 1) % n_u]))
        uvs.append(((j + 0.5) * du, 1.0, j * du, vl, (j + 1) * du, vl))
    f = np.array(faces, dtype=np.int64)
    uv = np.array(uvs, dtype=np.float64).reshape(-1, 3, 2)
    mesh = TriMesh(v_all, f, uv)
    if mesh.volume() < 0:
        mesh = TriMesh(v_all, f[:, [0, 2, 1]], uv[:, [0, 2, 1]])
    return mesh


def _inset(spec: ToothSpec, h):
    """Enamel thickness (proximal, labial, lingual) at crown height h: thin at the CEJ, full by mid-crown."""
    w = _smoothstep(0.0, 0.45, h)
    c = spec.enamel_cervical
    return (c + (spec.enamel_proximal - c) * w, c + (spec.enamel_labial - c) * w, c + (spec.enamel_lingual - c) * w)


def _tooth_surfaces(spec: ToothSpec, n_u: int, n_crown: int, n_root: int):
    cr = _Crown(spec)
    phi = 2.0 * np.pi * np.arange(n_u) / n_u
    n_cap = max(3, n_crown // 3)
    # enamel
    rings = []
    hs = 1.0 - _rows_cos(n_crown)  # crown rows below the top, top to bottom
    if cr.zip_top:
        rings.append(cr.crown_point(np.ones(n_u), phi))
        top_kind, top_point = "zip", None
    else:
        outline = cr.crown_point(np.ones(n_u), phi)
        z_f = spec.crown - spec.fossa_depth
        cap, top_point = cr.premolar_cap(np.linspace(0, 1, n_cap + 1)[1:-1], phi, z_f, outline)
        rings.extend(list(cap))
        rings.append(outline)
        top_kind = "pole"
    rings.extend(cr.crown_point(np.full(n_u, h), phi) for h in hs)
    rings.append(cr.crown_point(np.zeros(n_u), phi))  # the CEJ
    ts = _rows_cos(n_root) ** 0.8
    rings.extend(cr.root_point(np.full(n_u, t), phi) for t in ts)
    apex = np.array([0.0, 0.0, -spec.root - 0.25])
    enamel = _assemble(rings, top_kind, top_point, apex)
    # dentin: the crown's inset, stopping incisal_enamel short of the top (incisal third = enamel only)
    n_ud = max(8, (3 * n_u // 4) // 2 * 2)
    phid = 2.0 * np.pi * np.arange(n_ud) / n_ud
    cx, cy = cr.dirs(phid)
    z_cej = cr.cej(cx)
    z_top_e = cr.top_height(cx, cy)
    drop = spec.incisal_enamel
    if spec.kind == "incisor":  # three mamelons on the dentin's incisal border
        am, ad = cr.a_edge
        x_end = np.where(cx > 0, am, ad) * cx
        lobes = sum(np.exp(-((x_end - x0 * cr.a_max) / (0.22 * cr.a_max)) ** 2) for x0 in (-0.6, 0.0, 0.6))
        z_top_d = z_top_e - drop + 0.45 * (lobes - 1.0)
    else:
        z_top_d = z_top_e - drop
    drings = []
    hd_rows = 1.0 - _rows_cos(max(6, 3 * n_crown // 4))
    h_close = 1.0 - 0.6 / spec.crown  # the dentin's rounded top
    for hd in np.concatenate([[1.0], hd_rows, [0.0]]):
        z = z_cej + hd * (z_top_d - z_cej)
        drings.append(_dentin_point(cr, spec, cr.h_at(z, phid), phid, hd, h_close))
    if cr.zip_top:
        d_top, d_top_point = "zip", None
    else:
        z_fd = spec.crown - spec.fossa_depth - 1.4  # the dentin's occlusal surface under the fossa's enamel
        cap_d, d_top_point = cr.premolar_cap(np.linspace(0, 1, n_cap + 1)[1:-1], phid, z_fd, drings[0])
        drings = list(cap_d) + drings
        d_top = "pole"
    tsd = _rows_cos(max(4, 3 * n_root // 4)) ** 0.8
    drings.extend(cr.root_point(np.full(n_ud, t), phid, inset=0.35) for t in tsd)
    dentin_base = _assemble(drings, d_top, d_top_point, np.array([0.0, 0.0, -spec.root + 0.4]))
    return enamel, dentin_base


def _dentin_point(cr: _Crown, spec: ToothSpec, he, phi, hd, h_close):
    """Dentin at enamel height he (same z) and azimuth phi: the enamel point moved towards the crown's axis
    by the enamel thickness; closed at its top (hd -> 1) by a rounded border of 0.6 mm."""
    ti, tl, tg = _inset(spec, he)
    p = cr.crown_point(he, phi, inset=(ti, tl, tg))
    if cr.zip_top:
        rho = _round_off(hd, h_close)
        cx, cy = cr.dirs(phi)
        yl, yg = cr.labial(he), cr.lingual(he)
        ycen = 0.5 * (yl + yg)
        p[..., 1] = ycen + (p[..., 1] - ycen) * rho
        am, ad = cr.a_edge
        a_top = 0.85 * np.where(cx > 0, am, ad) - np.minimum(ti, 0.6 * am)
        a_now = np.abs(p[..., 0])
        blend = 1.0 - rho
        p[..., 0] = np.sign(cx) * np.minimum(a_now, a_now * rho + blend * np.abs(cx) * a_top)
    return p


def make_anatomical_tooth(template: str = "upper_central", resolution: int = 48) -> ToothGeometry:
    """Enamel surface + dentin blend shapes (eq. 5.5) of the dental-atlas tooth ``template`` (a key of
    ``SPECS``: upper/lower central, lateral, canine, premolar) in canonical tooth space (+x mesial).

    ``resolution``: vertices around the crown (even; the dentin uses 3/4); rows follow from it.
    """
    if template not in SPECS:
        raise UserError(f"unknown tooth template {template!r}; use one of {', '.join(SPECS)}")
    if resolution < 12:
        raise UserError("resolution must be >= 12")
    return tooth_from_spec(SPECS[template], resolution)


def tooth_from_spec(spec: ToothSpec, resolution: int = 48) -> ToothGeometry:
    """``make_anatomical_tooth`` for an explicit ``ToothSpec`` (e.g. ``dataclasses.replace`` of a table row)."""
    if spec.kind not in ANATOMY_KINDS:
        raise UserError(f"unknown tooth kind {spec.kind!r}; use one of {', '.join(ANATOMY_KINDS)}")
    n_u = max(12, int(resolution) // 2 * 2)
    n_crown = max(8, int(round(0.6 * n_u)))
    n_root = max(4, n_u // 5)
    enamel, base = _tooth_surfaces(spec, n_u, n_crown, n_root)
    dentin = DentinBlendShape(base, canonical_modes(base, spec.crown))
    return ToothGeometry(spec.kind, enamel, dentin, spec.crown)


def scaled(spec: ToothSpec, factor: float) -> ToothSpec:
    """``spec`` with every length scaled by ``factor`` (a smaller or larger tooth of the same shape)."""
    keys = ("crown", "root", "width", "cervical_width", "depth", "cervical_depth", "cej_mesial", "cej_distal",
            "edge_thickness", "incisal_enamel", "edge_offset", "lingual_cusp_drop", "fossa_depth",
            "enamel_labial", "enamel_proximal", "enamel_lingual", "enamel_cervical")
    kw = {k: getattr(spec, k) * factor for k in keys}
    kw["cusp_ridge_drop"] = tuple(x * factor for x in spec.cusp_ridge_drop)
    return replace(spec, **kw)


def cej_line(spec: ToothSpec, n: int = 96) -> np.ndarray:
    """(n, 3) points of the cemento-enamel junction in canonical tooth space (the crown's h = 0 ring):
    z = 0 at the labial and lingual centres, ``cej_mesial`` / ``cej_distal`` on the proximal sides."""
    phi = 2.0 * np.pi * np.arange(n) / n
    return _Crown(spec).crown_point(np.zeros(n), phi)
