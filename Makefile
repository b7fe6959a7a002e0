# The README's commands. Python >= 3.11 is taken from $(PYTHON).
PYTHON ?= python3
VENV ?= .venv
HOST ?= 127.0.0.1
PORT ?= 8000
BIN := $(VENV)/bin

.PHONY: run test test-train lint bench dataset train decoder correspondence sessions bodies models

$(BIN)/.installed: pyproject.toml
	@echo "Setting up $(VENV) with the service and its test dependencies (about a minute, once)..."
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install -e '.[dev]'
	@echo "Set up."
	touch $@

run: $(BIN)/.installed  ## set up and serve on $(HOST):$(PORT) (default 127.0.0.1:8000)
	$(BIN)/spectral-unions serve --host $(HOST) --port $(PORT)

test: $(BIN)/.installed  ## set up and run the test suite
	$(BIN)/python -m pytest -q

$(BIN)/.train: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet -e '.[dev,train]'
	touch $@

test-train: $(BIN)/.train  ## the suite plus the tests that need anny (the 'train' extra)
	$(BIN)/python -m pytest -q

dataset: $(BIN)/.train  ## the benchmark data set (PRESET=tiny|standard|large)
	$(BIN)/spectral-unions-train build-dataset --preset $(or $(PRESET),standard) --out data/$(or $(PRESET),standard)

train: $(BIN)/.train  ## train, export, evaluate on a built data set (PRESET=tiny|standard)
	$(BIN)/spectral-unions-train train --data data/$(or $(PRESET),standard) --runs runs/$(or $(PRESET),standard) --models models --preset $(or $(PRESET),standard)

decoder: $(BIN)/.train  ## the shape decoder (spectrum → body): anny bodies, training, export, evaluation
	$(BIN)/spectral-unions-train build-bodies --preset $(or $(PRESET),standard) --out data/bodies-$(or $(PRESET),standard)
	$(BIN)/spectral-unions-train train-decoder --bodies data/bodies-$(or $(PRESET),standard) --data data/$(or $(PRESET),standard) --union-run runs/$(or $(PRESET),standard)/union.pt --runs runs/$(or $(PRESET),standard) --models models --preset $(or $(PRESET),standard)

correspondence: $(BIN)/.train  ## the correspondence model (part → template): anny parts and pairs, training, export, evaluation
	$(BIN)/spectral-unions-train build-parts --preset $(or $(PRESET),standard) --out data/parts-$(or $(PRESET),standard)
	$(BIN)/spectral-unions-train train-correspondence --parts data/parts-$(or $(PRESET),standard) --runs runs/$(or $(PRESET),standard) --models models --preset $(or $(PRESET),standard)

sessions: $(BIN)/.train  ## σ of registered sessions' fused unions: anny people scanned as a front-end does, exact unions
	$(BIN)/spectral-unions-train calibrate-sessions --models models

bodies: $(BIN)/.train  ## the body basis sessions are fitted with, its intervals calibrated, bodies and measurements scored
	$(BIN)/spectral-unions-train fit-bodies --models models

models: dataset train decoder correspondence sessions bodies  ## everything from scratch: data → training → evaluation → export

lint: $(BIN)/.installed
	$(BIN)/ruff check app training tests benchmarks harness

bench: $(BIN)/.train  ## spectrum speed against LaPy on anny bodies
	$(BIN)/python benchmarks/bench_spectrum.py
