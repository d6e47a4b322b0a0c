"""Scratched metal in Blender (thesis ch. 4): shader group, packed scratch sets, lamp sync, tools.

How it fits together
--------------------
* ``cycles_osl/ms_scratch_metal.osl`` (+ ``ms_scratch.h``, generated ``ms_scratch_spectra.h``) ports
  ``core/scratch/scratch_radiance.py`` (energy "conserving", footprint rule "chords"; its Energy input 0
  gives "thesis") to OSL. Output:
  ``BSDF`` = (1 - rho_P) x base metal (GGX, F82-tint colour or complex IOR), which keeps seeing every
  lamp and the world, and ``Scratch`` = the scratch term through ``emission()``. Lamps are never
  light-linked away from scratched objects.
* ``material.py``: one node group per scratch set, ``Scratched Metal (<set>)``, one set per material
  (a new material's set name is made unique, ``Scratches.001``; an update writes only that set's own
  images, which the group holds by pointer); lamp inputs kept current by ``handlers.py``
  (depsgraph_update_post, render_pre) - moving a lamp just works.
  Lamps: point/spot with radius 0 -> point light (intensity P / 4 pi), radius r > 0 -> sphere light
  (radiance P / (4 pi^2 r^2)), sun -> directional (irradiance S), area square/rectangle -> polygon,
  disk/ellipse -> equal-area 16-gon (radiance P / (pi A), one-sided). At most 4 lamps (by name).
  Scratch shadows: one ``trace()`` per contributing lamp from the shading point to the lamp centre.
* ``tables.py``: the set is stored in the .blend as packed float images (source of truth) and
  extracted, on demand and after loading a file, into a content-addressed EXR cache folder
  ``<tempdir>/material_structures_scratch-<user>/<sha1>/`` (core ``scratch_io`` tables + two cell-major
  copies the shader walks), because OSL ``texture()`` needs a file path.
* Footprint: J = FootprintScale (default 0.5) x (d(x_um)/dx, d(x_um)/dy) from the UV map's ray
  differentials, x_um = UV x Tiling x patch size. Cycles keeps compact (isotropic) differentials:
  the two columns are orthogonal and one pixel wide on the surface, so oblique views are not
  elongated (measured; ``verify.footprint_pass``). Without differentials (e.g. bakes) the footprint
  is one coherence radius. Footprints beyond the set's index are shrunk exactly as in the core.
* ``world.py``: world (HDRI) light reaches the scratch term only through an opt-in approximation
  (the scene setting World Lights = K, ``scene.material_structures.scratch_world_lamps``): the K
  brightest environment regions as distant sphere lamps in free lamp slots. Measured error of the
  scratch term on a synthetic sun + sky: median 26 %, p99 79 % (``world.world_approximation_error``);
  the dim sky is dropped.
* Spectral mode (group input ``Spectral`` = 1): 16 bands instead of 3 wavelengths; a lamp's RGB
  colour feeds wavelengths >= 590 nm from R, 490-590 nm from G, below from B.
* Version differences handled by inputs the add-on sets: ``FlipT`` (texture t orientation) and
  ``GridAlpha`` (2-channel EXRs read as grey + alpha on 5.x, as R, G on 4.5).
* ``verify.py``: the flat-plate comparison used by tests and ``bench scratch-render``.
"""
