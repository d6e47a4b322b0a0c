"""Bad teeth inputs give a one-line error naming the problem (exit 1 from the CLI, a runtime error; a
bad command line exits 2) and change nothing:
malformed or incomplete captures, masks that select nothing, a checkpoint of another fit, a second fit
into a folder a fit is writing to, an output path that is a file, scenes that cannot be rendered (fields
missing, meshes that are open, not manifold, inside out or not finite), a resume under other settings."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import numpy as np
import pytest

from material_structures.cli import main
from material_structures.core.exr_io import write_exr
from material_structures.core.folder_lock import FolderLock
from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.optimise import FitSettings, fit
from material_structures.core.teeth.scene import load_scene

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cap") / "cap"
    assert main(["teeth", "synth", "--out", str(folder), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    return folder


def _digest(folder) -> str:
    h = hashlib.sha1()
    for root, _, files in sorted(os.walk(folder)):
        for name in sorted(files):
            p = os.path.join(root, name)
            h.update(p.encode())
            with open(p, "rb") as f:
                h.update(f.read())
    return h.hexdigest()


def _copy(capture_dir, tmp_path):
    out = tmp_path / "c"
    shutil.copytree(capture_dir, out)
    return out


def _edit_json(folder, fn) -> None:
    path = folder / "capture.json"
    meta = json.loads(path.read_text())
    fn(meta)
    path.write_text(json.dumps(meta))


@pytest.mark.parametrize("edit, said", [
    # the schema's words (core/schemas/capture.schema.json), then the loader's own checks
    (lambda m: m.pop("lights"), "capture.json: lacks the field 'lights'"),
    (lambda m: m.update(lights=[]), "capture.json: lights: expected a non-empty list, got 0"),
    (lambda m: m["lights"].append(m["lights"][0]), "no image for 1 (camera, light) pairs"),
    (lambda m: m["images"].pop("0,2"), "no image for 1 (camera, light) pairs"),
    (lambda m: m["images"].update({"0,9": m["images"]["0,0"]}), "does not exist"),
    (lambda m: m["images"].update({"zero": m["images"]["0,0"]}), 'images: key "zero" is not a "camera,light" pair'),
    (lambda m: m["masks"].clear() or m["masks"].update({"3": "masks/cam0.exr"}), "does not exist"),
    (lambda m: m["cameras"][0].pop("K"), "cameras[0]: lacks the field 'K'"),
    (lambda m: m["cameras"][0].update(width=0), "cameras[0].width: must be >= 1, got 0"),
    (lambda m: m["lights"][1].update(intensity=[-1, 1, 1]), "lights[1].intensity[0]: must be >= 0, got -1"),
    (lambda m: m["lights"][1].update(position=[float("nan"), 0, 0]), "light 1 has a non-finite position"),
    (lambda m: m.update(format="other/1"), 'format: expected "material_structures.teeth.capture/1", got "other/1"'),
    # a zero focal length or an R that is not a rotation rendered every image black without a word
    (lambda m: m["cameras"][0]["K"][0].__setitem__(0, 0.0), "camera 0 has a focal length (K[0][0], K[1][1])"),
    (lambda m: m["cameras"][0].update(R=[[0, 0, 0]] * 3), "camera 0's R is not a rotation"),
    (lambda m: m["cameras"][0].update(R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "camera 0's R is not a rotation"),
])
def test_malformed_capture_is_refused_by_name(capture_dir, tmp_path, capsys, edit, said):
    cap = _copy(capture_dir, tmp_path)
    _edit_json(cap, edit)
    before = _digest(cap)
    with pytest.raises(ValueError, match="capture.json"):
        Capture.load(cap)
    out = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap), "--out", str(out), "--iterations", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
    assert _digest(cap) == before


@pytest.mark.parametrize("fields", [("images",), ("masks",), ("images", "masks")])
def test_a_capture_without_images_or_masks_is_refused_before_the_fit_writes(capture_dir, tmp_path, capsys, fields):
    """A rig without photographs loads (``teeth render`` renders it) but cannot be fitted: the fit said so only
    after making --out, in words that named neither the file nor the field."""
    cap = _copy(capture_dir, tmp_path)
    _edit_json(cap, lambda m: [m.pop(f) for f in fields])
    out = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap), "--out", str(out), "--iterations", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert f"capture.json: a fit needs the capture's images and masks; it has no {' and no '.join(fields)}" in err
    assert not out.exists()


def test_not_json_negative_pixels_and_wrong_sizes_are_refused(capture_dir, tmp_path):
    cap = _copy(capture_dir, tmp_path)
    (cap / "capture.json").write_text("")
    with pytest.raises(ValueError, match="capture.json: not a JSON file"):
        Capture.load(cap)
    cap = _copy(capture_dir, tmp_path / "b")
    write_exr(str(cap / "images" / "cam0_light1.exr"), np.full((10, 12, 3), -0.5, dtype=np.float32))
    with pytest.raises(ValueError, match="cam0_light1.exr: has non-finite or negative pixels"):
        Capture.load(cap)
    write_exr(str(cap / "images" / "cam0_light1.exr"), np.full((5, 12, 3), 0.5, dtype=np.float32))
    with pytest.raises(ValueError, match="cam0_light1.exr: image size"):
        Capture.load(cap)


def test_masks_that_select_nothing_are_refused(capture_dir, tmp_path):
    cap = Capture.load(capture_dir)
    cap.masks[:] = False
    with pytest.raises(ValueError, match="masks select no pixel"):
        fit(load_scene(str(capture_dir / "scene.json")), cap, FitSettings(iterations=1))


def test_resume_under_another_capture_or_settings_is_refused(capture_dir, tmp_path):
    scene = load_scene(str(capture_dir / "scene.json"))
    cap = Capture.load(capture_dir)
    out = str(tmp_path / "fit")
    s = FitSettings(iterations=2, spp=1, image_spp=1, lights_per_iteration=1, max_depth=3)
    fit(scene, cap, s, out_dir=out)
    ckpt = os.path.join(out, "checkpoint.json")
    before = open(ckpt).read()
    other = Capture.load(capture_dir)
    other.images = other.images * 1.5
    with pytest.raises(ValueError, match="another fit .*the capture"):
        fit(scene, other, FitSettings(**{**s.__dict__, "iterations": 3}), out_dir=out, resume=True)
    with pytest.raises(ValueError, match="another fit .*the free parameters"):
        fit(scene, cap, FitSettings(**{**s.__dict__, "iterations": 3, "free": ("*.albedo",)}), out_dir=out,
            resume=True)
    with pytest.raises(ValueError, match="another fit .*the seed"):
        fit(scene, cap, FitSettings(**{**s.__dict__, "iterations": 3, "seed": 9}), out_dir=out, resume=True)
    assert open(ckpt).read() == before
    # a checkpoint that is not one: {} or a truncated file
    for text in ("{}", before[: len(before) // 2]):
        with open(ckpt, "w") as f:
            f.write(text)
        with pytest.raises(ValueError, match="checkpoint"):
            fit(scene, cap, FitSettings(**{**s.__dict__, "iterations": 3}), out_dir=out, resume=True)


def test_a_second_fit_into_a_busy_folder_is_refused(capture_dir, tmp_path):
    scene = load_scene(str(capture_dir / "scene.json"))
    cap = Capture.load(capture_dir)
    out = tmp_path / "fit"
    out.mkdir()
    (out / ".fit.lock").write_text("1")  # process 1 (init) is alive: "another fit" holds the folder
    with pytest.raises(ValueError, match=r"another fit \(process 1\) is writing to"):
        fit(scene, cap, FitSettings(iterations=1), out_dir=str(out))
    assert sorted(os.listdir(out)) == [".fit.lock"]
    (out / ".fit.lock").write_text("999999999")  # a lock whose process is gone is taken over
    fit(scene, cap, FitSettings(iterations=1, spp=1, image_spp=1, lights_per_iteration=1, max_depth=3),
        out_dir=str(out))
    assert not (out / ".fit.lock").exists() and (out / "scene_fit.json").exists()
    with FolderLock(str(out)):  # held by this process: a second lock, even here, is refused
        with pytest.raises(ValueError, match="another fit"):
            FolderLock(str(out)).__enter__()
    assert not (out / ".fit.lock").exists()


def test_output_that_is_a_file_is_a_one_line_error(capture_dir, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("keep me")
    for out in (blocker, blocker / "under"):
        assert main(["teeth", "fit", str(capture_dir), "--out", str(out), "--iterations", "1",
                     "--no-progress"]) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: ") and str(blocker) in err and err.count("\n") == 1, err
    assert blocker.read_text() == "keep me"


def test_render_refuses_to_write_over_its_inputs(capture_dir, tmp_path, capsys):
    cap = _copy(capture_dir, tmp_path)
    before = _digest(cap)
    for out in (cap / "images", cap, tmp_path):  # the capture's photographs, the capture, a folder holding it
        assert main(["teeth", "render", str(cap / "scene.json"), str(cap), "--out", str(out), "--samples", "1"]) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: ") and "would write over the input" in err and err.count("\n") == 1, err
    assert _digest(cap) == before


def test_synth_refuses_to_write_over_the_scene_it_renders(capture_dir, tmp_path, capsys):
    """``teeth synth --scene CAP/scene.json --out CAP`` replaced the capture it read its scene from (and left its
    other images stale)."""
    cap = _copy(capture_dir, tmp_path)
    before = _digest(cap)
    assert main(["teeth", "synth", "--out", str(cap), "--scene", str(cap / "scene.json"), "--lights", "1",
                 "--cameras", "1", "--width", "8", "--height", "8", "--samples", "1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "would write over the input" in err and err.count("\n") == 1, err
    assert _digest(cap) == before


@pytest.mark.parametrize("argv, said", [
    (["synth", "--out", "OUT", "--cameras", "0"], "argument --cameras: must be >= 1, got 0"),
    (["synth", "--out", "OUT", "--samples", "-3"], "argument --samples: must be >= 1, got -3"),
    (["synth", "--out", "OUT", "--width", "2"], "argument --width: must be >= 4, got 2"),
    (["synth", "--out", "OUT", "--mesh-resolution", "4"], "argument --mesh-resolution: must be >= 8, got 4"),
    (["render", "S", "C", "--out", "O", "--samples", "0"], "argument --samples: must be >= 1, got 0"),
    (["sensitivity", "C", "--noise-variance", "nan"], "argument --noise-variance: 'nan' is not a finite number"),
    (["sensitivity", "C", "--capture-samples", "4", "--block", "0"], "argument --block: must be >= 1, got 0"),
    (["sensitivity", "C", "--capture-samples", "4", "--passes", "1"], "argument --passes: must be >= 2, got 1"),
    (["fit", "C", "--out", "O", "--textured-iterations", "-1"], "argument --textured-iterations: must be >= 0"),
    (["fit", "C", "--out", "O", "--seed", "-2"], "argument --seed: must be >= 0, got -2"),
])
def test_numeric_flags_are_range_checked_at_the_parser(tmp_path, capsys, argv, said):
    argv = [str(tmp_path / a) if a in ("OUT", "S", "C", "O") else a for a in argv]
    assert main(["teeth", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_resume_from_a_missing_or_broken_checkpoint_is_one_line(capture_dir, tmp_path, capsys):
    out = tmp_path / "fit"
    argv = ["teeth", "fit", str(capture_dir), "--out", str(out), "--resume"]  # with progress bars: none drawn
    assert main(argv) == 1
    assert "no checkpoint to resume from" in capsys.readouterr().err
    assert not out.exists()  # nothing created
    out.mkdir()
    (out / "checkpoint.json").write_text("{not json")
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "checkpoint.json" in err and "not a fit checkpoint" in err and err.count("\n") == 1, err
    (out / "checkpoint.json").unlink()
    (out / "start_trials").mkdir()  # a fit stopped during its start trials, its saved starts damaged
    (out / "start_trials" / "starts.json").write_text('{"starts": [{"teeth": 1}]}')
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "starts.json: not the starts of a fit's trials" in err and err.count("\n") == 1, err


@pytest.mark.parametrize("text, name, said", [
    ("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "nan.obj", "1 vertices are NaN or infinite"),
    ("v 0 0 0\nv 1 0 0\n", "points.obj", "no triangles"),
    ("garbage\n", "junk.ply", "not a readable mesh"),
])
def test_a_mesh_that_cannot_be_traced_is_refused_naming_the_file(tmp_path, text, name, said):
    from material_structures.core.teeth.mesh import load_mesh

    (tmp_path / name).write_text(text)
    with pytest.raises(ValueError, match=said) as info:
        load_mesh(tmp_path / name)
    assert name in str(info.value)


def test_sigterm_stops_a_dask_teeth_fit_with_its_workers_and_it_resumes(capture_dir, tmp_path):
    """Ctrl-C (SIGTERM here: a background shell ignores SIGINT) on a fit rendering on a local Dask cluster:
    exit 130 with one line, no worker process left, and --resume finishes the fit from its checkpoint."""
    import subprocess
    import sys

    from ._interrupt import interrupt_when

    out = tmp_path / "fit"
    # the first checkpoint comes at iteration 5; a tiny capture's iterations are fast, so that before the
    # signal lands the fit may run a few more (with 8 in all it had sometimes ended: 3 failures in 10 runs;
    # with 20, the file polled every 0.05 s, it had run 5 when stopped in 5 of 5 runs, 0.08 s an iteration)
    n = 20
    argv = [sys.executable, "-m", "material_structures", "teeth", "fit", str(capture_dir), "--out", str(out),
            "--init", "scene", "--iterations", str(n), "--held-out-lights", "0", "--dask-workers", "1",
            "--no-progress"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ckpt = out / "checkpoint.json"
    interrupt_when(proc, ckpt.exists, 240)
    done = len(json.loads(ckpt.read_text())["log"])
    assert 5 <= done < n
    r = subprocess.run(argv + ["--resume"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(json.loads((out / "loss.json").read_text())["log"]) == n


# ---- issue 64: loud failures

def _scene_json(capture_dir, tmp_path, edit) -> str:
    d = json.loads((capture_dir / "scene.json").read_text())
    edit(d)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    return str(path)


def _drop_face(d):
    m = d["teeth"][0]["enamel_mesh"]
    m["faces"].pop()
    m["corner_uv"].pop()


def _third_face_on_an_edge(d):  # a face again, turned over: each of its edges has three triangles
    m = d["teeth"][0]["enamel_mesh"]
    m["faces"].append(m["faces"][0][::-1])
    m["corner_uv"].append(m["corner_uv"][0][::-1])


def _drop_a_face_of(mesh):
    mesh["faces"].pop()
    if mesh.get("corner_uv") is not None:
        mesh["corner_uv"].pop()


def _inside_out(d):
    m = d["teeth"][0]["enamel_mesh"]
    m["faces"] = [f[::-1] for f in m["faces"]]
    m["corner_uv"] = [c[::-1] for c in m["corner_uv"]]


@pytest.mark.parametrize("edit, said", [
    # the schema's words (core/schemas/teeth-scene.schema.json), then the loader's own checks
    (lambda d: d.pop("teeth"), "lacks the field 'teeth'"),
    (lambda d: d.update(teeth={"a": 1}), "teeth: expected a list, got an object"),
    (lambda d: d["teeth"][0].pop("enamel"), "teeth[0]: lacks the field 'enamel'"),
    (lambda d: d["teeth"][0]["enamel"].update(sigma_t="thick"),
     'teeth[0].enamel.sigma_t: expected 3 numbers, got "thick"'),
    (lambda d: d["teeth"][0]["enamel"].update(sigma_t=[float("nan")] * 3), "need sigma_t > 0"),
    (lambda d: d["teeth"][0].update(eta=0.5), "teeth[0].eta: must be >= 1, got 0.5"),
    (lambda d: d["teeth"][0].update(a_t=[float("nan")] * 3), "NaN or infinite"),
    (lambda d: d["teeth"][0].update(a_t=[float("inf")] * 3), "teeth[0].a_t: expected an RGB triple of fractions"),
    (_drop_face, "the enamel mesh is not closed (3 edges belong to one triangle only)"),
    (_third_face_on_an_edge, "the enamel mesh is not manifold (3 edges are shared by three or more triangles)"),
    (_inside_out, "the enamel mesh has its faces pointing inwards"),
    (lambda d: d["teeth"][0]["enamel_mesh"]["vertices"][0].__setitem__(1, float("nan")),
     "the enamel mesh has 1 vertices that are NaN or infinite"),
    (lambda d: _drop_a_face_of(d["teeth"][0]["dentin_shape"]["base"]), "the dentin mesh is not closed"),
    (lambda d: _drop_a_face_of(d["gums"]["mesh"]), "the gums mesh is not closed"),
    (lambda d: d.update(blend_spread_mm=-1), "blend_spread_mm: must be > 0, got -1"),
    (lambda d: d.update(blend_spread_mm=float("nan")), "blend_spread_mm must be a number > 0"),
    (lambda d: d.update(format="other/2"), 'format: expected "material_structures.teeth.scene/1", got "other/2"'),
    # out of range: a negative transmittance or cavity albedo was a traceback ("internal error"), a transmittance
    # above 1 or a dentin coefficient beyond the fit's range rendered without a word, a second tooth of the same
    # name was rendered and fitted as one tooth
    (lambda d: d["teeth"][0].update(a_t=[-1, -1, -1]), "teeth[0].a_t: expected an RGB triple of fractions, each 0-1"),
    (lambda d: d["teeth"][0].update(a_t=[5, 5, 5]), "teeth[0].a_t: expected an RGB triple of fractions, each 0-1"),
    (lambda d: d["teeth"][0].update(c=[5, -5, 5]), "teeth[0].c[0]: must be <= 0.8, got 5"),
    (lambda d: d["cavity"].update(albedo=[-3, 7, 2]), "cavity.albedo[0]: must be >= 0, got -3"),
    (lambda d: d["teeth"].append(d["teeth"][0]), "two teeth are named"),
])
def test_a_scene_that_cannot_be_rendered_is_one_line(capture_dir, tmp_path, capsys, edit, said):
    """A scene.json without "teeth" was KeyError: 'teeth' (render and fit); a mesh with a hole, an edge of three
    triangles, faces turned inwards or NaN vertices was rendered without a word."""
    from material_structures.core.errors import UserError

    d = json.loads((capture_dir / "scene.json").read_text())
    if "gums" in said and d.get("gums") is None:
        pytest.skip("the capture has no gums")
    path = _scene_json(capture_dir, tmp_path, edit)
    with pytest.raises(UserError, match="scene.json: "):
        load_scene(path)
    before, cap_before = _digest(tmp_path), _digest(capture_dir)
    assert main(["teeth", "render", path, str(capture_dir), "--out", str(tmp_path / "r"), "--samples", "1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: ") and said in err and err.count("\n") == 1, err
    assert main(["teeth", "fit", str(capture_dir), "--scene", path, "--out", str(tmp_path / "f"), "--iterations",
                 "1", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: ") and said in err and err.count("\n") == 1, err
    assert _digest(tmp_path) == before and _digest(capture_dir) == cap_before  # nothing written


def test_a_capture_whose_scene_json_lacks_teeth_is_one_line(capture_dir, tmp_path, capsys):
    cap = _copy(capture_dir, tmp_path)
    d = json.loads((cap / "scene.json").read_text())
    d.pop("teeth")
    (cap / "scene.json").write_text(json.dumps(d))
    before = _digest(cap)
    assert main(["teeth", "fit", str(cap), "--out", str(tmp_path / "f"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "scene.json: lacks the field 'teeth'" in err and err.count("\n") == 1, err
    assert _digest(cap) == before and not (tmp_path / "f").exists()


def test_a_resumed_fit_keeps_its_settings_and_refuses_other_flags(capture_dir, tmp_path, capsys):
    """--resume goes on with the settings the fit started with (settings_from_dict of its checkpoint): a flag
    that differs is one line naming both values and changes nothing; --iterations may lengthen the fit; a
    checkpoint of the textured phase under settings without one was "'textured' is not in list"."""
    out = tmp_path / "fit"
    argv = ["teeth", "fit", str(capture_dir), "--out", str(out), "--init", "scene", "--no-progress"]
    assert main(argv + ["--iterations", "1", "--textured-iterations", "1", "--seed", "3", "--held-out-lights",
                        "0", "--free", "*.albedo"]) == 0
    saved = json.loads((out / "checkpoint.json").read_text())
    assert saved["settings"]["seed"] == 3 and saved["phase"] == "textured"
    capsys.readouterr()
    before = _digest(out)
    for flags, said in ((["--seed", "4"], "--seed 4 (it started with 3)"),
                        (["--free", "*.g1"], "--free *.g1 (it started with *.albedo)"),
                        (["--held-out-lights", "2", "--seed", "4"],
                         "--held-out-lights 2 (it started with 0); --seed 4 (it started with 3)"),
                        (["--textured-iterations", "0"], "stopped in the 'textured' phase")):
        assert main(argv + ["--resume", *flags]) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
        assert _digest(out) == before
    # no flags: its own settings (seed 3, one light-free fit of the albedo), two more textured iterations
    assert main(argv + ["--resume", "--textured-iterations", "3"]) == 0
    ran = json.loads((out / "loss.json").read_text())
    assert ran["settings"]["seed"] == 3 and ran["settings"]["free"] == ["*.albedo"]
    assert ran["settings"]["textured_iterations"] == 3 and len(ran["log"]) == 4
    # a damaged settings record in the checkpoint is one line naming the file
    ckpt = json.loads((out / "checkpoint.json").read_text())
    ckpt["settings"]["spp"] = "many"
    (out / "checkpoint.json").write_text(json.dumps(ckpt))
    assert main(argv + ["--resume"]) == 1
    err = capsys.readouterr().err
    assert "checkpoint.json: fit settings of the wrong kind" in err and err.count("\n") == 1, err


def test_the_checkpoint_identity_holds_spp_lr_and_the_optimiser(capture_dir, tmp_path):
    from dataclasses import replace

    scene = load_scene(str(capture_dir / "scene.json"))
    cap = Capture.load(capture_dir)
    out = str(tmp_path / "fit")
    s = FitSettings(iterations=1, spp=1, image_spp=1, lights_per_iteration=1, max_depth=3, start_trials=0)
    fit(scene, cap, s, out_dir=out)
    ckpt = os.path.join(out, "checkpoint.json")
    before = open(ckpt).read()
    for change, said in (({"spp": 2}, "the samples per pixel"), ({"image_spp": 2}, "the image samples"),
                         ({"lr": 0.5}, "the learning rate"), ({"optimiser": "adam"}, "the optimiser")):
        with pytest.raises(ValueError, match=f"another fit .*{said}"):
            fit(scene, cap, replace(s, iterations=2, **change), out_dir=out, resume=True)
    assert open(ckpt).read() == before
    # a checkpoint of the version before, whose identity had none of them, still resumes
    d = json.loads(before)
    for k in ("spp", "image_spp", "lr", "optimiser"):
        d["identity"].pop(k)
    d.pop("settings")
    with open(ckpt, "w") as f:
        json.dump(d, f)
    _, log = fit(scene, cap, replace(s, iterations=2), out_dir=out, resume=True)
    assert len(log) == 2


def test_a_free_pattern_that_names_no_parameter_is_refused(capture_dir, tmp_path, capsys):
    """--free with a typo fitted fewer parameters than asked, without a word."""
    assert main(["teeth", "fit", str(capture_dir), "--out", str(tmp_path / "f"), "--free", "*.albedo,*.albdo",
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --free *.albdo: no parameter of ") and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content, said", [
    (b"\xff\xfe\x00garbage", "is not a fit checkpoint"),
    (json.dumps({"phase": "homogeneous", "iteration": "five", "scene": {}, "y": [], "adam_m": None, "adam_v": None,
                 "adam_n": 0, "best_loss": 1.0, "best_scene": {}, "log": "none", "identity": {}}).encode(),
     "a damaged fit checkpoint (fields of the wrong kind: ['iteration', 'log'])"),
])
def test_a_damaged_checkpoint_is_one_line(capture_dir, tmp_path, capsys, content, said):
    out = tmp_path / "fit"
    out.mkdir()
    (out / "checkpoint.json").write_bytes(content)
    before = _digest(out)
    assert main(["teeth", "fit", str(capture_dir), "--out", str(out), "--resume", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "checkpoint.json" in err and said in err and err.count("\n") == 1, err
    assert _digest(out) == before


def test_a_render_that_fails_half_way_leaves_its_output_as_it_was(tmp_path, capsys, monkeypatch):
    """``teeth render`` wrote each batch of lights as it went: a failure after the first batch left --out half new,
    half old. Now nothing of a failed render reaches --out; an image name taken by a folder is refused first."""
    from material_structures.core.teeth import path_tracer

    cap = tmp_path / "cap"  # 10 lights: two batches of 9
    assert main(["teeth", "synth", "--out", str(cap), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "10", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    out = tmp_path / "out"
    argv = ["teeth", "render", str(cap / "scene.json"), str(cap), "--out", str(out), "--samples", "1"]
    assert main(argv) == 0
    before = _digest(out)
    calls = []
    real = path_tracer.render

    def fail_on_second(*a, **kw):
        calls.append(1)
        if len(calls) > 1:
            raise OSError("disk full")
        return real(*a, **kw)

    monkeypatch.setattr(path_tracer, "render", fail_on_second)
    assert main([*argv, "--seed", "7"]) == 1
    assert "disk full" in capsys.readouterr().err
    assert _digest(out) == before and len(calls) == 2 and sorted(os.listdir(out))[0] == "cam0_light0.exr"
    monkeypatch.setattr(path_tracer, "render", real)
    (out / "cam0_light0.exr").unlink()
    (out / "cam0_light0.exr").mkdir()
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "cam0_light0.exr is a folder there" in err and err.count("\n") == 1, err


def test_sensitivity_checks_its_output_before_the_renders(capture_dir, tmp_path, capsys, monkeypatch):
    """``teeth sensitivity --out`` that is a folder was found only after the renders (and named a temp file)."""
    from material_structures.core.teeth import sensitivity

    monkeypatch.setattr(sensitivity, "capture_sensitivity", lambda *a, **k: pytest.fail("rendered first"))
    (tmp_path / "taken").mkdir()
    assert main(["teeth", "sensitivity", str(capture_dir), "--capture-samples", "1", "--out",
                 str(tmp_path / "taken")]) == 1
    err = capsys.readouterr().err
    assert "is a folder; give a .json file name" in err and err.count("\n") == 1, err
