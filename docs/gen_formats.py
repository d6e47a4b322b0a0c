"""The JSON formats' field tables, rendered from their schemas (``core/schemas/NAME.schema.json``).

An MkDocs hook (``hooks:`` in mkdocs.yml): at build time it replaces each marker line ``<!-- schema: NAME -->`` in
``formats.md`` with that schema's tables (field, type, unit, description), so the reference is the schema the
loaders validate with, never a hand-written copy. ``python docs/gen_formats.py NAME`` prints the same Markdown.
It reads the schema files directly (no import of the package), so it runs wherever MkDocs does.
"""

from __future__ import annotations

import json
import os
import re
import sys

PAGE = "formats.md"
MARKER = re.compile(r"^<!-- schema: ([\w-]+) -->$", re.M)
SCHEMA_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "core", "schemas")


def load(name: str) -> dict:
    with open(os.path.join(SCHEMA_DIR, f"{name}.schema.json"), encoding="utf-8") as f:
        return json.load(f)


def _def_name(node: dict) -> str | None:
    ref = node.get("$ref", "")
    return ref.rsplit("/", 1)[1] if ref.startswith("#/$defs/") else None


def _resolve(root: dict, node: dict) -> dict:
    while _def_name(node):
        node = root["$defs"][_def_name(node)]
    return node


def _is_table(node: dict) -> bool:
    """An object with fields of its own: it gets rows (inline) or a table (a $def)."""
    return "properties" in node


def _bounds(node: dict) -> str:
    lo = [f">= {node['minimum']:g}"] if "minimum" in node else [f"> {node['exclusiveMinimum']:g}"] \
        if "exclusiveMinimum" in node else []
    hi = [f"<= {node['maximum']:g}"] if "maximum" in node else [f"< {node['exclusiveMaximum']:g}"] \
        if "exclusiveMaximum" in node else []
    return ", ".join(lo + hi)


def type_text(root: dict, node: dict) -> str:
    """The field's kind in a few words: ``3 numbers, >= 0``, ``integer, >= 1, <= 16384``, ``list of `camera```."""
    name = _def_name(node)
    target = _resolve(root, node)
    if name and _is_table(target):
        return f"`{name}` (below)"
    if "const" in target:
        return f"`{json.dumps(target['const'])}`"
    if "oneOf" in target:
        return " or ".join(type_text(root, s) for s in target["oneOf"])
    if "title" in target:
        return target["title"]
    t = target.get("type")
    if isinstance(t, list):
        if "null" in t and len(t) == 2:
            other = [x for x in t if x != "null"][0]
            return f"{type_text(root, {**target, 'type': other})} or null"
        return " or ".join(t)
    if t == "array":
        items = _resolve(root, target.get("items", {}))
        n = target.get("minItems")
        count = str(n) if n is not None and n == target.get("maxItems") else "N"
        scalar = items.get("type") if items.get("type") in ("number", "integer", "string") else None
        if scalar and "title" not in items:  # 3 numbers, >= 0
            bounds = _bounds(items)
            text = f"{count} {scalar}s" + (f", {bounds}" if bounds else "")
        else:
            inner = type_text(root, target.get("items", {}))
            if re.fullmatch(r"[\dN x]+ (numbers|integers)(, .*)?", inner):  # nested lists: 3 x 3 numbers
                text = f"{count} x {inner}"
            else:
                text = f"list of {inner}"
        if count == "N" and (target.get("minItems") or 0) >= 1:
            text += f" (N >= {target['minItems']})"
        return text
    if t == "object" and "additionalProperties" in target and isinstance(target["additionalProperties"], dict):
        return f"object: key -> {type_text(root, target['additionalProperties'])}"
    bounds = _bounds(target)
    return f"{t}, {bounds}" if bounds else (t or "any")


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _rows(root: dict, node: dict, prefix: str):
    """(field, type, unit, description) of every field of ``node``, inline objects and lists of them expanded."""
    required = set(node.get("required", ()))
    for key, sub in node.get("properties", {}).items():
        target = _resolve(root, sub)
        desc = sub.get("description") or target.get("description", "")
        unit = sub.get("x-unit") or target.get("x-unit", "")
        if target.get("items"):
            unit = unit or _resolve(root, target["items"]).get("x-unit", "")
        field = f"`{prefix}{key}`" + ("" if key in required else " (optional)")
        yield field, type_text(root, sub), unit, desc
        if _def_name(sub):
            continue
        if _is_table(target):
            yield from _rows(root, target, f"{prefix}{key}.")
        elif target.get("type") == "array" and _is_table(_resolve(root, target.get("items", {}))) \
                and not _def_name(target["items"]):
            yield from _rows(root, target["items"], f"{prefix}{key}[i].")


def _table(rows) -> str:
    lines = ["| field | type | unit | description |", "|---|---|---|---|"]
    lines += [f"| {' | '.join(_cell(c) for c in row)} |" for row in rows]
    return "\n".join(lines)


def _referenced(root: dict, node, seen: list) -> list:
    """The $defs with fields of their own that ``node`` refers to, in order of first reference (transitively)."""
    if isinstance(node, dict):
        name = _def_name(node)
        if name and name not in seen and _is_table(root["$defs"][name]):
            seen.append(name)
            _referenced(root, root["$defs"][name], seen)
        for key, value in node.items():
            if key != "$defs":
                _referenced(root, value, seen)
    elif isinstance(node, list):
        for value in node:
            _referenced(root, value, seen)
    return seen


def render(name: str) -> str:
    """Markdown for schema ``name``: its description, the table of its fields, then a table per object type."""
    root = load(name)
    parts = [f"{root['description']} Schema: `core/schemas/{name}.schema.json` (JSON Schema draft 2020-12).", ""]
    if _is_table(root):
        parts.append(_table(_rows(root, root, "")))
    else:  # a list at the top (the curves file)
        parts.append(_table([("(the file)", type_text(root, root), "", "one entry per curve"),
                             ("`[i]`", type_text(root, root["items"]), "", root["items"]["description"]),
                             ("`[i][j]`", type_text(root, root["items"]["items"]),
                              root["items"]["items"].get("x-unit", ""), root["items"]["items"]["description"])]))
    for d in _referenced(root, {k: v for k, v in root.items() if k != "$defs"}, []):
        node = root["$defs"][d]
        parts += ["", f"`{d}`" + (f": {node['description']}" if node.get("description") else ""), "",
                  _table(_rows(root, node, ""))]
    return "\n".join(parts)


def on_page_markdown(markdown: str, page, config, files) -> str:  # MkDocs hook
    if page.file.src_uri == PAGE:
        return MARKER.sub(lambda m: render(m.group(1)), markdown)
    return markdown


def expand(markdown: str) -> str:
    """``markdown`` with every schema marker replaced by its tables (what the hook does)."""
    return MARKER.sub(lambda m: render(m.group(1)), markdown)


if __name__ == "__main__":
    for arg in sys.argv[1:] or sorted(f[: -len(".schema.json")] for f in os.listdir(SCHEMA_DIR)):
        print(f"## {arg}\n\n{render(arg)}\n")
