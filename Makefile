# `make demo`, `make test` (everything) and `make quick` (lint, types and the tests not
# marked slow, for the edit-test loop). Each creates .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test quick lint typecheck docs unit bench bench-mrpt clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/sonarmap demo -o out

# ruff, then lint-imports: the layers and import rules of pyproject's [tool.importlinter].
lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/lint-imports

typecheck: $(STAMP)
	$(BIN)/mypy

# The documentation site (mkdocs.yml, docs/) into site/; --strict fails on any warning,
# an unresolved link or anchor included.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# Two workers: the tests use their own tmp paths and free ports, so they run in parallel.
PYTEST := $(BIN)/pytest -q -n 2

unit: $(STAMP)
	$(PYTEST)

test: lint typecheck docs unit

quick: lint typecheck
	$(PYTEST) -m "not slow"

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run

# Installs MRPT with apt (root) when missing, builds our harness against it and runs it.
bench-mrpt: $(STAMP)
	$(BIN)/python -m benchmarks.mrpt.run --install --minutes 10

clean:
	rm -rf $(VENV) out site .pytest_cache .mypy_cache .ruff_cache .import_linter_cache
