"""Compose labelled contact sheets of rendered previews (Pillow; no bpy needed)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..core.imaging import to_display_uint8

TITLE_SIZE = 16
LABEL_SIZE = 12


def _draw_words(draw, xy: tuple[int, int], text: str, font, fill, size: int) -> None:
    """``text`` with word gaps of at least a third of the font size (the default font's space is 2-3 px
    wide, which ran "Structures sample" together)."""
    x, y = xy
    gap = max(draw.textlength(" ", font=font), size / 3.0)
    for word in text.split(" "):
        draw.text((x, y), word, fill=fill, font=font)
        x += draw.textlength(word, font=font) + gap


def contact_sheet(
    images: Sequence[np.ndarray],
    labels: Sequence[str],
    columns: int = 4,
    cell: tuple[int, int] = (240, 180),
    title: str = "Material Structures sample library",
):
    """Linear RGB(A) images -> one labelled ``PIL.Image`` grid (cells resized to ``cell``)."""
    from PIL import Image, ImageDraw, ImageFont

    if len(images) != len(labels):
        raise ValueError("one label per image")
    columns = max(1, min(columns, len(images)))
    rows = max(1, math.ceil(len(images) / columns))
    pad, label_h, title_h = 8, 22, 34
    width = columns * (cell[0] + pad) + pad
    height = title_h + rows * (cell[1] + label_h + pad) + pad
    sheet = Image.new("RGB", (width, height), (24, 24, 26))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=LABEL_SIZE)
    _draw_words(draw, (pad, 8), title, ImageFont.load_default(size=TITLE_SIZE), (235, 235, 235), TITLE_SIZE)
    for k, (img, label) in enumerate(zip(images, labels, strict=True)):
        r, c = divmod(k, columns)
        x = pad + c * (cell[0] + pad)
        y = title_h + r * (cell[1] + label_h + pad)
        tile = Image.fromarray(to_display_uint8(img)).resize(cell, Image.Resampling.LANCZOS)
        sheet.paste(tile, (x, y))
        _draw_words(draw, (x + 2, y + cell[1] + 4), label, font, (220, 220, 220), LABEL_SIZE)
    return sheet
