"""Add Tooth with a dental-atlas template (core.teeth.anatomy): the pair is the core's mesh at the scene's scale."""

from __future__ import annotations

import bpy
import numpy as np
import pytest


@pytest.mark.parametrize("template", ["upper_central", "upper_premolar"])
def test_add_anatomical_tooth(addon_module, template):
    from material_structures.core.teeth.anatomy import SPECS, make_anatomical_tooth

    assert bpy.ops.material_structures.teeth_add_tooth(kind=template.upper(), resolution=24) == {"FINISHED"}
    enamel = bpy.context.active_object
    dentin = enamel.ms_tooth.partner
    geo = make_anatomical_tooth(template, 24)
    assert enamel.ms_tooth.kind == SPECS[template].kind and dentin is not None
    assert len(dentin.data.vertices) == len(geo.dentin.base.vertices)
    assert [k.name for k in dentin.data.shape_keys.key_blocks] == ["Basis", "buccal", "proximal", "occlusal"]
    co = np.empty(len(enamel.data.vertices) * 3, dtype=np.float32)
    enamel.data.vertices.foreach_get("co", co)
    outer = co.reshape(-1, 3)[: len(geo.enamel.vertices)]
    np.testing.assert_allclose(outer, geo.enamel.vertices, atol=1e-5)  # mm, object scale 1 / 1000
    assert enamel.scale[0] == pytest.approx(1e-3)
