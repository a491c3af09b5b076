"""The rest treatment of the sand (``attach(stabilize=True)``): pure array functions, no MuJoCo.

3D-RFT is rate-independent: the stress follows the direction of motion and is undefined at rest, where
the sand can hold any load up to its capacity. Rigid-body engines treat Coulomb friction the same way:
implicitly, as a bounded constraint. This module does that for the sand, per *group* (the sand bodies of
one MuJoCo weld group: one rigid body), in one step of the integrator:

1. The *free twist* ``Vf`` of every touching group: its twist (linear velocity of a reference point,
   angular velocity; world frame) at the end of the step without sand. The coupling computes it from
   MuJoCo's mass matrix, the smooth forces of this evaluation, and the constraint forces of MuJoCo's
   previous solve (contacts, welds, joint and tendon limits, frictionloss: loads that reach a sand body
   through a constraint are in it; see :mod:`rft_mujoco.coupling.handle`).
2. The motion direction of every element is that of the *blended* twist (:func:`blend`): the group's
   twist ``V`` when it moves fast compared with the change ``Vf - V`` one step makes, the free twist when
   it is at rest. The published law gives the RFT wrench ``F`` of each group at that twist.
3. Every loaded group first tries to *rest* (:func:`rest_wrenches`): the sand wrenches that make the
   free twists of the resting groups zero at the end of the step, solved together through the groups'
   mobility ``A = J M^-1 J^T`` (a group pushes on the others through the joints). A group whose rest
   wrench exceeds its capacity *flows* instead: it gets its RFT wrench, scaled down only as far as needed
   not to reverse its motion in the step (which also drops a wrench the fitted law would let do positive
   work). The rest wrenches are then solved again for the others. The capacity is the sand's resistance
   along the motion the group would start: with ``u`` the blended twist, a rest wrench ``W`` is
   admissible when ``-W.u <= -F.u`` -- the supporting half-space of the sand's yield set in that
   direction (plasticity: the dissipation ``-F(u).u`` is the support function of the set of wrenches
   the sand can hold). A load larger than the sand can resist along the way it pushes makes it flow.

So a group below its capacity stops within one step and stays at rest, whatever holds or pushes it
(the load is in ``Vf``), and a group above it gets the published force. In steady flow the blended
direction differs from the published one by ``(|Vf - V| / |V|)^3`` (below 1e-3 at ten times the speed
change of one step). Neither regime adds kinetic energy in the step: the rest wrench removes the free
motion, the flow wrench never overshoots it, and a final check (:func:`passive_scale`) scales every
wrench back should the combination do so.

With RK4, stages 2-4 of a step (states within one step of the first) may reuse the first stage's
mobility and the factor of its rest solve, weights included (:class:`StepFactor`, the ``keep`` and
``reuse`` arguments of :func:`rest_wrenches`): the free twists, RFT wrenches and capacities are still
each stage's own, and the rest wrenches still stop the resting groups as that mobility predicts.

Units: SI. Twists are (linear m/s, angular rad/s), wrenches (force N, torque N m), both world frame, at
each group's reference point; ``A`` maps a wrench to a twist change per second, per unit time step, in
(m/s per N s, rad/s per N m s). Radii (m) make the two parts comparable: a twist counts
``|v| + R |w|``, a wrench ``|(f, tau / R)|``.
"""

from __future__ import annotations

import numpy as np

from rft_mujoco import tol

DEPENDENT_TOL = 1e-3
"""The rest solve keeps a rest constraint (one twist component of one group) only while the part of its
mobility that the constraints already kept do not explain is above this fraction of its whole mobility
(a diagonally pivoted Cholesky, :func:`pivoted_solve`). Four feet on a trunk of 18 degrees of freedom
give 24 constraints of rank 18, and some of the 18 are nearly implied by the others: holding those
exactly costs internal wrenches far above the load (measured on the bundled quadruped: 1,266 N of
sideways squeeze for a 118 N robot, from a mode with 1e-4 of the mean mobility). Left out, they are
held to within this fraction by the constraints kept."""

WEIGHT_FLOOR = 1e-6
"""The rest solve's per-group weights (squared capacities, :func:`pivoted_solve`) are at least this fraction
of the largest: a group that barely touches the sand next to one that carries the load keeps the solve
well conditioned (measured: a 1e-4 N group beside a 10 N one made it singular)."""

CAPACITY_TOL = 1e-9
"""A rest wrench may exceed the RFT capacity by this fraction (round-off) before the group flows."""


def _scales(radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G, 6) twist and wrench weights: ``(1, 1, 1, R, R, R)`` and ``(1, 1, 1, 1/R, 1/R, 1/R)``."""
    r = np.asarray(radius, dtype=float)[:, None]
    ones = np.ones((r.shape[0], 3))
    return np.hstack([ones, ones * r]), np.hstack([ones, ones / r])


def twist_speed(twist: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """``|v| + R |w|`` of (G, 6) twists: an upper bound of the speed of a group's surface points (m/s)."""
    twist = np.asarray(twist, dtype=float)
    return np.linalg.norm(twist[:, :3], axis=1) + np.asarray(radius) * np.linalg.norm(twist[:, 3:], axis=1)


def blend(twist: np.ndarray, free_twist: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The twists (G, 6) whose element motions give the sand's direction.

    ``U = V + w (Vf - V)`` with ``w = s^2 / (|V|^2 + s^2)``, ``s = |Vf - V|`` (twist speeds, see
    :func:`twist_speed`): the published motion ``V`` when ``|V| >> s`` (relative change ``(s / |V|)^3``),
    the motion the group would have after this step without sand when it is at rest.
    """
    twist = np.asarray(twist, dtype=float)
    step = np.asarray(free_twist, dtype=float) - twist
    s = twist_speed(step, radius)
    v = twist_speed(twist, radius)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(s > 0.0, s * s / (v * v + s * s), 0.0)
    return twist + w[:, None] * step


def _flow_factor(h: float, q: float) -> float:
    """The factor in [0, 1] of an impulse with energy change ``h l + q l^2 / 2`` (J) that removes the most
    kinetic energy: 1 unless the full impulse would overshoot, 0 when it would do positive work."""
    if h >= 0.0:
        return 0.0
    if q <= 0.0:
        return 1.0
    return min(1.0, -h / q)


class StepFactor:
    """The factor of a rest solve kept for the later stages of one RK4 step (see :func:`rest_wrenches`).

    ``rest``: (G,) the resting groups it was made for (None: none kept); ``factor``: what
    :func:`pivoted_factor` returned, with the weights it was made with."""

    __slots__ = ("rest", "factor")

    def __init__(self) -> None:
        self.rest = None
        self.factor = None

    def clear(self) -> None:
        self.rest = None
        self.factor = None


def rest_wrenches(free_twist: np.ndarray, mobility: np.ndarray, rft: np.ndarray, direction: np.ndarray,
                  radius: np.ndarray, dt: float, keep: StepFactor | None = None,
                  reuse: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Sand wrenches of G touching groups: rest where the sand can hold them, RFT flow elsewhere.

    Args:
        free_twist: (G, 6) twists at the end of the step without sand (m/s, rad/s).
        mobility: (6G, 6G) ``J M^-1 J^T`` of the groups' reference points (symmetric PSD).
        rft: (G, 6) RFT wrenches at the blended twists (N, N m); a zero row is a group with no loaded
            element (it gets no wrench).
        direction: (G, 6) the blended twists the RFT wrenches were evaluated at (only their directions
            matter).
        radius: (G,) m, each group's radius (> 0).
        dt: the time step in s (> 0).
        keep: where the factor of each solve is kept (None: nowhere).
        reuse: solve with ``keep``'s factor (and its weights) when it was made for the same resting groups
            (the later stages of an RK4 step, whose ``mobility`` is the first stage's: the factor depends
            on the mobility and the weights only; the free twists and capacities are this evaluation's).
    Returns:
        wrenches (G, 6) (N, N m), resting (G,) bool: the groups held at rest.
    """
    vf = np.asarray(free_twist, dtype=float)
    rft = np.asarray(rft, dtype=float)
    n = rft.shape[0]
    if vf.shape != (n, 6) or rft.shape != (n, 6) or np.shape(mobility) != (6 * n, 6 * n):
        raise ValueError(f"free_twist and rft must be (G, 6) and mobility (6G, 6G), got {vf.shape}, "
                         f"{rft.shape} and {np.shape(mobility)}")
    sv, sw = _scales(radius)
    # Scaled coordinates: twists (v, R w), wrenches (f, tau / R); products (and energies) unchanged.
    a = dt * (sv.reshape(-1)[:, None] * np.asarray(mobility, dtype=float) * sv.reshape(-1)[None, :])
    v = (vf * sv).reshape(-1)
    target = v
    cap = rft * sw
    u = np.asarray(direction, dtype=float) * sv
    capacity = -np.einsum("ij,ij->i", cap, u)            # the sand's resistance along u (J/s per unit u)
    rest = np.any(cap != 0.0, axis=1)
    flow = np.zeros(n, dtype=bool)
    while True:
        w = np.zeros((n, 6))
        for g in np.flatnonzero(flow):
            sl = slice(6 * g, 6 * g + 6)
            w[g] = _flow_factor(float(cap[g] @ v[sl]), float(cap[g] @ a[sl, sl] @ cap[g])) * cap[g]
        idx = np.flatnonzero(np.repeat(rest, 6))
        if idx.size:
            rhs = target[idx] + a[idx] @ w.reshape(-1)
            block = a[np.ix_(idx, idx)]
            if reuse and keep is not None and keep.rest is not None and np.array_equal(keep.rest, rest):
                factor = keep.factor
            else:
                weight = np.repeat(np.einsum("ij,ij->i", cap, cap), 6)[idx]
                weight = np.maximum(weight, WEIGHT_FLOOR * weight.max())
                factor = pivoted_factor(block, weight, DEPENDENT_TOL, tol.TINY)
                if keep is not None:
                    keep.rest, keep.factor = rest.copy(), factor
            w.reshape(-1)[idx] = -pivoted_apply(block, rhs, *factor)
            demand = -np.einsum("ij,ij->i", w, u)
            over = rest & (demand > np.maximum(capacity, 0.0) * (1.0 + CAPACITY_TOL))
            if over.any():
                rest &= ~over
                flow |= over
                continue
        break
    w *= passive_scale(w.reshape(-1), v, a)
    return w / sw, rest


def passive_scale(wrench: np.ndarray, twist: np.ndarray, a: np.ndarray) -> float:
    """The factor in [0, 1] that keeps a stacked impulse from adding kinetic energy: 1 when
    ``dt (W.Vf) + dt^2 W.A.W / 2 <= 0`` (``a`` is ``dt A``, ``twist`` ``Vf``), else the energy-minimizing
    scale along the ray."""
    h = float(wrench @ twist)
    q = float(wrench @ a @ wrench)
    if h + 0.5 * q <= 0.0:
        return 1.0
    return _flow_factor(h, q) if h < 0.0 else 0.0


def pivoted_solve(a: np.ndarray, rhs: np.ndarray, weight: np.ndarray, dependent_tol: float,
                  tiny: float) -> np.ndarray:
    """The smallest ``x`` (m,) in the norm ``sum x_i^2 / weight_i`` with ``(a x)[K] = rhs[K]``, for the rows
    K that a diagonally pivoted Cholesky of ``a`` (m, m, symmetric PSD) keeps (``weight`` (m,) > 0).

    Row selection: the next row kept is the one whose remaining diagonal (the part of its mobility the rows
    already kept leave unexplained) is the largest fraction of its own diagonal; the selection stops when
    that fraction is at most ``dependent_tol`` (the remaining rows are implied by the kept ones to within
    it). Then ``x = D B^T (B D B^T)^-1 rhs[K]`` with ``B = a[K, :]``, ``D = diag(weight)``: among all
    wrenches that hold the kept rows, the smallest in that norm (with the groups' squared capacities as
    weights, two groups tied to one rigid body share its load in proportion to their capacities). Plain
    loops (:func:`pivoted_factor` then :func:`pivoted_apply`): the compiled rest evaluation runs the same
    arithmetic (:mod:`rft_mujoco.compiled.rest`).
    """
    order, g, w = pivoted_factor(a, weight, dependent_tol, tiny)
    return pivoted_apply(a, rhs, order, g, w)


def pivoted_factor(a: np.ndarray, weight: np.ndarray, dependent_tol: float,
                   tiny: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The part of :func:`pivoted_solve` that does not depend on ``rhs``: the kept rows ``order`` (k,) in
    pivot order, the lower Cholesky factor ``g`` (k, k) of ``B D B^T``, and ``weight``."""
    m = a.shape[0]
    diag0 = np.empty(m)
    rem = np.empty(m)
    for i in range(m):
        diag0[i] = a[i, i]
        rem[i] = a[i, i]
    order = np.empty(m, dtype=np.int64)
    kept = np.zeros(m, dtype=np.bool_)
    low = np.zeros((m, m))                          # low[i, k]: column k of the factor, rows in input order
    k = 0
    while k < m:
        p = -1
        best = dependent_tol
        for i in range(m):
            if not kept[i] and diag0[i] > tiny and rem[i] > best * diag0[i]:
                best = rem[i] / diag0[i]
                p = i
        if p < 0:
            break
        kept[p] = True
        order[k] = p
        piv = np.sqrt(rem[p])
        for i in range(m):
            if kept[i] and i != p:
                continue
            t = a[i, p]
            for j in range(k):
                t -= low[i, j] * low[p, j]
            low[i, k] = t / piv
        for i in range(m):
            if not kept[i]:
                rem[i] -= low[i, k] * low[i, k]
        k += 1
    if k == 0:
        return order[:0], np.zeros((0, 0)), weight
    g = np.empty((k, k))                            # B D B^T, B = a[order[:k], :]
    for r in range(k):
        for c in range(r + 1):
            t = 0.0
            for j in range(m):
                t += a[order[r], j] * weight[j] * a[order[c], j]
            g[r, c] = t
    for c in range(k):                              # Cholesky, in place (lower)
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
    return order[:k], g, weight


def pivoted_apply(a: np.ndarray, rhs: np.ndarray, order: np.ndarray, g: np.ndarray,
                  weight: np.ndarray) -> np.ndarray:
    """``x`` of :func:`pivoted_solve` from :func:`pivoted_factor`'s ``(order, g, weight)``."""
    m = rhs.shape[0]
    k = order.shape[0]
    x = np.zeros(m)
    if k == 0:
        return x
    y = np.empty(k)
    for r in range(k):
        t = rhs[order[r]]
        for c in range(r):
            t -= g[r, c] * y[c]
        y[r] = t / g[r, r]
    for r in range(k - 1, -1, -1):
        t = y[r]
        for c in range(r + 1, k):
            t -= g[c, r] * y[c]
        y[r] = t / g[r, r]
    for j in range(m):
        t = 0.0
        for r in range(k):
            t += a[order[r], j] * y[r]
        x[j] = weight[j] * t
    return x


# --- dry friction (frictionloss) that holds a dof still ----------------------------------------------------
def friction_estimate(d: np.ndarray, aref: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The force (L,) of MuJoCo's frictionloss rows in their unsaturated zone: ``-D (a - aref)``.

    A frictionloss row of dof ``j`` is a soft constraint on ``a = qacc[j]``; its force is ``-D (a - aref)``
    clamped to ``[-frictionloss, frictionloss]`` (N or N m). ``d`` (1/kg-like impedance) and ``aref``
    (m/s^2 or rad/s^2) are this step's (MuJoCo computes them before ``mjcb_control``), ``acc`` the dofs'
    accelerations of MuJoCo's previous solve: where the estimate lies strictly inside the bounds, the
    friction held the dof in that solve (it equals MuJoCo's ``efc_force`` there)."""
    return -np.asarray(d, dtype=float) * (np.asarray(acc, dtype=float) - np.asarray(aref, dtype=float))


LOCK_TOL = 1e-4
"""A lock is tried only where the friction MuJoCo adds to hold the stuck dofs under the unlocked rest
wrenches would move a group by more than this fraction of its twist change in the step (twist speeds,
:func:`twist_speed`). Measured (docs/rest.md): the bundled quadruped standing, every joint stuck, 4e-6
(its unlocked solve is already what the locks give); the ``frictionloss`` load path chattering without
locks, 3e-4 to 8e-2."""


def locked_rest(free_twist: np.ndarray, mobility: np.ndarray, coupling: np.ndarray, gram: np.ndarray,
                acc: np.ndarray, force: np.ndarray, capacity: np.ndarray, dt: float, solve, twist: np.ndarray,
                radius: np.ndarray, check: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rest solve with L dofs held still by their dry friction (MuJoCo's ``frictionloss``).

    MuJoCo solves dry friction after ``mjcb_control``; the free twists see the previous solve's friction
    force only, so a dof that the friction holds still is, to the rest solve, free to move under that
    force plus whatever the sand adds, and the two chatter without rest (the ``frictionloss`` load path
    of :mod:`rft_mujoco.studies.loadpaths`). Here such a dof is *locked* in the step: with ``E`` its unit
    rows, the motion is ``M a = f + J^T W + E^T lam``, ``E a = 0``, whose mobility and free twists are

        ``A_l = A - C S^-1 C^T``,  ``Vf_l = Vf - dt C S^-1 y``,  ``lam = -S^-1 (y + C^T W)``

    with ``C = J M^-1 E^T``, ``S = E M^-1 E^T`` and ``y = E M^-1 f``.

    1. The unlocked solve gives ``W_u``; ``lam_u`` is the friction MuJoCo would add to hold every dof
       under it, ``dt C lam_u`` the groups' motion from that. Where it is within :data:`LOCK_TOL` of each
       group's twist change ``Vf - V``, ``W_u`` is the answer (no lock). Skipped without ``check`` (the
       caller's choice when a dof was locked in the previous evaluation: a lock that holds stays, where
       the test alone would alternate locked and unlocked steps at a residual of LOCK_TOL).
    2. Otherwise every dof is locked; a lock holds while the friction force it needs, ``force + lam``,
       is within ``capacity``; the dofs over it are released (all at once) and the rest solve is
       repeated, until every lock left holds; with none left, ``W_u`` is the answer. A released dof keeps
       the lagged ``force``.
    3. If that answer would add kinetic energy to the motion with every dof held (``A_l``, ``Vf_l`` of all
       L locks, :func:`passive_scale` below 1), the motion MuJoCo's friction makes wherever the answer
       leaves it within its bound, step 2 is repeated with each released dof slipping in the step, its
       friction at the bound, ``sign(force + lam) capacity`` (the free twists move by ``dt C df``, ``y``
       by ``S df``).
       The lagged force alone let the sand pull down a foot that it pushed up, while MuJoCo's friction
       held the knee and the foot fell with the trunk (the ``frictionloss`` load path as the trunk lands:
       1.1e-4 J added at 2 ms). Slipping always, the standing quadruped (twelve servo joints, 0.05 N m of
       friction each) did not rest: its joints are released all at once, with signs that the unlocked
       solve contradicts (docs/rest.md).

    Args:
        free_twist: (G, 6) and mobility (6G, 6G): those of :func:`rest_wrenches`, without locks.
        coupling: (6G, L) ``C``; gram: (L, L) ``S`` (symmetric positive definite); acc: (L,) ``y``, the free
            accelerations of the dofs (m/s^2, rad/s^2, the previous friction force included).
        force: (L,) the friction force already in ``y`` (:func:`friction_estimate`), N or N m; capacity:
            (L,) the rows' ``frictionloss``.
        dt: the time step (s).
        solve: ``solve(free_twist, mobility) -> (wrenches (G, 6), resting (G,))``, :func:`rest_wrenches`
            with its other arguments bound.
        twist: (G, 6) the groups' twists now; radius: (G,) m.
        check: whether step 1 runs.
    Returns:
        wrenches (G, 6), resting (G,), locked (L,) bool: the dofs held in the final solve.
    """
    n = np.shape(coupling)[1]
    if np.shape(gram) != (n, n) or np.shape(acc) != (n,) or np.shape(force) != (n,) or np.shape(capacity) != (n,):
        raise ValueError(f"coupling (6G, L) = {np.shape(coupling)} needs gram (L, L) and acc, force, capacity "
                         f"(L,), got {np.shape(gram)}, {np.shape(acc)}, {np.shape(force)}, {np.shape(capacity)}")
    free_twist = np.asarray(free_twist, dtype=float)
    coupling, gram, acc = (np.asarray(x, dtype=float) for x in (coupling, gram, acc))
    w_u, rest_u = solve(free_twist, mobility)
    lock = np.ones(n, dtype=bool)
    low, x, z = _lock_factor(coupling, gram, acc, lock)
    if check:
        moved = (-dt * (x.T @ (z + x @ w_u.reshape(-1)))).reshape(free_twist.shape)
        if np.all(twist_speed(moved, radius) <= LOCK_TOL * twist_speed(free_twist - twist, radius)):
            return w_u, rest_u, ~lock
    args = (free_twist, mobility, coupling, gram, acc, force, capacity, dt, solve, (w_u, rest_u))
    w, resting, lock = _release(*args, False)
    held = (free_twist - dt * (x.T @ z).reshape(free_twist.shape)).reshape(-1)
    if lock.all() or passive_scale(w.reshape(-1), held, dt * (mobility - x.T @ x)) >= 1.0:
        return w, resting, lock
    return _release(*args, True)


def _release(free_twist, mobility, coupling, gram, acc, force, capacity, dt, solve, unlocked, slip):
    """Step 2 of :func:`locked_rest` from every dof locked: (wrenches, resting, locked). A released dof keeps
    the lagged ``force`` (the unlocked solve ``unlocked`` is the answer when none is left), or with ``slip``
    gets its friction at the bound (step 3)."""
    lock = np.ones(np.shape(coupling)[1], dtype=bool)
    while lock.any():
        i = np.flatnonzero(lock)
        low, x, z = _lock_factor(coupling, gram, acc, lock)
        w, resting = solve(free_twist - dt * (x.T @ z).reshape(free_twist.shape), mobility - x.T @ x)
        need = force[i] - _backward(low, z + x @ w.reshape(-1))     # the friction the lock needs
        over = np.abs(need) > capacity[i]
        if not over.any():
            return w, resting, lock
        r = i[over]
        lock[r] = False
        if slip:                        # the dof slips in the step, its friction at the bound the lock needed
            df = np.sign(need[over]) * capacity[r] - force[r]
            free_twist = free_twist + dt * (coupling[:, r] @ df).reshape(free_twist.shape)
            acc = acc + gram[:, r] @ df
    return (*solve(free_twist, mobility), lock) if slip else (*unlocked, lock)


def _lock_factor(coupling, gram, acc, lock):
    """For the locked dofs: the lower Cholesky factor ``R`` of ``S``, ``X = R^-1 C^T`` and ``z = R^-1 y``
    (so that ``C S^-1 C^T = X^T X`` and ``C S^-1 y = X^T z``)."""
    i = np.flatnonzero(lock)
    low = _cholesky(gram[np.ix_(i, i)])
    return low, _forward(low, coupling[:, i].T), _forward(low, acc[i][:, None])[:, 0]


def _cholesky(s: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor of ``s`` (n, n), plain loops (as :mod:`rft_mujoco.compiled.rest`)."""
    n = s.shape[0]
    low = np.zeros((n, n))
    for c in range(n):
        t = s[c, c] - low[c, :c] @ low[c, :c]
        d = np.sqrt(t) if t > tol.TINY else np.sqrt(tol.TINY)
        low[c, c] = d
        for r in range(c + 1, n):
            low[r, c] = (s[r, c] - low[r, :c] @ low[c, :c]) / d
    return low


def _forward(low: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``low^-1 b`` for a lower triangular ``low`` (n, n) and ``b`` (n, m)."""
    x = np.array(b, dtype=float)
    for r in range(low.shape[0]):
        x[r] = (x[r] - low[r, :r] @ x[:r]) / low[r, r]
    return x


def _backward(low: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``low^-T b`` for a lower triangular ``low`` (n, n) and ``b`` (n,)."""
    x = np.array(b, dtype=float)
    for r in range(low.shape[0] - 1, -1, -1):
        x[r] = (x[r] - low[r + 1:, r] @ x[r + 1:]) / low[r, r]
    return x
