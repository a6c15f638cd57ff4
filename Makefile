# make serve  - local single-user server on http://127.0.0.1:8000 (SQLite, local worker pool)
# make test   - bootstrap .venv (and the system pieces the tests need), lint (ruff), check the
#               architecture contracts (lint-imports, docs/architecture.md) and run the whole suite
#               (tests/test_docs.py builds the documentation site strictly and runs its tutorials)
# make docs   - the documentation site (MkDocs, strict) into site/; `pba serve` serves it under /docs-site
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: serve test lint venv services system-deps ceres-headers native bench clean openapi docs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

# Debian packages the browser tests need (chromium; Playwright drives it, no browser download).
system-deps: ceres-headers
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian chromium for the browser tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	  { echo "could not install chromium"; exit 1; }; }

# ceres/cost_function.h for the compiled cost functions (Debian's libceres-dev; g++ and the Python
# headers are on the machine). Without root or apt, the build is skipped and solves use Python.
ceres-headers:
	@test -f /usr/include/ceres/cost_function.h || test -n "$$CERES_INCLUDE_DIR" || { \
	  echo "installing Debian libceres-dev for the compiled cost functions"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libceres-dev >/dev/null) || \
	  echo "could not install libceres-dev: solves will use the slower Python cost functions"; }

# the compiled cost functions (solver/engine/native), rebuilt when their source or pyceres changes,
# then the numba kernels compiled into the installation's cache (solver/__pycache__) that every
# process finds: one to three minutes of CPU once per installation and version of the kernels,
# seconds when they are there already (pba warmup)
native: $(STAMP) ceres-headers
	$(BIN)/python scripts/build_native.py $(NATIVE_FLAGS)
	$(BIN)/pba warmup

# PostgreSQL and Redis on 127.0.0.1 for the scale-out tests: start them if they are not running.
services:
	@bash scripts/ensure-services.sh

# native compiles the numba kernels too (pba warmup), so no job waits for the compiler
serve: $(STAMP) native
	$(BIN)/pba serve --host 127.0.0.1 --port 8000

# the tests run both evaluation paths; here the compiled one must exist (PBA_REQUIRE_NATIVE)
test: NATIVE_FLAGS = --require
test: $(STAMP) system-deps services native
	$(BIN)/ruff check solver service tests bench scripts
	$(BIN)/lint-imports
	PBA_REQUIRE_NATIVE=1 $(BIN)/python -m pytest -q

# ruff and the import contracts alone (seconds; also the first step of make test)
lint: $(STAMP)
	$(BIN)/ruff check solver service tests bench scripts
	$(BIN)/lint-imports

# the documentation site: docs/ plus the reference pages generated from the code (scripts/gen_reference.py)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict

openapi: $(STAMP)
	$(BIN)/python -m service.openapi_dump > openapi.yaml

bench: $(STAMP)
	$(BIN)/python bench/bench_solver.py

clean:
	rm -rf $(VENV) build site *.egg-info .pytest_cache solver/engine/native/*.so solver/engine/native/*.stamp
