"""This step's constraint rows, linearized in their zones (float64), one thread per world: the ports of
:func:`rft_mujoco.coupling.reference.constraint_zones` and of the rows' part of
:func:`rft_mujoco.coupling.reference.constrained_free_motion`.

MuJoCo Warp keeps the rows of each world in ``d.efc``: ``type``, ``id``, ``frictionloss``, ``aref`` (nworld, njmax),
``D`` (nworld, njmax_pad), all float32, and ``J`` dense (nworld, njmax_pad, nv_pad) or, for a sparse model
(``m.is_sparse``), (nworld, 1, njmax_nnz) with ``J_rownnz``, ``J_rowadr`` (nworld, njmax) and ``J_colind``
(nworld, 1, njmax_nnz). Rows ``i < nefc`` (at most njmax) are this step's; their order may differ from MuJoCo C's,
but the rows of one contact are contiguous (normal first). A row in its quadratic zone acts as the force
``-D (J qacc - aref)``, a saturated dry-friction row as a constant force, an inactive row not at all.
"""

from __future__ import annotations

import mujoco
import warp as wp

from rft_mujoco.warp.common import F64

_C = mujoco.mjtConstraint
EQUALITY = wp.constant(int(_C.mjCNSTR_EQUALITY))
FRICTION_DOF = wp.constant(int(_C.mjCNSTR_FRICTION_DOF))
FRICTION_TENDON = wp.constant(int(_C.mjCNSTR_FRICTION_TENDON))
LIMIT_JOINT = wp.constant(int(_C.mjCNSTR_LIMIT_JOINT))
LIMIT_TENDON = wp.constant(int(_C.mjCNSTR_LIMIT_TENDON))
CONTACT_FRICTIONLESS = wp.constant(int(_C.mjCNSTR_CONTACT_FRICTIONLESS))
CONTACT_PYRAMIDAL = wp.constant(int(_C.mjCNSTR_CONTACT_PYRAMIDAL))
CONTACT_ELLIPTIC = wp.constant(int(_C.mjCNSTR_CONTACT_ELLIPTIC))
"""Constraint types (``mujoco.mjtConstraint``; MuJoCo Warp's ``ConstraintType`` has the same values)."""


@wp.func
def _row_dot(w: int, i: int, efc_J: wp.array3d(dtype=float), J_rownnz: wp.array2d(dtype=int),
             J_rowadr: wp.array2d(dtype=int), J_colind: wp.array3d(dtype=int), sparse: int, nv: int,
             x: wp.array3d(dtype=F64)) -> F64:
    """J_i x[0, :nv, w] of row i of world w (dense or sparse layout)."""
    s = F64(0.0)
    if sparse != 0:
        adr = J_rowadr[w, i]
        for k in range(J_rownnz[w, i]):
            s += F64(efc_J[w, 0, adr + k]) * x[0, J_colind[w, 0, adr + k], w]
    else:
        for k in range(nv):
            jk = efc_J[w, i, k]
            if jk != 0.0:
                s += F64(jk) * x[0, k, w]
    return s


@wp.func
def row_zones(w: int, nefc: int, efc_type: wp.array2d(dtype=int), efc_id: wp.array2d(dtype=int),
              efc_D: wp.array2d(dtype=float), efc_aref: wp.array2d(dtype=float),
              efc_frictionloss: wp.array2d(dtype=float), efc_J: wp.array3d(dtype=float),
              J_rownnz: wp.array2d(dtype=int), J_rowadr: wp.array2d(dtype=int), J_colind: wp.array3d(dtype=int),
              sparse: int, nv: int, qacc: wp.array3d(dtype=F64), use_prev: int,
              quad: wp.array2d(dtype=int), const: wp.array2d(dtype=F64), est: wp.array2d(dtype=F64)) -> int:
    """The zone of each constraint row i < nefc of world w at the accelerations ``qacc[0, :nv, w]`` (m/s^2,
    rad/s^2): ``quad[i, w]`` 1 in the quadratic zone, else 0; ``const[i, w]`` the constant force of a saturated
    dry-friction row (N or N m), else 0 (``reference.constraint_zones``). ``est[i, w]`` (work) := the row's force
    in its quadratic zone, ``-D (J qacc - aref)`` (N or N m). Equality rows quadratic; dry friction quadratic
    inside its bound, ``sign(est) frictionloss`` at it; limits and contacts quadratic while pushing (est > 0);
    all rows of an elliptic contact take the flag of its first (normal) row.

    ``use_prev != 0``: ``quad``/``const`` on entry are the zones ``qacc`` was solved in; a friction row saturated
    there stays saturated only while ``sign(const) est >= frictionloss`` (the slip goes on), else it sticks.
    Returns 1 when a row's zone differs from the one on entry (always 1 with ``use_prev == 0``)."""
    n = wp.min(nefc, efc_type.shape[1])
    changed = int(0)
    head = int(0)               # the quadratic flag of the elliptic contact being read
    for i in range(n):
        t = efc_type[w, i]
        e = -F64(efc_D[w, i]) * (_row_dot(w, i, efc_J, J_rownnz, J_rowadr, J_colind, sparse, nv, qacc)
                                 - F64(efc_aref[w, i]))
        est[i, w] = e
        q = int(0)
        c = F64(0.0)
        if t == EQUALITY:
            q = 1
        elif t == FRICTION_DOF or t == FRICTION_TENDON:
            fl = F64(efc_frictionloss[w, i])
            p = const[i, w]
            if use_prev != 0 and p != F64(0.0):
                s = e
                if p < F64(0.0):
                    s = -e
                if s >= fl:
                    c = p
                else:
                    q = 1
            elif wp.abs(e) < fl:
                q = 1
            elif e > F64(0.0):
                c = fl
            else:
                c = -fl
        elif t == LIMIT_JOINT or t == LIMIT_TENDON or t == CONTACT_FRICTIONLESS or t == CONTACT_PYRAMIDAL:
            if e > F64(0.0):
                q = 1
        elif t == CONTACT_ELLIPTIC:
            first = int(1)
            if i > 0:
                if efc_type[w, i - 1] == CONTACT_ELLIPTIC and efc_id[w, i - 1] == efc_id[w, i]:
                    first = 0
            if first == 1:
                head = 0
                if e > F64(0.0):
                    head = 1
            q = head
        if use_prev != 0 and (q != quad[i, w] or c != const[i, w]):
            changed = 1
        quad[i, w] = q
        const[i, w] = c
    if use_prev == 0:
        changed = 1
    return changed


@wp.func
def add_rows(w: int, nefc: int, efc_D: wp.array2d(dtype=float), efc_aref: wp.array2d(dtype=float),
             efc_J: wp.array3d(dtype=float), J_rownnz: wp.array2d(dtype=int), J_rowadr: wp.array2d(dtype=int),
             J_colind: wp.array3d(dtype=int), sparse: int, nv: int,
             quad: wp.array2d(dtype=int), const: wp.array2d(dtype=F64),
             h: wp.array3d(dtype=F64), f: wp.array3d(dtype=F64)):
    """The rows i < nefc of world w in their zones (``quad``, ``const``: :func:`row_zones`):
    ``h[:nv, :nv, w] += Jq^T diag(Dq) Jq`` into its lower triangle only (j <= i; kg, kg m, kg m^2) and
    ``f[0, :nv, w] += Jq^T (Dq aref_q) + J^T const`` (N, N m), accumulated in float64."""
    n = wp.min(nefc, efc_aref.shape[1])
    for i in range(n):
        qi = quad[i, w]
        ci = const[i, w]
        if qi == 0 and ci == F64(0.0):
            continue
        d = F64(0.0)
        s = ci                                  # the row's force in f: D aref (quadratic) + const
        if qi != 0:
            d = F64(efc_D[w, i])
            s = s + d * F64(efc_aref[w, i])
        if sparse != 0:
            adr = J_rowadr[w, i]
            nnz = J_rownnz[w, i]
            for k in range(nnz):
                jk = F64(efc_J[w, 0, adr + k])
                ck = J_colind[w, 0, adr + k]
                f[0, ck, w] = f[0, ck, w] + jk * s
                if qi != 0:
                    djk = d * jk
                    for l in range(nnz):
                        cl = J_colind[w, 0, adr + l]
                        if cl <= ck:
                            h[ck, cl, w] = h[ck, cl, w] + djk * F64(efc_J[w, 0, adr + l])
        else:
            for k in range(nv):
                j32 = efc_J[w, i, k]
                if j32 == 0.0:
                    continue
                jk = F64(j32)
                f[0, k, w] = f[0, k, w] + jk * s
                if qi != 0:
                    djk = d * jk
                    for l in range(k + 1):
                        jl = efc_J[w, i, l]
                        if jl != 0.0:
                            h[k, l, w] = h[k, l, w] + djk * F64(jl)
