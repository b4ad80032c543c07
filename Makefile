# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint format bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# CPU torch first, so that the project's `torch>=` requirement is already met and pip
# never pulls the multi-GB CUDA build.
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e ".[test,cluster,ap,baselines]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/ham demo --out runs/demo

# one worker per core (2 cores): 5:28 on a fresh clone with the install, 4:29 the tests (2026-12-04)
test: $(STAMP)
	$(BIN)/python -m pytest -n auto tests

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

format: $(STAMP)
	$(BIN)/ruff format src tests benchmarks
	$(BIN)/ruff check --fix src tests benchmarks

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_glance.py

clean:
	rm -rf runs .pytest_cache
