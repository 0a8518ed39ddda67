# The README's two commands: `make run` and `make test`. Both set up .venv first.
#
# Python: python3.11 when it is on PATH (the version these machines test), otherwise the
# newest python3.1x >= 3.10 found on PATH, otherwise python3 (check-python refuses it unless
# it is 3.10-3.14); `make PYTHON=/path/to/python3.x` chooses one.
# On 3.12 and later pip builds PyBullet 3.2.7 from source (no wheel): install a C++
# compiler first (Debian/Ubuntu: `apt install g++ python3-dev`).
PYTHON ?= $(shell for v in 3.11 3.14 3.13 3.12 3.10 3; do \
	command -v python$$v >/dev/null 2>&1 && { echo python$$v; break; }; done)
# torch first: on these machines torch==2.13.0 resolves to a local CPU build, and the
# pinned version then satisfies stable-baselines3 without downloading CUDA packages.
# Elsewhere choose your own, e.g. make TORCH='torch --index-url https://download.pytorch.org/whl/cpu'
TORCH ?= torch==2.13.0
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

PTRACK := $(VENV)/bin/ptrack

.PHONY: setup check-python run test test-slow lint docs bench experiment verdict clean

setup: $(STAMP)

check-python:
	@test -n "$(PYTHON)" || { echo "make: no python3.1x or python3 found on PATH: install Python 3.11 (or 3.10, 3.12-3.14), or pass PYTHON=/path/to/python3.x" >&2; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(0 if (3, 10) <= sys.version_info[:2] < (3, 15) else 1)' \
		|| { echo "make: $(PYTHON) is not Python 3.10-3.14; pass PYTHON=/path/to/python3.x" >&2; exit 1; }

$(STAMP): pyproject.toml constraints.txt | check-python
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet $(TORCH)
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

# The main job (about 8 min on 2 cores): the slice of the iiwa verdict (run.yml) — nine
# model-based controllers at tuned gains, no disturbance and four presets at level 1, 12
# paired seeds — with a progress bar, then its headline tables and where its report is.
# The full verdict and the RL sweeps are experiments (train/configs/README.md). No --resume:
# results of older code are never reused silently; an existing results/ folder is refused
# with a message saying what to do.
run: setup
	$(PTRACK) evaluate --config train/configs/evaluate/run.yml --out results/run

# One experiment of docs/experiments.md (train/configs/README.md lists them): the command is
# the config's folder name, e.g.
#   make experiment CONFIG=train/configs/tune/tune_iiwa.yml ARGS=--save
#   make experiment CONFIG=train/configs/campaign/rl_study_two_link.yml ARGS='--workers 2'
# ARGS go to the command as they are (--resume continues an interrupted one).
experiment: setup
	@test -n "$(CONFIG)" || { echo "usage: make experiment CONFIG=train/configs/<command>/<name>.yml [ARGS=...]" >&2; exit 2; }
	$(PTRACK) $(notdir $(patsubst %/,%,$(dir $(CONFIG)))) --config $(CONFIG) $(ARGS)

# The verdict across robots and paths (issue 38): 4 robots x 8 random test paths x 15
# conditions x 10 seeds x 9 controllers at tuned gains = 43 200 episodes of 8 s, about
# 13 core-hours (train/configs/verdict/verdict.yml says how the figure was measured).
# Resumable: make verdict ARGS=--resume continues an interrupted one.
verdict: setup
	$(PTRACK) verdict --config train/configs/verdict/verdict.yml $(ARGS)

lint: setup
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

# In parallel over the cores (pytest-xdist); one BLAS/torch thread per worker. The tests
# marked slow (make test-slow) are left out: each is a longer variant of a claim the
# default run checks, or an optional backend's (Ray).
TEST_ENV := OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
test: lint
	$(TEST_ENV) $(PY) -m pytest -q -n auto -m "not slow"

test-slow: setup
	$(TEST_ENV) $(PY) -m pytest -q -n auto -m slow

# The documentation site (MkDocs material; API pages from the docstrings) into site/.
docs: setup
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

bench: setup
	$(PY) bench/env_step.py
	$(PY) bench/controller_cost.py
	$(PY) bench/eval_scaling.py
	$(PY) bench/same_work.py
	$(PY) bench/train_throughput.py --steps 1000 --warmup 300 --env-steps 5000 --repeats 3

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache site
