"""SandWheel-v0: a driven wheel on a carriage pulling a drawbar load over sand."""

from __future__ import annotations

import math

import mujoco
import numpy as np
from gymnasium import utils
from gymnasium.spaces import Box

from rft_mujoco.physics.media import Media

from .sand_bed import MediaRanges
from .sand_task import SandTaskEnv

DEFAULT_CAMERA_CONFIG = {"trackbodyid": 1, "distance": 0.9, "elevation": -10.0, "azimuth": 90.0}

DRIVES = ("torque", "slip")
"""``torque``: the action is the wheel torque, the carriage carries a drawbar load (RL). ``slip``: the
action is the slip ratio; wheel and carriage are velocity-servoed (the constant-slip drawbar-pull test)."""

SLIP_EPS = 1e-3
"""Speeds (m/s) below which the slip ratio is taken as 0."""


def slip_ratio(wheel_rate_rad_s: float, carriage_speed_m_s: float, radius_m: float) -> float:
    """Slip in [-1, 1]: ``(w r - v) / max(|w r|, |v|)`` (1: spinning in place, 0: rolling, < 0: skidding)."""
    rim = wheel_rate_rad_s * radius_m
    scale = max(abs(rim), abs(carriage_speed_m_s))
    return 0.0 if scale < SLIP_EPS else float(np.clip((rim - carriage_speed_m_s) / scale, -1.0, 1.0))


class SandWheelEnv(SandTaskEnv, utils.EzPickle):
    r"""
    ## Description
    A wheel test rig (``models/sand_wheel.xml``): a rigid wheel (radius ``wheel_radius_m``, width
    ``wheel_width_m``, optional grousers) on an axle that slides freely up and down under the normal
    load ``normal_load_n``, on a carriage that slides along x. The wheel rolls on a bed of granular media
    (3D-RFT, :mod:`rft_mujoco`, loose 3 mm glass beads by default) over a rigid bottom ``bed_depth_m`` deep.

    Two drives (``drive``):

    * ``"torque"`` (RL): the action is the wheel torque; the carriage is held back by a constant drawbar
      load (drawn per episode from ``drawbar_load_n``). The task is to travel forward against the load
      with little torque and power, i.e. to produce drawbar pull at low slip.
    * ``"slip"`` (scripted): the wheel spins at ``wheel_speed_rad_s`` and the carriage is servoed to
      ``v = w r (1 - s)`` with the action ``s`` the slip ratio; ``info["drawbar_pull_n"]`` is the
      horizontal force the carriage needs to hold that speed (positive: the wheel pulls forward). A
      constant action gives the classical constant-slip drawbar-pull measurement::

          env = gymnasium.make("rft_mujoco/SandWheel-v0", drive="slip")
          env.reset(seed=0)
          for _ in range(300):
              obs, reward, terminated, truncated, info = env.step(np.array([0.3], np.float32))
          info["drawbar_pull_n"], info["wheel_torque_nm"], info["sinkage_m"]

    ## Action Space
    ``Box(-1, 1, (1,), float32)``. ``torque``: wheel torque ``= max_torque_nm * action`` (N m, positive
    drives toward +x). ``slip``: the slip ratio ``s`` (-1 .. 1).

    ## Observation Space
    ``Box(-inf, inf, (9,), float64)`` (13 with ``include_sand_in_observation=True``):

    | Num | Observation                                              | Unit  |
    |-----|----------------------------------------------------------|-------|
    | 0   | wheel angular velocity (positive rolls toward +x)        | rad/s |
    | 1   | carriage velocity along x                                | m/s   |
    | 2   | sinkage: depth of the wheel's lowest point below the surface | m |
    | 3   | axle vertical velocity                                   | m/s   |
    | 4   | slip ratio ``(w r - v) / max(|w r|, |v|)``               | -     |
    | 5   | drawbar load (torque drive; 0 for slip drive)            | N     |
    | 6   | previous action                                          | -     |
    | 7-8 | sin and cos of the wheel angle                           | -     |
    | 9-12| (optional) sand force on the wheel, world x, y, z; its sinkage | N, m |

    ## Rewards
    ``reward = forward_reward - ctrl_cost - power_cost``, each a method and in ``info``:

    - ``reward_forward`` = ``forward_reward_weight * v`` (carriage velocity, m/s);
    - ``reward_ctrl`` = ``-ctrl_cost_weight * action^2``;
    - ``reward_power`` = ``-power_cost_weight * |tau w|``, the wheel's mechanical power in W.

    ``info`` also has ``x_position`` (m), ``x_velocity`` (m/s), ``slip``, ``sinkage_m``,
    ``wheel_torque_nm`` (the torque the wheel drive applies), ``drawbar_pull_n`` (slip drive: the force
    the carriage needs to hold its speed; torque drive: the drawbar load), ``drawbar_load_n``,
    ``sand_force`` (1, 3) N and ``sand_sinkage`` (1,) m.

    ## Starting State
    Wheel at rest with its lowest point on the surface (plus ``reset_noise_scale * U(-1, 1)`` of a
    wheel radius in height, up only, and a random wheel angle); the drawbar load drawn uniformly from
    ``drawbar_load_n`` (a number or a (low, high) range in N).

    ## Episode End
    No termination. Truncated at 500 steps (10 s) by the registered TimeLimit.

    ## Arguments
    | Parameter                     | Type                | Default                  | Description |
    |-------------------------------|---------------------|--------------------------|-------------|
    | `xml_file`                    | str                 | `"sand_wheel.xml"`       | bundled model name or a path |
    | `frame_skip`                  | int                 | `10`                     | physics steps (2 ms) per env step |
    | `default_camera_config`       | dict                | side view                | render camera |
    | `drive`                       | str                 | `"torque"`               | ``"torque"`` (RL) or ``"slip"`` (constant-slip test) |
    | `max_torque_nm`               | float               | `3.0`                    | wheel torque at action 1 (torque drive), N m |
    | `wheel_speed_rad_s`           | float               | `2.0`                    | wheel speed of the slip drive, rad/s |
    | `drawbar_load_n`              | float or (lo, hi)   | `(0.0, 8.0)`             | drawbar load per episode (torque drive), N |
    | `normal_load_n`               | float               | `30.0`                   | weight of wheel + axle, N |
    | `wheel_radius_m`              | float               | `0.10`                   | wheel radius, m |
    | `wheel_width_m`               | float               | `0.06`                   | wheel width, m |
    | `grousers`                    | int                 | `0`                      | number of grousers (plates across the tread) |
    | `grouser_height_m`            | float               | `0.01`                   | grouser height, m |
    | `forward_reward_weight`       | float               | `10.0`                   | weight of the carriage velocity |
    | `ctrl_cost_weight`            | float               | `0.1`                    | weight of ``action^2`` |
    | `power_cost_weight`           | float               | `0.01`                   | weight of the wheel power (W) |
    | `reset_noise_scale`           | float               | `0.01`                   | initial height noise (fraction of the radius) |
    | `media`                       | Media or str        | `"li_loose_glass_beads"` | granular medium |
    | `resolution`                  | str or float        | `0.015`                  | sand element size (preset or m) |
    | `bed_depth_m`                 | float or None       | `0.3`                    | rigid bottom this far below the surface (None: bottomless) |
    | `media_ranges`                | MediaRanges or None | `None`                   | per-episode medium randomization |
    | `include_sand_in_observation` | bool                | `False`                  | append the wheel's sand force and sinkage |
    | plus ``render_mode``, ``width``, ``height``, ``camera_id``, ``camera_name`` of ``MujocoEnv`` |

    ## Version History
    * v0: first version.
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(
        self,
        xml_file: str = "sand_wheel.xml",
        frame_skip: int = 10,
        *,
        default_camera_config: dict[str, float | int] = DEFAULT_CAMERA_CONFIG,
        drive: str = "torque",
        max_torque_nm: float = 3.0,
        wheel_speed_rad_s: float = 2.0,
        drawbar_load_n: float | tuple[float, float] = (0.0, 8.0),
        normal_load_n: float = 30.0,
        wheel_radius_m: float = 0.10,
        wheel_width_m: float = 0.06,
        grousers: int = 0,
        grouser_height_m: float = 0.01,
        forward_reward_weight: float = 10.0,
        ctrl_cost_weight: float = 0.1,
        power_cost_weight: float = 0.01,
        reset_noise_scale: float = 0.01,
        media: Media | str = "li_loose_glass_beads",
        resolution: str | float = 0.015,
        bed_depth_m: float | None = 0.3,
        media_ranges: MediaRanges | None = None,
        include_sand_in_observation: bool = False,
        **kwargs,
    ):
        utils.EzPickle.__init__(self, xml_file, frame_skip, default_camera_config, drive, max_torque_nm,
                                wheel_speed_rad_s, drawbar_load_n, normal_load_n, wheel_radius_m, wheel_width_m,
                                grousers, grouser_height_m, forward_reward_weight, ctrl_cost_weight,
                                power_cost_weight, reset_noise_scale, media, resolution, bed_depth_m, media_ranges,
                                include_sand_in_observation, **kwargs)
        if drive not in DRIVES:
            raise ValueError(f"drive must be one of {DRIVES}, got {drive!r}")
        load = np.broadcast_to(np.asarray(drawbar_load_n, dtype=float), (2,)) if np.ndim(drawbar_load_n) == 0 \
            else np.asarray(drawbar_load_n, dtype=float)
        if load.shape != (2,) or not np.all(np.isfinite(load)) or load[0] > load[1]:
            raise ValueError(f"drawbar_load_n must be a number or (low, high) in N, got {drawbar_load_n!r}")
        for name, value in (("max_torque_nm", max_torque_nm), ("normal_load_n", normal_load_n),
                            ("wheel_radius_m", wheel_radius_m), ("wheel_width_m", wheel_width_m)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value!r}")
        if not (isinstance(grousers, (int, np.integer)) and grousers >= 0):
            raise ValueError(f"grousers must be an int >= 0, got {grousers!r}")
        self._drive = drive
        self._max_torque = float(max_torque_nm)
        self._wheel_speed = float(wheel_speed_rad_s)
        self._load_range = load.copy()
        self._normal_load = float(normal_load_n)
        self._radius = float(wheel_radius_m)
        self._width = float(wheel_width_m)
        self._grousers = int(grousers)
        self._grouser_height = float(grouser_height_m)
        self._forward_reward_weight = forward_reward_weight
        self._ctrl_cost_weight = ctrl_cost_weight
        self._power_cost_weight = power_cost_weight
        self._reset_noise_scale = reset_noise_scale
        self._drawbar_load = 0.0
        self._last_action = 0.0
        SandTaskEnv.__init__(self, xml_file, frame_skip, media=media, resolution=resolution, sand_bodies=["wheel"],
                             bed_depth_m=bed_depth_m, media_ranges=media_ranges,
                             include_sand_in_observation=include_sand_in_observation,
                             default_camera_config=default_camera_config, **kwargs)
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        m = self.model
        self._act = {name: m.actuator(name).id for name in ("wheel_torque", "drawbar", "wheel_speed", "carriage_speed")}
        self._qx, self._qz, self._qw = (m.jnt_qposadr[m.joint(n).id] for n in ("carriage_x", "axle_z", "wheel_spin"))
        self._vx, self._vz, self._vw = (m.jnt_dofadr[m.joint(n).id] for n in ("carriage_x", "axle_z", "wheel_spin"))
        self._surface_z = float(self.sand.handle.terrain.max_height)
        self._axle_z0 = float(m.body("carriage").pos[2])
        obs_size = 9 + self._sand_obs_size()
        self.observation_space = Box(low=-np.inf, high=np.inf, shape=(obs_size,), dtype=np.float64)

    def _set_action_space(self):
        self.action_space = Box(low=-1.0, high=1.0, shape=(1,), dtype=np.float32)
        return self.action_space

    def _edit_spec(self, spec):
        r, half_w = self._radius, 0.5 * self._width
        wheel = spec.geom("wheel")
        wheel.size = [r, half_w, 0.0]
        spec.geom("spoke").size = [0.8 * r, half_w + 0.001, 0.006]
        spec.body("carriage").pos = [0.0, 0.0, r]
        g = abs(spec.option.gravity[2])
        wheel_mass = wheel.mass
        ballast = self._normal_load / g - wheel_mass
        if ballast <= 0:
            raise ValueError(f"normal_load_n={self._normal_load} N is less than the wheel's own weight "
                             f"{wheel_mass * g:.2f} N")
        spec.geom("axle").mass = ballast
        body = spec.body("wheel")
        h = self._grouser_height
        for i in range(self._grousers):
            angle = 2.0 * math.pi * i / self._grousers
            grouser = body.add_geom()
            grouser.name = f"grouser{i}"
            grouser.type = mujoco.mjtGeom.mjGEOM_BOX
            grouser.size = [0.0025, half_w, 0.5 * h]
            rad = r + 0.5 * h
            grouser.pos = [rad * math.sin(angle), 0.0, rad * math.cos(angle)]
            grouser.quat = [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]
            grouser.mass = 0.0
            grouser.contype = 1
            grouser.conaffinity = 0
            grouser.rgba = [0.3, 0.3, 0.32, 1.0]
        if self._drive == "slip":
            for name, kv in (("wheel_speed", 50.0), ("carriage_speed", 2000.0)):
                act = spec.actuator(name)
                act.gainprm[0] = kv
                act.biasprm[2] = -kv

    # --- state -----------------------------------------------------------------------------------
    def _wheel_rate(self) -> float:
        # wheel_spin turns about +y; a positive rate about +y rolls a wheel toward +x.
        return float(self.data.qvel[self._vw])

    def sinkage_m(self) -> float:
        """Depth of the wheel's lowest point (rim) below the surface, m (negative when above)."""
        axle_height = self._axle_z0 + self.data.qpos[self._qz] - self._surface_z
        return float(self._radius - axle_height)

    def slip(self) -> float:
        return slip_ratio(self._wheel_rate(), float(self.data.qvel[self._vx]), self._radius)

    def wheel_torque_nm(self) -> float:
        return float(self.data.actuator_force[self._act["wheel_torque"]]
                     + self.data.actuator_force[self._act["wheel_speed"]])

    # --- reward terms ----------------------------------------------------------------------------
    def forward_reward(self, x_velocity: float) -> float:
        return self._forward_reward_weight * x_velocity

    def control_cost(self, action) -> float:
        return self._ctrl_cost_weight * float(np.sum(np.square(action)))

    def power_cost(self) -> float:
        return self._power_cost_weight * abs(self.wheel_torque_nm() * self._wheel_rate())

    # --- gymnasium API ---------------------------------------------------------------------------
    def _ctrl(self, action) -> np.ndarray:
        ctrl = np.zeros(self.model.nu)
        a = float(np.clip(action[0], -1.0, 1.0))
        if self._drive == "torque":
            ctrl[self._act["wheel_torque"]] = self._max_torque * a
            ctrl[self._act["drawbar"]] = -self._drawbar_load
        else:
            ctrl[self._act["wheel_speed"]] = self._wheel_speed
            ctrl[self._act["carriage_speed"]] = self._wheel_speed * self._radius * (1.0 - a)
        return ctrl

    def step(self, action):
        action = np.asarray(action, dtype=np.float64).reshape(1)
        x_before = float(self.data.qpos[self._qx])
        self.do_simulation(self._ctrl(action), self.frame_skip)
        x_after = float(self.data.qpos[self._qx])
        x_velocity = (x_after - x_before) / self.dt
        forward = self.forward_reward(x_velocity)
        ctrl_cost = self.control_cost(action)
        power_cost = self.power_cost()
        self._last_action = float(action[0])
        if self._drive == "slip":
            drawbar_pull = -float(self.data.actuator_force[self._act["carriage_speed"]])
        else:
            drawbar_pull = self._drawbar_load
        info = {"x_position": x_after, "x_velocity": x_velocity, "slip": self.slip(), "sinkage_m": self.sinkage_m(),
                "wheel_torque_nm": self.wheel_torque_nm(), "drawbar_pull_n": drawbar_pull,
                "drawbar_load_n": self._drawbar_load, "reward_forward": forward, "reward_ctrl": -ctrl_cost,
                "reward_power": -power_cost, **self.sand.info(self.data)}
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), forward - ctrl_cost - power_cost, False, False, info

    def _get_obs(self):
        angle = float(self.data.qpos[self._qw])
        load = self._drawbar_load if self._drive == "torque" else 0.0
        return np.concatenate([[self._wheel_rate(), self.data.qvel[self._vx], self.sinkage_m(),
                                self.data.qvel[self._vz], self.slip(), load, self._last_action,
                                math.sin(angle), math.cos(angle)], self._sand_obs()])

    def reset_model(self):
        self._randomize_media()
        lo, hi = self._load_range
        self._drawbar_load = float(lo + self.np_random.uniform() * (hi - lo))
        self._last_action = 0.0
        qpos = self.init_qpos.copy()
        qvel = self.init_qvel.copy()
        qpos[self._qz] += self._reset_noise_scale * self._radius * self.np_random.uniform()
        qpos[self._qw] = self.np_random.uniform(-math.pi, math.pi)
        self.set_state(qpos, qvel)
        return self._get_obs()

    def _get_reset_info(self):
        return {"x_position": float(self.data.qpos[self._qx]), "sinkage_m": self.sinkage_m(),
                "drawbar_load_n": self._drawbar_load, **self.sand.info(self.data)}
