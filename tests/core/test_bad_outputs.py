"""Outputs never overwrite inputs, across the CLI: each case is a one-line error (exit 1) and the input is
byte-identical afterwards."""

from __future__ import annotations

import hashlib

import pytest

from material_structures.cli import main


def _sha(path) -> str:
    return hashlib.sha1(open(path, "rb").read()).hexdigest()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("in")
    assert main(["fabric", "synth", "--out", str(d / "btf"), "--width", "4", "--height", "3", "--lights", "3",
                 "--views", "3", "--gt-out", str(d / "params")]) == 0
    assert main(["scratch", "generate", "--kind", "wear", "--count", "20", "--out", str(d / "s.npz")]) == 0
    (d / "x.blend").write_bytes(b"BLENDER-not-really")
    return d


@pytest.mark.parametrize("argv, victim", [
    (["fabric", "eval", "{d}/params", "--directions", "{d}/btf", "--out", "{d}/btf"], "btf/btf.json"),
    (["fabric", "eval", "{d}/params", "--directions", "{d}/btf/btf.json", "--out", "{d}/btf"], "btf/btf.json"),
    (["fabric", "fit", "{d}/btf", "--out", "{d}/btf", "--no-dask"], "btf/btf.json"),
    (["fabric", "ndf", "{d}/btf", "--texel", "0", "0", "--out", "{d}/btf/0000.exr"], "btf/0000.exr"),
    (["scratch", "eval", "{d}/s.npz", "--out", "{d}/s.npz"], "s.npz"),
    (["render", "--blend", "{d}/x.blend", "--out", "{d}/x.blend"], "x.blend"),
])
def test_an_output_over_an_input_is_refused(inputs, capsys, argv, victim):
    before = _sha(inputs / victim)
    assert main([a.format(d=inputs) for a in argv]) == 1  # a runtime error
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "would write over the input" in err and err.count("\n") == 1, err
    assert _sha(inputs / victim) == before


def test_render_refuses_other_formats_and_absurd_sizes(tmp_path, capsys):
    (tmp_path / "a.blend").write_bytes(b"")
    for argv, said in ((["--out", str(tmp_path / "r.jpg")], "give a .exr (linear) or .png"),
                       (["--resolution", "200000x200000", "--out", str(tmp_path / "r.exr")], "larger than 16384"),
                       (["--blend", str(tmp_path / "a.blend"), "--out", str(tmp_path / "r.exr")],  # rendered the file
                        "give a scene name (fabric-velvet) or --blend FILE, not both")):
        assert main(["render", "fabric-velvet", *argv]) == 2
        err = capsys.readouterr().err
        assert said in err and err.count("\n") == 1, err
    assert [p.name for p in tmp_path.iterdir()] == ["a.blend"]


def test_blender_backed_commands_leave_no_temp_dirs(tmp_path):
    """A render leaves the temporary folder as it was: no Blender user folder, no compiled OSL shader (Cycles
    compiles a script node as its script is set, with OSL on, and leaves the .oso)."""
    import os
    import subprocess
    import sys

    temp = tmp_path / "temp"
    temp.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "BLENDER_USER_RESOURCES"} | {"TMPDIR": str(temp)}
    r = subprocess.run([sys.executable, "-m", "material_structures", "render", "fabric-velvet", "--resolution",
                        "16x12", "--samples", "1", "--out", str(tmp_path / "v.png")], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "v.png").is_file()
    assert sorted(p.name for p in temp.iterdir()) == []


@pytest.mark.parametrize("which", ["a file", "not writable"])
def test_synth_checks_both_outputs_before_writing_either(inputs, tmp_path, capsys, monkeypatch, which):
    """``fabric synth --out BTF --gt-out GT`` where GT cannot be written: one line naming --gt-out, and the BTF
    folder as it was (it was replaced before the ground truth failed). Not writable is simulated (tests may run
    as root, whom permissions do not stop)."""
    import os
    import shutil

    btf = tmp_path / "btf"
    shutil.copytree(inputs / "btf", btf)
    before = _sha(btf / "btf.json")
    gt = tmp_path / "gt"
    if which == "a file":
        gt.write_text("")
    else:
        gt.mkdir()
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode: False if os.path.abspath(p) == str(gt) else real(p, mode))
    assert main(["fabric", "synth", "--out", str(btf), "--gt-out", str(gt), "--width", "3", "--height", "3",
                 "--lights", "2", "--views", "2"]) == 1
    err = capsys.readouterr().err
    said = "is a file" if which == "a file" else "not writable"
    assert err.startswith("error: --gt-out ") and said in err and err.count("\n") == 1, err
    assert _sha(btf / "btf.json") == before


def test_input_written_over_follows_links_and_nesting(tmp_path):
    """The one rule the CLI and the add-on share: the output is the input, inside it, or holds it."""
    import os

    from material_structures.core.output_paths import input_written_over

    (tmp_path / "in").mkdir()
    os.symlink(tmp_path / "in", tmp_path / "alias")
    for out in ("in", "in/sub", "alias/x"):  # the input, inside it, inside it through a link
        assert input_written_over(tmp_path / out, [tmp_path / "other", tmp_path / "in"]) == str(tmp_path / "in")
    assert input_written_over(tmp_path, [tmp_path / "in"]) == str(tmp_path / "in")  # holding it
    assert input_written_over(tmp_path / "in2", [tmp_path / "in"]) is None  # a prefix of the name is not inside
