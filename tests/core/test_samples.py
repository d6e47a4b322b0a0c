"""The sample data shipped in ``samples/`` (``scripts/make_samples.py``, ``make samples``; issue 67): each sample
loads through its format's loader (which checks it against the JSON schema), holds what the generator says it
holds, the whole stays small, and the extension zip takes it along (nothing in the manifest's exclusions)."""

from __future__ import annotations

import importlib.util
import os
import tomllib

import numpy as np
import pytest

from material_structures.core.fabric.btf_io import read_btf_header
from material_structures.core.fabric.parameter_maps import load_params
from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.scene import load_scene

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLES = os.path.join(ROOT, "samples")
MAX_BYTES = 3 * 1024 * 1024  # all samples together: the zip ships them to every user


def _generator():
    spec = importlib.util.spec_from_file_location("make_samples", os.path.join(ROOT, "scripts", "make_samples.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _option(args: list[str], name: str) -> int:
    return int(args[args.index(name) + 1])


def test_the_add_on_names_the_generated_folders():
    text = open(os.path.join(ROOT, "addon", "operators.py")).read()
    for folder in ("fabric_btf", "teeth_capture", "brush_states"):
        assert f'"{folder}"' in text
        assert os.path.isdir(os.path.join(SAMPLES, folder)), folder


def test_sample_btf_loads_as_generated():
    gen = _generator()
    hdr = read_btf_header(os.path.join(SAMPLES, "fabric_btf"))
    assert (hdr.width, hdr.height) == (_option(gen.BTF, "--width"), _option(gen.BTF, "--height"))
    assert hdr.count == _option(gen.BTF, "--lights") * _option(gen.BTF, "--views")


def test_sample_capture_and_scene_load_as_generated():
    gen = _generator()
    folder = os.path.join(SAMPLES, "teeth_capture")
    cap = Capture.load(folder)
    assert len(cap.cameras) == _option(gen.CAPTURE, "--cameras")
    assert len(cap.lights) == _option(gen.CAPTURE, "--lights")
    assert cap.images.shape[2:4] == (_option(gen.CAPTURE, "--height"), _option(gen.CAPTURE, "--width"))
    assert cap.masks.any()  # the tooth is in view
    scene = load_scene(os.path.join(folder, "scene.json"))
    assert len(scene.teeth) == _option(gen.CAPTURE, "--teeth")


@pytest.mark.parametrize("k", range(8))
def test_sample_brush_states_load_as_generated(k):
    maps = load_params(os.path.join(SAMPLES, "brush_states", f"state_{k}"))
    want = _generator().brush_state(k)
    for name in ("kd", "ks", "sigma", "basis"):
        np.testing.assert_allclose(getattr(maps, name), getattr(want, name), atol=1e-6, err_msg=name)


def test_samples_are_small():
    total = sum(os.path.getsize(os.path.join(d, f)) for name in ("fabric_btf", "teeth_capture", "brush_states")
                for d, _, files in os.walk(os.path.join(SAMPLES, name)) for f in files)
    assert 0 < total < MAX_BYTES, total


def test_the_extension_zip_ships_the_samples():
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        excluded = tomllib.load(f)["build"]["paths_exclude_pattern"]
    for pattern in excluded:
        p = pattern.strip("/")
        assert not ("samples".startswith(p) or p in ("samples/fabric_btf", "samples/teeth_capture",
                                                     "samples/brush_states")), pattern
    with open(os.path.join(ROOT, ".gitignore")) as f:
        ignored = [ln.strip().strip("/") for ln in f if ln.strip() and not ln.startswith("#")]
    assert not [p for p in ignored if p in ("samples", "samples/*", "*.exr", "*.json")], ignored
