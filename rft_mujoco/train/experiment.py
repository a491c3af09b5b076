"""One training run: config -> run directory with config.yaml, model, VecNormalize stats, logs; and its resumption.

The run directory is written in this order so that an interrupted run still documents itself:
``config.yaml`` first, then Monitor CSVs, TensorBoard logs and checkpoints while training, then
``model.zip`` and ``vecnormalize.pkl``.

SIGTERM or SIGINT (Ctrl-C) during training stops it at the next env step (a second signal stops at once) and
saves the model so far as a checkpoint, ``checkpoints/model_<steps>_steps.zip`` with the VecNormalize
statistics and, for SAC when it is at most :data:`REPLAY_BUFFER_MAX_BYTES`, the replay buffer, besides
``model.zip``; :func:`train` then raises :class:`Interrupted` (the command line exits with 128 + the signal
number: 143 for SIGTERM, 130 for SIGINT). :func:`resume` continues a run from its latest checkpoint (or
``model.zip``) with its ``config.yaml``, counting timesteps on: ``python -m rft_mujoco.train train --resume RUN``.
"""

from __future__ import annotations

import dataclasses
import inspect
import signal
import threading
import time
from pathlib import Path

from .config import (
    DEFAULT_PROG,
    CONFIG_FILENAME,
    MODEL_FILENAME,
    VECNORMALIZE_FILENAME,
    RunConfig,
    _positive_int,
    algo_class,
    algo_kwargs,
    load_config,
    save_config,
    set_num_threads,
)
from .environments import check_env_id, make_vec_env
from .runs import CHECKPOINT_PREFIX, Checkpoint, checkpoint_paths, is_shipped, latest_checkpoint

REPLAY_BUFFER_MAX_BYTES = 2 ** 30
"""An interrupted off-policy run saves its replay buffer when the buffer's arrays take at most this many
bytes (SB3 pickles the whole preallocated buffer); a larger one is left out and the resumed run refills it."""
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
"""Signals that stop a training run and save it (:class:`Interrupted`)."""


class Interrupted(Exception):
    """Training was stopped by a signal; the model so far is saved (``checkpoint``, a :class:`.runs.Checkpoint`).

    ``exit_code`` is the shell's status for the signal, 128 + its number (143 for SIGTERM, 130 for SIGINT)."""

    def __init__(self, signum: int, checkpoint: Checkpoint, message: str):
        super().__init__(message)
        self.signum = int(signum)
        self.checkpoint = checkpoint
        self.exit_code = 128 + self.signum


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


class _SignalStop:
    """While training: SIGTERM/SIGINT set :attr:`signum` and the :meth:`callback` ends training at the next env
    step (SB3 returns from ``learn`` normally); a second signal raises KeyboardInterrupt at once. Installed only
    in the main thread (Python delivers signals there); elsewhere nothing changes."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._saved: dict = {}

    def __enter__(self) -> "_SignalStop":
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                self._saved[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)   # (None: one set outside Python)

    def _handle(self, signum, frame) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        print(f"{signal.Signals(signum).name} received: stopping at the next step to save the run (send it again "
              "to stop at once)", flush=True)

    def callback(self):
        from stable_baselines3.common.callbacks import BaseCallback

        stop = self

        class StopOnSignal(BaseCallback):
            def _on_step(self) -> bool:
                return stop.signum is None

        return StopOnSignal()


def _eval_callback(config: RunConfig, run_dir: Path, eval_freq: int, episodes: int, env, verbose: int,
                   resumed: bool = False):
    """rl-zoo3's evaluation during training: SB3's EvalCallback on one separate env every ``eval_freq``
    total steps, the best model to ``run_dir/best_model.zip``, results to ``run_dir/evaluations.npz``;
    the eval env shares the training env's VecNormalize statistics (synced by the callback). A ``resumed``
    run continues the evaluations (and the best reward) of ``evaluations.npz``."""
    import numpy as np
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from .environments import make_env

    eval_env = DummyVecEnv([lambda: make_env(config.env_id, config.env_kwargs)])
    if isinstance(env, VecNormalize):
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                **{k: v for k, v in config.normalize.items() if k not in ("norm_reward",)})
    eval_env.seed(config.seed + 10_000)
    callback = EvalCallback(eval_env, n_eval_episodes=episodes, eval_freq=max(eval_freq // config.n_envs, 1),
                            best_model_save_path=str(run_dir), log_path=str(run_dir), deterministic=True,
                            verbose=verbose)
    earlier = run_dir / "evaluations.npz"
    if resumed and earlier.is_file():
        with np.load(earlier) as old:
            callback.evaluations_timesteps = [int(t) for t in old["timesteps"]]
            callback.evaluations_results = [list(r) for r in old["results"]]
            callback.evaluations_length = [list(n) for n in old["ep_lengths"]]
            if "successes" in old:
                callback.evaluations_successes = [list(x) for x in old["successes"]]
            if len(old["results"]):
                callback.best_mean_reward = float(np.max(np.mean(old["results"], axis=1)))
    return callback


def train(config: RunConfig, run_dir: str | Path, *, progress_bar: bool = True, verbose: int = 1,
          prog: str = DEFAULT_PROG, max_minutes: float | None = None, eval_freq: int = 0,
          eval_episodes: int = 5) -> Path:
    """Train ``config.algo`` on ``config.env_id`` for ``config.n_timesteps`` steps, or until ``max_minutes``
    of wall-clock time (min) have passed; returns the model path.

    Every run logs the env's reward terms to TensorBoard (:class:`.callbacks.RewardTermsCallback`); with
    ``eval_freq`` > 0 it evaluates ``eval_episodes`` episodes every ``eval_freq`` total steps (rl-zoo3's
    ``--eval-freq``). ``prog`` is the command named in the hints it prints and writes (``config.yaml``'s
    header). Raises :class:`Interrupted` after saving when SIGTERM or SIGINT stopped it (module docstring)."""
    if max_minutes is not None and not max_minutes > 0:
        raise ValueError(f"max_minutes must be > 0 (minutes of wall-clock time), got {max_minutes!r}")

    check_env_id(config.env_id)
    run_dir = Path(run_dir)
    cls = algo_class(config.algo)
    _check_hyperparams(cls, algo_kwargs(config), config)
    save_config(config, run_dir, prog)
    return _learn(config, run_dir, None, progress_bar=progress_bar, verbose=verbose, prog=prog,
                  max_minutes=max_minutes, eval_freq=eval_freq, eval_episodes=eval_episodes)


def resume_dir(run: str | Path, runs_dir: str | Path = "runs") -> Path:
    """The folder of the run to resume: ``run`` itself, or ``runs_dir/run`` (a run name), holding ``config.yaml``.

    Raises FileNotFoundError when neither holds one, ValueError for a shipped run (inside the package)."""
    for candidate in dict.fromkeys((Path(run), Path(runs_dir) / run)):
        if (candidate / CONFIG_FILENAME).is_file():
            if is_shipped(candidate):
                raise ValueError(f"{candidate} is a shipped run (inside the installed package); copy the folder "
                                 "somewhere else and resume the copy")
            return candidate
    raise FileNotFoundError(f"no run {str(run)!r} to resume: neither {Path(run)} nor {Path(runs_dir) / run} holds "
                            f"{CONFIG_FILENAME}; pass a run folder written by `{DEFAULT_PROG} train` "
                            "(runs/<env>_<algo>_<seed>_<timestamp>) or its name with --runs-dir")


def resume(run: str | Path, *, timesteps: int | None = None, runs_dir: str | Path = "runs",
           progress_bar: bool = True, verbose: int = 1, prog: str = DEFAULT_PROG, max_minutes: float | None = None,
           eval_freq: int = 0, eval_episodes: int = 5) -> Path:
    """Continue the run ``run`` (its folder, or its name under ``runs_dir``) from its latest saved state
    (:func:`.runs.latest_checkpoint`: the checkpoint with the most steps, or ``model.zip`` of a run that
    finished) with its ``config.yaml``, counting timesteps on, until ``timesteps`` total env steps (default the
    run's ``n_timesteps``; another total is written into ``config.yaml``). Returns the model path.

    The resumed part logs into the same TensorBoard run, into ``monitor/resumed_<steps>/`` (the plots merge
    every Monitor file of the run) and continues ``evaluations.npz``. It is not the uninterrupted run bit for
    bit: checkpoints hold no random-number state, so its envs and model are seeded with ``seed + steps``,
    and an off-policy run without a saved replay buffer refills one. Other arguments as :func:`train`."""
    if max_minutes is not None and not max_minutes > 0:
        raise ValueError(f"max_minutes must be > 0 (minutes of wall-clock time), got {max_minutes!r}")
    run_dir = resume_dir(run, runs_dir)
    config = load_config(run_dir)
    check_env_id(config.env_id)
    start = latest_checkpoint(run_dir)
    if start is None:
        raise FileNotFoundError(f"nothing to resume in {run_dir}: no {CHECKPOINT_PREFIX}_<steps>_steps.zip in "
                                f"checkpoints/ and no {MODEL_FILENAME} (the run stopped before it saved anything); "
                                "train it again")
    total = config.n_timesteps if timesteps is None else _positive_int("timesteps", timesteps)
    if total <= start.steps:
        what = "--timesteps" if timesteps is not None else "its n_timesteps"
        raise ValueError(f"{run_dir} has trained {start.steps} steps ({start.model.relative_to(run_dir)}) and {what} "
                         f"is {total}: nothing left to train; pass --timesteps above {start.steps} to train it further")
    if total != config.n_timesteps:
        config = dataclasses.replace(config, n_timesteps=total)
        save_config(config, run_dir, prog)
    return _learn(config, run_dir, start, progress_bar=progress_bar, verbose=verbose, prog=prog,
                  max_minutes=max_minutes, eval_freq=eval_freq, eval_episodes=eval_episodes)


def _learn(config: RunConfig, run_dir: Path, start: Checkpoint | None, *, progress_bar: bool, verbose: int,
           prog: str, max_minutes: float | None, eval_freq: int, eval_episodes: int) -> Path:
    """Train from scratch (``start`` None) or on from ``start``; save; raise :class:`Interrupted` when a signal
    stopped it."""
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from .callbacks import RewardTermsCallback

    set_num_threads(config)
    cls = algo_class(config.algo)
    done = 0 if start is None else start.steps
    seed = config.seed + done
    monitor_dir = run_dir / "monitor" if start is None else run_dir / "monitor" / f"resumed_{done}"
    env = make_vec_env(dataclasses.replace(config, seed=seed), monitor_dir=monitor_dir)
    notes = []
    if start is not None and start.vecnormalize is not None:
        env = VecNormalize.load(str(start.vecnormalize), env)
        env.training = True
    elif config.normalize is not None:
        if start is not None:
            notes.append(f"no VecNormalize statistics beside {start.model.name}: they start anew")
        env = VecNormalize(env, **config.normalize)
    stop = None
    try:
        if start is None:
            model = cls(env=env, seed=config.seed, device=config.device, verbose=verbose,
                        tensorboard_log=str(run_dir / "tb"), **algo_kwargs(config))
        else:
            # force_reset: the envs were just made; SB3 would otherwise step on from the saved last observation
            model = cls.load(start.model, env=env, device=config.device, force_reset=True, verbose=verbose,
                             tensorboard_log=str(run_dir / "tb"))
            model.set_random_seed(seed)
            if start.replay_buffer is not None:
                model.load_replay_buffer(start.replay_buffer)
                notes.append(f"replay buffer of {model.replay_buffer.size()} transitions loaded")
            elif getattr(model, "replay_buffer", None) is not None:
                notes.append("no replay buffer saved with it: it fills anew")
        callbacks = [RewardTermsCallback()]
        if eval_freq > 0:
            callbacks.append(_eval_callback(config, run_dir, eval_freq, eval_episodes, env, verbose,
                                            resumed=start is not None))
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
        stop = _SignalStop()
        callbacks.append(stop.callback())
        what = "" if start is None else f"resuming from {start.model.relative_to(run_dir)} at {done} steps, "
        print(f"training {config.algo.upper()} on {config.env_id}: {what}{config.n_timesteps} steps, "
              f"{config.n_envs} env(s), seed {seed} -> {run_dir}" + "".join(f"\n  {n}" for n in notes), flush=True)
        begin = time.perf_counter()
        with stop:
            try:
                model.learn(total_timesteps=config.n_timesteps - model.num_timesteps, callback=callbacks,
                            progress_bar=progress_bar, tb_log_name=config.algo.upper(),
                            reset_num_timesteps=start is None)
            except KeyboardInterrupt:                # a second signal, or Ctrl-C outside the main thread's handler
                stop.signum = stop.signum or signal.SIGINT
            except (EOFError, BrokenPipeError, ConnectionResetError):
                if stop.signum is None:
                    raise
                # Ctrl-C in a terminal reaches --vec-env subproc workers too, which end: the model and the
                # VecNormalize statistics live in this process and are saved all the same
            elapsed = time.perf_counter() - begin
            model_path = run_dir / MODEL_FILENAME
            model.save(model_path)
            if isinstance(env, VecNormalize):
                env.save(str(run_dir / VECNORMALIZE_FILENAME))
            saved = _save_checkpoint(model, env, run_dir) if stop.signum is not None else None
    finally:
        try:
            env.close()
        except (EOFError, BrokenPipeError, ConnectionResetError):
            if stop is None or stop.signum is None:     # (workers a signal ended: nothing left to close)
                raise
    steps = model.num_timesteps - done
    print(f"{steps} steps in {elapsed:.1f} s ({steps / max(elapsed, 1e-9):.0f} steps/s), {model.num_timesteps} in "
          f"all; saved {model_path}", flush=True)
    if saved is not None:
        name = signal.Signals(stop.signum).name
        files = ", ".join(str(p.relative_to(run_dir)) for p in saved.files())
        message = (f"interrupted by {name} at {model.num_timesteps} of {config.n_timesteps} steps: saved {files} "
                   f"in {run_dir}\nresume with: {prog} train --resume {run_dir}")
        print(message, flush=True)
        raise Interrupted(stop.signum, saved, message)
    print(f"evaluate with: {prog} evaluate --run {run_dir}\nfor rl-zoo3's enjoy: {prog} zoo --run {run_dir} -f logs",
          flush=True)
    return model_path


def _save_checkpoint(model, env, run_dir: Path) -> Checkpoint:
    """The interrupted run's checkpoint, named as SB3's CheckpointCallback names them (:func:`.runs.checkpoint_paths`):
    the model, the VecNormalize statistics, and an off-policy replay buffer of at most
    :data:`REPLAY_BUFFER_MAX_BYTES`."""
    from stable_baselines3.common.vec_env import VecNormalize

    paths = checkpoint_paths(run_dir, model.num_timesteps)
    paths.model.parent.mkdir(parents=True, exist_ok=True)
    model.save(paths.model)
    vecnormalize = replay = None
    if isinstance(env, VecNormalize):
        env.save(str(paths.vecnormalize))
        vecnormalize = paths.vecnormalize
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None:
        size = _nbytes(buffer)
        if size <= REPLAY_BUFFER_MAX_BYTES:
            model.save_replay_buffer(paths.replay_buffer)
            replay = paths.replay_buffer
        else:
            print(f"replay buffer not saved ({size / 2 ** 20:.0f} MiB > {REPLAY_BUFFER_MAX_BYTES / 2 ** 20:.0f} MiB): "
                  "a resumed run fills it anew", flush=True)
    return Checkpoint(model.num_timesteps, paths.model, vecnormalize, replay)


def _nbytes(buffer) -> int:
    """Bytes of the numpy arrays of an SB3 replay buffer (dict observations included)."""
    import numpy as np

    total = 0
    for value in vars(buffer).values():
        for a in (value.values() if isinstance(value, dict) else (value,)):
            if isinstance(a, np.ndarray):
                total += a.nbytes
    return total
