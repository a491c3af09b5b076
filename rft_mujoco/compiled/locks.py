"""Dofs held by their dry friction (MuJoCo's ``frictionloss``), locked in the rest solve, compiled.

:func:`rft_mujoco.physics.rest.locked_rest` and :func:`rft_mujoco.coupling.reference.stuck_dofs` on work
buffers: the stuck dofs from MuJoCo's friction rows (:func:`stuck_dofs`), ``S = E M^-1 E^T`` from the dofs'
columns of ``D^-1/2 L^-T`` along their chains (:func:`lock_matrices`), the test of whether to lock
without building ``C`` (:func:`_lock_needed`) and the lock / release loop around
:func:`rft_mujoco.compiled.rest.rest_wrenches` (:func:`locked_rest`). Design: docs/rest.md, "Dry friction".
Nothing here calls MuJoCo; :mod:`rft_mujoco.compiled.evaluate` calls it.
"""

from __future__ import annotations

import math

from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.compiled.rest import _chain_dof, _cholesky, _cholesky_solve, rest_wrenches
from rft_mujoco.physics import rest as _rest

TREE = ("body_dofnum", "body_dofadr", "body_parentid", "dof_parentid")
"""The ``tree`` bundle: the model's kinematic tree (``mjModel`` arrays of those names, int64): each body's dof
count and first dof, its parent body, each dof's parent dof."""
FACTOR = ("rownnz", "rowadr", "colind", "qld", "qld_diag_inv")
"""The ``factor`` bundle: MuJoCo's sparse factor ``M = L^T D L`` (``M_rownnz``, ``M_rowadr``, ``M_colind`` of the
model, ``qLD``, ``qLDiagInv`` of the data; :func:`rft_mujoco.compiled.rest.solve_m`)."""
MOTION = ("twist", "chain", "zt")
"""The ``motion`` bundle: the groups' twists now (G, 6) [m/s, rad/s] and their scaled Jacobians
``W = D^-1/2 L^-T J^T`` along their chains (``zt`` (nv, 6 G), ``chain`` (G, 1 + nv) int: length, then the
dofs) of :func:`rft_mujoco.compiled.evaluate._mobility`."""
LOCK = ("lock_i", "lock_f", "lock_z", "lock_chain", "lock_s", "lock_c", "lock_r", "lock_x", "lock_mob", "lock_free",
        "lock_w", "lock_rest")
"""The ``lock`` bundle: the locks' work space for L <= nv stuck dofs (the workspace's arrays of those names).
``lock_i`` (3, >= L) int: the stuck dofs, whether each is held, the held ones' indices; ``lock_f`` (5, nv):
their friction forces [N or N m], frictionloss, ``y = E qacc``, the held ones' ``z`` / ``lam``, an nv-vector;
``lock_z`` (nv, >= L) their columns ``W_E``, ``lock_chain`` (>= L, 1 + nv) int their chains; ``lock_s``,
``lock_r`` (>= L, >= L) ``S`` and ``R``, ``lock_c``, ``lock_x`` (>= L, 6 G) ``C^T`` and ``X``; ``lock_mob``
(6 G, 6 G), ``lock_free`` (G, 6) the locked solve's mobility and free twists, ``lock_w`` (G, 6), ``lock_rest``
(G,) bool the unlocked solve's wrenches and rest flags."""

FRICTION_DOF = 1
"""MuJoCo's ``mjCNSTR_FRICTION_DOF`` (checked against the bindings by tests/test_compiled_rest.py)."""
LOCK_TOL = _rest.LOCK_TOL
""":data:`rft_mujoco.physics.rest.LOCK_TOL` (frozen into the compiled code)."""


@njit(**JIT)
def _tree_dof(j, dof_parentid):
    """:func:`rft_mujoco.coupling.reference._tree_dof`."""
    while j >= 0 and dof_parentid[j] >= 0:
        j = dof_parentid[j]
    return j


@njit(**JIT)
def stuck_dofs(fr, ng, active, ids, group_ref, tree, lock_i, lock_f, group_tree):
    """:func:`rft_mujoco.coupling.reference.stuck_dofs` from MuJoCo's last constraint solve ``fr``
    (:data:`rft_mujoco.compiled.evaluate.FRICTION_FIELDS`) for the ``ng`` groups ``active`` (bodies
    ``ids[group_ref[active]]``; ``tree``: :data:`TREE`): the dofs into ``lock_i[0]``, their friction forces and
    frictionloss into ``lock_f[0]``, ``lock_f[1]``; returns their number L. ``group_tree`` (G,): work space (the
    groups' tree dofs, found at the first friction row)."""
    efc_type, efc_id, efc_d, efc_aref, efc_frictionloss, qacc_prev = fr
    body_dofnum, body_dofadr, body_parentid, dof_parentid = tree
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
def lock_matrices(nl, factor, qacc, dof_parentid, lock):
    """For the ``nl`` dofs of :func:`stuck_dofs` (``lock_i[0]`` of ``lock``, :data:`LOCK`): ``S = E M^-1 E^T``
    into ``lock_s`` (L, L) and ``y = E qacc`` into ``lock_f[2]``. A dof's column ``W_E = D^-1/2 L^-T e_j``
    (``lock_z[:, l]``; the factor ``M = L^T D L``, :data:`FACTOR`, as in
    :func:`rft_mujoco.compiled.evaluate._mobility`) lies on its chain (``lock_chain``); products sum over the
    dofs two chains share (next to the root)."""
    rownnz, rowadr, colind, qld, qld_diag_inv = factor
    lock_i, lock_f, lock_z, lock_chain, lock_s = lock[0], lock[1], lock[2], lock[3], lock[4]
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
def _lock_needed(nl, ng, nv, dt, motion, free, radius, w, lock, tiny):
    """Step 1 of :func:`rft_mujoco.physics.rest.locked_rest`: whether the groups' motion ``dt C lam_u``
    from the friction that would hold every dof under the unlocked wrenches ``w`` exceeds LOCK_TOL of their
    twist change (``motion``: :data:`MOTION`; ``free``, ``radius``: those of the rest solve). Without ``C``:
    ``C^T w = W_E^T (W w)`` and ``C lam = W^T (W_E lam)`` through nv-vectors (``lock_f[4]`` of ``lock``,
    :data:`LOCK`); ``lam_u`` in ``lock_f[3]``."""
    twist, chain, zt = motion
    lock_i, lock_f, lock_z, lock_chain, lock_s, lock_r = lock[0], lock[1], lock[2], lock[3], lock[4], lock[6]
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
def _slip(lr, df, nl, n6, dt, free, lock_f, lock_s, lock_c):
    """A released dof ``lr`` slips: its friction changes by ``df`` (to its bound; N or N m), which moves the free
    twists ``free`` by ``dt C df`` and the dofs' free accelerations ``y`` (``lock_f[2]``) by ``S df``."""
    for l in range(nl):
        lock_f[2, l] += lock_s[l, lr] * df
    for i in range(n6):
        free[i // 6, i % 6] += dt * (lock_c[lr, i] * df)


@njit(**JIT)
def _adds_energy(nl, ng, dt, free, mob, w, lock, tiny):
    """Step 3 of :func:`rft_mujoco.physics.rest.locked_rest`: whether the wrenches ``w`` (G, 6) would add kinetic
    energy to the motion with all ``nl`` dofs held (:func:`rft_mujoco.physics.rest.passive_scale` below 1 on
    ``A - X^T X`` and ``Vf - dt X^T z``; ``X``, ``z`` into ``lock_x``, ``lock_f[3]`` of ``lock``)."""
    lock_i, lock_f, lock_s, lock_c, lock_r, lock_x = lock[0], lock[1], lock[4], lock[5], lock[6], lock[7]
    n6 = 6 * ng
    for l in range(nl):
        lock_i[2, l] = l
    _lock_factor(nl, n6, lock_i, lock_f, lock_s, lock_c, lock_r, lock_x, tiny)
    h = 0.0
    q = 0.0
    for i in range(n6):
        wi = w[i // 6, i % 6]
        h += wi * free[i // 6, i % 6]
        t = 0.0
        for k in range(n6):
            t += mob[i, k] * w[k // 6, k % 6]
        q += wi * t
    for r in range(nl):
        xw = 0.0
        for i in range(n6):
            xw += lock_x[r, i] * w[i // 6, i % 6]
        h -= dt * xw * lock_f[3, r]
        q -= xw * xw
    return h + 0.5 * (dt * q) > 0.0


@njit(**JIT)
def locked_rest(nl, groups, dt, ng, settings, out, work, kept, motion, lock, check):
    """:func:`rft_mujoco.physics.rest.locked_rest` on the matrices of :func:`lock_matrices`, with
    :func:`rest_wrenches` (``groups``, ``dt``, ``ng``, ``settings``, ``out``, ``work``, ``kept``: its arguments;
    no factor is kept: ``state[KEPT_GROUPS]`` is 0); ``motion`` (:data:`MOTION`): the groups' twists now and the
    scaled Jacobians of ``_mobility``; ``check``: whether step 1 runs. Returns the number of dofs held in the
    final solve; which: ``lock_i[1]`` (1/0); the other arrays of ``lock`` (:data:`LOCK`) are work space. Where a
    released dof slips (step 3), its friction at the bound moves ``groups``' free twists (:func:`_slip`)."""
    free, mob, radius = groups[0], groups[1], groups[4]
    w, rest = out
    chain, zt = motion[1], motion[2]
    lock_i, lock_f, lock_c, lock_w, lock_rest = lock[0], lock[1], lock[5], lock[10], lock[11]
    tiny = settings[3]
    if check:                                        # step 1 needs the unlocked solve; without it (a dof held at
        rest_wrenches(groups, dt, ng, settings, out, work, kept, False)
        for l in range(nl):                          # the last evaluation) it is made only if every lock releases:
            lock_i[1, l] = 0                         # the same numbers, one rest solve fewer while a robot stands
        if not _lock_needed(nl, ng, lock_f.shape[1], dt, motion, free, radius, w, lock, tiny):
            return 0
        for g in range(ng):
            lock_rest[g] = rest[g]
            for c in range(6):
                lock_w[g, c] = w[g, c]
    _lock_coupling(nl, ng, chain, zt, lock[2], lock[3], lock_c)
    m = _release(nl, groups, dt, ng, settings, out, work, kept, lock, check, False)
    if m == nl or not _adds_energy(nl, ng, dt, free, mob, w, lock, tiny):
        return m
    return _release(nl, groups, dt, ng, settings, out, work, kept, lock, check, True)


@njit(**JIT)
def _release(nl, groups, dt, ng, settings, out, work, kept, lock, check, slip):
    """Step 2 of :func:`rft_mujoco.physics.rest.locked_rest` from every dof locked (``slip``: with step 3's
    friction at the bound); returns the number of dofs held. With none left and no ``slip``, the unlocked
    solve (kept in ``lock_w``, ``lock_rest`` by step 1, made here without ``check``)."""
    free, mob, rft, direction, radius = groups
    w, rest = out
    lock_i, lock_f, lock_z, lock_chain, lock_s, lock_c, lock_r, lock_x, lock_mob, lock_free, lock_w, lock_rest = lock
    n6 = 6 * ng
    tiny = settings[3]
    for l in range(nl):
        lock_i[1, l] = 1
    locked = (lock_free, lock_mob, rft, direction, radius)
    while True:
        m = 0
        for l in range(nl):
            if lock_i[1, l] != 0:
                lock_i[2, m] = l
                m += 1
        if m == 0:                                   # every lock released: the unlocked solve
            if slip or not check:
                rest_wrenches(groups, dt, ng, settings, out, work, kept, False)
                return 0
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
        rest_wrenches(locked, dt, ng, settings, out, work, kept, False)
        _plus_xw(m, n6, w, lock_x, lock_f)           # lam = -R^-T (z + X W)
        for r in range(m - 1, -1, -1):
            t = lock_f[3, r]
            for j in range(r + 1, m):
                t -= lock_r[j, r] * lock_f[3, j]
            lock_f[3, r] = t / lock_r[r, r]
        over = False
        for r in range(m):
            lr = lock_i[2, r]
            need = lock_f[0, lr] - lock_f[3, r]      # the friction the lock needs
            if abs(need) > lock_f[1, lr]:
                lock_i[1, lr] = 0
                over = True
                if slip:
                    _slip(lr, math.copysign(lock_f[1, lr], need) - lock_f[0, lr], nl, n6, dt, free, lock_f, lock_s,
                          lock_c)
        if not over:
            return m
