"""SandSwimmer-v0: a sandfish-like undulator swimming inside sand (``rft_mujoco/SandSwimmer-v0``)."""

from __future__ import annotations

import warnings

import numpy as np
from gymnasium import utils
from gymnasium.spaces import Box

from rft_mujoco.geometry.elements import SandSetupWarning
from rft_mujoco.physics.media import Media

from .sand_bed import MediaRanges
from .sand_task import SandTaskEnv

DEFAULT_CAMERA_CONFIG = {"trackbodyid": 1, "distance": 0.35, "elevation": -60.0, "azimuth": 90.0}

N_JOINTS = 6
"""Body joints (head to tail) of ``models/sand_swimmer.xml``."""
EXPLICIT_DENSITY_SCALE = 100.0
"""The density over the animal's at which the explicit sand solve swims this body at its quasi-static limit
(docs/rest.md, "Any mass"); lighter with the explicit solve is warned."""


def serpenoid_action(time_s: float, *, amplitude_rad: float = 0.6, frequency_hz: float = 2.0,
                     waves_per_body: float = 1.0, n_joints: int = N_JOINTS) -> np.ndarray:
    """Joint targets (n_joints,) rad of a travelling wave running from head to tail (a serpenoid).

    ``theta_i(t) = amplitude * sin(2 pi f t - 2 pi waves_per_body i / n_joints)``, i = 0 at the head;
    the wave moves backward along the body, which pushes the body forward through the sand.
    """
    i = np.arange(n_joints)
    return amplitude_rad * np.sin(2.0 * np.pi * frequency_hz * time_s - 2.0 * np.pi * waves_per_body * i / n_joints)


class SandSwimmerEnv(SandTaskEnv, utils.EzPickle):
    r"""
    ## Description
    A sandfish-like undulator (``models/sand_swimmer.xml``: 7 capsule links, ~0.13 m long, ~22 g) buried
    in dry granular media, the 0.3 mm glass beads of Maladen et al. (Science 2009) by default. It swims
    by bending its 6 horizontal hinges; every link feels 3D-RFT sand forces (:mod:`rft_mujoco`). The goal
    is to move the centre of mass forward (+x) as fast as possible.

    By default (``planar=True``) the head moves in a horizontal plane ``depth_m`` below the surface (root
    joints: slide x, slide y, yaw), like the planar sand-swimming of Maladen et al. With
    ``planar=False`` the root is a free joint: in 3D-RFT a laterally undulating body feels lift, and this
    body (with no pitch control) rises to the surface within a few seconds.

    A hand-written travelling wave, :func:`serpenoid_action` (0.6 rad, 2 Hz, one wave per body), swims
    forward (and the reversed wave backward; ``tests/test_envs.py``). The env scales the bundled model (the
    animal's density) by ``density_scale`` = 100 (masses, inertias, joint armature and damping; see
    ``models/sand_swimmer.xml``) so that the explicit step converges on this quasi-static, servo-driven body;
    ``density_scale=1.0, solve="implicit"`` runs the animal itself (docs/rest.md, "Any mass"). Mean ``x_velocity`` over env steps 50-250 (seed 0, mujoco 4.0.0,
    ``tests/test_envs.py::test_swimmer_speed_is_step_converged``):

    | ``timestep_s``            | 0.005 (default) | 0.002   | 0.001   | 0.0005  |
    |---------------------------|-----------------|---------|---------|---------|
    | serpenoid speed (m/s)     | 0.0241          | 0.0259  | 0.0266  | 0.0269  |
    | random actions (m/s)      | -0.0003         | -0.0002 | -0.0002 | -0.0001 |

    The default 5 ms step is ~10% slow against the 0.5 ms value, at ~5x the env steps per second. Before
    mass scaling (real 17 g), the same table spread 6x and random flailing "swam" at +0.1 m/s at 5 ms:
    a numerical ratchet an RL agent would have exploited.

    ## Action Space
    ``Box(-0.9, 0.9, (6,), float32)``: target angles of the position servos (kp 0.5 N m/rad, torque limit
    0.3 N m).

    | Num | Action                                     | Min  | Max | Name (XML) | Joint | Unit |
    |-----|--------------------------------------------|------|-----|------------|-------|------|
    | 0-5 | target angle of body joint j1 (head) ... j6 (tail) | -0.9 | 0.9 | j1 ... j6 | hinge | rad |

    ## Observation Space
    ``Box(-inf, inf, (16,), float64)`` with ``planar=True`` (``(23,)`` with ``planar=False``), plus 28 with
    ``include_sand_in_observation=True``. The head's x, y are excluded (they are in ``info``).

    | Num   | Observation (planar=True)                          | Unit  |
    |-------|----------------------------------------------------|-------|
    | 0     | head yaw angle (root_yaw)                          | rad   |
    | 1-6   | body joint angles j1 ... j6                        | rad   |
    | 7-8   | head velocity along world x, y (root_x, root_y)    | m/s   |
    | 9     | head yaw rate                                      | rad/s |
    | 10-15 | body joint angular velocities j1 ... j6            | rad/s |
    | 16+4i .. 19+4i | (optional) sand force on link i (head = 0) world x, y, z; its sinkage | N, m |

    With ``planar=False`` the observation is ``qpos[2:]`` (head z in m, head quaternion, 6 joint angles)
    then ``qvel`` (head linear velocity in m/s world frame, angular velocity in rad/s body frame, 6 joint
    rates): 11 + 12 = 23 entries.

    ## Rewards
    ``reward = forward_reward - ctrl_cost``, each term a method and in ``info``:

    - ``reward_forward`` = ``forward_reward_weight * dx_com / dt``: the centre of mass x velocity (m/s)
      over the step (``dt = frame_skip * timestep_s``, 0.02 s by default);
    - ``reward_ctrl`` = ``-ctrl_cost_weight * sum(action^2)`` (action in rad).

    ``info`` also has ``x_position``, ``y_position`` (COM, m), ``x_velocity``, ``y_velocity`` (COM, m/s),
    ``sand_force`` (7, 3) N and ``sand_sinkage`` (7,) m.

    ## Starting State
    Straight body at ``depth_m`` heading +x, joint angles ``U(-noise, noise)``, joint velocities
    ``noise * N(0, 1)`` with ``noise = reset_noise_scale``.

    ## Episode End
    No termination (``terminated`` is always False). Truncation at 1000 steps (20 s) by the registered
    TimeLimit.

    ## Arguments
    | Parameter                     | Type                | Default                 | Description |
    |-------------------------------|---------------------|-------------------------|-------------|
    | `xml_file`                    | str                 | `"sand_swimmer.xml"`    | bundled model name or a path |
    | `frame_skip`                  | int                 | `4`                     | physics steps per env step |
    | `timestep_s`                  | float               | `0.005`                 | physics step (s) |
    | `default_camera_config`       | dict                | tracking, top-down      | render camera |
    | `forward_reward_weight`       | float               | `10.0`                  | weight of the forward velocity |
    | `ctrl_cost_weight`            | float               | `0.01`                  | weight of ``sum(action^2)`` |
    | `reset_noise_scale`           | float               | `0.05`                  | initial joint angle/velocity noise |
    | `depth_m`                     | float               | `0.03`                  | depth of the head centre below the surface (m) |
    | `planar`                      | bool                | `True`                  | planar root (fixed depth) or free joint |
    | `media`                       | Media or str        | `"maladen_glass_beads"` | granular medium |
    | `resolution`                  | str or float        | `"coarse"`              | sand element size (preset or m) |
    | `media_ranges`                | MediaRanges or None | `None`                  | per-episode medium randomization |
    | `include_sand_in_observation` | bool                | `False`                 | append per-link sand force and sinkage |
    | `density_scale`               | float               | `100.0`                 | density over the animal's (> 0; below 100 with the explicit solve: warned) |
    | plus ``render_mode``, ``width``, ``height``, ``camera_id``, ``camera_name`` of ``MujocoEnv`` |

    ## Version History
    * v0: first version (7 links, planar root, Maladen glass beads, 50 Hz control). ``density_scale`` added
      (2026-12-04) when the bundled model became the animal's: its default 100 is the body v0 always had (the
      joint damping differs by one unit in the last place, 1e-6 * 100).
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(
        self,
        xml_file: str = "sand_swimmer.xml",
        frame_skip: int = 4,
        *,
        timestep_s: float = 0.005,
        default_camera_config: dict[str, float | int] = DEFAULT_CAMERA_CONFIG,
        forward_reward_weight: float = 10.0,
        ctrl_cost_weight: float = 0.01,
        reset_noise_scale: float = 0.05,
        depth_m: float = 0.03,
        planar: bool = True,
        media: Media | str = "maladen_glass_beads",
        resolution: str | float = "coarse",
        media_ranges: MediaRanges | None = None,
        include_sand_in_observation: bool = False,
        density_scale: float = EXPLICIT_DENSITY_SCALE,
        **kwargs,
    ):
        utils.EzPickle.__init__(self, xml_file, frame_skip, timestep_s, default_camera_config,
                                forward_reward_weight, ctrl_cost_weight, reset_noise_scale, depth_m, planar,
                                media, resolution, media_ranges, include_sand_in_observation, density_scale,
                                **kwargs)
        if not density_scale > 0.0:
            raise ValueError(f"density_scale must be > 0 (the swimmer's density over the animal's; 100 by default, "
                             f"1 for the animal with solve='implicit'), got {density_scale!r}")
        if density_scale < EXPLICIT_DENSITY_SCALE and kwargs.get("solve", "explicit") == "explicit":
            warnings.warn(f"rft_mujoco: SandSwimmer-v0 with density_scale={density_scale!r} and the explicit sand "
                          f"solve: the body is lighter than the {EXPLICIT_DENSITY_SCALE:g}x the explicit solve "
                          "needs on it, and its swimming is off the quasi-static answer (the animal, density_scale=1: "
                          "2-3x too fast). Do: pass solve='implicit' (right at any mass), or keep the default "
                          "density_scale.", SandSetupWarning, stacklevel=2)
        if not depth_m > 0.0:
            raise ValueError(f"depth_m must be > 0 (the swimmer is buried), got {depth_m!r}")
        if not timestep_s > 0.0:
            raise ValueError(f"timestep_s must be > 0 s, got {timestep_s!r}")
        self._forward_reward_weight = forward_reward_weight
        self._ctrl_cost_weight = ctrl_cost_weight
        self._reset_noise_scale = reset_noise_scale
        self._timestep_s = float(timestep_s)
        self._depth_m = float(depth_m)
        self._planar = bool(planar)
        self._density_scale = float(density_scale)
        SandTaskEnv.__init__(self, xml_file, frame_skip, media=media, resolution=resolution,
                             sand_bodies=[f"link{i}" for i in range(1, N_JOINTS + 1)] + ["head"],
                             bed_depth_m=None, media_ranges=media_ranges,
                             include_sand_in_observation=include_sand_in_observation,
                             default_camera_config=default_camera_config, **kwargs)
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self._root = self.model.body("head").id
        self._n_root_q = 3 if self._planar else 7
        obs_size = self.data.qpos.size - 2 + self.data.qvel.size + self._sand_obs_size()
        self.observation_space = Box(low=-np.inf, high=np.inf, shape=(obs_size,), dtype=np.float64)
        self.observation_structure = {"skipped_qpos": 2, "qpos": self.data.qpos.size - 2,
                                      "qvel": self.data.qvel.size, "sand": self._sand_obs_size()}

    def _edit_spec(self, spec):
        spec.option.timestep = self._timestep_s
        head = spec.body("head")
        head.pos = [0.0, 0.0, -self._depth_m]
        for geom in spec.geoms:                # the swimmer's links (the floor, a plane of the world, has no mass)
            geom.density *= self._density_scale
        for joint in spec.joints:
            if joint.name.startswith("j"):
                joint.armature *= self._density_scale
                joint.damping *= self._density_scale
        if not self._planar:
            for name in ("root_x", "root_y", "root_yaw"):
                spec.delete(spec.joint(name))
            head.add_freejoint(name="root")
            for key in list(spec.keys):
                spec.delete(key)

    # --- reward terms ----------------------------------------------------------------------------
    def forward_reward(self, x_velocity: float) -> float:
        return self._forward_reward_weight * x_velocity

    def control_cost(self, action) -> float:
        return self._ctrl_cost_weight * float(np.sum(np.square(action)))

    # --- gymnasium API ---------------------------------------------------------------------------
    def _com_xy(self) -> np.ndarray:
        return self.data.subtree_com[self._root, :2].copy()

    def step(self, action):
        xy_before = self._com_xy()
        self.do_simulation(action, self.frame_skip)
        xy_after = self._com_xy()
        x_velocity, y_velocity = (xy_after - xy_before) / self.dt
        forward = self.forward_reward(x_velocity)
        ctrl = self.control_cost(action)
        info = {"x_position": xy_after[0], "y_position": xy_after[1], "x_velocity": x_velocity,
                "y_velocity": y_velocity, "reward_forward": forward, "reward_ctrl": -ctrl,
                **self.sand.info(self.data)}
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), forward - ctrl, False, False, info

    def _get_obs(self):
        return np.concatenate([self.data.qpos[2:], self.data.qvel, self._sand_obs()])

    def reset_model(self):
        self._randomize_media()
        noise = self._reset_noise_scale
        qpos = self.init_qpos.copy()
        qvel = self.init_qvel.copy()
        qpos[self._n_root_q:] += self.np_random.uniform(-noise, noise, size=N_JOINTS)
        qvel[self.model.nv - N_JOINTS:] += noise * self.np_random.standard_normal(N_JOINTS)
        self.set_state(qpos, qvel)
        return self._get_obs()

    def _get_reset_info(self):
        xy = self._com_xy()
        return {"x_position": xy[0], "y_position": xy[1], **self.sand.info(self.data)}
