"""Compiled (numba) stabilized evaluation: the free motion, the body Jacobians and the impulse limiter of
``SandHandle._free_motion`` / ``SandHandle._limit`` in one call, for ``attach(stabilize=True)`` with the
numba backend.

The numpy path of :class:`rft_mujoco.coupling.SandHandle` stays the readable reference; this module
computes the same quantities without Python in the loop (tests/test_fastlimit.py compares them):

* :func:`body_jacobians` -- ``mj_jacBodyCom`` of several bodies from ``cdof`` and ``subtree_com`` (the
  same backward pass over each body's dof chain as MuJoCo's ``mj_jac``);
* :func:`stabilized` -- the free generalized force (``qfrc_passive - qfrc_bias + qfrc_actuator +
  qfrc_applied`` plus the user's ``xfrc_applied`` through the Jacobians), the free acceleration with the
  inverse mass matrix, the RFT octant wrenches with the predicted motion direction
  (:func:`rft_mujoco.fastkernel.wrenches`), and the impulse limiter with its extra rest columns, the same
  steps in the same order as ``SandHandle._limit``, solved by the same compiled projected Gauss-Seidel
  loops (:func:`rft_mujoco.kernel.limit_impulses`).

Warm start (``attach(warm_start=True)``; off by default). The limiter's QP is degenerate (many octant
wrenches, a generalized impulse of rank <= nv), and projected Gauss-Seidel converges slowly along its flat
directions: started from the published force every step, a standing quadruped takes the full
:data:`rft_mujoco.kernel.LIMITER_ITERATIONS` (100) sweeps in every solve. The optimum changes little from
one step to the next, so with the warm start :func:`stabilized` starts each solve from the factors of the
same (body, octant, round, column) at the end of the previous evaluation of the same MjData (the caller's
``warm`` buffer; a body that was not limited then starts from the published force, as in the reference)
and stops after :data:`rft_mujoco.kernel.LIMITER_WARM_ITERATIONS` (30) sweeps. Measured on the quadruped
settling on sand (tests/test_fastlimit.py checks the same on a small scene): the kinetic energy left
after the step exceeds that of a 3000-sweep solve by a median 5e-6 of the energy the sand removes,
against 6e-6 for 100 cold sweeps, at half the cost. The price is in the tail: over the 429 cases of
``python -m rft_mujoco stability`` no failure, but resting bodies kept up to 3.6e-5 m/s of jitter (5
cases above 1e-5 m/s; 7.7e-5 and 3, 2.8e-4 and 8 with earlier builds' round-off) where the cold solves
leave 1e-6,
which is why it is not the default. The coupling
clears the buffer whenever time does not run on by at most one step (a reset, ``mj_setState`` back in
time), so rollouts from a reset repeat bit for bit.

The inverse mass matrix is passed in dense (``mj_solveM`` of the identity, one MuJoCo call per evaluation);
everything else reads MjData's arrays. Working arrays are views into two buffers the caller allocates once
per (handle, MjData) (:func:`arena_sizes`); only the element pass's four small buffers and the solver's own
arrays are allocated per call.
"""

from __future__ import annotations

import math

import numpy as np

from . import kernel
from .fastkernel import GROUPS_PER_BODY, SCRATCH_ROWS, _JIT, finish, njit, wrenches

if kernel.GROUPS_PER_BODY != GROUPS_PER_BODY:  # pragma: no cover - a guard against editing one of them
    raise ImportError("kernel.GROUPS_PER_BODY and fastkernel.GROUPS_PER_BODY differ")

try:
    _FACTOR, _PGS = kernel._compiled()
except ImportError:  # pragma: no cover - numba missing: the coupling uses numpy and never calls this module
    _FACTOR = _PGS = None

BAD_ACCELERATION = -2
"""Status of :func:`stabilized` when the free acceleration is not finite (NaN/inf in the inputs)."""


def solver_settings() -> np.ndarray:
    """(8,) solver settings for :func:`stabilized`, read now from :mod:`rft_mujoco.kernel` and passed at run
    time (numba would freeze module globals into its on-disk cache): [LIMITER_ITERATIONS, LIMITER_TOL,
    LIMITER_ENERGY_TOL, FACTOR_TOL (unused: the factor is exact), REST_COLUMNS, REST_SPEED,
    LIMITER_WARM_ITERATIONS, LIMITER_WARM_ENERGY_TOL]."""
    return np.array([kernel.LIMITER_ITERATIONS, kernel.LIMITER_TOL, kernel.LIMITER_ENERGY_TOL,
                     kernel.FACTOR_TOL, kernel.REST_COLUMNS, kernel.REST_SPEED, kernel.LIMITER_WARM_ITERATIONS,
                     kernel.LIMITER_WARM_ENERGY_TOL])


# --- Jacobians ---------------------------------------------------------------------------------------------
@njit(**_JIT)
def body_jacobians(bids, n, xipos, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid,
                   dof_parentid, jac):
    """``mj_jacBodyCom`` of bodies ``bids[:n]`` into ``jac[:n]`` (n, 6, nv): rows 0-2 the linear velocity
    of the body's COM (``xipos``) per unit qvel, rows 3-5 the angular velocity (world frame)."""
    for i in range(n):
        b = bids[i]
        jac[i] = 0.0
        rt = body_rootid[b]
        ox = xipos[b, 0] - subtree_com[rt, 0]
        oy = xipos[b, 1] - subtree_com[rt, 1]
        oz = xipos[b, 2] - subtree_com[rt, 2]
        body = b
        while body > 0 and body_dofnum[body] == 0:          # welded to its parent: the parent's dofs
            body = body_parentid[body]
        if body == 0:
            continue
        j = body_dofadr[body] + body_dofnum[body] - 1
        while j >= 0:
            a0, a1, a2 = cdof[j, 0], cdof[j, 1], cdof[j, 2]
            jac[i, 0, j] = cdof[j, 3] + (a1 * oz - a2 * oy)
            jac[i, 1, j] = cdof[j, 4] + (a2 * ox - a0 * oz)
            jac[i, 2, j] = cdof[j, 5] + (a0 * oy - a1 * ox)
            jac[i, 3, j] = a0
            jac[i, 4, j] = a1
            jac[i, 5, j] = a2
            j = dof_parentid[j]


# --- the limiter -----------------------------------------------------------------------------------------
@njit(**_JIT)
def _solve(A, c, group, lam, free, ensure_passive, settings, warm):
    """:func:`rft_mujoco.kernel.limit_impulses` on ``lam`` (the start, updated in place), with the
    objective already factored: ``0.5 l.G.l + h.l = 0.5 |A l + c|^2 - 0.5 |c|^2``. A ``warm`` start gets
    at most LIMITER_WARM_ITERATIONS sweeps and stops at LIMITER_WARM_ENERGY_TOL, a cold one at
    LIMITER_ITERATIONS and LIMITER_ENERGY_TOL."""
    m = lam.shape[0]
    n_groups = 0
    for a in range(m):
        n_groups = max(n_groups, group[a] + 1)
    _PGS(A, c, group, free, lam, n_groups, int(settings[6] if warm else settings[0]), settings[1],
         settings[7] if warm else settings[2])
    if ensure_passive:
        quad, lin = _quadratic(A, c, lam)
        if 0.5 * quad + lin > 0.0:
            f = min(1.0, max(0.0, -lin / quad)) if quad > 0.0 else 0.0
            for a in range(m):
                lam[a] *= f


@njit(**_JIT)
def _quadratic(A, c, lam):
    """(``l.G.l``, ``h.l``) of the limiter's objective ``0.5 l.G.l + h.l`` (J) in factored form."""
    quad = 0.0
    lin = 0.0
    for d in range(A.shape[0]):
        y = 0.0
        for a in range(A.shape[1]):
            y += A[d, a] * lam[a]
        quad += y * y
        lin += c[d] * y
    return quad, lin


@njit(**_JIT)
def _energy(A, c, lam):
    """The limiter's objective ``0.5 l.G.l + h.l`` (J)."""
    quad, lin = _quadratic(A, c, lam)
    return 0.5 * quad + lin


@njit(**_JIT)
def _speed(jac, j, qv, radius, twist):
    """``|v_com| + radius |omega|`` of body row j for generalized velocity ``qv`` (nv,); the body's twist
    ``J_j qv`` is left in ``twist`` (6,)."""
    nv = qv.shape[0]
    for r in range(6):
        s = 0.0
        for d in range(nv):
            s += jac[j, r, d] * qv[d]
        twist[r] = s
    return math.sqrt(twist[0] * twist[0] + twist[1] * twist[1] + twist[2] * twist[2]) + radius * math.sqrt(
        twist[3] * twist[3] + twist[4] * twist[4] + twist[5] * twist[5])


@njit(**_JIT)
def _columns(q, minv, chol, dt, first, m, mq, at):
    """For the new columns a = first..m-1 of the generalized forces ``q`` (rows): ``mq[a] = q[a] M^-1``
    and ``at[a] = dt q[a] C`` with ``M^-1 = C C^T`` (C lower-triangular). ``A = at[:m].T`` (nv, m) is then the
    limiter's factor: ``A^T A = dt^2 Q M^-1 Q^T = G`` exactly (no m x m matrix is formed; the kernel's
    pivoted factorization of G is not needed). Plain loops, not BLAS: at these sizes (m <= 8 B R, nv of a
    robot) a BLAS call costs more than its arithmetic (~270 ns for 8 x 14 x 14 measured)."""
    nv = minv.shape[0]
    for a in range(first, m):
        for e in range(nv):
            mq[a, e] = 0.0
            at[a, e] = 0.0
        for d in range(nv):
            x = q[a, d]
            for e in range(nv):
                mq[a, e] += x * minv[d, e]
            for e in range(d + 1):
                at[a, e] += x * chol[d, e]
        for e in range(nv):
            at[a, e] *= dt


@njit(**_JIT)
def _cholesky(M, C):
    """Lower-triangular C (nv, nv), filled and returned, with ``C C^T = M`` for the symmetric positive
    (semi-)definite ``M`` (nv, nv); pivots below 1e-14 of the largest diagonal entry are clamped to it, so
    that a numerically singular ``M^-1`` (extreme mass ratios) still gives a usable factor instead of an
    exception."""
    n = M.shape[0]
    C[:] = 0.0
    top = 0.0
    for i in range(n):
        top = max(top, M[i, i])
    floor = 1e-14 * top if top > 0.0 else 1e-300
    for j in range(n):
        s = M[j, j]
        for q in range(j):
            s -= C[j, q] * C[j, q]
        d = math.sqrt(s if s > floor else floor)
        C[j, j] = d
        for i in range(j + 1, n):
            v = 0.5 * (M[i, j] + M[j, i])
            for q in range(j):
                v -= C[i, q] * C[j, q]
            C[i, j] = v / d
    return C


@njit(**_JIT)
def _forward(chol, x, out):
    """``out = C^-1 x`` for lower-triangular C (forward substitution); returns ``out``."""
    n = x.shape[0]
    for i in range(n):
        s = x[i]
        for j in range(i):
            s -= chol[i, j] * out[j]
        out[i] = s / chol[i, i]
    return out


@njit(**_JIT)
def _add_column(jac, j, w, q, a):
    """Column a: the generalized force q[a] = J_j^T w of wrench w (6,) on body row j."""
    for d in range(q.shape[1]):
        s = 0.0
        for r in range(6):
            s += jac[j, r, d] * w[r]
        q[a, d] = s


@njit(**_JIT)
def _append_columns(src, k, jac, rd, group, rnd, wrench, q, m):
    """Append the non-zero octant wrenches ``src[:k]`` (k, 8, 6) as columns m, m+1, ... of round ``rd``
    (their group, round, wrench and generalized force); returns the new column count."""
    ng = GROUPS_PER_BODY
    for j in range(k):
        for o in range(ng):
            nz = False
            for c in range(6):
                if src[j, o, c] != 0.0:
                    nz = True
            if nz:
                group[m] = j * ng + o
                rnd[m] = rd
                for c in range(6):
                    wrench[m, c] = src[j, o, c]
                _add_column(jac, j, wrench[m], q, m)
                m += 1
    return m


@njit(**_JIT)
def _warm_starts(lam, free, group, rnd, touch, warm, warm_rounds, rd, m):
    """Start the free factors of bodies that went through round ``rd`` last time from their values at the
    end of that round then (rescaled per octant group to a sum <= 1, as the columns may differ). Returns
    whether any start was taken from the previous evaluation."""
    ng = GROUPS_PER_BODY
    used = False
    for a in range(m):
        b = touch[group[a] // ng]
        if free[a] and warm_rounds[b] > rd:
            lam[a] = warm[b, group[a] % ng, rd, rnd[a]]
            used = True
    if not used:
        return False
    n_groups = 0
    for a in range(m):
        n_groups = max(n_groups, group[a] + 1)
    total = np.zeros(n_groups)
    for a in range(m):
        total[group[a]] += lam[a]
    for a in range(m):
        if free[a] and total[group[a]] > 1.0:
            lam[a] /= total[group[a]]
    return True


def limit_arena(n_bodies: int, nv: int, rest_columns: int) -> tuple[int, int]:
    """Lengths (float64, int64) of the buffers :func:`limit` carves from its ``arena`` / ``iarena`` for up
    to ``n_bodies`` touching bodies, ``nv`` dofs and ``rest_columns`` motion directions per octant."""
    cap = n_bodies * GROUPS_PER_BODY * rest_columns
    return cap * (7 + 3 * nv) + nv * nv + 3 * nv + 6, 3 * cap + 3 * n_bodies


def arena_sizes(n_bodies: int, nv: int, rest_columns: int) -> tuple[int, int]:
    """Lengths (float64, int64) of the preallocated ``arena`` / ``iarena`` buffers of :func:`stabilized`
    (its own: accelerations 6 B, predicted velocity nv, free-motion scratch 7 nv; body ids B and one
    scratch id; then :func:`limit_arena`'s), allocated once per (handle, MjData)."""
    f, i = limit_arena(n_bodies, nv, rest_columns)
    return f + 6 * n_bodies + 8 * nv, i + n_bodies + 1


@njit(**_JIT)
def limit(jac, groups, touch, k, qvel_pred, minv, dt, radius, warm, warm_rounds, warm_start, settings,
          packed_centroids, packed_normals, packed_areas, cluster_start, cluster_octant, cluster_center,
          cluster_radius, body_clusters, body_pos, body_mat, body_com, g_hat, max_height, kind, tp, heights,
          xi_n, coef, mu_surf, no_tension, no_forward, no_power, tol, scratch, col_v, col_w, col_groups,
          col_count, col_max_depth, arena, iarena, out):
    """``SandHandle._limit`` compiled: stabilized wrenches ``out[:k]`` (k, 6) from the octant wrenches
    ``groups[:k]`` (k, 8, 6) of the touching bodies (handle indices ``touch[:k]``; ``jac`` (k, 6, nv) their
    Jacobians, ``radius`` (B,) their bounding radii by handle index).

    ``warm`` (B, 8, R, R) and ``warm_rounds`` (B,) hold the previous evaluation's factors per (body,
    octant, round, column) and how many rounds each body went through (0: not limited); both are updated.
    The remaining arguments are those of :func:`rft_mujoco.fastkernel.wrenches` for the rest columns (the
    RFT octant wrenches of body twists ``col_v``/``col_w`` into ``col_groups``). ``arena`` (float64) and
    ``iarena`` (int64) are preallocated buffers at least as long as :func:`limit_arena` says; nothing else
    is allocated here but the warm start's group sums and the solver's own small arrays. Returns the number
    of solves.
    """
    ng = GROUPS_PER_BODY
    nv = minv.shape[0]
    # never more rounds than the buffers were sized for (warm and the arenas are sized together from the
    # same settings; this keeps a later edit of the settings from writing past them)
    rest_columns = min(int(settings[4]), warm.shape[2])
    rest_speed = settings[5]
    cap = k * ng * rest_columns
    # the buffers, carved from the arenas in the order limit_arena counts them
    wrench = arena[0:cap * 6].reshape((cap, 6))
    o = cap * 6
    q = arena[o:o + cap * nv].reshape((cap, nv))
    o += cap * nv
    mq = arena[o:o + cap * nv].reshape((cap, nv))
    o += cap * nv
    at = arena[o:o + cap * nv].reshape((cap, nv))      # A = at[:m].T (nv, m), F-ordered: columns contiguous
    o += cap * nv
    chol = arena[o:o + nv * nv].reshape((nv, nv))
    o += nv * nv
    cvec = arena[o:o + nv]
    tot = arena[o + nv:o + 2 * nv]
    qv = arena[o + 2 * nv:o + 3 * nv]
    twist = arena[o + 3 * nv:o + 3 * nv + 6]
    lam = arena[o + 3 * nv + 6:o + 3 * nv + 6 + cap]
    group = iarena[0:cap]
    rnd = iarena[cap:2 * cap]                           # the round that added each column
    rounds = iarena[2 * cap:2 * cap + k]
    free = iarena[2 * cap + k:3 * cap + k].view(np.bool_)[:cap]
    low = iarena[3 * cap + k:3 * cap + 2 * k].view(np.bool_)[:k]
    refine = iarena[3 * cap + 2 * k:3 * cap + 3 * k].view(np.bool_)[:k]
    rnd[:] = 0
    m = _append_columns(groups, k, jac, 0, group, rnd, wrench, q, 0)
    _cholesky(minv, chol)
    _columns(q, minv, chol, dt, 0, m, mq, at)
    _forward(chol, qvel_pred, cvec)
    A = at[:m].T
    # Low-speed regime per body: predicted speed below the speed change of the full impulse of all columns.
    tot[:] = 0.0
    for a in range(m):
        for d in range(nv):
            tot[d] += dt * mq[a, d]
    for j in range(k):
        rad = radius[touch[j]]
        low[j] = _speed(jac, j, qvel_pred, rad, twist) < _speed(jac, j, tot, rad, twist)
    free[:] = False
    lam[:] = 1.0
    any_free = False
    for a in range(m):
        free[a] = low[group[a] // ng]
        any_free = any_free or free[a]
    solves = 0
    if any_free:
        warmed = warm_start and _warm_starts(lam, free, group, rnd, touch, warm, warm_rounds, 0, m)
        _solve(A, cvec, group[:m], lam[:m], free[:m], False, settings, warmed)
        solves += 1
    if _energy(A, cvec, lam[:m]) > 0.0:                      # the published force of bodies in flow adds energy
        for a in range(m):
            free[a] = True
            lam[a] = 1.0
        warmed = warm_start and _warm_starts(lam, free, group, rnd, touch, warm, warm_rounds, 0, m)
        _solve(A, cvec, group[:m], lam[:m], free[:m], True, settings, warmed)
        solves += 1
    rounds[:] = 0
    for a in range(m):
        j = group[a] // ng
        if free[a]:
            rounds[j] = 1
        warm[touch[j], group[a] % ng, 0, 0] = lam[a]
    # Rest columns: the RFT resistance to the motion left after the step, for limited low-speed bodies.
    for rd in range(1, rest_columns):
        refine[:] = False
        for a in range(m):
            if lam[a] < 1.0 - 1e-12:
                refine[group[a] // ng] = True
        for d in range(nv):
            s = 0.0
            for a in range(m):
                s += mq[a, d] * lam[a]
            qv[d] = qvel_pred[d] + dt * s
        n_refine = 0
        for j in range(k):
            sp = _speed(jac, j, qv, radius[touch[j]], twist)
            refine[j] = refine[j] and low[j] and sp > rest_speed
            for r in range(3):
                col_v[j, r] = twist[r] if refine[j] else 0.0
                col_w[j, r] = twist[3 + r] if refine[j] else 0.0
            if refine[j]:
                n_refine += 1
        if n_refine == 0:
            break
        # dt = 0: the elements move along the twists, no predicted direction (``wrench`` only fills the
        # typed accelerations argument; it is not read)
        wrenches(touch, k, packed_centroids, packed_normals, packed_areas, cluster_start, cluster_octant,
                 cluster_center, cluster_radius, body_clusters, body_pos, body_mat, body_com, col_v, col_w,
                 wrench, 0.0, g_hat, max_height, kind, tp, heights, xi_n, coef, mu_surf, no_tension,
                 no_forward, no_power, tol, scratch, col_groups, col_count, col_max_depth)
        first_new = m
        m = _append_columns(col_groups, k, jac, rd, group, rnd, wrench, q, m)
        for a in range(first_new, m):
            free[a] = True
            lam[a] = 0.0
        if m == first_new:
            break
        _columns(q, minv, chol, dt, first_new, m, mq, at)
        A = at[:m].T
        warmed = warm_start and _warm_starts(lam, free, group, rnd, touch, warm, warm_rounds, rd, m)
        _solve(A, cvec, group[:m], lam[:m], free[:m], True, settings, warmed)
        solves += 1
        for a in range(m):
            j = group[a] // ng
            warm[touch[j], group[a] % ng, rd, rnd[a]] = lam[a]
        for j in range(k):
            if refine[j]:
                rounds[j] = rd + 1
    for j in range(k):
        warm_rounds[touch[j]] = rounds[j]
        for c in range(6):
            out[j, c] = 0.0
    for a in range(m):
        j = group[a] // ng
        for c in range(6):
            out[j, c] += wrench[a, c] * lam[a]
    return solves


@njit(**_JIT)
def free_acceleration(user_xfrc, xipos, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
                      body_parentid, dof_parentid, qfrc_passive, qfrc_bias, qfrc_actuator, qfrc_applied, minv,
                      qacc, work, iwork):
    """``SandHandle._free_motion``'s free acceleration into ``qacc`` (nv,): ``M^-1`` (``minv`` (nv, nv))
    times the smooth generalized force and the user's ``xfrc_applied`` (nbody, 6) rows (at each body's
    COM, as MuJoCo applies them). ``work`` (>= 7 nv float) and ``iwork`` (>= 1 int) are scratch. Returns
    False when it is not finite."""
    nv = qacc.shape[0]
    qfrc = work[0:nv]
    jb = work[nv:7 * nv].reshape((1, 6, nv))
    one = iwork[0:1]
    for d in range(nv):
        qfrc[d] = qfrc_passive[d] - qfrc_bias[d] + qfrc_actuator[d] + qfrc_applied[d]
    for b in range(1, user_xfrc.shape[0]):
        nz = False
        for c in range(6):
            if user_xfrc[b, c] != 0.0:
                nz = True
        if not nz:
            continue
        one[0] = b
        body_jacobians(one, 1, xipos, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid,
                       dof_parentid, jb)
        for d in range(nv):
            s = 0.0
            for c in range(6):
                s += jb[0, c, d] * user_xfrc[b, c]
            qfrc[d] += s
    ok = True
    for d in range(nv):
        s = 0.0
        for e in range(nv):
            s += minv[d, e] * qfrc[e]
        qacc[d] = s
        ok = ok and math.isfinite(s)
    return ok


@njit(**_JIT)
def stabilized(touch, k, ids, user_xfrc, xipos, cdof, subtree_com, qvel, qfrc_passive, qfrc_bias, qfrc_actuator,
               qfrc_applied, minv, body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid, dt, radius,
               warm, warm_rounds, warm_start, settings, packed_centroids, packed_normals, packed_areas,
               cluster_start, cluster_octant, cluster_center, cluster_radius, body_clusters, body_pos, body_mat,
               body_com, v_com, omega, g_hat, max_height, kind, tp, heights, xi_n, coef, mu_surf, no_tension,
               no_forward, no_power, tol, scratch, groups, count, max_depth, col_v, col_w, col_groups, col_count,
               col_max_depth, jac, qacc, limited, force, torque, submerged, depth_max, scale, rft_force,
               arena, iarena, sand_out):
    """The stabilized evaluation of the touching bodies ``touch[:k]`` (handle indices; MuJoCo ids
    ``ids[touch]``): their Jacobians (``jac``), the free acceleration (``qacc``), the RFT octant wrenches
    with the predicted direction (``groups``, ``count``, ``max_depth``, as :func:`fastkernel.wrenches`),
    when any is loaded the limited wrenches (``limited[:k]``, see :func:`limit`), and then
    :func:`fastkernel.finish`: the diagnostics (``force`` ... ``rft_force``, all B rows) and the applied
    wrenches added into ``sand_out`` (nbody, 6).

    Returns :data:`BAD_ACCELERATION` when the free acceleration is not finite (nothing else computed),
    else the status of :func:`fastkernel.finish` (1: a wrench is non-zero, 0: none, -1: one is not finite,
    nothing added). ``arena`` / ``iarena``: preallocated float64 / int64 buffers of the lengths
    :func:`arena_sizes` gives for B bodies: every working array of this call and of :func:`limit` is a
    view into them (numba allocated 30-69 small arrays per SandAnt-v0 evaluation before, 16-70 ns each).
    """
    nv = qacc.shape[0]
    acc = arena[0:6 * k].reshape((k, 6))
    qvel_pred = arena[6 * k:6 * k + nv]
    fa_work = arena[6 * k + nv:6 * k + 8 * nv]
    bids = iarena[0:k]
    for j in range(k):
        bids[j] = ids[touch[j]]
    body_jacobians(bids, k, xipos, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid,
                   dof_parentid, jac)
    if not free_acceleration(user_xfrc, xipos, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
                             body_parentid, dof_parentid, qfrc_passive, qfrc_bias, qfrc_actuator, qfrc_applied,
                             minv, qacc, fa_work, iarena[k:k + 1]):
        return BAD_ACCELERATION
    for d in range(nv):
        qvel_pred[d] = qvel[d] + dt * qacc[d]
    for j in range(k):
        for r in range(6):
            s = 0.0
            for d in range(nv):
                s += jac[j, r, d] * qacc[d]
            acc[j, r] = s
    n = wrenches(touch, k, packed_centroids, packed_normals, packed_areas, cluster_start, cluster_octant,
                 cluster_center, cluster_radius, body_clusters, body_pos, body_mat, body_com, v_com, omega, acc,
                 dt, g_hat, max_height, kind, tp, heights, xi_n, coef, mu_surf, no_tension, no_forward, no_power,
                 tol, scratch, groups, count, max_depth)
    if n == 0:
        for j in range(k):
            warm_rounds[touch[j]] = 0
    for b in range(warm_rounds.shape[0]):                # bodies out of the sand: no warm start later
        inside = False
        for j in range(k):
            inside = inside or touch[j] == b
        if not inside:
            warm_rounds[b] = 0
    if n > 0:
        limit(jac, groups, touch, k, qvel_pred, minv, dt, radius, warm, warm_rounds, warm_start, settings,
              packed_centroids, packed_normals, packed_areas, cluster_start, cluster_octant, cluster_center,
              cluster_radius, body_clusters, body_pos, body_mat, body_com, g_hat, max_height, kind, tp,
              heights, xi_n, coef, mu_surf, no_tension, no_forward, no_power, tol, scratch, col_v, col_w,
              col_groups, col_count, col_max_depth, arena[6 * k + 8 * nv:], iarena[k + 1:], limited)
    return finish(groups, count, max_depth, v_com, omega, limited[:k] if n > 0 else limited[:0], False, touch,
                  k, ids, force, torque, submerged, depth_max, scale, rft_force, sand_out)


def _warm_up(packed, kind, tp, heights, coef, tol) -> None:
    """Compile :func:`stabilized` for the argument types the coupling passes (called by
    :func:`rft_mujoco.fastkernel.ensure_compiled` with its tiny packed body)."""
    i8 = np.int64
    nv, nbody, B = 6, 2, 1
    z3, z6 = np.zeros((nbody, 3)), np.zeros((nbody, 6))
    tree = (np.zeros(nbody, i8), np.array([0, 6], i8), np.array([-1, 0], i8), np.zeros(nbody, i8),
            np.array([-1, 0, 1, 2, 3, 4], i8))
    work = [np.zeros((B, 3)), np.zeros((B, 9)), np.zeros((B, 3)), np.zeros((B, 3)), np.zeros((B, 3))]
    stabilized(np.zeros(B, i8), 0, np.ones(B, i8), z6, z3, np.zeros((nv, 6)), z3, np.zeros(nv), np.zeros(nv),
               np.zeros(nv), np.zeros(nv), np.zeros(nv), np.eye(nv), *tree, 0.001, np.ones(B),
               np.zeros((B, GROUPS_PER_BODY, 3, 3)), np.zeros(B, i8), True, solver_settings(), *packed.arrays(),
               *work, np.array([0.0, 0.0, -1.0]), 0.0, kind, tp, heights, 1.0, coef, 0.4, False, False, False, tol,
               np.zeros((SCRATCH_ROWS, packed.cluster_start[-1] + 128)), np.zeros((B, GROUPS_PER_BODY, 6)),
               np.zeros(B, i8),
               np.zeros(B), np.zeros((B, 3)), np.zeros((B, 3)), np.zeros((B, GROUPS_PER_BODY, 6)), np.zeros(B, i8),
               np.zeros(B), np.zeros((B, 6, nv)), np.zeros(nv), np.zeros((B, 6)), np.zeros((B, 3)),
               np.zeros((B, 3)), np.zeros(B, i8), np.zeros(B), np.ones(B), np.zeros((B, 3)),
               *(np.zeros(n, dtype) for n, dtype in zip(arena_sizes(B, nv, 3), (np.float64, i8))), z6.copy())
