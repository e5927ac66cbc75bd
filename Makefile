# gsa_jax -- everything runs inside .venv (created on first use).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test answer score sweep figures bench bench-quick profile profile-bench scene clean
EXP ?= experiments/fig1_small/fig1_small.toml

# pip's own lines (warnings of the build backend and of the machine's pip configuration included) go to a log, shown
# where an install fails
PIP_LOG := $(VENV)/pip.log
PIP := $(BIN)/python -m pip install -q
$(STAMP): pyproject.toml
	@echo "installing gsa_jax and its dependencies into $(VENV) (minutes, the first time; pip's log: $(PIP_LOG))"
	@$(PY) -m venv $(VENV)
	@$(PIP) --upgrade pip > $(PIP_LOG) 2>&1 || { tail -n 30 $(PIP_LOG); exit 1; }
	@$(PIP) -e ".[test,deploy]" >> $(PIP_LOG) 2>&1 || { tail -n 30 $(PIP_LOG); exit 1; }
	@touch $(STAMP)

install: $(STAMP)

# the tests also train a MuJoCo Playground environment, check the DeepMind Control Suite's tasks against
# dm_control and certify regions of attraction (gsa verify --certify): their optional extras (warp-lang: ~390 MB
# installed; dm_control ~60 MB; cvxpy and Clarabel ~175 MB)
TEST_STAMP := $(VENV)/.installed-test
$(TEST_STAMP): $(STAMP) pyproject.toml
	@echo "installing the test extras into $(VENV) (MuJoCo Playground, dm_control, cvxpy; pip's log: $(PIP_LOG))"
	@$(PIP) -e ".[test,deploy,playground,dmc,verify]" >> $(PIP_LOG) 2>&1 || { tail -n 30 $(PIP_LOG); exit 1; }
	@touch $(TEST_STAMP)

## demo: a short real training run (mixture of 4 linear controllers on inverted_double_pendulum, ~2 min)
demo: $(STAMP)
	rm -rf runs/demo
	$(BIN)/gsa train --env inverted_double_pendulum --policy mixture --clusters 4 --steps 400000 --out runs/demo
	@echo
	@echo "'eval' is the deterministic controller (4 linear pieces: most probable cluster, mean action) over 16 episodes;"
	@echo "the task's maximum is ~9,360 (1000 steps holding both poles up), a random policy scores ~176."
	@echo "Next: .venv/bin/gsa inspect runs/demo    (clusters, each piece as u = u0 + K (x - x*) -> runs/demo/inspect/)"
	@echo "      .venv/bin/gsa export runs/demo --out controller.h    (the controller as one C header)"
	@echo "      .venv/bin/tensorboard --logdir runs    (after .venv/bin/pip install tensorboard)"

## test: the pytest suite, one worker per core (at most 4), each test file on one worker (~15-18 min on 2 cores;
## the 15 slowest tests are listed at the end). One worker: $(BIN)/python -m pytest tests -m "not benchmark"
test: $(TEST_STAMP)
	$(BIN)/python -m pytest -q tests -m "not benchmark" -n auto --maxprocesses 4 --dist loadfile --durations=15

## answer: how few linear controllers a task needs, decided with as many seeds as it takes (gsa answer;
## make answer ENV=dmc:cartpole-swingup ARGS="--budget-minutes 60"); installs dm_control (the extra dmc) for dmc: tasks
ENV ?= InvertedDoublePendulum-v5
ARGS ?=
DMC_STAMP := $(VENV)/.installed-dmc
$(DMC_STAMP): $(STAMP) pyproject.toml
	@echo "installing dm_control into $(VENV) (pip's log: $(PIP_LOG))"
	@$(PIP) -e ".[test,deploy,dmc]" >> $(PIP_LOG) 2>&1 || { tail -n 30 $(PIP_LOG); exit 1; }
	@touch $(DMC_STAMP)

answer: $(DMC_STAMP)
	$(BIN)/gsa answer --env $(ENV) $(ARGS)

## score: every committed controller under DIRS re-run in MuJoCo C from fixed start states (controller_scores.csv)
DIRS ?= experiments/atlas_dmc/results experiments/fig1_v5/results
score: $(DMC_STAMP)
	$(BIN)/gsa score $(DIRS)

## sweep: train an experiment's whole grid as vmapped programs (make sweep EXP=experiments/fig1/fig1.toml)
sweep: $(STAMP)
	$(BIN)/gsa sweep $(EXP)

## figures: the paper-style figure and final-return table of a sweep (make figures SWEEP=runs/sweeps/fig1_small)
SWEEP ?= runs/sweeps/$(basename $(notdir $(EXP)))
figures: $(STAMP)
	$(BIN)/gsa plot $(SWEEP)

## bench: sweep throughput vs MuJoCo C on this machine (~20 min; bench-quick ~3 min)
bench: $(STAMP)
	$(BIN)/gsa bench --out runs/bench

bench-quick: $(STAMP)
	$(BIN)/gsa bench --quick --out runs/bench-quick

## profile: where the PPO program's time goes, part by part, on the five v5 tasks and dm_control's cartpole
## (gsa profile: one sweep worker's 8 runs on one core, mixture and flat PPO; ~10 min on an idle machine;
## installs the test extras, dm_control among them, for dmc:cartpole-swingup)
profile: $(TEST_STAMP)
	$(BIN)/gsa profile --out runs/profile

## profile-bench: the bench's coarser split at 64 hopper runs (physics / rollout / update, MJX; ~7 min)
profile-bench: $(STAMP)
	$(BIN)/gsa bench --sizes 64 --processes 1 --raw-batches 256 --profile-runs 64 --solver-variant none --out runs/profile-bench

## scene: a picture of the Allegro task (offscreen OSMesa rendering; installs Debian's libosmesa6 if missing)
scene: $(STAMP)
	@ldconfig -p | grep -q libOSMesa || (apt-get install -y -q libosmesa6 >/dev/null || sudo apt-get install -y -q libosmesa6 >/dev/null) \
		|| (echo "could not install libosmesa6; install it (Debian/Ubuntu: apt-get install libosmesa6) and re-run" && false)
	@mkdir -p runs
	MUJOCO_GL=osmesa $(BIN)/gsa render allegro_cylinder --out runs/allegro_scene.png

clean:
	rm -rf $(VENV) runs .pytest_cache
