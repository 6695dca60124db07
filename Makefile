# Every target builds .venv from pyproject.toml first when it is missing or older than pyproject.toml.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PORT ?= 5000
TRACKING_URI ?= sqlite:///mlflow.db

.PHONY: help setup test test-fast lint format bench train ablation-cartpole report mlflow-ui clean

help:
	@echo "make ablation-cartpole  run experiments/cartpole.toml on a local Ray, track in MLflow, write the report"
	@echo "make test               the test suite (sets up .venv first)"
	@echo "make train              one CartPole trial: curve, video, weights in outputs/train/"
	@echo "make report             rebuild reports/cartpole/ from the MLflow store"
	@echo "make mlflow-ui          browse the runs at http://127.0.0.1:$(PORT)"
	@echo "make bench              speed and memory figures (~20 min)"
	@echo "make lint               ruff check and format check"

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "ablate needs Python 3.11, found " + sys.version.split()[0]'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check ablate tests benchmarks
	$(BIN)/ruff format --check ablate tests benchmarks

format: $(STAMP)
	$(BIN)/ruff format ablate tests benchmarks
	$(BIN)/ruff check --fix ablate tests benchmarks

bench: $(STAMP)
	$(BIN)/python benchmarks/bench.py

train: $(STAMP)
	$(BIN)/ablate train $(ARGS)

ablation-cartpole: $(STAMP)
	PORT=$(PORT) $(BIN)/ablate run experiments/cartpole.toml --tracking-uri $(TRACKING_URI)

report: $(STAMP)
	$(BIN)/ablate report experiments/cartpole.toml --tracking-uri $(TRACKING_URI)

mlflow-ui: $(STAMP)
	$(BIN)/mlflow ui --backend-store-uri $(TRACKING_URI) --host 127.0.0.1 --port $(PORT)

clean:
	rm -rf outputs .pytest_cache .ruff_cache
