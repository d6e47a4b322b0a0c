"""``bench teeth-smile`` (benchmarks/teeth_smile.py): its per-tooth figures are what they say, and (nightly) a
short run end to end, whose kept capture and fit a second run reuses."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

from material_structures.benchmarks import teeth_smile as bench


def test_tooth_mean_errors_are_per_tooth_light_and_channel():
    """Tooth 0 predicted 2 % too bright, tooth 1 3 % too dark under light 1 only, pixels of no tooth (-1) off
    by 50 %: the errors are 0.02 and 0 / 0.03 per light, every channel (closed form)."""
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 1.0, (2, 6, 8, 3))
    region = np.full((6, 8), -1)
    region[1:4, 1:4], region[2:5, 5:7] = 0, 1
    pred = ref.copy()
    pred[:, region == 0] *= 1.02
    pred[1][region == 1] *= 0.97
    pred[:, region == -1] *= 1.5
    err = bench.tooth_mean_errors(pred, ref, region, [0, 1])
    assert err.shape == (2, 2, 3)
    np.testing.assert_allclose(err[0], 0.02, rtol=1e-9)
    np.testing.assert_allclose(err[1, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(err[1, 1], 0.03, rtol=1e-9)


@pytest.mark.slow
def test_a_short_run_end_to_end(monkeypatch, tmp_path):
    """Nightly: a 4-light smile capture of 52 x 32 pixels at 4 spp, a 2-iteration fit from the scene's values:
    every figure is there, each upper tooth the held-out camera sees is checked (at this size the far ones hide),
    and a second run in the same kept folder renders no capture and fits nothing again (the same fit time), nor a
    third whose check has more samples than the capture (it is judged against the truth rendered at them)."""
    pytest.importorskip("mitsuba")
    for key, value in (("CAPTURE_SPP", "4"), ("SYNTH_ARGS", "--lights 4 --width 52 --height 32"),
                       ("FIT_ARGS", "--init scene --iterations 2 --held-out-lights 1"),
                       ("KEEP", str(tmp_path / "kept"))):
        monkeypatch.setenv(f"TEETH_SMILE_{key}", value)
    calls = []
    run = bench._run
    monkeypatch.setattr(bench, "_run", lambda cmd, what: (calls.append(cmd[:2]), run(cmd, what)))
    first = bench.teeth_smile()
    assert calls == [["teeth", "synth"], ["teeth", "fit"]]
    seen = first["per_upper_tooth"]
    assert len(seen) + len(first["upper_teeth_unseen"]) == 8 and len(seen) >= 5 and first["teeth"] == 16
    assert first["check_lights"] == [0, 1, 2, 3] and first["held_out_camera"] == "left"
    for key in ("upper_tooth_mean_rel_err_worst", "upper_tooth_mean_rel_err_median",
                "truth_upper_tooth_mean_rel_err_worst", "fit_seconds"):
        assert np.isfinite(first[key]) and first[key] > 0, key
    assert all(t["pixels"] > 0 for t in first["per_upper_tooth"].values())
    from PIL import Image

    with Image.open(tmp_path / "kept" / bench.PICTURE) as picture:  # 2 lights x 3 panels, pixels doubled
        assert picture.size == (2 * (3 * 52 + 4), 2 * (2 * 32 + 2))
    calls.clear()
    second = bench.teeth_smile()
    assert calls == [] and second["fit_seconds"] == first["fit_seconds"]
    assert first["reference"] == second["reference"] == "the capture"
    # a check with more samples than the capture judges against the truth rendered again at them
    monkeypatch.setenv("TEETH_SMILE_CHECK_SPP", "8")
    third = bench.teeth_smile()
    assert calls == [] and third["check_spp"] == 8 and third["reference"] == "the truth rendered again at 8 spp"
    assert np.isfinite(third["upper_tooth_mean_rel_err_median"]) and third["truth_upper_tooth_mean_rel_err_worst"] > 0


def test_a_kept_capture_of_another_truth_is_made_again_and_its_fit_not_reused(monkeypatch, tmp_path):
    """A kept capture is reused only where its scene.json is the truth this checkout's smile makes: one of another
    smile (as the captures made before the gums were cut around the teeth) is captured again, and a fit kept
    beside a capture of another truth is fitted again (the capture's identity holds the truth's digest). That
    ``truth_scene_bytes`` is what ``teeth synth`` writes is the nightly end-to-end run's (its second run keeps the
    capture)."""
    truth = b'{"teeth": "this checkout\'s smile"}'
    calls = []

    def fake_run(cmd, what):  # teeth synth writes the truth's scene.json (no images); teeth fit a scene_fit.json
        calls.append(cmd[:2])
        out = cmd[cmd.index("--out") + 1]
        os.makedirs(out, exist_ok=True)
        name, content = ("scene.json", truth) if cmd[1] == "synth" else ("scene_fit.json", b"{}")
        with open(os.path.join(out, name), "wb") as f:
            f.write(content)

    monkeypatch.setattr(bench, "_run", fake_run)
    monkeypatch.setattr(bench, "truth_scene_bytes", lambda cmd: truth)
    cap, fit = str(tmp_path / "capture"), str(tmp_path / "fit")
    first = bench._capture(cap, 4, [])
    assert calls == [["teeth", "synth"]] and first["truth_sha256"] == hashlib.sha256(truth).hexdigest()
    assert bench._capture(cap, 4, []) == first and len(calls) == 1  # kept
    bench._fit(cap, fit, first, [])
    assert bench._fit(cap, fit, first, []) is not None and calls[1:] == [["teeth", "fit"]]  # kept
    with open(os.path.join(cap, "scene.json"), "wb") as f:  # the kept capture's truth is another smile's
        f.write(b'{"teeth": "another smile"}')
    calls.clear()
    assert bench._capture(cap, 4, []) == first and calls == [["teeth", "synth"]]
    # a fit kept with a capture identity that names no truth (as every one before the digest) is fitted again
    with open(os.path.join(fit, bench.IDENTITY), "w") as f:
        json.dump({"identity": {"capture": {"command": first["command"]}, "fit_args": ["--held-out-camera", "0"]},
                   "seconds": 1.0}, f)
    calls.clear()
    bench._fit(cap, fit, first, [])
    assert calls == [["teeth", "fit"]]
