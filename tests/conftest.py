"""Shared pytest configuration: the ``--update-refs`` switch of the render-regression suite."""

from __future__ import annotations

import os
import sys

import pytest

# Test helpers (``regression``) import as top-level modules under --import-mode=importlib.
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--update-refs",
        action="store_true",
        default=False,
        help="rewrite the reference EXRs under tests/references/ instead of comparing (make refs)",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "regression: render-regression test against tests/references/")
