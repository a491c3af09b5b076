"""Batched 3D-RFT sand on MuJoCo Warp: :func:`attach` installs it in ``mjw_model.callback.control``.

From then on every ``mujoco_warp.step(mjw_model, mjw_data)`` (and ``forward``, ``step1``) evaluates the sand in
every world, as the CPU coupling (:func:`rft_mujoco.attach`) does for one MjData: the same elements (culled
at attach inside the body's own geoms and inside geoms welded to it), the same run-time culling (an element
inside a geom of another weld group -- a calf inside its thigh at the knee, a rock -- carries nothing while it
is inside; ``cull=False`` turns both off), law, terrain, weld groups and rest treatment
(:mod:`rft_mujoco.physics.rest`), ported to warp kernels (:mod:`rft_mujoco.warp.kernels`), or with
``solve="implicit"`` the implicit solve (:mod:`rft_mujoco.warp.implicit`: the law at the twist the step ends with,
this step's constraint rows linearized in their zones); and the same
``xfrc_applied`` bookkeeping (the row ends as user wrench + sand wrench whether the user left it alone, zeroed
or reassigned it).

Per-world quantities live in device arrays the callback reads, so they change without recompiling or
re-capturing: the medium (:meth:`WarpSandHandle.set_media`), the flat surface height
(:meth:`WarpSandHandle.set_surface_height`) and an element mask (:meth:`WarpSandHandle.set_element_mask`).

CUDA graphs: the evaluation launches kernels only -- no allocation, no host read-back, no Python branch on
device values. Call :meth:`WarpSandHandle.bind` (or ``attach(..., data=d)``) before capturing, so that the
per-data buffers exist; after capture, change per-world values only through the setters (they copy into the
same buffers). Re-capture after attach/detach, or after a ``set_element_mask`` that changes the mask's shape
(1 <-> nworld rows: a new buffer). Not tested on a GPU here: the code keeps to these rules by construction.
On a GPU the per-body sums use atomics, so wrenches may differ run to run in the last float32 bit. Errors (a non-finite acceleration or wrench) cannot raise inside a step: they set bits of a
per-world flag and that world gets no sand for the evaluation; :meth:`WarpSandHandle.check` raises them.

Differences from the CPU coupling, by design: no validity monitor (it would read back every step); RK4 in
MuJoCo Warp keeps ``time`` fixed over a step's stages (the sand is evaluated at every stage, as with
``rk4_stages="all"``); state is float32 (MuJoCo Warp's), the small solves float64.
"""

from __future__ import annotations

import dataclasses
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import mujoco_warp as mjw
import numpy as np
import warp as wp

from rft_mujoco import tol
from rft_mujoco.physics import law
from rft_mujoco.physics.law import PUBLISHED, Guards, gravity_direction
from rft_mujoco.physics.media import Media, get_media
from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.physics.terrain import Terrain, as_terrain
from rft_mujoco.warp import kernels as K
from rft_mujoco.coupling import layout as _layout
from rft_mujoco.coupling.handle import CONSTRAINTS, SOLVES
from rft_mujoco.warp import implicit_eval as _implicit_eval
from rft_mujoco.warp import occlusion as _occlusion


PER_WORLD_BLOCK = 32
"""Threads per block of the one-thread-per-world kernels (free_twist, rest_solve): one warp, so that a few
thousand worlds spread over every multiprocessor of a GPU instead of filling a few 256-thread blocks."""


@dataclasses.dataclass
class WarpDiagnostics:
    """Per-world, per-body sand state of the latest evaluation (numpy copies; arrays over ``body_ids``).

    Attributes (W worlds, B attached bodies):
        force: (W, B, 3) N, world frame, at each body's COM. torque: (W, B, 3) N m about the COM.
        submerged: (W, B) int, loaded elements. max_depth: (W, B) m, deepest loaded element.
        scale: (W, B) ``|applied| / |RFT|`` (1 in flow; the fraction of the capacity used at rest).
        rft_force: (W, B, 3) N, the RFT force at the motion direction. resting: (W, B) bool.
        status: (W,) int, 1 when a wrench was non-zero. errors: (W,) int, sticky bits
            (:data:`rft_mujoco.warp.kernels.NOT_FINITE`, ``BAD_ACCELERATION``).
        occluded_area: (W, B) m^2, submerged surface inside a geom of another weld group (culled this
            evaluation; 0 with ``cull=False``), as the CPU diagnostics' ``occluded_area``.
    """

    force: np.ndarray
    torque: np.ndarray
    submerged: np.ndarray
    max_depth: np.ndarray
    scale: np.ndarray
    rft_force: np.ndarray
    resting: np.ndarray
    status: np.ndarray
    errors: np.ndarray
    occluded_area: np.ndarray


class _State:
    """Buffers of one (handle, mujoco_warp Data): per-world parameters, the book, work arrays, outputs."""

    def __init__(self, handle: "WarpSandHandle", nworld: int, data) -> None:
        dev = handle.device
        w, b, g, nv = nworld, handle.n_bodies, handle.n_groups, handle.nv
        n6 = 6 * g
        z = lambda shape, dtype=float: wp.zeros(shape, dtype=dtype, device=dev)  # noqa: E731
        self.nworld = w
        # per-world parameters (host mirrors: the setters write them and copy the whole array)
        self.host_xi = np.full(w, handle._xi_per_g0, dtype=np.float32)
        self.host_mu = np.full(w, handle._mu_surf0, dtype=np.float32)
        self.host_height = np.full(w, handle._flat_height0, dtype=np.float32)
        self.xi_per_g = wp.array(self.host_xi, dtype=float, device=dev)
        self.mu_surf = wp.array(self.host_mu, dtype=float, device=dev)
        self.flat_height = wp.array(self.host_height, dtype=float, device=dev)
        self.elem_mask = wp.array(np.ones((1, handle.n_elements), dtype=np.int32), dtype=int, device=dev)
        self.media = [handle._media0] * w
        # the book and the sand
        sv = wp.spatial_vector
        self.user, self.added, self.written, self.sand, self.rft = (z((w, b), sv) for _ in range(5))
        self.wrench = z((w, b), sv)
        self.cand, self.touch, self.count, self.resting = (z((w, b), int) for _ in range(4))
        self.max_depth, self.scale, self.occluded = z((w, b)), z((w, b)), z((w, b))
        self.near = z((w, max(handle.n_occluders, 1)), int)
        self.v_lin, self.v_ang = z((w, b), wp.vec3), z((w, b), wp.vec3)
        self.last_time = wp.array(np.full(w, -np.inf, dtype=np.float32), dtype=float, device=dev)
        self.errors, self.status, self.ngroups = z(w, int), z(w, int), z(w, int)
        # work of the one-thread-per-world kernels (float64), world index last: the threads of a GPU warp
        # (consecutive worlds) read consecutive addresses
        f8 = wp.float64
        self.slot, self.arm, self.size = z((b, w), int), z((b, w), wp.vec3d), z((b, w), f8)
        self.active = z((g, w), int)
        self.mf = z((nv, nv, w), f8)
        self.qacc = z((1, nv, w), f8)
        self.jac, self.minv_jt = z((n6, nv, w), f8), z((n6, nv, w), f8)
        self.twist, self.free, self.u, self.vs = (z((n6, w), f8) for _ in range(4))
        self.a, self.low, self.gram = (z((n6, n6, w), f8) for _ in range(3))
        self.rft_g, self.cap, self.wv, self.rhs, self.weight, self.x = (z((n6, w), f8) for _ in range(6))
        self.diag0, self.rem, self.y = (z((n6, w), f8) for _ in range(3))
        self.idx, self.order, self.kept = (z((n6, w), int) for _ in range(3))
        self.capacity, self.total = z((g, w), f8), z((g, w), f8)
        self.rest_flag, self.flow = z((g, w), int), z((g, w), int)
        self.implicit = None                    # the implicit solve's buffers (rft_mujoco.warp.implicit_eval)
        if handle.stabilize and handle.solve == "implicit":
            self.implicit = _implicit_eval.ImplicitState(handle, data, self)


def _terrain_spec(terrain: Terrain) -> tuple[int, np.ndarray, np.ndarray, float]:
    """(kind, tp (N_PARAMS,) float32, heights float32, flat height m) for :func:`rft_mujoco.warp.law.depth`: the
    shared :func:`rft_mujoco.physics.terrain_spec.terrain_spec` in float32 (the flat height also returned apart:
    warp keeps it per world); the kinds warp evaluates are FLAT and HEIGHTFIELD."""
    spec = ts.terrain_spec(terrain)
    if spec is None or spec.kind not in (ts.FLAT, ts.HEIGHTFIELD):
        raise ValueError(f"terrain must be a FlatSurface, HeightfieldSurface or SandRegion (of either), got "
                         f"{type(terrain).__name__}")
    flat_height = float(spec.params[ts.TP_HEIGHT]) if spec.kind == ts.FLAT else 0.0
    return (spec.kind, spec.params.astype(np.float32), np.ascontiguousarray(spec.heights, dtype=np.float32),
            flat_height)


def _media_list(media, n: int) -> list[Media]:
    if isinstance(media, (Media, str)):
        return [get_media(media)] * n
    out = [get_media(m) for m in media]
    if len(out) != n:
        raise ValueError(f"media must be one Media (or preset name) or one per selected world ({n}), got {len(out)}")
    return out


def _worlds(worlds, nworld: int) -> np.ndarray:
    if worlds is None:
        return np.arange(nworld)
    idx = np.asarray(worlds)
    if idx.dtype == bool:
        if idx.shape != (nworld,):
            raise ValueError(f"a boolean worlds mask must have shape ({nworld},), got {idx.shape}")
        return np.flatnonzero(idx)
    idx = idx.astype(np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= nworld):
        raise ValueError(f"worlds must be indices in 0..{nworld - 1}, got {idx.min()}..{idx.max()}")
    return idx


class WarpSandHandle:
    """Sand attached to some bodies of a MuJoCo Warp model, in every world. Create with :func:`attach`.

    Attributes:
        body_ids: (B,) int, the attached bodies (MuJoCo ids); body_names: their names.
        n_elements: E, surface elements over those bodies. groups: the weld groups.
        stabilize, passive, guards, terrain, cull: as in :func:`rft_mujoco.attach`.
        culled_area: (B,) m^2 of each body's surface culled at attach.
        occluders: the run-time occluders (:class:`rft_mujoco.geometry.occlusion.Occluders`, the CPU path's list);
            n_occluders: their number (0 with ``cull=False``).
        device: the warp device of the model.
    """

    def __init__(self, mj_model, mjw_model, media: Media, layout: _layout.Layout, terrain: Terrain,
                 guards: Guards, stabilize: bool, passive: bool) -> None:
        self.mj_model = mj_model
        self.mjw_model = mjw_model
        self.layout = layout
        self.body_ids = layout.body_ids
        self.body_names = layout.body_names
        self.groups = layout.groups
        self.n_bodies = int(layout.body_ids.size)
        self.n_groups = int(layout.groups.ref.size)
        self.n_elements = layout.n_elements
        self.cull = layout.cull
        self.culled_area = layout.culled_area
        self.occluders = layout.occluders
        self.n_occluders = int(layout.occluders.geom.size)
        self.nv = int(mj_model.nv)
        self.guards = guards
        self.stabilize = bool(stabilize)
        self.passive = bool(passive)
        self._solve, self._constraints = "explicit", "linearized"
        self.device = mjw_model.body_parentid.device
        self._media0 = media
        self._xi_per_g0 = float(media.xi_n_at(1.0))
        self._mu_surf0 = float(media.mu_surf)
        self.terrain = terrain
        kind, tp, heights, h0 = _terrain_spec(terrain)
        self._kind, self._flat_height0 = kind, h0
        g_hat, _ = gravity_direction(mj_model.opt.gravity)
        if (kind != ts.FLAT or tp[ts.TP_REGION] != 0.0) and g_hat[2] > -1.0 + tol.VERTICAL_GRAVITY_TOL:
            raise ValueError(f"a {type(terrain).__name__} needs gravity along -z (heights are world z), got "
                             f"gravity direction {np.round(g_hat, 6).tolist()}; use a FlatSurface")
        dev = self.device
        i4 = lambda x: wp.array(np.ascontiguousarray(x, dtype=np.int32), dtype=int, device=dev)  # noqa: E731
        v3 = lambda x: wp.array(np.ascontiguousarray(x, dtype=np.float32), dtype=wp.vec3, device=dev)  # noqa: E731
        m = mj_model
        attached_index = np.full(m.nbody, -1)
        attached_index[layout.body_ids] = np.arange(self.n_bodies)
        self._a = dict(
            body_id=i4(layout.body_ids), elem_body=i4(layout.elem_body), centroid=v3(layout.centroids),
            normal=v3(layout.normals), bound_center=v3(layout.bound_center), area=wp.array(layout.areas.astype(np.float32), dtype=float, device=dev),
            body_group=i4(layout.groups.of_body), group_ref=i4(layout.groups.ref),
            group_radius=wp.array(layout.groups.radius, dtype=wp.float64, device=dev),
            bound_radius=wp.array(np.where(np.isfinite(layout.bound_radius), layout.bound_radius,  # no elements
                                           layout.element_size), dtype=wp.float64, device=dev),
            attached_index=i4(attached_index), body_rootid=i4(m.body_rootid), body_dofnum=i4(m.body_dofnum),
            body_dofadr=i4(m.body_dofadr), body_parentid=i4(m.body_parentid), dof_parentid=i4(m.dof_parentid),
            tp=wp.array(tp, dtype=float, device=dev), heights=wp.array(heights, dtype=float, device=dev),
            coef=wp.array(law.COEFFICIENTS, dtype=wp.float64, device=dev))
        self._occ = _occlusion.device_arrays(layout.occluders, self.n_bodies, dev)
        self._states: dict[int, tuple[weakref.ref, _State]] = {}
        self._chained = None
        self.attached = False

    @property
    def solve(self) -> str:
        """"explicit" or "implicit" (:func:`attach`); set it between steps (new buffers are made at the next
        evaluation: re-capture CUDA graphs)."""
        return self._solve

    @solve.setter
    def solve(self, value: str) -> None:
        if value not in SOLVES:
            raise ValueError(f"solve must be one of {SOLVES}, got {value!r}")
        self._solve = value

    @property
    def constraints(self) -> str:
        """The implicit solve's constraint forces: "linearized" or "lagged" (:func:`attach`)."""
        return self._constraints

    @constraints.setter
    def constraints(self, value: str) -> None:
        if value not in CONSTRAINTS:
            raise ValueError(f"constraints must be one of {CONSTRAINTS}, got {value!r}")
        self._constraints = value

    # --- per-data buffers ---------------------------------------------------------------------------
    def bind(self, data) -> _State:
        """The buffers of ``data`` (a ``mujoco_warp.Data`` of this model), allocated on first use. Call it
        before capturing ``mujoco_warp.step`` in a CUDA graph."""
        key = id(data)
        entry = self._states.get(key)
        if entry is not None and entry[0]() is data:
            return entry[1]
        nworld = int(data.time.shape[0])
        state = _State(self, nworld, data)
        self._states[key] = (weakref.ref(data, lambda _r, k=key: self._states.pop(k, None)), state)
        return state

    def _state(self, data) -> _State:
        entry = self._states.get(id(data))
        if entry is None or entry[0]() is not data:
            raise ValueError("this mujoco_warp Data has not been stepped with the sand yet; call "
                             "handle.bind(data) or mujoco_warp.step(model, data) first")
        return entry[1]

    # --- per-world parameters -------------------------------------------------------------------------
    def set_media(self, data, media: Media | str | Sequence[Media | str], worlds=None) -> None:
        """Use ``media`` (one, or one per selected world) in ``worlds`` (indices or a (nworld,) bool mask;
        None: all) of ``data`` from the next evaluation on. No recompilation, graph-safe."""
        st = self.bind(data)
        idx = _worlds(worlds, st.nworld)
        ms = _media_list(media, idx.size)
        for i, m in zip(idx, ms):
            st.media[i] = m
        st.host_xi[idx] = [m.xi_n_at(1.0) for m in ms]
        st.host_mu[idx] = [m.mu_surf for m in ms]
        st.xi_per_g.assign(st.host_xi)
        st.mu_surf.assign(st.host_mu)

    def media(self, data) -> list[Media]:
        """The medium of each world of ``data`` (a list of nworld :class:`Media`)."""
        return list(self.bind(data).media)

    def set_surface_height(self, data, height, worlds=None) -> None:
        """Flat free-surface height(s) in m (scalar or one per selected world) for a flat terrain."""
        if self._kind != ts.FLAT:
            raise ValueError("set_surface_height needs a flat terrain (FlatSurface or a SandRegion of one); this "
                             f"handle's terrain is {type(self.terrain).__name__}")
        st = self.bind(data)
        idx = _worlds(worlds, st.nworld)
        h = np.broadcast_to(np.asarray(height, dtype=np.float64), idx.shape)
        if not np.all(np.isfinite(h)):
            raise ValueError(f"surface heights must be finite (m), got {np.asarray(height)!r}")
        st.host_height[idx] = h
        st.flat_height.assign(st.host_height)

    def surface_height(self, data) -> np.ndarray:
        """(nworld,) m: the flat surface height of each world."""
        return self.bind(data).host_height.astype(float)

    def set_element_mask(self, data, mask) -> None:
        """Switch elements off: ``mask`` (E,) or (nworld, E) bool/int, 0 = the element does not exist (it
        neither touches nor loads). The hook for run-time culling; None restores all elements."""
        st = self.bind(data)
        e = self.n_elements
        if mask is None:
            arr = np.ones((1, e), dtype=np.int32)
        else:
            arr = np.asarray(mask).astype(np.int32)
            if arr.ndim == 1:
                arr = arr[None, :]
            if arr.ndim != 2 or arr.shape[1] != e or arr.shape[0] not in (1, st.nworld):
                raise ValueError(f"mask must have shape ({e},) or ({st.nworld}, {e}), got {np.shape(mask)}")
        if arr.shape == st.elem_mask.shape:
            st.elem_mask.assign(arr)
        else:                                   # a new shape: a new buffer (re-capture graphs after this)
            st.elem_mask = wp.array(np.ascontiguousarray(arr), dtype=int, device=self.device)

    # --- results ----------------------------------------------------------------------------------------
    def forces(self, data) -> np.ndarray:
        """(nworld, B, 3) float: the sand force on each attached body in N (world frame, at its COM) of the
        latest evaluation (a host copy: synchronizes)."""
        return self._state(data).sand.numpy()[:, :, :3].astype(np.float64)

    def torques(self, data) -> np.ndarray:
        """(nworld, B, 3) float: the sand torque about each attached body's COM in N m."""
        return self._state(data).sand.numpy()[:, :, 3:].astype(np.float64)

    def diagnostics(self, data) -> WarpDiagnostics:
        """Forces, torques, loaded element counts, depths, rest state and occluded area of the latest evaluation
        (host copies)."""
        st = self._state(data)
        sand, rft = st.sand.numpy().astype(np.float64), st.rft.numpy().astype(np.float64)
        return WarpDiagnostics(sand[:, :, :3], sand[:, :, 3:], st.count.numpy().astype(np.int64),
                               st.max_depth.numpy().astype(np.float64), st.scale.numpy().astype(np.float64),
                               rft[:, :, :3], st.resting.numpy().astype(bool), st.status.numpy().copy(),
                               st.errors.numpy().copy(), st.occluded.numpy().astype(np.float64))

    def check(self, data) -> None:
        """Raise FloatingPointError naming the worlds whose evaluation failed since the last check (and clear)."""
        st = self._state(data)
        err = st.errors.numpy().copy()            # numpy() is a view on the CPU device
        bad = np.flatnonzero(err)
        if bad.size:
            st.errors.zero_()
            acc = np.flatnonzero(err & int(K.BAD_ACCELERATION))
            nan = np.flatnonzero(err & int(K.NOT_FINITE))
            raise FloatingPointError(
                f"sand evaluation failed in worlds {bad[:20].tolist()}{' ...' if bad.size > 20 else ''}: "
                f"non-finite acceleration without sand in {acc.size} world(s) (NaN/inf in ctrl, qfrc_applied, "
                f"xfrc_applied or the state), non-finite sand wrench in {nan.size}; those worlds got no sand "
                "in that evaluation. Reset them or fix the input")

    # --- the callback -----------------------------------------------------------------------------------
    def _control(self, m, d) -> None:
        if self._chained is not None:
            self._chained(m, d)
        if self.attached:
            self._evaluate(m, d, self.bind(d))

    def _evaluate(self, m, d, st: _State) -> None:
        a, dev, nw = self._a, self.device, st.nworld
        wb, we = (nw, self.n_bodies), (nw, self.n_elements)
        guards = (int(self.guards.no_tension), int(self.guards.no_forward_tangential),
                  int(self.guards.no_positive_power))
        wp.launch(K.user_part, dim=wb, device=dev,
                  inputs=[a["body_id"], d.xfrc_applied, st.written, st.added, a["bound_center"], a["bound_radius"],
                          d.xpos, d.xmat, m.opt.gravity, self._kind, st.flat_height, a["tp"], st.user, st.cand,
                          st.touch, st.wrench, st.count, st.max_depth, st.occluded])
        wp.launch(K.touch_pass, dim=we, device=dev,
                  inputs=[a["body_id"], a["elem_body"], a["centroid"], st.elem_mask, st.cand, d.xpos, d.xmat,
                          m.opt.gravity,
                          self._kind, st.flat_height, a["tp"], a["heights"], st.touch])
        o = self._occ
        if self.n_occluders:                    # static: the same launches every evaluation (graph-safe)
            wp.launch(K.near_occluders, dim=(nw, self.n_occluders), device=dev,
                      inputs=[a["body_id"], a["bound_center"], a["bound_radius"], o["occ_body"], o["occ_geom"],
                              o["occ_rbound"], d.xpos, d.xmat, d.geom_xpos, st.touch, st.near])
        if self.stabilize:
            mjw.fwd_actuation(m, d)            # MuJoCo computes qfrc_actuator only after the control callback
            if self.solve == "implicit":
                _implicit_eval.evaluate_implicit(self, m, d, st, guards, PER_WORLD_BLOCK)
                wp.launch(K.commit, dim=wb, device=dev,
                          inputs=[a["body_id"], st.user, st.sand, d.xfrc_applied, st.added, st.written])
                return
            wp.launch(K.free_twist, dim=nw, device=dev, block_dim=PER_WORLD_BLOCK, inputs=[
                self.mj_model.nbody, a["body_rootid"], a["body_dofnum"], a["body_dofadr"], a["body_parentid"],
                a["dof_parentid"], m.M_rownnz, m.M_rowadr, m.M_colind, m.opt.timestep,
                a["body_id"], a["attached_index"], a["body_group"], a["group_ref"], a["group_radius"],
                d.time, d.qvel, d.qfrc_passive, d.qfrc_bias, d.qfrc_actuator, d.qfrc_applied, d.qfrc_constraint,
                d.M, d.cdof, d.subtree_com, d.xipos, d.xfrc_applied, st.user, st.touch,
                st.last_time, st.errors, st.ngroups, st.active, st.slot, st.mf, st.qacc, st.jac, st.minv_jt,
                st.twist, st.free, st.u, st.vs, st.a, st.arm, st.v_lin, st.v_ang])
        else:
            wp.launch(K.body_twist, dim=wb, device=dev,
                      inputs=[a["body_id"], a["body_rootid"], d.cvel, d.xipos, d.subtree_com, st.v_lin, st.v_ang])
        wp.launch(K.force_pass, dim=we, device=dev, inputs=[
            a["body_id"], a["elem_body"], a["centroid"], a["normal"], a["area"], st.elem_mask, d.xpos, d.xmat,
            d.xipos, m.opt.gravity, self._kind, st.flat_height, a["tp"], a["heights"], a["coef"], st.xi_per_g,
            st.mu_surf, *guards, st.touch, st.v_lin, st.v_ang, st.wrench, st.count, st.max_depth, o["occ_start"],
            o["occ_geom"], o["occ_kind"], o["occ_size"], o["occ_rbound"], o["occ_hs_start"], o["occ_hs"],
            o["margin"], st.near, d.geom_xpos, d.geom_xmat, st.occluded])
        wp.launch(K.rest_solve, dim=nw, device=dev, block_dim=PER_WORLD_BLOCK, inputs=[
            int(self.stabilize), int(self.passive), a["body_group"], a["group_radius"], a["bound_radius"],
            st.ngroups, st.active, st.slot, st.touch, st.wrench, st.count, st.vs, st.a, st.u, st.arm, st.v_lin,
            st.v_ang, st.rft_g, st.cap, st.capacity, st.rest_flag, st.flow, st.wv, st.idx, st.rhs, st.weight,
            st.x, st.diag0, st.rem, st.order, st.kept, st.low, st.gram, st.y, st.size, st.total,
            st.sand, st.rft, st.scale, st.resting, st.status, st.errors])
        wp.launch(K.commit, dim=wb, device=dev,
                  inputs=[a["body_id"], st.user, st.sand, d.xfrc_applied, st.added, st.written])

    # --- attach / detach ----------------------------------------------------------------------------------
    def _install(self) -> None:
        cb = self.mjw_model.callback
        mine = set(self.body_ids.tolist())
        other = cb.control
        while other is not None:
            owner = getattr(other, "__self__", None)
            if isinstance(owner, WarpSandHandle):
                if owner.attached and mine & set(owner.body_ids.tolist()):
                    raise ValueError(f"bodies {sorted(mine & set(owner.body_ids.tolist()))} already have sand "
                                     "attached on this model; detach that handle first or attach other bodies")
                other = owner._chained
            else:
                other = None
        self._chained = cb.control
        cb.control = self._control
        self.attached = True

    def detach(self) -> None:
        """Remove the sand: later steps are the plain model; sand wrenches are taken out of xfrc_applied."""
        if not self.attached:
            return
        self.attached = False
        cb = self.mjw_model.callback
        if cb.control == self._control:
            cb.control = self._chained
        # otherwise a later callback chains ours: it stays in the chain but only passes through.
        for ref, st in list(self._states.values()):
            d = ref()
            if d is not None:
                wp.launch(K.remove_sand, dim=(st.nworld, self.n_bodies), device=self.device,
                          inputs=[self._a["body_id"], d.xfrc_applied, st.written, st.added, st.user])

    def __enter__(self) -> "WarpSandHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.detach()

    def __repr__(self) -> str:
        return (f"WarpSandHandle(media={self._media0.name!r}, bodies={self.body_names}, elements={self.n_elements}, "
                f"element_size={self.layout.element_size} m, stabilize={self.stabilize}, cull={self.cull}, "
                f"device={self.device}, attached={self.attached})")


def attach(mj_model, mjw_model, media: Media | str, bodies: Sequence[str | int] | None = None,
           surface_height: float | Terrain = 0.0, resolution: str | float = "default", *,
           guards: Guards = PUBLISHED, stabilize: bool = True, passive: bool = True, cull: bool = True,
           solve: str = "explicit", constraints: str = "linearized", data=None) -> WarpSandHandle:
    """Attach 3D-RFT sand to a MuJoCo Warp model: ``mujoco_warp.step(mjw_model, d)`` then includes it in every
    world of ``d``.

    Args:
        mj_model: the ``mujoco.MjModel`` that ``mjw_model`` was made from (``mujoco_warp.put_model``); its
            geometry gives the elements.
        mjw_model: the ``mujoco_warp.Model``.
        media: a :class:`rft_mujoco.Media` or a preset name: the medium of every world (change per world with
            :meth:`WarpSandHandle.set_media`).
        bodies, surface_height, resolution, guards, stabilize, passive, cull: as in :func:`rft_mujoco.attach`
            (``surface_height``: a height in m, or a FlatSurface, HeightfieldSurface or SandRegion; ``cull``:
            True (default) culls elements inside the body's own and welded geoms at attach and, at each
            evaluation in each world, elements inside a geom of another weld group; False: neither).
        solve: with ``stabilize=True``, "explicit" (default) or "implicit" (:mod:`rft_mujoco.warp.implicit`: the law
            at the twist the step ends with, the CPU path's ``attach(solve="implicit")``).
        constraints: the implicit solve's constraint forces: "linearized" (this step's rows in their zones) or
            "lagged" (MuJoCo's last constraint forces), as the CPU handle's ``constraints``.
        data: optionally a ``mujoco_warp.Data`` to allocate buffers for now (:meth:`WarpSandHandle.bind`).
    Returns:
        a :class:`WarpSandHandle`; ``handle.detach()`` removes it.
    """
    if not isinstance(mj_model, mujoco.MjModel):
        raise TypeError(f"mj_model must be a mujoco.MjModel, got {type(mj_model).__name__}")
    if not isinstance(mjw_model, mjw.Model):
        raise TypeError(f"mjw_model must be a mujoco_warp.Model (mujoco_warp.put_model(mj_model)), got "
                        f"{type(mjw_model).__name__}")
    if mjw_model.nv != mj_model.nv or mjw_model.nbody != mj_model.nbody:
        raise ValueError(f"mjw_model (nv {mjw_model.nv}, nbody {mjw_model.nbody}) was not made from mj_model "
                         f"(nv {mj_model.nv}, nbody {mj_model.nbody})")
    if mj_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ACTUATION:
        warnings.warn("rft_mujoco.warp: the model disables actuation; MuJoCo Warp then skips the control "
                      "callback and the sand is not applied", RuntimeWarning, stacklevel=2)
    media = get_media(media)
    terrain = as_terrain(surface_height)
    gravity_direction(mj_model.opt.gravity)              # raises on zero gravity
    lay = _layout.build(mj_model, bodies, resolution, cull)
    handle = WarpSandHandle(mj_model, mjw_model, media, lay, terrain, guards, stabilize, passive)
    handle.solve, handle.constraints = solve, constraints           # checked
    handle._install()
    if data is not None:
        handle.bind(data)
    return handle
