"""A run's trained policy as a function ``obs -> action``, and the zero action: what evaluation, the command
table and users' own rollouts share (:func:`load_run` is the public call)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .config import MODEL_FILENAME, VECNORMALIZE_FILENAME, RunConfig, algo_class, load_config
from .environments import check_env_id, make_env
from .experiment import CHECKPOINT_PREFIX
from .runs import find_run

EVAL_SEED_OFFSET = 10_000  # default episode seeds start at the training seed + this (unseen resets)

Policy = Callable[[Any], Any]


def _vecnormalize_path(run_dir: Path, model_path: Path) -> Path:
    """Stats saved with ``model_path``: ``vecnormalize.pkl``, or a checkpoint's own ``.pkl``."""
    stem = model_path.stem  # model_<steps>_steps for checkpoints
    prefix = f"{CHECKPOINT_PREFIX}_"
    if model_path.parent.name == "checkpoints" and stem.startswith(prefix) and stem.endswith("_steps"):
        return model_path.with_name(f"{CHECKPOINT_PREFIX}_vecnormalize_{stem[len(prefix):]}.pkl")
    return run_dir / VECNORMALIZE_FILENAME


def load_policy(config: RunConfig, run_dir: str | Path, env, *, model_path: str | Path | None = None,
                deterministic: bool = True) -> tuple[Policy, Path]:
    """The trained policy of a run as ``obs -> action`` for the single env ``env``, and the model path."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    run_dir = Path(run_dir)
    path = Path(model_path) if model_path is not None else run_dir / MODEL_FILENAME
    if not path.is_file():
        raise FileNotFoundError(f"no model at {path}: the run has not finished (checkpoints are in "
                                f"{run_dir / 'checkpoints'}; pass one with --model)")
    # schedules are not needed to act; this keeps loading robust across SB3 versions (as rl-zoo3 does)
    custom_objects = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    model = algo_class(config.algo).load(path, device=config.device, custom_objects=custom_objects)
    normalize: Callable[[Any], Any] = lambda obs: obs  # noqa: E731
    if config.normalize is not None:
        stats = _vecnormalize_path(run_dir, path)
        if not stats.is_file():
            raise FileNotFoundError(f"the run normalizes observations but {stats} is missing")
        vecnorm = VecNormalize.load(str(stats), DummyVecEnv([lambda: env]))  # checks the spaces match
        vecnorm.training, vecnorm.norm_reward = False, False
        normalize = vecnorm.normalize_obs

    def act(obs):
        return model.predict(normalize(obs), deterministic=deterministic)[0]

    return act, path


def load_run(run: str | Path, *, deterministic: bool = True, **env_kwargs) -> tuple[Policy, Any, RunConfig]:
    """A run's policy and a fresh env of its task: ``(act, env, config)``; ``act(obs) -> action``.

    ``run`` is a run folder or a shipped run's name (``load_run("SandQuadruped-v1")``, :func:`.runs.find_run`);
    ``env_kwargs`` update the run's own (e.g. ``render_mode="rgb_array"``, ``ground="rigid"``). Close the env."""
    run_dir = find_run(run)
    config = load_config(run_dir)
    check_env_id(config.env_id)
    env = make_env(config.env_id, {**config.env_kwargs, **env_kwargs})
    try:
        act, _ = load_policy(config, run_dir, env, deterministic=deterministic)
    except BaseException:
        env.close()
        raise
    return act, env, config


def zero_action(space) -> Any | None:
    """The zero action clipped into a Box's bounds (``start`` for Discrete); None for other spaces."""
    from gymnasium import spaces

    if isinstance(space, spaces.Box):
        return np.clip(np.zeros(space.shape), space.low, space.high).astype(space.dtype)
    if isinstance(space, spaces.Discrete):
        return int(space.start)
    return None
