"""The sand bed shared by every task: floor handling, body choice, media randomization, observations.

* :func:`make_sand_floor` edits an ``MjSpec`` before compilation: the floor (every colliding plane or
  heightfield geom of the world body) stops colliding but still draws the sand surface; optionally an
  invisible rigid bottom is added ``bed_depth_m`` below it. (Moving a world geom after compilation does
  not work: MuJoCo 4.0 keeps the compiled pose of static world geoms, so the edit happens in the spec.)
* :class:`SandBed` attaches 3D-RFT sand (:func:`rft_mujoco.attach`) to the chosen bodies, with the free
  surface at the floor's height (a plane) or shape (a heightfield);
* :meth:`SandBed.post_constraint` recomputes MuJoCo's ``cfrc_ext`` without the sand wrench, so that the
  contact-force observations and contact costs of Gymnasium's envs keep meaning *rigid contact* (the
  sand acts through ``xfrc_applied``, which ``mj_rnePostConstraint`` would otherwise add to ``cfrc_ext``);
* :class:`MediaRanges` draws a new medium per episode;
* :meth:`SandBed.features` gives per-body sand force and sinkage as an observation block.
"""

from __future__ import annotations

import dataclasses
import math
import re
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np

import rft_mujoco
from rft_mujoco.compiled.share import put_back_rows, take_out_rows
from rft_mujoco.coupling.checks import COARSE_MESSAGE
from rft_mujoco.physics.media import MU_INT_RANGE, RHO_C_RANGE, Media
from rft_mujoco.physics.terrain import HeightfieldSurface

FOOT_NAME_PATTERN = re.compile(r"foot|feet|toe|paw|shin|calf|ankle", re.IGNORECASE)
"""Body names that :func:`auto_sand_bodies` takes as touching the ground."""

FEATURES_PER_BODY = 4
"""Sand observation entries per body: world force x, y, z (N) and sinkage (m)."""

_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
_HFIELD = int(mujoco.mjtGeom.mjGEOM_HFIELD)


@dataclasses.dataclass(frozen=True)
class MediaRanges:
    """Uniform per-episode ranges for the medium; ``None`` keeps the base medium's value.

    Attributes:
        rho_c: (low, high) bulk density, kg/m^3.
        mu_int: (low, high) internal friction coefficient.
        mu_surf: (low, high) intruder-grain friction coefficient; clipped to the drawn ``mu_int``.
    """

    rho_c: tuple[float, float] | None = (1300.0, 1800.0)
    mu_int: tuple[float, float] | None = (0.3, 0.5)
    mu_surf: tuple[float, float] | None = (0.2, 0.4)

    def __post_init__(self) -> None:
        limits = {"rho_c": RHO_C_RANGE, "mu_int": MU_INT_RANGE, "mu_surf": (0.0, MU_INT_RANGE[1])}
        for name, (lo_ok, hi_ok) in limits.items():
            value = getattr(self, name)
            if value is None:
                continue
            if (len(value) != 2 or not all(math.isfinite(v) for v in value)
                    or not lo_ok <= value[0] <= value[1] <= hi_ok):
                raise ValueError(f"MediaRanges.{name} must be (low, high) with {lo_ok} <= low <= high <= "
                                 f"{hi_ok}, got {value!r}")

    def sample(self, rng: np.random.Generator, base: Media) -> Media:
        """A medium with each ranged field drawn uniformly from ``rng`` (3 draws, always, in this order)."""
        u = rng.uniform(size=3)
        rho_c = base.rho_c if self.rho_c is None else self.rho_c[0] + u[0] * (self.rho_c[1] - self.rho_c[0])
        mu_int = base.mu_int if self.mu_int is None else self.mu_int[0] + u[1] * (self.mu_int[1] - self.mu_int[0])
        mu_surf = base.mu_surf if self.mu_surf is None else \
            self.mu_surf[0] + u[2] * (self.mu_surf[1] - self.mu_surf[0])
        return base.replace(rho_c=float(rho_c), mu_int=float(mu_int), mu_surf=float(min(mu_surf, mu_int)),
                            name=f"{base.name}~random")


SAND_BOTTOM_PREFIX = "sand_bottom"
"""Name prefix of the rigid bottom geoms :func:`make_sand_floor` adds."""

_COPIED_GEOM_FIELDS = ("type", "size", "quat", "hfieldname", "contype", "conaffinity", "condim", "friction",
                       "solref", "solimp", "solmix", "margin", "gap", "priority")


def make_sand_floor(spec: mujoco.MjSpec, bed_depth_m: float | None = None) -> list[str]:
    """Edit ``spec`` (before compiling) so that its floor becomes the surface of a sand bed.

    Every colliding plane or heightfield geom of the world body stops colliding but stays visible (it
    draws the sand surface). With ``bed_depth_m`` a copy of each, invisible and colliding, is added
    ``bed_depth_m`` below it: a rigid bottom under that depth of sand.

    Returns:
        the names of the (now non-colliding) surface geoms, to pass as ``SandBed(surface=...)``.
    """
    if bed_depth_m is not None and not (math.isfinite(bed_depth_m) and bed_depth_m > 0):
        raise ValueError(f"bed_depth_m must be None (no rigid bottom) or a depth > 0 in m, got {bed_depth_m!r}")
    floors = [g for g in spec.worldbody.geoms
              if int(g.type) in (_PLANE, _HFIELD) and (g.contype or g.conaffinity)]
    if not floors:
        raise ValueError("the model has no colliding plane or hfield geom in the world body to turn into sand; "
                         "add a floor plane (its height is the sand surface)")
    names = []
    for i, g in enumerate(floors):
        if not g.name:
            g.name = f"sand_surface{i}"
        names.append(g.name)
        if bed_depth_m is not None:
            bottom = spec.worldbody.add_geom()
            for field in _COPIED_GEOM_FIELDS:
                setattr(bottom, field, getattr(g, field))
            bottom.name = f"{SAND_BOTTOM_PREFIX}{i}"
            bottom.pos = [g.pos[0], g.pos[1], g.pos[2] - bed_depth_m]
            bottom.rgba = [0.0, 0.0, 0.0, 0.0]
        g.contype = 0
        g.conaffinity = 0
    return names


def initialize_sand_simulation(env, bed_depth_m: float | None, edit=None):
    """``MujocoEnv._initialize_simulation`` for a sand env: the compiled sand model (offscreen buffer at
    least the env's render size), its MjData, and the names of the surface geoms stored on ``env``."""
    model, env._surface_geoms = compile_sand_model(env.fullpath, bed_depth_m, edit)
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, env.width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, env.height)
    return model, mujoco.MjData(model)


def step_with_sand(env, ctrl, n_frames: int, include_sand: bool = False) -> None:
    """``MujocoEnv._step_mujoco_simulation`` for a sand env: step, then keep cfrc_ext free of sand."""
    env.data.ctrl[:] = ctrl
    mujoco.mj_step(env.model, env.data, nstep=n_frames)
    env.sand.post_constraint(env.data, include_sand=include_sand)


def compile_sand_model(xml_path: str, bed_depth_m: float | None = None, edit=None):
    """Load ``xml_path`` into an MjSpec, apply ``edit(spec)`` (if given) and :func:`make_sand_floor`, compile.

    Returns:
        (model, surface_geom_names).
    """
    spec = mujoco.MjSpec.from_file(xml_path)
    if edit is not None:
        edit(spec)
    names = make_sand_floor(spec, bed_depth_m)
    return spec.compile(), names


def _geom_surface(model, g: int):
    """The sand free surface of floor geom ``g``: a height in m (plane) or a HeightfieldSurface."""
    if int(model.geom_type[g]) == _HFIELD:
        return HeightfieldSurface.from_model(model, g)
    if int(model.geom_type[g]) != _PLANE or model.geom_bodyid[g] != 0:
        raise ValueError(f"surface geom {model.geom(g).name!r} must be a plane or hfield of the world body")
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, model.geom_quat[g])
    if mat[8] < 1.0 - 1e-9:
        raise ValueError(f"floor plane {model.geom(g).name!r} is tilted (normal {mat[2::3].round(4).tolist()}); "
                         "the sand bed needs a horizontal floor: pass a height or terrain as surface")
    return float(model.geom_pos[g][2])


def surface_of(model, geoms: Sequence[str | int]):
    """The sand surface (a height in m or a HeightfieldSurface) of the floor geoms ``geoms``."""
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) if isinstance(g, str) else int(g) for g in geoms]
    if not ids or min(ids) < 0:
        raise ValueError(f"surface geoms {list(geoms)} not all found in the model")
    surfaces = [_geom_surface(model, g) for g in ids]
    if len(surfaces) > 1 and not all(isinstance(s, float) and s == surfaces[0] for s in surfaces):
        raise ValueError(f"floor geoms {list(geoms)} have different surfaces; pass one height or terrain")
    return surfaces[0]


def all_sand_bodies(model) -> list[int]:
    """Every body (but the world) with a non-terrain geom: whatever part of the robot reaches the sand feels it."""
    has_geom = np.zeros(model.nbody, dtype=bool)
    for g in range(model.ngeom):
        if int(model.geom_type[g]) not in (_PLANE, _HFIELD):
            has_geom[model.geom_bodyid[g]] = True
    return [b for b in range(1, model.nbody) if has_geom[b]]


def auto_sand_bodies(model) -> list[int]:
    """Bodies that usually touch the ground: foot-like names (:data:`FOOT_NAME_PATTERN`) and the leaves of
    the kinematic tree (distal links), each only if it has a non-terrain geom.

    Falls back to every body with a non-terrain geom when neither rule finds one. Examples (Gymnasium
    v5): Ant -> the four lower legs (unnamed leaves); HalfCheetah -> bshin, bfoot, fshin, ffoot; Hopper ->
    foot; Walker2d -> foot, foot_left; Humanoid -> shins, feet and lower arms.
    """
    with_geom = all_sand_bodies(model)
    has_geom = np.zeros(model.nbody, dtype=bool)
    has_geom[with_geom] = True
    parents = set(int(p) for p in model.body_parentid[1:])
    picked = [b for b in range(1, model.nbody) if has_geom[b]
              and (b not in parents or FOOT_NAME_PATTERN.search(model.body(b).name or ""))]
    return picked or with_geom


class SandBed:
    """Sand under one compiled MjModel: RFT forces on some bodies, media randomization, observations.

    Args:
        model: the MjModel, usually compiled from a spec edited by :func:`make_sand_floor`.
        media: a :class:`rft_mujoco.Media` or a preset name.
        bodies: body names or ids, ``"auto"`` (:func:`auto_sand_bodies`) or ``"all"`` (every body with a
            non-terrain geom, :func:`all_sand_bodies`).
        resolution: element size, a preset name or metres (see ``rft_mujoco.geometry.surface.RESOLUTIONS``).
        surface: the free surface: names or ids of floor geoms (:func:`surface_of`), a height in m or a
            terrain object (``rft_mujoco.FlatSurface``, ``HeightfieldSurface``, ``SandRegion``).
        media_ranges: per-episode randomization (:meth:`randomize`), or None.
        stabilize: passed to :func:`rft_mujoco.attach`.
        solve: the sand solve, passed to :func:`rft_mujoco.attach` when given (``"explicit"`` or
            ``"implicit"``: docs/rest.md); None: attach's default.
        reuse_tol: passed to :func:`rft_mujoco.attach` when given (0: off); None: attach's default (1e-3).
        rk4_stages: passed to :func:`rft_mujoco.attach` when given ("all", "midpoint" or "first": the RK4
            stages at which the sand is evaluated); None: attach's default ("all").
    """

    def __init__(self, model, media: Media | str, bodies: str | Sequence[str | int] = "auto",
                 resolution: str | float = "coarse", surface=0.0, media_ranges: MediaRanges | None = None,
                 stabilize: bool = True, solve: str | None = None, reuse_tol: float | None = None,
                 rk4_stages: str | None = None):
        if media_ranges is not None and not isinstance(media_ranges, MediaRanges):
            raise TypeError(f"media_ranges must be a MediaRanges or None, got {type(media_ranges).__name__}")
        self.model = model
        self.base_media = rft_mujoco.get_media(media)
        self.media_ranges = media_ranges
        if isinstance(surface, (list, tuple)):
            surface = surface_of(model, surface)
        if isinstance(bodies, str):
            ids = {"auto": auto_sand_bodies, "all": all_sand_bodies}.get(bodies, lambda _: [bodies])(model)
        else:
            ids = list(bodies)
        # monitor=False: random exploration leaves the quasi-static range all the time; a validity warning
        # per environment instance would be noise (the library's monitor is for scripted scenes).
        # A task's resolution is a speed trade made on purpose: the notice about bodies thinner than two
        # elements (rft_mujoco.coupling.checks.check_resolution) would come with every env instance.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=COARSE_MESSAGE, category=rft_mujoco.SandSetupWarning)
            self.handle = rft_mujoco.attach(model, self.base_media, bodies=ids, surface_height=surface,
                                            resolution=resolution, stabilize=stabilize, monitor=False,
                                            **{k: v for k, v in (("solve", solve), ("reuse_tol", reuse_tol),
                                                                 ("rk4_stages", rk4_stages)) if v is not None})
        # A bed (an env) dropped without close() detaches its sand when collected, even where something else
        # still holds its model (the library detaches a handle by itself only when its model is collected).
        self._detach = weakref.finalize(self, self.handle.detach)
        self.body_ids = self.handle.body_ids
        self.body_names = [n or f"body{b}" for n, b in zip(self.handle.body_names, self.body_ids)]
        self.n_bodies = len(self.body_ids)

    @property
    def media(self) -> Media:
        """The medium now in use."""
        return self.handle.media

    def randomize(self, rng: np.random.Generator) -> Media:
        """Draw a new medium (when ``media_ranges`` is set) and use it from the next evaluation on."""
        if self.media_ranges is not None:
            self.handle.media = self.media_ranges.sample(rng, self.base_media)
        return self.handle.media

    def post_constraint(self, data, include_sand: bool = False) -> None:
        """``mj_rnePostConstraint`` (fills ``cfrc_ext``), without the sand wrench unless ``include_sand``.

        The sand wrench of the latest evaluation is taken out of ``xfrc_applied`` for the call and then
        put back bit for bit (the coupling recognises its own rows by their exact value).
        """
        if include_sand or not self.handle.attached:
            mujoco.mj_rnePostConstraint(self.model, data)
            return
        diag = self.handle.diagnostics(data)
        xfrc, saved = data.xfrc_applied, np.empty((self.n_bodies, 6))
        take_out_rows(xfrc, self.body_ids, diag.force, diag.torque, saved)     # compiled: a third of the numpy
        try:                                                                    # indexing's 11 us (SandAnt-v0)
            mujoco.mj_rnePostConstraint(self.model, data)
        finally:
            put_back_rows(xfrc, self.body_ids, saved)

    def features(self, data) -> np.ndarray:
        """(4 B,) float: per sand body, world force x, y, z in N and sinkage (deepest loaded element) in m."""
        diag = self.handle.diagnostics(data)
        return np.concatenate([diag.force, diag.max_depth[:, None]], axis=1).ravel()

    def info(self, data) -> dict:
        """Per-body sand force (B, 3) N and sinkage (B,) m for an env's ``info``."""
        diag = self.handle.diagnostics(data)
        return {"sand_force": diag.force.copy(), "sand_sinkage": diag.max_depth.copy()}

    def close(self) -> None:
        """Detach the sand (idempotent)."""
        self._detach()
