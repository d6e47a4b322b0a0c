"""Compose labelled contact sheets of rendered previews (Pillow; no bpy needed)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..core.imaging import to_display_uint8


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
    font = ImageFont.load_default()
    draw.text((pad, 10), title, fill=(235, 235, 235), font=font)
    for k, (img, label) in enumerate(zip(images, labels, strict=True)):
        r, c = divmod(k, columns)
        x = pad + c * (cell[0] + pad)
        y = title_h + r * (cell[1] + label_h + pad)
        tile = Image.fromarray(to_display_uint8(img)).resize(cell, Image.Resampling.LANCZOS)
        sheet.paste(tile, (x, y))
        draw.text((x + 2, y + cell[1] + 4), label, fill=(220, 220, 220), font=font)
    return sheet
