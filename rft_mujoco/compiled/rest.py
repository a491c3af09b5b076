"""The rest treatment's math, compiled: MuJoCo's mass-matrix factor, body Jacobians, the rest solve.

* :func:`solve_m`: ``x <- M^-1 x`` with MuJoCo's own sparse factor ``qLD`` (read, never written);
  :func:`check_layout` verifies once per model that the factor is laid out as it reads it (mujoco 4).
* :func:`jacobian`: a body point's Jacobian from MuJoCo's ``cdof`` (what ``mj_jac`` computes).
* :func:`rest_wrenches`: :func:`rft_mujoco.physics.rest.rest_wrenches` on work buffers, with the very
  :func:`~rft_mujoco.physics.rest.pivoted_solve` of the reference compiled.

Nothing here calls MuJoCo. The evaluation that uses them is :mod:`rft_mujoco.compiled.evaluate`.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.physics import rest as _rest
from rft_mujoco.compiled.jit import JIT, njit

@njit(**JIT)
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


@njit(**JIT)
def _chain_dof(b, body_dofnum, body_dofadr, body_parentid):
    """The last dof of body ``b``'s kinematic chain (its own, or its nearest ancestor's), -1 if none."""
    while b > 0:
        if body_dofnum[b] > 0:
            return body_dofadr[b] + body_dofnum[b] - 1
        b = body_parentid[b]
    return -1


@njit(**JIT)
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


KEPT_GROUPS, KEPT_RANK = 6, 7
"""Entries of the evaluation's ``state`` (:data:`rft_mujoco.compiled.evaluate.STATE`) that the rest solve
reads and writes: the groups whose mobility is kept for this RK4 step (0: none), the kept factor's rank."""

pivoted_factor = njit(**JIT)(_rest.pivoted_factor)
pivoted_apply = njit(**JIT)(_rest.pivoted_apply)


@njit(**JIT)
def pivoted_solve(a, rhs, weight, dependent_tol, tiny):
    """:func:`rft_mujoco.physics.rest.pivoted_solve` compiled as it is (the oracle of :func:`min_norm_solve`)."""
    order, g, w = pivoted_factor(a, weight, dependent_tol, tiny)
    return pivoted_apply(a, rhs, order, g, w)


@njit(**JIT)
def min_norm_solve(a, rhs, weight, m, dependent_tol, tiny, lin, perm, x):
    """:func:`rft_mujoco.physics.rest.pivoted_solve` of ``a[:m, :m]`` (a symmetric buffer, rows of any
    width >= m), ``rhs[:m]``, ``weight[:m]`` into ``x[:m]``, with the same arithmetic in the same order
    (bit for bit), on work buffers: ``lin`` (>= 3 m + 5, >= m) float, ``perm`` (>= 2 m,) int:
    :func:`min_norm_factor` then :func:`min_norm_apply`."""
    k = min_norm_factor(a, weight, m, dependent_tol, tiny, lin, perm)
    min_norm_apply(a, rhs, weight, m, k, lin, perm, x)


@njit(**JIT)
def min_norm_factor(a, weight, m, dependent_tol, tiny, lin, perm):
    """:func:`rft_mujoco.physics.rest.pivoted_factor` of ``a[:m, :m]`` and ``weight[:m]`` into ``lin`` (the
    factor ``g`` in rows 2 m..3 m) and ``perm`` (the kept rows first); returns their number k.

    The reference's inner loops are dot products (a serial chain of additions: latency-bound); here each
    is an update of a whole contiguous row by one product per step (the same additions per entry, in
    the same order, independent across entries: vectorized), e.g. the factor's new column is
    ``a[p] - sum_j low_j * low_j[p]`` accumulated over j as row updates rather than entry by entry, four
    terms per pass (each entry still adds them one after the other)."""
    low = lin[0:m]                    # low[k, i]: column k of the pivoted factor, rows i in input order
    bt = lin[m:2 * m]                 # bt[j, r] = a[order[r], j]
    g = lin[2 * m:3 * m]
    diag0, rem = lin[3 * m], lin[3 * m + 1]
    order, kept = perm[0:m], perm[m:2 * m]
    for i in range(m):
        diag0[i] = a[i, i]
        rem[i] = a[i, i]
        kept[i] = 0
    k = 0
    while k < m:
        p = -1
        best = dependent_tol
        for i in range(m):
            if kept[i] == 0 and diag0[i] > tiny and rem[i] > best * diag0[i]:
                best = rem[i] / diag0[i]
                p = i
        if p < 0:
            break
        kept[p] = 1
        order[k] = p
        piv = np.sqrt(rem[p])
        col = low[k]
        for i in range(m):
            col[i] = a[i, p]
        j = 0
        while j + 4 <= k:                           # four updates per pass over the column, in order
            l0, l1, l2, l3 = low[j], low[j + 1], low[j + 2], low[j + 3]
            f0, f1, f2, f3 = l0[p], l1[p], l2[p], l3[p]
            for i in range(m):
                col[i] = (((col[i] - l0[i] * f0) - l1[i] * f1) - l2[i] * f2) - l3[i] * f3
            j += 4
        while j < k:
            lj = low[j]
            f = lj[p]
            for i in range(m):
                col[i] -= lj[i] * f
            j += 1
        for i in range(m):
            col[i] = col[i] / piv if (kept[i] == 0 or i == p) else 0.0
        for i in range(m):
            if kept[i] == 0:
                rem[i] -= col[i] * col[i]
        k += 1
    if k == 0:
        return 0
    for j in range(m):
        for r in range(k):
            bt[j, r] = a[order[r], j]
    for r in range(k):
        for c in range(r + 1):
            g[r, c] = 0.0
    j = 0
    while j + 4 <= m:                               # four terms per pass over g, in order
        b0, b1, b2, b3 = bt[j], bt[j + 1], bt[j + 2], bt[j + 3]
        w0, w1, w2, w3 = weight[j], weight[j + 1], weight[j + 2], weight[j + 3]
        for r in range(k):
            s0, s1, s2, s3 = b0[r] * w0, b1[r] * w1, b2[r] * w2, b3[r] * w3
            gr = g[r]
            for c in range(r + 1):
                gr[c] = (((gr[c] + s0 * b0[c]) + s1 * b1[c]) + s2 * b2[c]) + s3 * b3[c]
        j += 4
    while j < m:
        wj = weight[j]
        row = bt[j]
        for r in range(k):
            s = row[r] * wj
            gr = g[r]
            for c in range(r + 1):
                gr[c] += s * row[c]
        j += 1
    _cholesky(k, g, tiny)                           # in place (lower), as the reference
    return k


@njit(**JIT)
def _cholesky(k, g, tiny):
    """The lower Cholesky factor of ``g[:k, :k]`` in place (its lower triangle read; the loops of
    :func:`rft_mujoco.physics.rest.pivoted_factor`; a pivot below ``tiny`` is ``sqrt(tiny)``)."""
    for c in range(k):
        t = g[c, c]
        for j in range(c):
            t -= g[c, j] * g[c, j]
        d = np.sqrt(t) if t > tiny else np.sqrt(tiny)
        g[c, c] = d
        for r in range(c + 1, k):
            t = g[r, c]
            for j in range(c):
                t -= g[r, j] * g[c, j]
            g[r, c] = t / d


@njit(**JIT)
def _cholesky_solve(m, low, x):
    """``x[:m] <- (R R^T)^-1 x[:m]`` for the lower triangular ``R = low[:m, :m]`` (the loops of
    :func:`rft_mujoco.physics.rest.pivoted_apply`)."""
    for r in range(m):
        t = x[r]
        for c in range(r):
            t -= low[r, c] * x[c]
        x[r] = t / low[r, r]
    for r in range(m - 1, -1, -1):
        t = x[r]
        for c in range(r + 1, m):
            t -= low[c, r] * x[c]
        x[r] = t / low[r, r]


@njit(**JIT)
def min_norm_apply(a, rhs, weight, m, k, lin, perm, x):
    """:func:`rft_mujoco.physics.rest.pivoted_apply`: ``x[:m]`` from :func:`min_norm_factor`'s ``k``, ``lin``
    and ``perm`` (made with these ``a[:m, :m]`` and ``weight[:m]``) and ``rhs[:m]``."""
    if k == 0:
        for i in range(m):
            x[i] = 0.0
        return
    g = lin[2 * m:3 * m]
    y, acc = lin[3 * m + 2], lin[3 * m + 3]
    order = perm[0:m]
    for r in range(k):
        y[r] = rhs[order[r]]
    _cholesky_solve(k, g, y)
    for j in range(m):
        acc[j] = 0.0
    for r in range(k):
        yr = y[r]
        ar = a[order[r]]
        for j in range(m):
            acc[j] += ar[j] * yr
    for j in range(m):
        x[j] = weight[j] * acc[j]


@njit(**JIT)
def _flow_factor(h, q):
    """:func:`rft_mujoco.physics.rest._flow_factor`."""
    if h >= 0.0:
        return 0.0
    if q <= 0.0:
        return 1.0
    return min(1.0, -h / q)


@njit(**JIT)
def rest_wrenches(free, mob, rft, direction, radius, dt, ng, dependent_tol, weight_floor, capacity_tol, tiny, a, v,
                  cap, w, rest, flow, idx, block, rhs, capacity, v_w, lin, perm, sol, keep_rest, state, reuse):
    """:func:`rft_mujoco.physics.rest.rest_wrenches` for groups 0..ng-1 (rows of ``free``, ``rft``, ``displacement``:
    (>= ng, 6), ``mob`` (>= 6 ng, >= 6 ng)); the wrenches go to ``w`` (>= ng, 6), the rest flags to ``rest``.
    The other arguments are work buffers: ``a`` (6 ng, 6 ng), ``v``/``rhs`` (6 ng,), ``cap`` (ng, 6),
    ``flow`` (ng,) bool, ``idx`` (6 ng,) int, ``block`` (6 ng, 6 ng), and those of :func:`min_norm_solve`
    (``lin``, ``perm``, ``sol`` (6 ng,)). The kept factor (``keep`` and ``reuse`` of the reference): its
    resting groups in ``keep_rest`` (G,), its rank in ``state[KEPT_RANK]`` (-1: none), made only while
    ``state[KEPT_GROUPS] > 0`` (the caller keeps the mobility of this step); ``lin``, ``perm`` and
    ``v_w`` hold it until the next factor, and with ``reuse`` ``a`` still holds the scaled mobility the
    factor was made from (the same ``mob``, radii and dt), so it is not rebuilt."""
    n6 = 6 * ng
    for gi in range(ng):                             # loops over (group, component): no i // 6, i % 6
        for ci in range(6):
            i = 6 * gi + ci
            si = radius[gi] if ci >= 3 else 1.0
            v[i] = free[gi, ci] * si
            if reuse:                                # ``a`` is still the first stage's (same mob, radii, dt)
                continue
            for gj in range(ng):
                rj = radius[gj]
                for cj in range(6):
                    sj = rj if cj >= 3 else 1.0
                    a[i, 6 * gj + cj] = dt * (si * mob[i, 6 * gj + cj] * sj)
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
            any_flow = False
            for g in range(ng):
                any_flow = any_flow or flow[g]
            for i in range(m):
                s = v[idx[i]]
                if any_flow:                          # w is zero without a group in flow: rhs = v exactly
                    row = a[idx[i]]
                    for gj in range(ng):
                        for cj in range(6):
                            s += row[6 * gj + cj] * w[gj, cj]
                rhs[i] = s
            every = m == n6                           # every group at rest: the block is ``a`` itself
            if not every:
                for i in range(m):
                    for j in range(m):
                        block[i, j] = a[idx[i], idx[j]]
            same = reuse and state[KEPT_RANK] >= 0.0
            for g in range(ng):
                same = same and rest[g] == keep_rest[g]
            if same:
                k = int(state[KEPT_RANK])
            else:
                top = 0.0
                for i in range(m):                    # the groups' squared capacities (rest.rest_wrenches)
                    gi = idx[i] // 6
                    t = 0.0
                    for c in range(6):
                        t += cap[gi, c] * cap[gi, c]
                    v_w[i] = t
                    top = max(top, t)
                for i in range(m):
                    v_w[i] = max(v_w[i], weight_floor * top)
                k = min_norm_factor(a if every else block, v_w, m, dependent_tol, tiny, lin, perm)
                state[KEPT_RANK] = k if state[KEPT_GROUPS] > 0.0 else -1.0
                for g in range(ng):
                    keep_rest[g] = rest[g]
            min_norm_apply(a if every else block, rhs, v_w, m, k, lin, perm, sol)
            for i in range(m):
                w[idx[i] // 6, idx[i] % 6] = -sol[i]
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
    for gi in range(ng):
        for ci in range(6):
            i = 6 * gi + ci
            wi = w[gi, ci]
            h += wi * v[i]
            t = 0.0
            row = a[i]
            for gj in range(ng):
                for cj in range(6):
                    t += row[6 * gj + cj] * w[gj, cj]
            q += wi * t
    scale = 1.0
    if h + 0.5 * q > 0.0:
        scale = _flow_factor(h, q) if h < 0.0 else 0.0
    for g in range(ng):
        for c in range(6):
            w[g, c] *= scale * (radius[g] if c >= 3 else 1.0)


# --- dofs held by their dry friction (rest.locked_rest) --------------------------------------------------
FRICTION_DOF = 1
"""MuJoCo's ``mjCNSTR_FRICTION_DOF`` (checked against the bindings by tests/test_fastrest.py)."""
LOCK_TOL = _rest.LOCK_TOL
""":data:`rft_mujoco.physics.rest.LOCK_TOL` (frozen into the compiled code)."""


@njit(**JIT)
def _tree_dof(j, dof_parentid):
    """:func:`rft_mujoco.coupling.reference._tree_dof`."""
    while j >= 0 and dof_parentid[j] >= 0:
        j = dof_parentid[j]
    return j


@njit(**JIT)
def stuck_dofs(efc_type, efc_id, efc_d, efc_aref, efc_frictionloss, qacc_prev, ng, active, ids, group_ref,
               body_dofnum, body_dofadr, body_parentid, dof_parentid, lock_i, lock_f, group_tree):
    """:func:`rft_mujoco.coupling.reference.stuck_dofs`: the dofs into ``lock_i[0]``, their friction forces
    and frictionloss into ``lock_f[0]``, ``lock_f[1]``; returns their number L. ``group_tree`` (G,): work
    space (the groups' tree dofs, found at the first friction row)."""
    n = 0
    trees = False
    for e in range(efc_type.shape[0]):
        if efc_type[e] != FRICTION_DOF:
            continue
        j = efc_id[e]
        f = -efc_d[e] * (qacc_prev[j] - efc_aref[e])       # rest.friction_estimate
        cap = efc_frictionloss[e]
        if not abs(f) < cap:
            continue
        if not trees:
            for r in range(ng):
                b = ids[group_ref[active[r]]]
                group_tree[r] = _tree_dof(_chain_dof(b, body_dofnum, body_dofadr, body_parentid), dof_parentid)
            trees = True
        tree = _tree_dof(j, dof_parentid)
        mine = False
        for r in range(ng):
            mine = mine or group_tree[r] == tree
        if not mine:
            continue
        lock_i[0, n] = j
        lock_f[0, n] = f
        lock_f[1, n] = cap
        n += 1
    return n


@njit(**JIT)
def lock_matrices(nl, rowadr, rownnz, colind, qld, qld_diag_inv, qacc, dof_parentid, lock_i, lock_f, lock_z,
                  lock_chain, lock_s):
    """For the ``nl`` dofs of :func:`stuck_dofs` (``lock_i[0]``): ``S = E M^-1 E^T`` into ``lock_s`` (L, L)
    and ``y = E qacc`` into ``lock_f[2]``. A dof's column ``W_E = D^-1/2 L^-T e_j`` (``lock_z[:, l]``; the
    factor ``M = L^T D L`` as in :func:`rft_mujoco.compiled.evaluate._mobility`) lies on its chain
    (``lock_chain``); products sum over the dofs two chains share (next to the root)."""
    for l in range(nl):
        j = lock_i[0, l]
        n = 0
        while j >= 0:
            lock_chain[l, 1 + n] = j
            lock_z[j, l] = 0.0
            n += 1
            j = dof_parentid[j]
        lock_chain[l, 0] = n
        lock_z[lock_i[0, l], l] = 1.0
        for u in range(n):
            j = lock_chain[l, 1 + u]
            a0 = rowadr[j]
            x = lock_z[j, l]
            for a in range(a0, a0 + rownnz[j] - 1):
                lock_z[colind[a], l] -= qld[a] * x
        for u in range(n):
            j = lock_chain[l, 1 + u]
            lock_z[j, l] *= math.sqrt(qld_diag_inv[j])
        lock_f[2, l] = qacc[lock_i[0, l]]
    for l in range(nl):
        nd = lock_chain[l, 0]
        for m in range(l + 1):
            nm = lock_chain[m, 0]
            s = 0.0
            t = 0
            while t < nd and t < nm and lock_chain[l, nd - t] == lock_chain[m, nm - t]:
                j = lock_chain[l, nd - t]
                s += lock_z[j, l] * lock_z[j, m]
                t += 1
            lock_s[l, m] = s
            lock_s[m, l] = s


@njit(**JIT)
def _lock_coupling(nl, ng, chain, zt, lock_z, lock_chain, lock_c):
    """``C^T = E M^-1 J^T = W_E^T W`` into ``lock_c`` (L, 6 ng), with ``zt``/``chain`` the scaled
    ``W = D^-1/2 L^-T J^T`` of :func:`rft_mujoco.compiled.evaluate._mobility`."""
    for l in range(nl):
        nd = lock_chain[l, 0]
        for r in range(ng):
            nr = chain[r, 0]
            for c in range(6):
                lock_c[l, 6 * r + c] = 0.0
            t = 0
            while t < nr and t < nd and chain[r, nr - t] == lock_chain[l, nd - t]:
                j = chain[r, nr - t]
                z = lock_z[j, l]
                for c in range(6):
                    lock_c[l, 6 * r + c] += z * zt[j, 6 * r + c]
                t += 1


@njit(**JIT)
def _lock_cholesky(m, lock_i, lock_s, lock_r, tiny):
    """The lower Cholesky factor ``R`` of ``S`` over the dofs ``lock_i[2, :m]`` into ``lock_r``
    (:func:`rft_mujoco.physics.rest._cholesky`)."""
    for c in range(m):
        lc = lock_i[2, c]
        for r in range(c, m):
            lock_r[r, c] = lock_s[lock_i[2, r], lc]
    _cholesky(m, lock_r, tiny)


@njit(**JIT)
def _lock_factor(m, n6, lock_i, lock_f, lock_s, lock_c, lock_r, lock_x, tiny):
    """:func:`rft_mujoco.physics.rest._lock_factor` for the ``m`` dofs ``lock_i[2, :m]``: ``R`` into
    ``lock_r``, ``X`` into ``lock_x`` rows, ``z`` into ``lock_f[3]`` (compact: index r of ``lock_i[2]``)."""
    _lock_cholesky(m, lock_i, lock_s, lock_r, tiny)
    for r in range(m):                               # X = R^-1 C^T, z = R^-1 y
        lr = lock_i[2, r]
        for i in range(n6):
            t = lock_c[lr, i]
            for j in range(r):
                t -= lock_r[r, j] * lock_x[j, i]
            lock_x[r, i] = t / lock_r[r, r]
        t = lock_f[2, lr]
        for j in range(r):
            t -= lock_r[r, j] * lock_f[3, j]
        lock_f[3, r] = t / lock_r[r, r]


@njit(**JIT)
def _lock_needed(nl, ng, nv, dt, chain, zt, free, twist, radius, w, lock_i, lock_f, lock_z, lock_chain, lock_s,
                 lock_r, tiny):
    """Step 1 of :func:`rft_mujoco.physics.rest.locked_rest`: whether the groups' motion ``dt C lam_u``
    from the friction that would hold every dof under the unlocked wrenches ``w`` exceeds LOCK_TOL of their
    twist change. Without ``C``: ``C^T w = W_E^T (W w)`` and ``C lam = W^T (W_E lam)`` through nv-vectors
    (``lock_f[4]``); ``lam_u`` in ``lock_f[3]``."""
    q = lock_f[4]
    for j in range(nv):
        q[j] = 0.0
    for r in range(ng):                              # q = W w
        for u in range(chain[r, 0]):
            j = chain[r, 1 + u]
            t = 0.0
            for c in range(6):
                t += zt[j, 6 * r + c] * w[r, c]
            q[j] += t
    for l in range(nl):                              # y + C^T w
        t = lock_f[2, l]
        for u in range(lock_chain[l, 0]):
            j = lock_chain[l, 1 + u]
            t += lock_z[j, l] * q[j]
        lock_f[3, l] = t
        lock_i[2, l] = l
    _lock_cholesky(nl, lock_i, lock_s, lock_r, tiny)
    lam = lock_f[3]
    _cholesky_solve(nl, lock_r, lam)                 # lam_u = -S^-1 (y + C^T w)
    for l in range(nl):
        lam[l] = -lam[l]
    for j in range(nv):
        q[j] = 0.0
    for l in range(nl):                              # q = W_E lam_u
        for u in range(lock_chain[l, 0]):
            j = lock_chain[l, 1 + u]
            q[j] += lock_z[j, l] * lock_f[3, l]
    for g in range(ng):                              # dt C lam_u = dt W^T q, against the twist change
        ml = ma = sl = sa = 0.0
        for c in range(6):
            t = 0.0
            for u in range(chain[g, 0]):
                j = chain[g, 1 + u]
                t += zt[j, 6 * g + c] * q[j]
            t *= dt
            d = free[g, c] - twist[g, c]
            if c < 3:
                ml += t * t
                sl += d * d
            else:
                ma += t * t
                sa += d * d
        if math.sqrt(ml) + radius[g] * math.sqrt(ma) > LOCK_TOL * (math.sqrt(sl) + radius[g] * math.sqrt(sa)):
            return True
    return False


@njit(**JIT)
def _plus_xw(m, n6, w, lock_x, lock_f):
    """``lock_f[3, :m] += X W`` (``W`` (G, 6) flattened)."""
    for r in range(m):
        t = lock_f[3, r]
        for i in range(n6):
            t += lock_x[r, i] * w[i // 6, i % 6]
        lock_f[3, r] = t


@njit(**JIT)
def locked_rest(nl, free, mob, rft, direction, radius, dt, ng, settings, a, v, cap, w, rest, flow, idx, block, rhs,
                capacity, v_w, lin, perm, sol, keep_rest, state, twist, chain, zt, lock_i, lock_f, lock_z, lock_chain,
                lock_s, lock_c, lock_r, lock_x, lock_mob, lock_free, lock_w, lock_rest, check):
    """:func:`rft_mujoco.physics.rest.locked_rest` on the matrices of :func:`lock_matrices`, with
    :func:`rest_wrenches` (its arguments as there; ``settings`` = dependent_tol, weight_floor,
    capacity_tol, tiny; no factor is kept: ``state[KEPT_GROUPS]`` is 0); ``twist`` (G, 6) the groups'
    twists now; ``chain``, ``zt``: the scaled Jacobians of ``_mobility``; ``check``: whether step 1 runs.
    Returns the number of dofs held
    in the final solve; which: ``lock_i[1]`` (1/0); the other ``lock_*`` are work space."""
    n6 = 6 * ng
    tiny = settings[3]
    rest_wrenches(free, mob, rft, direction, radius, dt, ng, settings[0], settings[1], settings[2], tiny, a, v, cap,
                  w, rest, flow, idx, block, rhs, capacity, v_w, lin, perm, sol, keep_rest, state, False)
    for l in range(nl):
        lock_i[1, l] = 0
    if check and not _lock_needed(nl, ng, lock_f.shape[1], dt, chain, zt, free, twist, radius, w, lock_i, lock_f,
                                  lock_z, lock_chain, lock_s, lock_r, tiny):
        return 0
    _lock_coupling(nl, ng, chain, zt, lock_z, lock_chain, lock_c)
    for l in range(nl):
        lock_i[1, l] = 1
    for g in range(ng):
        lock_rest[g] = rest[g]
        for c in range(6):
            lock_w[g, c] = w[g, c]
    while True:
        m = 0
        for l in range(nl):
            if lock_i[1, l] != 0:
                lock_i[2, m] = l
                m += 1
        if m == 0:                                   # every lock released: the unlocked solve
            for g in range(ng):
                rest[g] = lock_rest[g]
                for c in range(6):
                    w[g, c] = lock_w[g, c]
            return 0
        _lock_factor(m, n6, lock_i, lock_f, lock_s, lock_c, lock_r, lock_x, tiny)
        for i in range(n6):                          # A - X^T X, Vf - dt X^T z
            for k in range(i + 1):
                t = mob[i, k]
                for r in range(m):
                    t -= lock_x[r, i] * lock_x[r, k]
                lock_mob[i, k] = t
                lock_mob[k, i] = t
            t = 0.0
            for r in range(m):
                t += lock_x[r, i] * lock_f[3, r]
            lock_free[i // 6, i % 6] = free[i // 6, i % 6] - dt * t
        rest_wrenches(lock_free, lock_mob, rft, direction, radius, dt, ng, settings[0], settings[1], settings[2],
                      tiny, a, v, cap, w, rest, flow, idx, block, rhs, capacity, v_w, lin, perm, sol, keep_rest,
                      state, False)
        _plus_xw(m, n6, w, lock_x, lock_f)           # lam = -R^-T (z + X W)
        for r in range(m - 1, -1, -1):
            t = lock_f[3, r]
            for j in range(r + 1, m):
                t -= lock_r[j, r] * lock_f[3, j]
            lock_f[3, r] = t / lock_r[r, r]
        over = False
        for r in range(m):
            lr = lock_i[2, r]
            if abs(lock_f[0, lr] - lock_f[3, r]) > lock_f[1, lr]:
                lock_i[1, lr] = 0
                over = True
        if not over:
            return m
