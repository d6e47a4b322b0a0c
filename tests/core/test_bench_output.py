"""``bench NAME`` prints one JSON object on standard output, whatever the benchmark's renderer logs."""

from __future__ import annotations

import argparse
import json
import os

import pytest

from material_structures import benchmarks
from material_structures.cli import bench


def _chatty() -> dict:
    os.write(1, b"00:01.000  render           | Saved: '/tmp/x.exr'\n")  # a C library writing to fd 1
    print("a Python print")
    return {"figure": 1.5}


def test_standard_output_holds_only_the_json(monkeypatch, capfd):
    monkeypatch.setattr(benchmarks, "available", lambda: ["chatty"])
    monkeypatch.setattr(benchmarks, "run_benchmark", lambda name: _chatty())
    args = argparse.Namespace(list=False, all=False, name="chatty", out=None)
    assert bench.run(args) == 0
    out, err = capfd.readouterr()
    assert json.loads(out) == pytest.approx({"figure": 1.5})
    assert "Saved:" in err and "a Python print" in err
