# The README's two commands: `make run` and `make test`. Both set up .venv first.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup run test lint bench clean

setup: $(STAMP)

# torch==2.13.0 first: it resolves to the machine's local CPU build, and the pinned
# version then satisfies stable-baselines3 without downloading CUDA packages.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

# The main job: two paired sweeps (iiwa, model-based controllers; two-link with the shipped
# residual SAC). No --resume: results of older code or another model are never reused
# silently; an existing results/ folder is refused with a message saying what to do.
run: setup
	$(PY) -m train.evaluate --config train/configs/main.yml --out results/main --no-progress
	$(PY) -m train.evaluate --config train/configs/main_rl.yml --out results/main_rl --no-progress

lint: setup
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

test: lint
	$(PY) -m pytest -q

bench: setup
	$(PY) bench/env_step.py
	$(PY) bench/controller_cost.py
	$(PY) bench/eval_scaling.py
	$(PY) bench/train_throughput.py --steps 1000 --warmup 300 --env-steps 5000 --repeats 3

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
