# Material Structures. Every target bootstraps what it needs (scripts/bootstrap.sh) on first use.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
CVENV := .venv-compat
CPY := $(CVENV)/bin/python
STAMP := $(VENV)/.material-structures-stamp
CSTAMP := $(CVENV)/.material-structures-stamp
PYTEST_JOBS ?=

.PHONY: setup setup-compat test test-fast test-all test-compat lint demo library build bench refs clean help

help:
	@echo "make demo        set up and render the sample library into out/"
	@echo "make test        set up and run lint + the default test suite (Blender 5.2 LTS)"
	@echo "make test-fast   the core tests without the heavy ones (under a minute)"
	@echo "make test-all    also the slow suites (-m slow)"
	@echo "make test-compat Blender-side smoke tests on Blender 4.5 LTS (CPython 3.11)"
	@echo "make library     (re)build the artist asset library in samples/library"
	@echo "make build       installable extension zip in dist/ (includes the asset library)"
	@echo "make bench       every benchmark into bench/results/NAME.json"
	@echo "make refs        regenerate the render-regression reference EXRs (deliberately)"

$(STAMP): requirements.txt pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh main

$(CSTAMP): requirements-compat.txt pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh compat

setup: $(STAMP)
setup-compat: $(CSTAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

test: $(STAMP) lint
	$(PY) -m pytest -m "not slow" -q $(PYTEST_JOBS)

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow and not blender and not heavy" -q tests/core

test-all: $(STAMP) lint
	$(PY) -m pytest -q $(PYTEST_JOBS)

test-compat: $(CSTAMP)
	$(CPY) -m pytest -m "blender and not slow" -q tests/blender

demo: $(STAMP)
	$(PY) -m material_structures demo --out out
	$(PY) -m material_structures library build

library: $(STAMP)
	$(PY) -m material_structures library build

build: $(STAMP)
	@test -f samples/library/material_structures_library.blend || $(PY) -m material_structures library build
	$(PY) -m material_structures build --out dist

bench: $(STAMP)
	$(PY) -m material_structures bench --all --out bench/results

refs: $(STAMP)
	$(PY) -m pytest -m regression -q --update-refs tests

clean:
	rm -rf out dist tests/output .pytest_cache
