"""The numpy reference of one evaluation (``backend="numpy"``): what the compiled path must compute.

Plain, readable numpy on the handle's arrays and MuJoCo's functions (``mj_jacBodyCom``, ``mj_solveM``,
``mj_applyFT``); tests/test_compiled_rest.py compares the compiled evaluation with it. The steps are those
of :mod:`rft_mujoco.compiled.evaluate`: broadphase, run-time culling, the rest treatment
(:mod:`rft_mujoco.physics.rest`) or the naive published force, diagnostics and the wrenches into the sum.
The evaluations return what they did (:class:`Outcome`); the evaluator that calls them
(:class:`rft_mujoco.coupling.evaluators.NumpyEvaluator`) records it in the workspace's counters.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from rft_mujoco.geometry import occlusion
from rft_mujoco.physics import elements, implicit, rest


def touching(handle, data, g_hat, work) -> np.ndarray:
    """Broadphase and depth pre-pass: indices (k,) into ``body_ids`` of the bodies with a submerged element;
    fills rows 0..k-1 of the workspace's pose and velocity buffers."""
    ids = handle.body_ids
    xmat = data.xmat[ids].reshape(-1, 3, 3)
    centers = data.xpos[ids] + np.einsum("bij,bj->bi", xmat, handle.layout.bound_center)
    low = -(centers @ g_hat) - handle.layout.bound_radius
    cand = np.flatnonzero(low < work.terrain.max_height)
    if cand.size == 0:
        return cand
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
        bad = [handle.body_names[i] for i in cand]
        raise FloatingPointError(
            f"non-finite qpos/qvel while computing sand forces on bodies {bad}: the simulation already "
            "diverged (check timestep, actuator gains and masses; keep stabilize=True)")
    sel = np.concatenate([np.arange(handle.layout.elem_slices[i], handle.layout.elem_slices[i + 1]) for i in cand])
    remap = np.empty(len(ids), dtype=np.int64)
    remap[cand] = np.arange(cand.size)
    b = remap[handle.elem_body[sel]]
    pos = data.xpos[ids[cand]][b] + np.einsum("eij,ej->ei", xmat[cand][b], handle.local_centroids[sel])
    hit = np.bincount(b, weights=work.terrain.depth(pos, g_hat) > 0.0, minlength=cand.size) > 0
    touch = cand[hit]
    k, bids = touch.size, ids[touch]
    a = work.arrays
    a["body_pos"][:k] = data.xpos[bids]
    a["body_mat"][:k] = data.xmat[bids]
    a["body_com"][:k] = data.xipos[bids]
    omega = a["omega"][:k]
    omega[:] = data.cvel[bids, :3]
    a["v_com"][:k] = data.cvel[bids, 3:] + np.cross(omega, data.xipos[bids] - data.subtree_com[handle.layout.root[touch]])
    return touch


def occluded_mask(handle, data, touch, sel, b_of_sel) -> np.ndarray:
    """(len(sel),) bool: elements ``sel`` (of the touching bodies ``touch[b_of_sel]``) inside a run-time
    occluder (a geom of another weld group, :func:`rft_mujoco.compiled.elements.occluders`)."""
    occ = handle.layout.occluders
    out = np.zeros(sel.size, dtype=bool)
    for j, i in enumerate(touch):
        rows = np.flatnonzero(b_of_sel == j)
        if occ.start[i] == occ.start[i + 1] or rows.size == 0:
            continue
        b = handle.body_ids[i]
        world = data.xpos[b] + handle.local_centroids[sel[rows]] @ data.xmat[b].reshape(3, 3).T
        for o in range(occ.start[i], occ.start[i + 1]):
            g = occ.geom[o]
            local = (world - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
            hs = occ.halfspaces[occ.hs_start[o]:occ.hs_start[o + 1]] if occ.kind[o] == mujoco.mjtGeom.mjGEOM_MESH \
                else None
            out[rows] |= occlusion.inside_geom(local, int(occ.kind[o]), occ.size[o], mesh_halfspaces=hs,
                                               margin=occ.margin)
    return out


def _touching_elements(handle, data, touch):
    """The elements (n,) of the touching bodies, their rows (n,) in ``touch``, and which are inside a run-time
    occluder (n,) bool."""
    sel = np.concatenate([np.arange(handle.layout.elem_slices[i], handle.layout.elem_slices[i + 1]) for i in touch])
    remap = np.empty(len(handle.body_ids), dtype=np.int64)
    remap[touch] = np.arange(touch.size)
    b = remap[handle.elem_body[sel]]
    return sel, b, occluded_mask(handle, data, touch, sel, b)


def _surface(handle, sel, b, k) -> elements.BodySurface:
    """The elements ``sel`` of the ``k`` touching bodies, on their rows ``b`` (:func:`_touching_elements`)."""
    return elements.BodySurface(handle.local_centroids[sel], handle.local_normals[sel], handle.areas[sel], b, k)


def _pose(a, k) -> elements.BodyPose:
    """The poses of the ``k`` touching bodies: the first rows of the workspace's arrays ``a``."""
    return elements.BodyPose(a["body_pos"][:k], a["body_mat"][:k].reshape(k, 3, 3), a["body_com"][:k])


def rft(handle, data, work, touch, v_com, omega, g_hat):
    """RFT wrenches (k, 6) about each touching body's COM for body twists (v_com, omega) (k, 3), the loaded
    element counts (k,), deepest loaded depths (k,) m and the submerged area inside occluders (k,) m^2."""
    k = touch.size
    a = work.arrays
    sel, b, hidden = _touching_elements(handle, data, touch)
    pos = a["body_pos"][:k][b] + np.einsum("eij,ej->ei", a["body_mat"][:k].reshape(k, 3, 3)[b],
                                           handle.local_centroids[sel])
    submerged = work.terrain.depth(pos, g_hat) > 0.0
    occluded = np.bincount(b, weights=handle.areas[sel] * (hidden & submerged), minlength=k)
    wrench, count, max_depth = elements.body_wrenches(
        _surface(handle, sel, b, k), _pose(a, k), v_com, omega, work.terrain, g_hat, handle.model.opt.gravity,
        handle.media, handle.guards, active=~hidden)
    return wrench, count, max_depth, occluded


class Outcome(NamedTuple):
    """What one evaluation did besides its wrenches.

    Attributes:
        status: :func:`commit`'s (1: a non-zero wrench, 0: none, -1: not finite).
        kept: a later RK4 stage used the first stage's mobility and rest factor (rest treatment).
        locked_dofs: dofs held by their dry friction in the rest solve.
        newton_iterations: the implicit solve's Newton iterations (0: another solve).
    """

    status: int
    kept: bool = False
    locked_dofs: int = 0
    newton_iterations: int = 0


def evaluate_naive(handle, data, work, touch, g_hat, sand_out) -> Outcome:
    """``stabilize=False``: the published force at each element's velocity (``passive``: a body's wrench is
    dropped when it would do positive work)."""
    k = touch.size
    v_com, omega = work.arrays["v_com"][:k], work.arrays["omega"][:k]
    wrench, count, max_depth, occluded = rft(handle, data, work, touch, v_com, omega, g_hat)
    applied = wrench.copy()
    if handle.passive:
        power = np.einsum("ij,ij->i", wrench[:, :3], v_com) + np.einsum("ij,ij->i", wrench[:, 3:], omega)
        applied[power > 0.0] = 0.0
    return Outcome(commit(handle, work.diag, touch, applied, wrench, count, max_depth, occluded,
                          np.zeros(k, dtype=bool), sand_out))


def evaluate_rest(handle, data, user_xfrc, work, touch, dt, g_hat, lagged, stage, sand_out) -> Outcome:
    """The rest treatment (:mod:`rft_mujoco.physics.rest`) of the touching bodies; ``lagged``: MuJoCo's last
    constraint solve belongs to this motion (:meth:`~rft_mujoco.coupling.workspace._Workspace.follow_time`);
    ``stage``: the RK4 stage (1-4; 0: another integrator)."""
    m, grp = handle.model, handle.groups
    a = work.arrays
    group_of = grp.of_body[touch]                      # (k,) group of each touching body
    active = np.unique(group_of)                       # (G,) touching groups
    slot = np.searchsorted(active, group_of)           # (k,) row of each body's group in ``active``
    ref = handle.body_ids[grp.ref[active]]             # (G,) MuJoCo ids of the reference bodies
    radius = grp.radius[active]
    jac, free, twist, qacc = free_twists(handle, data, user_xfrc, ref, dt, lagged)
    dofs, force, capacity = stuck_dofs(handle, data, ref) if lagged else (np.zeros(0, np.int64),) * 3
    # Element motions of the blended twists, at each touching body's COM.
    u = rest.blend(twist, free, radius)
    arm = a["body_com"][:touch.size] - data.xipos[ref[slot]]    # (k, 3) reference point -> body COM
    omega = u[slot, 3:]
    v_com = u[slot, :3] + np.cross(omega, arm)
    wrench, count, max_depth, occluded = rft(handle, data, work, touch, v_com, omega, g_hat)
    # The groups' RFT wrenches at their reference points, their mobility, the rest wrenches.
    rft_g = np.zeros((active.size, 6))
    np.add.at(rft_g, slot, np.hstack([wrench[:, :3], wrench[:, 3:] + np.cross(arm, wrench[:, :3])]))
    keep = work.keep
    # A later RK4 stage reuses an earlier stage's mobility and factor while the same groups touch and no
    # dof is held by its dry friction (the locks change the mobility).
    frozen = stage >= 2 and keep.groups is not None and np.array_equal(keep.groups, active) and dofs.size == 0
    if not frozen:
        flat = jac.reshape(-1, m.nv)
        minv_jt = np.empty_like(flat)
        mujoco.mj_solveM(m, data, minv_jt, flat)
        keep.factor.clear()
        kept = stage >= 1 and dofs.size == 0
        keep.groups, keep.mobility = (active if kept else None), flat @ minv_jt.T
    n_locked = 0
    prev = work.arrays["lock_prev"]                        # (nv,) the dofs locked in the last evaluation
    sticky = bool(prev[dofs].any())
    prev[:] = False
    if dofs.size:
        rows = np.zeros((dofs.size, m.nv))
        rows[np.arange(dofs.size), dofs] = 1.0
        minv_et = np.empty_like(rows)                      # (L, nv) M^-1 E^T, by rows
        mujoco.mj_solveM(m, data, minv_et, rows)
        applied_g, resting_g, locked = rest.locked_rest(
            free, keep.mobility, jac.reshape(-1, m.nv) @ minv_et.T, minv_et[:, dofs], qacc[dofs], force, capacity,
            dt, lambda f, mob: rest.rest_wrenches(f, mob, rft_g, u, radius, dt), twist, radius, not sticky)
        prev[dofs[locked]] = True
        n_locked = int(np.count_nonzero(locked))
    else:
        applied_g, resting_g = rest.rest_wrenches(free, keep.mobility, rft_g, u, radius, dt,
                                                  keep.factor if keep.groups is not None else None, frozen)
    applied = share(applied_g, rft_g, resting_g, wrench, slot, arm, radius)
    status = commit(handle, work.diag, touch, applied, wrench, count, max_depth, occluded, resting_g[slot], sand_out)
    return Outcome(status, bool(frozen), n_locked)


class StepKeep:
    """What the rest treatment keeps from the first stage of an RK4 step for its later stages, per
    (handle, MjData): the touching groups (None: nothing kept), their mobility ``J M^-1 J^T`` and the
    rest solve's factor (:class:`rft_mujoco.physics.rest.StepFactor`).

    Stages 2-4 of a step evaluate the sand at states within one step of the first; while the same groups
    touch, they use its mobility and its rest factor (the weights of the load sharing included) with
    their own free twists, RFT wrenches and capacities: the rest wrenches still stop the resting groups
    at the end of the step as that mobility predicts it. The compiled path keeps the same in its
    workspace (``keep_active``, ``keep_rest``, ``mob``, ``lin``, ``perm``; :data:`rft_mujoco.compiled.evaluate.STATE`)."""

    __slots__ = ("groups", "mobility", "factor")

    def __init__(self) -> None:
        self.groups = None
        self.mobility = None
        self.factor = rest.StepFactor()

    def clear(self) -> None:
        self.groups = None
        self.mobility = None
        self.factor.clear()


def free_twists(handle, data, user_xfrc, ref, dt, lagged):
    """Jacobians (G, 6, nv) of the reference bodies' COMs, their free twists (G, 6) at the end of the step
    without sand, their twists now (G, 6) and the free acceleration (nv,).

    The free acceleration uses the smooth forces of this evaluation (passive, bias, actuators, applied,
    the user's xfrc_applied) plus, when ``lagged``, the constraint forces of MuJoCo's previous solve.
    """
    m = handle.model
    jac, qfrc = _jacobians_and_forces(m, data, user_xfrc, ref)
    if lagged:
        qfrc = qfrc + data.qfrc_constraint
    qacc = np.empty(m.nv)
    mujoco.mj_solveM(m, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
    _check_acceleration(m, ref, qacc)
    twist = jac @ data.qvel
    return jac, twist + dt * (jac @ qacc), twist, qacc


def _jacobians_and_forces(m, data, user_xfrc, ref):
    """Jacobians (G, 6, nv) of the reference bodies' COMs and the smooth generalized force (nv,) of this
    evaluation: passive, bias, actuators (``mj_fwdActuation`` is run: MuJoCo computes them after
    ``mjcb_control``), ``qfrc_applied`` and the user's ``xfrc_applied``."""
    jac = np.empty((ref.size, 6, m.nv))
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for i, b in enumerate(ref):
        mujoco.mj_jacBodyCom(m, data, jacp, jacr, int(b))
        jac[i, :3] = jacp
        jac[i, 3:] = jacr
    mujoco.mj_fwdActuation(m, data)
    qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
    for b in np.flatnonzero(np.any(user_xfrc[1:] != 0.0, axis=1)) + 1:
        mujoco.mj_applyFT(m, data, user_xfrc[b, :3].copy(), user_xfrc[b, 3:].copy(), data.xipos[b].copy(),
                          int(b), qfrc)
    return jac, qfrc


def _check_acceleration(m, ref, qacc) -> None:
    if not np.all(np.isfinite(qacc)):
        names = [m.body(int(b)).name for b in ref]
        raise FloatingPointError(
            f"non-finite acceleration without sand while computing sand forces on bodies {names}: "
            "data.ctrl, data.qfrc_applied or data.xfrc_applied holds NaN/inf (or the model's "
            "actuators produce it); fix the input before stepping")


def stuck_dofs(handle, data, ref):
    """The dofs (L,) whose dry friction (``frictionloss``) held them still in MuJoCo's last solve, on the
    kinematic trees of the reference bodies ``ref``, in MuJoCo's row order; their friction force (L,) and
    ``frictionloss`` (L,) (N or N m; :func:`rft_mujoco.physics.rest.friction_estimate`).

    MuJoCo makes this step's rows, their impedance and reference acceleration before ``mjcb_control``;
    ``qacc`` still holds its last solve. Tendon frictionloss rows are not locked."""
    m = handle.model
    rows = np.flatnonzero(data.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF)
    dofs = data.efc_id[rows].astype(np.int64)
    force = rest.friction_estimate(data.efc_D[rows], data.efc_aref[rows], data.qacc[dofs])
    capacity = data.efc_frictionloss[rows].copy()
    trees = {_tree_dof(m, _chain_dof(m, int(b))) for b in ref}
    stuck = (np.abs(force) < capacity) & np.array([_tree_dof(m, int(d)) in trees for d in dofs], dtype=bool)
    return dofs[stuck], force[stuck], capacity[stuck]


def _chain_dof(m, b: int) -> int:
    """The last dof of body ``b``'s kinematic chain (its own, or its nearest ancestor's), -1 if none."""
    while b > 0:
        if m.body_dofnum[b] > 0:
            return int(m.body_dofadr[b] + m.body_dofnum[b] - 1)
        b = int(m.body_parentid[b])
    return -1


def _tree_dof(m, j: int) -> int:
    """The dof nearest the world on dof ``j``'s chain (-1 for -1): dofs of one tree share it."""
    while j >= 0 and m.dof_parentid[j] >= 0:
        j = int(m.dof_parentid[j])
    return j


def share(applied_g, rft_g, resting_g, rft_b, slot, arm, radius) -> np.ndarray:
    """Each touching body's part (k, 6) of its group's wrench (about the body's COM).

    A group in flow gives each body its own RFT wrench times the group's factor; a resting group's rest
    wrench is shared in proportion to the bodies' RFT wrenches (torques over the group radius), with the
    torque chosen so that the parts add up to the group's wrench about its reference point. The bodies of
    a group are welded together, so the split changes the diagnostics only, never the motion.
    """
    k = slot.size
    out = np.zeros((k, 6))
    r = radius[slot][:, None]
    size = np.linalg.norm(np.hstack([rft_b[:, :3], rft_b[:, 3:] / r]), axis=1)
    total = np.bincount(slot, weights=size, minlength=rft_g.shape[0])
    g_norm = np.linalg.norm(np.hstack([rft_g[:, :3], rft_g[:, 3:] / radius[:, None]]), axis=1)
    a_norm = np.linalg.norm(np.hstack([applied_g[:, :3], applied_g[:, 3:] / radius[:, None]]), axis=1)
    for j in range(k):
        g = slot[j]
        if total[g] <= 0.0:
            continue
        if not resting_g[g]:
            out[j] = rft_b[j] * (a_norm[g] / g_norm[g] if g_norm[g] > 0.0 else 0.0)
            continue
        out[j, :3] = size[j] / total[g] * applied_g[g, :3]
    for g in np.flatnonzero(resting_g):
        mine = np.flatnonzero(slot == g)
        if total[g] <= 0.0:
            continue
        moment = applied_g[g, 3:] - np.cross(arm[mine], out[mine, :3]).sum(axis=0)
        out[mine, 3:] = (size[mine] / total[g])[:, None] * moment[None, :]
    return out


def commit(handle, diag, touch, applied, rft_b, count, max_depth, occluded, resting, sand_out) -> int:
    """Diagnostics of the touching bodies and ``applied`` (k, 6) into ``sand_out``. Returns 1 when a wrench
    is non-zero, 0 when none is, -1 (``sand_out`` untouched) when one is not finite."""
    diag.clear()
    radius = handle.layout.bound_radius[touch][:, None]
    rft_norm = np.linalg.norm(np.hstack([rft_b[:, :3], rft_b[:, 3:] / radius]), axis=1)
    app_norm = np.linalg.norm(np.hstack([applied[:, :3], applied[:, 3:] / radius]), axis=1)
    loaded = rft_norm > 0.0
    diag.force[touch] = applied[:, :3]
    diag.torque[touch] = applied[:, 3:]
    diag.rft_force[touch] = rft_b[:, :3]
    diag.submerged[touch] = count
    diag.max_depth[touch] = max_depth
    diag.occluded_area[touch] = occluded
    diag.scale[touch[loaded]] = app_norm[loaded] / rft_norm[loaded]
    diag.resting[touch] = resting & loaded
    if not np.all(np.isfinite(applied)):
        return -1
    np.add.at(sand_out, handle.body_ids[touch], applied)
    return int(np.any(applied != 0.0))


# --- the implicit solve (attach(solve="implicit"), numpy backend) -------------------------------------------
_C = mujoco.mjtConstraint
_UNILATERAL = tuple(int(c) for c in (_C.mjCNSTR_LIMIT_JOINT, _C.mjCNSTR_LIMIT_TENDON, _C.mjCNSTR_CONTACT_FRICTIONLESS,
                                     _C.mjCNSTR_CONTACT_PYRAMIDAL))
_FRICTION = (int(_C.mjCNSTR_FRICTION_DOF), int(_C.mjCNSTR_FRICTION_TENDON))
_EQUALITY, _ELLIPTIC = int(_C.mjCNSTR_EQUALITY), int(_C.mjCNSTR_CONTACT_ELLIPTIC)


def constraint_rows(model, data) -> np.ndarray:
    """(nefc, nv) this step's constraint Jacobian ``efc_J``, dense (MuJoCo stores it sparse for large models)."""
    nefc = data.nefc
    if nefc == 0:
        return np.zeros((0, model.nv))
    if mujoco.mj_isSparse(model):
        dense = np.zeros((nefc, model.nv))
        for i in range(nefc):
            adr, nnz = data.efc_J_rowadr[i], data.efc_J_rownnz[i]
            dense[i, data.efc_J_colind[adr:adr + nnz]] = data.efc_J[adr:adr + nnz]
        return dense
    return np.asarray(data.efc_J[:nefc * model.nv]).reshape(nefc, model.nv).copy()


def constraint_zones(model, data, rows: np.ndarray, qacc: np.ndarray, prev=None):
    """The zone of each of this step's constraint rows (``rows``: :func:`constraint_rows`) at the accelerations
    ``qacc`` (nv,): ``quad`` (nefc,) bool, the rows in their quadratic zone, and ``const`` (nefc,), the constant
    force of saturated dry-friction rows (N or N m). A row's zone is that of the force it would carry at
    ``qacc`` in its quadratic zone, ``-D (J qacc - aref)``: equality rows quadratic; dry friction quadratic
    inside its bound, a constant force at it; limits and contacts quadratic while pushing; an elliptic
    contact's rows all quadratic while its first (normal) row is (an approximation of the cone).

    ``prev``: the zones ``(quad, const)`` that ``qacc`` was solved in. A dry friction saturated there stays
    saturated only while the force it would carry keeps its sign and bound (the slip goes on), and sticks
    (quadratic) otherwise: a stiff friction row's quadratic force at a slipping solution is far beyond its
    bound, with the sign of the slip, so the plain rule would flip it from one bound to the other."""
    n = rows.shape[0]
    kind = data.efc_type[:n]
    est = rest.friction_estimate(data.efc_D[:n], data.efc_aref[:n], rows @ qacc)
    quad = np.zeros(n, dtype=bool)
    const = np.zeros(n)
    for i, t in enumerate(kind.tolist()):
        if t == _EQUALITY:
            quad[i] = True
        elif t in _FRICTION:
            fl = data.efc_frictionloss[i]
            if prev is not None and prev[1][i] != 0.0:
                slip = np.sign(prev[1][i]) * est[i] >= fl
                quad[i], const[i] = not slip, prev[1][i] if slip else 0.0
            elif abs(est[i]) < fl:
                quad[i] = True
            else:
                const[i] = np.sign(est[i]) * fl
        elif t in _UNILATERAL:
            quad[i] = est[i] > 0.0
    if np.any(kind == _ELLIPTIC):
        for c in np.unique(data.efc_id[:n][kind == _ELLIPTIC]):
            sel = np.flatnonzero((kind == _ELLIPTIC) & (data.efc_id[:n] == c))
            quad[sel] = est[sel[0]] > 0.0
    return quad, const


def constrained_free_motion(model, data, qfrc: np.ndarray, zones=None):
    """This step's constraints, linearized in their ``zones`` (:func:`constraint_zones`; default: at the
    accelerations of MuJoCo's last solve, ``data.qacc``): the matrix ``H`` (nv, nv), the force ``f`` (nv,) with
    ``H qacc = f + J^T W`` for any sand wrench ``W`` while the rows keep their zone, and the zones.

    MuJoCo's constraint solve minimizes ``1/2 |qacc - qacc_smooth|_M^2 + sum_i s_i(J_i qacc - aref_i)``; a row
    in its quadratic zone has ``s = D (J qacc - aref)^2 / 2`` (force ``-D (J qacc - aref)``), a saturated
    dry-friction row a constant force, an inactive row none. MuJoCo makes this step's rows (``efc_J``, ``efc_D``,
    ``efc_aref``) before ``mjcb_control``. So the loads that reach the sand through contacts, welds, limits
    and dry friction enter with this step's constraint forces, and the sand's own wrench moves them as
    MuJoCo's solve will; :func:`evaluate_implicit` takes the zones again at the step's end accelerations."""
    nv = model.nv
    mass = np.zeros((nv, nv))
    mujoco.mj_fullM(model, data, mass)
    rows = constraint_rows(model, data)
    if rows.shape[0] == 0:
        return mass, qfrc, None
    quad, const = constraint_zones(model, data, rows, data.qacc) if zones is None else zones
    d, aref = data.efc_D[:rows.shape[0]], data.efc_aref[:rows.shape[0]]
    jq, dq = rows[quad], d[quad]
    return mass + jq.T @ (dq[:, None] * jq), qfrc + jq.T @ (dq * aref[quad]) + rows.T @ const, (quad, const)


_IMPLICIT = (int(mujoco.mjtIntegrator.mjINT_IMPLICIT), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))


def velocity_damping(model) -> np.ndarray:
    """(nv,) the damping (N s/m, N m s/rad) that MuJoCo's implicit integrators treat implicitly, on the diagonal:
    joint damping plus the velocity gain of affine actuators on a joint (a position servo's ``kv``, times the
    gear squared); zeros with Euler and RK4. The step's velocity is then ``(M + dt D) qacc = f``, as MuJoCo's
    ``implicitfast`` integrates it (a servo's ``kv`` on a light link is far beyond an explicit step:
    ``dt kv / I`` is 100 on the swimmer at the animal's density). Tendon and fluid damping are left out."""
    out = np.zeros(model.nv)
    if int(model.opt.integrator) not in _IMPLICIT:
        return out
    out += model.dof_damping
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and \
                model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE:
            dof = model.jnt_dofadr[model.actuator_trnid[a, 0]]
            out[dof] += -model.actuator_biasprm[a, 2] * model.actuator_gear[a, 0] ** 2
    return out


def implicit_free(handle, data, user_xfrc, ref, dt, constraints: str, zones=None, lagged: bool = False):
    """Jacobians (G, 6, nv), free twists (G, 6), twists now (G, 6), the mobility (6G, 6G) of the groups'
    reference points for the implicit solve, and the end accelerations (nv,) as a function of the groups'
    wrenches (G, 6): with ``constraints="linearized"`` through this step's constraint rows in their ``zones``
    (:func:`constrained_free_motion`; default: at MuJoCo's last solve) and the zones, with
    ``"lagged"`` through the mass matrix and MuJoCo's previous constraint forces when they belong to this motion
    (``lagged``, as :func:`free_twists`; zones None)."""
    m = handle.model
    jac, qfrc = _jacobians_and_forces(m, data, user_xfrc, ref)
    flat = jac.reshape(-1, m.nv)
    if constraints == "linearized":
        h, f, zones = constrained_free_motion(m, data, qfrc, zones)
        h = h + dt * np.diag(velocity_damping(m))
        chol = np.linalg.cholesky(h)
        solve = lambda b: np.linalg.solve(chol.T, np.linalg.solve(chol, b))       # noqa: E731
        qacc = solve(f)
        minv_jt = solve(flat.T)
    else:
        if lagged:
            qfrc = qfrc + data.qfrc_constraint
        qacc = np.empty(m.nv)
        mujoco.mj_solveM(m, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
        minv_jt = np.empty_like(flat)
        mujoco.mj_solveM(m, data, minv_jt, flat)
        minv_jt = minv_jt.T
        zones = None
    _check_acceleration(m, ref, qacc)
    twist = jac @ data.qvel
    end_qacc = lambda w: qacc + minv_jt @ w.reshape(-1)                              # noqa: E731
    return jac, twist + dt * (jac @ qacc), twist, flat @ minv_jt, end_qacc, zones


def rft_jacobian(handle, data, work, touch, v_com, omega, g_hat, speed_scale, elements_=None):
    """As :func:`rft` with the regularized law and its derivative (k, 6, 6) in each body's COM twist.
    ``elements_``: :func:`_touching_elements` of this pose, if already computed (the poses do not change
    while a step's solve calls the law again and again)."""
    k = touch.size
    a = work.arrays
    sel, b, hidden = _touching_elements(handle, data, touch) if elements_ is None else elements_
    return elements.body_wrench_jacobians(
        _surface(handle, sel, b, k), _pose(a, k), v_com, omega, work.terrain, g_hat, handle.model.opt.gravity,
        handle.media, handle.guards, speed_scale, active=~hidden)


def _shift(arm: np.ndarray) -> np.ndarray:
    """(k, 6, 6) ``S`` with (v_com, omega) = S (v_ref, omega) for COMs at ``arm`` (k, 3) from the reference."""
    s = np.zeros((arm.shape[0], 6, 6))
    s[:, :3, :3] = np.eye(3)
    s[:, 3:, 3:] = np.eye(3)
    s[:, 0, 4], s[:, 0, 5], s[:, 1, 5] = arm[:, 2], -arm[:, 1], arm[:, 0]
    s[:, 1, 3], s[:, 2, 3], s[:, 2, 4] = -arm[:, 2], arm[:, 1], -arm[:, 0]
    return s


def evaluate_implicit(handle, data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out) -> Outcome:
    """The implicit solve (:func:`rft_mujoco.physics.implicit.implicit_wrenches`) of the touching bodies;
    ``lagged`` as in :func:`evaluate_rest`."""
    grp = handle.groups
    group_of = grp.of_body[touch]
    active = np.unique(group_of)
    slot = np.searchsorted(active, group_of)
    ref = handle.body_ids[grp.ref[active]]
    radius = grp.radius[active]
    jac, free, twist, mobility, end_qacc, zones = implicit_free(handle, data, user_xfrc, ref, dt,
                                                                 handle.constraints, lagged=lagged)
    arm = work.arrays["body_com"][:touch.size] - data.xipos[ref[slot]]
    shift = _shift(arm)
    last = {}
    touching = _touching_elements(handle, data, touch)

    def law(u, groups):
        ub = np.einsum("kij,kj->ki", shift, u[slot])
        w_b, j_b, count, max_depth = rft_jacobian(handle, data, work, touch, ub[:, :3], ub[:, 3:], g_hat,
                                                  implicit.SPEED_SCALE, touching)
        f = np.zeros((active.size, 6))
        np.add.at(f, slot, np.einsum("kji,kj->ki", shift, w_b))
        df = np.zeros((active.size, 6, 6))
        np.add.at(df, slot, np.einsum("kji,kjl,klm->kim", shift, j_b, shift))
        last.update(w_b=w_b, count=count, max_depth=max_depth, u=u)
        return f, df

    prior = work.flowing                              # (groups, flowed) of the last evaluation of this motion
    flowing = prior[1] if prior is not None and lagged and np.array_equal(prior[0], active) else None
    applied_g, resting_g, end, its = implicit.implicit_wrenches(free, mobility, law, twist, radius, dt, flowing)
    for _ in range(implicit.ZONE_PASSES - 1):
        if zones is None:
            break
        now = constraint_zones(handle.model, data, constraint_rows(handle.model, data), end_qacc(applied_g), zones)
        if np.array_equal(now[0], zones[0]) and np.array_equal(now[1], zones[1]):
            break
        last_end, last_rest = end, resting_g
        jac, free, twist, mobility, end_qacc, zones = implicit_free(handle, data, user_xfrc, ref, dt,
                                                                     handle.constraints, now, lagged)
        start = np.where(last_rest[:, None], twist, last_end)   # a group that flowed starts from its last answer
        applied_g, resting_g, end, its = implicit.implicit_wrenches(free, mobility, law, twist, radius, dt,
                                                                    flowing, start)
    work.flowing = (active, ~resting_g)
    # The bodies' own law wrenches at the end twists (flow) and at the probe (capacities, rest sharing).
    probe = rest.blend(twist, free, radius)
    law(np.where(resting_g[:, None], probe, end), np.ones(active.size, dtype=bool))
    wrench = last["w_b"]
    rft_g = np.zeros((active.size, 6))
    np.add.at(rft_g, slot, np.einsum("kji,kj->ki", shift, wrench))
    applied = share(applied_g, rft_g, resting_g, wrench, slot, arm, radius)
    sel, b, hidden = touching                          # the submerged area inside other bodies' geoms
    mats = work.arrays["body_mat"][:touch.size].reshape(-1, 3, 3)[b]
    pos = work.arrays["body_pos"][:touch.size][b] + np.einsum("eij,ej->ei", mats, handle.local_centroids[sel])
    occluded = np.bincount(b, weights=handle.areas[sel] * (hidden & (handle.terrain.depth(pos, g_hat) > 0.0)),
                           minlength=touch.size)
    status = commit(handle, work.diag, touch, applied, wrench, last["count"], last["max_depth"], occluded,
                    resting_g[slot], sand_out)
    return Outcome(status, newton_iterations=int(its))
