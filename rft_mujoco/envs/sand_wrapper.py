"""Any Gymnasium MuJoCo locomotion env on sand: ``SandAntEnv``, ``SandHalfCheetahEnv``, ... and a factory.

:func:`sand_env_class` derives a sand version of a :class:`gymnasium.envs.mujoco.MujocoEnv` subclass (its
rewards, observations, termination and arguments are unchanged unless stated below);
:func:`make_sand_env` builds one from a registered id::

    import gymnasium, rft_mujoco.envs
    env = gymnasium.make("rft_mujoco/SandAnt-v0", render_mode="rgb_array")
    env = rft_mujoco.envs.make_sand_env("Humanoid-v5", media="maladen_glass_beads", bed_depth_m=0.1)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import gymnasium
import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.envs.mujoco.ant_v5 import AntEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.envs.mujoco.hopper_v5 import HopperEnv
from gymnasium.envs.mujoco.humanoid_v5 import HumanoidEnv
from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv
from gymnasium.envs.registration import load_env_creator
from gymnasium.spaces import Box

from rft_mujoco.physics.media import Media

from .camera import track_body
from .sand_bed import FEATURES_PER_BODY, MediaRanges, SandBed, initialize_sand_simulation, step_with_sand

DEFAULT_MEDIA = "li_loose_glass_beads"
"""Loose 3 mm glass beads (Li, Zhang & Goldman 2013, legged locomotion on granular media)."""

_SPEC = """Sand version of :class:`{base_module}.{base}`: the rigid floor is a bed of granular media (3D-RFT,
:mod:`rft_mujoco`). Rewards, termination and every base argument are those of ``{base}`` (see its
docstring); the sand changes the following.

## Sand
The floor plane stops colliding (``bed_depth_m=None``) or is lowered to a rigid bottom ``bed_depth_m``
below the sand surface (the floor's original height). Sand forces act on ``sand_bodies`` (default
``"auto"``: foot-like names and distal links, see :func:`rft_mujoco.envs.sand_bed.auto_sand_bodies`).
Sand forces enter through ``xfrc_applied`` but are kept out of ``cfrc_ext`` (its observation and
``contact_cost`` still mean rigid contact) unless ``sand_in_contact_forces=True``.

## Observation Space
The base observation, followed, when ``include_sand_in_observation=True``, by 4 entries per sand body
(in ``env.unwrapped.sand.body_names`` order):

| Num        | Observation                                        | Min  | Max | Unit |
|------------|----------------------------------------------------|------|-----|------|
| base + 4 i | sand force on body i, world x                      | -Inf | Inf | N    |
| base+4i+1  | sand force on body i, world y                      | -Inf | Inf | N    |
| base+4i+2  | sand force on body i, world z                      | -Inf | Inf | N    |
| base+4i+3  | sinkage of body i (depth of its deepest loaded element) | 0 | Inf | m    |

## Action Space
Unchanged (``{base}``).

## Rendering
Without ``camera_id`` or ``camera_name`` the camera follows the root body (MuJoCo's tracking camera,
:func:`rft_mujoco.envs.camera.track_body`; the base env's free camera stays where the robot started).

## Rewards, Termination, Truncation
Unchanged. ``info`` adds ``sand_force`` (B, 3) N and ``sand_sinkage`` (B,) m; ``env.unwrapped.sand.media``
is the medium of the current episode.

## Arguments (in addition to ``{base}``'s)
| Parameter                     | Type               | Default                  | Description |
|-------------------------------|--------------------|--------------------------|-------------|
| `media`                       | Media or str       | `"li_loose_glass_beads"` | the granular medium (a preset name or ``rft_mujoco.Media``) |
| `resolution`                  | str or float       | `{resolution!r}`         | surface element size (preset name or m) |
| `sand_bodies`                 | "auto" or names    | `"auto"`                 | bodies that feel the sand (names or ids) |
| `bed_depth_m`                 | float or None      | `None`                   | rigid bottom this far below the surface (m); None: bottomless |
| `sand_in_contact_forces`      | bool               | `False`                  | let the sand wrench show in ``cfrc_ext`` (observation, contact cost) |
| `include_sand_in_observation` | bool               | `False`                  | append per-body sand force and sinkage |
| `media_ranges`                | MediaRanges or None| `None`                   | per-episode uniform ranges for rho_c, mu_int, mu_surf |
| `stabilize`                   | bool               | `True`                   | the coupling's implicit direction and impulse limiter |
| `solve`                       | str or None        | `None`                   | the sand solve: `"explicit"` or `"implicit"` (docs/rest.md); None: `attach`'s default (`"explicit"`) |
| `reuse_tol`                   | float or None      | `None`                   | `attach`'s: a body's wrench reused while its motion and pose hold (0: off); None: `attach`'s default (`1e-3`) |
| `rk4_stages`                  | str                | `"midpoint"`             | `attach`'s, with RK4: the sand at a step's first two stages, the second's wrench held (`"all"`: every stage, 15% more time per SandAnt-v0 env step; docs/performance.md, "2c. RK4 stages") |

## Version History
* v0: first version (mujoco 4.0.0, gymnasium 1.4 ``{base}`` v5 assets). Since 2026-12-04 the sand is evaluated at
  two of RK4's four stages (``rk4_stages="midpoint"``); ``rk4_stages="all"`` gives the dynamics from before.
"""


class _SandEnv:
    """Mixin placed before a MujocoEnv subclass by :func:`sand_env_class`."""

    _sand_resolution: str | float = "coarse"

    def __init__(self, *, media: Media | str = DEFAULT_MEDIA, resolution: str | float | None = None,
                 sand_bodies: str | Sequence[str | int] = "auto", bed_depth_m: float | None = None,
                 sand_in_contact_forces: bool = False, include_sand_in_observation: bool = False,
                 media_ranges: MediaRanges | None = None, stabilize: bool = True, solve: str | None = None,
                 reuse_tol: float | None = None, rk4_stages: str = "midpoint", **base_kwargs):
        resolution = self._sand_resolution if resolution is None else resolution
        self.sand = None
        self._bed_depth_m = bed_depth_m
        super().__init__(**base_kwargs)
        if base_kwargs.get("camera_id") is None and base_kwargs.get("camera_name") is None:
            track_body(self)  # the base renders from a free camera that the robot walks out of
        utils.EzPickle.__init__(self, media=media, resolution=resolution, sand_bodies=sand_bodies,
                                bed_depth_m=bed_depth_m, sand_in_contact_forces=sand_in_contact_forces,
                                include_sand_in_observation=include_sand_in_observation,
                                media_ranges=media_ranges, stabilize=stabilize, solve=solve, reuse_tol=reuse_tol,
                                rk4_stages=rk4_stages, **base_kwargs)
        self._sand_in_contact_forces = bool(sand_in_contact_forces)
        self._include_sand_in_observation = bool(include_sand_in_observation)
        self.sand = SandBed(self.model, media, bodies=sand_bodies, resolution=resolution,
                            surface=self._surface_geoms, media_ranges=media_ranges, stabilize=stabilize,
                            solve=solve, reuse_tol=reuse_tol, rk4_stages=rk4_stages)
        if self._include_sand_in_observation:
            extra = FEATURES_PER_BODY * self.sand.n_bodies
            base = self.observation_space
            self.observation_space = Box(low=-np.inf, high=np.inf, shape=(base.shape[0] + extra,),
                                         dtype=base.dtype)
            if hasattr(self, "observation_structure"):
                self.observation_structure = {**self.observation_structure, "sand": extra}

    def _initialize_simulation(self):
        return initialize_sand_simulation(self, self._bed_depth_m)

    def _step_mujoco_simulation(self, ctrl, n_frames):
        step_with_sand(self, ctrl, n_frames, include_sand=self._sand_in_contact_forces)

    def _get_obs(self):
        obs = super()._get_obs()
        if self.sand is not None and self._include_sand_in_observation:
            obs = np.concatenate([obs, self.sand.features(self.data)]).astype(obs.dtype, copy=False)
        return obs

    def reset_model(self):
        self.sand.randomize(self.np_random)
        return super().reset_model()

    def step(self, action):
        observation, reward, terminated, truncated, info = super().step(action)
        info.update(self.sand.info(self.data))
        return observation, reward, terminated, truncated, info

    def close(self):
        if self.sand is not None:
            self.sand.close()
        super().close()


def sand_env_class(base: type, *, resolution: str | float = "coarse", name: str | None = None) -> type:
    """A subclass of the MujocoEnv subclass ``base`` that stands on sand (see the class docstring).

    Args:
        base: a :class:`gymnasium.envs.mujoco.MujocoEnv` subclass whose step calls ``do_simulation``.
        resolution: the default element size of the new class (preset name or m).
        name: class name (default ``"Sand" + base.__name__``).
    """
    if not (isinstance(base, type) and issubclass(base, MujocoEnv)):
        raise TypeError(f"base must be a gymnasium MujocoEnv subclass, got {base!r}; for an env id use "
                        "make_sand_env(env_id)")
    name = name or f"Sand{base.__name__}"
    doc = _SPEC.format(base=base.__name__, base_module=base.__module__, resolution=resolution)
    return type(name, (_SandEnv, base), {"__doc__": doc, "__module__": __name__, "__qualname__": name,
                                         "_sand_resolution": resolution})


SandAntEnv = sand_env_class(AntEnv, resolution=0.04)
SandHalfCheetahEnv = sand_env_class(HalfCheetahEnv, resolution="coarse")
SandHopperEnv = sand_env_class(HopperEnv, resolution="coarse")
SandWalker2dEnv = sand_env_class(Walker2dEnv, resolution="coarse")
SandHumanoidEnv = sand_env_class(HumanoidEnv, resolution=0.03)


def make_sand_env(env_id: str, **kwargs) -> gymnasium.Env:
    """``gymnasium.make`` of a registered MuJoCo env id (e.g. ``"Ant-v5"``), on sand.

    ``kwargs`` are the sand arguments of :func:`sand_env_class`'s classes and the base env's own; the
    result has the base id's time limit and the usual Gymnasium wrappers. Its ``spec.id`` is a registered
    id that ``gymnasium.make`` rebuilds exactly: the package's own (``"Ant-v5"`` ->
    ``rft_mujoco/SandAnt-v0``, the same env as ``gymnasium.make("rft_mujoco/SandAnt-v0")``) when one is
    registered on the same base class and arguments, else one that this call registers (:func:`sand_id`).
    """
    return gymnasium.make(sand_id(env_id), **kwargs)


def _sand_base(spec) -> tuple[type, dict] | None:
    """(base MujocoEnv class, base kwargs) of a registered sand spec, None for any other spec."""
    entry = spec.entry_point
    cls = load_env_creator(entry) if isinstance(entry, str) else entry
    if not (isinstance(cls, type) and issubclass(cls, _SandEnv)):
        return None
    return cls.__mro__[cls.__mro__.index(_SandEnv) + 1], dict(spec.kwargs)


def sand_id(env_id: str) -> str:
    """The registered sand id of the Gymnasium MuJoCo env ``env_id``, registering one when needed.

    ``rft_mujoco/Sand<Name>-v0`` when it exists on the same base class and base arguments (``Ant-v5`` ->
    ``rft_mujoco/SandAnt-v0``); otherwise ``rft_mujoco/Sand<Name>_v<version>-v0`` (``Ant-v4`` ->
    ``rft_mujoco/SandAnt_v4-v0``), registered here with the base's time limit, arguments and the default
    element size ``"coarse"``. ValueError for an id that is not a MuJoCo env."""
    spec = gymnasium.spec(env_id)
    entry = spec.entry_point
    base = load_env_creator(entry) if isinstance(entry, str) else entry
    if not (isinstance(base, type) and issubclass(base, MujocoEnv)):
        raise ValueError(f"{env_id!r} is not a MuJoCo env (entry point {entry!r}); make_sand_env needs a "
                         "gymnasium MujocoEnv such as 'Ant-v5', 'HalfCheetah-v5', 'Hopper-v5'")
    if issubclass(base, _SandEnv):
        return spec.id
    wanted = (base, dict(spec.kwargs))
    for candidate in (f"rft_mujoco/Sand{spec.name}-v0", f"rft_mujoco/Sand{spec.name}_v{spec.version}-v0"):
        if candidate not in gymnasium.registry:
            break
        if _sand_base(gymnasium.registry[candidate]) == wanted:
            return candidate
    else:
        raise ValueError(f"cannot register a sand id for {env_id!r}: {candidate!r} is taken by another env")
    gymnasium.registry[candidate] = dataclasses.replace(
        spec, id=candidate, entry_point=sand_env_class(base), kwargs=dict(spec.kwargs), vector_entry_point=None)
    return candidate
