"""SandQuadruped-v1: the quadruped on sand, every body in the sand, rewarded for tracking its command."""

from __future__ import annotations

import types
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from gymnasium import utils
from gymnasium.spaces import Box

from rft_mujoco.physics.media import Media
from rft_mujoco.models.quadruped import LEGS, TrotGait

from .sand_bed import FEATURES_PER_BODY, MediaRanges
from .quadruped_task import CommandedQuadruped
from .sand_task import SandTaskEnv

DEFAULT_COMMAND_RANGES = ((0.0, 0.6), (0.0, 0.0), (-0.5, 0.5))
"""Per-episode uniform ranges of the command: forward velocity (m/s), lateral velocity (m/s), yaw rate
(rad/s), in the trunk's heading frame."""

DEFAULT_REWARD_WEIGHTS = types.MappingProxyType({
    "tracking_lin_vel": 1.0,
    "tracking_ang_vel": 0.5,
    "lin_vel_z": 0.5,
    "ang_vel_xy": 0.01,
    "orientation": 0.5,
    "torques": 2e-5,
    "action_rate": 0.005,
    "healthy": 0.05,
})
"""Reward weights (see the class docstring for each term; read-only); pass ``reward_weights`` to change
some. The two tracking terms pay up to 1.5 per step; the survival bonus is 0.05."""

DEFAULT_CAMERA_CONFIG = {"distance": 1.6, "elevation": -20.0, "azimuth": 120.0}
"""Free-camera settings, used only with ``camera_id=-1`` (the default camera is the model's ``track``)."""

TRACK_CAMERA = "track"
"""The model's camera that follows the robot's centre of mass (``mode="trackcom"``): the default render
camera."""

GROUNDS = ("sand", "rigid")
"""Values of ``ground``: 3D-RFT sand (over the rigid bottom ``bed_depth_m`` down), or the same floor rigid."""

OBS_SIZE = 49
"""Observation entries without the optional sand block (see the class docstring)."""


class SandQuadrupedEnv(CommandedQuadruped, SandTaskEnv, utils.EzPickle):
    r"""
    ## Description
    The bundled Go1-class quadruped (``models/quadruped.xml``: 12 kg, 12 position-servoed joints, ball
    feet of 0.02 m radius) on a bed of granular media (3D-RFT, :mod:`rft_mujoco`; loose 3 mm glass beads
    of Li, Zhang & Goldman 2013 by default) over a rigid bottom ``bed_depth_m`` below the surface. The
    sand acts on every body of the robot that reaches it (``sand_bodies="all"``: trunk, hips, thighs,
    calves and feet; a body above the surface costs next to nothing). Each episode draws a command
    (forward velocity, lateral velocity, yaw rate) that the trunk should follow; the reward pays for
    following it, so standing still scores well only when the command is close to zero.

    ## Action Space
    ``Box(-1, 1, (12,), float32)``: joint target offsets from the ``home`` pose,
    ``target = home + action_scale_rad * action``, clipped to the joint ranges, in actuator order
    FL_hip FL_thigh FL_calf FR_hip ... RR_calf (``rft_mujoco.models.quadruped.ACTUATOR_NAMES``).

    | Num  | Action                                  | Min | Max | Unit (times ``action_scale_rad``) |
    |------|-----------------------------------------|-----|-----|-----------------------------------|
    | 3i   | hip (abduction) target offset of leg i  | -1  | 1   | rad                               |
    | 3i+1 | thigh (flexion) target offset of leg i  | -1  | 1   | rad                               |
    | 3i+2 | calf (knee) target offset of leg i      | -1  | 1   | rad                               |

    Legs i = 0..3 are FL, FR, RL, RR. Servos: kp 80 N m/rad, kv 1.5 N m s/rad, torque limits 25 N m (hip,
    thigh) and 35 N m (calf). The zero action holds the ``home`` pose (standing).

    ## Observation Space
    ``Box(-inf, inf, (49,), float64)`` (65 with ``include_sand_in_observation=True``):

    | Num   | Observation                                                    | Unit            |
    |-------|----------------------------------------------------------------|-----------------|
    | 0     | trunk height above the sand surface                            | m               |
    | 1-3   | gravity direction in the trunk frame (unit vector)             | -               |
    | 4-6   | trunk linear velocity in the trunk frame                       | m/s             |
    | 7-9   | trunk angular velocity in the trunk frame                      | rad/s           |
    | 10-21 | joint angles minus the ``home`` pose (actuator order)          | rad             |
    | 22-33 | joint angular velocities (actuator order)                      | rad/s           |
    | 34-45 | previous action                                                | -               |
    | 46-48 | command: forward velocity, lateral velocity, yaw rate          | m/s, m/s, rad/s |
    | 49+4i .. 51+4i | (optional) sand force on leg i (FL, FR, RL, RR; hip + thigh + calf + foot), world x, y, z | N |
    | 52+4i | (optional) sinkage of leg i (its deepest loaded element)       | m               |

    ## Rewards
    ``reward`` is ``max(0, sum)`` of ``weight * term`` over the terms below (weights in
    ``reward_weights``, defaults :data:`DEFAULT_REWARD_WEIGHTS`); each term is a method of the same name
    and each weighted term is in ``info`` as ``reward_<name>`` (unclipped). The clip at zero
    (``only_positive_rewards``, as in legged_gym and mujoco_playground) keeps a fall from paying: with
    negative steps, ending the episode early would raise the return. Velocities are the trunk's: planar
    velocity ``v_xy`` in the heading (yaw) frame, vertical velocity ``v_z`` and yaw rate ``w_z`` in the
    world frame, roll and pitch rates ``w_xy`` in the trunk frame; ``c`` is the command.

    | term               | value                                             | unit of the argument | weight |
    |--------------------|---------------------------------------------------|----------------------|--------|
    | `tracking_lin_vel` | ``exp(-|v_xy - c_xy|^2 / lin_vel_sigma)``          | m/s                  | 1.0    |
    | `tracking_ang_vel` | ``exp(-(w_z - c_yaw)^2 / ang_vel_sigma)``           | rad/s                | 0.5    |
    | `lin_vel_z`        | ``-v_z^2``                                        | m/s                  | 0.5    |
    | `ang_vel_xy`       | ``-|w_xy|^2``                                     | rad/s                | 0.01   |
    | `orientation`      | ``-|g_xy|^2``, gravity direction in the trunk frame, x and y | -         | 0.5    |
    | `torques`          | ``-|tau|^2``, the 12 actuator torques              | N m                  | 2e-5   |
    | `action_rate`      | ``-|action - previous action|^2``                  | -                    | 0.005  |
    | `healthy`          | 1 per step while healthy (a survival bonus)        | -                    | 0.05   |

    The tracking terms pay at most 1.5 per step, the survival bonus 0.05. The kernels' widths (0.1) are
    legged_gym's 0.25 scaled to these command ranges (0.6 of its 1 m/s and 1 rad/s): under a 0.4 m/s
    command a robot standing still earns 0.20 of the linear-tracking term, the scripted trot of
    :func:`scripted_trot` (0.37 m/s on the default bed) 0.93. Measured over 1000 steps at (0.4, 0, 0):
    zero action ~745, random actions ~3-18 (they fall within 4 s), the scripted trot ~1416. The penalties
    are small enough that a policy with action noise of std 0.37 still earns more than nothing per step.

    ``info`` also has ``x_position``, ``y_position`` (m), ``x_velocity``, ``y_velocity`` (heading
    frame, m/s), ``yaw_rate`` (rad/s), ``command`` (3,), and per sand body (``env.unwrapped.sand.body_names``
    order) ``sand_force`` (B, 3) N and ``sand_sinkage`` (B,) m.

    ## Starting State
    The ``home`` keyframe (standing, trunk 0.30 m above the surface, feet on it) with joint angles
    ``+ U(-noise, noise)`` rad and every velocity ``noise * N(0, 1)`` (``noise = reset_noise_scale``); the
    robot settles into the sand in the first ~0.3 s. The command is drawn uniformly from
    ``command_ranges`` at each reset, or given by ``reset(options={"command": (vx, vy, yaw_rate)})``. With
    ``media_ranges`` the medium is drawn anew at each reset too.

    ## Episode End
    Terminated on a fall (``terminate_when_unhealthy``): trunk height above the surface below
    ``min_height_m`` (trunk on the sand), z component of the trunk's z axis below ``min_upright`` (tipped
    over or flipped), or a non-finite state. Truncated at 1000 steps (20 s) by the registered TimeLimit.

    ## Arguments
    | Parameter                     | Type                | Default                  | Description |
    |-------------------------------|---------------------|--------------------------|-------------|
    | `xml_file`                    | str                 | `"quadruped.xml"`        | bundled model name or a path |
    | `frame_skip`                  | int                 | `10`                     | physics steps (2 ms) per env step |
    | `default_camera_config`       | dict                | :data:`DEFAULT_CAMERA_CONFIG` | free-camera settings (with ``camera_id=-1``) |
    | `reward_weights`              | dict                | `{}`                     | overrides of :data:`DEFAULT_REWARD_WEIGHTS` |
    | `lin_vel_sigma`               | float               | `0.1`                    | width of the linear tracking kernel, (m/s)^2 |
    | `ang_vel_sigma`               | float               | `0.1`                    | width of the yaw-rate tracking kernel, (rad/s)^2 |
    | `only_positive_rewards`       | bool                | `True`                   | clip each step's reward at 0 |
    | `command_ranges`              | 3 x (low, high)     | :data:`DEFAULT_COMMAND_RANGES` | per-episode command ranges (m/s, m/s, rad/s) |
    | `action_scale_rad`            | float               | `0.5`                    | joint offset per unit action, rad |
    | `terminate_when_unhealthy`    | bool                | `True`                   | terminate on a fall |
    | `min_height_m`                | float               | `0.12`                   | lowest healthy trunk height above the surface, m |
    | `min_upright`                 | float               | `0.5`                    | lowest healthy z component of the trunk z axis |
    | `reset_noise_scale`           | float               | `0.05`                   | initial state noise (rad, rad/s, m/s) |
    | `media`                       | Media or str        | `"li_loose_glass_beads"` | granular medium |
    | `resolution`                  | str or float        | `"default"`              | sand element size (preset or m) |
    | `bed_depth_m`                 | float or None       | `0.1`                    | rigid bottom this far below the surface, m (None: bottomless) |
    | `sand_bodies`                 | "all" or names      | `"all"`                  | bodies that feel the sand |
    | `media_ranges`                | MediaRanges or None | `None`                   | per-episode medium randomization |
    | `include_sand_in_observation` | bool                | `False`                  | append per-leg sand force and sinkage |
    | `ground`                      | "sand" or "rigid"   | `"sand"`                 | "rigid": the same floor as a rigid plane, no sand (the sand-gap comparison) |
    | plus ``render_mode``, ``width``, ``height``, ``camera_id``, ``camera_name`` of ``MujocoEnv``; with neither camera argument the render camera is the model's ``track`` (follows the robot) |

    ## Version History
    * v1: the sand acts on every body (v0: the feet only), 0.1 m of sand over the rigid bottom (v0: 0.05 m;
      standing, the sand now carries the whole weight at 93 mm sinkage, where the 5 cm bottom carried
      64% of it; the scripted trot still walks at 0.33 m/s, at 0.11 m it bogs down to 0.12 m/s);
      ``ground="rigid"`` for the same task without sand. Rewards pay for tracking the command (in v0,
      under 0.4 m/s, standing still earned 73% of the scripted trot's return, 1220 against 1668 over 1000
      steps, and a flailing robot lost reward every step, so falling early paid): kernels of width 0.1 instead of 0.25; survival bonus 0.05
      instead of 0.2; no ``upright`` bonus and no sinkage penalty; penalties on tilt (``orientation``)
      and actuator torque instead of ``ctrl``; smaller penalty weights; each step's reward clipped at 0.
      Commands forward 0-0.6 m/s, no lateral, yaw +-0.5 rad/s (v0: -0.3-0.6, +-0.2, +-0.6). The
      optional sand observation is per leg (v0: per foot). Renders from the model's tracking camera.
    * v0: first version.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(
        self,
        xml_file: str = "quadruped.xml",
        frame_skip: int = 10,
        *,
        default_camera_config: dict[str, float | int] = DEFAULT_CAMERA_CONFIG,
        reward_weights: Mapping[str, float] | None = None,
        lin_vel_sigma: float = 0.1,
        ang_vel_sigma: float = 0.1,
        only_positive_rewards: bool = True,
        command_ranges: Sequence[tuple[float, float]] = DEFAULT_COMMAND_RANGES,
        action_scale_rad: float = 0.5,
        terminate_when_unhealthy: bool = True,
        min_height_m: float = 0.12,
        min_upright: float = 0.5,
        reset_noise_scale: float = 0.05,
        media: Media | str = "li_loose_glass_beads",
        resolution: str | float = "default",
        bed_depth_m: float | None = 0.1,
        sand_bodies: str | Sequence[str] = "all",
        media_ranges: MediaRanges | None = None,
        include_sand_in_observation: bool = False,
        ground: str = "sand",
        **kwargs,
    ):
        utils.EzPickle.__init__(
            self, xml_file=xml_file, frame_skip=frame_skip, default_camera_config=default_camera_config,
            reward_weights=reward_weights, lin_vel_sigma=lin_vel_sigma, ang_vel_sigma=ang_vel_sigma,
            only_positive_rewards=only_positive_rewards,
            command_ranges=command_ranges, action_scale_rad=action_scale_rad,
            terminate_when_unhealthy=terminate_when_unhealthy, min_height_m=min_height_m, min_upright=min_upright,
            reset_noise_scale=reset_noise_scale, media=media, resolution=resolution, bed_depth_m=bed_depth_m,
            sand_bodies=sand_bodies, media_ranges=media_ranges,
            include_sand_in_observation=include_sand_in_observation, ground=ground, **kwargs)
        if ground not in GROUNDS:
            raise ValueError(f"ground must be one of {GROUNDS}, got {ground!r}")
        unknown = set(reward_weights or {}) - set(DEFAULT_REWARD_WEIGHTS)
        if unknown:
            raise ValueError(f"unknown reward_weights {sorted(unknown)}; valid names: {sorted(DEFAULT_REWARD_WEIGHTS)}")
        ranges = np.asarray(command_ranges, dtype=float)
        if ranges.shape != (3, 2) or not np.all(np.isfinite(ranges)) or np.any(ranges[:, 0] > ranges[:, 1]):
            raise ValueError(f"command_ranges must be 3 (low, high) pairs with low <= high for (vx m/s, vy m/s, "
                             f"yaw rate rad/s), got {command_ranges!r}")
        for name, value in (("lin_vel_sigma", lin_vel_sigma), ("ang_vel_sigma", ang_vel_sigma),
                            ("action_scale_rad", action_scale_rad)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        self._weights = {**DEFAULT_REWARD_WEIGHTS, **(reward_weights or {})}
        self._lin_vel_sigma = float(lin_vel_sigma)
        self._ang_vel_sigma = float(ang_vel_sigma)
        self._only_positive_rewards = bool(only_positive_rewards)
        self._command_ranges = ranges
        self._action_scale = float(action_scale_rad)
        self._terminate_when_unhealthy = bool(terminate_when_unhealthy)
        self._min_height = float(min_height_m)
        self._min_upright = float(min_upright)
        self._reset_noise_scale = float(reset_noise_scale)
        self._reset_options: dict = {}
        if kwargs.get("camera_id") is None and kwargs.get("camera_name") is None:
            kwargs["camera_name"] = TRACK_CAMERA
        SandTaskEnv.__init__(self, xml_file, frame_skip, media=media, resolution=resolution,
                             sand_bodies=sand_bodies if isinstance(sand_bodies, str) else list(sand_bodies),
                             bed_depth_m=bed_depth_m, media_ranges=media_ranges,
                             include_sand_in_observation=include_sand_in_observation,
                             default_camera_config=default_camera_config, **kwargs)
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self.ground = ground
        if ground == "rigid":                        # the surface geoms collide again; no sand forces
            self.sand.close()
            for name in self._surface_geoms:
                g = self.model.geom(name).id
                self.model.geom_contype[g] = self.model.geom_conaffinity[g] = 1
        key = self.model.key("home")
        self.init_qpos = key.qpos.copy()
        self._home_ctrl = key.ctrl.copy()
        self._ctrl_low, self._ctrl_high = self.model.actuator_ctrlrange.T.copy()
        self._surface_z = float(self.sand.handle.terrain.max_height)
        self._command = np.zeros(3)
        self._last_action = np.zeros(self.model.nu)
        # each leg's rows in the sand bodies (its hip, thigh, calf and foot: names starting "<leg>_")
        names = self.sand.body_names
        self._leg_rows = [np.array([i for i, n in enumerate(names) if n.startswith(f"{leg}_")], dtype=int)
                          for leg in LEGS]
        if self._include_sand_in_observation and not all(rows.size for rows in self._leg_rows):
            raise ValueError(f"include_sand_in_observation needs sand bodies on every leg {LEGS}, got {names}")
        sand_size = FEATURES_PER_BODY * len(LEGS) if self._include_sand_in_observation else 0
        self.observation_space = Box(low=-np.inf, high=np.inf, shape=(OBS_SIZE + sand_size,), dtype=np.float64)
        self.observation_structure = {"base": 10, "joint_pos": 12, "joint_vel": 12, "last_action": 12,
                                      "command": 3, "sand": sand_size}

    # --- state helpers ---------------------------------------------------------------------------
    @property
    def home_ctrl(self) -> np.ndarray:
        """(12,) rad, the joint targets of the zero action (the ``home`` keyframe's ctrl)."""
        return self._home_ctrl.copy()

    @property
    def action_scale_rad(self) -> float:
        """Joint target offset per unit action, rad."""
        return self._action_scale

    # --- reward terms (unweighted) -----------------------------------------------------------------
    def tracking_lin_vel(self, v_xy: np.ndarray) -> float:
        return float(np.exp(-np.sum(np.square(v_xy - self._command[:2])) / self._lin_vel_sigma))

    def tracking_ang_vel(self, yaw_rate: float) -> float:
        return float(np.exp(-(yaw_rate - self._command[2]) ** 2 / self._ang_vel_sigma))

    def orientation(self) -> float:
        return -float(np.sum(np.square(self._gravity_body()[:2])))

    def torques(self) -> float:
        return -float(np.sum(np.square(self.data.actuator_force)))

    def _get_rew(self, action: np.ndarray) -> tuple[float, dict[str, float], np.ndarray, float]:
        """The reward, its weighted terms (``reward_<name>``), and the heading-frame velocity and yaw rate."""
        v_xy, yaw_rate = self._heading_velocity()
        terms = {
            "tracking_lin_vel": self.tracking_lin_vel(v_xy),
            "tracking_ang_vel": self.tracking_ang_vel(yaw_rate),
            "lin_vel_z": self.lin_vel_z(),
            "ang_vel_xy": self.ang_vel_xy(),
            "orientation": self.orientation(),
            "torques": self.torques(),
            "action_rate": self.action_rate(action),
            "healthy": self.healthy(),
        }
        rewards = {f"reward_{k}": self._weights[k] * v for k, v in terms.items()}
        reward = float(sum(rewards.values()))
        if self._only_positive_rewards:
            reward = max(reward, 0.0)
        return reward, rewards, v_xy, yaw_rate

    def _sand_obs(self) -> np.ndarray:
        """(16,) per leg: sand force summed over its bodies (world x, y, z, N) and its sinkage (m)."""
        if not self._include_sand_in_observation:
            return np.zeros(0)
        diag = self.sand.handle.diagnostics(self.data)
        return np.concatenate([np.append(diag.force[rows].sum(axis=0), diag.max_depth[rows].max())
                               for rows in self._leg_rows])

    def _get_obs(self):
        rot = self._trunk_rotation()
        height = self.data.qpos[2] - self._surface_z
        v_body = rot.T @ self.data.qvel[:3]
        return np.concatenate([[height], self._gravity_body(), v_body, self.data.qvel[3:6],
                               self.data.qpos[7:] - self._home_ctrl, self.data.qvel[6:], self._last_action,
                               self._command, self._sand_obs()])

SCRIPTED_TROT = types.MappingProxyType({"frequency_hz": 2.5, "step_height_m": 0.06, "hip_height_m": 0.28,
                                        "ramp_time_s": 0.5})
"""The gait of :func:`scripted_trot`: the rigid-ground trot of :class:`~rft_mujoco.models.quadruped.TrotGait`
(its joint offsets from ``home`` stay within the default 0.5 rad action scale)."""


def scripted_trot(env, speed_mps: float = 0.4, **gait_kwargs) -> Callable[[np.ndarray], np.ndarray]:
    """A scripted trot as a policy of this env: ``obs -> action`` (the gait's phase is the env's simulated
    time since the last reset, ``env.unwrapped.data.time``).

    The :class:`~rft_mujoco.models.quadruped.TrotGait` joint targets (rad) become actions
    ``(target - home) / action_scale_rad``, clipped to [-1, 1]. The stride is chosen for a nominal
    ``speed_mps`` (feet that do not slip; on sand the trunk is slower).

    Args:
        env: a ``SandQuadruped-v1`` env (wrapped or not).
        speed_mps: nominal forward speed, m/s.
        gait_kwargs: :class:`TrotGait` fields over :data:`SCRIPTED_TROT` (``stride_m`` overrides the speed).
    """
    u = env.unwrapped
    if not isinstance(u, SandQuadrupedEnv):
        raise TypeError(f"scripted_trot needs a SandQuadruped-v1 env, got {type(u).__name__}")
    fields = {**SCRIPTED_TROT, **gait_kwargs}
    duty = fields.get("duty_factor", 0.5)
    fields.setdefault("stride_m", float(speed_mps) * duty / fields["frequency_hz"])
    gait = TrotGait.from_model(u.model, **fields)
    home, scale = u.home_ctrl, u.action_scale_rad

    def act(obs: np.ndarray) -> np.ndarray:
        q = gait.targets(u.data.time)
        return np.clip((q - home) / scale, -1.0, 1.0).astype(np.float32)

    return act
