"""SandQuadruped on MuJoCo Warp: ``num_envs`` quadrupeds on sand stepped together (needs ``rft_mujoco[warp]``).

The task of :class:`~.sand_quadruped_v0.SandQuadrupedEnv` (``rft_mujoco/SandQuadruped-v0``) -- same model,
sand bed, action, observation, reward terms, termination and reset -- batched over worlds:

* :class:`BatchedSandQuadruped`: the simulation and task with numpy in and out, same-step auto-reset;
* :class:`SandQuadrupedVectorEnv`: a ``gymnasium.vector.VectorEnv`` over it (``autoreset_mode`` SAME_STEP:
  ``info["final_obs"]`` / ``info["final_info"]`` hold the last step of the worlds that reset);
* :class:`rft_mujoco.envs.sb3_vec_env.SB3VecEnv`: the Stable-Baselines3 ``VecEnv`` adapter.

Where users find it: ``rft_mujoco.envs.make_batched_sand_quadruped(num_envs, device=...)``, or gymnasium's
vector entry point of ``rft_mujoco/SandQuadruped-v0``: ``gymnasium.make_vec("rft_mujoco/SandQuadruped-v0",
num_envs=N, vectorization_mode="vector_entry_point", device="cuda:0")`` (both give a
:class:`SandQuadrupedVectorEnv`; keywords go to :class:`BatchedSandQuadruped`).

The reward is pluggable: ``reward=`` takes any object with ``weights`` (name -> float) and
``terms(state: QuadrupedState) -> {name: (num_envs,) array}`` (unweighted); the default
:class:`QuadrupedRewardV0` computes v0's terms. Per-world commands (drawn at each reset from
``command_ranges``, or ``set_command``) and media (``media_ranges``: a new medium per world per episode;
no recompilation). Physics: MuJoCo Warp in float32, sand by :func:`rft_mujoco.warp.attach`; observations
and rewards in numpy (one host copy of qpos, qvel and the sand's sinkage per env step).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import mujoco
import mujoco_warp as mjw
import numpy as np
import warp as wp
from gymnasium.spaces import Box
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

import rft_mujoco.warp as rw
from rft_mujoco.physics.media import Media, get_media
from rft_mujoco.models.quadruped import FOOT_BODIES

from .sand_bed import FEATURES_PER_BODY, MediaRanges, compile_sand_model, surface_of
from .sand_quadruped_v0 import DEFAULT_COMMAND_RANGES, DEFAULT_REWARD_WEIGHTS
from .sand_task import model_path

MAX_EPISODE_STEPS = 1000
"""Truncation of every world's episode (v0's registered TimeLimit: 20 s at 20 ms per step)."""


@dataclasses.dataclass(frozen=True)
class QuadrupedState:
    """What a reward sees after an env step (W worlds; arrays, world axis first).

    Attributes:
        qpos: (W, 19), qvel: (W, 18) MuJoCo state. rot: (W, 3, 3) trunk orientation (world <- trunk).
        height: (W,) m, trunk above the sand surface. v_heading: (W, 2) m/s planar trunk velocity in the
        heading frame. yaw_rate: (W,) rad/s. action, last_action: (W, 12). command: (W, 3).
        sinkage: (W, B) m per sand body. sand_force: (W, B, 3) N. healthy: (W,) bool.
    """

    qpos: np.ndarray
    qvel: np.ndarray
    rot: np.ndarray
    height: np.ndarray
    v_heading: np.ndarray
    yaw_rate: np.ndarray
    action: np.ndarray
    last_action: np.ndarray
    command: np.ndarray
    sinkage: np.ndarray
    sand_force: np.ndarray
    healthy: np.ndarray


class QuadrupedRewardV0:
    """The reward of SandQuadruped-v0, vectorized (same terms and default weights, see its docstring)."""

    default_weights = DEFAULT_REWARD_WEIGHTS

    def __init__(self, weights: dict[str, float] | None = None, tracking_sigma: float = 0.25) -> None:
        unknown = set(weights or {}) - set(self.default_weights)
        if unknown:
            raise ValueError(f"unknown reward weights {sorted(unknown)}; valid names: {sorted(self.default_weights)}")
        self.weights = {**self.default_weights, **(weights or {})}
        self.tracking_sigma = float(tracking_sigma)

    def terms(self, s: QuadrupedState) -> dict[str, np.ndarray]:
        sigma = self.tracking_sigma
        return {
            "tracking_lin_vel": np.exp(-np.sum(np.square(s.v_heading - s.command[:, :2]), axis=1) / sigma),
            "tracking_ang_vel": np.exp(-np.square(s.yaw_rate - s.command[:, 2]) / sigma),
            "upright": s.rot[:, 2, 2],
            "healthy": s.healthy.astype(float),
            "lin_vel_z": -np.square(s.qvel[:, 2]),
            "ang_vel_xy": -np.sum(np.square(s.qvel[:, 3:5]), axis=1),
            "ctrl": -np.sum(np.square(s.action), axis=1),
            "action_rate": -np.sum(np.square(s.action - s.last_action), axis=1),
            "sinkage": -np.sum(s.sinkage, axis=1),
        }


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(W, 3, 3) rotation matrices of (W, 4) unit quaternions (w, x, y, z), as mju_quat2Mat."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)


class BatchedSandQuadruped:
    """``num_envs`` SandQuadruped-v0 tasks in one MuJoCo Warp Data (numpy API, same-step auto-reset).

    Args (those of SandQuadrupedEnv, plus):
        num_envs: worlds.
        reward: the reward (default :class:`QuadrupedRewardV0` with ``reward_weights``/``tracking_sigma``).
        max_episode_steps: truncation (default 1000, as v0's registration).
        device: warp device (default: warp's preferred one).
        nconmax, njmax: MuJoCo Warp's contact and constraint capacity per world.
        use_graph: on CUDA, record the ``frame_skip`` physics steps in a CUDA graph (replayed each env step).
        solve: the sand solve, "explicit" (default) or "implicit" (:func:`rft_mujoco.warp.attach`), as the CPU
            tasks' ``solve``.
        seed: of the generator that draws resets, commands and media.
    """

    def __init__(self, num_envs: int, *, xml_file: str = "quadruped.xml", frame_skip: int = 10,
                 reward=None, reward_weights: dict[str, float] | None = None, tracking_sigma: float = 0.25,
                 command_ranges: Sequence[tuple[float, float]] = DEFAULT_COMMAND_RANGES,
                 action_scale_rad: float = 0.5, terminate_when_unhealthy: bool = True, min_height_m: float = 0.12,
                 min_upright: float = 0.5, reset_noise_scale: float = 0.05, media: Media | str = "li_loose_glass_beads",
                 resolution: str | float = "default", bed_depth_m: float | None = 0.05,
                 sand_bodies: Sequence[str] = FOOT_BODIES, media_ranges: MediaRanges | None = None,
                 include_sand_in_observation: bool = False, max_episode_steps: int = MAX_EPISODE_STEPS,
                 device: str | None = None, nconmax: int = 24, njmax: int = 128, use_graph: bool = True,
                 seed: int | None = None, solve: str = "explicit") -> None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        ranges = np.asarray(command_ranges, dtype=float)
        if ranges.shape != (3, 2) or np.any(ranges[:, 0] > ranges[:, 1]):
            raise ValueError(f"command_ranges must be 3 (low, high) pairs with low <= high for (vx m/s, vy m/s, "
                             f"yaw rate rad/s), got {command_ranges!r}")
        if media_ranges is not None and not isinstance(media_ranges, MediaRanges):
            raise TypeError(f"media_ranges must be a MediaRanges or None, got {type(media_ranges).__name__}")
        self.num_envs = int(num_envs)
        self.frame_skip = int(frame_skip)
        self.reward = reward if reward is not None else QuadrupedRewardV0(reward_weights, tracking_sigma)
        self._command_ranges = ranges
        self._action_scale = float(action_scale_rad)
        self._terminate = bool(terminate_when_unhealthy)
        self._min_height, self._min_upright = float(min_height_m), float(min_upright)
        self._noise = float(reset_noise_scale)
        self.base_media = get_media(media)
        self.media_ranges = media_ranges
        self._include_sand = bool(include_sand_in_observation)
        self.max_episode_steps = int(max_episode_steps)
        self.rng = np.random.default_rng(seed)
        self.device = wp.get_device(device)
        # the model of v0 (floor -> sand surface, rigid bottom), on device
        self.model, surface_geoms = compile_sand_model(model_path(xml_file), bed_depth_m)
        self.dt = self.model.opt.timestep * self.frame_skip
        self._surface_z = float(surface_of(self.model, surface_geoms))
        key = self.model.key("home")
        self._init_qpos, self._home_ctrl = key.qpos.copy(), key.ctrl.copy()
        self._ctrl_low, self._ctrl_high = self.model.actuator_ctrlrange.T.copy()
        nw = self.num_envs
        with wp.ScopedDevice(self.device):
            self.mjw_model = mjw.put_model(self.model)
            data = mujoco.MjData(self.model)
            mujoco.mj_resetDataKeyframe(self.model, data, key.id)
            self.data = mjw.put_data(self.model, data, nworld=nw, nconmax=nconmax, njmax=njmax)
            self.sand = rw.attach(self.model, self.mjw_model, self.base_media, bodies=list(sand_bodies),
                                  surface_height=self._surface_z, resolution=resolution, data=self.data,
                                  solve=solve)
        self.n_sand_bodies = self.sand.n_bodies
        obs_size = 49 + (FEATURES_PER_BODY * self.n_sand_bodies if self._include_sand else 0)
        self.single_observation_space = Box(-np.inf, np.inf, (obs_size,), np.float64)
        self.single_action_space = Box(-1.0, 1.0, (self.model.nu,), np.float32)
        self._command = np.zeros((nw, 3))
        self._last_action = np.zeros((nw, self.model.nu))
        self._steps = np.zeros(nw, dtype=np.int64)
        self._qpos = np.zeros((nw, self.model.nq))
        self._qvel = np.zeros((nw, self.model.nv))
        self._graph = None
        self._use_graph = bool(use_graph) and self.device.is_cuda
        self._ctrl_host = np.zeros((nw, self.model.nu), dtype=np.float32)
        self.render_mode = None

    # --- commands and media -----------------------------------------------------------------------------
    @property
    def command(self) -> np.ndarray:
        """(num_envs, 3) the commands: forward velocity (m/s), lateral velocity (m/s), yaw rate (rad/s)."""
        return self._command.copy()

    def set_command(self, command, worlds=None) -> None:
        """Set the command (3,) or (n, 3) of ``worlds`` (indices; None: all) for the rest of their episodes."""
        idx = np.arange(self.num_envs) if worlds is None else np.asarray(worlds, dtype=np.int64).reshape(-1)
        c = np.broadcast_to(np.asarray(command, dtype=float), (idx.size, 3))
        if not np.all(np.isfinite(c)):
            raise ValueError(f"commands must be finite (vx m/s, vy m/s, yaw rate rad/s), got {command!r}")
        self._command[idx] = c

    def media(self) -> list[Media]:
        """The medium of each world."""
        return self.sand.media(self.data)

    # --- state ------------------------------------------------------------------------------------------
    def _read_state(self) -> None:
        self._qpos[:] = self.data.qpos.numpy()
        self._qvel[:] = self.data.qvel.numpy()

    def _derived(self, action: np.ndarray, last_action: np.ndarray, fresh=None) -> QuadrupedState:
        """The state after a step; ``fresh``: worlds just reset (no sand evaluated there yet: zero sand)."""
        qpos, qvel = self._qpos, self._qvel
        rot = _quat_to_mat(qpos[:, 3:7])
        yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        vx, vy = qvel[:, 0], qvel[:, 1]
        v_heading = np.stack([c * vx + s * vy, -s * vx + c * vy], axis=1)
        yaw_rate = np.einsum("wij,wj->wi", rot, qvel[:, 3:6])[:, 2]
        height = qpos[:, 2] - self._surface_z
        finite = np.isfinite(qpos).all(axis=1) & np.isfinite(qvel).all(axis=1)
        healthy = finite & (height >= self._min_height) & (rot[:, 2, 2] >= self._min_upright)
        diag = self.sand.diagnostics(self.data)
        if fresh is not None:
            diag.max_depth[fresh] = 0.0
            diag.force[fresh] = 0.0
        return QuadrupedState(qpos.copy(), qvel.copy(), rot, height, v_heading, yaw_rate, action, last_action,
                              self._command.copy(), diag.max_depth, diag.force, healthy)

    def _obs(self, s: QuadrupedState, worlds: np.ndarray | None = None) -> np.ndarray:
        rows = slice(None) if worlds is None else worlds
        rot = s.rot[rows]
        gravity_body = -rot[:, 2, :]                       # rot^T (0, 0, -1)
        v_body = np.einsum("wji,wj->wi", rot, s.qvel[rows, :3])
        parts = [s.height[rows, None], gravity_body, v_body, s.qvel[rows, 3:6], s.qpos[rows, 7:] - self._home_ctrl,
                 s.qvel[rows, 6:], self._last_action[rows], self._command[rows]]
        if self._include_sand:
            parts.append(np.concatenate([s.sand_force[rows], s.sinkage[rows, :, None]], axis=2).reshape(
                len(rot), -1))
        return np.concatenate(parts, axis=1)

    # --- reset / step -----------------------------------------------------------------------------------
    def _reset_worlds(self, idx: np.ndarray, options: dict | None = None) -> None:
        """Reset worlds ``idx`` (v0's reset_model): medium, command, noisy home pose; qpos/qvel rows written."""
        n, nu, nv = idx.size, self.model.nu, self.model.nv
        if n == 0:
            return
        if self.media_ranges is not None:
            self.sand.set_media(self.data, [self.media_ranges.sample(self.rng, self.base_media) for _ in range(n)],
                                worlds=idx)
        command = (options or {}).get("command")
        if command is None:
            lo, hi = self._command_ranges.T
            self._command[idx] = lo + self.rng.uniform(size=(n, 3)) * (hi - lo)
        else:
            self.set_command(command, idx)
        self._last_action[idx] = 0.0
        self._steps[idx] = 0
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[idx] = True
        mjw.reset_data(self.mjw_model, self.data, reset=wp.array(mask, dtype=bool, device=self.device))
        self._qpos[idx] = self._init_qpos
        self._qpos[idx, 7:] += self.rng.uniform(-self._noise, self._noise, size=(n, nu))
        self._qvel[idx] = self._noise * self.rng.standard_normal((n, nv))
        self._ctrl_host[idx] = self._home_ctrl
        self.data.qpos.assign(self._qpos.astype(np.float32))
        self.data.qvel.assign(self._qvel.astype(np.float32))
        self.data.ctrl.assign(self._ctrl_host)
        self._qpos[:] = self.data.qpos.numpy()           # what the worlds hold (float32)
        self._qvel[:] = self.data.qvel.numpy()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Reset every world; ``options={"command": (3,) or (num_envs, 3)}`` fixes the commands."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._reset_worlds(np.arange(self.num_envs), options)
        s = self._derived(np.zeros_like(self._last_action), self._last_action, fresh=slice(None))
        return self._obs(s), {"command": self.command}

    def _physics(self) -> None:
        if self._use_graph:
            if self._graph is None:
                with wp.ScopedCapture(device=self.device) as capture:
                    for _ in range(self.frame_skip):
                        mjw.step(self.mjw_model, self.data)
                self._graph = capture.graph
            wp.capture_launch(self._graph)
        else:
            for _ in range(self.frame_skip):
                mjw.step(self.mjw_model, self.data)

    def step(self, actions: np.ndarray):
        """One env step of every world. Returns obs (W, obs), reward (W,), terminated (W,), truncated (W,),
        info (dict of (W, ...) arrays: the step's reward terms, positions, velocities, command, sand; and for
        the worlds that reset in this step ``final_obs`` (object array, None elsewhere) with mask
        ``_final_obs``). The returned obs of a reset world is its first observation of the new episode."""
        action = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1), -1.0, 1.0)
        target = np.clip(self._home_ctrl + self._action_scale * action, self._ctrl_low, self._ctrl_high)
        self._ctrl_host[:] = target
        self.data.ctrl.assign(self._ctrl_host)
        self._physics()
        self._read_state()
        s = self._derived(action, self._last_action)
        terms = self.reward.terms(s)
        rewards = {f"reward_{k}": self.reward.weights[k] * v for k, v in terms.items()}
        reward = np.sum(list(rewards.values()), axis=0)
        self._last_action = action.copy()
        self._steps += 1
        terminated = ~s.healthy if self._terminate else np.zeros(self.num_envs, dtype=bool)
        truncated = (self._steps >= self.max_episode_steps) & ~terminated
        obs = self._obs(s)
        info = {"x_position": s.qpos[:, 0], "y_position": s.qpos[:, 1], "x_velocity": s.v_heading[:, 0],
                "y_velocity": s.v_heading[:, 1], "yaw_rate": s.yaw_rate, "command": s.command, **rewards,
                "sand_force": s.sand_force, "sand_sinkage": s.sinkage}
        done = np.flatnonzero(terminated | truncated)
        if done.size:
            final = np.full(self.num_envs, None, dtype=object)
            for i in done:
                final[i] = obs[i].copy()
            info["final_obs"] = final
            info["_final_obs"] = terminated | truncated
            self._reset_worlds(done)
            s2 = self._derived(np.zeros_like(action), self._last_action, fresh=done)
            obs[done] = self._obs(s2, done)
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        self.sand.detach()


class SandQuadrupedVectorEnv(VectorEnv):
    """``gymnasium.vector.VectorEnv`` of :class:`BatchedSandQuadruped` (same-step auto-reset).

    ``SandQuadrupedVectorEnv(num_envs=4096, device="cuda:0", media_ranges=MediaRanges())``; every keyword of
    :class:`BatchedSandQuadruped` is accepted.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int, **kwargs) -> None:
        self.sim = BatchedSandQuadruped(num_envs, **kwargs)
        self.num_envs = self.sim.num_envs
        self.single_observation_space = self.sim.single_observation_space
        self.single_action_space = self.sim.single_action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.action_space.seed(seed)
        return self.sim.reset(seed=seed, options=options)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.sim.step(actions)
        if "final_obs" in info:
            mask = info["_final_obs"]
            info["final_info"] = {k: v for k, v in info.items() if not k.startswith(("final_", "_final"))}
            info["_final_info"] = mask
        return obs, reward, terminated, truncated, info

    def close_extras(self, **kwargs) -> None:
        self.sim.close()
