"""core.png_io writes PNGs that an independent decoder (Pillow) reads back pixel for pixel."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.png_io import png_bytes, write_png


def test_png_round_trips_through_pillow(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    rgb = np.random.default_rng(3).integers(0, 256, size=(7, 13, 3), dtype=np.uint8)
    path = tmp_path / "x.png"
    write_png(path, rgb)
    np.testing.assert_array_equal(np.asarray(Image.open(path).convert("RGB")), rgb)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"]  # no temporary left


def test_png_refuses_what_is_not_an_rgb_image():
    for bad in (np.zeros((4, 4)), np.zeros((4, 4, 4)), np.zeros((0, 3, 3))):
        with pytest.raises(ValueError, match="png"):
            png_bytes(bad)
