# Two entry points for a fresh machine: `make demo` and `make test`.
# Both create .venv, install torch 2.13.0 (the CPU build on this machine) first, then gaintune.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: install demo lint test test-all bench clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install "torch==2.13.0"
	$(PY) -m pip install -e ".[dev,postgres,ray,parquet]"
	# an editable install compiles no bytecode (pip does for a regular one): without it, and with
	# PYTHONDONTWRITEBYTECODE set, every command recompiles gaintune's modules (~0.13 s a query)
	$(PY) -m compileall -q gaintune api >/dev/null
	touch $(STAMP)

install: $(STAMP)

## Tune the built-in demo loop, verify it and write result.json, report.html and exports to out/demo.
demo: $(STAMP)
	$(VENV)/bin/gaintune demo --out out/demo

## Lint and types on gaintune/ and api/ (config in pyproject.toml): zero findings, or the target fails.
lint: $(STAMP)
	$(PY) -m ruff check gaintune api
	$(PY) -m mypy

## Lint, types, then the whole default test suite on two xdist workers (slow tests excluded; `make test-all` runs
## those too). Not --dist loadgroup/loadscope: those key tests by node id, and schemathesis gives its 17 API
## fuzz cases one id, so they ran 1 of the 17. The Ray tests take turns through a file lock (tests/conftest.py).
test: lint
	$(PY) -m pytest -q -n 2

test-all: $(STAMP)
	$(PY) -m pytest -q -m ""

bench: $(STAMP)
	$(VENV)/bin/gaintune bench sim
	$(VENV)/bin/gaintune bench verify

clean:
	rm -rf $(VENV) out .pytest_cache
