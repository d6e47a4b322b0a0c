"""The project's JSON file formats as JSON Schemas (``core/schemas/*.schema.json``, draft 2020-12), and a small
validator for the subset of JSON Schema they use, so that the add-on needs no ``jsonschema`` package (a desktop
Blender has none, and it needs the compiled ``rpds-py``).

Supported keywords: ``type`` (a name or a list of names), ``properties``, ``required``, ``additionalProperties``
(``false`` or a schema), ``propertyNames``, ``items``, ``minItems``, ``maxItems``, ``minimum``, ``maximum``,
``exclusiveMinimum``, ``exclusiveMaximum``, ``minLength``, ``pattern``, ``enum``, ``const``, ``$ref`` to
``#/$defs/NAME`` and ``oneOf``; annotations (``description``, ``title``, ``x-unit``, ...) are ignored, as the
standard says. Semantics follow the standard (``tests/core/test_json_schema.py`` checks them against the
``jsonschema`` package): booleans are not numbers, 1.0 is an integer, and NaN passes ``minimum`` (the loaders
refuse non-finite values themselves). ``x-unit`` is this project's annotation: the physical unit of a number
(or of each number in an array), shown in the documentation (``docs/gen_formats.py``).

A loader calls :func:`check` on the document it parsed; a document the schema refuses raises
:class:`~core.errors.UserError` with one line: ``FILE: WHERE: WHAT``, e.g.
``.../capture.json: lights[2].position: expected 3 numbers, got 2``.
"""

from __future__ import annotations

import json
import os
import re
from functools import cache

from .errors import UserError

SCHEMA_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "schemas")
KNOWN = frozenset({
    "$schema", "$id", "$defs", "$ref", "$comment", "title", "description", "x-unit", "examples", "default",
    "type", "properties", "required", "additionalProperties", "propertyNames", "items", "minItems", "maxItems",
    "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "minLength", "pattern", "enum", "const", "oneOf",
})
_NOUN = {"object": "an object", "array": "a list", "string": "a string", "number": "a number",
         "integer": "an integer", "boolean": "true or false", "null": "null"}
_PLURAL = {"number": "numbers", "integer": "integers", "string": "strings", "object": "objects", "array": "lists"}


class SchemaError(Exception):
    """A document the schema refuses: ``where`` (a path such as ``lights[2].position``) and ``what``."""

    def __init__(self, where: str, what: str) -> None:
        super().__init__(f"{where}: {what}" if where else what)
        self.where, self.what = where, what


def schema_names() -> list[str]:
    """The names of the schemas in ``core/schemas`` (``capture`` for ``capture.schema.json``)."""
    return sorted(f[: -len(".schema.json")] for f in os.listdir(SCHEMA_DIR) if f.endswith(".schema.json"))


@cache
def load_schema(name: str) -> dict:
    """The schema ``core/schemas/NAME.schema.json``, checked to use only the keywords this validator knows."""
    with open(os.path.join(SCHEMA_DIR, f"{name}.schema.json"), encoding="utf-8") as f:
        schema = json.load(f)
    _check_keywords(schema, name)
    return schema


def _check_keywords(node, where: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            if key not in KNOWN:
                raise ValueError(f"schema {where}: keyword {key!r} is not supported by core/json_schema.py")
            if key in ("properties", "$defs"):
                for k, sub in value.items():
                    _check_keywords(sub, f"{where}/{key}/{k}")
            elif key in ("items", "additionalProperties", "propertyNames"):
                _check_keywords(value, f"{where}/{key}")
            elif key == "oneOf":
                for i, sub in enumerate(value):
                    _check_keywords(sub, f"{where}/oneOf/{i}")


def _json_type(x) -> str:
    if x is None:
        return "null"
    if isinstance(x, bool):
        return "boolean"
    if isinstance(x, int):
        return "integer"
    if isinstance(x, float):
        return "number"
    if isinstance(x, str):
        return "string"
    if isinstance(x, (list, tuple)):
        return "array"
    if isinstance(x, dict):
        return "object"
    return type(x).__name__


def _is(x, t: str) -> bool:
    k = _json_type(x)
    if t == "number":
        return k in ("integer", "number")
    if t == "integer":
        return k == "integer" or (k == "number" and x.is_integer())
    return k == t


def _show(x) -> str:
    k = _json_type(x)
    if k == "array":
        return f"a list of {len(x)}"
    if k == "object":
        return _NOUN[k]
    text = json.dumps(x) if k != "number" or x == x else "NaN"
    return text if len(text) <= 40 else text[:37] + "..."


def _where(path: tuple) -> str:
    out = ""
    for p in path:
        if isinstance(p, int):
            out += f"[{p}]"
        elif re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", p):
            out += f".{p}" if out else p
        else:
            out += f"[{json.dumps(p)}]"
    return out


class _Validator:
    def __init__(self, root: dict) -> None:
        self.root = root

    def resolve(self, schema: dict) -> dict:
        while "$ref" in schema:
            ref = schema["$ref"]
            if not ref.startswith("#/$defs/"):
                raise ValueError(f"unsupported $ref {ref!r} (only #/$defs/NAME)")
            schema = self.root["$defs"][ref[len("#/$defs/"):]]
        return schema

    def expected(self, schema: dict) -> str:
        """What ``schema`` wants, in words (for errors)."""
        schema = self.resolve(schema)
        if "title" in schema:
            return schema["title"]
        if "const" in schema:
            return _show(schema["const"])
        t = schema.get("type")
        if t == "array" and schema.get("minItems") is not None and schema.get("minItems") == schema.get("maxItems"):
            return self.count_words(schema)
        if isinstance(t, list):
            return " or ".join(_NOUN.get(x, x) for x in t)
        if isinstance(t, str):
            return _NOUN.get(t, t)
        if "oneOf" in schema:
            return " or ".join(self.expected(s) for s in schema["oneOf"])
        return "something else"

    def count_words(self, schema: dict) -> str:
        """``3 numbers`` for an array of exactly 3 numbers."""
        item = self.resolve(schema.get("items", {})).get("type")
        return f"{schema['minItems']} {_PLURAL.get(item, 'items') if isinstance(item, str) else 'items'}"

    def validate(self, x, schema: dict, path: tuple) -> None:
        schema = self.resolve(schema)
        t = schema.get("type")
        if t is not None:
            types = t if isinstance(t, list) else (t,)
            if not any(_is(x, ty) for ty in types):
                raise SchemaError(_where(path), f"expected {self.expected(schema)}, got {_show(x)}")
        if "const" in schema and not _equal(x, schema["const"]):
            raise SchemaError(_where(path), f"expected {_show(schema['const'])}, got {_show(x)}")
        if "enum" in schema and not any(_equal(x, e) for e in schema["enum"]):
            raise SchemaError(_where(path), f"expected one of {', '.join(_show(e) for e in schema['enum'])}, "
                                            f"got {_show(x)}")
        if "oneOf" in schema:
            self.one_of(x, schema, path)
        k = _json_type(x)
        if k in ("integer", "number"):
            self.number(x, schema, path)
        elif k == "string":
            if "minLength" in schema and len(x) < schema["minLength"]:
                raise SchemaError(_where(path), "expected a non-empty string" if schema["minLength"] == 1 else
                                  f"expected at least {schema['minLength']} characters, got {len(x)}")
            if "pattern" in schema and not re.search(schema["pattern"], x):
                raise SchemaError(_where(path), f"{_show(x)} is not {schema.get('title', 'of the right form')}")
        elif k == "array":
            self.array(x, schema, path)
        elif k == "object":
            self.object(x, schema, path)

    def number(self, x, schema: dict, path: tuple) -> None:
        for key, bad, word in (("minimum", lambda v, b: v < b, ">="), ("maximum", lambda v, b: v > b, "<="),
                               ("exclusiveMinimum", lambda v, b: v <= b, ">"),
                               ("exclusiveMaximum", lambda v, b: v >= b, "<")):
            if key in schema and bad(x, schema[key]):
                raise SchemaError(_where(path), f"must be {word} {_show(schema[key])}, got {_show(x)}")

    def array(self, x, schema: dict, path: tuple) -> None:
        lo, hi = schema.get("minItems"), schema.get("maxItems")
        if (lo is not None and len(x) < lo) or (hi is not None and len(x) > hi):
            if lo is not None and lo == hi:
                want = self.count_words(schema)
            elif lo == 1 and hi is None:
                want = "a non-empty list"
            else:
                want = (f"at least {lo}" if hi is None else f"at most {hi}" if lo is None else f"{lo} to {hi}") + \
                    " items"
            raise SchemaError(_where(path), f"expected {want}, got {len(x)}")
        items = schema.get("items")
        if items is not None:
            items = self.resolve(items)
            if set(items) <= {"type", "description", "x-unit"} and items.get("type") == "number":  # the fast path
                for i, v in enumerate(x):
                    if isinstance(v, bool) or not isinstance(v, (int, float)):
                        raise SchemaError(_where(path + (i,)), f"expected a number, got {_show(v)}")
                return
            for i, v in enumerate(x):
                self.validate(v, items, path + (i,))

    def object(self, x, schema: dict, path: tuple) -> None:
        for key in schema.get("required", ()):
            if key not in x:
                raise SchemaError(_where(path), f"lacks the field {key!r}")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        names = schema.get("propertyNames")
        for key, v in x.items():
            if names is not None:
                try:
                    self.validate(key, names, ())
                except SchemaError as e:
                    raise SchemaError(_where(path), f"key {e.what}") from None
            if key in props:
                self.validate(v, props[key], path + (key,))
            elif extra is False:
                known = ", ".join(props)
                raise SchemaError(_where(path), f"unknown field {key!r} (known: {known})")
            elif isinstance(extra, dict):
                self.validate(v, extra, path + (key,))

    def one_of(self, x, schema: dict, path: tuple) -> None:
        matched, errors = [], []
        for i, sub in enumerate(schema["oneOf"]):
            try:
                self.validate(x, sub, path)
                matched.append(i)
            except SchemaError as e:
                errors.append(e)
        if len(matched) == 1:
            return
        if matched:
            raise SchemaError(_where(path), f"matches more than one of: {self.expected(schema)}")
        # the branch whose type fits says the most precise thing; else name the alternatives
        fitting = [(e, sub) for e, sub in zip(errors, schema["oneOf"], strict=True)
                   if "type" not in self.resolve(sub) or any(_is(x, t) for t in _types(self.resolve(sub)))]
        if len(fitting) == 1:
            raise fitting[0][0]
        raise SchemaError(_where(path), f"expected {self.expected(schema)}, got {_show(x)}")


def _types(schema: dict) -> tuple:
    t = schema["type"]
    return tuple(t) if isinstance(t, list) else (t,)


def _equal(a, b) -> bool:
    """JSON equality: 1 == 1.0, but true is not 1."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_equal(u, v) for u, v in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return a == b


def first_error(doc, schema: dict) -> SchemaError | None:
    """The first place where ``doc`` breaks ``schema`` (a schema dict), or None when it is valid."""
    try:
        _Validator(schema).validate(doc, schema, ())
    except SchemaError as e:
        return e
    return None


def errors(doc, name: str) -> SchemaError | None:
    """The first place where ``doc`` breaks schema ``name`` (``core/schemas/NAME.schema.json``), or None."""
    return first_error(doc, load_schema(name))


def check(doc, name: str, source: str | os.PathLike) -> None:
    """Refuse ``doc`` (read from ``source``) unless it is valid under schema ``name``: a one-line
    :class:`UserError` ``SOURCE: WHERE: WHAT``."""
    e = errors(doc, name)
    if e is not None:
        raise UserError(f"{os.fspath(source)}: {e}")
