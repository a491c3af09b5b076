"""Compiled (numba) rest evaluation: :meth:`rft_mujoco.coupling.handle.SandHandle._evaluate_rest` in one call.

The same numbers as the numpy reference (to round-off, tests/test_fastrest.py), without temporaries:
Jacobians of the groups' reference points from MuJoCo's ``cdof``, the free acceleration from the smooth
forces (and the previous solve's constraint forces) through MuJoCo's own factor of the mass matrix
(``qLD``, solved here: :func:`solve_m`), the groups' mobility, the blended twists, the element kernel
(:func:`rft_mujoco.compiled.elements.wrenches`), the rest solve of :mod:`rft_mujoco.physics.rest` and the wrenches into
the dispatcher's sum.

Nothing here calls MuJoCo: the caller runs ``mj_fwdActuation`` first (MuJoCo computes actuator forces
only after ``mjcb_control``). :func:`check_layout` verifies, once per model, that MuJoCo's factor is laid
out as :func:`solve_m` reads it (the layout of mujoco 4); the coupling uses the numpy path with a
warning where it is not.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.physics import rest as _rest
from rft_mujoco.compiled.elements import GROUPS_PER_BODY, _JIT, njit, wrenches

# Status codes of :func:`evaluate` (besides 0: no wrench, 1: a non-zero wrench).
NOT_FINITE = -1
"""A wrench came out non-finite; nothing was written."""
BAD_ACCELERATION = -2
"""The acceleration without sand is not finite (NaN/inf inputs); nothing was written."""


@njit(**_JIT)
def solve_m(rownnz, rowadr, colind, qld, qld_diag_inv, x):
    """``x <- M^-1 x`` in place with MuJoCo's sparse factor ``M = L^T D L`` (``qLD``, ``qLDiagInv``; CSR
    rows ``rowadr``/``rownnz``/``colind`` of ``M_*``, diagonal last in each row)."""
    nv = x.shape[0]
    for i in range(nv - 1, 0, -1):
        xi = x[i]
        if xi != 0.0:
            a0 = rowadr[i]
            for a in range(a0, a0 + rownnz[i] - 1):
                x[colind[a]] -= qld[a] * xi
    for i in range(nv):
        x[i] *= qld_diag_inv[i]
    for i in range(1, nv):
        a0 = rowadr[i]
        s = 0.0
        for a in range(a0, a0 + rownnz[i] - 1):
            s += qld[a] * x[colind[a]]
        x[i] -= s


def check_layout(model, data) -> bool:
    """Whether :func:`solve_m` agrees with ``mujoco.mj_solveM`` on this model (after ``mj_forward``-like
    factorization of ``data``), to 1e-9 relative; and MuJoCo's reals are float64."""
    import mujoco

    if data.qLD.dtype != np.float64 or data.cdof.dtype != np.float64:
        return False
    if model.nv == 0:
        return True
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_crb(model, data)
    mujoco.mj_factorM(model, data)
    y = np.random.default_rng(0).normal(size=model.nv)
    ref = np.zeros(model.nv)
    mujoco.mj_solveM(model, data, ref.reshape(1, -1), y.reshape(1, -1))
    x = y.copy()
    solve_m(model.M_rownnz.astype(np.int64), model.M_rowadr.astype(np.int64), model.M_colind.astype(np.int64),
            data.qLD, data.qLDiagInv, x)
    return bool(np.all(np.isfinite(x)) and np.abs(x - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max()))


@njit(**_JIT)
def _chain_dof(b, body_dofnum, body_dofadr, body_parentid):
    """The last dof of body ``b``'s kinematic chain (its own, or its nearest ancestor's), -1 if none."""
    while b > 0:
        if body_dofnum[b] > 0:
            return body_dofadr[b] + body_dofnum[b] - 1
        b = body_parentid[b]
    return -1


@njit(**_JIT)
def jacobian(b, px, py, pz, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid,
             dof_parentid, out, row):
    """Rows ``row..row+5`` of ``out`` (.., nv) := the Jacobian [linear velocity of point p; angular velocity]
    of body ``b`` (``mj_jac``), from ``cdof`` (motions about ``subtree_com`` of the root)."""
    nv = out.shape[1]
    for r in range(6):
        for j in range(nv):
            out[row + r, j] = 0.0
    rt = body_rootid[b]
    dx = px - subtree_com[rt, 0]
    dy = py - subtree_com[rt, 1]
    dz = pz - subtree_com[rt, 2]
    j = _chain_dof(b, body_dofnum, body_dofadr, body_parentid)
    while j >= 0:
        wx, wy, wz = cdof[j, 0], cdof[j, 1], cdof[j, 2]
        out[row + 0, j] = cdof[j, 3] + (wy * dz - wz * dy)
        out[row + 1, j] = cdof[j, 4] + (wz * dx - wx * dz)
        out[row + 2, j] = cdof[j, 5] + (wx * dy - wy * dx)
        out[row + 3, j] = wx
        out[row + 4, j] = wy
        out[row + 5, j] = wz
        j = dof_parentid[j]


pivoted_solve = njit(**_JIT)(_rest.pivoted_solve)
"""The rest solve's rank-revealing Cholesky, :func:`rft_mujoco.physics.rest.pivoted_solve` compiled."""


@njit(**_JIT)
def _flow_factor(h, q):
    """:func:`rft_mujoco.physics.rest._flow_factor`."""
    if h >= 0.0:
        return 0.0
    if q <= 0.0:
        return 1.0
    return min(1.0, -h / q)


@njit(**_JIT)
def rest_wrenches(free, mob, rft, direction, radius, dt, ng, dependent_tol, weight_floor, capacity_tol, tiny, a, v,
                  cap, w, rest, flow, idx, block, rhs, capacity, v_w):
    """:func:`rft_mujoco.physics.rest.rest_wrenches` for groups 0..ng-1 (rows of ``free``, ``rft``, ``displacement``:
    (>= ng, 6), ``mob`` (>= 6 ng, >= 6 ng)); the wrenches go to ``w`` (>= ng, 6), the rest flags to ``rest``.
    The other arguments are work buffers: ``a`` (6 ng, 6 ng), ``v``/``rhs`` (6 ng,), ``cap`` (ng, 6),
    ``flow`` (ng,) bool, ``idx`` (6 ng,) int, ``block`` (6 ng, 6 ng)."""
    n6 = 6 * ng
    for i in range(n6):
        gi = i // 6
        si = radius[gi] if i % 6 >= 3 else 1.0
        v[i] = free[gi, i % 6] * si
        for j in range(n6):
            gj = j // 6
            sj = radius[gj] if j % 6 >= 3 else 1.0
            a[i, j] = dt * (si * mob[i, j] * sj)
    for g in range(ng):
        nonzero = False
        d = 0.0
        for c in range(6):
            x = rft[g, c] / radius[g] if c >= 3 else rft[g, c]
            cap[g, c] = x
            nonzero = nonzero or x != 0.0
            d -= rft[g, c] * direction[g, c]         # the same in unscaled units (products are invariant)
        capacity[g] = d if d > 0.0 else 0.0
        rest[g] = nonzero
        flow[g] = False
    while True:
        for g in range(ng):
            for c in range(6):
                w[g, c] = 0.0
            if flow[g]:
                h = 0.0
                q = 0.0
                for c in range(6):
                    h += cap[g, c] * v[6 * g + c]
                    t = 0.0
                    for e in range(6):
                        t += a[6 * g + c, 6 * g + e] * cap[g, e]
                    q += cap[g, c] * t
                f = _flow_factor(h, q)
                for c in range(6):
                    w[g, c] = f * cap[g, c]
        m = 0
        for g in range(ng):
            if rest[g]:
                for c in range(6):
                    idx[m] = 6 * g + c
                    m += 1
        if m > 0:
            for i in range(m):
                s = v[idx[i]]
                for j in range(n6):
                    s += a[idx[i], j] * w[j // 6, j % 6]
                rhs[i] = s
                for j in range(m):
                    block[i, j] = a[idx[i], idx[j]]
            top = 0.0
            for i in range(m):                        # the groups' squared capacities (rest.rest_wrenches)
                gi = idx[i] // 6
                t = 0.0
                for c in range(6):
                    t += cap[gi, c] * cap[gi, c]
                v_w[i] = t
                top = max(top, t)
            for i in range(m):
                v_w[i] = max(v_w[i], weight_floor * top)
            x = pivoted_solve(block[:m, :m], rhs[:m], v_w[:m], dependent_tol, tiny)
            for i in range(m):
                w[idx[i] // 6, idx[i] % 6] = -x[i]
            over = False
            for g in range(ng):
                if rest[g]:
                    demand = 0.0
                    for c in range(6):
                        s = radius[g] if c >= 3 else 1.0
                        demand -= w[g, c] * direction[g, c] * s    # w is scaled, direction is not
                    if demand > capacity[g] * (1.0 + capacity_tol):
                        rest[g] = False
                        flow[g] = True
                        over = True
            if over:
                continue
        break
    # passivity of the whole impulse (rest.passive_scale)
    h = 0.0
    q = 0.0
    for i in range(n6):
        wi = w[i // 6, i % 6]
        h += wi * v[i]
        t = 0.0
        for j in range(n6):
            t += a[i, j] * w[j // 6, j % 6]
        q += wi * t
    scale = 1.0
    if h + 0.5 * q > 0.0:
        scale = _flow_factor(h, q) if h < 0.0 else 0.0
    for g in range(ng):
        for c in range(6):
            w[g, c] *= scale * (radius[g] if c >= 3 else 1.0)


class Buffers:
    """The work arrays of :func:`evaluate` for one (handle, MjData): B attached bodies, G groups, nv dofs."""

    def __init__(self, n_bodies: int, n_groups: int, nv: int) -> None:
        b, g, n6 = n_bodies, n_groups, 6 * n_groups
        self.active = np.zeros(g, dtype=np.int64)
        self.slot = np.zeros(b, dtype=np.int64)
        self.idx = np.zeros(n6, dtype=np.int64)
        self.rest = np.zeros(g, dtype=np.bool_)
        self.flow = np.zeros(g, dtype=np.bool_)
        self.jac = np.zeros((n6, nv))
        self.minv_jt = np.zeros((n6, nv))
        self.mob = np.zeros((n6, n6))
        self.a = np.zeros((n6, n6))
        self.block = np.zeros((n6, n6))
        self.qacc = np.zeros(nv)
        self.v = np.zeros(n6)
        self.rhs = np.zeros(n6)
        self.weight = np.zeros(n6)
        self.twist, self.free, self.u, self.rft_g, self.w, self.cap = (np.zeros((g, 6)) for _ in range(6))
        self.u_lin, self.u_ang, self.arm = (np.zeros((b, 3)) for _ in range(3))
        self.wrench, self.applied = np.zeros((b, 6)), np.zeros((b, 6))
        self.size = np.zeros(b)
        self.total = np.zeros(g)

    def arrays(self) -> tuple:
        """In the order of :func:`evaluate`'s buffer arguments."""
        return (self.active, self.slot, self.idx, self.rest, self.flow, self.jac, self.minv_jt, self.mob, self.a,
                self.block, self.qacc, self.v, self.rhs, self.weight, self.twist, self.free, self.u, self.rft_g, self.w,
                self.cap, self.u_lin, self.u_ang, self.arm, self.wrench, self.applied, self.size, self.total)


@njit(**_JIT)
def _norm6(x, r):
    """|(x[:3], x[3:] / r)|."""
    return math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
                     + (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]) / (r * r))


@njit(**_JIT)
def evaluate(touch, k, ids, group_of, group_ref, group_radius, bound_radius,
             xipos, cdof, subtree_com, qvel, qfrc_passive, qfrc_bias, qfrc_actuator, qfrc_applied,
             qfrc_constraint, qld, qld_diag_inv, body_rootid, body_dofnum, body_dofadr, body_parentid,
             dof_parentid, rownnz, rowadr, colind, user_xfrc, lagged, dt,
             centroids, normals, areas, cluster_start, cluster_octant, cluster_center, cluster_radius,
             body_clusters, body_pos, body_mat, body_com, v_com, omega, g_hat, max_height, kind, tp, heights, xi_n,
             coef, mu_surf, no_tension, no_forward, no_power, tol, settings, scratch, groups, count, max_depth,
             active, slot, idx, rest, flow, jac, minv_jt, mob, a, block, qacc, v, rhs, weight, twist, free, u, rft_g,
             w, cap,
             u_lin, u_ang, arm, wrench, applied, size, total,
             force, torque, submerged, depth_max, scale, rft_force, resting, sand_out):
    """The rest evaluation of the touching bodies ``touch[:k]`` (indices into ``ids``; their poses in rows
    0..k-1 of ``body_pos``/``body_mat``/``body_com``, velocities in ``v_com``/``omega``, from
    :func:`rft_mujoco.compiled.elements.touching`), as ``SandHandle._evaluate_rest`` computes it.

    MjData arrays: ``xipos`` .. ``qld_diag_inv`` (``qfrc_actuator`` after ``mj_fwdActuation``); model
    arrays: ``body_rootid`` .. ``colind`` (``M_rownnz``, ``M_rowadr``, ``M_colind``); the handle's groups
    (``group_of`` (B,), ``group_ref`` (G,), ``group_radius`` (G,)); ``user_xfrc`` (nbody, 6) the user's
    wrenches; ``lagged``: add ``qfrc_constraint`` (MuJoCo's previous solve) to the free acceleration;
    ``settings`` = (DEPENDENT_TOL, WEIGHT_FLOOR, CAPACITY_TOL, TINY) of :mod:`rft_mujoco.physics.rest`. Diagnostics (B, ...) are overwritten in every row, the
    applied wrenches added to ``sand_out`` (nbody, 6) at rows ``ids[touch[j]]``.

    Returns 1 (a non-zero wrench), 0 (none), NOT_FINITE or BAD_ACCELERATION (nothing written).
    """
    nv = qvel.shape[0]
    nb = ids.shape[0]
    # 1. the touching groups, in increasing group order, and each touching body's row among them
    ng_all = group_ref.shape[0]
    for g in range(ng_all):
        rest[g] = False
    for j in range(k):
        rest[group_of[touch[j]]] = True
    ng = 0
    for g in range(ng_all):
        if rest[g]:
            active[ng] = g
            ng += 1
    for j in range(k):
        gj = group_of[touch[j]]
        for r in range(ng):
            if active[r] == gj:
                slot[j] = r
    # 2. free acceleration: smooth forces (+ the previous constraint forces) + the user's wrenches, M^-1
    for i in range(nv):
        f = qfrc_passive[i] - qfrc_bias[i] + qfrc_actuator[i] + qfrc_applied[i]
        qacc[i] = f + qfrc_constraint[i] if lagged else f
    for b in range(1, user_xfrc.shape[0]):
        nonzero = False
        for c in range(6):
            if user_xfrc[b, c] != 0.0:
                nonzero = True
        if not nonzero:
            continue
        jacobian(b, xipos[b, 0], xipos[b, 1], xipos[b, 2], cdof, subtree_com, body_rootid, body_dofnum,
                 body_dofadr, body_parentid, dof_parentid, minv_jt, 0)
        for i in range(nv):
            s = 0.0
            for c in range(6):
                s += minv_jt[c, i] * user_xfrc[b, c]
            qacc[i] += s
    solve_m(rownnz, rowadr, colind, qld, qld_diag_inv, qacc)
    for i in range(nv):
        if not math.isfinite(qacc[i]):
            return BAD_ACCELERATION
    # 3. Jacobians of the reference points, twists now and free, mobility J M^-1 J^T
    for r in range(ng):
        b = ids[group_ref[active[r]]]
        jacobian(b, xipos[b, 0], xipos[b, 1], xipos[b, 2], cdof, subtree_com, body_rootid, body_dofnum,
                 body_dofadr, body_parentid, dof_parentid, jac, 6 * r)
    n6 = 6 * ng
    for i in range(n6):
        t = 0.0
        s = 0.0
        for j in range(nv):
            t += jac[i, j] * qvel[j]
            s += jac[i, j] * qacc[j]
            minv_jt[i, j] = jac[i, j]
        twist[i // 6, i % 6] = t
        free[i // 6, i % 6] = t + dt * s
        solve_m(rownnz, rowadr, colind, qld, qld_diag_inv, minv_jt[i])
    for i in range(n6):
        for j in range(i + 1):
            s = 0.0
            for c in range(nv):
                s += jac[i, c] * minv_jt[j, c]
            mob[i, j] = s
            mob[j, i] = s
    # 4. blended twists (rest.blend), moved to each touching body's COM
    for r in range(ng):
        g = active[r]
        rad = group_radius[g]
        sl = 0.0
        sa = 0.0
        vl = 0.0
        va = 0.0
        for c in range(3):
            d0 = free[r, c] - twist[r, c]
            d1 = free[r, 3 + c] - twist[r, 3 + c]
            sl += d0 * d0
            sa += d1 * d1
            vl += twist[r, c] * twist[r, c]
            va += twist[r, 3 + c] * twist[r, 3 + c]
        s = math.sqrt(sl) + rad * math.sqrt(sa)
        vv = math.sqrt(vl) + rad * math.sqrt(va)
        wgt = s * s / (vv * vv + s * s) if s > 0.0 else 0.0
        for c in range(6):
            u[r, c] = twist[r, c] + wgt * (free[r, c] - twist[r, c])
    for j in range(k):
        r = slot[j]
        b_ref = ids[group_ref[active[r]]]
        ax = body_com[j, 0] - xipos[b_ref, 0]
        ay = body_com[j, 1] - xipos[b_ref, 1]
        az = body_com[j, 2] - xipos[b_ref, 2]
        arm[j, 0] = ax
        arm[j, 1] = ay
        arm[j, 2] = az
        wx, wy, wz = u[r, 3], u[r, 4], u[r, 5]
        u_ang[j, 0] = wx
        u_ang[j, 1] = wy
        u_ang[j, 2] = wz
        u_lin[j, 0] = u[r, 0] + (wy * az - wz * ay)
        u_lin[j, 1] = u[r, 1] + (wz * ax - wx * az)
        u_lin[j, 2] = u[r, 2] + (wx * ay - wy * ax)
    # 5. RFT wrenches at the blended twists; the groups' wrenches about their reference points
    wrenches(touch, k, centroids, normals, areas, cluster_start, cluster_octant, cluster_center, cluster_radius,
             body_clusters, body_pos, body_mat, body_com, u_lin, u_ang, wrench[:0], 0.0, g_hat, max_height, kind,
             tp, heights, xi_n, coef, mu_surf, no_tension, no_forward, no_power, tol, scratch, groups, count,
             max_depth)
    for r in range(ng):
        for c in range(6):
            rft_g[r, c] = 0.0
    for j in range(k):
        for c in range(6):
            s = 0.0
            for o in range(GROUPS_PER_BODY):
                s += groups[j, o, c]
            wrench[j, c] = s
        r = slot[j]
        fx, fy, fz = wrench[j, 0], wrench[j, 1], wrench[j, 2]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
        rft_g[r, 0] += fx
        rft_g[r, 1] += fy
        rft_g[r, 2] += fz
        rft_g[r, 3] += wrench[j, 3] + (ay * fz - az * fy)
        rft_g[r, 4] += wrench[j, 4] + (az * fx - ax * fz)
        rft_g[r, 5] += wrench[j, 5] + (ax * fy - ay * fx)
    # 6. the rest solve (rest.rest_wrenches), in the groups' radii
    rad_g = total                                   # (G,) reuses ``total`` as the active groups' radii
    for r in range(ng):
        rad_g[r] = group_radius[active[r]]
    rest_wrenches(free, mob, rft_g, u, rad_g, dt, ng, settings[0], settings[1], settings[2], settings[3], a, v, cap,
                  w, rest, flow, idx, block, rhs, size, weight)
    # 7. each body's part (coupling._share)
    for j in range(k):
        size[j] = _norm6(wrench[j], rad_g[slot[j]])
    for r in range(ng):
        cap[r, 0] = 0.0                             # reuses ``cap`` column 0 as the groups' total size
    for j in range(k):
        cap[slot[j], 0] += size[j]
    for j in range(k):
        r = slot[j]
        for c in range(6):
            applied[j, c] = 0.0
        if cap[r, 0] <= 0.0:
            continue
        if not rest[r]:
            gn = _norm6(rft_g[r], rad_g[r])
            f = _norm6(w[r], rad_g[r]) / gn if gn > 0.0 else 0.0
            for c in range(6):
                applied[j, c] = wrench[j, c] * f
        else:
            share = size[j] / cap[r, 0]
            for c in range(3):
                applied[j, c] = share * w[r, c]
    for r in range(ng):
        if not rest[r] or cap[r, 0] <= 0.0:
            continue
        mx, my, mz = w[r, 3], w[r, 4], w[r, 5]
        for j in range(k):
            if slot[j] == r:
                ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
                fx, fy, fz = applied[j, 0], applied[j, 1], applied[j, 2]
                mx -= ay * fz - az * fy
                my -= az * fx - ax * fz
                mz -= ax * fy - ay * fx
        for j in range(k):
            if slot[j] == r:
                share = size[j] / cap[r, 0]
                applied[j, 3] = share * mx
                applied[j, 4] = share * my
                applied[j, 5] = share * mz
    # 8. diagnostics and the wrenches into sand_out (SandHandle._commit)
    for i in range(nb):
        for c in range(3):
            force[i, c] = 0.0
            torque[i, c] = 0.0
            rft_force[i, c] = 0.0
        submerged[i] = 0
        depth_max[i] = 0.0
        scale[i] = 1.0
        resting[i] = False
    status = 0
    for j in range(k):
        i = touch[j]
        rb = bound_radius[i]
        rn = _norm6(wrench[j], rb)
        for c in range(3):
            force[i, c] = applied[j, c]
            torque[i, c] = applied[j, 3 + c]
            rft_force[i, c] = wrench[j, c]
        submerged[i] = count[j]
        depth_max[i] = max_depth[j]
        if rn > 0.0:
            scale[i] = _norm6(applied[j], rb) / rn
            resting[i] = rest[slot[j]]
        for c in range(6):
            x = applied[j, c]
            if not math.isfinite(x):
                status = NOT_FINITE
            elif x != 0.0 and status == 0:
                status = 1
    if status == NOT_FINITE:
        return NOT_FINITE
    for j in range(k):
        row = ids[touch[j]]
        for c in range(6):
            sand_out[row, c] += applied[j, c]
    return status


def warm_up(wrench_arrays, kind, tp, heights, coef, tol) -> None:
    """Compile :func:`evaluate` for the argument types the coupling passes (one tiny call)."""
    i8 = np.int64
    nv, nb, nc = 6, 2, 1
    one = np.zeros(1, dtype=i8)
    buf = Buffers(1, 1, nv)
    tree = tuple(np.zeros(nb, dtype=i8) for _ in range(4)) + (np.full(nv, -1, dtype=i8),) + tuple(
        np.zeros(nv, dtype=i8) for _ in range(3))
    diag = (np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1, dtype=i8), np.zeros(1), np.ones(1), np.zeros((1, 3)),
            np.zeros(1, dtype=np.bool_))
    evaluate(one[:0], 0, np.ones(1, dtype=i8), one, one, np.ones(1), np.ones(1), np.zeros((nb, 3)),
             np.zeros((nv, 6)), np.zeros((nb, 3)), np.zeros(nv), np.zeros(nv), np.zeros(nv), np.zeros(nv),
             np.zeros(nv), np.zeros(nv), np.zeros(nc), np.ones(nv), *tree, np.zeros((nb, 6)), False, 0.001,
             *wrench_arrays, np.zeros((1, 3)), np.zeros((1, 9)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)),
             np.zeros(3), 0.0, kind, tp, heights, 1.0, coef, 0.4, False, False, False, tol, np.zeros(4),
             np.zeros((11, 128)), np.zeros((1, GROUPS_PER_BODY, 6)), np.zeros(1, dtype=i8), np.zeros(1),
             *buf.arrays(), *diag, np.zeros((nb, 6)))
