"""Env ids and env factories: the sand tasks are registered by importing ``rft_mujoco.envs``.

Any id in ``gymnasium.registry`` works (``Pendulum-v1``, ``HalfCheetah-v5``, ...); an id of the form
``module:Name-v0`` imports ``module`` first, as ``gymnasium.make`` does.
"""

from __future__ import annotations

import difflib
import functools
import importlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym

SAND_NAMESPACE = "rft_mujoco"
SAND_PACKAGE = "rft_mujoco.envs"


def register_envs() -> None:
    """Import ``rft_mujoco.envs`` so that its ``rft_mujoco/...`` ids are registered.

    A missing package is tolerated (other gymnasium ids still work); an error inside it is not.
    """
    try:
        importlib.import_module(SAND_PACKAGE)
    except ModuleNotFoundError as err:
        if err.name not in ("rft_mujoco", SAND_PACKAGE):
            raise


def sand_env_ids() -> list[str]:
    """Registered ids in the ``rft_mujoco`` namespace, sorted."""
    register_envs()
    return sorted(env_id for env_id, spec in gym.registry.items() if spec.namespace == SAND_NAMESPACE)


def check_env_id(env_id: str) -> str:
    """``env_id`` if registered; ValueError listing the sand ids and close matches otherwise."""
    register_envs()
    module, sep, name = str(env_id).rpartition(":")
    if sep:
        try:
            importlib.import_module(module)
        except ImportError as err:
            raise ValueError(f"env id {env_id!r}: cannot import module {module!r}: {err}") from None
    if name in gym.registry:
        return str(env_id)
    sand = sand_env_ids()
    # an id given without its namespace ("SandSwimmer-v0") matches on the name part first
    same_name = [i for i in gym.registry if i.rpartition("/")[2] == name.rpartition("/")[2]]
    close = same_name or difflib.get_close_matches(name, list(gym.registry), n=3, cutoff=0.6)
    raise ValueError(
        f"unknown env id {env_id!r}. Registered {SAND_NAMESPACE} ids: "
        f"{', '.join(sand) if sand else f'none (is {SAND_PACKAGE} installed and importable?)'}"
        + (f"; close matches: {', '.join(close)}" if close else "")
        + ". Any id in gymnasium.registry works (list them with "
        "`python -c 'import gymnasium; gymnasium.pprint_registry()'`)."
    )


def make_env(env_id: str, env_kwargs: Mapping[str, Any] | None = None,
             render_mode: str | None = None) -> gym.Env:
    """``gymnasium.make(env_id, **env_kwargs)`` after registering the sand tasks (works in subprocesses)."""
    register_envs()
    kwargs = dict(env_kwargs or {})
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    return gym.make(env_id, **kwargs)


def make_vec_env(config, *, monitor_dir: str | Path | None = None):
    """The training envs of ``config`` (a :class:`.config.RunConfig`), Monitor-wrapped, not normalized.

    Env rank ``i`` is seeded with ``config.seed + i``; rank ``i`` writes ``monitor_dir/<i>.monitor.csv``.
    """
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if monitor_dir is not None:
        Path(monitor_dir).mkdir(parents=True, exist_ok=True)
    return sb3_make_vec_env(
        functools.partial(make_env, config.env_id),
        n_envs=config.n_envs,
        seed=config.seed,
        env_kwargs={"env_kwargs": config.env_kwargs},
        monitor_dir=None if monitor_dir is None else str(monitor_dir),
        vec_env_cls=SubprocVecEnv if config.vec_env == "subproc" else DummyVecEnv,
    )
