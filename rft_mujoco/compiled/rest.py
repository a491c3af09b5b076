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
from rft_mujoco.compiled import schema as sc
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


JAC_TREE = ("body_rootid", "body_dofnum", "body_dofadr", "body_parentid", "dof_parentid")
"""The ``tree`` bundle of :func:`jacobian` and :func:`add_user_wrenches`: ``mjModel`` arrays of those names (int64)."""


@njit(**JIT)
def jacobian(b, px, py, pz, cdof, subtree_com, tree, out, row):
    """Rows ``row..row+5`` of ``out`` (.., nv) := the Jacobian [linear velocity of point p; angular velocity]
    of body ``b`` (``mj_jac``), from ``cdof`` (motions about ``subtree_com`` of the root); ``tree``
    (:data:`JAC_TREE`): the model's kinematic tree."""
    body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid = tree
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


@njit(**JIT)
def add_user_wrenches(user_xfrc, xipos, cdof, subtree_com, tree, rows, out):
    """``out`` (nv,) += the generalized force of the user's wrenches ``user_xfrc`` (nbody, 6) [N, N m] at the
    bodies' COMs (``mj_applyFT``), through the scratch rows ``rows[:6]`` (.., nv)."""
    nv = out.shape[0]
    for b in range(1, user_xfrc.shape[0]):
        nonzero = False
        for c in range(6):
            if user_xfrc[b, c] != 0.0:
                nonzero = True
        if not nonzero:
            continue
        jacobian(b, xipos[b, 0], xipos[b, 1], xipos[b, 2], cdof, subtree_com, tree, rows, 0)
        for i in range(nv):
            s = 0.0
            for c in range(6):
                s += rows[c, i] * user_xfrc[b, c]
            out[i] += s


KEPT_GROUPS, KEPT_RANK = sc.S_KEPT_GROUPS, sc.S_KEPT_RANK
"""Entries of the evaluation's ``state`` (:data:`rft_mujoco.compiled.schema.STATE`) that the rest solve
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
    :func:`rft_mujoco.physics.rest.pivoted_factor`; a pivot not above ``tiny`` > 0 is ``sqrt(tiny)``). With
    ``tiny`` = 0 a pivot not above 0 stops the factor instead: returns False (True when factored)."""
    for c in range(k):
        t = g[c, c]
        for j in range(c):
            t -= g[c, j] * g[c, j]
        if t > tiny:
            d = np.sqrt(t)
        elif tiny > 0.0:
            d = np.sqrt(tiny)
        else:
            return False
        g[c, c] = d
        for r in range(c + 1, k):
            t = g[r, c]
            for j in range(c):
                t -= g[r, j] * g[c, j]
            g[r, c] = t / d
    return True


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


REST_GROUPS = ("free", "mob", "rft", "direction", "radius")
"""The ``groups`` bundle of :func:`rest_wrenches`: the touching groups' twists at the end of the step without
sand (>= G, 6) [m/s, rad/s], their mobility ``J M^-1 J^T`` (>= 6 G, >= 6 G), their RFT wrenches (>= G, 6)
[N, N m] about their reference points, the blended twists those were evaluated at (>= G, 6; only their
directions matter) and their radii (G,) [m]."""
REST_OUT = ("w", "rest")
"""The ``out`` bundle of :func:`rest_wrenches`: the groups' sand wrenches (>= G, 6) [N, N m], rest flags (G,) bool."""
REST_WORK = ("a", "v", "cap", "flow", "idx", "block", "rhs", "capacity", "v_w", "lin", "perm", "sol")
"""The ``work`` bundle of :func:`rest_wrenches`: ``a``/``block`` (6 G, 6 G) the scaled mobility and its rows at
rest, ``v``/``rhs``/``v_w``/``sol`` (6 G,) the scaled free twists, the solve's right-hand side, weights and
solution, ``cap`` (G, 6) the scaled RFT wrenches, ``flow`` (G,) bool, ``idx`` (6 G,) int, ``capacity`` (G,) [W],
and the buffers of :func:`min_norm_solve` (``lin``, ``perm``)."""
REST_KEPT = ("keep_rest", "state")
"""The ``kept`` bundle of :func:`rest_wrenches`: the resting groups of the kept factor (G,) bool and the
evaluation's ``state`` (:data:`rft_mujoco.compiled.schema.STATE`: ``KEPT_GROUPS``, ``KEPT_RANK``)."""


@njit(**JIT)
def blend(twist, free, radius, ng, out):
    """:func:`rft_mujoco.physics.rest.blend` of the ``ng`` groups' twists now and free (ng, 6: m/s, rad/s about
    their reference points) in their radii ``radius`` (m), into ``out`` (ng, 6)."""
    for r in range(ng):
        sl = sa = vl = va = 0.0
        for c in range(3):
            d0 = free[r, c] - twist[r, c]
            d1 = free[r, 3 + c] - twist[r, 3 + c]
            sl += d0 * d0
            sa += d1 * d1
            vl += twist[r, c] * twist[r, c]
            va += twist[r, 3 + c] * twist[r, 3 + c]
        s = math.sqrt(sl) + radius[r] * math.sqrt(sa)
        v = math.sqrt(vl) + radius[r] * math.sqrt(va)
        w = s * s / (v * v + s * s) if s > 0.0 else 0.0
        for c in range(6):
            out[r, c] = twist[r, c] + w * (free[r, c] - twist[r, c])


@njit(**JIT)
def rest_wrenches(groups, dt, ng, settings, out, work, kept, reuse):
    """:func:`rft_mujoco.physics.rest.rest_wrenches` for groups 0..ng-1 (``groups``: :data:`REST_GROUPS`) and
    the step ``dt`` [s]; the wrenches and rest flags go to ``out`` (:data:`REST_OUT`). ``settings`` (>= 4,):
    dependent_tol, weight_floor, capacity_tol, tiny (``hc.settings``). ``work`` (:data:`REST_WORK`): work
    buffers. The kept factor (``keep`` and ``reuse`` of the reference, ``kept``: :data:`REST_KEPT`): its
    resting groups in ``keep_rest``, its rank in ``state[KEPT_RANK]`` (-1: none), made only while
    ``state[KEPT_GROUPS] > 0`` (the caller keeps the mobility of this step); ``lin``, ``perm`` and ``v_w``
    hold it until the next factor, and with ``reuse`` ``a`` still holds the scaled mobility the factor was
    made from (the same ``mob``, radii and dt), so it is not rebuilt."""
    free, mob, rft, direction, radius = groups
    dependent_tol, weight_floor, capacity_tol, tiny = settings[0], settings[1], settings[2], settings[3]
    w, rest = out
    a, v, cap, flow, idx, block, rhs, capacity, v_w, lin, perm, sol = work
    keep_rest, state = kept
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
    _passive_scale(ng, radius, v, a, w)


@njit(**JIT)
def _passive_scale(ng, radius, v, a, w):
    """The passivity of the whole impulse (:func:`rft_mujoco.physics.rest.passive_scale`): ``w`` (>= ng, 6)
    scaled wrenches scaled down to a passive impulse against the scaled twists ``v`` and mobility ``a``, then
    back to [N, N m] (torques times the radii (ng,) [m])."""
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
