"""The pile-fabric library materials under the studio lamps and under a sky HDRI (README picture).

Under lamps the fabric shader evaluates eq. 3.9 exactly for each lamp; under an environment (no
lamps) it integrates eq. 3.9 against the world's radiance itself (exact world light,
``core.fabric.environment_sampling``), so the pair shows the same model under both lightings. The
HDRI is ``closure_accuracy.sky_hdri`` (sky gradient and a sun-like hot spot), the one the accuracy
benchmark uses, turned so that the sun lights the ball from the camera's side as the studio's key
lamp does.
"""

from __future__ import annotations

import os

import numpy as np

FABRICS = ("Velvet (brushed)", "Corduroy", "Plush")


def render_under_hdri(name: str, workdir: str, resolution=(640, 480), samples: int = 16,
                      strength: float = 0.35) -> np.ndarray:
    """Library material ``name`` on its preview stage, the stage's lamps removed and the world lit by
    the sky HDRI (scaled by ``strength``); denoised for display. Linear RGBA (H, W, 4)."""
    import bpy

    from ..addon.fabric.material import sync_fabric_lamps
    from ..addon.fabric.verify import hdri_world
    from ..core.fabric.closure_accuracy import sky_hdri
    from ..render import denoise_for_display, render_to_array
    from . import library

    scene = library._fresh_scene(workdir, resolution, samples)
    entry = library.MATERIALS[name]
    material = entry.build(scene, workdir)
    (entry.preview or library.build_preview_scene)(scene, material)
    for obj in [o for o in scene.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(obj, do_unlink=True)
    sky = np.roll(sky_hdri(256, 512), 256, axis=1)  # sun turned to azimuth 300 deg: a key light from the camera side
    world = hdri_world(scene, sky * strength, os.path.join(workdir, "sky.exr"))
    world.node_tree.nodes["Environment Texture"].interpolation = "Linear"  # a picture, not a quadrature
    sync_fabric_lamps(scene)  # no lamps left; hands the sky to the exact world path
    denoise_for_display(scene)
    return render_to_array(scene)


def fabric_lighting_sheet(out_png: str, workdir: str, width: int = 640, samples: int = 16,
                          cell: tuple[int, int] = (320, 240)) -> str:
    """Render the three pile fabrics under lamps (left) and under the sky HDRI (right) at ``width`` px
    and write one labelled PNG (cells resized to ``cell``)."""
    from . import library
    from .contact_sheet import contact_sheet

    res = (width, width * 3 // 4)
    images, labels = [], []
    for name in FABRICS:
        images.append(library.render_material_preview(name, workdir, res, samples, denoise=True))
        labels.append(f"{name}: studio lamps (exact eq. 3.9)")
        images.append(render_under_hdri(name, workdir, res, samples))
        labels.append(f"{name}: sky HDRI (exact eq. 3.9)")
    sheet = contact_sheet(images, labels, columns=2, cell=cell, title="Pile fabric under lamps and under an HDRI")
    sheet.save(out_png, optimize=True)
    return out_png


if __name__ == "__main__":
    import sys
    import time

    from ..render.session import prepare_user_resources

    prepare_user_resources()
    start = time.monotonic()
    out = sys.argv[1] if len(sys.argv) > 1 else "docs/fabric-hdri.png"
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        fabric_lighting_sheet(out, tmp, width=int(sys.argv[2]) if len(sys.argv) > 2 else 640,
                              samples=int(sys.argv[3]) if len(sys.argv) > 3 else 16)
    print(f"{out} in {time.monotonic() - start:.0f} s")
