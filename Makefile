# Material Structures. Every target bootstraps what it needs (scripts/bootstrap.sh) on first use.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
CVENV := .venv-compat
CPY := $(CVENV)/bin/python
STAMP := $(VENV)/.material-structures-stamp
CSTAMP := $(CVENV)/.material-structures-stamp
BSTAMP := .venv-bare/.material-structures-stamp
BCSTAMP := .venv-bare-compat/.material-structures-stamp
VERSION := $(shell sed -n 's/^version = "\(.*\)"/\1/p' blender_manifest.toml)
# the next patch version: the repository test publishes a build of it over this one to see Blender upgrade
NEXT_VERSION := $(shell echo $(VERSION) | awk -F. '{print $$1 "." $$2 "." $$3 + 1}')
# test processes (pytest-xdist; 0: everything in one process). Test files stay whole on one worker (--dist
# loadfile: a file's Blender state and module fixtures are its own), handed out in the order tests/conftest.py
# sorts them (--no-loadscope-reorder: xdist would otherwise start with the files holding the most tests, the
# teeth tracer's among them, which then wait for the numba warm-up). --durations: the slowest tests, every run.
PYTEST_JOBS ?= 2
PYTEST_XDIST = -n $(PYTEST_JOBS) --dist loadfile --no-loadscope-reorder
PYTEST_DURATIONS ?= 25
# the teeth tracer's compiled kernels, shared by every target and Python that runs the same sources: the test
# suites, the zip installed into a bare Blender (core/teeth/numba_kernels.py); a clean clone compiles them once
# per Python instead of once per stage
export MATERIAL_STRUCTURES_NUMBA_CACHE ?= $(CURDIR)/build/numba-cache
# the project's own modules, compiled before a test run: where PYTHONDONTWRITEBYTECODE is set, each of the run's
# processes would compile them again on import (the venvs' packages are compiled when installed)
SOURCES := __init__.py __main__.py addon benchmarks cli core render scaleout showcase tests

.PHONY: lock setup setup-compat test test-fast test-all test-compat test-bare test-bare-compat lint demo library \
	previews build release docs bench refs samples clean help

help:
	@echo "make demo        set up and render the sample library into out/"
	@echo "make test        set up and run lint + the default test suite (Blender 5.2 LTS)"
	@echo "make test-fast   the core tests without the heavy ones (under a minute)"
	@echo "make test-all    also the slow suites (-m slow) and the render regression on Cycles' SSE4.2 kernel (nightly)"
	@echo "make test-compat Blender-side smoke tests on Blender 4.5 LTS (CPython 3.11)"
	@echo "make test-bare   the built zip in a Python with only bpy 5.2 (a desktop Blender): every operator"
	@echo "make test-bare-compat  the same on Blender 4.5 LTS"
	@echo "make library     (re)build the artist asset library in samples/library"
	@echo "make previews    render the library previews a build copies (showcase/previews), after a material changes"
	@echo "make samples     regenerate the sample data in samples/ (a BTF, a teeth capture, the brush states)"
	@echo "make build       installable extension zips in dist/, per platform and Python (with the asset library)"
	@echo "make release     the zips and Blender's repository index in dist/: serve dist/ and add its index.json URL"
	@echo "make docs        the documentation site into site/ (mkdocs --strict)"
	@echo "make bench       every benchmark into bench/results/NAME.json"
	@echo "make lock        re-resolve uv.lock after editing pyproject.toml's dependencies (then make rebuilds the venvs)"
	@echo "make refs        regenerate the render-regression reference EXRs (deliberately)"

$(STAMP): uv.lock pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh main

$(CSTAMP): uv.lock pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh compat

$(BSTAMP): uv.lock pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh bare

$(BCSTAMP): uv.lock pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh bare-compat

setup: $(STAMP)
setup-compat: $(CSTAMP)

# pyproject.toml is the one place for dependencies; uv.lock is written here, never by hand. Bump one
# package: `make lock ARGS="--upgrade-package NAME"`
lock:
	@bash scripts/bootstrap.sh lock $(ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

test: $(STAMP) lint
	@$(PY) -m compileall -q -j 0 $(SOURCES) > /dev/null
	$(PY) -m pytest -m "not slow" -q $(PYTEST_XDIST) --durations=$(PYTEST_DURATIONS)

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow and not blender and not heavy" -q $(PYTEST_XDIST) tests/core

# nightly: everything, then the render regression again with Cycles' CPU kernel forced down to SSE4.2
test-all: $(STAMP) lint
	@$(PY) -m compileall -q -j 0 $(SOURCES) > /dev/null
	$(PY) -m pytest -q $(PYTEST_XDIST) --durations=$(PYTEST_DURATIONS)
	$(PY) -m pytest -m regression -q $(PYTEST_XDIST) --cycles-kernel=sse42 tests/blender

test-compat: $(CSTAMP)
	@$(CPY) -m compileall -q -j 0 $(SOURCES) > /dev/null
	$(CPY) -m pytest -m "blender and not slow" -q $(PYTEST_XDIST) --durations=$(PYTEST_DURATIONS) tests/blender

samples/library/material_structures_library.blend: | $(STAMP)
	$(PY) -m material_structures library build

# the linux-x64 zip of one Python installed into a venv with only bpy (tests/bare/bare_blender.py)
test-bare: $(STAMP) $(BSTAMP) samples/library/material_structures_library.blend
	$(PY) -m material_structures release --out dist --platform linux-x64 --python 3.13
	.venv-bare/bin/python tests/bare/bare_blender.py dist/material_structures-$(VERSION)-cp313-linux_x64.zip \
		build/bare-313
	$(PY) -m material_structures release --out build/next-313 --platform linux-x64 --python 3.13 \
		--set-version $(NEXT_VERSION)
	.venv-bare/bin/python tests/bare/repository.py dist build/next-313 build/repo-313

test-bare-compat: $(STAMP) $(BCSTAMP) samples/library/material_structures_library.blend
	$(PY) -m material_structures release --out build/release-311 --platform linux-x64 --python 3.11
	.venv-bare-compat/bin/python tests/bare/bare_blender.py \
		build/release-311/material_structures-$(VERSION)-cp311-linux_x64.zip build/bare-311
	$(PY) -m material_structures release --out build/next-311 --platform linux-x64 --python 3.11 \
		--set-version $(NEXT_VERSION)
	.venv-bare-compat/bin/python tests/bare/repository.py build/release-311 build/next-311 build/repo-311

demo: $(STAMP)
	$(PY) -m material_structures demo --out out
	$(PY) -m material_structures library build

library: $(STAMP)
	$(PY) -m material_structures library build

previews: $(STAMP)
	$(PY) -m material_structures library previews

# the sample data shipped in samples/ (committed; regenerate after changing a format or the synthetic models)
samples: $(STAMP)
	$(PY) scripts/make_samples.py samples

build: $(STAMP) samples/library/material_structures_library.blend
	$(PY) -m material_structures build --out dist

# every platform's zips and Blender's repository index (index.json, index.html): dist/ is a repository
release: $(STAMP) samples/library/material_structures_library.blend
	$(PY) -m material_structures release --out dist

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

bench: $(STAMP)
	$(PY) -m material_structures bench --all --out bench/results

refs: $(STAMP)
	$(PY) -m pytest -m regression -q $(PYTEST_XDIST) --update-refs tests

clean:
	rm -rf out dist tests/output .pytest_cache
