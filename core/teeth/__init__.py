"""Teeth appearance model and differentiable volumetric path tracer (thesis chapter 5).

Modules, named in the thesis' terms:

* ``fresnel`` / ``enamel_transmission``: thin dielectric enamel boundary, eq. 5.1-5.2, 5.10.
* ``phase_function``: two-lobe Henyey-Greenstein phase function and its derivatives, eq. 5.4, 5.11-5.14.
* ``sigmoid_blend``: logistic blending of enamel/dentin parameters by distance to dentin, eq. 5.15-5.19.
* ``parameterisation``: dual domains sigma_t = exp(xi), albedo = 1 - 10^kappa, eq. 5.22, 5.24.
* ``distance_derivatives``: ray-triangle and point-triangle distance derivatives, eq. 5.28-5.29, 5.33-5.41.
* ``dentin_blend_shapes``: dentin blend-shape model V = B0 + c (B - B0), eq. 5.5, 5.26.
* ``tooth_mesh``: procedural incisor/canine/premolar/molar meshes with UVs; PLY/OBJ loading.
* ``scene``: the serialisable scene model (teeth, gums, oral-cavity proxy).
* ``capture``: calibrated cameras, point lights, default 54 x 3 rig, dataset folder format.
* ``ray_queries``: triangle-scene ray casting (embree via embreex, numpy fallback).
* ``path_tracer``: Monte Carlo volumetric path tracer with per-path analytic derivatives, eq. 5.7-5.32.
* ``param_vector``: flat parameter vector <-> scene.
* ``optimise``: L2 loss, Adam (eq. 2.38-2.39), best-loss tracking, "homogeneous"/"textured" phases.
* ``literature_init``: literature-table initialisation search.
* ``synthetic``: the synthetic ground-truth scene and capture used by tests, demos and benchmarks.
"""
