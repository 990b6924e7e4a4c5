# sharedspace — every set-up step lives here: `make run` and `make test` work on a fresh machine
# with a Rust toolchain and python3. The Python virtualenv is created inside the repository.

SHELL := /bin/bash
CARGO ?= cargo
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SERVER := target/release/sim-server
HBS_CSV ?= ../shared/data/hbs/hbs.csv

.PHONY: help run build serve test lint fmt bench bench-rust bench-pysf calibrate table1 lint-py venv clean

help: ## list the targets
	@grep -E '^[a-zA-Z0-9_-]+:.*## ' $(MAKEFILE_LIST) | awk -F ':.*## ' '{printf "  %-12s %s\n", $$1, $$2}'

build: ## release build of the workspace
	$(CARGO) build --release --workspace

$(SERVER): $(shell find sim-core scenarios protocol sim-server -name '*.rs' -o -name '*.json' -o -name Cargo.toml) Cargo.lock
	$(CARGO) build --release -p sim-server
	@touch $@

$(VENV)/.installed: clients/requirements-dev.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r clients/requirements-dev.txt
	@touch $@

venv: $(VENV)/.installed ## create the Python virtualenv in .venv

run: $(SERVER) ## the main job on the embedded pool (see README)
	./scripts/run_main.sh

test: ## every test: Rust (fmt, clippy, unit, integration, property)
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	$(CARGO) test --workspace

lint: ## cargo fmt --check and clippy -D warnings
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings

lint-py: $(VENV)/.installed ## ruff on the Python tooling (calibration/)
	$(PY) -m ruff check calibration

fmt: ## format the Rust code
	$(CARGO) fmt --all

bench: bench-rust bench-pysf ## every benchmark (results go in docs/BENCHMARKS.md)

bench-rust: ## criterion benchmarks
	$(CARGO) bench --workspace

bench-pysf: $(SERVER) $(VENV)/.installed ## world step vs pysocialforce, side by side, same N
	$(PY) bench/step_vs_pysocialforce.py --server $(SERVER)

CALIBRATED := params/calibrated.json5
CALIBRATE ?= 0

calibrate: $(SERVER) $(VENV)/.installed ## Bayesian-optimise the pedestrian models on the TRAIN split -> params/calibrated.json5
	$(PY) -m calibration.calibrate --server $(SERVER) --out $(CALIBRATED)

table1: $(SERVER) $(VENV)/.installed ## paper Table I on the test split (calibrates first if needed or CALIBRATE=1; docs/RESULTS.md)
	@if [ "$(CALIBRATE)" = 1 ] || [ ! -f $(CALIBRATED) ]; then \
		echo "calibrating (train split only) -> $(CALIBRATED)"; \
		$(PY) -m calibration.calibrate --server $(SERVER) --out $(CALIBRATED); \
	fi
	rm -rf out/table1-trajectories
	$(SERVER) eval-peds --split test --params $(CALIBRATED) --out docs/table1.json --trajectories out/table1-trajectories
	$(PY) -m calibration.plot_trajectories --trajectories out/table1-trajectories --out docs/figures

clean:
	$(CARGO) clean
	rm -rf $(VENV)
