"""SandQuadruped-v0: a Go1-class quadruped tracking a planar velocity command on sand."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from gymnasium import utils
from gymnasium.spaces import Box

from rft_mujoco.models.quadruped import FOOT_BODIES
from rft_mujoco.physics.media import Media

from .sand_bed import MediaRanges
from .quadruped_task import CommandedQuadruped
from .sand_task import SandTaskEnv

DEFAULT_CAMERA_CONFIG = {"trackbodyid": 1, "distance": 1.6, "elevation": -20.0, "azimuth": 120.0}

DEFAULT_COMMAND_RANGES = ((-0.3, 0.6), (-0.2, 0.2), (-0.6, 0.6))
"""Per-episode uniform ranges of the command: forward velocity (m/s), lateral velocity (m/s), yaw rate
(rad/s), in the trunk's heading frame."""

DEFAULT_REWARD_WEIGHTS = {
    "tracking_lin_vel": 1.0,
    "tracking_ang_vel": 0.5,
    "upright": 0.2,
    "healthy": 0.2,
    "lin_vel_z": 1.0,
    "ang_vel_xy": 0.05,
    "ctrl": 0.02,
    "action_rate": 0.01,
    "sinkage": 1.0,
}
"""Reward weights (see the class docstring for each term); pass ``reward_weights`` to change some."""


class SandQuadrupedEnv(CommandedQuadruped, SandTaskEnv, utils.EzPickle):
    r"""
    ## Description
    The bundled Go1-class quadruped (``models/quadruped.xml``: 12 kg, 12 position-servoed joints, ball
    feet of 0.02 m radius) on a bed of granular media (3D-RFT, :mod:`rft_mujoco`; loose 3 mm glass beads
    of Li, Zhang & Goldman 2013 by default) over a rigid bottom ``bed_depth_m`` below the surface. The
    sand acts on the feet (``sand_bodies``). Each episode draws a command (forward velocity, lateral
    velocity, yaw rate) that the trunk should follow.

    ## Action Space
    ``Box(-1, 1, (12,), float32)``: joint target offsets from the ``home`` pose,
    ``target = home + action_scale_rad * action``, clipped to the joint ranges, in actuator order
    FL_hip FL_thigh FL_calf FR_hip ... RR_calf (``rft_mujoco.models.quadruped.ACTUATOR_NAMES``). Servos: kp 80 N m/rad,
    kv 1.5 N m s/rad, torque limits 25 N m (hip, thigh) and 35 N m (calf).

    ## Observation Space
    ``Box(-inf, inf, (49,), float64)`` (65 with ``include_sand_in_observation=True``):

    | Num   | Observation                                                   | Unit  |
    |-------|---------------------------------------------------------------|-------|
    | 0     | trunk height above the sand surface                           | m     |
    | 1-3   | gravity direction in the trunk frame (unit vector)            | -     |
    | 4-6   | trunk linear velocity in the trunk frame                      | m/s   |
    | 7-9   | trunk angular velocity in the trunk frame                     | rad/s |
    | 10-21 | joint angles minus the ``home`` pose (actuator order)         | rad   |
    | 22-33 | joint angular velocities                                      | rad/s |
    | 34-45 | previous action                                               | -     |
    | 46-48 | command: forward velocity, lateral velocity, yaw rate         | m/s, m/s, rad/s |
    | 49+4i .. 52+4i | (optional) sand force on foot i (FL, FR, RL, RR) world x, y, z; its sinkage | N, m |

    ## Rewards
    ``reward`` is the sum of these terms, each ``weight * term`` (weights in ``reward_weights``, defaults
    :data:`DEFAULT_REWARD_WEIGHTS`), each a method and in ``info`` as ``reward_<name>``:

    - ``tracking_lin_vel``: ``exp(-|v_xy - c_xy|^2 / tracking_sigma)``, planar trunk velocity in the heading
      frame (m/s) against the command;
    - ``tracking_ang_vel``: ``exp(-(w_z - c_yaw)^2 / tracking_sigma)``, yaw rate (rad/s);
    - ``upright``: the z component of the trunk's z axis (1 upright, 0 on its side);
    - ``healthy``: 1 per step while healthy;
    - ``lin_vel_z``: ``-v_z^2``, vertical trunk velocity (m/s);
    - ``ang_vel_xy``: ``-|w_xy|^2``, roll and pitch rates (rad/s);
    - ``ctrl``: ``-|action|^2``;
    - ``action_rate``: ``-|action - previous action|^2``;
    - ``sinkage``: ``-sum of the feet's sinkage`` (m).

    ``info`` also has ``x_position``, ``y_position`` (m), ``x_velocity``, ``y_velocity`` (heading
    frame, m/s), ``yaw_rate`` (rad/s), ``command`` (3,), ``sand_force`` (4, 3) N and ``sand_sinkage`` (4,) m.

    ## Starting State
    The ``home`` keyframe (trunk 0.30 m above the surface) with joint angles ``+ U(-noise, noise)`` and
    trunk and joint velocities ``noise * N(0, 1)`` (``noise = reset_noise_scale``). The command is drawn
    uniformly from ``command_ranges``, or given by ``reset(options={"command": (vx, vy, yaw_rate)})``.

    ## Episode End
    Terminated when unhealthy (``terminate_when_unhealthy``): trunk height above the surface below
    ``min_height_m``, trunk z axis z-component below ``min_upright``, or a non-finite state. Truncated at
    1000 steps (20 s) by the registered TimeLimit.

    ## Arguments
    | Parameter                     | Type                | Default                  | Description |
    |-------------------------------|---------------------|--------------------------|-------------|
    | `xml_file`                    | str                 | `"quadruped.xml"`        | bundled model name or a path |
    | `frame_skip`                  | int                 | `10`                     | physics steps (2 ms) per env step |
    | `default_camera_config`       | dict                | tracking                 | render camera |
    | `reward_weights`              | dict                | `{}`                     | overrides of :data:`DEFAULT_REWARD_WEIGHTS` |
    | `tracking_sigma`              | float               | `0.25`                   | width of the tracking kernels ((m/s)^2, (rad/s)^2) |
    | `command_ranges`              | 3 x (low, high)     | :data:`DEFAULT_COMMAND_RANGES` | per-episode command ranges |
    | `action_scale_rad`            | float               | `0.5`                    | joint offset per unit action (rad) |
    | `terminate_when_unhealthy`    | bool                | `True`                   | terminate on a fall |
    | `min_height_m`                | float               | `0.12`                   | lowest healthy trunk height above the surface (m) |
    | `min_upright`                 | float               | `0.5`                    | lowest healthy z component of the trunk z axis |
    | `reset_noise_scale`           | float               | `0.05`                   | initial state noise |
    | `media`                       | Media or str        | `"li_loose_glass_beads"` | granular medium |
    | `resolution`                  | str or float        | `"default"`              | sand element size (preset or m) |
    | `bed_depth_m`                 | float or None       | `0.05`                   | rigid bottom this far below the surface (None: bottomless) |
    | `sand_bodies`                 | names               | the four feet            | bodies that feel the sand (e.g. add the calves) |
    | `media_ranges`                | MediaRanges or None | `None`                   | per-episode medium randomization |
    | `include_sand_in_observation` | bool                | `False`                  | append per-foot sand force and sinkage |
    | plus ``render_mode``, ``width``, ``height``, ``camera_id``, ``camera_name`` of ``MujocoEnv`` |

    ## Version History
    * v0: first version.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(
        self,
        xml_file: str = "quadruped.xml",
        frame_skip: int = 10,
        *,
        default_camera_config: dict[str, float | int] = DEFAULT_CAMERA_CONFIG,
        reward_weights: dict[str, float] | None = None,
        tracking_sigma: float = 0.25,
        command_ranges: Sequence[tuple[float, float]] = DEFAULT_COMMAND_RANGES,
        action_scale_rad: float = 0.5,
        terminate_when_unhealthy: bool = True,
        min_height_m: float = 0.12,
        min_upright: float = 0.5,
        reset_noise_scale: float = 0.05,
        media: Media | str = "li_loose_glass_beads",
        resolution: str | float = "default",
        bed_depth_m: float | None = 0.05,
        sand_bodies: Sequence[str] = FOOT_BODIES,
        media_ranges: MediaRanges | None = None,
        include_sand_in_observation: bool = False,
        **kwargs,
    ):
        utils.EzPickle.__init__(self, xml_file, frame_skip, default_camera_config, reward_weights, tracking_sigma,
                                command_ranges, action_scale_rad, terminate_when_unhealthy, min_height_m,
                                min_upright, reset_noise_scale, media, resolution, bed_depth_m, sand_bodies,
                                media_ranges, include_sand_in_observation, **kwargs)
        unknown = set(reward_weights or {}) - set(DEFAULT_REWARD_WEIGHTS)
        if unknown:
            raise ValueError(f"unknown reward_weights {sorted(unknown)}; valid names: {sorted(DEFAULT_REWARD_WEIGHTS)}")
        ranges = np.asarray(command_ranges, dtype=float)
        if ranges.shape != (3, 2) or np.any(ranges[:, 0] > ranges[:, 1]):
            raise ValueError(f"command_ranges must be 3 (low, high) pairs with low <= high for (vx m/s, vy m/s, "
                             f"yaw rate rad/s), got {command_ranges!r}")
        self._weights = {**DEFAULT_REWARD_WEIGHTS, **(reward_weights or {})}
        self._tracking_sigma = float(tracking_sigma)
        self._command_ranges = ranges
        self._action_scale = float(action_scale_rad)
        self._terminate_when_unhealthy = terminate_when_unhealthy
        self._min_height = float(min_height_m)
        self._min_upright = float(min_upright)
        self._reset_noise_scale = reset_noise_scale
        self._reset_options: dict = {}
        SandTaskEnv.__init__(self, xml_file, frame_skip, media=media, resolution=resolution,
                             sand_bodies=list(sand_bodies), bed_depth_m=bed_depth_m, media_ranges=media_ranges,
                             include_sand_in_observation=include_sand_in_observation,
                             default_camera_config=default_camera_config, **kwargs)
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        key = self.model.key("home")
        self.init_qpos = key.qpos.copy()
        self._home_ctrl = key.ctrl.copy()
        self._ctrl_low, self._ctrl_high = self.model.actuator_ctrlrange.T.copy()
        self._trunk = self.model.body("trunk").id
        self._surface_z = float(self.sand.handle.terrain.max_height)
        self._command = np.zeros(3)
        self._last_action = np.zeros(self.model.nu)
        obs_size = 49 + self._sand_obs_size()
        self.observation_space = Box(low=-np.inf, high=np.inf, shape=(obs_size,), dtype=np.float64)
        self.observation_structure = {"base": 10, "joint_pos": 12, "joint_vel": 12, "last_action": 12,
                                      "command": 3, "sand": self._sand_obs_size()}

    # --- reward terms (unweighted) -----------------------------------------------------------------
    def tracking_lin_vel(self, v_xy: np.ndarray) -> float:
        return float(np.exp(-np.sum(np.square(v_xy - self._command[:2])) / self._tracking_sigma))

    def tracking_ang_vel(self, yaw_rate: float) -> float:
        return float(np.exp(-(yaw_rate - self._command[2]) ** 2 / self._tracking_sigma))

    def upright(self) -> float:
        return float(self._trunk_rotation()[2, 2])

    def ctrl(self, action: np.ndarray) -> float:
        return -float(np.sum(np.square(action)))

    def sinkage(self) -> float:
        return -float(np.sum(self.sand.handle.diagnostics(self.data).max_depth))

    def _get_rew(self, action):
        """(reward, named weighted terms, heading-frame velocity (2,) m/s, yaw rate rad/s) of this step."""
        v_xy, yaw_rate = self._heading_velocity()
        terms = {
            "tracking_lin_vel": self.tracking_lin_vel(v_xy),
            "tracking_ang_vel": self.tracking_ang_vel(yaw_rate),
            "upright": self.upright(),
            "healthy": self.healthy(),
            "lin_vel_z": self.lin_vel_z(),
            "ang_vel_xy": self.ang_vel_xy(),
            "ctrl": self.ctrl(action),
            "action_rate": self.action_rate(action),
            "sinkage": self.sinkage(),
        }
        rewards = {f"reward_{k}": self._weights[k] * v for k, v in terms.items()}
        return float(sum(rewards.values())), rewards, v_xy, yaw_rate

    # --- gymnasium API ---------------------------------------------------------------------------

    def _get_obs(self):
        rot = self._trunk_rotation()
        height = self.data.qpos[2] - self._surface_z
        gravity_body = rot.T @ np.array([0.0, 0.0, -1.0])
        v_body = rot.T @ self.data.qvel[:3]
        omega_body = self.data.qvel[3:6]
        return np.concatenate([[height], gravity_body, v_body, omega_body, self.data.qpos[7:] - self._home_ctrl,
                               self.data.qvel[6:], self._last_action, self._command, self._sand_obs()])
