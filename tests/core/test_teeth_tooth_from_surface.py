"""A tooth from a closed enamel surface (a scan): the dentin's B0 lies the enamel thickness inside, against the
closed form on a sphere; inward winding is turned out; an open surface is one line."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.errors import UserError
from material_structures.core.teeth.tooth_from_surface import tooth_from_enamel_surface


def _sphere(radius: float, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A closed UV sphere (poles single vertices), faces wound outwards."""
    th = np.linspace(0.0, np.pi, n + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    v = np.vstack([[0.0, 0.0, 1.0], ring, [0.0, 0.0, -1.0]]) * radius
    m, rows = 2 * n, n - 1
    idx = lambda i, j: 1 + i * m + (j % m)  # noqa: E731
    faces = [(0, idx(0, j), idx(0, j + 1)) for j in range(m)]
    for i in range(rows - 1):
        for j in range(m):
            faces += [(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i, j + 1))]
    last = len(v) - 1
    faces += [(idx(rows - 1, j), last, idx(rows - 1, j + 1)) for j in range(m)]
    return v, np.array(faces)


def test_b0_lies_the_enamel_thickness_inside_a_sphere():
    v, f = _sphere(5.0)
    enamel, dentin = tooth_from_enamel_surface(v, f, enamel_occlusal_mm=1.8, enamel_side_mm=1.1)
    assert enamel.volume() > 0 and enamel.is_watertight()
    h = (v[:, 2] - v[:, 2].min()) / np.ptp(v[:, 2])
    want = 5.0 - (1.1 + 0.7 * h ** 4)  # radial normals on a sphere: |B0| = r - d(h)
    got = np.linalg.norm(dentin.base.vertices, axis=1)
    assert np.max(np.abs(got - want)) < 0.02, np.max(np.abs(got - want))
    assert dentin.deltas.shape == (3, len(v), 3) and np.all(np.isfinite(dentin.deltas))


def test_inward_winding_is_turned_out_and_gives_the_same_dentin():
    v, f = _sphere(5.0)
    out_enamel, out_dentin = tooth_from_enamel_surface(v, f)
    in_enamel, in_dentin = tooth_from_enamel_surface(v, f[:, [0, 2, 1]])
    assert in_enamel.volume() == pytest.approx(out_enamel.volume(), rel=1e-12) and in_enamel.volume() > 0
    np.testing.assert_allclose(in_dentin.base.vertices, out_dentin.base.vertices, atol=1e-12)


def test_an_open_surface_is_one_line():
    v, f = _sphere(5.0)
    with pytest.raises(UserError, match=r"^'scan' is not a closed \(watertight\) triangle mesh$"):
        tooth_from_enamel_surface(v, f[1:], name="scan")


@pytest.mark.parametrize(("squash", "said"), [((1.0, 1.0, 0.0), "0 mm"), ((1.0, 1.0, 1e-3), "0.01 mm"),
                                              ((0.0, 0.0, 0.0), "0 mm"), ((0.2, 0.2, 0.2), "2 mm")])
def test_a_flat_collapsed_or_tiny_surface_is_one_line(squash, said):
    """A closed surface thinner than twice the enamel (flat, collapsed to a point, or modelled at the wrong unit
    scale) gave a tooth whose dentin, the surface moved inwards by the enamel thickness, turned inside out: a
    flat disc became a tooth 2.2 mm tall."""
    v, f = _sphere(5.0)  # 10 mm across
    with pytest.raises(UserError, match=rf"^'scan' is {said} across at its thinnest, less than twice the enamel"):
        tooth_from_enamel_surface(v * np.asarray(squash), f, name="scan")
    tooth_from_enamel_surface(v * 0.25, f, name="scan")  # 2.5 mm across: thin but a tooth
