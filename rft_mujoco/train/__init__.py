"""Training and evaluation of stable-baselines3 agents on the sand tasks (and any gymnasium id).

Hyperparameter YAMLs ship as package data. A thin command line (``python -m rft_mujoco.train
{train,evaluate,gap,plot,zoo} --help``, or the console script ``rft-mujoco-train``) over a few modules:

- ``config``       the run configuration: YAML hyperparameters keyed by env id, CLI overrides, and the
                   ``config.yaml`` saved beside every model (the one source ``evaluate`` rebuilds from);
- ``environments`` env-id checks (unknown ids list the registered ``rft_mujoco/`` tasks) and env factories;
- ``experiment``   one training run: vectorized envs, optional VecNormalize, TensorBoard, checkpoints,
                   saving on SIGTERM/SIGINT, resuming;
- ``evaluate``     reload a run from its ``config.yaml``; trained vs random vs zero-action baselines,
                   JSON, bar chart + learning curve, and a video where offscreen rendering works;
- ``plot``         learning curves (episode return vs timesteps) from the Monitor CSVs of runs;
- ``zoo``          a run written in rl-zoo3's layout, for ``python -m rl_zoo3.enjoy``.

A run directory ``runs/<env>_<algo>_<seed>_<timestamp>/`` holds::

    config.yaml          exact resolved configuration (algo, env id and kwargs, hyperparameters, ...)
    model.zip            final model
    vecnormalize.pkl     VecNormalize statistics (only when the run normalizes)
    checkpoints/         model_<steps>_steps.zip (+ model_vecnormalize_<steps>_steps.pkl; periodic, and on SIGTERM
                         or Ctrl-C, then with the SAC replay buffer): ``train --resume RUN`` continues from the latest
    monitor/             <rank>.monitor.csv, one per training env (episode return, length, time); resumed_<steps>/
    tb/                  TensorBoard logs (``tensorboard --logdir runs``)

``evaluate`` writes into ``./out/eval/<run name>/`` (never into a run folder). The shipped runs
(``pretrained/``, package data) are found by name: ``--run SandQuadruped-v1``, or in Python
``act, env, config = rft_mujoco.train.load_run("SandQuadruped-v1")``.
"""

from __future__ import annotations

import os
import sys

# Offscreen rendering for videos on headless Linux. MuJoCo reads MUJOCO_GL when it is first imported
# and only fails when a GL context is actually created, so this default is harmless elsewhere.
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")


def find_run(run):
    """The folder of a run: a run folder, or a shipped run by name (``find_run("SandQuadruped-v1")``)."""
    from .runs import find_run as _find

    return _find(run)


def load_run(run, **kwargs):
    """``(act, env, config)`` of a run folder or shipped run name: see :func:`.policies.load_run`."""
    from .policies import load_run as _load

    return _load(run, **kwargs)


__all__ = ["find_run", "load_run"]
