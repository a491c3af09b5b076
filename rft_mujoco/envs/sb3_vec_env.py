"""A Stable-Baselines3 ``VecEnv`` over a batched sand task (:class:`~.sand_quadruped_warp.BatchedSandQuadruped`).

``SB3VecEnv(BatchedSandQuadruped(4096, device="cuda:0"))`` steps every world at once; SB3's algorithms see
``num_envs`` environments with SB3's conventions: ``dones = terminated | truncated``, the worlds that reset
carry ``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]``. Wrap it in ``VecMonitor`` for
episode statistics. Needs stable-baselines3 (the ``train`` extra).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv


class SB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` adapter. ``sim``: an object with ``num_envs``, ``single_observation_space``,
    ``single_action_space``, ``reset(seed=, options=) -> (obs, info)`` and ``step(actions) -> (obs, reward,
    terminated, truncated, info)`` with same-step auto-reset (``info["final_obs"]`` for the worlds that reset)."""

    def __init__(self, sim) -> None:
        self.sim = sim
        super().__init__(sim.num_envs, sim.single_observation_space, sim.single_action_space)
        self._actions = None
        self._seed = None

    def reset(self):
        obs, _ = self.sim.reset(seed=self._seed)
        self._seed = None
        return obs

    def seed(self, seed: int | None = None):
        self._seed = seed
        return [seed] * self.num_envs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.sim.step(self._actions)
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        final = info.get("final_obs")
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = final[i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.sim.close()

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.sim, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        if indices is not None and len(self._indices(indices)) != self.num_envs:
            raise ValueError(f"the worlds of a batched task share attributes; set {attr_name!r} for all worlds "
                             "(indices=None)")
        setattr(self.sim, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = getattr(self.sim, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]
