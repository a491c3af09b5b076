"""What the commanded quadruped tasks (SandQuadruped-v0 and -v1) share: the command drawn at reset, the
trunk's heading-frame velocity, the health test, the reset, and the reward terms both use.

A task class lists this mixin before :class:`~rft_mujoco.envs.sand_task.SandTaskEnv` and sets
``_command_ranges`` (3, 2), ``_reset_noise_scale``, ``_min_height``, ``_min_upright``, ``_surface_z`` and
``_home_ctrl`` (and ``_action_scale``, ``_ctrl_low``, ``_ctrl_high``, ``_terminate_when_unhealthy``), and
implements ``_get_rew(action)``; :meth:`CommandedQuadruped.step` is the step of both."""

from __future__ import annotations

import mujoco
import numpy as np
from gymnasium.spaces import Box


class CommandedQuadruped:
    """Mixin of the commanded quadruped tasks (see the module docstring)."""

    def step(self, action):
        """Servo targets ``home + action_scale * action`` (action clipped to [-1, 1]), ``frame_skip`` physics
        steps, then the task's reward (its ``_get_rew(action)`` -> (reward, named terms, heading-frame
        velocity (2,) m/s, yaw rate rad/s))."""
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (self.model.nu,):
            raise ValueError(f"action must have shape ({self.model.nu},) (one servo offset per actuator, in "
                             f"[-1, 1]), got shape {action.shape}")
        action = np.clip(action, -1.0, 1.0)
        target = np.clip(self._home_ctrl + self._action_scale * action, self._ctrl_low, self._ctrl_high)
        self.do_simulation(target, self.frame_skip)
        reward, rewards, v_xy, yaw_rate = self._get_rew(action)
        self._last_action = action
        terminated = self._terminate_when_unhealthy and not self.is_healthy
        info = {"x_position": self.data.qpos[0], "y_position": self.data.qpos[1], "x_velocity": v_xy[0],
                "y_velocity": v_xy[1], "yaw_rate": yaw_rate, "command": self.command, **rewards,
                **self.sand.info(self.data)}
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), reward, terminated, False, info

    def _set_action_space(self):
        self.action_space = Box(low=-1.0, high=1.0, shape=(self.model.nu,), dtype=np.float32)
        return self.action_space

    # --- state helpers ---------------------------------------------------------------------------
    @property
    def command(self) -> np.ndarray:
        """(3,) the current command: forward velocity (m/s), lateral velocity (m/s), yaw rate (rad/s)."""
        return self._command.copy()

    def _trunk_rotation(self) -> np.ndarray:
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, self.data.qpos[3:7])
        return rot.reshape(3, 3)

    def _heading_velocity(self) -> tuple[np.ndarray, float]:
        """Planar trunk velocity (2,) m/s in the heading (yaw) frame and yaw rate (rad/s, world z)."""
        rot = self._trunk_rotation()
        yaw = np.arctan2(rot[1, 0], rot[0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        vx, vy = self.data.qvel[0], self.data.qvel[1]
        omega_world = rot @ self.data.qvel[3:6]
        return np.array([c * vx + s * vy, -s * vx + c * vy]), float(omega_world[2])

    def _gravity_body(self) -> np.ndarray:
        """(3,) the gravity direction (unit) in the trunk frame."""
        return -self._trunk_rotation()[2]

    @property
    def is_healthy(self) -> bool:
        height = self.data.qpos[2] - self._surface_z
        upright = self._trunk_rotation()[2, 2]
        return bool(np.isfinite(self.state_vector()).all() and height >= self._min_height
                    and upright >= self._min_upright)

    # --- reward terms both versions use (unweighted) -----------------------------------------------
    def healthy(self) -> float:
        return float(self.is_healthy)

    def lin_vel_z(self) -> float:
        return -float(self.data.qvel[2] ** 2)

    def ang_vel_xy(self) -> float:
        return -float(np.sum(np.square(self.data.qvel[3:5])))   # free joint: angular velocity in the trunk frame

    def action_rate(self, action: np.ndarray) -> float:
        return -float(np.sum(np.square(action - self._last_action)))

    # --- reset ---------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._reset_options = options or {}
        return super().reset(seed=seed, options=options)

    def reset_model(self):
        """Draw the command (``options["command"]`` or uniform in the ranges), the medium, and the noisy
        ``home`` state (joints uniform +-noise rad, velocities normal with std noise)."""
        self._randomize_media()
        command = self._reset_options.get("command")
        if command is None:
            lo, hi = self._command_ranges.T
            self._command = lo + self.np_random.uniform(size=3) * (hi - lo)
        else:
            command = np.asarray(command, dtype=float)
            if command.shape != (3,) or not np.all(np.isfinite(command)):
                raise ValueError(f"options['command'] must be 3 finite numbers (vx m/s, vy m/s, yaw rate rad/s), "
                                 f"got {command.tolist()}")
            self._command = command.copy()
        self._last_action = np.zeros(self.model.nu)
        noise = self._reset_noise_scale
        qpos = self.init_qpos.copy()
        qvel = self.init_qvel.copy()
        qpos[7:] += self.np_random.uniform(-noise, noise, size=self.model.nu)
        qvel += noise * self.np_random.standard_normal(self.model.nv)
        self.set_state(qpos, qvel)
        self.data.ctrl[:] = self._home_ctrl
        return self._get_obs()

    def _get_reset_info(self):
        return {"x_position": self.data.qpos[0], "y_position": self.data.qpos[1], "command": self.command,
                **self.sand.info(self.data)}
