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

.PHONY: setup run test lint bench tune adversary fronts rates rl-study rl-deadband rl-gated-eval rl-pure-long rl-iiwa rl-iiwa-small rl-iiwa-accel rl-iiwa-accel1 rl-iiwa-slow-actor rl-iiwa-bc rl-iiwa-wide rl-iiwa-wide-long rl-iiwa-tuned rl-iiwa-tuned-variants rl-iiwa-tuned-bc rl-iiwa-tuned-prior rl-iiwa-tuned-prior-seeds rl-iiwa-tuned-prior-ct rl-iiwa-prior-alone prior-vs-learned rl-iiwa-prior-bc-screen authority-probe rl-pure-sbx rl-pure-sbx-iiwa rl-pure-sbx-iiwa-ent rl-pure-dagger-iiwa rl-residual-imitation-iiwa rl-residual-k10-iiwa rl-three-arms-iiwa rl-three-arms-iiwa-k10 heldout clean check-python

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

# The main job: three paired sweeps (iiwa, model-based controllers; two-link with the shipped
# SAC policies; iiwa with the shipped residual SAC). No --resume: results of older code or
# another model are never reused silently; an existing results/ folder is refused with a
# message saying what to do.
run: setup
	$(PY) -m train.evaluate --config train/configs/main.yml --out results/main --no-progress
	$(PY) -m train.evaluate --config train/configs/main_rl.yml --out results/main_rl --no-progress
	$(PY) -m train.evaluate --config train/configs/main_rl_iiwa.yml --out results/main_rl_iiwa --no-progress
	$(PY) -m train.rates --config train/configs/rates_main.yml --out results/rates --no-progress

# The control-rate study of docs/control_rates.md (default gains on four robots, then tuned
# gains on two; about 22 + 11 min on 2 cores). Refuses to overwrite: --resume to continue.
rates: setup
	$(PY) -m train.rates --config train/configs/rates.yml --no-progress
	$(PY) -m train.rates --config train/configs/rates_tuned.yml --no-progress

# Pure SAC on a longer budget: the study's pure runs of seeds 0 and 1 (needs rl-study's
# runs/) resumed to 600 000 steps, 2 processes (about 1 h on 2 cores), then evaluated.
# (docs/results/rl_pure_long_two_link: the same, stopped by a wall-clock limit at 570 000
# and 600 000 steps.)
LONG := runs/rl_pure_long_two_link
rl-pure-long: setup
	mkdir -p $(LONG) && for s in 0 1; do cp -a runs/rl_study_two_link/pure_s$$s $(LONG)/; done
	pids=; for s in 0 1; do $(PY) -m train.train --out $(LONG)/pure_s$$s --seed $$s --disturbance impulse:1.0 \
	  --steps 540000 --set 'policy_kwargs=dict(net_arch=[64, 64])' --eval-freq 0 --checkpoint-freq 30000 \
	  --resume --reward kernel --kernel-weights 0.5 0.4 0.1 --max-path-distance 0.5 & pids="$$pids $$!"; done; \
	for p in $$pids; do wait $$p || exit 1; done
	$(PY) -m train.rl_study --runs $(LONG) --out docs/results/rl_pure_long_two_link --episodes 10 --every 60000 --no-progress

# The RL entrants on three paths they were not trained on (about 1 min each on 2 cores).
heldout: setup
	for k in 1 2 3; do $(PY) -m train.evaluate --config train/configs/heldout_paths_rl.yml \
	  --set path_seed=$$k --out results/heldout_path$$k --no-progress || exit 1; done

# The studies behind the main job's report (each minutes to tens of minutes on 2 cores;
# their results are committed: agents/tuned, docs/results). Each refuses to overwrite its
# output: pass --resume by hand to continue an interrupted one.
tune: setup
	$(PY) -m train.tune --config train/configs/tune_iiwa.yml --save
	$(PY) -m train.tune --config train/configs/tune_two_link.yml --save

adversary: setup
	$(PY) -m train.adversary --config train/configs/adversary_iiwa.yml --no-progress
	$(PY) -m train.adversary --config train/configs/adversary_two_link.yml --no-progress
	$(PY) -m train.adversary --config train/configs/adversary_iiwa_default_gains.yml --no-progress

fronts: setup
	$(PY) -m train.fronts --out docs/results/fronts_iiwa --no-progress

# The RL study of docs/rl.md (20 SAC runs, about 65 min on 2 cores, then 12 min of evaluation).
rl-study: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_two_link.yml --out runs/rl_study_two_link --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_two_link --out docs/results/rl_study_two_link --episodes 10 --every 20000 --no-progress

# The deadband-gated residuals of docs/rl.md (10 SAC runs, 28 min on 2 cores, then 6 min).
rl-deadband: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_deadband_two_link.yml --out runs/rl_deadband_two_link --workers 2
	$(PY) -m train.rl_study --runs runs/rl_deadband_two_link --out docs/results/rl_deadband_two_link --episodes 10 --every 20000 --no-progress

# The same 2-mrad deadband put on residuals trained without a gate, at evaluation only (a
# deploy.yml beside copies of the final checkpoints of rl-study's computed-torque residuals
# and the penalty ablation's w = 0 passivity residuals; needs both campaigns' runs/).
# $(call deploy_copy,RUN,DEST[,STEPS]): a finished run of STEPS (default 60 000) steps copied to
# DEST (final model, its last checkpoint, statistics, config) with a deploy.yml putting the
# 2-mrad deadband gate on it.
deploy_copy = mkdir -p $(2)/checkpoints && \
  cp -a $(1)/config.yml $(1)/command.txt $(1)/versions.json $(1)/monitor $(1)/model.zip $(1)/vecnormalize.pkl $(2)/ && \
  cp -a $(1)/checkpoints/rl_model_$(or $(3),60000)_steps.zip $(1)/checkpoints/rl_model_vecnormalize_$(or $(3),60000)_steps.pkl $(2)/checkpoints/ && \
  printf 'gate_rad: 0.002\ngate_deadband_rad: 0.002\n' > $(2)/deploy.yml
# $(call deploy_all,RUNS,DEST[,STEPS]): every residual run <group>_s<seed> of RUNS copied by
# deploy_copy to DEST/<group>-deploy_s<seed>; the first failed copy stops the recipe.
HASH := \#
deploy_all = for src in $(1)/residual-*_s*; do \
	  b=$$(basename $$src); $(call deploy_copy,$$src,$(2)/$${b%_s*}-deploy_s$${b$(HASH)$(HASH)*_s},$(3)) || exit 1; \
	done
GATED := runs/rl_deploy_deadband_two_link
rl-gated-eval: setup
	for i in 0 1 2 3 4; do \
	  for pair in rl_ablation_two_link/residual-passivity-penalty0_s$$i:residual-passivity-deploy_s$$i \
	              rl_study_two_link/residual-computed_torque_s$$i:residual-computed_torque-deploy_s$$i; do \
	    $(call deploy_copy,runs/$${pair%%:*},$(GATED)/$${pair##*:}); \
	  done; \
	done
	$(PY) -m train.rl_study --runs $(GATED) --out docs/results/rl_deploy_deadband_two_link --episodes 10 --no-progress

# Issue 14 on the iiwa: 10 residual SAC runs (about 30 min on 2 cores), their study, then the
# same final checkpoints gated at evaluation (the 2-mrad deadband of rl-gated-eval).
IIWA := runs/rl_study_iiwa
IIWA_GATED := runs/rl_deploy_iiwa
rl-iiwa: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa.yml --out $(IIWA) --workers 2
	$(PY) -m train.rl_study --runs $(IIWA) --out docs/results/rl_study_iiwa --episodes 10 --every 20000 --no-progress
	$(call deploy_all,$(IIWA),$(IIWA_GATED))
	$(PY) -m train.rl_study --runs $(IIWA_GATED) --out docs/results/rl_deploy_iiwa --episodes 10 --no-progress

# The iiwa's second try: the residual's authority 0.01 tau_max instead of 0.1 (6 runs, about
# 20 min on 2 cores, then the study).
rl-iiwa-small: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_scale001.yml --out runs/rl_study_iiwa_scale001 --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_scale001 --out docs/results/rl_study_iiwa_scale001 --episodes 10 --every 20000 --no-progress

# The iiwa's third and fourth tries: the residual as a joint acceleration, tau_res = M(q) 10 a
# (3 seeds per base), then the same with SAC's entropy coefficient starting at 0.001 (3 more);
# about 35 min of training on 2 cores, then one study of all 12 runs on the same episodes.
rl-iiwa-accel: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_accel.yml --out runs/rl_study_iiwa_accel --workers 2
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_accel_ent.yml --out runs/rl_study_iiwa_accel --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_accel --out docs/results/rl_study_iiwa_accel --episodes 10 --every 20000 --no-progress

# The iiwa's fifth try: alpha = 1 rad/s^2 instead of 10 (3 seeds per base, entropy coefficient
# from 0.001 as the -ent groups); 33 min of training one run at a time beside other jobs
# (the target trains 2 at a time), then ~25 min of evaluation.
rl-iiwa-accel1: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_accel1.yml --out runs/rl_study_iiwa_accel1 --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_accel1 --out docs/results/rl_study_iiwa_accel1 --episodes 10 --every 20000 --no-progress

# The iiwa's sixth try: alpha = 1 with the actor at a tenth of the critic's learning rate.
rl-iiwa-slow-actor: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_slow_actor.yml --out runs/rl_study_iiwa_slow_actor --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_slow_actor --out docs/results/rl_study_iiwa_slow_actor --episodes 10 --every 20000 --no-progress

# The iiwa's seventh try: alpha = 1 with a behaviour-cloning pull of the actor toward 0 (the base).
rl-iiwa-bc: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_bc.yml --out runs/rl_study_iiwa_bc --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_bc --out docs/results/rl_study_iiwa_bc --episodes 10 --every 20000 --no-progress

# The iiwa's eighth try: alpha = 1 with a 10 000-step critic warm-up that explores with std 0.5.
rl-iiwa-wide: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_wide.yml --out runs/rl_study_iiwa_wide --workers 2
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_wide --out docs/results/rl_study_iiwa_wide --episodes 10 --every 20000 --no-progress

# Its passivity residuals continued to 120 000 steps (needs rl-iiwa-wide's runs/): each run
# copied, then resumed with its own recorded command (about 20 min, 2 at a time).
WIDE_LONG := runs/rl_study_iiwa_wide_long
rl-iiwa-wide-long: setup
	mkdir -p $(WIDE_LONG) && for s in 0 1 2; do cp -a runs/rl_study_iiwa_wide/residual-passivity-wide_s$$s $(WIDE_LONG)/; done
	pids=; for s in 0 1 2; do \
	  cmd=$$(head -1 $(WIDE_LONG)/residual-passivity-wide_s$$s/command.txt | \
	    sed -e 's#^[^ ]* -m #$(PY) -m #' -e 's#rl_study_iiwa_wide/#rl_study_iiwa_wide_long/#'); \
	  eval "$$cmd --resume" & pids="$$pids $$!"; \
	  if [ $$s = 1 ]; then for p in $$pids; do wait $$p || exit 1; done; pids=; fi; \
	done; for p in $$pids; do wait $$p || exit 1; done
	$(PY) -m train.rl_study --runs $(WIDE_LONG) --out docs/results/rl_study_iiwa_wide_long --episodes 10 --every 60000 --no-progress

# The iiwa's ninth try: the residual over the main job's passivity controller (tuned gains,
# 1 kHz) with alpha = 10 rad/s^2 (4 runs of 100 000 steps, about 35 min on 2 cores), its
# study, then the final checkpoints gated at evaluation (2-mrad deadband).
IIWA_TUNED := runs/rl_study_iiwa_tuned
IIWA_TUNED_GATED := runs/rl_deploy_iiwa_tuned
rl-iiwa-tuned: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_tuned.yml --out $(IIWA_TUNED) --workers 2
	$(PY) -m train.rl_study --runs $(IIWA_TUNED) --out docs/results/rl_study_iiwa_tuned --episodes 10 --every 20000 --no-progress
	$(call deploy_all,$(IIWA_TUNED),$(IIWA_TUNED_GATED),100000)
	$(PY) -m train.rl_study --runs $(IIWA_TUNED_GATED) --out docs/results/rl_deploy_iiwa_tuned --episodes 10 --no-progress

# Two one-seed screens of it: a behaviour-cloning pull toward the base, and the deadband gate
# while training (2 runs of 100 000 steps, about 20 min on 2 cores); the BC run is also
# evaluated gated at evaluation (a deploy.yml copy beside it).
rl-iiwa-tuned-variants: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_tuned_variants.yml --out runs/rl_study_iiwa_tuned_variants --workers 2
	$(call deploy_copy,runs/rl_study_iiwa_tuned_variants/residual-passivity-tuned-bc_s0,runs/rl_study_iiwa_tuned_variants/residual-passivity-tuned-bc-deploy_s0,100000)
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_tuned_variants --out docs/results/rl_study_iiwa_tuned_variants --episodes 10 --every 50000 --no-progress

# The BC screen on 5 seeds (seed 0 is the screen's run, copied), gated at evaluation.
IIWA_BC := runs/rl_study_iiwa_tuned_bc
IIWA_BC_GATED := runs/rl_deploy_iiwa_tuned_bc
rl-iiwa-tuned-bc: setup
	mkdir -p $(IIWA_BC) && test -e $(IIWA_BC)/residual-passivity-tuned-bc_s0 || cp -a runs/rl_study_iiwa_tuned_variants/residual-passivity-tuned-bc_s0 $(IIWA_BC)/
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_tuned_bc.yml --out $(IIWA_BC) --workers 2
	$(call deploy_all,$(IIWA_BC),$(IIWA_BC_GATED),100000)
	$(PY) -m train.rl_study --runs $(IIWA_BC_GATED) --out docs/results/rl_deploy_iiwa_tuned_bc --episodes 10 --no-progress

# What a residual of acceleration authority alpha can gain over that base at all: a hand-made
# bang-bang residual toward the controller's own reference (train/authority_probe.py).
authority-probe: setup
	$(PY) -m train.authority_probe --base passivity --base-gains tuned --control-hz 1000 --alpha 1 3 10 --gate 0.002 --disturbance none impulse periodic payload noise
	$(PY) -m train.authority_probe --base passivity --base-gains tuned --control-hz 1000 --alpha 10 --disturbance none impulse periodic payload noise

# The BC recipe with the probe's feedback as a control prior (prior_gain_per_rad 1000), two
# one-seed screens (trained ungated, trained gated; about 25 min on 2 cores); the ungated run is
# also evaluated gated at evaluation (a deploy.yml copy beside it).
rl-iiwa-tuned-prior: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_study_iiwa_tuned_prior.yml --out runs/rl_study_iiwa_tuned_prior --workers 2
	$(call deploy_copy,runs/rl_study_iiwa_tuned_prior/residual-passivity-tuned-prior_s0,runs/rl_study_iiwa_tuned_prior/residual-passivity-tuned-prior-deploy_s0,100000)
	$(PY) -m train.rl_study --runs runs/rl_study_iiwa_tuned_prior --out docs/results/rl_study_iiwa_tuned_prior --episodes 10 --every 50000 --no-progress

# $(call gated_study,CONFIG,RUNS,GATED,RESULTS[,STEPS]): a campaign of STEPS-step (default
# 100 000) residual runs (CONFIG into RUNS), each copied by deploy_all to GATED with the 2-mrad
# deadband gate put on at evaluation, and the study of those copies under every preset into
# RESULTS.
gated_study = $(PY) -m train.rl_campaign --config $(1) --out $(2) --workers 2 && \
  $(call deploy_all,$(2),$(3),$(or $(5),100000)) && \
  $(PY) -m train.rl_study --runs $(3) --out $(4) --episodes 10 --no-progress

# The control-prior recipe on 5 seeds (trained ungated; about 25 min on 2 cores), gated at
# evaluation.
rl-iiwa-tuned-prior-seeds: setup
	$(call gated_study,train/configs/rl_study_iiwa_tuned_prior_seeds.yml,runs/rl_study_iiwa_tuned_prior_seeds,runs/rl_deploy_iiwa_tuned_prior,docs/results/rl_deploy_iiwa_tuned_prior)

# The same recipe over the main job's computed-torque controller (its prior: stiffness toward
# the controller's clock-indexed reference), 5 seeds (about 25 min on 2 cores), gated at
# evaluation.
rl-iiwa-tuned-prior-ct: setup
	$(call gated_study,train/configs/rl_study_iiwa_tuned_prior_ct.yml,runs/rl_study_iiwa_tuned_prior_ct,runs/rl_deploy_iiwa_tuned_prior_ct,docs/results/rl_deploy_iiwa_tuned_prior_ct)

# The control prior alone, through the same harness and test episodes: each recipe stopped at
# 1 000 steps, inside its critic warm-up, so the zero-initialised actor outputs exactly 0
# (about 4 min on 2 cores).
rl-iiwa-prior-alone: setup
	$(call gated_study,train/configs/rl_prior_alone_iiwa.yml,runs/rl_prior_alone_iiwa,runs/rl_deploy_prior_alone_iiwa,docs/results/rl_deploy_prior_alone_iiwa,1000)
	$(PY) -m train.action_probe runs/rl_deploy_prior_alone_iiwa/*

# The trained prior residuals against the prior alone, paired on the same test episodes (needs
# the runs of the three targets above; about 3 min each on 2 cores). Like every sweep it
# refuses to overwrite its committed results: move them aside to re-run.
prior-vs-learned: setup
	for b in passivity computed_torque; do $(PY) -m train.evaluate \
	  --config train/configs/prior_vs_learned_$${b}_iiwa.yml --no-progress || exit 1; done

# Two one-seed screens over computed torque with a weaker / no BC pull toward the prior
# (about 10 min on 2 cores), gated at evaluation.
rl-iiwa-prior-bc-screen: setup
	$(call gated_study,train/configs/rl_study_iiwa_prior_bc_screen.yml,runs/rl_study_iiwa_prior_bc_screen,runs/rl_deploy_iiwa_prior_bc_screen,docs/results/rl_deploy_iiwa_prior_bc_screen)

# Pure SAC on the iiwa with sbx: the two-link's pure recipe, 2 seeds to 400 000 steps (about
# 35 min on 2 cores), evaluated every 100 000 steps.
rl-pure-sbx-iiwa: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_pure_sbx_iiwa.yml --out runs/rl_pure_sbx_iiwa --workers 2
	$(PY) -m train.rl_study --runs runs/rl_pure_sbx_iiwa --out docs/results/rl_pure_sbx_iiwa --episodes 10 --every 100000 --no-progress

# Its second try: two one-seed screens that keep the entropy bonus small (a fixed coefficient;
# a tuned one with a target entropy sized for precision), 200 000 steps (about 20 min).
rl-pure-sbx-iiwa-ent: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_pure_sbx_iiwa_ent.yml --out runs/rl_pure_sbx_iiwa_ent --workers 2
	$(PY) -m train.rl_study --runs runs/rl_pure_sbx_iiwa_ent --out docs/results/rl_pure_sbx_iiwa_ent --episodes 10 --every 100000 --no-progress

# Pure RL on the iiwa, third try: DAgger of tuned PD + gravity, then SAC fine-tuning (issue 14;
# 5 seeds x (300 000 imitation + 20 000 RL steps), ~30 min on 2 cores).
rl-pure-dagger-iiwa: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_pure_dagger_iiwa.yml --out runs/rl_pure_dagger_iiwa --workers 2
	$(PY) -m train.rl_study --runs runs/rl_pure_dagger_iiwa --out docs/results/rl_pure_dagger_iiwa --episodes 10 --no-progress

# Issue 14, pure RL on the iiwa, fourth try: RL refines the shipped imitation as a residual
# over it, deciding at 100 Hz (5 seeds x 40 000 decisions; ~11 min of training, ~10 of
# evaluation on 2 cores).
rl-residual-imitation-iiwa: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_residual_imitation_iiwa.yml --out runs/rl_residual_imitation_iiwa --workers 2
	$(PY) -m train.rl_study --runs runs/rl_residual_imitation_iiwa --out docs/results/rl_residual_imitation_iiwa --episodes 10 --no-progress

# Issue 14: residuals over the tuned passivity and computed-torque controllers without the
# control prior, deciding at 100 Hz, 5 seeds per base (~20 min of training on 2 cores), gated at
# evaluation (~15 min).
rl-residual-k10-iiwa: setup
	$(call gated_study,train/configs/rl_residual_k10_iiwa.yml,runs/rl_residual_k10_iiwa,runs/rl_deploy_residual_k10_iiwa,docs/results/rl_deploy_residual_k10_iiwa,40000)

# The iiwa's three arms (pure, residual on passivity, residual on computed torque; 5 seeds each)
# on the same paired test episodes (needs the three targets' local runs; ~15 min on 2 cores).
rl-three-arms-iiwa: setup
	$(PY) -m train.evaluate --config train/configs/three_arms_iiwa.yml --no-progress

# The three arms on equal RL budgets (each an SAC residual at 100 Hz, 400 000 env steps, 5 seeds;
# needs the runs of rl-residual-imitation-iiwa and rl-residual-k10-iiwa; ~10 min on 2 cores).
rl-three-arms-iiwa-k10: setup
	$(PY) -m train.evaluate --config train/configs/three_arms_iiwa_k10.yml --no-progress

# Pure SAC on the two-link with the sbx backend (make setup installs it, after torch):
# 5 seeds to 300 000 steps (about 1 h of training on 2 cores), evaluated every 60 000 steps
# (~20 min), then the final policies on the three held-out paths (results/heldout_sbx_path*).
SBX_RUNS := $(foreach s,0 1 2 3 4,"sb3:runs/rl_pure_sbx_two_link/pure-sbx_s$(s)",)
rl-pure-sbx: setup
	$(PY) -m train.rl_campaign --config train/configs/rl_pure_sbx_two_link.yml --out runs/rl_pure_sbx_two_link --workers 2
	$(PY) -m train.rl_study --runs runs/rl_pure_sbx_two_link --out docs/results/rl_pure_sbx_two_link --episodes 10 --every 60000 --no-progress
	for k in 1 2 3; do $(PY) -m train.evaluate --config train/configs/heldout_paths_rl.yml --set path_seed=$$k \
	  --set 'controllers=[pd_gravity, computed_torque, $(SBX_RUNS)]' --set 'disturbances=[none, impulse]' \
	  --set reference=pd_gravity --out results/heldout_sbx_path$$k --no-progress || exit 1; done

lint: setup
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

# In parallel over the cores (pytest-xdist); one BLAS/torch thread per worker.
test: lint
	OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n auto

bench: setup
	$(PY) bench/env_step.py
	$(PY) bench/controller_cost.py
	$(PY) bench/eval_scaling.py
	$(PY) bench/same_work.py
	$(PY) bench/train_throughput.py --steps 1000 --warmup 300 --env-steps 5000 --repeats 3

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
