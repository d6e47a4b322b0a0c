"""The add-on speaks a user's words: no CLI flags, equation numbers, "Lamp" or replay internals in what
Blender shows (labels, tooltips, property names and descriptions, enum items), one capitalisation for
descriptions (a capital first letter) and for enum identifiers (UPPER_CASE)."""

from __future__ import annotations

import re
import sys

import bpy
import pytest

BANNED = [
    (re.compile(r"(?<![\w-])--\w"), "a command-line flag"),
    (re.compile(r"\b[Ee]qs?\.\s*\d|\bequation \d|\([345]\.\d+\)"), "an equation number"),
    (re.compile(r"\b[Ll]amps?\b"), "'Lamp' (Blender calls them lights)"),
    (re.compile(r"\bEXEC\b|\breplays?\b"), "how scripts call it"),
    (re.compile(r"\b[Ss]ec\.\s*\d"), "a thesis section number"),
]

def _texts(addon_module) -> list[tuple[str, str, str]]:
    """(where, kind, text) of every string the registered classes show in Blender."""
    out = []
    for cls in sys.modules[f"{addon_module}.addon"].CLASSES:
        rna = cls.bl_rna
        if issubclass(cls, bpy.types.Operator):  # its properties are on the operator's RNA type
            module, op = cls.bl_idname.split(".")
            rna = getattr(getattr(bpy.ops, module), op).get_rna_type()
        name = cls.__name__
        for attr in ("bl_label", "bl_description"):
            text = getattr(cls, attr, "") or ""
            if attr == "bl_description":
                text = rna.description or ""
            if text:
                out.append((name, attr, text))
        for prop in rna.properties:
            if prop.identifier in ("rna_type",):
                continue
            where = f"{name}.{prop.identifier}"
            if prop.name:
                out.append((where, "name", prop.name))
            if prop.description:
                out.append((where, "description", prop.description))
            if prop.type == "ENUM":
                for item in prop.enum_items:
                    out.append((f"{where}[{item.identifier}]", "enum_id", item.identifier))
                    if item.name:
                        out.append((f"{where}[{item.identifier}]", "name", item.name))
                    if item.description:
                        out.append((f"{where}[{item.identifier}]", "description", item.description))
    return out


def test_ui_strings_are_in_a_users_words(addon_module):
    bad = [f"{where} {kind}: {why}: {text!r}" for where, kind, text in _texts(addon_module)
           for rx, why in BANNED if kind != "enum_id" and rx.search(text)]
    assert not bad, "\n".join(bad)


def test_one_capitalisation(addon_module):
    texts = _texts(addon_module)
    assert len(texts) > 100
    bad = [f"{where}: description starts lower-case: {text!r}" for where, kind, text in texts
           if kind in ("description", "bl_description") and text[:1].islower()]
    bad += [f"{where}: enum identifier not UPPER_CASE: {text!r}" for where, kind, text in texts
            if kind == "enum_id" and not re.fullmatch(r"[A-Z0-9_]+", text)]
    assert not bad, "\n".join(bad)


def test_panels_share_one_base(addon_module):
    panels = [c for c in sys.modules[f"{addon_module}.addon"].CLASSES if issubclass(c, bpy.types.Panel)]
    assert panels
    base = sys.modules[f"{addon_module}.addon.common"].Panel
    assert all(issubclass(c, base) for c in panels), [c.__name__ for c in panels if not issubclass(c, base)]


@pytest.mark.parametrize("text", ["use --iterations 5", "eq. 3.9", "Sync Lamps", "EXEC replays stroke"])
def test_the_scan_catches(text):
    assert any(rx.search(text) for rx, _ in BANNED)
