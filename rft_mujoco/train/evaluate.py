"""Evaluate a run rebuilt from its ``config.yaml`` alone (rl-zoo3's "enjoy" pattern).

Three policies run over the same episode seeds (episode ``i`` resets with ``seed + i``):

- ``trained``: the saved model, deterministic by default, observations normalized with the run's
  saved VecNormalize statistics (frozen) when the run normalized;
- ``random``:  uniform samples of the action space (its RNG seeded with ``seed``);
- ``zero``:    the zero action (clipped into the action bounds), i.e. a limp robot.

Per policy: mean and standard deviation of the episode return (raw env reward, never normalized), mean
episode length and, when the env's ``info`` has a forward speed (first of :data:`SPEED_KEYS`), the mean
over episodes of the per-episode mean forward speed. Writes ``eval.json``, ``eval.png`` (bar charts and
the learning curve from the run's Monitor CSVs) and ``video.mp4`` (one trained episode rendered with
``render_mode="rgb_array"`` from a camera that follows the robot: the env's own camera when it names
one, else MuJoCo's tracking camera on the root body, :func:`rft_mujoco.envs.camera.track_body`; skipped
with a message when offscreen rendering or mp4 writing fails).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rft_mujoco.tables import table

from .config import RunConfig, deep_update, load_config, set_num_threads
from .environments import check_env_id, make_env
from .policies import EVAL_SEED_OFFSET, Policy, load_policy, zero_action
from .runs import check_free, default_out, find_run

SPEED_KEYS = ("x_velocity", "forward_speed")
DEFAULT_MAX_STEPS = 1000  # episode cap for envs registered without a time limit
JSON_FILENAME = "eval.json"
PLOT_FILENAME = "eval.png"
VIDEO_FILENAME = "video.mp4"

def rollout(env, act: Policy, seed: int, *, max_steps: int) -> dict[str, Any]:
    """One episode from ``env.reset(seed=seed)``: return, length and mean forward speed (None if absent)."""
    obs, _ = env.reset(seed=seed)
    total, steps, speeds, key = 0.0, 0, [], None
    while steps < max_steps:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        total += float(reward)
        steps += 1
        key = key or next((k for k in SPEED_KEYS if k in info), None)
        if key is not None and key in info:
            speeds.append(float(info[key]))
        if terminated or truncated:
            break
    return {"return": total, "length": steps, "speed": float(np.mean(speeds)) if speeds else None,
            "speed_key": key}


def _summary(episodes: Sequence[dict]) -> dict[str, Any]:
    returns = np.array([e["return"] for e in episodes])
    speeds = [e["speed"] for e in episodes if e["speed"] is not None]
    return {
        "return_mean": float(returns.mean()),
        "return_std": float(returns.std()),
        "length_mean": float(np.mean([e["length"] for e in episodes])),
        "speed_mean": float(np.mean(speeds)) if speeds else None,
        "speed_std": float(np.std(speeds)) if speeds else None,
        "returns": returns.tolist(),
        "lengths": [e["length"] for e in episodes],
        "speeds": speeds,
    }


def record_video(config: RunConfig, act: Policy, seed: int, path: str | Path, *,
                 max_frames: int) -> tuple[Path | None, str]:
    """Render one episode of ``act`` to ``path`` (mp4; GIF when no mp4 writer); (path or None, message).

    MuJoCo envs that render from Gymnasium's free camera get a tracking camera on their root body."""
    from rft_mujoco.envs.camera import track_body

    try:
        env = make_env(config.env_id, config.env_kwargs, render_mode="rgb_array")
    except Exception as err:  # noqa: BLE001 (any failure here only costs the video)
        return None, f"video skipped: the env cannot be made with render_mode='rgb_array' ({err})"
    frames = []
    try:
        track_body(env)  # a free camera (Gymnasium's default) would stay where the robot started
        obs, _ = env.reset(seed=seed)
        frames.append(env.render())
        for _ in range(max_frames - 1):
            obs, _, terminated, truncated, _ = env.step(act(obs))
            frames.append(env.render())
            if terminated or truncated:
                break
        fps = float(env.metadata.get("render_fps") or 30)
    except Exception as err:  # noqa: BLE001
        return None, (f"video skipped: offscreen rendering failed ({type(err).__name__}: {err}); for MuJoCo "
                      "envs on a headless machine set MUJOCO_GL=egl (GPU) or MUJOCO_GL=osmesa (CPU)")
    finally:
        env.close()
    if not frames or frames[0] is None:
        return None, "video skipped: env.render() returned no frame"
    import imageio.v2 as imageio

    path = Path(path)
    try:
        imageio.mimsave(path, frames, fps=fps, macro_block_size=1)
        return path, f"video: {path} ({len(frames)} frames at {fps:.0f} fps)"
    except Exception as err:  # noqa: BLE001 (no ffmpeg backend)
        path.unlink(missing_ok=True)
        gif = path.with_suffix(".gif")
        try:
            imageio.mimsave(gif, frames, duration=1000.0 / fps, loop=0)
        except Exception as err2:  # noqa: BLE001
            return None, f"video skipped: cannot write {path} ({err}) nor {gif} ({err2})"
        return gif, (f"video: {gif} ({len(frames)} frames); mp4 needs an ffmpeg backend "
                     f"(pip install imageio-ffmpeg): {type(err).__name__}")


def plot_evaluation(results: dict, run_dir: str | Path, out: str | Path, *, window: int = 10) -> Path:
    """Bar charts of return (and forward speed) per policy, plus the run's learning curve if logged."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plot import load_monitor, plot_learning_curves

    policies = results["policies"]
    names = list(policies)
    has_speed = results["speed_key"] is not None
    has_curve = load_monitor(run_dir)["returns"].size > 0
    ncols = 1 + has_speed + has_curve
    fig, axes = plt.subplots(1, ncols, figsize=(4.5 * ncols, 4.2), squeeze=False)
    axes = list(axes[0])
    panels = [("return", "episode return")] + ([("speed", f"forward speed (info['{results['speed_key']}'])")]
                                               if has_speed else [])
    for ax, (key, label) in zip(axes, panels):
        means = [policies[n][f"{key}_mean"] or 0.0 for n in names]
        stds = [policies[n][f"{key}_std"] or 0.0 for n in names]
        ax.bar(names, means, yerr=stds, capsize=4, color=["C0", "C7", "C3"][: len(names)], alpha=0.8)
        for i, n in enumerate(names):
            values = policies[n][f"{key}s"]
            ax.plot(np.full(len(values), i), values, "k.", alpha=0.4, ms=4)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(label)
        ax.set_title(f"{label.split(' (')[0]}: mean ± std over {results['episodes']} episodes", fontsize="medium")
    if has_curve:
        plot_learning_curves(axes[-1], [run_dir], window=window)
    fig.suptitle(f"{results['env_id']} {results['algo'].upper()} ({Path(results['model']).name})")
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def format_table(results: dict) -> str:
    """The per-policy numbers as a table."""
    key = results["speed_key"]
    rows = []
    for name, s in results["policies"].items():
        row = [name, f"{s['return_mean']:.3f} ± {s['return_std']:.3f}", f"{s['length_mean']:.1f}"]
        if key:
            row.append(f"{s['speed_mean']:.4f} ± {s['speed_std']:.4f}" if s["speed_mean"] is not None else "-")
        rows.append(row)
    return table(["policy", "return mean ± std", "length"] + ([f"speed ({key})"] if key else []), rows)


def evaluate(run_dir: str | Path, *, episodes: int = 10, seed: int | None = None,
             model_path: str | Path | None = None, out_dir: str | Path | None = None,
             deterministic: bool = True, video: bool = True, max_video_frames: int = 1000,
             window: int = 10, commands: bool = True, overwrite: bool = False,
             env_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Evaluate the run in ``run_dir`` against random and zero-action baselines; returns the results dict.

    Args:
        run_dir: run directory holding ``config.yaml`` and ``model.zip``, or the name of a shipped run
            (``"SandQuadruped-v1"``, :func:`.runs.find_run`).
        episodes: episodes per policy.
        seed: episode ``i`` resets with ``seed + i``; default: training seed + :data:`EVAL_SEED_OFFSET`.
        model_path: a checkpoint instead of ``run_dir/model.zip``.
        out_dir: where to write eval.json, eval.png and the video; default ``./out/eval/<run name>``
            (never the run folder).
        deterministic: act with the policy's mean/mode action.
        video: render one trained episode (seed ``seed``) to ``out_dir/video.mp4``.
        max_video_frames: frame cap of the video.
        window: moving-average window of the learning curve.
        commands: for an env with a velocity command (SandQuadruped-v1), also the command-tracking table
            of :func:`.commands.command_table` (forward speed against command, falls, sinkage).
        overwrite: replace existing eval.json, eval.png and video in ``out_dir`` (FileExistsError otherwise).
        env_kwargs: keyword arguments of ``gymnasium.make`` on top of the run's own (e.g. ``{"solve":
            "implicit"}``: the policy under the other sand solve); recorded in eval.json.
    """
    from tqdm.auto import tqdm

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    run_dir = find_run(run_dir)
    config = load_config(run_dir)
    if env_kwargs:
        config = dataclasses.replace(config, env_kwargs=deep_update(config.env_kwargs, env_kwargs))
    check_env_id(config.env_id)
    set_num_threads(config)
    out = Path(out_dir) if out_dir is not None else default_out("eval", run_dir)
    check_free([out / JSON_FILENAME, out / PLOT_FILENAME] + ([out / VIDEO_FILENAME] if video else []),
               overwrite=overwrite)
    out.mkdir(parents=True, exist_ok=True)
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else int(seed)
    seeds = [seed + i for i in range(episodes)]

    env = make_env(config.env_id, config.env_kwargs)
    max_steps = (env.spec.max_episode_steps if env.spec is not None else None) or DEFAULT_MAX_STEPS
    trained, path = load_policy(config, run_dir, env, model_path=model_path, deterministic=deterministic)
    policies: dict[str, Policy] = {"trained": trained, "random": lambda obs: env.action_space.sample()}
    zero = zero_action(env.action_space)
    if zero is not None:
        policies["zero"] = lambda obs: zero
    else:
        print(f"zero-action baseline skipped: no zero action for {env.action_space}")

    summaries, speed_key = {}, None
    bar = tqdm(total=episodes * len(policies), desc="evaluating", unit="episode")
    try:
        for name, act in policies.items():
            start = time.perf_counter()
            env.action_space.seed(seed)  # the random baseline's actions are reproducible
            episodes_out = []
            for s in seeds:
                episodes_out.append(rollout(env, act, s, max_steps=max_steps))
                bar.update()
            speed_key = speed_key or next((e["speed_key"] for e in episodes_out if e["speed_key"]), None)
            summaries[name] = {**_summary(episodes_out), "seconds": time.perf_counter() - start}
    finally:
        bar.close()
        env.close()

    results: dict[str, Any] = {
        "run": str(run_dir), "env_id": config.env_id, "algo": config.algo, "model": str(path),
        "env_kwargs": config.env_kwargs, "episodes": episodes, "seeds": seeds,
        "deterministic": deterministic, "max_steps": max_steps, "speed_key": speed_key,
        "policies": summaries,
    }
    if speed_key is None:
        print(f"no forward speed: the env's info has none of {list(SPEED_KEYS)}")
    if video:
        video_path, message = record_video(config, trained, seeds[0], out / VIDEO_FILENAME,
                                           max_frames=max_video_frames)
    else:
        video_path, message = None, "video skipped (--no-video)"
    results["video"] = None if video_path is None else str(video_path)
    results["video_message"] = message
    results["plot"] = str(plot_evaluation(results, run_dir, out / PLOT_FILENAME, window=window))
    if commands:
        from .commands import command_table, takes_commands

        probe = make_env(config.env_id, config.env_kwargs)
        try:
            has_commands = takes_commands(probe)
        finally:
            probe.close()
        if has_commands:
            print("command tracking (mean over episodes after the first second):")
            results["commands"] = command_table(run_dir, episodes=min(episodes, 3), seed=seed,
                                                env_kwargs=env_kwargs)
    json_path = out / JSON_FILENAME
    json_path.write_text(json.dumps(results, indent=2) + "\n")
    results["json"] = str(json_path)
    print(f"{config.env_id} {config.algo.upper()} {path} ({episodes} episodes, seeds {seeds[0]}..{seeds[-1]}, "
          f"{'deterministic' if deterministic else 'stochastic'} policy)")
    print(format_table(results))
    print(message)
    print(f"wrote {json_path} and {results['plot']}")
    return results
