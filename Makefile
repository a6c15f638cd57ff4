# make serve  - local single-user server on http://127.0.0.1:8000 (SQLite, local worker pool)
# make test   - bootstrap .venv (and the system pieces the tests need), lint (ruff), check the
#               architecture contracts (lint-imports, docs/architecture.md) and run the whole suite
#               (tests/test_docs.py builds the documentation site strictly and runs its tutorials)
# make docs   - the documentation site (MkDocs, strict) into site/; `pba serve` serves it under /docs-site
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: serve test lint venv services system-deps bench clean openapi docs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

# Debian packages the browser tests need (chromium; Playwright drives it, no browser download).
system-deps:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian chromium for the browser tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	  { echo "could not install chromium"; exit 1; }; }

# PostgreSQL and Redis on 127.0.0.1 for the scale-out tests: start them if they are not running.
services:
	@bash scripts/ensure-services.sh

# pba warmup: the numba kernels compiled into their disk cache before the server starts
# (one to two minutes the first time, a few seconds after), so no job waits for the compiler
serve: $(STAMP)
	$(BIN)/pba warmup
	$(BIN)/pba serve --host 127.0.0.1 --port 8000

test: $(STAMP) system-deps services
	$(BIN)/ruff check solver service tests bench scripts
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q

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
	rm -rf $(VENV) build site *.egg-info .pytest_cache
