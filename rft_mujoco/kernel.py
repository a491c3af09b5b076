"""Per-evaluation element kernel: body poses and velocities -> per-body sand wrenches (pure numpy).

This is the readable reference of the coupling's hot path; a compiled version must agree with it.
The impulse limiter's small QP (:func:`limit_impulses`) is written as plain loops and compiled with numba.
"""

from __future__ import annotations

import numpy as np

from . import law
from .law import Guards
from .media import Media

GROUPS_PER_BODY = 8
"""Each body's elements are split into the 8 octants of its body frame (about its bounding-box centre).
The impulse limiter scales each octant's wrench separately, so the sand can supply any wrench inside the
cone of its octant wrenches (up to their RFT values) and can stop translation and rotation together; near
rest it also mixes each octant's wrenches for several motion directions (:data:`REST_COLUMNS`)."""


def octants(local_centroids: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Octant index 0..7 of each (E, 3) body-frame centroid relative to ``center`` (3,)."""
    rel = local_centroids - center
    return ((rel[:, 0] > 0).astype(np.int64) + 2 * (rel[:, 1] > 0) + 4 * (rel[:, 2] > 0))


def element_states(local_centroids, local_normals, elem_body, body_pos, body_mat, body_com, v_com, omega):
    """World positions, unit normals and velocities of elements attached to rigid bodies.

    Args:
        local_centroids: (E, 3) float, m, body frame.
        local_normals: (E, 3) float, unit, body frame.
        elem_body: (E,) int, row of each element in the body arrays below.
        body_pos: (B, 3) float, body frame origins in world (MuJoCo ``xpos``), m.
        body_mat: (B, 3, 3) float, body orientations (``xmat``).
        body_com: (B, 3) float, body centres of mass in world (``xipos``), m.
        v_com: (B, 3) float, linear velocity of each centre of mass, m/s, world frame.
        omega: (B, 3) float, angular velocity, rad/s, world frame.
    Returns:
        positions (E, 3) m, normals (E, 3), lever arms from the COM (E, 3) m, velocities (E, 3) m/s.
    """
    rot = body_mat[elem_body]
    pos = body_pos[elem_body] + np.einsum("eij,ej->ei", rot, local_centroids)
    nrm = np.einsum("eij,ej->ei", rot, local_normals)
    arm = pos - body_com[elem_body]
    vel = v_com[elem_body] + np.cross(omega[elem_body], arm)
    return pos, nrm, arm, vel


def body_wrenches(local_centroids, local_normals, areas, elem_body, n_bodies, body_pos, body_mat, body_com,
                  v_com, omega, terrain, g_hat, gravity, media: Media, guards: Guards,
                  a_com=None, alpha=None, dt=0.0, elem_octant=None):
    """3D-RFT wrench about each body's centre of mass, split by body-frame octant.

    The motion direction of each element is its velocity ``v``; when ``dt > 0`` and free accelerations
    are given, the direction is ``v + w a dt`` with ``w = (|a| dt)^2 / (|v|^2 + (|a| dt)^2)``: at
    speeds well above ``|a| dt`` this is ``v`` (published direction, relative change ~ (|a| dt / |v|)^3),
    and at rest it is the direction the element would move in this step without sand.

    Args:
        (element and body arrays as in :func:`element_states`), areas (E,) m^2, n_bodies B.
        terrain: object with ``depth(points (n, 3), g_hat) -> (n,)`` in m.
        g_hat: (3,) unit gravity direction; gravity: (3,) m/s^2.
        a_com, alpha: (B, 3) free linear (m/s^2) and angular (rad/s^2) accelerations, or None.
        dt: the step in s used for the predicted direction (0 disables it).
        elem_octant: (E,) int in 0..7 (see :func:`octants`), or None (all in octant 0).
    Returns:
        wrench (B, 8, 6) [force N, torque N m about the body's COM] per octant (sum over axis 1 for the
        body), submerged leading element count (B,) int, maximum depth (B,) m (0 if none submerged).
    """
    pos, nrm, arm, vel = element_states(local_centroids, local_normals, elem_body, body_pos, body_mat,
                                        body_com, v_com, omega)
    depth = terrain.depth(pos, g_hat)
    wrench = np.zeros((n_bodies * GROUPS_PER_BODY, 6))
    count = np.zeros(n_bodies, dtype=np.int64)
    max_depth = np.zeros(n_bodies)
    sub = np.flatnonzero(depth > 0.0)
    if sub.size == 0:
        return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth
    v = vel[sub]
    if dt > 0.0 and a_com is not None:
        b = elem_body[sub]
        acc = a_com[b] + np.cross(alpha[b], arm[sub])
        step = acc * dt
        s2 = np.einsum("ij,ij->i", step, step)
        v2 = np.einsum("ij,ij->i", v, v)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(s2 > 0.0, s2 / (v2 + s2), 0.0)
        v = v + w[:, None] * step
    speed = np.linalg.norm(v, axis=1)
    moving = speed > law.ZERO_SPEED
    sub, v, speed = sub[moving], v[moving], speed[moving]
    v_hat = v / speed[:, None]
    n_hat = nrm[sub]
    leading = np.einsum("ij,ij->i", n_hat, v_hat) >= -law.LEADING_TOL
    sub, v_hat, n_hat = sub[leading], v_hat[leading], n_hat[leading]
    if sub.size == 0:
        return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth
    alpha_s = law.stress_per_depth(n_hat, v_hat, media, gravity, guards)
    f = alpha_s * (depth[sub] * areas[sub])[:, None]
    b = elem_body[sub]
    grp = b * GROUPS_PER_BODY + (0 if elem_octant is None else elem_octant[sub])
    n_groups = n_bodies * GROUPS_PER_BODY
    for k in range(3):
        wrench[:, k] = np.bincount(grp, weights=f[:, k], minlength=n_groups)
    tau = np.cross(arm[sub], f)
    for k in range(3):
        wrench[:, 3 + k] = np.bincount(grp, weights=tau[:, k], minlength=n_groups)
    count[:] = np.bincount(b, minlength=n_bodies)
    np.maximum.at(max_depth, b, depth[sub])
    return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth


REST_COLUMNS = 3
"""Most motion directions the impulse limiter combines per octant group in one evaluation (see
:func:`limit_impulses` and ``SandHandle._limit``): the predicted direction, then up to
``REST_COLUMNS - 1`` more, each the RFT resistance to the motion the body would still have after the step.
Only bodies in the low-speed regime whose limiter binds (the sand can stop them within the step) get the
extra columns."""

REST_SPEED = 1e-9
"""m/s: a body whose speed after the step (``|v_com| + radius |omega|``) is below this is at rest; the limiter
adds no column for it."""

LIMITER_ITERATIONS = 100
"""Most sweeps of the projected Gauss-Seidel solver in :func:`limit_impulses`."""
LIMITER_WARM_ITERATIONS = 30
"""Most sweeps of a solve the compiled coupling starts from the previous evaluation's factors
(:mod:`rft_mujoco.fastlimit`) ..."""
LIMITER_WARM_ENERGY_TOL = 1e-12
"""... and its energy tolerance (see LIMITER_ENERGY_TOL). Measured on the quadruped settling on sand
(1 s, every step against a 3000-sweep solve): 30 warm sweeps leave a median 5e-6 (90th percentile 2e-5)
of the kinetic energy the sand removes unremoved, the 100 cold sweeps of the reference 6e-6 (3e-5), at
half the cost. A looser 1e-8 here cut the cost by another third at the same median, but three of the 429
cases of ``python -m rft_mujoco stability`` then missed rest (light bodies at 5-10 ms steps)."""
LIMITER_TOL = 1e-10
"""The solver stops when no scale factor changed by more than this in a sweep ..."""
LIMITER_ENERGY_TOL = 1e-12
"""... or when a sweep lowered the objective (an energy, J) by less than this fraction of its scale."""
FACTOR_TOL = 1e-13
"""Pivoted Cholesky of the solver stops at diagonal remainders below this fraction of the largest."""
SUBSPACE_EVERY = 10
"""Sweeps between two subspace-minimization steps of the solver ...
(SUBSPACE_* are read when numba compiles the solver: change them before the first use.)"""
SUBSPACE_MAX = 24
"""... which it takes only while at most this many factors are positive (its cost grows as their cube):
single bodies get exact solutions; large multi-body problems rely on the sweeps alone."""


def _factor_loops(G, h, rel_tol):
    """Pivoted Cholesky ``G ~ A^T A`` (A (r, k), r the numerical rank) and ``c`` (r,) with ``A^T c ~ h``,
    so that ``0.5 l.G.l + h.l = 0.5 |A l + c|^2 - 0.5 |c|^2``: the solver then works with the (r,) vector
    ``y = A l + c`` (r <= nv, usually much smaller than k)."""
    k = G.shape[0]
    diag = np.empty(k)
    for a in range(k):
        diag[a] = G[a, a]
    top = 0.0
    for a in range(k):
        top = max(top, diag[a])
    L = np.zeros((k, k))
    used = np.zeros(k, dtype=np.bool_)
    r = 0
    while r < k:
        p = -1
        best = rel_tol * top
        for a in range(k):
            if not used[a] and diag[a] > best:
                best = diag[a]
                p = a
        if p < 0:
            break
        used[p] = True
        s = np.sqrt(diag[p])
        for a in range(k):
            v = G[a, p]
            for j in range(r):
                v -= L[j, a] * L[j, p]
            L[r, a] = v / s
        for a in range(k):
            diag[a] -= L[r, a] * L[r, a]
        r += 1
    A = L[:r].copy()
    c = np.zeros(r)
    if r:
        c = np.linalg.solve(A @ A.T, A @ h)
    return A, c


def _subspace_step_loops(A, group, free, lam, gsum, y, n_groups):
    """One subspace-minimization step of :func:`_pgs`: minimize exactly over the variables that are
    strictly positive (with the sum of each saturated group held at 1), then take the better of that step
    cut at the first constraint and that step projected onto the constraints, if it lowers the objective.
    The objective's Hessian is ``G = A^T A``; only its (n, n) block over those variables is formed.
    Updates ``lam``, ``gsum``, ``y``; returns the objective change (<= 0)."""
    k = lam.shape[0]
    r = y.shape[0]
    idx = np.zeros(k, dtype=np.int64)
    n = 0
    for a in range(k):
        norm = 0.0
        for j in range(r):
            norm += A[j, a] * A[j, a]
        if free[a] and lam[a] > 0.0 and norm > 1e-300:
            idx[n] = a
            n += 1
    if n == 0 or n > SUBSPACE_MAX:
        return 0.0
    grad = np.zeros(n)
    for i in range(n):
        for j in range(r):
            grad[i] += A[j, idx[i]] * y[j]
    G = np.zeros((n, n))                                # G[i, j] = A[:, idx[i]] . A[:, idx[j]]
    for i in range(n):
        for j in range(i + 1):
            v = 0.0
            for q in range(r):
                v += A[q, idx[i]] * A[q, idx[j]]
            G[i, j] = v
            G[j, i] = v
    row = np.full(n_groups, -1, dtype=np.int64)      # equality row of each saturated group
    m = 0
    for i in range(n):
        g = group[idx[i]]
        if row[g] < 0 and gsum[g] >= 1.0 - 1e-12:
            row[g] = m
            m += 1
    K = np.zeros((n + m, n + m))
    rhs = np.zeros(n + m)
    for i in range(n):
        a = idx[i]
        for j in range(n):
            K[i, j] = G[i, j]
        rhs[i] = -grad[i]                               # the step d: G_FF d + E^T mu = -grad_F, E d = 0
        q = row[group[a]]
        if q >= 0:
            K[i, n + q] = 1.0
            K[n + q, i] = 1.0
    d = np.linalg.lstsq(K, rhs, -1.0)[0][:n]
    slope = 0.0
    curv = 0.0
    for i in range(n):
        slope += grad[i] * d[i]
        for j in range(n):
            curv += d[i] * G[i, j] * d[j]
    if not slope < 0.0:
        return 0.0
    t_free = 1.0 if curv <= 0.0 else min(1.0, -slope / curv)
    # Candidate 1: the step cut at the first constraint it meets (ratio test), always feasible.
    t = t_free
    dsum = np.zeros(n_groups)
    for i in range(n):
        dsum[group[idx[i]]] += d[i]
        if d[i] < 0.0:
            t = min(t, -lam[idx[i]] / d[i])
    for g in range(n_groups):
        if row[g] < 0 and dsum[g] > 0.0:
            t = min(t, max(0.0, 1.0 - gsum[g]) / dsum[g])
    best = np.empty(n)
    best_change = 0.0
    if t > 0.0:
        for i in range(n):
            best[i] = max(0.0, lam[idx[i]] + t * d[i])
        best_change = t * slope + 0.5 * t * t * curv
    # Candidate 2: the full step projected onto the constraints (can cross several at once).
    new = np.empty(n)
    for i in range(n):
        new[i] = max(0.0, lam[idx[i]] + t_free * d[i])
    for g in range(n_groups):                           # groups over capacity: project onto the simplex
        total = 0.0
        current = 0.0
        cnt = 0
        for i in range(n):
            if group[idx[i]] == g:
                total += new[i]
                current += lam[idx[i]]
                cnt += 1
        if cnt == 0:
            continue
        cap = 1.0 - (gsum[g] - current)                 # what the group's other variables leave free
        if total <= cap:
            continue
        vals = np.empty(cnt)
        c = 0
        for i in range(n):
            if group[idx[i]] == g:
                vals[c] = new[i]
                c += 1
        vals = np.sort(vals)[::-1]
        acc = 0.0
        theta = 0.0
        for j in range(cnt):
            acc += vals[j]
            th = (acc - cap) / (j + 1)
            if vals[j] - th > 0.0:
                theta = th
        for i in range(n):
            if group[idx[i]] == g:
                new[i] = max(0.0, new[i] - theta)
    change = 0.0
    quad = 0.0
    for i in range(n):
        di = new[i] - lam[idx[i]]
        change += grad[i] * di
        for j in range(n):
            quad += di * G[i, j] * (new[j] - lam[idx[j]])
    change += 0.5 * quad
    if change < best_change:
        best_change = change
        for i in range(n):
            best[i] = new[i]
    if not best_change < 0.0:
        return 0.0
    for i in range(n):
        a = idx[i]
        step = best[i] - lam[a]
        lam[a] = best[i]
        gsum[group[a]] += step
        for j in range(r):
            y[j] += A[j, a] * step
    return best_change


def _pgs(A, c, group, free, lam, n_groups, iterations, tol, energy_tol):
    """Projected Gauss-Seidel on ``f = 0.5 |A l + c|^2`` (= the objective + const) over ``l >= 0``,
    ``sum of l over a group <= 1``.

    Plain loops (compiled with numba by :func:`limit_impulses`; run as Python in the tests). Each sweep
    minimizes exactly along every coordinate (upper bound: what its group leaves free), then along
    ``e_a - e_b`` for every pair of a saturated group (moves weight between columns at fixed sum, where
    single coordinates are stuck). Every SUBSPACE_EVERY sweeps, a subspace-minimization step solves the
    problem exactly on the current active set (PGS-SM): PGS finds the active set, the subspace step the
    values, which PGS alone approaches slowly when wrenches are nearly parallel. Works on ``y = A l + c``
    (r,): a coordinate step costs O(r). Stops when no factor changed by more than ``tol`` in a sweep, or
    when a sweep lowered the objective by less than ``energy_tol`` times ``|h.l| + l.G.l``.
    ``lam`` (k,) is the start (feasible) and is updated in place; variables with ``free[a]`` False keep
    their start value. Returns the number of sweeps done.
    """
    k = lam.shape[0]
    r = c.shape[0]
    gsum = np.zeros(n_groups)
    y = c.copy()
    for a in range(k):
        gsum[group[a]] += lam[a]
        for j in range(r):
            y[j] += A[j, a] * lam[a]
    order = np.argsort(group, kind="mergesort")        # the variables of group g: order[first[g]:first[g + 1]]
    first = np.zeros(n_groups + 1, dtype=np.int64)
    for a in range(k):
        first[group[a] + 1] += 1
    for g in range(n_groups):
        first[g + 1] += first[g]
    norm2 = np.zeros(k)                                 # |A[:, a]|^2 = G[a, a]
    for a in range(k):
        for j in range(r):
            norm2[a] += A[j, a] * A[j, a]
    sweeps = 0
    for _ in range(iterations):
        sweeps += 1
        change = 0.0
        decrease = 0.0
        for a in range(k):
            d = norm2[a]
            if d <= 1e-300 or not free[a]:
                continue
            g_a = 0.0
            for j in range(r):
                g_a += A[j, a] * y[j]
            g = group[a]
            new = min(1.0 - (gsum[g] - lam[a]), max(0.0, lam[a] - g_a / d))
            delta = new - lam[a]
            if delta != 0.0:
                decrease -= delta * (g_a + 0.5 * d * delta)
                gsum[g] += delta
                lam[a] = new
                for j in range(r):
                    y[j] += A[j, a] * delta
                change = max(change, abs(delta))
        for ga in range(n_groups):
            if first[ga + 1] - first[ga] < 2 or gsum[ga] < 1.0 - 1e-12:
                continue
            for ia in range(first[ga], first[ga + 1]):
                a = order[ia]
                for ib in range(ia + 1, first[ga + 1]):
                    b = order[ib]
                    if not (free[a] and free[b]):
                        continue
                    curv = 0.0
                    slope = 0.0
                    for j in range(r):
                        diff = A[j, a] - A[j, b]
                        curv += diff * diff
                        slope += diff * y[j]
                    if curv <= 1e-300:
                        continue
                    t = min(lam[b], max(-lam[a], -slope / curv))
                    if t != 0.0:
                        decrease -= t * (slope + 0.5 * curv * t)
                        lam[a] += t
                        lam[b] -= t
                        for j in range(r):
                            y[j] += (A[j, a] - A[j, b]) * t
                        change = max(change, abs(t))
        scale = 0.0
        for j in range(r):
            scale += y[j] * y[j] + c[j] * c[j]
        if change < tol or decrease <= energy_tol * scale:
            break
        if sweeps % SUBSPACE_EVERY == 0:
            _subspace_step(A, group, free, lam, gsum, y, n_groups)
    return sweeps


_subspace_step = _subspace_step_loops    # what _pgs calls; the compiled version once numba compiled it
_COMPILED = None


def _compiled():
    """(factor, pgs) compiled with numba (once; cached on disk)."""
    global _COMPILED, _subspace_step
    if _COMPILED is None:
        import numba  # a hard dependency; imported here so that pure-law users do not pay for it
        _subspace_step = numba.njit(cache=True)(_subspace_step_loops)
        # The solver's sweeps are dot products of length nv: with "reassoc" LLVM may split their sums into
        # SIMD lanes (the order is fixed by the machine code: still deterministic, run to run), and with
        # "contract" fuse multiply-adds. Measured: 1.48 -> 0.99 us per sweep on a 18 x 96 problem, the
        # standing quadruped's step 537-575 -> 492 us; the results agree with the plain loops to round-off
        # (tests/test_fastkernel.py, tests/test_stability.py).
        _COMPILED = (numba.njit(cache=True)(_factor_loops),
                     numba.njit(cache=True, fastmath={"reassoc", "contract"})(_pgs))
    return _COMPILED


def limit_impulses(G: np.ndarray, h: np.ndarray, group: np.ndarray | None = None,
                   start: np.ndarray | None = None, free: np.ndarray | None = None, *,
                   iterations: int | None = None, tol: float | None = None,
                   energy_tol: float | None = None, compiled: bool = True,
                   ensure_passive: bool = True) -> np.ndarray:
    """Scale factors ``l`` (k,) minimizing ``0.5 l.G.l + h.l`` (the kinetic energy after the step, up to
    a constant) over ``l >= 0`` with ``sum(l[group == g]) <= 1`` for every group g.

    Variable a scales one RFT wrench W_a (an octant group of one body, for one motion direction):
    ``G[a, b] = dt^2 Q_a . M^-1 Q_b`` and ``h[a] = dt qvel_pred . Q_a`` with ``Q_a = J_a^T W_a`` its
    generalized force and ``qvel_pred`` the velocity after the step without sand. Wrenches of the same
    octant for different motion directions share a group: the sand supplies a convex combination of
    its RFT wrenches, never more than one of them in full (its capacity). With one variable per group
    this is the box ``[0, 1]^k``; ``l = 1`` is the published force.

    Passivity (``ensure_passive``, default): the result satisfies ``0.5 l.G.l + h.l <= 0`` (the sand
    impulse never adds kinetic energy to the step): should the solution not (fixed variables, or an
    unconverged solve), it is scaled back along the ray to the best point, which does.

    Args:
        G: (k, k) float, symmetric positive semi-definite, J (energy: ``0.5 l.G.l + h.l`` is in J).
        h: (k,) float, J.
        group: (k,) int in 0..n_groups-1 (default: every variable its own group).
        start: (k,) feasible start (default all ones: the published force).
        free: (k,) bool, the variables to optimize (default all); the others keep their start value
            (the final passivity scaling applies to all).
        iterations, tol, energy_tol: most solver sweeps; stop when no factor changes by more than
            ``tol`` or the objective by less than ``energy_tol`` times its scale in a sweep (None: the
            module's LIMITER_* values).
        compiled: use the numba-compiled solver (False runs the same loops in Python; the tests compare
            the two).
    Returns:
        (k,) float scale factors.
    """
    G = np.ascontiguousarray(G, dtype=float)
    h = np.ascontiguousarray(h, dtype=float).reshape(-1)
    k = h.shape[0]
    if G.shape != (k, k):
        raise ValueError(f"G must have shape ({k}, {k}) to match h, got {G.shape}")
    if k == 0:
        return np.zeros(0)
    group = np.arange(k) if group is None else np.ascontiguousarray(group, dtype=np.int64).reshape(-1)
    lam = np.ones(k) if start is None else np.array(start, dtype=float).reshape(-1)
    free = np.ones(k, dtype=np.bool_) if free is None else np.ascontiguousarray(free, dtype=np.bool_).reshape(-1)
    if group.shape != (k,) or lam.shape != (k,) or free.shape != (k,):
        raise ValueError(f"group, start and free must have shape ({k},), got {group.shape}, {lam.shape} and "
                         f"{free.shape}")
    factor, solve = _compiled() if compiled else (_factor_loops, _pgs)
    A, c = factor(G, h, FACTOR_TOL)
    solve(A, c, group, free, lam, int(group.max()) + 1,
          int(LIMITER_ITERATIONS if iterations is None else iterations),
          float(LIMITER_TOL if tol is None else tol), float(LIMITER_ENERGY_TOL if energy_tol is None else energy_tol))
    if not ensure_passive:
        return lam
    quad = float(lam @ G @ lam)
    lin = float(h @ lam)
    if 0.5 * quad + lin > 0.0:
        lam *= min(1.0, max(0.0, -lin / quad)) if quad > 0.0 else 0.0
    return lam
