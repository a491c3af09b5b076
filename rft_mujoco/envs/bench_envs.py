"""Env steps per second of every sand task and of the plain Gymnasium envs they are built on.

Run ``python -m rft_mujoco.envs.bench_envs [--steps N] [--ids ID ...]``; prints a table. Each env is
reset with seed 0, warmed up for 20 steps, then timed over ``--steps`` uniformly random actions
(resetting on termination or truncation). Numbers are wall-clock on one core of this machine.
"""

from __future__ import annotations

import argparse
import sys
import time

import gymnasium

from rft_mujoco.tables import Columns

from . import ENV_IDS

PLAIN_IDS = ("Ant-v5", "HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Humanoid-v5")
"""The Gymnasium envs the wrapped sand ids are built on (timed for comparison)."""

WARMUP_STEPS = 20


def steps_per_second(env_id: str, steps: int, seed: int = 0) -> dict:
    """Time ``steps`` random-action steps of ``env_id``; returns a row of the table."""
    env = gymnasium.make(env_id)
    try:
        env.action_space.seed(seed)
        env.reset(seed=seed)
        for _ in range(WARMUP_STEPS):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        resets = 0
        start = time.perf_counter()
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
                resets += 1
        elapsed = time.perf_counter() - start
        sand = getattr(env.unwrapped, "sand", None)
        return {"id": env_id, "obs": env.observation_space.shape[0], "act": env.action_space.shape[0],
                "elements": sand.handle.n_elements if sand is not None else 0,
                "dt_s": env.unwrapped.dt, "steps_per_s": steps / elapsed,
                "realtime": steps * env.unwrapped.dt / elapsed, "resets": resets}
    finally:
        env.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco.envs.bench_envs", description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="timed steps per env (default 300)")
    parser.add_argument("--ids", nargs="*", default=None,
                        help=f"env ids (default: all sand ids and {', '.join(PLAIN_IDS)})")
    args = parser.parse_args(argv)
    if args.steps <= 0:
        parser.error(f"--steps must be > 0, got {args.steps}")
    ids = args.ids or [*ENV_IDS, *PLAIN_IDS]
    unknown = [i for i in ids if i not in gymnasium.registry]
    if unknown:
        parser.error(f"unknown env ids {unknown}; registered sand ids: {sorted(ENV_IDS)}")
    columns = Columns(["env id", "obs", "act", "elements", "dt (s)", "steps/s", "x realtime"],
                      widths=[max(map(len, ids)), 4, 4, 8, 7, 8, 10])
    print(columns.header())
    for env_id in ids:
        row = steps_per_second(env_id, args.steps)
        print(columns.row([row["id"], row["obs"], row["act"], row["elements"], f"{row['dt_s']:.3f}",
                           f"{row['steps_per_s']:.0f}", f"{row['realtime']:.2f}"]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
