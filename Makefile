# Set-up and everyday commands. Every target creates .venv when it is missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
KEY := $(shell cksum pyproject.toml | cut -d' ' -f1)
STAMP := $(VENV)/.installed-$(KEY)
DEMO_STAMP := $(VENV)/.installed-demo-$(KEY)
export MUJOCO_GL ?= egl

.PHONY: demo test view validate bench stability train first-use wheel clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0   # the CPU wheel, before stable-baselines3
	$(BIN)/python -m pip install -q -e '.[studies,envs,train,test]'
	rm -f $(VENV)/.installed-* && touch $@ $(DEMO_STAMP)

# the demo needs only the studies extra (no torch, no warp): a shorter first install
$(DEMO_STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q -e '.[studies]'
	touch $@

demo: $(DEMO_STAMP)     ## quadruped trotting on sand (headless): summary, plot and video in out/
	$(BIN)/python -m rft_mujoco demo

test: $(STAMP)          ## the test suite (what CI runs)
	$(BIN)/python -m pytest -q -p no:cacheprovider

view: $(STAMP)          ## the demo scene in the interactive viewer (needs a display)
	$(BIN)/python -m rft_mujoco view

validate: $(STAMP)      ## the paper's validation set: tables and plots in out/validation
	$(BIN)/python -m rft_mujoco validate

bench: $(STAMP)         ## speed and speed-accuracy tables and plots in out/bench
	$(BIN)/python -m rft_mujoco bench

stability: $(STAMP)     ## drop/drag/rotate stability study: table and map in out/stability
	$(BIN)/python -m rft_mujoco stability

train: $(STAMP)         ## PPO on SandQuadruped-v1 for 60 min, the README's training run
	$(BIN)/python -m rft_mujoco.train train --algo ppo --env rft_mujoco/SandQuadruped-v1 --max-minutes 60

first-use: $(STAMP)     ## time first use in a new venv (empty numba cache, then the user's) and the warm demo
	$(BIN)/python -m rft_mujoco.studies.first_use

wheel: $(DEMO_STAMP)    ## a wheel in dist/ that carries the numba machine code for this CPU (compile --ship)
	$(BIN)/python -m rft_mujoco compile --ship
	$(BIN)/python -m pip wheel -q --no-deps -w dist .

clean:
	rm -rf $(VENV) out .pytest_cache
