# sharedspace — every set-up step lives here: `make run` and `make test` work on a fresh machine
# with a Rust toolchain and python3. The Python virtualenv is created inside the repository.

SHELL := /bin/bash
CARGO ?= cargo
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# uv installs the venv: its cache (~/.cache/uv) keeps every wheel, so the fresh-venv install test
# (clients/tests/test_installed_package.py) installs torch again offline, by hard links.
UV_VERSION := 0.13.9
UV := $(VENV)/bin/uv
SERVER := target/release/sim-server
GENERAL_POOL := out/table2g/pool-general.json
HBS_CSV ?= ../shared/data/hbs/hbs.csv

.PHONY: help run build wheel wheel-check ppo marl benchmarl serve router view browser cycles test lint fmt bench bench-rust bench-pysf soak calibrate table1 table2 table2v table2g train eval lint-py venv clean demos

help: ## list the targets
	@grep -E '^[a-zA-Z0-9_-]+:.*## ' $(MAKEFILE_LIST) | awk -F ':.*## ' '{printf "  %-12s %s\n", $$1, $$2}'

build: ## release build of the workspace
	$(CARGO) build --release --workspace

$(SERVER): $(shell find sim-core scenarios protocol sim-server -name '*.rs' -o -name '*.json' -o -name Cargo.toml) Cargo.lock
	$(CARGO) build --release -p sim-server
	@touch $@

$(VENV)/.installed: clients/requirements-dev.txt clients/requirements-train.txt clients/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet uv==$(UV_VERSION)
	$(UV) pip install --quiet --python $(PY) -r clients/requirements-dev.txt \
		-r clients/requirements-train.txt -e 'clients[train]'
	@touch $@

venv: $(VENV)/.installed ## create the Python virtualenv in .venv

# The `train` extra at the lower end of its ranges (clients/requirements-lower.txt overrides the
# locked pins): the trainer's and the bench's tests run in it too (torch 2.9 from PyPI: about a
# minute, uv's cache keeps it). torchrl 0.13 lacks `rsample_and_log_prob`, which SAC's update uses.
LOWER_VENV := .venv-lower
$(LOWER_VENV)/.installed: clients/requirements-lower.txt clients/requirements-train.txt clients/pyproject.toml
	$(PYTHON) -m venv $(LOWER_VENV)
	$(LOWER_VENV)/bin/python -m pip install --quiet uv==$(UV_VERSION)
	$(LOWER_VENV)/bin/uv pip install --quiet --python $(LOWER_VENV)/bin/python \
		-r clients/requirements-train.txt --override clients/requirements-lower.txt -e 'clients[train]'
	@touch $@

#: The tests the lower end runs: the trainers (PPO, SAC, the multi-car learners, a plug-in, the
#: updates, the GCN), the TorchRL envs, the bench with its checkpoints, the shipped policies.
LOWER_TESTS := test_learner_protocol.py test_update.py test_ppo.py test_overlap.py \
	test_train_gcn.py test_remote_torchrl.py test_bench.py test_shipped_policy.py \
	test_train_extra.py

# BenchMARL 1.5.2 pins torchrl < 0.12 (its experiment builds a SyncDataCollector, which torchrl
# 0.13 removed): its own venv, the package installed editable beside it without the `train`
# extra. torch comes from uv's cache (the same 2.15.0 as .venv): about 20 s.
BENCHMARL_VENV := .venv-benchmarl
$(BENCHMARL_VENV)/.installed: clients/requirements-benchmarl.txt clients/pyproject.toml
	$(PYTHON) -m venv $(BENCHMARL_VENV)
	$(BENCHMARL_VENV)/bin/python -m pip install --quiet uv==$(UV_VERSION)
	$(BENCHMARL_VENV)/bin/uv pip install --quiet --python $(BENCHMARL_VENV)/bin/python \
		-r clients/requirements-benchmarl.txt -e clients
	@touch $@

# The live viewer's page (viewer/, npm with its committed lock file).
VIEWER_PAGE := viewer/dist/index.html
$(VIEWER_PAGE): viewer/package-lock.json viewer/build.mjs $(wildcard viewer/src/*)
	cd viewer && npm ci --no-audit --no-fund && npm run build

# The wheels a Python user installs (README, "Install"; docs/DEVELOPING.md, "The wheels"): sharedspace-server (the
# sim-server binary, jemalloc inside; maturin's `bin` bindings) and the pure sharedspace package.
# deploy/Dockerfile's builder runs this target with its own maturin and uv and no venv:
# `make wheel WHEEL_TOOLS= MATURIN=... UV=...`.
# `make wheel WHEEL_PROFILE= DIST=DIR` builds in the dev profile (the test of the installed
# wheels, clients/tests/test_installed_package.py, reuses make test's debug build that way).
MATURIN := $(VENV)/bin/maturin
WHEEL_TOOLS := $(VENV)/.installed
WHEEL_PROFILE := --release
DIST := dist
# The server wheel runs on every Linux with glibc >= 2.17 (manylinux2014: CentOS 7, Ubuntu 18.04,
# Debian 10, RHEL 8/9 clusters): zig links it against glibc 2.17's symbols, with no container.
# zig comes from the pinned `ziglang` package (clients/requirements-dev.txt); maturin runs it as
# `python3 -m ziglang`, hence the venv first on PATH. `make wheel WHEEL_LINK=` links against this
# machine's glibc instead (the wheel is then tagged for it, manylinux_2_35 here).
WHEEL_LINK := --zig --compatibility manylinux2014
WHEEL_PATH := $(abspath $(VENV)/bin):$(PATH)
# The highest glibc the server wheel may need (`make wheel-check`, scripts/wheel_check.py).
WHEEL_MAX_GLIBC := 2.17
# The Python wheel carries the viewer's built page (sharedspace/viewer_page), so that an installed
# `python -m sharedspace.viewer` needs no checkout.
PAGE_IN_PACKAGE := clients/src/sharedspace/viewer_page
# ... and the paper's scenario pool (what the server embeds as hbs-paper), so that an installed
# trainer carves its validation split from it (sharedspace.worlds.held_out_scenes).
POOL_IN_PACKAGE := clients/src/sharedspace/pool_data
wheel: $(WHEEL_TOOLS) $(VIEWER_PAGE) ## the server's wheel (manylinux2014) and sdist, and the Python package's wheel (with the viewer's page), in dist/
	rm -f $(DIST)/sharedspace*.whl $(DIST)/sharedspace_server-*.tar.gz
	PATH="$(WHEEL_PATH)" $(MATURIN) build $(WHEEL_PROFILE) $(WHEEL_LINK) --locked --manifest-path sim-server/Cargo.toml --out $(DIST)
	@# the server's source, for a platform with no wheel (macOS, aarch64): `pip install` builds it
	@# with cargo (README, "Install"; docs/DEVELOPING.md, "The wheels")
	$(MATURIN) sdist --manifest-path sim-server/Cargo.toml --out $(DIST)
	rm -rf $(PAGE_IN_PACKAGE) && cp -r viewer/dist $(PAGE_IN_PACKAGE)
	rm -rf $(POOL_IN_PACKAGE) && mkdir -p $(POOL_IN_PACKAGE) && cp scenarios/data/hbs-paper.json $(POOL_IN_PACKAGE)/
	$(UV) build --quiet --wheel --out-dir $(DIST) clients; status=$$?; rm -rf $(PAGE_IN_PACKAGE) $(POOL_IN_PACKAGE); exit $$status
	@ls -l $(DIST)/*.whl $(DIST)/*.tar.gz

wheel-check: wheel ## the server wheel's platform tags and its binary's highest glibc symbol, at most WHEEL_MAX_GLIBC (2.17)
	$(PY) scripts/wheel_check.py $(DIST)/sharedspace_server-*.whl --max-glibc $(WHEEL_MAX_GLIBC)
	$(VENV)/bin/auditwheel show $(DIST)/sharedspace_server-*.whl

# scripts/module_cycles.py reads the crates' `use` paths from their source (scripts/rust_uses.py):
# no tool to build.
cycles: $(VENV)/.installed ## no import cycle between the modules of any crate or of the Python package, and its layers
	$(PYTHON) scripts/module_cycles.py sim-core scenarios protocol sim-server
	cd clients && ../$(VENV)/bin/lint-imports --no-logo

browser: ## Debian's chromium + chromium-driver (the viewer's browser test)
	./scripts/install-browser.sh

view: $(SERVER) $(VENV)/.installed $(VIEWER_PAGE) ## live viewer in the browser of the servers on VIEW_CONNECT (default tcp/127.0.0.1:7447; docs/VIEWER.md)
	$(PY) -m sharedspace.viewer --connect $(or $(VIEW_CONNECT),tcp/127.0.0.1:7447) $(ARGS)

run: $(SERVER) $(VENV)/.installed $(GENERAL_POOL) ## the main job: serve, train PPO-GCN-Cog remotely, evaluate, plot; score the shipped best policies with the bench
	./scripts/run_main.sh

serve: $(SERVER) ## a simulation server on this machine (deploy/server.json5; ARGS='--cfg capacity:64')
	$(SERVER) serve --config deploy/server.json5 $(ARGS)

router: $(SERVER) ## a zenoh router with auth and access control (deploy/router.json5, deploy/README.md)
	@test -f deploy/credentials.txt || { echo "deploy/credentials.txt is missing: cp deploy/credentials.txt.example deploy/credentials.txt and change the passwords (deploy/README.md)"; exit 1; }
	$(SERVER) router --config deploy/router.json5 $(ARGS)

test: $(VENV)/.installed $(LOWER_VENV)/.installed $(BENCHMARL_VENV)/.installed $(VIEWER_PAGE) browser $(GENERAL_POOL) ## every test: Rust (fmt, clippy, module cycles, unit, integration, property), Python (pytest against a live server, the viewer in headless Chromium), ruff, import contracts
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --features sim-server/bench -- -D warnings
	$(PYTHON) scripts/module_cycles.py sim-core scenarios protocol sim-server
	$(PYTHON) scripts/long_functions.py --limit 80 sim-server/src clients/src
	$(CARGO) test --workspace
	$(CARGO) build -p sim-server
	@# a hung interpreter exit must fail CI in minutes, not eat its whole budget
	SHAREDSPACE_SIM_SERVER=target/debug/sim-server SHAREDSPACE_REQUIRE_BROWSER=1 timeout --kill-after=30 1800 $(PY) -m pytest clients/tests -q -p no:cacheprovider \
		|| { rc=$$?; [ $$rc = 124 ] && echo "pytest did not exit within 1800 s (hung at exit?)"; exit $$rc; }
	@# the train extra's lower bounds (clients/requirements-lower.txt)
	SHAREDSPACE_SIM_SERVER=target/debug/sim-server timeout --kill-after=30 900 $(LOWER_VENV)/bin/python -m pytest $(addprefix clients/tests/,$(LOWER_TESTS)) -q -p no:cacheprovider
	@# BenchMARL's torchrl (0.11, its pin): the envs and a BenchMARL experiment
	SHAREDSPACE_SIM_SERVER=target/debug/sim-server timeout --kill-after=30 600 $(BENCHMARL_VENV)/bin/python -m pytest clients/tests_benchmarl -q -p no:cacheprovider
	$(PY) -m ruff check clients calibration benchmarks scripts examples
	cd clients && ../$(VENV)/bin/lint-imports --no-logo

lint: ## cargo fmt --check and clippy -D warnings
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --features sim-server/bench -- -D warnings

lint-py: $(VENV)/.installed ## ruff and the import contracts (clients/pyproject.toml) on the Python code
	$(PY) -m ruff check clients calibration benchmarks scripts examples
	cd clients && ../$(VENV)/bin/lint-imports --no-logo

fmt: ## format the Rust code
	$(CARGO) fmt --all

bench: bench-rust bench-pysf ## every benchmark (results go in docs/BENCHMARKS.md)

bench-rust: ## criterion benchmarks
	$(CARGO) bench --workspace --features sim-server/bench

soak: $(SERVER) $(VENV)/.installed ## soak: 8 trainers x 64 envs for 10 min with churn and kills (ARGS='--minutes 600' for 10 h; not in make test)
	$(PY) benchmarks/soak.py $(ARGS)

bench-pysf: $(SERVER) $(VENV)/.installed ## world step vs pysocialforce, side by side, same N
	$(PY) benchmarks/step_vs_pysocialforce.py --server $(SERVER)

CALIBRATED := params/calibrated.json5
CALIBRATED_COLL := params/calibrated_collisions.json5
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
	$(PY) -m calibration.paired --table docs/table1.json
	$(SERVER) eval-peds --pool embedded:hbs-general --split test --params $(CALIBRATED) --out docs/table1_general.json
	$(PY) -m calibration.paired --table docs/table1_general.json
	@# the collision-priced fit (CALIBRATE=1 refits it too): the paper pool's and the general pool's test splits
	@if [ "$(CALIBRATE)" = 1 ] || [ ! -f $(CALIBRATED_COLL) ]; then \
		$(PY) -m calibration.calibrate --server $(SERVER) --objective collisions --collision-weight 2 --out $(CALIBRATED_COLL); \
	fi
	$(SERVER) eval-peds --split test --params $(CALIBRATED_COLL) --out docs/table1_collisions.json
	$(PY) -m calibration.paired --table docs/table1_collisions.json
	$(SERVER) eval-peds --pool embedded:hbs-general --split test --params $(CALIBRATED_COLL) --out docs/table1_general_collisions.json
	$(PY) -m calibration.paired --table docs/table1_general_collisions.json
	@# 5-fold cross-validation over all 77 scenes (fits cached in out/crossval; a smaller budget:
	@# CROSSVAL_ARGS='--n-init 5 --n-iter 10 --out out/crossval-small')
	$(PY) -m calibration.crossval --server $(SERVER) --folds 5 --table docs/table1_crossval.json $(CROSSVAL_ARGS)
	$(PY) -m calibration.paired --table docs/table1_crossval.json

TRAIN_ARGS ?= --set network=gcn_risk total_frames=200000 log_dir=runs/gcn_risk
CKPT ?= runs/gcn_risk/checkpoints/last.pt

train: $(SERVER) $(VENV)/.installed ## train against a fresh local server (TRAIN_ARGS='--set network=mlp ...')
	./scripts/with_server.sh sh -c '$(PY) -m sharedspace.train $(TRAIN_ARGS) --set server_endpoint=$$SHAREDSPACE_ENDPOINT'

eval: $(SERVER) $(VENV)/.installed ## evaluate CKPT on the test split (Table II columns and the human driver)
	./scripts/with_server.sh sh -c '$(PY) -m sharedspace.paper.evaluate --checkpoint $(CKPT) --split test --set server_endpoint=$$SHAREDSPACE_ENDPOINT'

table2: $(SERVER) $(VENV)/.installed ## paper Table II: three variants trained at once against one server, evaluated (docs/RESULTS.md)
	./scripts/table2.sh

POWERED_ARGS ?= --variations 128 --planner 32 --by-m 8,16,32,64,128
table2v: $(SERVER) $(VENV)/.installed ## Table II on seeded variations: the shipped policies, scripts and planner bound, paired (docs/RESULTS.md)
	mkdir -p results/variations
	$(PY) -m sharedspace.paper.powered --policies results/table2/policies \
		--drivers pursuit_3 pursuit_5 hold stop $(POWERED_ARGS) \
		--json results/variations/baseline.json --markdown results/variations/baseline.md

# hbs-general (every pedestrian and car of each car's window) as a file: Table II-G's pool (the
# bench's `crowd` task; GENERAL_POOL is set at the top).
$(GENERAL_POOL): scenarios/data/hbs.csv.gz
	mkdir -p $(dir $@)
	csv=$$(mktemp) && gunzip -c $< > $$csv && \
		$(CARGO) run --quiet --release -p scenarios --bin extract-hbs -- --csv $$csv --pool general --out $@; \
		status=$$?; rm -f $$csv; exit $$status

# Prior data for the learner (sharedspace.paper.demos): the car-aware and pursuit scripts, a
# noisy copy and the planner on the TRAIN split of each world; cached, re-recorded only when the
# world or the recipe changes.
DEMOS_G := out/demos/table2g
DEMOS_PAPER := out/demos/table2
marl: $(SERVER) $(VENV)/.installed ## several learning cars: MAPPO, IPPO, MASAC x 3 seeds on the crossing task vs the car-aware script (results/marl/)
	$(PY) -m sharedspace.marl.table --out results/marl

benchmarl: $(SERVER) $(BENCHMARL_VENV)/.installed ## one BenchMARL MAPPO experiment on the crossing task (its own venv; results/marl/benchmarl/)
	SHAREDSPACE_SIM_SERVER=$(SERVER) $(BENCHMARL_VENV)/bin/python -m sharedspace.marl.benchmarl_task --out results/marl/benchmarl

# PPO from scratch for the `crowd` task, Table II-G's world (docs/RESULTS.md, "PPO from scratch"):
# PPO_NETWORK (gcn_risk, gcn_uniform, mlp), PPO_SEEDS, PPO_FRAMES; curves on the validation split
# carved from the train scenes, the last checkpoint is the run's policy.
PPO_NETWORK ?= gcn_risk
PPO_SEEDS ?= 0 1 2
PPO_FRAMES ?= 6000000
ppo: $(SERVER) $(VENV)/.installed $(GENERAL_POOL) ## PPO from scratch for the crowd task, 3 seeds (results/ppo/runs/)
	for seed in $(PPO_SEEDS); do \
		$(PY) -m sharedspace.train --set algorithm=ppo task=crowd network=$(PPO_NETWORK) \
			seed=$$seed total_frames=$(PPO_FRAMES) checkpoint_interval=2097152 \
			log_dir=results/ppo/runs/crowd-scratch-$(PPO_NETWORK)-s$$seed || exit 1; \
	done

demos: $(SERVER) $(VENV)/.installed $(GENERAL_POOL) ## prior data: demonstrations on the train scenes of Table II-G's and Table II's worlds (out/demos/)
	$(PY) -m sharedspace.paper.demos --pool $(GENERAL_POOL) --params params/table2g.json5 \
		--set max_agents=10 --out $(DEMOS_G)
	$(PY) -m sharedspace.paper.demos --params params/table2.json5 --scale 4 --out $(DEMOS_PAPER)

# The learner's recipe (docs/RESULTS.md, "Prior data and the learner"): a residual over the
# car-aware script, LayerNorm critics, UTD 1, critic warm-up, a BC term toward the script.
RECIPE := base_driver=car_aware critic_layer_norm=true utd_ratio=1 init_random_frames=0 \
	alpha_init=0.01 critic_warmup=2000 bc_weight=0.2
TABLE2G_VARIATIONS := variations={"position_sigma":0.5,"start_offset_steps":2,"desired_speed_scale":0.2,"mirror":true}
TABLE2G_WORLD := max_agents=10 server_params=params/table2g.json5 $(TABLE2G_VARIATIONS)
table2g: $(SERVER) $(VENV)/.installed ## Table II-G, the crowded benchmark: hbs-general with reactive traffic, 3 variants x 3 seeds (docs/RESULTS.md)
	TABLE2_POOL=general TABLE2_OUT=$${TABLE2_OUT:-out/table2g_residual} TABLE2_PARAMS=params/table2g.json5 \
		TABLE2_FRAMES=$${TABLE2_FRAMES:-15000} TABLE2_CKPT=5000 TABLE2_EVAL=0 TABLE2_DOC= \
		TABLE2_SEARCH_ROUNDS=0 TABLE2_JSON=$${TABLE2_JSON:-results/table2g/table2g.json} \
		TABLE2_SHIP=$${TABLE2_SHIP-results/table2g/policies} \
		TABLE2_SET='$(TABLE2G_WORLD) $(RECIPE) $(TABLE2G_EXTRA)' \
		./scripts/table2.sh

clean:
	$(CARGO) clean
	rm -rf $(VENV) $(LOWER_VENV)
