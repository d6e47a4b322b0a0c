"""``python -m material_structures scratch ...``: generate, info, eval, and clear errors."""

from __future__ import annotations

import json
import os

import numpy as np

from material_structures.cli import main
from material_structures.core.exr_io import read_exr
from material_structures.core.scratch import load_scratch_set


def test_generate_info_eval_round_trip(tmp_path, capsys):
    out = tmp_path / "tables"
    assert main(["scratch", "generate", "--kind", "hairline", "--count", "40", "--patch-mm", "4", "--out",
                 str(out), "--angle-deg", "30"]) == 0
    summary = json.loads(capsys.readouterr().out)
    s = load_scratch_set(out)
    assert summary["segments"] == s.n_segments > 0 and summary["scratches"] == s.n_scratches
    assert main(["scratch", "info", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["grid"]["nx"] == s.grid_shape[1]
    img = tmp_path / "img.exr"
    assert main(["scratch", "eval", str(out), "--size", "24", "--light", "-0.65", "0.26", "0.71", "0.1",
                 "--out", str(img)]) == 0
    a = read_exr(img, ["R", "G", "B", "A"])
    assert a.shape == (24, 24, 4) and np.all(np.isfinite(a)) and np.all((a[..., 3] >= 0) & (a[..., 3] <= 1))
    assert np.count_nonzero(a[..., :3].sum(-1)) > 0


def test_curves_and_errors(tmp_path, capsys):
    curves = tmp_path / "c.json"
    curves.write_text(json.dumps([[[0.1, 0.1], [0.9, 0.5]], [[0.2, 0.8], [0.5, 0.5], [0.8, 0.9]]]))
    npz = tmp_path / "c.npz"
    assert main(["scratch", "generate", "--kind", "curves", "--curves", str(curves), "--patch-mm", "3",
                 "--out", str(npz)]) == 0
    assert load_scratch_set(npz).n_scratches == 2
    capsys.readouterr()
    assert main(["scratch", "info", str(tmp_path / "nope.npz")]) == 1
    assert "not found" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{")
    assert main(["scratch", "generate", "--kind", "curves", "--curves", str(tmp_path / "bad.json"),
                 "--out", str(npz)]) == 1  # a bad file: a runtime error
    assert "not valid JSON" in capsys.readouterr().err
    assert main(["scratch", "generate", "--kind", "curves", "--out", str(npz)]) == 2  # a usage error
    capsys.readouterr()
    (tmp_path / "outside.json").write_text(json.dumps([[[5, 5], [6, 6]], [[0.3, 0.3], [0.3, 0.3]]]))
    before = npz.read_bytes()
    assert main(["scratch", "generate", "--kind", "curves", "--curves", str(tmp_path / "outside.json"),
                 "--out", str(npz)]) == 1  # no scratch: not an empty set written without a word
    err = capsys.readouterr().err
    assert "no curve adds a scratch" in err and err.count("\n") == 1, err
    assert npz.read_bytes() == before
    assert main(["scratch", "generate", "--kind", "spiral", "--out", str(npz)]) == 2  # one line, no traceback
    assert capsys.readouterr().err.count("\n") == 1
    assert os.path.exists(npz)
