"""``teeth synth`` / ``teeth fit`` end to end on a tiny capture: files, determinism and resume."""

from __future__ import annotations

import json

import numpy as np
import pytest

from material_structures.cli import main
from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import load_scene


def test_synth_then_fit_with_resume(tmp_path):
    cap_dir, fit_dir = tmp_path / "cap", tmp_path / "fit"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "4", "--cameras", "2", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    cap = Capture.load(cap_dir)
    assert cap.images.shape == (2, 4, 12, 16, 3) and cap.masks.any()
    # the stored images are the renderer's output for the stored ground-truth scene (same seeds)
    scene = load_scene(cap_dir / "scene.json")
    pixels = [np.flatnonzero(m.ravel()) for m in cap.masks]
    res = render(scene, cap.cameras, cap.lights, RenderSettings(2, None, 12345), pixels=pixels,
                 light_ids=np.arange(4))
    masked = cap.masks[:, None, :, :, None] & np.ones((1, 4, 1, 1, 3), dtype=bool)
    np.testing.assert_allclose(cap.images[masked], res.images[masked], rtol=1e-6, atol=1e-9)

    common = ["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--init", "perturbed",
              "--lights-per-iteration", "2", "--no-progress", "--max-depth", "3"]
    assert main(common + ["--iterations", "3"]) == 0
    log3 = json.loads((fit_dir / "loss.json").read_text())["log"]
    assert len(log3) == 3 and (fit_dir / "loss.png").exists() and (fit_dir / "scene_fit.json").exists()
    assert main(common + ["--iterations", "5", "--resume"]) == 0
    log5 = json.loads((fit_dir / "loss.json").read_text())["log"]
    assert [e["iteration"] for e in log5] == [0, 1, 2, 3, 4]
    assert [e["loss"] for e in log5[:3]] == pytest.approx([e["loss"] for e in log3], rel=0, abs=0)
    # an uninterrupted 5-iteration run gives the same losses as 3 + resume 2
    fit2 = tmp_path / "fit2"
    assert main(common[:4] + [str(fit2)] + common[5:] + ["--iterations", "5"]) == 0
    log5b = json.loads((fit2 / "loss.json").read_text())["log"]
    assert [e["loss"] for e in log5b] == pytest.approx([e["loss"] for e in log5], rel=1e-12)
    assert main(["teeth", "fit", str(tmp_path / "nope"), "--out", str(fit_dir)]) == 2


def test_fit_with_anchor_control_variate_resumes_exactly(tmp_path):
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    common = ["teeth", "fit", str(cap_dir), "--init", "perturbed", "--lights-per-iteration", "2", "--no-progress",
              "--max-depth", "3", "--anchor-spp", "2", "--anchor-every", "2", "--domain", "absorption"]
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(common + ["--out", str(a), "--iterations", "3"]) == 0
    assert main(common + ["--out", str(a), "--iterations", "5", "--resume"]) == 0
    assert main(common + ["--out", str(b), "--iterations", "5"]) == 0
    la = json.loads((a / "loss.json").read_text())["log"]
    lb = json.loads((b / "loss.json").read_text())["log"]
    assert [e["iteration"] for e in la] == [0, 1, 2, 3, 4]
    assert [e["loss"] for e in la] == pytest.approx([e["loss"] for e in lb], rel=1e-12)
    assert all(np.isfinite(e["loss"]) for e in la)


def test_sensitivity_cli_writes_a_table(tmp_path, capsys):
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "4", "--cameras", "1", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    out = tmp_path / "sens.json"
    assert main(["teeth", "sensitivity", str(cap_dir), "--capture-spp", "2", "--passes", "3", "--block", "4",
                 "--max-depth", "4", "--json", str(out)]) == 0
    table = json.loads(out.read_text())
    names = list(table["chi2"])
    assert "tooth0.enamel.sigma_s[0]" in names and "tooth0.c[2]" in names and table["noise_variance"] > 0
    assert table["chi2"]["tooth0.enamel.sigma_s[1]"] > 0
    assert "chi2 of each change" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:  # neither noise option: argparse's usage error
        main(["teeth", "sensitivity", str(cap_dir)])
    assert e.value.code == 2


def test_fit_starts_from_the_literature_search(tmp_path):
    """``--init literature`` (the default) runs the table search before the fit: the first iteration's
    scene is the search's start (table values, c = 0)."""
    from material_structures.core.teeth.literature_init import literature_start, literature_table

    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "3", "--cameras", "1", "--spp", "2", "--spp-background", "0",
                 "--resolution", "12"]) == 0
    cap = Capture.load(cap_dir)
    table, _ = literature_table()
    fit_dir = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--iterations", "1",
                 "--lights-per-iteration", "1", "--no-progress", "--max-depth", "3", "--free", "*.c"]) == 0
    fitted = load_scene(fit_dir / "scene_fit.json")  # best of 1 iteration = the start (only c is free)
    expected = literature_start(load_scene(cap_dir / "scene.json"), cap)  # scale-invariant, the default
    for t, e in zip(fitted.teeth, expected.teeth, strict=True):
        np.testing.assert_allclose(t.enamel.sigma_t, e.enamel.sigma_t, rtol=1e-12)
        np.testing.assert_allclose(t.dentin.albedo, e.dentin.albedo, rtol=1e-12)
        assert all(np.isclose(table[:, 0], s).any() for s in t.enamel.sigma_t)
        np.testing.assert_array_equal(t.c, 0.0)


def test_fit_image_spp_and_workers_in_one_process(tmp_path, capsys):
    """``--no-dask --workers 2`` traces each pass in 2 forked processes: the same losses as one
    process; ``--image-spp`` reaches pass A (more path vertices per iteration); ``--workers`` without
    ``--no-dask`` is a clear error."""
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    common = ["teeth", "fit", str(cap_dir), "--init", "perturbed", "--lights-per-iteration", "2", "--no-progress",
              "--max-depth", "3", "--iterations", "2", "--no-dask", "--image-spp", "6"]
    logs = {}
    for name, extra in (("one", []), ("two", ["--workers", "2"]), ("plain", ["--image-spp", "0"])):
        assert main(common + ["--out", str(tmp_path / name), *extra]) == 0
        logs[name] = json.loads((tmp_path / name / "loss.json").read_text())["log"]
    assert [e["loss"] for e in logs["two"]] == pytest.approx([e["loss"] for e in logs["one"]], rel=1e-9)
    assert logs["plain"][0]["path_vertices"] < logs["one"][0]["path_vertices"]
    capsys.readouterr()
    assert main(["teeth", "fit", str(cap_dir), "--out", str(tmp_path / "x"), "--workers", "2"]) == 2
    assert "--workers is for --no-dask" in capsys.readouterr().err


def test_fit_gauss_newton_from_the_command_line(tmp_path, capsys):
    """``--optimiser gauss-newton`` estimates the Gauss-Newton matrix from ``--gn-start`` on every
    ``--gn-every`` iterations (logged per iteration), writes it to the checkpoint, and bad values are clear
    errors."""
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    out = tmp_path / "gn"
    assert main(["teeth", "fit", str(cap_dir), "--out", str(out), "--init", "perturbed", "--no-progress", "--no-dask",
                 "--lights-per-iteration", "2", "--max-depth", "3", "--iterations", "3", "--optimiser", "gauss-newton",
                 "--gn-start", "1", "--gn-every", "2", "--gn-passes", "1", "--gn-guard-window", "2",
                 "--gn-guard-rise", "0.5", "--free", "*.enamel.albedo,*.dentin.albedo,tooth0.c"]) == 0
    loss_json = json.loads((out / "loss.json").read_text())
    log = loss_json["log"]
    assert ["gauss_newton_seconds" in e for e in log] == [False, True, False]
    assert [loss_json["settings"][k] for k in ("gn_guard_window", "gn_guard_rise")] == [2, 0.5]
    assert ["gauss_newton_damping" in e for e in log] == [False, True, True]
    ckpt = json.loads((out / "checkpoint.json").read_text())
    assert np.array(ckpt["gn_hmat"]).shape == (6, 6)  # the albedos; the coefficients keep Adam
    assert ckpt["precond_iteration"] == 1
    capsys.readouterr()
    assert main(["teeth", "fit", str(cap_dir), "--out", str(tmp_path / "x"), "--no-dask", "--optimiser",
                 "gauss-newton", "--gn-damping", "0"]) == 2
    assert "gn_damping" in capsys.readouterr().err


def test_fit_preset_sets_defaults_and_explicit_flags_win(tmp_path, capsys):
    from material_structures.cli import build_parser
    from material_structures.cli.teeth import FIT_CLI_DEFAULTS, fit_preset_settings
    from material_structures.core.teeth.fit_presets import FIT_PRESETS

    parser = build_parser()
    base = ["teeth", "fit", "cap", "--out", "fit"]
    for name in FIT_PRESETS:
        assert parser.parse_args(base + ["--preset", name]).preset == name
    with pytest.raises(SystemExit):
        parser.parse_args(base + ["--preset", "fast"])
    assert fit_preset_settings(parser.parse_args(base)) == FIT_CLI_DEFAULTS
    acc = fit_preset_settings(parser.parse_args(base + ["--preset", "acceptance"]))
    assert acc == {**FIT_CLI_DEFAULTS, **FIT_PRESETS["acceptance"]}
    assert acc["loss_block"] == 8 and acc["optimiser"] == "gauss-newton" and acc["image_spp"] == 32
    assert acc["iterations"] == FIT_PRESETS["acceptance"]["iterations"] > FIT_CLI_DEFAULTS["iterations"]
    # the help text lists the preset's values as the flags that would set them
    with pytest.raises(SystemExit):
        parser.parse_args(["teeth", "fit", "--help"])
    help_text = "".join(capsys.readouterr().out.split())  # argparse wraps lines at spaces and hyphens
    for key, value in FIT_PRESETS["acceptance"].items():
        assert f"--{key.replace('_', '-')}{value}" in help_text, key
    mixed = fit_preset_settings(parser.parse_args(base + ["--preset", "acceptance", "--lr", "0.01",
                                                          "--loss-block", "1"]))
    assert mixed == {**acc, "lr": 0.01, "loss_block": 1}

    # end to end: the settings the fit ran with are the preset's (loss.json records them)
    cap_dir, fit_dir = tmp_path / "cap", tmp_path / "fit"
    assert main(["teeth", "synth", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--spp", "2", "--spp-background", "1",
                 "--resolution", "12"]) == 0
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--init", "perturbed", "--no-progress",
                 "--no-dask", "--max-depth", "3", "--iterations", "2", "--preset", "acceptance",
                 "--image-spp", "4", "--gn-start", "1"]) == 0
    ran = json.loads((fit_dir / "loss.json").read_text())
    s = ran["settings"]
    assert (s["loss_block"], s["optimiser"], s["lr"], s["spp"], s["image_spp"], s["gn_start"]) == \
        (8, "gauss-newton", 0.04, 4, 4, 1)
    assert len(ran["log"]) == 2 and "gauss_newton_seconds" in ran["log"][1]


def test_fit_cli_gauss_newton_defaults_match_fit_settings():
    """The CLI parser does not import the numpy core for --help, so FIT_CLI_DEFAULTS' gn_* values and
    --gn-estimator's choices are written out in cli/teeth.py; they must stay those of FitSettings and
    gauss_newton.ESTIMATORS."""
    import dataclasses

    from material_structures.cli import build_parser
    from material_structures.cli.teeth import FIT_CLI_DEFAULTS
    from material_structures.core.teeth.gauss_newton import ESTIMATORS
    from material_structures.core.teeth.optimise import FitSettings

    fields = {f.name: f.default for f in dataclasses.fields(FitSettings)}
    gn_keys = [k for k in FIT_CLI_DEFAULTS if k.startswith("gn_")]
    assert len(gn_keys) >= 7
    for key in gn_keys:
        assert FIT_CLI_DEFAULTS[key] == fields[key], key
    fit_parser = build_parser()._subparsers._group_actions[0].choices["teeth"]
    fit_parser = fit_parser._subparsers._group_actions[0].choices["fit"]
    choices = {a.dest: a.choices for a in fit_parser._actions}
    assert tuple(choices["gn_estimator"]) == tuple(ESTIMATORS)
