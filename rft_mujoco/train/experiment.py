"""One training run: config -> run directory with config.yaml, model, VecNormalize stats, logs.

The run directory is written in this order so that an interrupted run still documents itself:
``config.yaml`` first, then Monitor CSVs, TensorBoard logs and checkpoints while training, then
``model.zip`` and ``vecnormalize.pkl``. Ctrl-C stops training early and still saves the model.
"""

from __future__ import annotations

import inspect
import time
from pathlib import Path

from .config import (
    DEFAULT_PROG,
    MODEL_FILENAME,
    VECNORMALIZE_FILENAME,
    RunConfig,
    algo_class,
    algo_kwargs,
    save_config,
    set_num_threads,
)
from .environments import check_env_id, make_vec_env

CHECKPOINT_PREFIX = "model"


def new_run_dir(config: RunConfig, runs_dir: str | Path = "runs", name: str | None = None) -> Path:
    """``runs_dir/<env>_<algo>_<seed>_<timestamp>`` (or ``runs_dir/name``), made unique with ``-2``, ..."""
    base = Path(runs_dir) / (name or config.run_name())
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path


def _check_hyperparams(cls: type, kwargs: dict, config: RunConfig) -> None:
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self", "env"}
    unknown = sorted(set(kwargs) - accepted)
    if unknown:
        raise ValueError(
            f"{cls.__name__} does not accept {unknown} (from {config.hyperparams_file} entries "
            f"{config.hyperparams_entries} and overrides {config.overrides}); accepted: {sorted(accepted)}"
        )


def _wall_clock_limit(minutes: float):
    """An SB3 callback that stops training once ``minutes`` of wall-clock time have passed since it started."""
    from stable_baselines3.common.callbacks import BaseCallback

    class WallClockLimit(BaseCallback):
        def _on_training_start(self) -> None:
            self.deadline = time.perf_counter() + 60.0 * minutes

        def _on_step(self) -> bool:
            if time.perf_counter() < self.deadline:
                return True
            print(f"wall-clock limit of {minutes:g} min reached at {self.num_timesteps} steps: stopping",
                  flush=True)
            return False

    return WallClockLimit()


def _eval_callback(config: RunConfig, run_dir: Path, eval_freq: int, episodes: int, env, verbose: int):
    """rl-zoo3's evaluation during training: SB3's EvalCallback on one separate env every ``eval_freq``
    total steps, the best model to ``run_dir/best_model.zip``, results to ``run_dir/evaluations.npz``;
    the eval env shares the training env's VecNormalize statistics (synced by the callback)."""
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from .environments import make_env

    eval_env = DummyVecEnv([lambda: make_env(config.env_id, config.env_kwargs)])
    if isinstance(env, VecNormalize):
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                **{k: v for k, v in config.normalize.items() if k not in ("norm_reward",)})
    eval_env.seed(config.seed + 10_000)
    return EvalCallback(eval_env, n_eval_episodes=episodes, eval_freq=max(eval_freq // config.n_envs, 1),
                        best_model_save_path=str(run_dir), log_path=str(run_dir), deterministic=True,
                        verbose=verbose)


def train(config: RunConfig, run_dir: str | Path, *, progress_bar: bool = True, verbose: int = 1,
          prog: str = DEFAULT_PROG, max_minutes: float | None = None, eval_freq: int = 0,
          eval_episodes: int = 5) -> Path:
    """Train ``config.algo`` on ``config.env_id`` for ``config.n_timesteps`` steps, or until ``max_minutes``
    of wall-clock time (min) have passed; returns the model path.

    Every run logs the env's reward terms to TensorBoard (:class:`.callbacks.RewardTermsCallback`); with
    ``eval_freq`` > 0 it evaluates ``eval_episodes`` episodes every ``eval_freq`` total steps (rl-zoo3's
    ``--eval-freq``). ``prog`` is the command named in the hints it prints and writes (``config.yaml``'s
    header)."""
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from .callbacks import RewardTermsCallback

    if max_minutes is not None and not max_minutes > 0:
        raise ValueError(f"max_minutes must be > 0 (minutes of wall-clock time), got {max_minutes!r}")

    check_env_id(config.env_id)
    run_dir = Path(run_dir)
    cls = algo_class(config.algo)
    kwargs = algo_kwargs(config)
    _check_hyperparams(cls, kwargs, config)
    save_config(config, run_dir, prog)
    set_num_threads(config)

    env = make_vec_env(config, monitor_dir=run_dir / "monitor")
    if config.normalize is not None:
        env = VecNormalize(env, **config.normalize)
    try:
        model = cls(env=env, seed=config.seed, device=config.device, verbose=verbose,
                    tensorboard_log=str(run_dir / "tb"), **kwargs)
        callbacks = [RewardTermsCallback()]
        if eval_freq > 0:
            callbacks.append(_eval_callback(config, run_dir, eval_freq, eval_episodes, env, verbose))
        if config.save_freq > 0:
            callbacks.append(CheckpointCallback(
                save_freq=max(config.save_freq // config.n_envs, 1),  # counted in calls to env.step
                save_path=str(run_dir / "checkpoints"),
                name_prefix=CHECKPOINT_PREFIX,
                save_vecnormalize=True,
                verbose=verbose,
            ))
        if max_minutes is not None:
            callbacks.append(_wall_clock_limit(max_minutes))
        print(f"training {config.algo.upper()} on {config.env_id}: {config.n_timesteps} steps, "
              f"{config.n_envs} env(s), seed {config.seed} -> {run_dir}", flush=True)
        start = time.perf_counter()
        try:
            model.learn(total_timesteps=config.n_timesteps, callback=callbacks,
                        progress_bar=progress_bar, tb_log_name=config.algo.upper())
        except KeyboardInterrupt:
            print(f"interrupted at {model.num_timesteps} steps: saving the model so far", flush=True)
        elapsed = time.perf_counter() - start
        model_path = run_dir / MODEL_FILENAME
        model.save(model_path)
        if isinstance(env, VecNormalize):
            env.save(str(run_dir / VECNORMALIZE_FILENAME))
    finally:
        env.close()
    print(f"{model.num_timesteps} steps in {elapsed:.1f} s ({model.num_timesteps / max(elapsed, 1e-9):.0f} "
          f"steps/s); saved {model_path}\nevaluate with: {prog} evaluate --run {run_dir}\n"
          f"for rl-zoo3's enjoy: {prog} zoo --run {run_dir} -f logs", flush=True)
    return model_path
