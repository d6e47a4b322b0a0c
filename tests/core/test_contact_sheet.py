"""The demo's contact sheet: its title's words stay apart (the default font's 2-3 px space ran
"Material Structuressample library" together)."""

from __future__ import annotations

import numpy as np

from material_structures.showcase.contact_sheet import TITLE_SIZE, contact_sheet


def _word_gaps(band: np.ndarray) -> list[int]:
    """Widths of the empty column runs between the first and last inked column of a text band."""
    inked = (band.max(axis=(0, 2)) > 120)
    cols = np.flatnonzero(inked)
    gaps, run = [], 0
    for c in range(cols[0], cols[-1] + 1):
        if inked[c]:
            if run:
                gaps.append(run)
            run = 0
        else:
            run += 1
    return gaps


def test_title_words_are_separated():
    sheet = np.asarray(contact_sheet([np.full((20, 30, 3), 0.2)] * 2, ["a", "b"]))
    gaps = _word_gaps(sheet[4:30, :, :])
    # four words: three gaps of at least a third of the font size; letters within a word are closer
    wide = [g for g in gaps if g >= TITLE_SIZE // 3]
    assert len(wide) == 3, gaps
