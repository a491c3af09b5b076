"""Base class of the native sand tasks: a bundled MJCF model, edited by the task, on a sand bed.

A task subclass sets its arguments, then calls :meth:`SandTaskEnv.__init__`, which

1. loads ``models/<xml_file>`` into an ``MjSpec``, lets the task edit it (:meth:`SandTaskEnv._edit_spec`:
   timestep, loads, joints) and compiles it (compiling works while other sand envs run: the library's
   dispatcher suspends its callback around compilation);
2. turns the floor into sand (optionally over a rigid bottom) and attaches 3D-RFT to the task's bodies
   (:class:`~.sand_bed.SandBed`);
3. keeps ``cfrc_ext`` free of sand after each step and draws a new medium at each reset when asked.
"""

from __future__ import annotations

import importlib.resources
import os
from collections.abc import Sequence

import mujoco
import numpy as np
from gymnasium.envs.mujoco import MujocoEnv

from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.physics.media import Media
from rft_mujoco.physics.terrain import FlatSurface

from .sand_bed import FEATURES_PER_BODY, MediaRanges, SandBed, initialize_sand_simulation, step_with_sand


DEFORMABLE_GRID = {"size": (4.0, 2.0), "cell": 0.01, "center": (1.0, 0.0)}
"""The grid of ``deformable=True`` (m): 4 x 2 m around x = 1 m (the tasks move toward +x), 1 cm cells."""


def deformable_surface(deformable, terrain) -> DeformableSurface:
    """The terrain of a task's ``deformable`` argument (True or a DeformableSurface) over its flat ``terrain``."""
    if isinstance(deformable, DeformableSurface):
        return deformable
    if deformable is not True:
        raise TypeError(f"deformable must be None, False, True or a rft_mujoco.DeformableSurface, got {deformable!r}")
    if not isinstance(terrain, FlatSurface):
        raise ValueError(f"deformable=True needs a flat floor, this task's sand surface is a {type(terrain).__name__}; "
                         "pass deformable=rft_mujoco.DeformableSurface(height=..., size=..., center=...) instead")
    return DeformableSurface(height=terrain.height, **DEFORMABLE_GRID)


def model_path(xml_file: str) -> str:
    """Absolute path of a bundled model (``rft_mujoco/models/<xml_file>``), or ``xml_file`` if it is a path."""
    if os.sep in xml_file or xml_file.startswith("."):
        return xml_file
    path = importlib.resources.files("rft_mujoco.models") / xml_file
    if not path.is_file():
        names = sorted(p.name for p in importlib.resources.files("rft_mujoco.models").iterdir()
                       if p.name.endswith(".xml"))
        raise ValueError(f"no bundled model {xml_file!r}; bundled models are {names}")
    return str(path)


class SandTaskEnv(MujocoEnv):
    """A MujocoEnv whose model is a bundled MJCF on sand. Subclasses set ``self._sand_*`` first.

    Every task takes ``deformable`` (keyword, default None: the sand's free surface never changes): True for
    a :class:`~rft_mujoco.DeformableSurface` at the floor's height with :data:`DEFORMABLE_GRID`, or a
    ``DeformableSurface`` of the caller's. Its bodies then leave footprints and ruts that later steps of the
    episode feel (:mod:`rft_mujoco.physics.deform`); a reset restores the initial surface. It runs compiled
    (docs/deformable.md, "The cost": the trotting quadruped at about 1.3 times its flat-surface cost).

    Every task also takes ``solve`` (keyword; default: :func:`rft_mujoco.attach`'s, ``"explicit"``): the sand
    solve (``"implicit"``: right at any mass, docs/rest.md, "The implicit solve"), and ``reuse_tol`` (keyword,
    default: attach's, 1e-3; 0: off): :func:`rft_mujoco.attach`'s, a body's wrench reused while its motion and pose
    hold.
    """

    def __init__(self, xml_file: str, frame_skip: int, *, media: Media | str, resolution: str | float,
                 sand_bodies: str | Sequence[str | int], bed_depth_m: float | None,
                 media_ranges: MediaRanges | None, include_sand_in_observation: bool, **kwargs):
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, (int, np.integer)) or frame_skip < 1:
            raise ValueError(f"frame_skip must be an int >= 1 (physics steps per env step), got {frame_skip!r}")
        self.sand = None
        self._include_sand_in_observation = bool(include_sand_in_observation)
        self._bed_depth_m = bed_depth_m
        deformable = kwargs.pop("deformable", None)
        solve = kwargs.pop("solve", None)
        reuse_tol = kwargs.pop("reuse_tol", None)
        MujocoEnv.__init__(self, model_path(xml_file), frame_skip, observation_space=None, **kwargs)
        self.sand = SandBed(self.model, media, bodies=sand_bodies, resolution=resolution,
                            surface=self._surface_geoms, media_ranges=media_ranges, solve=solve, reuse_tol=reuse_tol)
        if deformable is not None and deformable is not False:
            self.sand.handle.terrain = deformable_surface(deformable, self.sand.handle.terrain)

    # --- model -----------------------------------------------------------------------------------
    def _edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Task-specific changes to the model before compilation (default: none)."""

    def _initialize_simulation(self):
        return initialize_sand_simulation(self, self._bed_depth_m, self._edit_spec)

    # --- sand ------------------------------------------------------------------------------------
    def _step_mujoco_simulation(self, ctrl, n_frames):
        step_with_sand(self, ctrl, n_frames)

    def _sand_obs(self) -> np.ndarray:
        """Per-body sand force (N) and sinkage (m), or an empty array when not observed."""
        if not self._include_sand_in_observation:
            return np.zeros(0)
        return self.sand.features(self.data)

    def _sand_obs_size(self) -> int:
        return FEATURES_PER_BODY * self.sand.n_bodies if self._include_sand_in_observation else 0

    def _randomize_media(self) -> None:
        self.sand.randomize(self.np_random)

    def close(self):
        if self.sand is not None:
            self.sand.close()
        super().close()
