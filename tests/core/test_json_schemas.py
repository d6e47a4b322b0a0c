"""The JSON file formats as schemas (``core/schemas/*.schema.json``) and the in-house validator
(``core/json_schema.py``, for the add-on, which cannot import ``jsonschema``):

* every schema is a valid draft 2020-12 schema that uses only the keywords the validator knows, and describes
  every property;
* the validator accepts and refuses the same documents as the ``jsonschema`` package: small schemas for each
  keyword's corner cases, and every file the project writes (``fabric synth``, ``fabric fit``, ``teeth synth``,
  ``teeth fit``) with hundreds of mutations of each;
* the schemas accept every file the project writes;
* the loaders refuse what the schemas refuse, in one line ``FILE: WHERE: WHAT`` (exit 2 from the command line).
"""

from __future__ import annotations

import copy
import json
import random

import jsonschema
import pytest

from material_structures.cli import main
from material_structures.core import json_schema as J
from material_structures.core.errors import UserError

DRAFT = "https://json-schema.org/draft/2020-12/schema"
# the files the project writes include a teeth capture and fit (the compiled tracer): wait for the numba warm-up
# (tests/conftest.py) rather than compile it a second time beside it
pytestmark = pytest.mark.numba


# ---- the schemas themselves

def _properties(node, where=""):
    """(where, property schema) of every property declared anywhere in a schema."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "properties":
                for name, sub in value.items():
                    yield f"{where}/{name}", sub
                    yield from _properties(sub, f"{where}/{name}")
            elif key == "$defs":
                for name, sub in value.items():
                    yield from _properties(sub, f"{where}/$defs/{name}")
            elif key in ("items", "additionalProperties", "oneOf"):
                yield from _properties(value, f"{where}/{key}")
    elif isinstance(node, list):
        for i, sub in enumerate(node):
            yield from _properties(sub, f"{where}/{i}")


@pytest.mark.parametrize("name", J.schema_names())
def test_each_schema_is_draft_2020_12_and_describes_every_property(name):
    schema = J.load_schema(name)  # also refuses a keyword core/json_schema.py does not implement
    assert schema["$schema"] == DRAFT
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema.get("title") and schema.get("description")
    props = list(_properties(schema))
    assert props or schema["type"] == "array"  # the curves file is a list: its items are described
    for where, sub in props:
        target = sub
        if "$ref" in sub and "description" not in sub:  # a property may take its description from its $def
            target = schema["$defs"][sub["$ref"].rsplit("/", 1)[1]]
        assert target.get("description"), f"{name}{where} has no description"


def test_the_schemas_name_every_format_and_their_limits_match_the_loaders():
    from material_structures.core.fabric import btf_io
    from material_structures.core.teeth import capture, scene

    assert set(J.schema_names()) == {"btf", "capture", "fabric-params", "scratch-curves", "teeth-fit-report",
                                     "teeth-scene"}
    btf, cap, sc = J.load_schema("btf"), J.load_schema("capture"), J.load_schema("teeth-scene")
    assert btf["properties"]["width"]["maximum"] == btf_io.MAX_SIDE
    assert cap["$defs"]["camera"]["properties"]["width"]["maximum"] == capture.MAX_SIDE
    assert cap["properties"]["format"]["const"] == capture.FORMAT
    assert sc["properties"]["format"]["const"] == scene.SCENE_FORMAT


def test_the_format_reference_renders_every_schema():
    import os
    import re

    docs = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "docs")
    with open(os.path.join(docs, "formats.md"), encoding="utf-8") as f:
        markers = re.findall(r"^<!-- schema: ([\w-]+) -->$", f.read(), re.M)
    assert sorted(markers) == J.schema_names()


# ---- the validator against jsonschema, keyword by keyword

def _same(doc, schema) -> bool:
    mine = J.first_error(doc, schema) is None
    theirs = jsonschema.Draft202012Validator(schema).is_valid(doc)
    assert mine == theirs, (doc, schema, J.first_error(doc, schema))
    return mine


NAN = float("nan")
KEYWORD_CASES = [
    ({"type": "number"}, [1, 1.5, True, "1", None, NAN, [1]]),
    ({"type": "integer"}, [1, 1.0, 1.5, True, False, "1", -3]),
    ({"type": ["object", "null"]}, [None, {}, [], 0]),
    ({"type": "boolean"}, [True, False, 0, 1, None]),
    ({"minimum": 0, "maximum": 1}, [0, 1, -1e-9, 1.0000001, NAN, "x", True]),
    ({"exclusiveMinimum": 0, "exclusiveMaximum": 1}, [0, 1, 0.5, -1, NAN]),
    ({"const": 1}, [1, 1.0, True, "1", [1]]),
    ({"const": "a"}, ["a", "b", None]),
    ({"enum": ["a", 2, None]}, ["a", 2, 2.0, None, False, "b"]),
    ({"type": "string", "minLength": 1, "pattern": "^[0-9]+,[0-9]+$"}, ["", "1,2", "12,3x", "x1,2", "a"]),
    ({"type": "array", "minItems": 2, "maxItems": 3, "items": {"type": "number"}},
     [[], [1], [1, 2], [1, 2, 3], [1, 2, 3, 4], [1, "2"], [True, 1], "12", {"0": 1}]),
    ({"type": "object", "required": ["a"], "properties": {"a": {"type": "integer"}}, "additionalProperties": False},
     [{}, {"a": 1}, {"a": 1, "b": 2}, {"a": "1"}, {"b": 1}, [], "a"]),
    ({"type": "object", "additionalProperties": {"type": "string"},
      "propertyNames": {"type": "string", "pattern": "^[0-9]+$"}}, [{}, {"1": "a"}, {"1": 2}, {"x": "a"}]),
    ({"$defs": {"rgb": {"type": "array", "minItems": 3, "maxItems": 3, "items": {"type": "number"}}},
      "oneOf": [{"$ref": "#/$defs/rgb"},
                {"type": "array", "items": {"type": "array", "items": {"$ref": "#/$defs/rgb"}}}]},
     [[1, 2, 3], [[[1, 2, 3]]], [[1, 2, 3]], [], [1, 2], "x", [[[1, 2]]]]),  # [] is both: oneOf refuses it
    ({"oneOf": [{"type": "integer"}, {"type": "number", "minimum": 2}]}, [1, 2, 2.5, 0.5, "x"]),
]


@pytest.mark.parametrize("schema, docs", KEYWORD_CASES, ids=[str(i) for i in range(len(KEYWORD_CASES))])
def test_the_validator_agrees_with_jsonschema_on_each_keyword(schema, docs):
    results = [_same(d, schema) for d in docs]
    assert any(results) and not all(results)  # each case holds a document of each kind


# ---- files the project writes

@pytest.fixture(scope="module")
def synthesised(tmp_path_factory):
    """``fabric synth`` (BTF folder and ground-truth maps) and ``teeth synth`` (capture and scene), tiny."""
    d = tmp_path_factory.mktemp("synth")
    assert main(["fabric", "synth", "--out", str(d / "btf"), "--width", "2", "--height", "2", "--lights", "8",
                 "--views", "8", "--gt-out", str(d / "gt")]) == 0
    assert main(["teeth", "synth", str(d / "cap"), "--teeth", "1", "--width", "12", "--height", "10", "--lights",
                 "4", "--cameras", "1", "--spp", "1", "--spp-background", "0", "--resolution", "10"]) == 0
    return d


@pytest.fixture(scope="module")
def fitted(synthesised):
    """A fabric fit of that BTF and a one-iteration teeth fit of that capture (from its own scene)."""
    d = synthesised
    assert main(["fabric", "fit", str(d / "btf"), "--out", str(d / "ffit"), "--no-dask", "--workers", "1",
                 "--no-progress"]) == 0
    assert main(["teeth", "fit", str(d / "cap"), "--out", str(d / "tfit"), "--iterations", "1", "--init", "scene",
                 "--no-progress"]) == 0
    return d


SYNTH_FILES = [("btf/btf.json", "btf"), ("gt/params.json", "fabric-params"), ("cap/capture.json", "capture"),
               ("cap/scene.json", "teeth-scene")]
FIT_FILES = [("ffit/params.json", "fabric-params"), ("tfit/scene_fit.json", "teeth-scene"),
             ("tfit/scene_best.json", "teeth-scene"), ("tfit/fit_report.json", "teeth-fit-report")]
CURVES = [[[0.1, 0.1], [0.9, 0.5]], [[0.2, 0.8], [0.5, 0.5], [0.8, 0.9]]]  # as the scratch tutorial's


def _read(folder, rel):
    return json.loads((folder / rel).read_text())


@pytest.mark.parametrize("rel, name", SYNTH_FILES)
def test_the_schemas_accept_what_the_synthesisers_write(synthesised, rel, name):
    doc = _read(synthesised, rel)
    assert J.errors(doc, name) is None, J.errors(doc, name)
    jsonschema.validate(doc, J.load_schema(name))


@pytest.mark.heavy
@pytest.mark.parametrize("rel, name", FIT_FILES)
def test_the_schemas_accept_what_the_fits_write(fitted, rel, name):
    doc = _read(fitted, rel)
    assert J.errors(doc, name) is None, J.errors(doc, name)
    jsonschema.validate(doc, J.load_schema(name))


def test_the_curves_schema_accepts_a_curves_file():
    assert J.errors(CURVES, "scratch-curves") is None
    jsonschema.validate(CURVES, J.load_schema("scratch-curves"))


def _shrink(doc, n=5):
    """Every list cut to its first ``n`` items: a mesh of thousands of vertices validates as fast as a triangle
    (the schemas relate no two fields), so that hundreds of mutants stay cheap for jsonschema."""
    if isinstance(doc, dict):
        return {k: _shrink(v, n) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_shrink(v, n) for v in doc[:n]]
    return doc


def _nodes(doc, path=()):
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _nodes(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _nodes(v, path + (i,))


REPLACEMENTS = ["x", "", None, True, -1, 0, 0.5, 1.0, 2, 4.5, 1e9, NAN, [], {}, [1, 2], [0, 0, 0], [[0, 0, 1]],
                "material_structures.teeth.scene/1", "mm", "0,1"]


def _mutants(doc, seed: int, count: int):
    """``count`` copies of ``doc``, each changed in one place: a value replaced, a field dropped or added, a
    list cut, emptied or grown."""
    rng = random.Random(seed)
    nodes = list(_nodes(doc))
    for _ in range(count):
        path, node = rng.choice(nodes)
        m = copy.deepcopy(doc)
        parent = m
        for p in path[:-1]:
            parent = parent[p]
        target = parent[path[-1]] if path else m
        kind = rng.randrange(4)
        if kind == 1 and isinstance(target, dict) and target:
            target.pop(rng.choice(sorted(target)))
        elif kind == 1 and isinstance(target, dict):
            target["extra"] = 1
        elif kind == 2 and isinstance(target, dict):
            target[rng.choice(["extra", "name", "0", "7,7"])] = copy.deepcopy(rng.choice(REPLACEMENTS))
        elif kind in (1, 2) and isinstance(target, list) and target:
            if kind == 1:
                target.pop()
            else:
                target.append(copy.deepcopy(target[0]))
        elif kind == 3 and isinstance(target, list):
            target.clear()
        elif path:
            parent[path[-1]] = copy.deepcopy(rng.choice(REPLACEMENTS))
        else:
            m = copy.deepcopy(rng.choice(REPLACEMENTS))
        yield m


def _agree_on_mutants(doc, name, seed):
    schema = J.load_schema(name)
    reference = jsonschema.Draft202012Validator(schema)
    doc = _shrink(doc)
    accepted = refused = 0
    for m in _mutants(doc, seed, 300):
        mine = J.errors(m, name)
        theirs = reference.is_valid(m)
        assert (mine is None) == theirs, (name, json.dumps(m)[:300], mine)
        accepted += theirs
        refused += not theirs
    assert accepted >= 10 and refused >= 100, (accepted, refused)  # the mutants probe both sides


@pytest.mark.parametrize("rel, name", SYNTH_FILES)
def test_the_validator_agrees_with_jsonschema_on_mutated_files(synthesised, rel, name):
    _agree_on_mutants(_read(synthesised, rel), name, seed=len(rel))


@pytest.mark.heavy
@pytest.mark.parametrize("rel, name", [f for f in FIT_FILES if f[1] != "teeth-scene"])
def test_the_validator_agrees_with_jsonschema_on_mutated_fit_files(fitted, rel, name):
    _agree_on_mutants(_read(fitted, rel), name, seed=len(rel))


def test_the_validator_agrees_with_jsonschema_on_mutated_curves():
    _agree_on_mutants(CURVES, "scratch-curves", seed=1)


# ---- the loaders refuse what the schemas refuse, in one line

def _refused(status: int) -> bool:
    """A bad file's exit status: not 0 (the line on stderr, checked by ``_one_line``, says it is no bug)."""
    return status in (1, 2)


def _one_line(capsys, expected: str) -> None:
    """The error is one line (no traceback), the last on stderr (notes about the command line may precede it)."""
    err = capsys.readouterr().err
    assert err.endswith(f"\nerror: {expected}\n") or err == f"error: {expected}\n", err
    assert "Traceback" not in err and err.count("error: ") == 1, err


def _rewrite(path, edit) -> None:
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def test_a_capture_the_schema_refuses_is_one_line(synthesised, tmp_path, capsys):
    import shutil

    from material_structures.core.teeth.capture import Capture

    cap = tmp_path / "cap"
    shutil.copytree(synthesised / "cap", cap)
    _rewrite(cap / "capture.json", lambda d: d["lights"][2].update(position=[1.0, 2.0]))
    said = f"{cap / 'capture.json'}: lights[2].position: expected 3 numbers, got 2"
    with pytest.raises(UserError) as info:
        Capture.load(cap)
    assert str(info.value) == said
    assert _refused(main(["teeth", "fit", str(cap), "--out", str(tmp_path / "fit"), "--no-progress"]))
    _one_line(capsys, said)
    assert not (tmp_path / "fit").exists()


@pytest.mark.parametrize("edit, said", [
    (lambda d: d["teeth"][0]["enamel"].update(g1=1.5), "teeth[0].enamel.g1: must be < 1, got 1.5"),
    (lambda d: d["teeth"][0]["enamel_mesh"].pop("corner_uv"), "teeth[0].enamel_mesh: lacks the field 'corner_uv'"),
    (lambda d: d["teeth"][0].update(a_t=[1, 1]), "teeth[0].a_t: expected an RGB triple of fractions, each 0-1 or "
                                                 "an H x W x 3 texture, got a list of 2"),
    (lambda d: d.update(colour="pink"), "unknown field 'colour' (known: format, blend_spread_mm, teeth, gums, "
                                        "cavity)"),
])
def test_a_scene_the_schema_refuses_is_one_line(synthesised, tmp_path, capsys, edit, said):
    from material_structures.core.teeth.scene import load_scene

    path = tmp_path / "scene.json"
    path.write_text((synthesised / "cap" / "scene.json").read_text())
    _rewrite(path, edit)
    with pytest.raises(UserError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}: {said}"
    assert _refused(main(["teeth", "render", str(path), str(synthesised / "cap"), "--out", str(tmp_path / "r")]))
    _one_line(capsys, f"{path}: {said}")


def test_a_btf_description_the_schema_refuses_is_one_line(synthesised, tmp_path, capsys):
    import shutil

    btf = tmp_path / "btf"
    shutil.copytree(synthesised / "btf", btf)
    _rewrite(btf / "btf.json", lambda d: d["samples"][1].update(wi="up"))
    assert _refused(main(["fabric", "fit", str(btf), "--out", str(tmp_path / "fit"), "--no-dask", "--no-progress"]))
    _one_line(capsys, f"{btf / 'btf.json'}: samples[1].wi: expected 3 numbers, got \"up\"")
    _rewrite(btf / "btf.json", lambda d: d.update(width=0))
    assert _refused(main(["fabric", "fit", str(btf), "--out", str(tmp_path / "fit"), "--no-dask", "--no-progress"]))
    _one_line(capsys, f"{btf / 'btf.json'}: width: must be >= 1, got 0")
    assert not (tmp_path / "fit").exists()


def test_fabric_parameters_the_schema_refuses_are_one_line(synthesised, tmp_path, capsys):
    import shutil

    from material_structures.core.fabric.parameter_maps import load_params

    gt = tmp_path / "gt"
    shutil.copytree(synthesised / "gt", gt)
    _rewrite(gt / "params.json", lambda d: d["maps"]["kd"].update(channels="RGB"))
    said = f"{gt / 'params.json'}: maps.kd.channels: expected a list, got \"RGB\""
    with pytest.raises(UserError) as info:
        load_params(gt)
    assert str(info.value) == said
    assert _refused(main(["fabric", "eval", str(gt), "--directions", str(synthesised / "btf"), "--out",
                 str(tmp_path / "pred")]))
    _one_line(capsys, said)


def test_a_curves_file_the_schema_refuses_is_one_line(tmp_path, capsys):
    path = tmp_path / "c.json"
    path.write_text(json.dumps([[[0.1, 0.1], [0.9, 0.5]], [[0.2, 0.8], [0.5]]]))
    assert _refused(main(["scratch", "generate", "--kind", "curves", "--curves", str(path), "--out",
                 str(tmp_path / "s.npz")]))
    _one_line(capsys, f"{path}: [1][1]: expected 2 numbers, got 1")
    assert not (tmp_path / "s.npz").exists()
    # a curve of one point: the schema's words, naming the file (it was the generator's, naming neither)
    path.write_text(json.dumps([[[0.1, 0.1], [0.9, 0.5]], [[0.5, 0.5]]]))
    assert _refused(main(["scratch", "generate", "--kind", "curves", "--curves", str(path), "--out",
                 str(tmp_path / "s.npz")]))
    assert f"{path}: [1]: expected at least 2 items, got 1" in capsys.readouterr().err
    assert not (tmp_path / "s.npz").exists()
