# Every target builds .venv from pyproject.toml first when it is missing or older than pyproject.toml.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PORT ?= 5000
TRACKING_URI ?= sqlite:///mlflow.db
RAY_PORT ?= 6390
CLUSTER_MLFLOW_PORT ?= 5050
EXPERIMENT ?= experiments/cartpole.toml
ABLATION ?= cartpole
SHOTS ?= docs/images
TEST_WORKERS ?= 2

.PHONY: help setup mlflow-screenshots test test-e2e test-fast test-cluster test-cluster-postgres cluster-up cluster-down ablation-cartpole-cluster lint format bench train ablation-cartpole ablation-pong report mlflow-ui clean

help: ## this list (generated from the comments after each target's name)
	@awk '/^[A-Za-z0-9_.-]+:([^=]|$$).*## / {printf "make %-18s %s\n", substr($$0, 1, index($$0, ":") - 1), substr($$0, index($$0, "## ") + 3)}' $(MAKEFILE_LIST)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "ablate needs Python 3.11, found " + sys.version.split()[0]'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP) ## build .venv from pyproject.toml (every target does this first when needed)

test: $(STAMP) ## the test suite on 2 pytest-xdist workers (TEST_WORKERS), all but the e2e tests (4 min 4 s to 7 min 33 s on fresh clones of idle 2-core machines, as machines differ, after the venv)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal -m "not e2e"

test-e2e: $(STAMP) ## processes that die or are stopped: ablate run on its own Ray under Ctrl-C and SIGTERM, the live view in tmux, trial workers that die mid-trial; one at a time (CI runs it after make test)
	$(BIN)/python -m pytest -q -m e2e

test-fast: $(STAMP) ## the test suite without the slow learning tests
	$(BIN)/python -m pytest -q -m "not slow"

test-cluster: $(STAMP) ## two token-authenticated Ray nodes (one sees none of the driver's files), a basic-auth mlflow server, a lost node, refusals (root); a local run beside another Ray cluster
	ABLATE_CLUSTER_TESTS=1 $(BIN)/python -m pytest -q tests/test_cluster.py \
		tests/test_scheduler.py::test_a_local_run_ignores_another_cluster_listens_on_loopback_and_ray_address_joins

test-cluster-postgres: $(STAMP) ## test-cluster with the server's store in a private PostgreSQL (apt-get installs it; skipped where it can't)
	tools/postgres_test.sh

cluster-up: $(STAMP) ## a Ray head (token) and an mlflow server (basic-auth) on 127.0.0.1 (RAY_PORT=6390, CLUSTER_MLFLOW_PORT=5050); credentials in .cluster/credentials.env
	$(BIN)/python tools/local_cluster.py up --ray-port $(RAY_PORT) --mlflow-port $(CLUSTER_MLFLOW_PORT)

cluster-down: $(STAMP) ## stop what make cluster-up started
	$(BIN)/python tools/local_cluster.py down

ablation-cartpole-cluster: $(STAMP) ## experiments/cartpole.toml on the make cluster-up head, tracked on its server (its credentials)
	. .cluster/credentials.env && $(BIN)/ablate run experiments/cartpole.toml --address 127.0.0.1:$(RAY_PORT) --tracking-uri http://127.0.0.1:$(CLUSTER_MLFLOW_PORT)

lint: $(STAMP) ## ruff check and format check
	$(BIN)/ruff check ablate tests benchmarks tools
	$(BIN)/ruff format --check ablate tests benchmarks tools

format: $(STAMP) ## ruff format and fix what ruff can
	$(BIN)/ruff format ablate tests benchmarks tools
	$(BIN)/ruff check --fix ablate tests benchmarks tools

bench: $(STAMP) ## speed and memory figures, every section (~3 h on 2 idle cores; python benchmarks/bench.py SECTION runs one)
	$(BIN)/python benchmarks/bench.py

train: $(STAMP) ## one CartPole trial: curve, video, weights in outputs/train/ (ARGS="--preset course", ...)
	$(BIN)/ablate train $(ARGS)

ablation-cartpole: $(STAMP) ## run experiments/cartpole.toml on a local Ray (seeds in doubling rounds up to 640, populations of 64), track in MLflow, write the report
	PORT=$(PORT) $(BIN)/ablate run experiments/cartpole.toml --population 64 --tracking-uri $(TRACKING_URI)

ablation-pong: $(STAMP) ## run experiments/pong.toml: CNN vs MLP on Pong, each at its tuned rate, 5 seeds x 400 episodes, every trial alone (49 min to 1 h 42 min on a fresh clone of a 2-core machine, as machines differ; at most 2 h)
	$(BIN)/ablate run experiments/pong.toml --population 1 --tracking-uri $(TRACKING_URI)

report: $(STAMP) ## rebuild reports/<name>/ from the MLflow store (EXPERIMENT=experiments/cartpole.toml by default)
	$(BIN)/ablate report $(EXPERIMENT) --tracking-uri $(TRACKING_URI)

mlflow-screenshots: $(STAMP) ## the variant runs' table and chart view of ABLATION (default cartpole) as SHOTS/mlflow-*.png (default docs/images), in headless Chromium (apt-get install chromium)
	$(BIN)/python tools/mlflow_screenshots.py --tracking-uri $(TRACKING_URI) --experiment $(ABLATION) --out $(SHOTS)

mlflow-ui: $(STAMP) ## serve the MLflow UI at http://127.0.0.1:5000 (PORT=... for another port)
	$(BIN)/mlflow ui --backend-store-uri $(TRACKING_URI) --host 127.0.0.1 --port $(PORT)

clean: ## remove outputs/ and the pytest and ruff caches
	rm -rf outputs .pytest_cache .ruff_cache
