"""Evaluation, training and studies: the ``ptrack`` command line and its library.

Sub-packages, imported one way (``rl`` and ``studies`` → ``evaluation`` → ``plots``,
``common``):

* :mod:`train.evaluation` — paired evaluation sweeps: config, episode, sweep, results,
  report, video, trained-policy loading;
* :mod:`train.rl` — Stable-Baselines3 training: config, run, actor surgery, campaigns,
  learning-curve studies, imitation, hyperparameters, checkpoints;
* :mod:`train.studies` — gain tuning, error–effort fronts, adversarial search, the
  control-rate study, probes of trained policies;
* :mod:`train.common` — statistics, the run-folder harness, config files, command-line
  arguments, threads;
* :mod:`train.plots` — figures.
"""
