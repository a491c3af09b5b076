"""This step's constraints linearized, and the free motion of the sand groups through them, compiled.

Pure array functions (nothing here calls MuJoCo), the same algorithms as the numpy reference
(tests/test_compiled_implicit.py compares them):

* :func:`constrained_system` (zones by :func:`row_zones`): :func:`rft_mujoco.coupling.reference.
  constrained_free_motion` (and :func:`velocity_damping`'s term) on MuJoCo's sparse mass matrix and this
  step's constraint rows, dense or sparse;
* :func:`free_motion`: the groups' twists now, their free twists and the mobility ``J H^-1 J^T``
  (:func:`rft_mujoco.coupling.reference.implicit_free`), with a dense Cholesky factor of ``H``;
* :func:`end_acceleration`: the step's end accelerations under the groups' wrenches (the zones are taken
  again there: :data:`rft_mujoco.physics.implicit.ZONE_PASSES`).
"""

from __future__ import annotations

from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.compiled.rest import _cholesky, _cholesky_solve, jacobian

# MuJoCo's mjtConstraint (checked against the bindings by tests/test_compiled_implicit.py)
EQUALITY, FRICTION_DOF, FRICTION_TENDON, LIMIT_JOINT, LIMIT_TENDON = 0, 1, 2, 3, 4
CONTACT_FRICTIONLESS, CONTACT_PYRAMIDAL, CONTACT_ELLIPTIC = 5, 6, 7
TRN_JOINT, BIAS_AFFINE = 0, 1
"""MuJoCo's ``mjTRN_JOINT`` and ``mjBIAS_AFFINE`` (checked against the bindings by tests/test_compiled_implicit.py)."""


# --- this step's constraints, linearized ---------------------------------------------------------------
@njit(**JIT)
def row_zones(nv, sparse, efc, qacc, prev, use_prev, zones):
    """``zones`` (nefc,) := each constraint row's zone at the accelerations ``qacc`` (nv,), for the rows of ``efc``
    (MjData's ``efc_J``, ``efc_J_rowadr``, ``efc_J_rownnz``, ``efc_J_colind``, ``efc_type``, ``efc_id``,
    ``efc_D``, ``efc_aref``, ``efc_frictionloss`` and more: :data:`rft_mujoco.compiled.implicit_eval.EFC_FIELDS`), as
    :func:`rft_mujoco.coupling.reference.constraint_zones`: 0 none, 1 quadratic, 2 / 3 a saturated dry friction
    at +/- its bound. A row's zone is that of the force it would carry at ``qacc``, ``-D (J qacc - aref)``:
    equality rows quadratic; dry friction quadratic inside its bound, a constant force at it; limits and
    contacts quadratic while pushing; an elliptic contact's rows all quadratic while its first (normal) row is.
    With ``use_prev``, ``qacc`` was solved in the zones ``prev`` (nefc,): a dry friction saturated there stays
    saturated while its force keeps its sign and bound, and sticks (quadratic) otherwise."""
    efc_j, efc_rowadr, efc_rownnz, efc_colind, efc_type, efc_id, efc_d, efc_aref, efc_frictionloss = efc[:9]
    nefc = efc_type.shape[0]
    first = 0.0
    for e in range(nefc):
        a0 = efc_rowadr[e] if sparse else e * nv
        nnz = efc_rownnz[e] if sparse else nv
        acc = 0.0
        for a in range(a0, a0 + nnz):
            acc += efc_j[a] * qacc[efc_colind[a] if sparse else a - a0]
        est = -efc_d[e] * (acc - efc_aref[e])
        t = efc_type[e]
        z = 0
        if t == EQUALITY:
            z = 1
        elif t == FRICTION_DOF or t == FRICTION_TENDON:
            fl = efc_frictionloss[e]
            if use_prev and prev[e] >= 2:
                z = prev[e] if (est if prev[e] == 2 else -est) >= fl else 1
            elif abs(est) < fl:
                z = 1
            elif est > 0.0:
                z = 2
            elif est < 0.0:
                z = 3
        elif t == LIMIT_JOINT or t == LIMIT_TENDON or t == CONTACT_FRICTIONLESS or t == CONTACT_PYRAMIDAL:
            z = 1 if est > 0.0 else 0
        elif t == CONTACT_ELLIPTIC:
            if e == 0 or efc_type[e - 1] != CONTACT_ELLIPTIC or efc_id[e - 1] != efc_id[e]:
                first = est
            z = 1 if first > 0.0 else 0
        zones[e] = z


@njit(**JIT)
def constrained_system(nv, mass, sparse, efc, zones, linearized, damping, dt, h, f):
    """``h`` (nv, nv) := ``M`` (``mass`` = (``M_rowadr``, ``M_rownnz``, ``M_colind``, MjData's ``M``): MuJoCo's CSR
    lower triangle) and, with ``linearized``,
    ``+ Jq^T D Jq + dt diag(damping)``; ``f`` (nv,) (the smooth force on entry) ``+= Jq^T D aref + Js^T f_s``:
    :func:`rft_mujoco.coupling.reference.constrained_free_motion` with the rows in their ``zones`` (nefc,)
    (:func:`row_zones`). Row i of the constraint Jacobian is dense (``efc_j[i nv:(i + 1) nv]``) or, with
    ``sparse``, CSR (``efc_rowadr``, ``efc_rownnz``, ``efc_colind``); ``efc`` as :func:`row_zones`'s."""
    m_rowadr, m_rownnz, m_colind, m_val = mass
    efc_j, efc_rowadr, efc_rownnz, efc_colind, _, _, efc_d, efc_aref, efc_frictionloss = efc[:9]
    nefc = efc_d.shape[0]
    for i in range(nv):
        for j in range(nv):
            h[i, j] = 0.0
    for i in range(nv):
        for a in range(m_rowadr[i], m_rowadr[i] + m_rownnz[i]):
            c = m_colind[a]
            h[i, c] = m_val[a]
            h[c, i] = m_val[a]
    if not linearized:
        return
    for i in range(nv):
        h[i, i] += dt * damping[i]
    for e in range(nefc):
        a0 = efc_rowadr[e] if sparse else e * nv
        nnz = efc_rownnz[e] if sparse else nv
        if zones[e] == 1:
            d = efc_d[e]
            da = d * efc_aref[e]
            for a in range(a0, a0 + nnz):
                x = efc_j[a]
                if x == 0.0:                          # dense rows are mostly zeros (a dof's friction, limit)
                    continue
                p = efc_colind[a] if sparse else a - a0
                f[p] += x * da
                dx = d * x
                for b in range(a0, a0 + nnz):
                    h[p, efc_colind[b] if sparse else b - a0] += dx * efc_j[b]
        elif zones[e] >= 2:
            const = efc_frictionloss[e] if zones[e] == 2 else -efc_frictionloss[e]
            for a in range(a0, a0 + nnz):
                f[efc_colind[a] if sparse else a - a0] += efc_j[a] * const


@njit(**JIT)
def end_acceleration(nv, low, jrows, ng, w, qacc0, out):
    """``out`` (nv,) := ``qacc0 + H^-1 J^T w``: the step's end accelerations under the groups' wrenches ``w``
    (ng, 6), for the lower Cholesky factor ``low`` of ``H`` and the groups' Jacobians ``jrows`` (6 ng, nv)."""
    for i in range(nv):
        s = 0.0
        for r in range(ng):
            for c in range(6):
                s += jrows[6 * r + c, i] * w[r, c]
        out[i] = s
    _cholesky_solve(nv, low, out)
    for i in range(nv):
        out[i] += qacc0[i]


@njit(**JIT)
def cholesky(n, h):
    """The lower Cholesky factor of ``h[:n, :n]`` in place (lower triangle); False when ``h`` is not
    positive definite (or not finite): the rest solve's factor (:func:`rft_mujoco.compiled.rest._cholesky`)
    without its pivot floor."""
    return _cholesky(n, h, 0.0)


@njit(**JIT)
def _forward(n, low, x):
    """``x[:n] <- L^-1 x[:n]`` (a contiguous row)."""
    for r in range(n):
        t = x[r]
        for c in range(r):
            t -= low[r, c] * x[c]
        x[r] = t / low[r, r]


@njit(**JIT)
def _forward4(n, low, x0, x1, x2, x3):
    """:func:`_forward` of four rows at once: the same operations per entry, in the same order (the same
    numbers), as four independent chains (one chain of dependent subtractions is latency-bound)."""
    for r in range(n):
        t0, t1, t2, t3 = x0[r], x1[r], x2[r], x3[r]
        for c in range(r):
            lrc = low[r, c]
            t0 -= lrc * x0[c]
            t1 -= lrc * x1[c]
            t2 -= lrc * x2[c]
            t3 -= lrc * x3[c]
        d = low[r, r]
        x0[r], x1[r], x2[r], x3[r] = t0 / d, t1 / d, t2 / d, t3 / d


@njit(**JIT)
def free_motion(groups, kinematics, tree, low, f, dt, out):
    """For the reference bodies (COMs) of the groups ``groups`` = (``ng``, ``active``, ``ids``, ``group_ref``), group
    r's body ``ids[group_ref[active[r]]]``: their Jacobians into ``jrows`` (6 ng, nv), twists now (``twist``
    (ng, 6)), free twists ``twist + dt J H^-1 f`` (``free``) and the mobility ``mob`` (6 ng, 6 ng)
    ``= J H^-1 J^T = Y^T Y``, ``Y = L^-1 J^T`` (``y`` (6 ng, nv): ``Y^T``, rows contiguous), for the lower
    Cholesky factor ``low`` of ``H``; ``out`` = (``jrows``, ``y``, ``twist``, ``free``, ``mob``). ``kinematics`` =
    MjData's (``xipos``, ``cdof``, ``subtree_com``, ``qvel``), ``tree`` = MjModel's (``body_rootid``,
    ``body_dofnum``, ``body_dofadr``, ``body_parentid``, ``dof_parentid``). ``f`` (nv,) is overwritten with
    ``H^-1 f``."""
    ng, active, ids, group_ref = groups
    xipos, cdof, subtree_com, qvel = kinematics
    jrows, y, twist, free, mob = out
    nv = qvel.shape[0]
    n6 = 6 * ng
    for r in range(ng):
        b = ids[group_ref[active[r]]]
        jacobian(b, xipos[b, 0], xipos[b, 1], xipos[b, 2], cdof, subtree_com, tree, jrows, 6 * r)
    _cholesky_solve(nv, low, f)               # f <- H^-1 f
    for r in range(ng):
        for c in range(6):
            row = 6 * r + c
            s0 = 0.0
            s1 = 0.0
            for i in range(nv):
                s0 += jrows[row, i] * qvel[i]
                s1 += jrows[row, i] * f[i]
            twist[r, c] = s0
            free[r, c] = s0 + dt * s1
    for col in range(n6):
        for i in range(nv):
            y[col, i] = jrows[col, i]
    col = 0
    while col + 4 <= n6:
        _forward4(nv, low, y[col], y[col + 1], y[col + 2], y[col + 3])
        col += 4
    for c in range(col, n6):
        _forward(nv, low, y[c])
    for p in range(n6):                       # mob[p, q] = y[p] . y[q], four q at a time (independent sums)
        yp = y[p]
        q = 0
        while q + 4 <= p + 1:
            y0, y1, y2, y3 = y[q], y[q + 1], y[q + 2], y[q + 3]
            s0 = s1 = s2 = s3 = 0.0
            for i in range(nv):
                x = yp[i]
                s0 += x * y0[i]
                s1 += x * y1[i]
                s2 += x * y2[i]
                s3 += x * y3[i]
            mob[p, q], mob[p, q + 1], mob[p, q + 2], mob[p, q + 3] = s0, s1, s2, s3
            mob[q, p], mob[q + 1, p], mob[q + 2, p], mob[q + 3, p] = s0, s1, s2, s3
            q += 4
        for qq in range(q, p + 1):
            yq = y[qq]
            s = 0.0
            for i in range(nv):
                s += yp[i] * yq[i]
            mob[p, qq] = s
            mob[qq, p] = s


@njit(**JIT)
def velocity_damping(implicit_integrator, dof_damping, jnt_dofadr, trntype, trnid, biastype, biasprm, gear, out):
    """:func:`rft_mujoco.coupling.reference.velocity_damping` into ``out`` (nv,): joint damping plus each
    affine joint actuator's ``-biasprm[2] gear^2`` (N s/m, N m s/rad) with an implicit integrator, else
    zeros."""
    for i in range(out.shape[0]):
        out[i] = dof_damping[i] if implicit_integrator else 0.0
    if not implicit_integrator:
        return
    for a in range(trntype.shape[0]):
        if trntype[a] == TRN_JOINT and biastype[a] == BIAS_AFFINE:
            out[jnt_dofadr[trnid[a, 0]]] += -biasprm[a, 2] * gear[a, 0] ** 2
