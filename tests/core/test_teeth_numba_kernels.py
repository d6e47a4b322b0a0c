"""What the compiled teeth tracer is built from (``numba_kernels``, ``bvh``): the physics the two tracers share,
the BVH's leaf codes, depth limit and stack sizes, and a compile cache that follows edits of every kernel module.

Tolerances: the shared physics compiled by numba equals the numpy evaluation of the same source to 2 ulp
(rtol 5e-16) where it is arithmetic and sqrt, and to 2.5e-16 absolute where it takes a tanh (libm's and numpy's
round differently); the scalar and vector forms of the phase-function sampling agree to 1e-15; integer codes,
stack sizes and hit triangles exactly.
"""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.heavy  # compiles numba code (the cache test twice in a subprocess): outside `make test-fast`

numba = pytest.importorskip("numba")

from material_structures.core.teeth import bvh, numba_kernels  # noqa: E402
from material_structures.core.teeth.bvh import (  # noqa: E402
    LANES,
    MAX_DEPTH,
    WIDTH,
    TriangleBVH,
    closest_triangle,
    decode_leaf,
    encode_leaf,
    first_hit,
    leaf_blocks,
)
from material_structures.core.teeth.fresnel import fresnel_dielectric  # noqa: E402
from material_structures.core.teeth.phase_function import (  # noqa: E402
    direction_from_mu,
    direction_from_mu_into,
    hg,
    hg_dlog_dg,
    sample_hg_mu,
    sample_hg_mu_scalar,
    two_lobe,
)
from material_structures.core.teeth.sigmoid_blend import blend_weight, blend_weight_dq  # noqa: E402

from ._teeth_scenes import brute_force_hits  # noqa: E402

TEETH = Path(numba_kernels.__file__).parent


@numba.njit(cache=False, error_model="numpy")
def _physics_compiled(cos_i, eta, mu, g1, g2, beta, q, spread, u):
    n = cos_i.shape[0]
    out = np.empty((8, n))
    for i in range(n):
        out[0, i] = fresnel_dielectric(cos_i[i], eta[i])
        out[1, i] = hg(mu[i], g1[i])
        out[2, i] = hg_dlog_dg(mu[i], g1[i])
        out[3, i] = two_lobe(mu[i], g1[i], g2[i], beta[i])
        out[4, i] = blend_weight(q[i], spread)
        out[5, i] = blend_weight_dq(q[i], spread)
        out[6, i] = blend_weight(q[i])
        out[7, i] = sample_hg_mu_scalar(g1[i], u[i])
    return out


@numba.njit(cache=False, error_model="numpy")
def _directions_compiled(d, mu, phi):
    out = np.empty_like(d)
    for i in range(d.shape[0]):
        direction_from_mu_into(d[i], mu[i], phi[i], out[i])
    return out


def test_the_shared_physics_compiles_to_the_numpy_values():
    """``fresnel_dielectric``, ``hg``, ``hg_dlog_dg``, ``two_lobe``, ``blend_weight(_dq)``: one source each, evaluated
    by numpy on arrays and compiled by numba for scalars (the compiled tracer's use): equal to 2 ulp."""
    rng = np.random.default_rng(0)
    n = 5000
    cos_i = rng.uniform(-1.2, 1.2, n)  # beyond +-1: |cos| is clamped to 1
    eta = rng.uniform(1.0, 2.0, n)
    mu = rng.uniform(-1.0, 1.0, n)
    g1, g2, beta = rng.uniform(-0.95, 0.95, n), rng.uniform(-0.95, 0.95, n), rng.uniform(0.0, 1.0, n)
    q, spread = rng.uniform(-5.0, 5.0, n), 0.7
    u = rng.random(n)
    g1[:50] = rng.uniform(-1e-4, 1e-4, 50)  # the isotropic branch of the sampling
    got = _physics_compiled(cos_i, eta, mu, g1, g2, beta, q, spread, u)
    want = [fresnel_dielectric(cos_i, eta), hg(mu, g1), hg_dlog_dg(mu, g1), two_lobe(mu, g1, g2, beta),
            blend_weight(q, spread), blend_weight_dq(q, spread), blend_weight(q), sample_hg_mu(g1, u)]
    for k in range(4):  # arithmetic and sqrt: the same operations in the same order
        np.testing.assert_allclose(got[k], want[k], rtol=5e-16, atol=0.0, err_msg=str(k))
    # l(q) = (1 + tanh) / 2: libm's and numpy's tanh differ by up to 2 ulp of 1, so l by 2.3e-16 absolute
    np.testing.assert_allclose(got[4], want[4], rtol=0.0, atol=2.5e-16)
    np.testing.assert_allclose(got[6], want[6], rtol=0.0, atol=2.5e-16)
    np.testing.assert_allclose(got[5], want[5], rtol=0.0, atol=1e-15)  # l (1 - l) / s, s = 0.7
    np.testing.assert_allclose(got[7], want[7], rtol=0.0, atol=1e-15)  # the sampling's scalar form
    # the Fresnel term itself (eq. 5.1), in the angle form F = (sin^2(i - t) / sin^2(i + t) + tan^2(i - t) /
    # tan^2(i + t)) / 2 with sin t = sin i / eta: 0.0434 at normal incidence for eta 1.631, 1 at grazing incidence
    assert fresnel_dielectric(1.0, 1.631) == pytest.approx(((1.631 - 1) / (1.631 + 1)) ** 2, rel=1e-12)
    assert fresnel_dielectric(0.0, 1.631) == pytest.approx(1.0, abs=1e-12)
    for deg, e in ((30.0, 1.631), (60.0, 1.5), (75.0, 1.33)):
        i = np.radians(deg)
        t = np.arcsin(np.sin(i) / e)
        want = 0.5 * (np.sin(i - t) ** 2 / np.sin(i + t) ** 2 + np.tan(i - t) ** 2 / np.tan(i + t) ** 2)
        cos_i = np.array([np.cos(i)])
        assert _physics_compiled(cos_i, np.array([e]), *(np.zeros(1),) * 5, 1.0, np.zeros(1))[0, 0] == \
            pytest.approx(want, rel=1e-12), deg


def test_scattered_directions_of_the_scalar_and_vector_forms_agree():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:10] = [0.0, 0.0, -1.0]  # the frame's sign switch
    mu, phi = rng.uniform(-1.0, 1.0, 3000), rng.uniform(0.0, 2.0 * np.pi, 3000)
    np.testing.assert_allclose(_directions_compiled(d, mu, phi), direction_from_mu(d, mu, phi), rtol=0.0, atol=1e-15)


@numba.njit(cache=False, error_model="numpy")
def _blend_weight_compiled(q, s):
    return blend_weight(q, s)


def test_the_tracers_blend_shortcut_returns_what_blend_weight_returns():
    """``path_tracer_compiled._blend`` skips the tanh beyond |q / 2s| = 20, where l(q) is 0 or 1 to the last bit."""
    from material_structures.core.teeth.path_tracer_compiled import _blend

    s = 0.35
    for q in (40.0 * s, 40.0 * s * (1 + 1e-12), 1e3, -40.0 * s, -1e3, 3.0 * s, -0.1 * s, 0.0):
        assert _blend(q, s) == _blend_weight_compiled(q, s), q  # exactly, with the tanh numba compiles
    for q in (40.0 * s, 1e3, -40.0 * s, -1e3):  # saturated: numpy's tanh too gives exactly 1 or 0
        assert _blend(q, s) == blend_weight(q, s) == (1.0 if q > 0 else 0.0)


@numba.njit(cache=False)
def _decode_compiled(codes):
    out = np.empty((codes.shape[0], 4), dtype=np.int64)
    for i in range(codes.shape[0]):
        out[i, 0], out[i, 1] = decode_leaf(codes[i])
        out[i, 2], out[i, 3] = leaf_blocks(codes[i])
    return out


def test_leaf_codes_round_trip():
    """A leaf of ``count`` triangles from block ``first`` is the negative code ~(32 first + count); decoding it, in
    numpy and in numba, gives (first, count) back, and its blocks are first .. first + ceil(count / LANES)."""
    assert encode_leaf(3, 5) == ~(3 * 32 + 5) == -102
    assert encode_leaf(0, 0) == -1
    first = np.array([0, 1, 7, 1000, 2**40], dtype=np.int64)
    count = np.array([1, 4, 5, 31, 17], dtype=np.int64)
    codes = encode_leaf(first, count)
    assert (codes < 0).all()
    np.testing.assert_array_equal(np.stack(decode_leaf(codes)), [first, count])
    want = np.stack([first, count, first, first + (count + LANES - 1) // LANES], axis=1)
    np.testing.assert_array_equal(_decode_compiled(codes), want)


def _chain(n: int, ratio: float) -> np.ndarray:
    """n triangles across the x axis at x = ratio^i, each 10 % of its distance in size: the SAH splits off one or
    two at a time, a tree about n / 3 deep."""
    x = ratio ** np.arange(n, dtype=np.float64)
    s = 0.1 * x
    tris = np.zeros((n, 3, 3))
    tris[:, :, 0] = x[:, None]
    tris[:, 0, 1], tris[:, 0, 2] = -s, -s
    tris[:, 1, 1], tris[:, 1, 2] = s, -s
    tris[:, 2, 2] = s
    return tris


def test_a_tree_deeper_than_max_depth_is_refused():
    with pytest.raises(ValueError, match="deeper than MAX_DEPTH = 64"):
        TriangleBVH(_chain(160, 3.0))
    assert MAX_DEPTH == 64


def _need(wchild: np.ndarray, node: int) -> int:
    """Stack entries a traversal below wide node ``node`` holds at most: it holds the node's k children and,
    while it descends into one, the other k - 1."""
    kids = [int(c) for c in wchild[node] if c != encode_leaf(0, 0)]
    inner = [_need(wchild, c) for c in kids if c >= 0]
    return max([len(kids)] + [len(kids) - 1 + n for n in inner])


def test_stack_sizes_are_the_traversals_worst_case_and_suffice():
    """A chain-like tree (24 levels): the ray tree's ``stack_size`` equals the recursive worst case, the binary
    tree's is depth + 1, and first hits and closest triangles with stacks of exactly those sizes equal brute
    force (the same triangle; distances to 1e-12 relative)."""
    from material_structures.core.teeth.distance_derivatives import closest_point_on_triangle

    n = 64
    tris = _chain(n, 2.0)
    tree = TriangleBVH(tris)
    rt = tree.ray_arrays(tris)
    assert tree.depth >= 20 and tree.stack_size == tree.depth + 1
    assert rt.stack_size == _need(rt.wchild, 0) >= 8
    rng = np.random.default_rng(4)
    k = rng.integers(0, n, 400)
    scale = 2.0 ** k[:, None]
    target = tris[k].mean(axis=1) + rng.normal(size=(400, 3)) * 0.05 * scale
    o = target + rng.normal(size=(400, 3)) * 2.0 * scale
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    stack, dist = np.empty(rt.stack_size, dtype=np.int64), np.empty(WIDTH)
    n_hit = 0
    for i in range(len(o)):
        tri, t = first_hit(rt, o[i], d[i], 0.0, np.inf, stack, dist)
        tt, ok = brute_force_hits(tris, o[i], d[i])
        assert tri == (np.flatnonzero(ok)[np.argmin(tt[ok])] if ok.any() else -1), i
        n_hit += tri >= 0
    assert n_hit >= 100
    nodes, roots = TriangleBVH.merge([tree])
    bstack, bary = np.empty(tree.stack_size, dtype=np.int64), np.empty(3)
    for p in target[:100]:
        tri, dk = closest_triangle(nodes, roots[0], tris, p, bstack, bary)
        cp, _ = closest_point_on_triangle(np.repeat(p[None], n, 0), tris[:, 0], tris[:, 1], tris[:, 2])
        dd = np.linalg.norm(p - cp, axis=1)
        assert tri == np.argmin(dd) and dk == pytest.approx(dd.min(), rel=1e-12)


def test_every_module_the_compiled_tracer_is_made_of_stamps_its_cache():
    """``KERNEL_MODULES`` lists every teeth module that imports numba and every teeth module those import from."""
    listed = set(numba_kernels.KERNEL_MODULES)
    for path in TEETH.glob("*.py"):
        tree = ast.parse(path.read_text())
        imports = [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]
        uses_numba = any((isinstance(n, ast.Import) and any(a.name.split(".")[0] == "numba" for a in n.names))
                         or (isinstance(n, ast.ImportFrom) and (n.module or "").split(".")[0] == "numba"
                             and n.level == 0) for n in imports)
        if not uses_numba:
            continue
        assert path.stem in listed, path.stem
        for n in imports:
            if isinstance(n, ast.ImportFrom) and n.level == 1 and n.module:
                assert n.module.split(".")[0] in listed, (path.stem, n.module)


_PROBE = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from probe.core.teeth.dentin_reach_grid import dentin_reach_grid
tris = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
_, _, _, _, flags = dentin_reach_grid(tris, np.zeros(1, dtype=np.int64), 1, 0.02)
print("marked", int(flags.sum()))
"""


def test_editing_bvh_recompiles_its_cached_callers(tmp_path):
    """A copy of the teeth package: a first run fills numba's cache with ``dentin_reach_grid._mark``, which calls
    ``bvh.closest_point_triangle``; an edit of bvh.py alone (every distance + 1 mm, so no cell lies within reach)
    must reach the second run, which numba's own stamp (the hash of dentin_reach_grid.py) would not notice."""
    _probe_copy(tmp_path)
    pkg, script = tmp_path / "probe", tmp_path / "probe_run.py"
    # the copy's own __pycache__: not numba's user-wide folder, not the Makefile's shared one (which holds this
    # tree's kernels, the copy's sources being the same)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("NUMBA_CACHE") and k != numba_kernels.SHARED_CACHE_ENV}
    env["NUMBA_DEBUG_CACHE"] = "1"  # numba prints "[cache] data loaded from ..." / "data saved to ..."

    def run() -> tuple[int, bool]:
        """(cells marked, whether _mark came from the cache)"""
        out = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, env=env,
                             timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        loaded = any("data loaded from" in line and "dentin_reach_grid._mark-" in line
                     for line in out.stdout.splitlines())
        return int(out.stdout.split("marked")[-1]), loaded

    before, loaded = run()
    assert before > 0 and not loaded
    assert run() == (before, True)  # the cache serves the same code
    src = pkg / "core" / "teeth" / "bvh.py"
    text = src.read_text()
    old = "    return np.sqrt(dx * dx + dy * dy + dz * dz)\n"
    assert text.count(old) == 1
    src.write_text(text.replace(old, "    return np.sqrt(dx * dx + dy * dy + dz * dz) + 1.0\n"))
    assert run() == (0, False)  # compiled afresh with the edited bvh.py


def _probe_copy(root) -> None:
    """A copy of the teeth package as ``root/probe`` and the probe script as ``root/probe_run.py``."""
    pkg = root / "probe"
    (pkg / "core" / "teeth").mkdir(parents=True)
    for init in (pkg / "__init__.py", pkg / "core" / "__init__.py"):
        init.write_text("")
    for path in TEETH.glob("*.py"):
        shutil.copy(path, pkg / "core" / "teeth" / path.name)
    (root / "probe_run.py").write_text(textwrap.dedent(_PROBE))


def test_a_copy_elsewhere_finds_the_shared_cache(tmp_path):
    """With ``MATERIAL_STRUCTURES_NUMBA_CACHE`` set, the kernels one copy of the package compiled load in a
    copy of the same sources installed elsewhere (as the extension zip in a bare Blender after ``make test``),
    and nothing lands in either copy's ``__pycache__``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env[numba_kernels.SHARED_CACHE_ENV] = str(tmp_path / "shared")
    env["NUMBA_DEBUG_CACHE"] = "1"

    def run(root) -> tuple[int, str]:
        out = subprocess.run([sys.executable, str(root / "probe_run.py"), str(root)], capture_output=True,
                             text=True, env=env, timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        mark = [line for line in out.stdout.splitlines() if "dentin_reach_grid._mark-" in line]
        how = "loaded" if any("data loaded from" in line for line in mark) else "compiled"
        return int(out.stdout.split("marked")[-1]), how

    for name in ("a", "b"):
        _probe_copy(tmp_path / name)
    first = run(tmp_path / "a")
    assert first[0] > 0 and first[1] == "compiled"
    assert run(tmp_path / "b") == (first[0], "loaded")
    assert list((tmp_path / "shared").glob("teeth-*/dentin_reach_grid._mark-*.nbi"))
    assert not list(tmp_path.glob("*/probe/core/teeth/__pycache__/*.nb[ic]"))


def test_kernel_sources_digest_follows_each_file(tmp_path):
    for name in numba_kernels.KERNEL_MODULES:
        (tmp_path / f"{name}.py").write_text(f"# {name}\n")
    first = numba_kernels.kernel_sources_digest(str(tmp_path))
    assert numba_kernels.kernel_sources_digest(str(tmp_path)) == first
    (tmp_path / "bvh.py").write_text("# bvh, edited\n")
    second = numba_kernels.kernel_sources_digest(str(tmp_path))
    assert second != first
    (tmp_path / "unrelated.py").write_text("# not a kernel module\n")
    assert numba_kernels.kernel_sources_digest(str(tmp_path)) == second
    assert bvh.numba_callable is numba_kernels.numba_callable
