"""Anatomical tooth meshes (core.teeth.anatomy) and the arch with gums (core.teeth.arch), checked with trimesh
(an independent mesh library): closed and manifold, dentin inside the enamel, the table's sizes, the
features a dental atlas shows, neighbours that do not intersect, a gum line that follows the CEJ."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from material_structures.core.teeth.anatomy import SPECS, cej_line, make_anatomical_tooth
from material_structures.core.teeth.arch import build_arch, cavity_dome, gum_mesh, gums_around_teeth, margin_curve
from material_structures.core.teeth.tooth_from_surface import vertex_normals

RES = 40


def _tm(mesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def _surface_samples(mesh, n: int, seed: int = 0) -> np.ndarray:
    pts, _ = trimesh.sample.sample_surface(_tm(mesh), n, seed=seed)
    return pts


@pytest.fixture(scope="module")
def geos():
    return {k: make_anatomical_tooth(k, RES) for k in SPECS}


@pytest.mark.parametrize("name", list(SPECS))
def test_tooth_closed_manifold_and_sized(name, geos):
    geo, spec = geos[name], SPECS[name]
    for mesh in (geo.enamel, geo.dentin.base):
        t = _tm(mesh)
        assert mesh.is_watertight() and t.is_watertight and t.is_winding_consistent
        assert mesh.volume() == pytest.approx(t.volume, rel=1e-9) and mesh.volume() > 0
        # manifold: every vertex's faces form a single fan (no pinched vertices)
        assert len(t.split(only_watertight=False)) == 1
    assert geo.enamel.corner_uv is not None
    assert np.all((geo.enamel.corner_uv >= 0) & (geo.enamel.corner_uv <= 1))
    v = geo.enamel.vertices
    crown = v[v[:, 2] >= 0]
    # crown width (mesiodistal, at the contact areas) and height (labial CEJ to edge / cusp tip) within 5 %
    assert np.ptp(crown[:, 0]) == pytest.approx(spec.width, rel=0.05)
    assert v[:, 2].max() == pytest.approx(spec.crown, rel=0.05)
    assert v[:, 2].min() == pytest.approx(-spec.root, abs=0.5)
    # cervical constriction: the CEJ is narrower than the contact areas (table: 7.0 vs 8.5 on a central)
    cej = cej_line(spec)
    assert np.ptp(cej[:, 0]) == pytest.approx(spec.cervical_width, rel=0.02)
    assert np.ptp(cej[:, 0]) < 0.85 * np.ptp(crown[:, 0])
    # the CEJ curves crownward on the proximal sides
    assert cej[:, 2].max() == pytest.approx(max(spec.cej_mesial, spec.cej_distal), rel=0.02)


@pytest.mark.parametrize("name", list(SPECS))
def test_dentin_inside_enamel_and_short_of_the_edge(name, geos):
    geo, spec = geos[name], SPECS[name]
    enamel = _tm(geo.enamel)
    for c in (np.zeros(3), np.array([0.1, 0.1, 0.1]), np.array([-0.2, -0.2, -0.2])):
        d = geo.dentin.mesh(c)
        pts = np.concatenate([d.vertices, _surface_samples(d, 3000)])
        assert enamel.contains(pts).all(), c
    # the dentin stops short of the incisal edge / cusp tips: the incisal third is enamel only
    top_e, top_d = geo.enamel.vertices[:, 2].max(), geo.dentin.base.vertices[:, 2].max()
    assert top_e - top_d > 0.8 * spec.incisal_enamel - 0.5
    if spec.kind == "incisor":
        assert (top_e - top_d) / spec.crown > 0.16  # measured 0.2-0.25


def _thickness_y(mesh, z: float, x: float = 0.0) -> tuple[float, float]:
    """Labial and lingual y of the surface at height z over x (rays along -y and +y)."""
    t = _tm(mesh)
    loc, _, _ = t.ray.intersects_location([[x, 30.0, z], [x, -30.0, z]], [[0, -1.0, 0], [0, 1.0, 0]])
    ys = loc[:, 1]
    return float(ys.max()), float(ys.min())


def _top_z(mesh, x: float, y: float) -> float:
    loc, _, _ = _tm(mesh).ray.intersects_location([[x, y, 50.0]], [[0, 0, -1.0]])
    return float(loc[:, 2].max())


@pytest.mark.parametrize("name", ["upper_central", "upper_lateral", "lower_central"])
def test_incisor_edge_and_labial_convexity(name, geos):
    geo, spec = geos[name], SPECS[name]
    top = spec.crown
    lab_edge, lin_edge = _thickness_y(geo.enamel, top - 0.6)
    lab_mid, lin_mid = _thickness_y(geo.enamel, 0.5 * top)
    lab_c, _ = _thickness_y(geo.enamel, spec.labial_contour * top)
    assert lab_edge - lin_edge < 1.6 * spec.edge_thickness  # a thin incisal edge
    assert lab_mid - lin_mid > 0.45 * spec.depth  # a thick middle third
    # labial convexity: mid-crown lies labial of the chord from the height of contour to the edge
    chord = lab_c + (lab_edge - lab_c) * (0.5 - spec.labial_contour) / (1 - 0.6 / top - spec.labial_contour)
    assert lab_mid > chord + 0.2
    # a straight incisal edge: within 0.5 mm over the middle 60 % of the width
    xs = np.linspace(-0.3, 0.3, 7) * spec.width
    zs = [_top_z(geo.enamel, x, spec.edge_offset) for x in xs]
    assert np.ptp(zs) < 0.5


@pytest.mark.parametrize("name", ["upper_canine", "lower_canine"])
def test_canine_cusp(name, geos):
    geo, spec = geos[name], SPECS[name]
    tip = _top_z(geo.enamel, 0.0, spec.edge_offset)
    ridges = [_top_z(geo.enamel, s * 0.3 * spec.width, spec.edge_offset) for s in (-1, 1)]
    assert tip == pytest.approx(spec.crown, abs=0.3)
    assert min(tip - r for r in ridges) > 0.7  # the cusp ridges fall away from the tip


@pytest.mark.parametrize("name", ["upper_premolar", "lower_premolar"])
def test_premolar_cusps_and_fossa(name, geos):
    geo, spec = geos[name], SPECS[name]
    ys = np.linspace(-0.4, 0.4, 41) * spec.depth
    prof = np.array([_top_z(geo.enamel, 0.0, y) for y in ys])
    buccal, lingual = prof[ys > 0].max(), prof[ys < 0].max()
    fossa = prof[np.abs(ys) < 1.0].min()
    assert buccal == pytest.approx(spec.crown, abs=0.3)
    assert buccal - lingual == pytest.approx(spec.lingual_cusp_drop, abs=0.4)  # buccal cusp the taller
    assert min(buccal, lingual) - fossa > 1.0  # a central fossa / groove between the two cusps


def test_bad_template():
    with pytest.raises(ValueError, match="unknown tooth template"):
        make_anatomical_tooth("wisdom")
    with pytest.raises(ValueError, match="resolution"):
        make_anatomical_tooth("upper_central", 4)


@pytest.fixture(scope="module")
def arches():
    return {jaw: build_arch(jaw, resolution=32, edge_z=0.0 if jaw == "upper" else -3.2,
                            y0=0.0 if jaw == "upper" else -2.6) for jaw in ("upper", "lower")}


@pytest.mark.parametrize("jaw", ["upper", "lower"])
def test_arch_neighbours_do_not_intersect(jaw, arches):
    teeth, arch = arches[jaw]
    assert len(teeth) == 8
    assert [t.spec.kind for t in teeth] == ["premolar", "canine", "incisor", "incisor"] * 1 + \
        ["incisor", "incisor", "canine", "premolar"]
    for a, b in zip(teeth[:-1], teeth[1:], strict=True):
        for p, q in ((a, b), (b, a)):
            pts = np.concatenate([p.geometry.enamel.vertices, _surface_samples(p.geometry.enamel, 4000)])
            assert not _tm(q.geometry.enamel).contains(pts).any(), (p.name, q.name)
        # and they are neighbours: contact areas within 0.6 mm
        d = np.linalg.norm(a.geometry.enamel.vertices[:, None] - b.geometry.enamel.vertices[None], axis=-1).min()
        assert d < 0.6
    # mirror-symmetric about the midline, crown tips on the smile line
    right, left = teeth[4:], teeth[3::-1]
    for rt, lt in zip(right, left, strict=True):
        assert rt.name.replace("right", "left") == lt.name and rt.geometry.enamel.vertices[:, 0].min() > 0
        np.testing.assert_allclose(lt.geometry.enamel.vertices[:, 1:], rt.geometry.enamel.vertices[:, 1:], atol=1e-9)
    centrals = teeth[3:5]
    edge = [t.geometry.enamel.vertices[:, 2].min() if jaw == "upper" else t.geometry.enamel.vertices[:, 2].max()
            for t in centrals]
    # (placed with resolution-64 copies: a resolution-32 crown's tip differs by up to 0.05 mm)
    assert edge == pytest.approx([0.0 if jaw == "upper" else -3.2] * 2, abs=0.1)
    for t in teeth:  # the placed dentin stays inside its enamel
        assert _tm(t.geometry.enamel).contains(t.geometry.dentin.base.vertices).all()


@pytest.mark.parametrize("jaw", ["upper", "lower"])
def test_gums_follow_the_cej(jaw, arches):
    teeth, arch = arches[jaw]
    sign = 1.0 if jaw == "upper" else -1.0  # +1: the gum side is +z
    gums = gum_mesh(teeth, arch)
    tg = _tm(gums)
    assert gums.is_watertight() and tg.is_winding_consistent and gums.volume() > 0
    assert gums.corner_uv is not None
    zen = []
    for t in teeth:
        cej = t.cej(192)
        s_c, n_c = arch.coords(cej)
        lab = cej[np.argmax(n_c)]  # the labial centre of the CEJ
        s_lab, _ = arch.coords(lab[None])
        m = margin_curve(teeth, arch, s_lab)[0]
        # the gum line lies 1 mm crownward of the CEJ at the tooth's labial centre (within 0.15 mm)
        assert sign * (lab[2] - m) == pytest.approx(1.0, abs=0.15), t.name
        zen.append((s_lab[0], m))
        # the root is under the gum: the gum closes around its apex region (0.1 mm outside the root, beyond the
        # 0.05 mm film of air), and the root itself is not inside the gums' volume (cut out of it)
        e = t.geometry.enamel
        v, n = e.vertices, vertex_normals(e.vertices, e.faces)
        root = sign * v[:, 2] > sign * lab[2] + 3.0
        assert tg.contains(v[root] + 0.1 * n[root]).mean() > 0.95, t.name
        assert not tg.contains(v[root] - 0.02 * n[root]).any(), t.name
        assert not tg.contains(v[root] + 0.02 * n[root]).any(), t.name  # inside the film of air
    # papillae: between two neighbours the margin rises crownward into a tip, > 1 mm beyond both zeniths and
    # > 3 mm beyond the deeper one (measured 3.1-4.1 mm upper, 1.2-5.8 mm lower: the lower canine sits deeper)
    for (s0, m0), (s1, m1) in zip(zen[:-1], zen[1:], strict=True):
        s = np.linspace(s0, s1, 200)
        m = margin_curve(teeth, arch, s)
        tip = (m * sign).min()
        assert min(m0 * sign, m1 * sign) - tip > 1.0
        assert max(m0 * sign, m1 * sign) - tip > 3.0
    # no tooth's crown below the margin is covered by gum at its labial face (the crown shows)
    for t in teeth:
        cej = t.cej(192)
        _, n_c = arch.coords(cej)
        lab = cej[np.argmax(n_c)]
        v = t.geometry.enamel.vertices
        s_v, n_v = arch.coords(v)
        s_lab, _ = arch.coords(lab[None])
        face = v[(np.abs(s_v - s_lab[0]) < 1.0) & (sign * (v[:, 2] - lab[2]) < -2.5) & (n_v > np.percentile(n_v, 70))]
        assert len(face) > 5 and not tg.contains(face + np.array([0, 0, 0])).any(), t.name


def test_cavity_dome_faces_inwards():
    dome = cavity_dome()
    t = dome.triangles()
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    centre = np.array([0.0, -8.0, -2.0])
    assert (np.einsum("ij,ij->i", n, centre - t.mean(axis=1)) > 0).mean() > 0.99
    assert dome.vertices[:, 1].max() <= 1.0 + 1e-9


def test_gums_around_teeth_removes_the_teeth_and_keeps_the_uvs():
    """A 10 mm cube of gum with a 2 mm tooth cube half inside it: without a gap the gum loses exactly the 4 mm^3
    inside (closed form); with the gap the tooth is cut out grown by it (points within the film of air are in
    neither); the UVs of the gum's faces that were not cut are the ones given, the hole's walls get (0.5, 0.5)."""
    from material_structures.core.teeth.mesh import TriMesh

    def cube(lo, hi):
        c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        f = [(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4), (2, 6, 7), (2, 7, 3), (0, 4, 6),
             (0, 6, 2), (1, 3, 7), (1, 7, 5)]
        m = TriMesh(c, np.array(f))
        return m if m.volume() > 0 else TriMesh(c, np.array(f)[:, [0, 2, 1]])

    gum = cube((0, 0, 0), (10, 10, 10))
    uv = np.tile(np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]), (len(gum.faces), 1, 1))
    gum = TriMesh(gum.vertices, gum.faces, uv)
    tooth = cube((4, 4, 9), (6, 6, 11))  # half of it inside the gum
    exact = gums_around_teeth(gum, [tooth], gap=0.0)
    assert exact.is_watertight() and exact.volume() == pytest.approx(1000.0 - 4.0, rel=1e-12)
    out = gums_around_teeth(gum, [tooth], gap=0.05)
    assert out.is_watertight() and 1000.0 - 4.5 < out.volume() < 1000.0 - 4.0
    tg = _tm(out)
    # the tooth's inside and the film of air around it are not gum; 0.1 mm beyond the tooth is
    assert not tg.contains(np.array([[5.0, 5.0, 9.5], [3.99, 5.0, 9.5], [5.0, 5.0, 8.99]])).any()
    assert tg.contains(np.array([[5.0, 5.0, 8.85], [3.85, 5.0, 9.5], [5.0, 6.15, 9.5]])).all()
    # the bottom face (z = 0) was not cut: its UVs are the ones given
    bottom = np.all(np.abs(out.triangles()[..., 2]) < 1e-12, axis=1)
    assert bottom.any()
    got = {tuple(np.round(p, 9)) for p in out.corner_uv[bottom].reshape(-1, 2)}
    assert got <= {(0.1, 0.2), (0.3, 0.4), (0.5, 0.6)}
    walls = np.all(out.triangles()[..., 2] < 10.0 - 1e-9, axis=1) & np.all(out.triangles()[..., 2] > 8.5, axis=1)
    assert walls.any() and np.allclose(out.corner_uv[walls], 0.5)
