"""``teeth synth`` / ``teeth fit`` end to end on a tiny capture: files, determinism and resume."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from material_structures.cli import main
from material_structures.core import json_schema
from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.fit_settings import FitSettings
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import load_scene

TRIALS = 30  # FitSettings.start_trials of the tests of the start trials (the default fit has none)


@pytest.fixture
def with_trials(monkeypatch):
    """``teeth fit`` with start trials (a FitSettings option the command line does not offer)."""
    import dataclasses

    import material_structures.cli.teeth as cli_teeth

    monkeypatch.setattr(cli_teeth, "FIT_DEFAULTS", dataclasses.replace(FitSettings(), start_trials=TRIALS))

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`


def test_synth_then_fit_with_resume(tmp_path):
    cap_dir, fit_dir = tmp_path / "cap", tmp_path / "fit"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "4", "--cameras", "2", "--samples", "2", "--samples-background", "1",
                 "--mesh-resolution", "12"]) == 0
    cap = Capture.load(cap_dir)
    assert cap.images.shape == (2, 4, 12, 16, 3) and cap.masks.any()
    # the stored images are the renderer's output for the stored ground-truth scene (same seeds)
    scene = load_scene(cap_dir / "scene.json")
    pixels = [np.flatnonzero(m.ravel()) for m in cap.masks]
    res = render(scene, cap.cameras, cap.lights, RenderSettings(2, None, 12345), pixels=pixels,
                 light_ids=np.arange(4))
    masked = cap.masks[:, None, :, :, None] & np.ones((1, 4, 1, 1, 3), dtype=bool)
    np.testing.assert_allclose(cap.images[masked], res.images[masked], rtol=1e-6, atol=1e-9)

    common = ["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--init", "perturbed", "--no-progress"]
    assert main(common + ["--iterations", "3"]) == 0
    log3 = json.loads((fit_dir / "loss.json").read_text())["log"]
    assert len(log3) == 3 and (fit_dir / "loss.png").exists() and (fit_dir / "scene_fit.json").exists()
    # one of the 4 lights (at most a quarter) is held out: never fitted, rendered at the result to check it
    report = json.loads((fit_dir / "fit_report.json").read_text())
    assert report["held_out"]["lights"] == [2] and (fit_dir / "check.png").exists()
    held = report["held_out"]  # the light farthest off the capture's axis, outside the cone the fit saw
    assert len(held["light_angles_deg"]) == 1 and held["training_cone_deg"] < held["light_angles_deg"][0]
    assert all(2 not in e["lights"] for e in log3)
    assert 0 < report["held_out"]["rms_relative"] < 1 and len(report["held_out"]["mean_ratio_rgb"]) == 3
    assert main(common + ["--iterations", "5", "--resume"]) == 0
    log5 = json.loads((fit_dir / "loss.json").read_text())["log"]
    assert [e["iteration"] for e in log5] == [0, 1, 2, 3, 4]
    assert [e["loss"] for e in log5[:3]] == pytest.approx([e["loss"] for e in log3], rel=0, abs=0)
    # an uninterrupted 5-iteration run gives the same losses as 3 + resume 2
    fit2 = tmp_path / "fit2"
    assert main(common[:4] + [str(fit2)] + common[5:] + ["--iterations", "5"]) == 0
    log5b = json.loads((fit2 / "loss.json").read_text())["log"]
    assert [e["loss"] for e in log5b] == pytest.approx([e["loss"] for e in log5], rel=1e-12)
    assert main(["teeth", "fit", str(tmp_path / "nope"), "--out", str(fit_dir)]) == 1


def test_synth_renders_a_given_scene(tmp_path, capsys):
    """``teeth synth --scene`` renders the user's ground truth (other materials and coefficients than the
    built-in jaw section), writes it as the capture's scene.json, and refuses a missing file in one line."""
    from material_structures.core.teeth.scene import VolumeMaterial, save_scene
    from material_structures.core.teeth.synthetic import make_scene

    truth = make_scene(n_teeth=1, resolution=12)
    truth.teeth[0].enamel = VolumeMaterial([1.3, 1.5, 1.9], [0.95, 0.935, 0.91], 0.55, -0.25, 0.8)
    truth.teeth[0].c = np.array([0.25, -0.15, 0.1])
    save_scene(truth, tmp_path / "truth.json")
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--scene", str(tmp_path / "truth.json"), "--width",
                 "16", "--height", "12", "--lights", "3", "--cameras", "1", "--samples", "2", "--samples-background",
                 "0"]) == 0
    written = load_scene(cap_dir / "scene.json")
    np.testing.assert_array_equal(written.teeth[0].enamel.sigma_t, [1.3, 1.5, 1.9])
    np.testing.assert_array_equal(written.teeth[0].c, [0.25, -0.15, 0.1])
    cap = Capture.load(cap_dir)
    pixels = [np.flatnonzero(m.ravel()) for m in cap.masks]
    res = render(truth, cap.cameras, cap.lights, RenderSettings(2, None, 12345), pixels=pixels,
                 light_ids=np.arange(3))
    masked = cap.masks[:, None, :, :, None] & np.ones((1, 3, 1, 1, 3), dtype=bool)
    assert masked.sum() > 30
    np.testing.assert_allclose(cap.images[masked], res.images[masked], rtol=1e-6, atol=1e-9)
    capsys.readouterr()
    assert main(["teeth", "synth", "--out", str(tmp_path / "cap2"), "--scene", str(tmp_path / "nope.json")]) == 1
    err = capsys.readouterr().err
    assert "nope.json" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_sensitivity_cli_writes_a_table(tmp_path, capsys):
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "4", "--cameras", "1", "--samples", "2", "--samples-background", "1",
                 "--mesh-resolution", "12"]) == 0
    out = tmp_path / "sens.json"
    assert main(["teeth", "sensitivity", str(cap_dir), "--capture-samples", "2", "--passes", "3", "--block", "4",
                 "--max-depth", "4", "--out", str(out)]) == 0
    table = json.loads(out.read_text())
    names = list(table["chi2"])
    assert "tooth0.enamel.sigma_s[0]" in names and "tooth0.c[2]" in names and table["noise_variance"] > 0
    # chi2 is estimated without bias from pairs of passes and can come out below 0 where the image change is small
    # against the passes' noise: enamel sigma_s's (about 0.05 here) ranged -0.04 to 0.13 over 3-40 passes, while
    # the blue absorption's stayed within 0.020-0.030
    assert table["chi2"]["tooth0.enamel.sigma_a[2]"] > 0
    assert set(table["best_std"]) == set(names) and all(v > 0 for v in table["best_std"].values())
    assert "chi2 of each change" in capsys.readouterr().out
    capsys.readouterr()
    assert main(["teeth", "sensitivity", str(cap_dir)]) == 2  # neither noise option: one line
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--capture-samples" in err and err.count("\n") == 1, err


def test_fit_starts_at_the_literature_middle_g(tmp_path):
    """``--init literature`` (the default) runs the table search and starts from its start of g 0.6
    (``literature_init.START_G``): with only the dentin coefficients free, the materials stay that start's (its
    table values and g), and there are no trials (no start_trials.json, no trials' folder)."""
    from material_structures.core.teeth.literature_init import G_VALUES, START_G, literature_starts

    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "3", "--cameras", "1", "--samples", "2", "--samples-background", "0",
                 "--mesh-resolution", "12"]) == 0
    fit_dir = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--iterations", "1", "--no-progress",
                 "--free", "*.c"]) == 0
    assert START_G == 0.6 and not (fit_dir / "start_trials.json").exists() and not (fit_dir / "start_trials").exists()
    assert "start_trials" not in json.loads((fit_dir / "fit_report.json").read_text())
    expected = literature_starts(load_scene(cap_dir / "scene.json"), Capture.load(cap_dir))[G_VALUES.index(START_G)]
    for t, e in zip(load_scene(fit_dir / "scene_fit.json").teeth, expected.teeth, strict=True):
        assert t.enamel.g1 == t.dentin.g1 == START_G
        np.testing.assert_allclose(t.enamel.sigma_t, e.enamel.sigma_t, rtol=1e-12)
        np.testing.assert_allclose(t.dentin.albedo, e.dentin.albedo, rtol=1e-12)


def test_fit_starts_from_the_literature_search(tmp_path, with_trials):
    """With start trials, the table search's start of every phase-function g runs the fit's
    first iterations, and goes on from the trial of lowest loss (its iterations count): with only
    the dentin coefficients free, the materials stay that start's (table values), and start_trials.json /
    fit_report.json name it; the trials' folder is gone."""
    from material_structures.core.teeth.literature_init import G_VALUES, literature_starts, literature_table

    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "3", "--cameras", "1", "--samples", "2", "--samples-background", "0",
                 "--mesh-resolution", "12"]) == 0
    cap = Capture.load(cap_dir)
    table, _ = literature_table()
    fit_dir = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--iterations", "1", "--no-progress",
                 "--free", "*.c"]) == 0
    trials = json.loads((fit_dir / "start_trials.json").read_text())
    assert trials["g1"] == list(G_VALUES) and len(trials["trial_loss"]) == len(G_VALUES)
    assert trials["chosen"] == int(np.argmin(trials["trial_loss"]))
    report = json.loads((fit_dir / "fit_report.json").read_text())
    assert report["start_trials"] == trials and trials["iterations"] == [1, 1, 1] and report["iterations"] == 1
    assert json_schema.errors(report, "teeth-fit-report") is None  # core/schemas/teeth-fit-report.schema.json
    assert report["capture_outliers"]["values"] >= 0 and report["capture_outliers"]["noise_sd"] > 0
    # what the capture determines: an entry per parameter, an interval from the capture exactly where determined
    iv = report["intervals"]
    # enamel, dentin, gums: 6 sigma_s/sigma_a and 3 phase parameters each; 3 dentin coefficients
    assert iv["noise_variance"] > 0 and len(iv["parameters"]) == 30
    assert all((p["interval_from"] == "capture") == p["determined"] for p in iv["parameters"])
    assert iv["determined_count"] == sum(p["determined"] for p in iv["parameters"])
    assert not (fit_dir / "start_trials").exists() and (fit_dir / "checkpoint.json").is_file()
    fitted = load_scene(fit_dir / "scene_fit.json")  # only c is free: the materials are the chosen start's
    expected = literature_starts(load_scene(cap_dir / "scene.json"), cap)[trials["chosen"]]
    for t, e in zip(fitted.teeth, expected.teeth, strict=True):
        np.testing.assert_allclose(t.enamel.sigma_t, e.enamel.sigma_t, rtol=1e-12)
        np.testing.assert_allclose(t.dentin.albedo, e.dentin.albedo, rtol=1e-12)
        assert t.enamel.g1 == e.enamel.g1
        assert all(np.isclose(table[:, 0], s).any() for s in t.enamel.sigma_t)


def test_fit_workers_in_one_process_and_clear_errors(tmp_path, capsys):
    """``--workers 2`` traces each pass in 2 forked processes where numba is missing (the compiled tracer
    ignores it): the same losses as one process; ``--workers`` with Dask and out-of-range values are
    one-line errors (exit 2)."""
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--samples", "2", "--samples-background", "1",
                 "--mesh-resolution", "12"]) == 0
    common = ["teeth", "fit", str(cap_dir), "--init", "perturbed", "--no-progress", "--iterations", "2"]
    logs = {}
    for name, extra in (("one", []), ("two", ["--workers", "2"])):
        assert main(common + ["--out", str(tmp_path / name), *extra]) == 0
        logs[name] = json.loads((tmp_path / name / "loss.json").read_text())["log"]
    assert [e["loss"] for e in logs["two"]] == pytest.approx([e["loss"] for e in logs["one"]], rel=1e-9)
    # on a local Dask cluster (a task per band of a camera's rows; the intervals' renders too); more held-out
    # lights than a quarter of the capture's are held out as that quarter, and the fit says so (it did not)
    capsys.readouterr()
    assert main(common + ["--out", str(tmp_path / "dask"), "--dask-workers", "1", "--held-out-lights", "2"]) == 0
    assert len(json.loads((tmp_path / "dask" / "loss.json").read_text())["log"]) == 2
    assert ("note: --held-out-lights 2: a fit holds out at most a quarter of the capture's 3 lights; it holds out 0"
            in capsys.readouterr().err)
    assert main(["teeth", "fit", str(cap_dir), "--out", str(tmp_path / "x"), "--workers", "2", "--dask-workers",
                 "1"]) == 2
    assert "--workers is for fits in this process" in capsys.readouterr().err
    for flag, value, said in (("--iterations", "0", "argument --iterations: must be >= 1, got 0"),
                              ("--held-out-lights", "-1", "argument --held-out-lights: must be >= 0, got -1"),
                              ("--dask-workers", "0", "argument --dask-workers: must be >= 1, got 0"),
                              ("--workers", "nan", "argument --workers: 'nan' is not an integer")):
        assert main(["teeth", "fit", str(cap_dir), "--out", str(tmp_path / "x"), flag, value]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and said in err and err.count("\n") == 1, err


def test_fit_cli_defaults_are_fit_settings_and_help_is_short(tmp_path, capsys):
    """``teeth fit CAPTURE --out FIT`` runs FitSettings() (no second table of defaults), --help lists at most
    15 options, and the settings a fit ran with are recorded in loss.json."""
    import dataclasses

    from material_structures.cli import build_parser
    from material_structures.cli.teeth import fit_settings
    from material_structures.core.teeth.fit_settings import FitSettings

    parser = build_parser()
    base = ["teeth", "fit", "cap", "--out", "fit"]
    assert fit_settings(parser.parse_args(base)) == FitSettings()
    flags = fit_settings(parser.parse_args(base + ["--iterations", "40", "--seed", "3", "--free", "*.albedo, *.c",
                                                   "--held-out-lights", "0", "--textured-iterations", "5"]))
    assert flags == dataclasses.replace(FitSettings(), iterations=40, seed=3, free=("*.albedo", "*.c"),
                                        held_out_lights=0, textured_iterations=5)
    with pytest.raises(SystemExit):
        parser.parse_args(["teeth", "fit", "--help"])
    options = [line for line in capsys.readouterr().out.splitlines() if line.lstrip().startswith("-")]
    assert 5 <= len(options) <= 15, options

    cap_dir, fit_dir = tmp_path / "cap", tmp_path / "fit"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "16", "--height", "12",
                 "--lights", "3", "--cameras", "1", "--samples", "2", "--samples-background", "1",
                 "--mesh-resolution", "12"]) == 0
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--init", "perturbed", "--no-progress",
                 "--iterations", "2"]) == 0
    ran = json.loads((fit_dir / "loss.json").read_text())
    want = dataclasses.asdict(dataclasses.replace(FitSettings(), iterations=2))
    assert ran["settings"] == json.loads(json.dumps(want))
    assert len(ran["log"]) == 2
    # 3 lights: none held out (fewer than 4), and the report says so
    report = json.loads((fit_dir / "fit_report.json").read_text())
    assert report["held_out"]["lights"] == [] and not (fit_dir / "check.png").exists()


def test_fit_progress_as_json_lines(tmp_path, capsys, monkeypatch, with_trials):
    """With MATERIAL_STRUCTURES_PROGRESS=json (what the Blender add-on sets) the fit reports the literature
    search's points, each iteration, what it does between iterations and nothing else as JSON lines on stdout: no
    progress bars to parse."""
    from material_structures.core.teeth.literature_init import literature_points

    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    capsys.readouterr()
    monkeypatch.setenv("MATERIAL_STRUCTURES_PROGRESS", "json")
    n = TRIALS + 2
    assert main(["teeth", "fit", str(cap_dir), "--out", str(tmp_path / "fit"), "--iterations", str(n)]) == 0
    out, err = capsys.readouterr()
    events = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    fits = [e for e in events if e["progress"] == "fit"]
    # the trials are the fit's first start_trials iterations: the fit says so, and goes on from there
    assert [e["iteration"] for e in fits] == [n - 2, n - 1, n] and all(e["iterations"] == n for e in fits)
    assert all(np.isfinite(e["loss"]) for e in fits)
    assert events[0] == {"progress": "init", "message": "searching the literature table for a start"}
    # the search's progress (the panel shows the last message), every 5 % of its points, to the last
    inits = [e["message"] for e in events if e["progress"] == "init"][1:]
    searched = [m for m in inits if m.startswith("searching the literature table: ")]
    points = [int(m.split(": ")[1].split(" of ")[0]) for m in searched]
    total = literature_points()
    assert 10 <= len(searched) <= 20 and points == sorted(points)
    assert searched[-1].endswith(f"{total} of {total} points")
    trials = inits[len(searched):]
    assert trials[0] == f"trying 3 starts, {TRIALS} iterations each"
    ran = sum(json.loads((tmp_path / "fit" / "start_trials.json").read_text())["iterations"])  # some may stop early
    assert len(trials) == 1 + ran
    assert all(m.startswith(f"trying 3 starts: {i} of ") for i, m in enumerate(trials[1:], 1))
    assert trials[-1] == f"trying 3 starts: {ran} of {ran} iterations"
    assert any(e["progress"] == "status" and "held-out" in e["message"] for e in events)
    assert "it/s" not in err and "|" not in err  # no tqdm bars


@pytest.fixture(scope="module")
def uninterrupted_fit(tmp_path_factory):
    """A tiny capture and its fit with the start trials, not interrupted: (capture, fit folder, iterations,
    the literature search's starts). Shared by the interrupted fits below (read only)."""
    from material_structures.core.teeth import literature_init

    folder = tmp_path_factory.mktemp("trials")
    cap_dir, whole = folder / "cap", folder / "whole"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    n = TRIALS + 2
    real_search, starts = literature_init.literature_starts, []

    def search(*a, **kw):
        starts.extend(real_search(*a, **kw))
        return [s.copy() for s in starts]

    with pytest.MonkeyPatch.context() as mp:
        import dataclasses

        import material_structures.cli.teeth as cli_teeth

        mp.setattr(cli_teeth, "FIT_DEFAULTS", dataclasses.replace(FitSettings(), start_trials=TRIALS))
        mp.setattr(literature_init, "literature_starts", search)
        assert main(["teeth", "fit", str(cap_dir), "--out", str(whole), "--iterations", str(n), "--no-progress"]) == 0
    assert len(starts) == 3
    return cap_dir, whole, n, starts


# trial iterations before Ctrl-C: in the second start's first half; in the first start's second half (half 15); 0:
# after the trials, while the winner's files move into --out
@pytest.mark.parametrize("stop_after", [22, 47, 0])
def test_fit_stopped_during_its_start_trials_resumes_to_the_same_fit(uninterrupted_fit, tmp_path, monkeypatch,
                                                                     with_trials, stop_after):
    """Ctrl-C during the start trials, then ``--resume``: the trials go on from their checkpoints (no second
    search) and the fit ends with the uninterrupted fit's losses and result, to the bit."""
    from material_structures.core.teeth import literature_init, start_trials
    from material_structures.core.teeth.fit_checkpoint import stopped_fit

    cap_dir, whole, n, starts = uninterrupted_fit
    cut = tmp_path / "cut"
    # the uninterrupted fit's search (the same capture: the same starts), not a second one (60 % of a fit)
    monkeypatch.setattr(literature_init, "literature_starts", lambda *a, **k: [s.copy() for s in starts])

    real_fit, ran = start_trials.fit, [0]

    def fit_stopped_after(*a, **kw):
        def progress(entry):
            kw_progress(entry)
            ran[0] += 1
            if ran[0] == stop_after:
                raise KeyboardInterrupt
        kw_progress = kw.pop("progress")
        return real_fit(*a, progress=progress, **kw)

    monkeypatch.setattr(start_trials, "fit", fit_stopped_after)
    if stop_after == 0:
        real_replace = os.replace

        def replace_then_stop(src, dst):
            real_replace(src, dst)
            if "start_trials" in str(src) and str(src).endswith("loss.json"):
                raise KeyboardInterrupt

        monkeypatch.setattr(os, "replace", replace_then_stop)
    fit_cmd = ["teeth", "fit", str(cap_dir), "--out", str(cut), "--iterations", str(n), "--no-progress"]
    assert main(fit_cmd) == 130
    monkeypatch.undo()  # the real fit and os.replace again
    assert (cut / "start_trials" / "starts.json").is_file() and not (cut / "checkpoint.json").exists()
    assert (cut / "start_trials.json").exists() == (stop_after == 0)
    assert stopped_fit(str(cut)) and not stopped_fit(str(whole))  # what the Blender panel's Resume asks
    monkeypatch.setattr(literature_init, "literature_starts", lambda *a, **k: pytest.fail("searched again"))
    assert main(fit_cmd + ["--resume"]) == 0
    assert not (cut / "start_trials").exists() and not stopped_fit(str(cut))
    for name in ("start_trials.json", "scene_fit.json"):
        assert json.loads((cut / name).read_text()) == json.loads((whole / name).read_text()), name
    losses = [[e["loss"] for e in json.loads((d / "loss.json").read_text())["log"]] for d in (whole, cut)]
    assert len(losses[0]) == n and losses[1] == losses[0]


def test_fit_holds_out_a_camera_and_checks_it_under_every_light(tmp_path, capsys):
    """``--held-out-camera 1``: the fit never sees camera 1 (its checkpoint's capture identity has 2 of the 3
    cameras), renders it afterwards under all lights, and fit_report.json gives that check beside the held-out
    lights' (schema-valid; check_camera.png written). A camera the capture lacks, and a one-camera capture,
    are one-line errors that write nothing."""
    cap_dir = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap_dir), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "4", "--cameras", "3", "--samples", "2", "--samples-background", "0",
                 "--mesh-resolution", "12"]) == 0
    fit_dir = tmp_path / "fit"
    assert main(["teeth", "fit", str(cap_dir), "--out", str(fit_dir), "--init", "perturbed", "--iterations", "1",
                 "--no-progress", "--held-out-camera", "1"]) == 0
    report = json.loads((fit_dir / "fit_report.json").read_text())
    assert json_schema.errors(report, "teeth-fit-report") is None
    cam = report["held_out_camera"]
    assert cam["camera"] == 1 and cam["lights"] == [0, 1, 2, 3] and cam["rms_relative"] > 0
    assert report["held_out"]["lights"] == [2]  # the fit's own held-out light, as without a held-out camera
    assert (fit_dir / "check_camera.png").is_file()
    ident = json.loads((fit_dir / "checkpoint.json").read_text())
    assert "held_out_camera" in json.dumps(ident)
    assert "held-out camera 1:" in capsys.readouterr().out
    for cams, index, said in ((3, "3", "the held-out camera 3 is not in the capture (its cameras are 0-2)"),
                              (1, "0", "holding it out leaves the fit nothing to see")):
        src = cap_dir
        if cams == 1:
            src = tmp_path / "cap1"
            assert main(["teeth", "synth", "--out", str(src), "--teeth", "1", "--width", "12", "--height", "10",
                         "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                         "--mesh-resolution", "12"]) == 0
        out = tmp_path / f"bad{cams}"
        capsys.readouterr()
        assert main(["teeth", "fit", str(src), "--out", str(out), "--held-out-camera", index]) in (1, 2)
        err = capsys.readouterr().err
        assert said in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert not out.exists()
