"""Fitting from Blender: the core fit in a background process (progress, log, loss plot, cancel), its
result written into the teeth materials and dentin shape keys."""

from __future__ import annotations

import os
import subprocess
import time

import bpy
import numpy as np
import pytest

from ._teeth_capture import assert_fit_applied, import_capture_scene, write_tiny_capture


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    """A tiny synthetic capture (1 tooth, 1 camera, 4 lights, 20 x 15 px, 140 tooth pixels) written by the core."""
    return write_tiny_capture(str(tmp_path_factory.mktemp("teeth-capture")), width=20, height=15, n_lights=4)


def test_fit_operator_applies_result(addon_module, capture_dir, tmp_path):
    enamel = import_capture_scene(capture_dir)
    assert bpy.data.objects.get("Gums") is not None and bpy.data.objects.get("Oral Cavity") is not None
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    fs.out_dir = str(tmp_path / "fit")
    fs.iterations = 3
    fs.init = "PERTURBED"  # c reset to 0, volumes perturbed: the fit result differs from the import
    assert bpy.ops.material_structures.teeth_fit() == {"FINISHED"}  # EXEC: blocking
    t = assert_fit_applied(enamel, tmp_path / "fit")
    dnode = enamel.ms_tooth.partner.active_material.node_tree.nodes["Dentin"]
    np.testing.assert_allclose(tuple(dnode.inputs["Albedo"].default_value)[:3], t.dentin.albedo, rtol=1e-6)
    for name in ("fit_log.txt", "loss.png", "loss.json", "checkpoint.json"):
        assert os.path.isfile(tmp_path / "fit" / name), name
    log = open(tmp_path / "fit" / "fit_log.txt").read()
    assert '"progress": "fit", "iteration": 3, "iterations": 3' in log and "best loss" in log
    assert fs.progress == pytest.approx(1.0) and not fs.running


def test_fit_button_runs_the_fit_settings_defaults_and_shows_the_check(addon_module, capture_dir, tmp_path):
    """The panel's defaults are FitSettings' (one set), the Fit button runs FitSettings (loss.json records
    them), and the held-out check (1 of the 4 lights, the one farthest off the capture's axis) shows in the
    panel: its error and its image."""
    import dataclasses
    import json

    from material_structures.addon.teeth.properties import CHECK_IMAGE_NAME
    from material_structures.core.teeth.fit_settings import FitSettings

    import_capture_scene(capture_dir)
    fs = bpy.context.scene.ms_teeth_fit
    props = type(fs).bl_rna.properties
    assert props["iterations"].default == FitSettings().iterations
    assert "preset" not in props and "lights_per_iteration" not in props
    fs.capture_dir = capture_dir
    fs.out_dir = str(tmp_path / "fit")
    fs.iterations = 2
    fs.init = "SCENE"
    assert bpy.ops.material_structures.teeth_fit() == {"FINISHED"}
    ran = json.loads((tmp_path / "fit" / "loss.json").read_text())
    want = dataclasses.asdict(dataclasses.replace(FitSettings(), iterations=2))
    assert {k: v for k, v in ran["settings"].items() if k != "workers"} == \
        {k: v for k, v in json.loads(json.dumps(want)).items() if k != "workers"}
    from material_structures.core.teeth.capture import Capture
    from material_structures.core.teeth.optimise import light_angles_deg
    from material_structures.core.teeth.scene import load_scene
    from material_structures.core.teeth.synthetic import scene_target

    angles = light_angles_deg(Capture.load(capture_dir), scene_target(load_scene(os.path.join(capture_dir,
                                                                                              "scene.json"))))
    assert len(ran["log"]) == 2 and ran["held_out_lights"] == [int(np.argmax(angles))]  # the farthest off axis
    assert fs.check_error.startswith("Held-out lights:") and fs.check_image.endswith("check.png")
    img = bpy.data.images[CHECK_IMAGE_NAME]
    assert tuple(img.size)[1] == 15 and tuple(img.size)[0] > 3 * 20  # capture | fit | difference


def _fit_tracer_compiled() -> bool:
    """Whether the fit's interpreter (``python_executable``: this one or the checkout's .venv) has numba, which
    decides the tracer: compiled, or the numpy reference with worker processes."""
    from material_structures.addon.teeth.fit_job import python_executable

    return subprocess.run([python_executable(), "-c", "import numba"], capture_output=True).returncode == 0


def _live_in_group(pgid: int) -> list[int]:
    """Processes of process group ``pgid`` that are not zombies (Linux /proc)."""
    live = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            live.append(int(d))
    return live


def _process_report(job) -> str:
    """What the fit process was doing (for a failure message: a CI run once saw no forked workers for 60 s)."""
    pid = job.proc.pid
    lines = [f"iterations {job.done_iterations}, last line {job.last_line!r}"]
    for name in ("status", "wchan", "stack"):
        try:
            with open(f"/proc/{pid}/{name}") as f:
                text = f.read()
        except OSError as e:
            text = str(e)
        if name == "status":  # the state and thread count only
            text = " ".join(ln for ln in text.splitlines() if ln.startswith(("State", "Threads")))
        lines.append(f"/proc/{pid}/{name}: {text.strip()[:400]}")
    return "\n".join(lines)


def test_background_job_progress_and_cancel(addon_module, capture_dir, tmp_path):
    """Progress and loss while it runs; cancel stops the fit process and the render workers it forks
    (the numpy reference tracer, where numba is missing: 2 workers; the default 32-spp pass A on 140 tooth
    pixels is 2 chunks of paths, so every pass A forks; the compiled tracer runs threads in the fit process)."""
    from material_structures.addon.teeth.fit_job import FitJob

    t0 = time.perf_counter()
    job = FitJob(capture_dir, str(tmp_path / "fit"), iterations=10000, init="scene", workers=2).start()
    assert job.cmd[job.cmd.index("--workers") + 1] == "2"
    assert time.perf_counter() - t0 < 1.0  # returns at once: Blender keeps running
    deadline = time.time() + 90
    while job.done_iterations < 2 and job.poll() == "RUNNING" and time.time() < deadline:
        time.sleep(0.2)
    assert job.poll() == "RUNNING", job.last_line
    assert job.done_iterations >= 2 and job.loss is not None and job.loss > 0
    assert 0.0 < job.progress < 0.01
    assert "iteration" in job.status_text()
    if os.path.isdir("/proc") and not _fit_tracer_compiled():
        deadline = time.time() + 60  # catch a moment when the fit has forked its workers
        while len(_live_in_group(job.proc.pid)) < 2 and time.time() < deadline:
            time.sleep(0.01)
        assert len(_live_in_group(job.proc.pid)) >= 2, _process_report(job)
    job.cancel()
    assert job.poll() == "CANCELLED"
    assert job.proc.returncode != 0
    if os.path.isdir("/proc"):
        deadline = time.time() + 3  # SIGKILLed workers may take a moment to exit
        while _live_in_group(job.proc.pid) and time.time() < deadline:
            time.sleep(0.05)
        assert _live_in_group(job.proc.pid) == []


def test_fit_errors(addon_module, tmp_path):
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = str(tmp_path)
    with pytest.raises(RuntimeError, match="no capture.json"):
        bpy.ops.material_structures.teeth_fit()
    assert bpy.ops.material_structures.teeth_fit_cancel() == {"CANCELLED"}  # a warning, nothing to cancel


class _Recorder:
    def __init__(self):
        self.status, self.progress, self.ended, self.timer_removed = [], [], False, False

    # window manager
    def progress_update(self, v):
        self.progress.append(v)

    def progress_end(self):
        self.ended = True

    def event_timer_remove(self, timer):
        self.timer_removed = True

    # workspace
    def status_text_set(self, text):
        self.status.append(text)


def test_modal_fit_reports_progress_in_status_bar(addon_module, capture_dir, tmp_path):
    """Drive the modal operator's ``modal()`` with stand-in timer events (no window headless): the status bar
    text and the window-manager progress follow the background fit; at the end the result is applied."""
    from types import SimpleNamespace

    from material_structures.addon.teeth import operators as ops
    from material_structures.addon.teeth.fit_job import FitJob

    enamel = import_capture_scene(capture_dir)
    rec = _Recorder()
    context = SimpleNamespace(scene=bpy.context.scene, window_manager=rec, workspace=rec, screen=None)
    fake = SimpleNamespace(_timer=object(), report=lambda *a: None)
    fake._cleanup = lambda ctx: ops.MS_OT_teeth_fit._cleanup(fake, ctx)
    fake._finish = lambda ctx, job, state: ops.MS_OT_teeth_fit._finish(fake, ctx, job, state)
    # 3 iterations and no held-out render: where numba is missing (the 4.5 job) each iteration of the numpy
    # tracer takes about 28 s, and the deadline below is a guard against a hung job, not a speed test
    ops.set_current_job(FitJob(capture_dir, str(tmp_path / "fit"), iterations=3, init="scene",
                               extra=["--held-out-lights", "0"]).start())
    timer = SimpleNamespace(type="TIMER")
    result, deadline = {"PASS_THROUGH"}, time.time() + 120
    while result == {"PASS_THROUGH"} and time.time() < deadline:
        time.sleep(0.1)
        result = ops.MS_OT_teeth_fit.modal(fake, context, timer)
    assert result == {"FINISHED"}
    texts = [t for t in rec.status if t]
    assert texts and texts[-1].startswith("Teeth fit: iteration 3/3")
    assert rec.status[-1] is None and rec.ended and rec.timer_removed  # status bar restored
    assert max(rec.progress) == 1000
    assert enamel.ms_tooth.has_fit and "done" in bpy.context.scene.ms_teeth_fit.status


def test_a_cancelled_fit_resumes_from_the_panel_to_the_uninterrupted_fit(addon_module, capture_dir, tmp_path):
    """Cancel after the first checkpoint; the panel then offers Resume (the output folder holds a stopped fit),
    which ends with the uninterrupted fit's losses and result, applied; with no stopped fit, Resume refuses in
    one line."""
    import json

    from material_structures.addon.teeth.fit_job import FitJob
    from material_structures.core.teeth.fit_checkpoint import stopped_fit
    from material_structures.showcase import ui_panels as ui

    import_capture_scene(capture_dir)
    # the cancel must land after the first checkpoint (iteration 5) and before the end: the compiled tracer's
    # iterations on this tiny capture are a fraction of a second, the numpy tracer's (where numba is missing,
    # the 4.5 job) several seconds
    n = 20 if _fit_tracer_compiled() else 7
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir, fs.init, fs.iterations = capture_dir, "SCENE", n
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    fs.out_dir = str(whole)
    assert bpy.ops.material_structures.teeth_fit() == {"FINISHED"}
    assert not stopped_fit(str(whole))
    with pytest.raises(RuntimeError, match="no stopped fit to resume"):
        bpy.ops.material_structures.teeth_fit(resume=True)

    job = FitJob(capture_dir, str(cut), iterations=n, init="scene").start()
    deadline = time.time() + 120
    while not (cut / "checkpoint.json").exists() and job.poll() == "RUNNING" and time.time() < deadline:
        time.sleep(0.05)
    job.cancel()
    assert job.poll() == "CANCELLED"
    done = len(json.loads((cut / "checkpoint.json").read_text())["log"])
    assert 5 <= done < n and stopped_fit(str(cut))

    def resume_buttons() -> list:
        panel = next(c for c in ui.panel_classes(addon_module) if c.bl_idname == "VIEW3D_PT_material_structures_teeth")
        return [it for it in ui.record_panel(panel, bpy.context).items()
                if it.identifier == "material_structures.teeth_fit" and it.op_props.get("resume")]

    assert resume_buttons() == []  # the output folder is still the finished fit's
    fs.out_dir = str(cut)
    assert [it.text for it in resume_buttons()] == ["Resume"]
    assert bpy.ops.material_structures.teeth_fit(resume=True) == {"FINISHED"}
    assert not stopped_fit(str(cut)) and resume_buttons() == []
    logs = [json.loads((d / "loss.json").read_text())["log"] for d in (whole, cut)]
    assert [e["loss"] for e in logs[1]] == [e["loss"] for e in logs[0]] and len(logs[0]) == n
    assert json.loads((cut / "scene_fit.json").read_text()) == json.loads((whole / "scene_fit.json").read_text())
    assert fs.last_result.startswith("done: applied")
