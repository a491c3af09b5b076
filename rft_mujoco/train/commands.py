"""Command tracking of a run: forward speed and yaw rate against the commanded ones, falls and sinkage.

For envs that take a velocity command at reset (``env.reset(options={"command": (vx, vy, yaw_rate)})``,
as ``rft_mujoco/SandQuadruped-v1``): each policy (the trained one, the zero action, uniform random
actions) runs ``episodes`` episodes per command from the same seeds; per (policy, command) the table has
the mean forward speed (``info["x_velocity"]``, trunk velocity along its heading, m/s) and yaw rate
(``info["yaw_rate"]``, rad/s) after the first :data:`SETTLE_S` seconds, the falls (terminated episodes),
the sinkage (the deepest loaded sand element of the robot, m, mean over the steps) and the return.

``ground`` evaluates on another floor than the run was trained on (``env_kwargs`` ``ground="rigid"`` or
``"sand"``): the sand gap is the trained policy of one ground evaluated on the other
(:func:`gap_table`, ``python -m rft_mujoco.train gap``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rft_mujoco.tables import Columns, table

from .config import deep_update, load_config, set_num_threads
from .environments import make_env
from .policies import EVAL_SEED_OFFSET, load_policy, zero_action
from .runs import check_free, find_run

COMMANDS = ((0.2, 0.0, 0.0), (0.4, 0.0, 0.0), (0.6, 0.0, 0.0), (0.3, 0.0, 0.4))
"""Default commands (vx m/s, vy m/s, yaw rate rad/s): three forward speeds and a turn."""
SETTLE_S = 1.0
"""s: the start of each episode (standing up, the gait starting) is left out of the mean speeds."""
STEPS = 500
"""Env steps per episode (10 s of SandQuadruped-v1)."""


def takes_commands(env) -> bool:
    """Whether the env has a velocity command set at reset (``options={"command": ...}``)."""
    return hasattr(env.unwrapped, "command") and "x_velocity" in _probe_info(env)


def _probe_info(env) -> dict:
    env.reset(seed=0)
    info = env.step(env.action_space.sample())[-1]
    return info


def _episode(env, act, seed: int, command, steps: int) -> dict[str, float]:
    obs, _ = env.reset(seed=seed, options={"command": tuple(command)})
    settle = min(int(round(SETTLE_S / env.unwrapped.dt)), steps // 2)
    vx, yaw, depth, total, fell = [], [], [], 0.0, False
    for i in range(steps):
        obs, reward, terminated, truncated, info = env.step(act(obs))
        total += float(reward)
        if i >= settle:
            vx.append(float(info["x_velocity"]))
            yaw.append(float(info["yaw_rate"]))
        sinkage = info.get("sand_sinkage")
        depth.append(float(np.max(sinkage)) if sinkage is not None and np.size(sinkage) else 0.0)
        if terminated:
            fell = True
            break
        if truncated:
            break
    return {"vx": float(np.mean(vx)) if vx else float("nan"), "yaw": float(np.mean(yaw)) if yaw else float("nan"),
            "fell": fell, "sinkage": float(np.mean(depth)), "return": total}


def command_table(run_dir: str | Path, *, commands: Sequence[Sequence[float]] = COMMANDS, episodes: int = 3,
                  steps: int = STEPS, ground: str | None = None, seed: int | None = None,
                  baselines: bool = True, env_kwargs: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """Rows (policy, command, vx, yaw, falls, sinkage, return) of the run in ``run_dir`` (see the module
    docstring); ``env_kwargs`` go on top of the run's own, ``ground`` overrides the env's ``ground``
    argument. Prints progress per row."""
    run_dir = find_run(run_dir)
    config = load_config(run_dir)
    set_num_threads(config)
    kwargs = deep_update(config.env_kwargs, env_kwargs or {})
    if ground is not None:
        kwargs["ground"] = ground
    steps = min(steps, int(kwargs.pop("max_episode_steps", steps)))
    env = make_env(config.env_id, {**kwargs, "max_episode_steps": steps})
    try:
        if not takes_commands(env):
            raise ValueError(f"{config.env_id} takes no velocity command at reset (options={{'command': ...}}); "
                             "the command table needs an env such as rft_mujoco/SandQuadruped-v1")
        trained, _ = load_policy(config, run_dir, env)
        policies = {"trained": trained}
        if baselines:
            zero = zero_action(env.action_space)
            policies["zero"] = lambda obs: zero
            policies["random"] = lambda obs: env.action_space.sample()
        seed = config.seed + EVAL_SEED_OFFSET if seed is None else int(seed)
        rows = []
        for name, act in policies.items():
            env.action_space.seed(seed)
            for command in commands:
                eps = [_episode(env, act, seed + i, command, steps) for i in range(episodes)]
                row = {"policy": name, "ground": kwargs.get("ground", "sand"), "command": list(map(float, command)),
                       "vx": float(np.nanmean([e["vx"] for e in eps])), "yaw": float(np.nanmean([e["yaw"] for e in eps])),
                       "falls": int(sum(e["fell"] for e in eps)), "episodes": episodes,
                       "sinkage_m": float(np.mean([e["sinkage"] for e in eps])),
                       "return": float(np.mean([e["return"] for e in eps]))}
                rows.append(row)
                print(format_rows([row], header=not rows[:-1]), flush=True)
    finally:
        env.close()
    return rows


COMMAND_COLUMNS = Columns(["policy", "ground", "command vx, yaw", "vx m/s", "yaw rad/s", "falls", "sinkage mm",
                           "return"], widths=[7, 6, 15, 7, 9, 5, 10, 8], align="<<>>>>>>")
"""The command table's columns, fixed so that :func:`command_table` prints each row as it is measured."""


def format_rows(rows: Sequence[dict], header: bool = True) -> str:
    """Table lines of :func:`command_table` rows (:data:`COMMAND_COLUMNS`), with the header when ``header``."""
    lines = [COMMAND_COLUMNS.header()] if header else []
    lines += [COMMAND_COLUMNS.row([r["policy"], r["ground"], f"{r['command'][0]:.2f}, {r['command'][2]:.2f}",
                                   f"{r['vx']:.3f}", f"{r['yaw']:.3f}", f"{r['falls']}/{r['episodes']}",
                                   f"{1000 * r['sinkage_m']:.1f}", f"{r['return']:.1f}"]) for r in rows]
    return "\n".join(lines)


def gap_table(sand_run: str | Path, rigid_run: str | Path, *, command=(0.4, 0.0, 0.0), episodes: int = 3,
              steps: int = STEPS, out: str | Path | None = None, overwrite: bool = False) -> list[dict[str, Any]]:
    """The sand gap: the policy trained on sand and the one trained on rigid ground, each evaluated on
    both grounds at one command; rows with ``trained_on``. Writes ``out`` (JSON) when given (an existing
    file only with ``overwrite``)."""
    if out is not None:
        check_free([out], overwrite=overwrite)
    rows = []
    for trained_on, run in (("sand", sand_run), ("rigid", rigid_run)):
        for ground in ("sand", "rigid"):
            (row,) = command_table(run, commands=[command], episodes=episodes, steps=steps, ground=ground,
                                   baselines=False)
            rows.append({**row, "trained_on": trained_on})
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(rows, indent=2) + "\n")
    return rows


def format_gap(rows: Sequence[dict]) -> str:
    """The table of :func:`gap_table` rows."""
    return table(["trained on", "evaluated on", "vx m/s", "falls", "sinkage mm", "return"],
                 [[r["trained_on"], r["ground"], f"{r['vx']:.3f}", f"{r['falls']}/{r['episodes']}",
                   f"{1000 * r['sinkage_m']:.1f}", f"{r['return']:.1f}"] for r in rows], align="<<>>>>")
