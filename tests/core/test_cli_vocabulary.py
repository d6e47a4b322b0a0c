"""One CLI vocabulary (issue 67): every option of every subcommand has help and shows its default, every
subcommand that writes files takes ``--out`` and every one that renders takes ``--samples``, every numeric
option refuses out-of-range values at parse time (exit 2, one line), angles are degrees, old spellings still
work for one release with a note, ``--version`` and the ``material-structures`` console command exist, and
runtime errors exit 1."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tomllib

import pytest

from material_structures import __version__
from material_structures.cli import DefaultsHelpFormatter, build_parser, main
from material_structures.cli.checks import _OldSpelling

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# subcommands that write no file (they print): every other one takes --out
WRITES_NOTHING = {"fabric score", "scratch info"}
# subcommands that render with samples per pixel (Cycles or a path tracer): they take --samples
RENDERS = {"render", "demo", "library", "fabric material", "teeth synth", "teeth render"}
# options where a negative value means something (coordinates, signed angles)
NEGATIVE_OK = {"--light", "--angle-deg", "--rotation-deg", "--rotation"}
# options where 0 means something (none of it, no tilt, seed 0, the first texel, ...)
ZERO_OK = NEGATIVE_OK | {"--seed", "--truth-seed", "--noise", "--samples-background", "--spp-background",
                         "--textured-iterations", "--held-out-lights", "--held-out-camera", "--texel", "--max-tilt-deg",
                         "--max-tilt", "--view-deg"}


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices.items())
    return []


def _walk(parser, path=()):
    yield " ".join(path), parser
    for name, sub in _subparsers(parser):
        yield from _walk(sub, path + (name,))


PARSERS = list(_walk(build_parser()))
LEAVES = [(path, p) for path, p in PARSERS if not _subparsers(p)]
OPTIONS = [(path, a) for path, p in PARSERS for a in p._actions
           if not isinstance(a, argparse._HelpAction | argparse._VersionAction | argparse._SubParsersAction)]
NUMERIC = [(path, a) for path, a in OPTIONS if a.type is not None and a.type is not str and a.option_strings]


def _name(path: str, action: argparse.Action) -> str:
    return f"{path or 'ROOT'} {'/'.join(action.option_strings) or action.dest}"


def test_the_walk_sees_every_subcommand():
    paths = {path for path, _ in LEAVES}
    assert {"render", "demo", "fabric fit", "scratch eval", "teeth synth", "teeth sensitivity"} <= paths
    assert len(OPTIONS) > 100 and len(NUMERIC) > 40


@pytest.mark.parametrize("path, action", OPTIONS, ids=[_name(p, a) for p, a in OPTIONS])
def test_every_option_has_help_and_shows_its_default(path, action):
    assert action.help and action.help.strip() and action.help is not argparse.SUPPRESS, \
        f"{_name(path, action)} has no help"
    if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
        shown = DefaultsHelpFormatter("prog")._expand_help(action)
        assert "default" in shown, f"{_name(path, action)} hides its default {action.default!r}: {shown}"


@pytest.mark.parametrize("path, parser", LEAVES, ids=[p for p, _ in LEAVES])
def test_writers_take_out_and_renderers_take_samples(path, parser):
    options = {s for a in parser._actions for s in a.option_strings}
    if path not in WRITES_NOTHING:
        assert "--out" in options, f"'{path}' writes files but has no --out"
    if path in RENDERS:
        assert "--samples" in options, f"'{path}' renders but has no --samples"


@pytest.mark.parametrize("path, action", OPTIONS, ids=[_name(p, a) for p, a in OPTIONS])
def test_one_spelling_for_samples_resolution_and_angles(path, action):
    """Samples per pixel are --samples (``spp`` only in old spellings), --resolution is an image's WxH,
    angles are degrees (no option takes radians but an old spelling)."""
    old = isinstance(action, _OldSpelling)
    for s in action.option_strings:
        assert old or "spp" not in s, f"{_name(path, action)}: samples per pixel are --samples"
        if s == "--resolution" and not old:
            assert action.type.__name__ == "WxH", f"{_name(path, action)}: --resolution is an image's WxH"
    assert old or "radian" not in action.help and "(rad)" not in action.help, f"{_name(path, action)} takes radians"
    if any(s.endswith("-deg") for s in action.option_strings):
        assert "degree" in action.help, f"{_name(path, action)}: say the unit"


@pytest.mark.parametrize("path, action", NUMERIC, ids=[_name(p, a) for p, a in NUMERIC])
def test_numeric_options_are_range_checked(path, action):
    assert action.type not in (int, float), f"{_name(path, action)} takes any number: give it a range (cli/checks.py)"
    bad = ["nan", "inf", "-inf"]
    opt = action.option_strings[0]
    if opt not in NEGATIVE_OK:
        bad.append("-1")
    if opt not in ZERO_OK:
        bad.append("0")
    if action.type.__name__ == "WxH":
        bad = ["0x10", "-1x10", "10x0", "10", "nan"]
    for value in bad:
        with pytest.raises(argparse.ArgumentTypeError):
            action.type(value)
            pytest.fail(f"{_name(path, action)} accepts {value}")


@pytest.mark.parametrize("argv, said", [
    (["render", "--samples", "-5", "test-card"], "argument --samples: must be >= 1, got -5"),
    (["render", "--resolution", "0x10", "test-card"], "argument --resolution: must be at least 1x1"),
    (["teeth", "render", "S", "C", "--out", "O", "--samples", "0"], "argument --samples: must be >= 1, got 0"),
    (["scratch", "eval", "s.npz", "--out", "e.exr", "--workers", "0"], "argument --workers: must be >= 1, got 0"),
    (["fabric", "synth", "--out", "b", "--rotation-deg", "400"], "argument --rotation-deg: must be <= 360"),
    (["render", "--bogus"], "unrecognized arguments: --bogus"),
])
def test_usage_errors_are_one_line_and_exit_2(capsys, argv, said):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err


def test_runtime_errors_exit_1(tmp_path, capsys):
    assert main(["scratch", "info", str(tmp_path / "nope.npz")]) == 1  # a missing file: runtime
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    # an option combination that cannot work is a usage error, though found after parsing
    assert main(["scratch", "eval", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "e.png")]) == 2


def test_exit_status_is_in_the_help_and_the_docs():
    text = build_parser().format_help()
    assert "Exit status" in text and "2 a usage error" in text and "1 a runtime error" in text
    with open(os.path.join(ROOT, "docs", "cli.md")) as f:
        page = f.read()
    assert "2 for a usage error" in page and "1 for a runtime error" in page


@pytest.mark.parametrize("argv, dest, value, note", [
    (["teeth", "render", "S", "C", "--out", "O", "--spp", "3"], "samples", 3, "--spp"),
    (["teeth", "synth", "--out", "O", "--spp-background", "0"], "samples_background", 0, "--spp-background"),
    (["teeth", "synth", "--out", "O", "--resolution", "12"], "mesh_resolution", 12, "--resolution"),
    (["teeth", "sensitivity", "C", "--capture-spp", "4"], "capture_samples", 4, "--capture-spp"),
    (["teeth", "sensitivity", "C", "--capture-samples", "4", "--json", "t.json"], "out", "t.json", "--json"),
    (["fabric", "synth", "--out", "b", "--theta-max", "60"], "theta_max_deg", 60.0, "--theta-max"),
    (["fabric", "synth", "--out", "b", "--max-tilt", "20"], "max_tilt_deg", 20.0, "--max-tilt"),
    (["fabric", "synth", "--out", "b", "--rotation", "0.5"], "rotation_deg", pytest.approx(28.64788975654116),
     "--rotation"),
    (["fabric", "ndf", "B", "--out", "n.exr", "--resolution", "32"], "size", 32, "--resolution"),
])
def test_old_spellings_work_for_one_release_with_a_note(capsys, argv, dest, value, note):
    args = build_parser().parse_args(argv)
    assert getattr(args, dest) == value
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"note: {note} is an old spelling"), err


def test_old_spellings_are_range_checked_too(capsys):
    assert main(["teeth", "render", "S", "C", "--out", "O", "--spp", "0"]) == 2
    assert "argument --spp: must be >= 1, got 0" in capsys.readouterr().err


def test_teeth_synth_positional_out_is_an_old_spelling(tmp_path, capsys):
    missing = str(tmp_path / "nope.json")
    assert main(["teeth", "synth", str(tmp_path / "cap"), "--scene", missing]) == 1  # the note, then the error
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("note: the positional OUT is an old spelling") and missing in err[1], err
    assert main(["teeth", "synth", str(tmp_path / "a"), "--out", str(tmp_path / "b")]) == 2
    assert "two output folders" in capsys.readouterr().err
    assert main(["teeth", "synth", "--teeth", "1"]) == 2
    assert "required: --out" in capsys.readouterr().err


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"material-structures {__version__}"


def test_console_command():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        assert tomllib.load(f)["project"]["scripts"]["material-structures"] == "material_structures.cli:main"
    exe = os.path.join(os.path.dirname(sys.executable), "material-structures")
    assert os.path.isfile(exe), f"{exe} is missing: `bash scripts/bootstrap.sh main` installs it"
    r = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"material-structures {__version__}", r.stderr
    r = subprocess.run([exe, "render", "--samples", "-5", "test-card"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr == "error: material-structures render: argument --samples: must be >= 1, " \
                                             "got -5\n", r.stderr


@pytest.mark.heavy
def test_render_leaves_no_work_folder(tmp_path):
    out = tmp_path / "renders"
    r = subprocess.run([sys.executable, "-m", "material_structures", "render", "test-card", "--resolution", "32x24",
                        "--samples", "1", "--out", str(out / "card.png")], capture_output=True, text=True, timeout=600,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert sorted(os.listdir(out)) == ["card.png"] and sorted(os.listdir(tmp_path)) == ["renders"]
