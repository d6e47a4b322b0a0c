"""Flattened, ray-traceable form of a ``TeethScene`` for the path tracer.

Two parameter sets are compiled together: the *sampling* scene (which decides path structure and
sampling pdfs) and the *evaluation* scene (whose contribution f is computed along the same paths).
They are equal for ordinary rendering; keeping them apart lets the finite-difference tests and the
gradient share one estimator with common random numbers (f(x; theta) / p(x; theta_0)).

Media: 0 = air, 1 + 2 i = enamel of tooth i, 2 + 2 i = dentin of tooth i, then the gums.
Triangle kinds: 0 = thin dielectric boundary (enamel, gums), 1 = index-matched (dentin),
2 = opaque Lambertian (oral cavity).
"""

from __future__ import annotations

import numpy as np

from .distance_derivatives import closest_point_on_triangle, point_distance_vertex_derivative
from .param_vector import ParamLayout
from .ray_queries import RayCaster
from .scene import TeethScene

KIND_DIELECTRIC, KIND_INDEX_MATCHED, KIND_OPAQUE = 0, 1, 2
MED_AIR, MED_ENAMEL, MED_DENTIN, MED_GUMS = 0, 1, 2, 3


class DentinProximity:
    """Signed distance q from points to one tooth's dentin surface and dq/dc (eq. 5.33-5.41).

    The closest triangle is searched on the sampling geometry (k nearest triangle centroids);
    the distance and its derivative are evaluated on the same triangle of the evaluation geometry.
    """

    def __init__(self, faces: np.ndarray, verts_s: np.ndarray, verts_e: np.ndarray, deltas: np.ndarray,
                 k: int = 8):
        self.faces = faces
        self.ts = verts_s[faces]
        self.te = verts_e[faces]
        self.deltas = deltas  # (3, V, 3)
        self._tree = None  # built on the first query (the numpy reference tracer's; the compiled one has a BVH)
        self.k = min(k, len(faces))

    def query(self, p: np.ndarray, sign: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns (q_sampling, q_eval, dq_eval/dc (N, 3))."""
        n = len(p)
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.ts.mean(axis=1))
        _, cand = self._tree.query(p, k=self.k)
        cand = cand.reshape(n, -1)
        pp = np.repeat(p, cand.shape[1], axis=0)
        tri = self.ts[cand.ravel()]
        cp, _ = closest_point_on_triangle(pp, tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.linalg.norm(pp - cp, axis=1).reshape(n, -1)
        j = np.argmin(dist, axis=1)
        f = cand[np.arange(n), j]
        q_s = sign * dist[np.arange(n), j]
        te = self.te[f]
        cpe, bary = closest_point_on_triangle(p, te[:, 0], te[:, 1], te[:, 2])
        q_e = sign * np.linalg.norm(p - cpe, axis=1)
        dq_dv = point_distance_vertex_derivative(p, cpe, bary, sign)  # (N, 3, 3)
        dB = self.deltas[:, self.faces[f], :]  # (3 modes, N, 3 verts, 3)
        dq_dc = np.einsum("nvx,knvx->nk", dq_dv, dB)
        return q_s, q_e, dq_dc


class CompiledScene:
    def __init__(self, scene: TeethScene, sampling: TeethScene | None = None, layout: ParamLayout | None = None,
                 use_embree: bool | None = None):
        sampling = scene if sampling is None else sampling
        self.layout = layout or ParamLayout(scene)
        L = self.layout
        self.spread = scene.blend_spread
        nt = len(scene.teeth)
        n_media = 1 + 2 * nt + (1 if scene.gums is not None else 0)
        self.n_media = n_media
        self.sigma_s = np.zeros((n_media, 3))
        self.sigma_e = np.zeros((n_media, 3))
        self.med_kind = np.zeros(n_media, dtype=np.int64)
        self.med_tooth = np.full(n_media, -1, dtype=np.int64)
        self.col_sigma = np.full(n_media, -1, dtype=np.int64)
        # enamel-side (E) and dentin-side (D) material per medium, sampling (s) and evaluation (e)
        self.alb = {k: np.zeros((n_media, 3)) for k in ("Es", "Ds", "Ee", "De")}
        self.ph = {k: np.zeros((n_media, 3)) for k in ("Es", "Ds", "Ee", "De")}  # g1, g2, beta
        self.col_alb = {k: np.zeros(n_media, dtype=np.int64) for k in ("E", "D")}
        self.col_ph = {k: np.zeros((n_media, 3), dtype=np.int64) for k in ("E", "D")}

        tris_s, tris_e, kinds, inside, outside, eta, tex_id, uvs = [], [], [], [], [], [], [], []
        rest = []  # (index into tris_s, the dentin triangles at c = 0) per tooth
        dtooth, dface = [], []
        self.tex_s, self.tex_e, self.tex_col = [], [], []
        self.dentin: list[DentinProximity] = []
        self.c_col = np.zeros(nt, dtype=np.int64)

        def set_medium(m, kind, tooth, prefix_e, prefix_d, mat_es, mat_ds, mat_ee, mat_de, sig_s, sig_e, sig_prefix):
            self.med_kind[m] = kind
            self.med_tooth[m] = tooth
            self.sigma_s[m], self.sigma_e[m] = sig_s, sig_e
            self.col_sigma[m] = L.col(f"{sig_prefix}.sigma_t")
            for key, mat in (("Es", mat_es), ("Ds", mat_ds), ("Ee", mat_ee), ("De", mat_de)):
                self.alb[key][m] = mat.albedo
                self.ph[key][m] = (mat.g1, mat.g2, mat.beta)
            for key, prefix in (("E", prefix_e), ("D", prefix_d)):
                self.col_alb[key][m] = L.col(f"{prefix}.albedo")
                self.col_ph[key][m] = [L.col(f"{prefix}.g1"), L.col(f"{prefix}.g2"), L.col(f"{prefix}.beta")]

        for i, (te, ts) in enumerate(zip(scene.teeth, sampling.teeth, strict=True)):
            me, md = 1 + 2 * i, 2 + 2 * i
            pe, pd = f"{te.name}.enamel", f"{te.name}.dentin"
            set_medium(me, MED_ENAMEL, i, pe, pd, ts.enamel, ts.dentin, te.enamel, te.dentin,
                       ts.enamel.sigma_t, te.enamel.sigma_t, pe)
            set_medium(md, MED_DENTIN, i, pe, pd, ts.enamel, ts.dentin, te.enamel, te.dentin,
                       ts.dentin.sigma_t, te.dentin.sigma_t, pd)
            em = te.enamel_mesh
            nf = len(em.faces)
            tris_s.append(ts.enamel_mesh.triangles())
            tris_e.append(em.triangles())
            kinds.append(np.full(nf, KIND_DIELECTRIC))
            inside.append(np.full(nf, me))
            outside.append(np.full(nf, MED_AIR))
            eta.append(np.full(nf, te.eta))
            tex_id.append(np.full(nf, len(self.tex_e)))
            uvs.append(em.corner_uv)
            dtooth.append(np.full(nf, -1))
            dface.append(np.full(nf, -1))
            self.tex_s.append(ts.a_t)
            self.tex_e.append(te.a_t)
            self.tex_col.append(L.col(f"{te.name}.a_t"))
            faces = te.dentin_shape.base.faces
            vs, ve = ts.dentin_vertices(), te.dentin_vertices()
            nd = len(faces)
            rest.append((len(tris_s), ts.dentin_shape.base.vertices[faces]))
            tris_s.append(vs[faces])
            tris_e.append(ve[faces])
            kinds.append(np.full(nd, KIND_INDEX_MATCHED))
            inside.append(np.full(nd, md))
            outside.append(np.full(nd, me))
            eta.append(np.ones(nd))
            tex_id.append(np.full(nd, -1))
            uvs.append(np.zeros((nd, 3, 2)))
            dtooth.append(np.full(nd, i))
            dface.append(np.arange(nd))
            self.dentin.append(DentinProximity(faces, vs, ve, te.dentin_shape.deltas))
            self.c_col[i] = L.col(f"{te.name}.c")
        if scene.gums is not None:
            mg = 1 + 2 * nt
            gs, ge = sampling.gums, scene.gums
            set_medium(mg, MED_GUMS, -1, "gums", "gums", gs.material, gs.material, ge.material, ge.material,
                       gs.material.sigma_t, ge.material.sigma_t, "gums")
            nf = len(ge.mesh.faces)
            tris_s.append(gs.mesh.triangles())
            tris_e.append(ge.mesh.triangles())
            kinds.append(np.full(nf, KIND_DIELECTRIC))
            inside.append(np.full(nf, mg))
            outside.append(np.full(nf, MED_AIR))
            eta.append(np.full(nf, ge.eta))
            tex_id.append(np.full(nf, len(self.tex_e)))
            uvs.append(ge.mesh.corner_uv)
            dtooth.append(np.full(nf, -1))
            dface.append(np.full(nf, -1))
            self.tex_s.append(gs.a_t)
            self.tex_e.append(ge.a_t)
            self.tex_col.append(L.col("gums.a_t"))
        self.has_cavity = scene.cavity is not None
        if self.has_cavity:
            cm = scene.cavity.mesh
            nf = len(cm.faces)
            tris_s.append(sampling.cavity.mesh.triangles())
            tris_e.append(cm.triangles())
            kinds.append(np.full(nf, KIND_OPAQUE))
            inside.append(np.zeros(nf))
            outside.append(np.zeros(nf))
            eta.append(np.ones(nf))
            tex_id.append(np.full(nf, -1))
            uvs.append(np.zeros((nf, 3, 2)))
            dtooth.append(np.full(nf, -1))
            dface.append(np.full(nf, -1))
            self.rho_s = sampling.cavity.albedo.copy()
            self.rho_e = scene.cavity.albedo.copy()
            self.col_rho = L.col("cavity.albedo")
        self.tris_s = np.concatenate(tris_s)
        for part, tris in rest:
            tris_s[part] = tris
        # the sampling geometry with every dentin at its base shape: the BVHs' topology is built on this
        # (path_tracer_compiled._trees), so it does not depend on the coefficients or on earlier renders
        self.tris_rest = np.concatenate(tris_s)
        self.tris_e = np.concatenate(tris_e)
        self.kind = np.concatenate(kinds).astype(np.int64)
        self.inside = np.concatenate(inside).astype(np.int64)
        self.outside = np.concatenate(outside).astype(np.int64)
        self.eta = np.concatenate(eta).astype(np.float64)
        self.tex_id = np.concatenate(tex_id).astype(np.int64)
        self.corner_uv = np.concatenate(uvs)
        self.dentin_tooth = np.concatenate(dtooth).astype(np.int64)
        self.dentin_face = np.concatenate(dface).astype(np.int64)
        n = np.cross(self.tris_s[:, 1] - self.tris_s[:, 0], self.tris_s[:, 2] - self.tris_s[:, 0])
        self.normal_s = n / np.linalg.norm(n, axis=1, keepdims=True)
        self._use_embree = use_embree
        self._caster: RayCaster | None = None

    @property
    def caster(self) -> RayCaster:
        """First-hit queries on the sampling geometry (built on first use: the compiled tracer has its own)."""
        if self._caster is None:
            self._caster = RayCaster(self.tris_s, use_embree=self._use_embree)
        return self._caster
