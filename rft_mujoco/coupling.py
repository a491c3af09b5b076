"""MuJoCo coupling: attach 3D-RFT sand to bodies of a model; plain ``mujoco.mj_step`` then includes it.

Each physics evaluation (every integrator stage: once per step for Euler/implicitfast, four times for
RK4) the dispatcher calls :meth:`SandHandle._evaluate`, which

1. skips bodies whose bounding sphere is above the highest point of the sand (broadphase);
2. for the rest, takes element positions, normals and velocities from ``xpos``/``xmat``/``cvel``
   (``cvel``'s linear part refers to ``subtree_com`` of the root, converted to each body's COM);
3. computes the RFT force of every submerged leading element and the wrench about the body's COM
   (``xipos``, where ``xfrc_applied`` acts);
4. with ``stabilize=True`` (default), makes the force implicit in the motion direction and limits the
   impulse so the sand can stop a body but never reverse or accelerate it (see :mod:`rft_mujoco.kernel`
   and the README's "Stability" section);
5. adds the wrenches to ``data.xfrc_applied`` on top of the user's own wrench.
"""

from __future__ import annotations

import dataclasses
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np

from . import kernel, surface
from ._dispatch import DISPATCHER
from .law import PUBLISHED, Guards, gravity_direction
from .media import Media, get_media
from .terrain import FlatSurface, Terrain, as_terrain


@dataclasses.dataclass
class Diagnostics:
    """Per-body sand state of the latest evaluation of one MjData (arrays over ``SandHandle.body_ids``).

    Attributes:
        force: (B, 3) N, world frame, applied at each body's COM.
        torque: (B, 3) N m, world frame, about each body's COM.
        submerged: (B,) int, number of submerged leading elements that carried stress.
        max_depth: (B,) m, deepest loaded element (0 when none).
        scale: (B,) the impulse-limiter factor applied to the RFT wrench (1 = full published force).
        rft_force: (B, 3) N, the RFT force before the impulse limiter.
    """

    force: np.ndarray
    torque: np.ndarray
    submerged: np.ndarray
    max_depth: np.ndarray
    scale: np.ndarray
    rft_force: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> "Diagnostics":
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.zeros(n),
                   np.ones(n), np.zeros((n, 3)))


def _body_id(model, name) -> int:
    if isinstance(name, (int, np.integer)):
        if not 0 < int(name) < model.nbody:
            raise ValueError(f"body id {name} out of range 1..{model.nbody - 1} (0 is the world)")
        return int(name)
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if bid < 0:
        names = [model.body(i).name for i in range(1, model.nbody)]
        raise ValueError(f"no body named {name!r} in the model; bodies are {names}")
    if bid == 0:
        raise ValueError("the world body cannot be a sand intruder")
    return bid


class SandHandle:
    """Sand attached to some bodies of one MjModel. Create with :func:`attach`; remove with :meth:`detach`.

    Attributes:
        model: the MjModel.
        media: the granular medium.
        terrain: the free surface.
        body_ids: (B,) int, bodies that feel the sand.
        body_names: their names.
        n_elements: total surface elements (candidates) over those bodies.
    """

    def __init__(self, model, media: Media, body_ids: Sequence[int], terrain: Terrain, size: float,
                 guards: Guards, stabilize: bool, passive: bool):
        self.model = model
        self.media = media
        self.terrain = terrain
        self.guards = guards
        self.stabilize = bool(stabilize)
        self.passive = bool(passive)
        self.element_size = size
        self.body_ids = np.asarray(body_ids, dtype=np.int64)
        self.body_names = [model.body(int(b)).name for b in self.body_ids]
        parts, counts = [], []
        for b, name in zip(self.body_ids, self.body_names):
            el = surface.body_elements(model, int(b), size)
            if len(el) and model.body_subtreemass[b] <= 0:
                raise ValueError(f"body {name!r} has zero mass (subtree mass {model.body_subtreemass[b]}); "
                                 "sand forces on a massless body have nothing to act on: give it a mass "
                                 "or leave it out of bodies=")
            parts.append(el)
            counts.append(len(el))
        if sum(counts) == 0:
            raise ValueError(f"bodies {self.body_names} have no surface geoms (planes and heightfields are "
                             "terrain, not intruders); choose bodies with sphere/capsule/box/... geoms")
        el = surface.Elements.concatenate(parts)
        self.local_centroids = np.ascontiguousarray(el.centroids)
        self.local_normals = np.ascontiguousarray(el.normals)
        self.areas = np.ascontiguousarray(el.areas)
        self.elem_body = np.repeat(np.arange(len(self.body_ids)), counts)
        self.n_elements = int(self.areas.size)
        # Bounding spheres in the body frame (centre, radius) for the broadphase.
        self._bound_center = np.zeros((len(self.body_ids), 3))
        self._bound_radius = np.full(len(self.body_ids), -np.inf)
        for i, c in enumerate(counts):
            if c:
                pts = self.local_centroids[self.elem_body == i]
                lo, hi = pts.min(0), pts.max(0)
                center = 0.5 * (lo + hi)
                self._bound_center[i] = center
                self._bound_radius[i] = np.linalg.norm(pts - center, axis=1).max() + size
        self._elem_slices = np.concatenate([[0], np.cumsum(counts)])
        self.elem_octant = kernel.octants(self.local_centroids, self._bound_center[self.elem_body])
        self._diag: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self._root = model.body_rootid[self.body_ids]
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self.attached = False
        self.evaluations = 0
        self._replaced: list[tuple[int, int, int]] = []

    # --- public -------------------------------------------------------------------------------------
    @property
    def media(self) -> Media:
        """The granular medium; may be replaced between steps (e.g. per-episode randomization)."""
        return self._media

    @media.setter
    def media(self, value: Media) -> None:
        if not isinstance(value, Media):
            raise TypeError(f"media must be a rft_mujoco.Media, got {type(value).__name__}; "
                            "use rft_mujoco.get_media(name) for a preset")
        self._media = value

    def detach(self) -> None:
        """Remove the sand: later steps are the plain model; sand wrenches are taken out of xfrc_applied."""
        if not self.attached:
            return
        DISPATCHER.unregister(self)
        for gid, contype, conaffinity in self._replaced:
            self.model.geom_contype[gid] = contype
            self.model.geom_conaffinity[gid] = conaffinity
        self._replaced.clear()
        for data in DISPATCHER.datas_of(self.model):
            DISPATCHER.remove_sand(self.model, data, self.body_ids)
        self.attached = False

    def replace_rigid(self, geoms: Sequence[str | int]) -> None:
        """Switch off collisions of rigid geoms the sand replaces (e.g. the floor plane) until detach."""
        for g in geoms:
            gid = g if isinstance(g, (int, np.integer)) else mujoco.mj_name2id(
                self.model, mujoco.mjtObj.mjOBJ_GEOM, g)
            if gid < 0 or gid >= self.model.ngeom:
                raise ValueError(f"no geom named {g!r} to replace by sand")
            self._replaced.append((int(gid), int(self.model.geom_contype[gid]),
                                   int(self.model.geom_conaffinity[gid])))
            self.model.geom_contype[gid] = 0
            self.model.geom_conaffinity[gid] = 0

    def diagnostics(self, data) -> Diagnostics:
        """Per-body force, torque, submerged element count and max depth of the latest evaluation."""
        return self._diag.get(data) or Diagnostics.zeros(len(self.body_ids))

    def __enter__(self) -> "SandHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.detach()

    def __repr__(self) -> str:
        return (f"SandHandle(media={self.media.name!r}, bodies={self.body_names}, "
                f"elements={self.n_elements}, element_size={self.element_size} m, attached={self.attached})")

    # --- per evaluation -----------------------------------------------------------------------------
    def _evaluate(self, data, user_xfrc: np.ndarray, sand_out: np.ndarray) -> None:
        """Add this handle's wrenches (nbody, 6) into ``sand_out``."""
        m = self.model
        self.evaluations += 1
        diag = self._diag.get(data)
        if diag is None:
            diag = self._diag[data] = Diagnostics.zeros(len(self.body_ids))
        diag.force[:] = 0.0
        diag.torque[:] = 0.0
        diag.submerged[:] = 0
        diag.max_depth[:] = 0.0
        diag.scale[:] = 1.0
        diag.rft_force[:] = 0.0
        gravity = m.opt.gravity
        g_hat, _ = gravity_direction(gravity)
        ids = self.body_ids
        # Broadphase: lowest point of each bounding sphere against the highest sand.
        xmat = data.xmat[ids].reshape(-1, 3, 3)
        centers = data.xpos[ids] + np.einsum("bij,bj->bi", xmat, self._bound_center)
        low = -(centers @ g_hat) - self._bound_radius
        cand = np.flatnonzero(low < self.terrain.max_height)
        if cand.size == 0:
            return
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            bad = [m.body(int(b)).name for b in ids[cand]]
            raise FloatingPointError(
                f"non-finite qpos/qvel while computing sand forces on bodies {bad}: the simulation already "
                "diverged (check timestep, actuator gains and masses; keep stabilize=True)")
        bids = ids[cand]
        cvel = data.cvel[bids]
        omega = cvel[:, :3]
        com = data.xipos[bids]
        v_com = cvel[:, 3:] + np.cross(omega, com - data.subtree_com[self._root[cand]])
        dt = m.opt.timestep
        a_com = alpha = None
        if self.stabilize:
            jac, qvel_pred, qacc_free = self._free_motion(data, bids, user_xfrc, dt)
            acc = jac @ qacc_free                      # (k, 6): [linear at COM, angular]
            a_com, alpha = acc[:, :3], acc[:, 3:]
        # Elements of the candidate bodies.
        sel = np.concatenate([np.arange(self._elem_slices[i], self._elem_slices[i + 1]) for i in cand])
        remap = np.empty(len(ids), dtype=np.int64)
        remap[cand] = np.arange(cand.size)
        groups, count, max_depth = kernel.body_wrenches(
            self.local_centroids[sel], self.local_normals[sel], self.areas[sel], remap[self.elem_body[sel]],
            cand.size, data.xpos[bids], xmat[cand], com, v_com, omega, self.terrain, g_hat, gravity,
            self.media, self.guards, a_com, alpha, dt if self.stabilize else 0.0, self.elem_octant[sel])
        wrench = groups.sum(axis=1)
        diag.rft_force[cand] = wrench[:, :3]
        loaded = np.flatnonzero(np.any(wrench != 0.0, axis=1))
        if loaded.size and self.stabilize:
            flat = groups.reshape(-1, 6)
            active = np.flatnonzero(np.any(flat != 0.0, axis=1))
            lam = self._limit(data, jac[active // kernel.GROUPS_PER_BODY], flat[active], qvel_pred, dt)
            flat[active] *= lam[:, None]
            new = groups.sum(axis=1)
            rft_norm = np.linalg.norm(wrench[loaded], axis=1)
            diag.scale[cand[loaded]] = np.linalg.norm(new[loaded], axis=1) / rft_norm
            wrench = new
        elif loaded.size and self.passive:
            power = np.einsum("ij,ij->i", wrench[loaded, :3], v_com[loaded]) + \
                np.einsum("ij,ij->i", wrench[loaded, 3:], omega[loaded])
            pos = power > 0.0
            wrench[loaded[pos]] = 0.0
            diag.scale[cand[loaded[pos]]] = 0.0
        diag.force[cand] = wrench[:, :3]
        diag.torque[cand] = wrench[:, 3:]
        diag.submerged[cand] = count
        diag.max_depth[cand] = max_depth
        sand_out[bids] += wrench

    def _free_motion(self, data, bids, user_xfrc, dt):
        """Body Jacobians at the COM (k, 6, nv), predicted qvel (nv,) and free qacc (nv,) without sand.

        The free acceleration uses the smooth forces (passive, bias, actuators, applied, user xfrc) and
        ignores constraint forces (rigid contacts, limits).
        """
        m = self.model
        jac = np.empty((bids.size, 6, m.nv))
        for i, b in enumerate(bids):
            mujoco.mj_jacBodyCom(m, data, self._jacp, self._jacr, int(b))
            jac[i, :3] = self._jacp
            jac[i, 3:] = self._jacr
        mujoco.mj_fwdActuation(m, data)
        qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
        rows = np.flatnonzero(np.any(user_xfrc[1:] != 0.0, axis=1)) + 1
        for b in rows:
            mujoco.mj_applyFT(m, data, user_xfrc[b, :3].copy(), user_xfrc[b, 3:].copy(),
                              data.xipos[b].copy(), int(b), qfrc)
        qacc = np.empty(m.nv)
        mujoco.mj_solveM(m, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
        return jac, data.qvel + dt * qacc, qacc

    def _limit(self, data, jac, wrench, qvel_pred, dt):
        """Impulse-limiter factors (k,) in [0, 1]: see :func:`rft_mujoco.kernel.limit_impulses`."""
        q = np.einsum("kin,ki->kn", jac, wrench)         # generalized forces J^T W, (k, nv)
        minv_q = np.empty_like(q)
        mujoco.mj_solveM(self.model, data, minv_q, np.ascontiguousarray(q))
        G = dt * dt * (q @ minv_q.T)
        h = dt * (q @ qvel_pred)
        return kernel.limit_impulses(G, h)


def attach(model, media: Media | str, bodies: Sequence[str | int] | None = None,
           surface_height: float | Terrain = 0.0, resolution: str | float = "default", *,
           guards: Guards = PUBLISHED, stabilize: bool = True, passive: bool = True) -> SandHandle:
    """Attach 3D-RFT sand to ``model``: from now on ``mujoco.mj_step(model, data)`` includes it.

    Args:
        model: the MjModel.
        media: a :class:`Media` or a preset name (see ``rft_mujoco.PRESETS``).
        bodies: body names (or ids) whose geoms touch the sand; None means every body but the world.
        surface_height: a flat free surface height in m, or a terrain (:class:`FlatSurface`,
            :class:`HeightfieldSurface`, :class:`SandRegion`).
        resolution: element size: a preset name (``rft_mujoco.surface.RESOLUTIONS``) or metres.
        guards: clean-ups of the fit's artefacts (default none: the published law).
        stabilize: implicit motion direction and impulse limiting, which gives real rest on sand and
            guarantees the sand never does positive work in a step (default True). False applies the
            published force at every element's current velocity (the naive coupling).
        passive: with ``stabilize=False``, zero a body's wrench whenever it would do positive work.
    Returns:
        a :class:`SandHandle`; call ``handle.detach()`` (or use it as a context manager) to remove it.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    media = get_media(media)
    terrain = as_terrain(surface_height)
    size = surface.element_size(resolution)
    if bodies is None:
        ids = [b for b in range(1, model.nbody)
               if any(model.geom_bodyid[g] == b and model.geom_type[g] not in
                      (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)
                      for g in range(model.ngeom))]
    else:
        if isinstance(bodies, (str, int)):
            bodies = [bodies]
        ids = [_body_id(model, b) for b in bodies]
        if len(set(ids)) != len(ids):
            raise ValueError(f"bodies lists a body twice: {list(bodies)}")
    if not ids:
        raise ValueError("no bodies to attach sand to: the model has no body with surface geoms")
    gravity_direction(model.opt.gravity)  # raises on zero gravity
    handle = SandHandle(model, media, ids, terrain, size, guards, stabilize, passive)
    DISPATCHER.register(handle)
    handle.attached = True
    return handle


def detach_all() -> None:
    """Detach every sand handle in the process (and restore the user's own control callback)."""
    for h in DISPATCHER.handles:
        h.detach()
