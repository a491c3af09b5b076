"""The implicit sand solve compiled: this step's constraints linearized, backward Euler on the regularized law.

Pure array functions (nothing here calls MuJoCo), the same algorithms as the numpy reference
(tests/test_compiled_implicit.py compares them):

* the system of this step's constraints, linearized, and the groups' free motion through it:
  :mod:`rft_mujoco.compiled.system`;
* :func:`implicit_wrenches`: :func:`rft_mujoco.physics.implicit.implicit_wrenches` with its Newton flow
  solve (:func:`_newton_flow`) and its rest operator (:func:`rft_mujoco.physics.rest.pivoted_factor` as the
  explicit rest solve runs it, vectorized and bit for bit: :func:`rft_mujoco.compiled.rest.min_norm_factor`,
  and ``min_norm_apply`` on the vectors the operator meets instead of forming it), the law being
  :func:`rft_mujoco.compiled.implicit_law.group_law` on the evaluation's elements (the tuple ``lw``,
  :data:`LAW_FIELDS`).

``st``: the solve's settings (:data:`SETTINGS`), passed at run time (numba would freeze module globals).
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.implicit_law import DERIVATIVE_OF_LAST, LAW, group_law
from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.compiled.rest import blend, min_norm_apply, min_norm_factor

SETTINGS = sc.IMPLICIT_SETTINGS
"""Entries of ``st`` (:data:`rft_mujoco.compiled.schema.IMPLICIT_SETTINGS`, indexed as ``st[sc.ST_TINY]``)."""
LAW_FIELDS = ("bodies", "els", "lawc", "work")
"""The ``lw`` tuple: the ``law`` argument of :func:`rft_mujoco.compiled.implicit_law.group_law`, fixed within one
evaluation: the bodies (``k``, ``slot``, ``arm``), the elements (``implicit_law.ELEMENTS``), the law's constants
(``implicit_law.LAW_CONSTANTS``) and the bodies' work space and outputs (``implicit_law.BODY_WORK``)."""
SOLVE_WORK = ("sv", "sw", "v", "u_probe", "w", "x", "col", "pv", "v_eff", "u_flow", "rhs", "weight", "wf", "res",
              "step", "u_try", "wf_try", "res_try", "capacity", "weight_all", "full", "a", "block", "pa", "a_eff",
              "mat", "lin", "jac", "r_idx", "f_idx", "perm", "groups", "flow", "untried", "on")
"""The ``work`` bundle of :func:`solve_from_probe` (:func:`solve_work`): every buffer the solve writes, views of three
arenas the handle keeps per MjData (``iw``'s ``sf``, ``si``, ``sb``: :func:`arena_sizes`), each cut to the size
the groups touching now need; the solve allocates nothing. In order: 18 vectors of up to 6 G (the scaled
coordinates' scales, free twists, probe and wrenches; the rest operator's and the Newton solve's vectors), 2 of G
(capacities, weights), ``full`` (G, 6), 5 matrices of up to (6 G)^2 (the scaled mobility, the rest block, P a_rf,
the flowing system, Newton's matrix), ``lin`` (:func:`rft_mujoco.compiled.rest.min_norm_factor`'s), ``jac`` (G, 6,
6); int: ``r_idx``, ``f_idx`` (6 G), ``perm`` (12 G), ``groups`` (G); bool: ``flow``, ``untried``, ``on`` (G)."""
_VECTORS, _MATRICES = 18, 5
_ON = SOLVE_WORK.index("on")
"""The position of ``on`` in :data:`SOLVE_WORK` (the one buffer :func:`implicit_wrenches` reads by itself)."""


def arena_sizes(n_groups: int) -> tuple[int, int, int]:
    """The lengths of the float, int and bool arenas of :data:`SOLVE_WORK` for ``n_groups`` groups."""
    g = max(int(n_groups), 1)
    n = 6 * g
    return _VECTORS * n + 2 * g + 6 * g + _MATRICES * n * n + (3 * n + 5) * n + 36 * g, 4 * n + g, 3 * g


@njit(**JIT)
def _cut(buf, o, k):
    """``buf[o:o + k]`` and the next offset."""
    return buf[o:o + k], o + k


@njit(**JIT)
def solve_work(sf, si, sb, ng):
    """:data:`SOLVE_WORK` for ``ng`` groups: views of the arenas ``sf`` (float), ``si`` (int), ``sb`` (bool)."""
    n = 6 * ng
    o = 0
    sv, o = _cut(sf, o, n)
    sw, o = _cut(sf, o, n)
    v, o = _cut(sf, o, n)
    u_probe, o = _cut(sf, o, n)
    w, o = _cut(sf, o, n)
    x, o = _cut(sf, o, n)
    col, o = _cut(sf, o, n)
    pv, o = _cut(sf, o, n)
    v_eff, o = _cut(sf, o, n)
    u_flow, o = _cut(sf, o, n)
    rhs, o = _cut(sf, o, n)
    weight, o = _cut(sf, o, n)
    wf, o = _cut(sf, o, n)
    res, o = _cut(sf, o, n)
    step, o = _cut(sf, o, n)
    u_try, o = _cut(sf, o, n)
    wf_try, o = _cut(sf, o, n)
    res_try, o = _cut(sf, o, n)
    capacity, o = _cut(sf, o, ng)
    weight_all, o = _cut(sf, o, ng)
    full, o = _cut(sf, o, 6 * ng)
    a, o = _cut(sf, o, n * n)
    block, o = _cut(sf, o, n * n)
    pa, o = _cut(sf, o, n * n)
    a_eff, o = _cut(sf, o, n * n)
    mat, o = _cut(sf, o, n * n)
    lin, o = _cut(sf, o, (3 * n + 5) * n)
    jac, o = _cut(sf, o, 36 * ng)
    r_idx, o = _cut(si, 0, n)
    f_idx, o = _cut(si, o, n)
    perm, o = _cut(si, o, 2 * n)
    groups, o = _cut(si, o, ng)
    flow, o = _cut(sb, 0, ng)
    untried, o = _cut(sb, o, ng)
    on, o = _cut(sb, o, ng)
    return (sv, sw, v, u_probe, w, x, col, pv, v_eff, u_flow, rhs, weight, wf, res, step, u_try, wf_try, res_try,
            capacity, weight_all, full.reshape((ng, 6)), a.reshape((n, n)), block, pa, a_eff, mat,
            lin.reshape((3 * n + 5, n)), jac, r_idx, f_idx, perm, groups, flow, untried, on)

def settings() -> np.ndarray:
    """``st`` (:data:`SETTINGS`) from the reference modules' constants now."""
    from rft_mujoco import tol
    from rft_mujoco.physics import elements, implicit, rest
    values = dict(speed_scale=implicit.SPEED_SCALE, rest_retry=implicit.REST_RETRY,
                  newton_iterations=implicit.NEWTON_ITERATIONS, newton_rtol=implicit.NEWTON_RTOL,
                  fd_step=elements.FD_STEP, dependent_tol=rest.DEPENDENT_TOL, weight_floor=rest.WEIGHT_FLOOR,
                  capacity_tol=rest.CAPACITY_TOL, tiny=tol.TINY, zone_passes=implicit.ZONE_PASSES)
    return np.array([values[name] for name in SETTINGS], dtype=np.float64)


# --- the solve --------------------------------------------------------------------------------------------
@njit(**JIT)
def _law(lw, u, groups_on, ng, st, derivative, f, df):
    """:func:`rft_mujoco.compiled.implicit_law.group_law` with the fixed arguments of ``lw``."""
    group_law(u, groups_on, ng, lw, st[sc.ST_SPEED_SCALE], st[sc.ST_FD_STEP], derivative, f, df)


@njit(**JIT)
def lu_solve(n, a, b):
    """``b <- a^-1 b`` for ``a[:n, :n]`` (overwritten: Gaussian elimination with partial pivoting)."""
    for c in range(n):
        p = c
        best = abs(a[c, c])
        for r in range(c + 1, n):
            if abs(a[r, c]) > best:
                best = abs(a[r, c])
                p = r
        if p != c:
            for j in range(n):
                a[c, j], a[p, j] = a[p, j], a[c, j]
            b[c], b[p] = b[p], b[c]
        piv = a[c, c]
        for r in range(c + 1, n):
            m = a[r, c] / piv
            if m != 0.0:
                for j in range(c + 1, n):
                    a[r, j] -= m * a[c, j]
                b[r] -= m * b[c]
    for r in range(n - 1, -1, -1):
        t = b[r]
        for j in range(r + 1, n):
            t -= a[r, j] * b[j]
        b[r] = t / a[r, r]


@njit(**JIT)
def _flow_eval(lw, u, groups, ng, flow, sv, sw, st, full, f, df, wf):
    """The Newton solve's law: ``wf`` (6 k,) the flowing groups' scaled wrenches at scaled twists ``u`` (6 k,)
    (their twists, unscaled, in ``full``)."""
    kf = groups.shape[0]
    for g in range(ng):
        for c in range(6):
            full[g, c] = 0.0
    for i in range(kf):
        g = groups[i]
        for c in range(6):
            full[g, c] = u[6 * i + c] / sv[6 * g + c]
    _law(lw, full, flow, ng, st, LAW, f, df)
    for i in range(kf):
        g = groups[i]
        for a in range(6):
            wf[6 * i + a] = f[g, a] * sw[6 * g + a]


@njit(**JIT)
def _flow_jac(lw, groups, ng, flow, sv, sw, st, full, f, df, jac):
    """``jac`` (k, 6, 6): the scaled derivative blocks of the law :func:`_flow_eval` evaluated last (at ``full``)."""
    _law(lw, full, flow, ng, st, DERIVATIVE_OF_LAST, f, df)
    for i in range(groups.shape[0]):
        g = groups[i]
        for a in range(6):
            for b in range(6):
                jac[i, a, b] = sw[6 * g + a] * df[g, a, b] / sv[6 * g + b]


@njit(**JIT)
def _wrench_change(jac, du, wf, kf):
    """:func:`rft_mujoco.physics.implicit.wrench_change` with the blocks ``jac`` (k, 6, 6) and twists ``du``."""
    top, change = 0.0, 0.0
    for i in range(kf):
        for a in range(6):
            s = 0.0
            for b in range(6):
                s += jac[i, a, b] * du[6 * i + b]
            change = max(change, abs(s))
            top = max(top, abs(wf[6 * i + a]))
    return change / top if top > 0.0 else np.inf


@njit(**JIT)
def _newton_flow(lw, flow, ng, system, sv, sw, st, full, f, df, nw):
    """:func:`rft_mujoco.physics.implicit._newton_flow`: Newton's method on ``u - v_eff - a_eff F(u) = 0`` for
    the flowing groups (scaled coordinates), from ``u`` (overwritten with the answer). Returns the flowing
    groups' scaled wrenches and the iterations. The law's derivative is taken only at the points a step
    starts from (:data:`~rft_mujoco.compiled.implicit_law.DERIVATIVE_OF_LAST`), not at trial points of the
    line search nor at the answer: the iterates of a derivative at every evaluation, bit for bit. ``system`` =
    (``a_eff``, ``v_eff``, ``u``); ``nw``: its buffers (``groups``, ``wf``, ``jac``, ``res``, ``mat``, ``step``,
    ``u_try``, ``wf_try``, ``res_try`` of :data:`SOLVE_WORK`)."""
    a_eff, v_eff, u = system
    groups_buf, wf_buf, jac_buf, res_buf, mat_buf, step_buf, u_try_buf, wf_try_buf, res_try_buf = nw
    kf = 0
    for g in range(ng):
        if flow[g]:
            kf += 1
    groups = groups_buf[:kf]
    i = 0
    for g in range(ng):
        if flow[g]:
            groups[i] = g
            i += 1
    n = 6 * kf
    wf, res = wf_buf[:n], res_buf[:n]
    jac = jac_buf[:36 * kf].reshape((kf, 6, 6))
    _flow_eval(lw, u, groups, ng, flow, sv, sw, st, full, f, df, wf)
    scale = 0.0
    for p in range(n):
        res[p] = u[p] - v_eff[p]
        for q in range(n):
            res[p] -= a_eff[p, q] * wf[q]
        scale = max(scale, abs(v_eff[p] - u[p]))
    scale = max(scale, st[sc.ST_SPEED_SCALE]) * st[sc.ST_NEWTON_RTOL]
    floor = st[sc.ST_SPEED_SCALE] * st[sc.ST_NEWTON_RTOL]
    its = 0
    mat = mat_buf[:n * n].reshape((n, n))
    step, u_try, wf_try, res_try = step_buf[:n], u_try_buf[:n], wf_try_buf[:n], res_try_buf[:n]
    for it in range(1, int(st[sc.ST_NEWTON_ITERATIONS]) + 1):
        its = it
        top = 0.0
        for p in range(n):
            top = max(top, abs(res[p]))
        if top <= floor or (top <= scale and it > 1 and _wrench_change(jac, res, wf, kf) <= st[sc.ST_NEWTON_RTOL]):
            break                              # jac: the law's slope where the last step started
        _flow_jac(lw, groups, ng, flow, sv, sw, st, full, f, df, jac)   # the law evaluated last was at u
        for p in range(n):                     # I - a_eff J (J block diagonal)
            for i in range(kf):
                for b in range(6):
                    s = 0.0
                    for a in range(6):
                        s += a_eff[p, 6 * i + a] * jac[i, a, b]
                    mat[p, 6 * i + b] = -s
            mat[p, p] += 1.0
            step[p] = -res[p]
        lu_solve(n, mat, step)
        t = 1.0
        norm0 = 0.0
        for p in range(n):
            norm0 += res[p] * res[p]
        while t > 1e-3:
            for p in range(n):
                u_try[p] = u[p] + t * step[p]
            _flow_eval(lw, u_try, groups, ng, flow, sv, sw, st, full, f, df, wf_try)
            norm = 0.0
            for p in range(n):
                r = u_try[p] - v_eff[p]
                for q in range(n):
                    r -= a_eff[p, q] * wf_try[q]
                res_try[p] = r
                norm += r * r
            if norm < norm0:
                break
            t *= 0.5
        u[:] = u_try                           # the accepted step (or the last, shortest, one tried): the law
        wf[:] = wf_try                         # evaluated last
        res[:] = res_try
    return wf, its


@njit(**JIT)
def implicit_wrenches(system, lw, twist, flowing, prior, st, out, probe, f, df, work):
    """:func:`rft_mujoco.physics.implicit.implicit_wrenches` of groups 0..ng-1. ``system`` = (``free`` (ng, 6)
    m/s, rad/s, ``mob`` (6 ng, 6 ng), ``radius`` (ng,) m, ``dt`` s, ``ng``): the groups' free twists and
    mobility (:data:`SYSTEM`); ``twist`` (ng, 6) the twists now, ``flowing`` (ng,) bool the groups that flowed
    at the last evaluation (used with ``prior``), the law ``lw`` (:data:`LAW_FIELDS`). Outputs: ``out`` =
    (``w_out`` (ng, 6) wrenches (N, N m), ``rest`` (ng,) bool, ``end`` (ng, 6) end twists), ``probe`` (ng, 6)
    the blended twists of the capacity test, ``flowing`` (overwritten): the groups solved in flow at some
    point. ``f``, ``df``: the law's outputs; the rows of the groups never in flow (and their bodies' rows in
    ``lw``) hold the law at the probe. ``work``: :data:`SOLVE_WORK` (:func:`solve_work`). Returns the Newton
    iterations."""
    free, _, radius, _, ng = system
    blend(twist, free, radius, ng, probe)
    on = work[_ON]
    on[:] = True
    _law(lw, probe, on, ng, st, LAW, f, df)
    return solve_from_probe(system, lw, twist, flowing, prior, st, out, probe, f, df, True, work)


SYSTEM = ("free", "mob", "radius", "dt", "ng")
"""The ``system`` bundle of :func:`implicit_wrenches` and :func:`solve_from_probe`."""
NEED_ELEMENTS = -1
""":func:`solve_from_probe`: a group is to be solved in flow and ``lw`` does not hold the elements yet."""


@njit(**JIT)
def _scaled(free, mob, radius, dt, ng, out):
    """The solve's scaled coordinates (:func:`rft_mujoco.physics.rest._scales`) into ``out`` = (``sv``, ``sw``
    (6 ng,), the scaled ``a = dt S_v mob S_v`` (6 ng, 6 ng), ``v = S_v free`` (6 ng,)), which it returns."""
    n6 = 6 * ng
    sv, sw, a, v = out
    for g in range(ng):
        for c in range(6):
            sv[6 * g + c] = 1.0 if c < 3 else radius[g]
            sw[6 * g + c] = 1.0 if c < 3 else 1.0 / radius[g]
    for p in range(n6):
        v[p] = free[p // 6, p % 6] * sv[p]
        for q in range(n6):
            a[p, q] = dt * (sv[p] * mob[p, q] * sv[q])
    return sv, sw, a, v


@njit(**JIT)
def _capacities(f, probe, sv, sw, ng, prior, flowing, rest, flow, untried, out):
    """The capacity test's quantities of each group from the law ``f`` at the ``probe`` twists: ``capacity``
    (ng,) (the power the sand can take along the probe, scaled), ``weight_all`` (ng,) (the rest operator's
    weights) and ``u_probe`` (6 ng,) (the scaled probe). Sets ``rest`` (a group with sand under it), and with
    ``prior`` starts in flow (``flow``, ``untried``) the groups that flowed last (``flowing``, overwritten with
    ``flow``). ``out`` = (``capacity``, ``weight_all``, ``u_probe``): their buffers, returned."""
    capacity, weight_all, u_probe = out
    for g in range(ng):
        cp = 0.0
        wa = 0.0
        nz = False
        for c in range(6):
            x = f[g, c] * sw[6 * g + c]
            up = probe[g, c] * sv[6 * g + c]
            u_probe[6 * g + c] = up
            cp -= x * up
            wa += x * x
            nz = nz or x != 0.0
        capacity[g] = cp
        weight_all[g] = wa
        rest[g] = nz
        if prior and nz and flowing[g]:
            flow[g] = True
            rest[g] = False
            untried[g] = True
        flowing[g] = flow[g]                   # from here on: whether the group was solved in flow
    return capacity, weight_all, u_probe


@njit(**JIT)
def _indices(ng, rest, flow, r_buf, f_buf):
    """The scaled coordinates of the resting groups and of the flowing ones: ``r_idx`` (6 nr,), ``f_idx`` (6 nf,),
    the heads of the buffers ``r_buf``, ``f_buf`` (6 ng,)."""
    nr = 0
    nf = 0
    for g in range(ng):
        if rest[g]:
            nr += 1
        if flow[g]:
            nf += 1
    r_idx, f_idx = r_buf[:6 * nr], f_buf[:6 * nf]
    ir = jf = 0
    for g in range(ng):
        for c in range(6):
            if rest[g]:
                r_idx[ir] = 6 * g + c
                ir += 1
            if flow[g]:
                f_idx[jf] = 6 * g + c
                jf += 1
    return r_idx, f_idx


@njit(**JIT)
def _rest_factor(a, r_idx, weight_all, st, lin, perm, bufs):
    """The rest operator of the resting coordinates ``r_idx`` (:func:`rft_mujoco.physics.implicit.rest_operator`),
    factored by :func:`rft_mujoco.compiled.rest.min_norm_factor` into ``lin``, ``perm``: returns the block of
    ``a``, the capacity weights and the factor's rank, in the heads of ``bufs`` = (``block``, ``weight``)."""
    mr = r_idx.shape[0]
    block, weight = bufs[0][:mr * mr].reshape((mr, mr)), bufs[1][:mr]
    if mr == 0:
        return block, weight, 0
    top = 0.0
    for i in range(mr):
        weight[i] = weight_all[r_idx[i] // 6]
        top = max(top, weight[i])
    for i in range(mr):
        weight[i] = max(weight[i], st[sc.ST_WEIGHT_FLOOR] * top)
    for i in range(mr):
        for j in range(mr):
            block[i, j] = a[r_idx[i], r_idx[j]]
    return block, weight, min_norm_factor(block, weight, mr, st[sc.ST_DEPENDENT_TOL], st[sc.ST_TINY], lin, perm)


@njit(**JIT)
def _flow_system(a, v, r_idx, f_idx, start, sv, rest_op, bufs):
    """The flowing coordinates' system with the resting groups' wrenches following them, ``-P (v_r + a_rf w_f)``
    (P the rest operator ``rest_op`` = (block, weight, rank, lin, perm, x) applied to the vectors it meets rather
    than formed): ``a_eff``, ``v_eff`` and the Newton solve's start ``u_flow`` (scaled ``start`` rows), in the
    heads of ``bufs`` = (``pa``, ``col``, ``pv``, ``a_eff``, ``v_eff``, ``u_flow``)."""
    block, weight, kf, lin, perm, x = rest_op
    mr, mf = r_idx.shape[0], f_idx.shape[0]
    pa = bufs[0][:mr * mf].reshape((mr, mf))   # P a_rf
    pa[:] = 0.0
    col = bufs[1][:mr]
    for j in range(mf):
        if mr == 0:
            break
        for l in range(mr):
            col[l] = a[r_idx[l], f_idx[j]]
        min_norm_apply(block, col, weight, mr, kf, lin, perm, x)
        for l in range(mr):
            pa[l, j] = x[l]
    pv = bufs[2][:mr]                          # P v_r
    pv[:] = 0.0
    if mr:
        for l in range(mr):
            col[l] = v[r_idx[l]]
        min_norm_apply(block, col, weight, mr, kf, lin, perm, pv)
    a_eff, v_eff, u_flow = bufs[3][:mf * mf].reshape((mf, mf)), bufs[4][:mf], bufs[5][:mf]
    for i in range(mf):
        for j in range(mf):
            s = 0.0
            for l in range(mr):
                s += a[f_idx[i], r_idx[l]] * pa[l, j]
            a_eff[i, j] = a[f_idx[i], f_idx[j]] - s
        s = 0.0
        for l in range(mr):
            s += a[f_idx[i], r_idx[l]] * pv[l]
        v_eff[i] = v[f_idx[i]] - s
        u_flow[i] = start[f_idx[i] // 6, f_idx[i] % 6] * sv[f_idx[i]]
    return a_eff, v_eff, u_flow


@njit(**JIT)
def _passive_finish(w, v, a, sv, sw, end, w_out):
    """The passivity guard (:func:`rft_mujoco.physics.rest.passive_scale`) on the scaled wrenches ``w``, then the
    end twists ``end`` and the wrenches ``w_out`` (ng, 6) unscaled."""
    n6 = w.shape[0]
    hh = 0.0
    q = 0.0
    for i in range(n6):
        hh += w[i] * v[i]
        s = 0.0
        for j in range(n6):
            s += a[i, j] * w[j]
        q += w[i] * s
    scale = 1.0
    if hh + 0.5 * q > 0.0:
        scale = 0.0 if hh >= 0.0 else (1.0 if q <= 0.0 else min(1.0, -hh / q))
    for i in range(n6):
        w[i] *= scale
    for i in range(n6):
        s = v[i]
        for j in range(n6):
            s += a[i, j] * w[j]
        end[i // 6, i % 6] = s / sv[i]
        w_out[i // 6, i % 6] = w[i] / sw[i]


@njit(**JIT)
def solve_from_probe(system, lw, start, flowing, prior, st, out, probe, f, df, ready, work):
    """:func:`implicit_wrenches` from its capacity test on: ``probe`` (ng, 6) holds the blended twists
    (:func:`rft_mujoco.compiled.rest.blend`) and ``f`` (ng, 6) the groups' law at them; a flowing group's
    Newton solve starts from its row of ``start`` (ng, 6) (the twists now, or an earlier zone pass's answer).
    Without ``ready`` (``lw`` does
    not hold the evaluation's elements: the probe's law came from the element pass), returns
    :data:`NEED_ELEMENTS` before the first Newton solve, having written nothing but ``flowing`` (the caller
    restores it, fills ``lw`` and calls again with ``ready``); a solve that keeps every group at rest never needs
    them. ``system``, ``out``, ``work``: as :func:`implicit_wrenches`'s."""
    free, mob, radius, dt, ng = system
    w_out, rest, end = out
    (sv, sw, v, u_probe, w, x, col, pv, v_eff, u_flow, rhs_buf, weight, wf, res, step, u_try, wf_try, res_try,
     capacity, weight_all, full, a, block, pa, a_eff, mat, lin, jac, r_buf, f_buf, perm, groups, flow, untried,
     _) = work                                                                              # SOLVE_WORK
    n6, retry = 6 * ng, st[sc.ST_REST_RETRY] * st[sc.ST_SPEED_SCALE]
    _scaled(free, mob, radius, dt, ng, (sv, sw, a, v))
    flow[:] = False
    untried[:] = False
    _capacities(f, probe, sv, sw, ng, prior, flowing, rest, flow, untried, (capacity, weight_all, u_probe))
    w[:] = 0.0
    its = 0
    while True:
        r_idx, f_idx = _indices(ng, rest, flow, r_buf, f_buf)
        mr, mf = r_idx.shape[0], f_idx.shape[0]
        block_r, weight_r, kf = _rest_factor(a, r_idx, weight_all, st, lin, perm, (block, weight))
        for i in range(n6):
            w[i] = 0.0
        if mf and not ready:
            return NEED_ELEMENTS
        if mf:
            system_f = _flow_system(a, v, r_idx, f_idx, start, sv, (block_r, weight_r, kf, lin, perm, x),
                                    (pa, col, pv, a_eff, v_eff, u_flow))
            u_f = system_f[2]
            w_f, it = _newton_flow(lw, flow, ng, system_f, sv, sw, st, full, f, df,
                                   (groups, wf, jac, res, mat, step, u_try, wf_try, res_try))
            its += it
            for i in range(mf):
                w[f_idx[i]] = w_f[i]
            slow = False
            for i in range(mf // 6):           # a group started in flow that the step brings to (near) rest
                g = f_idx[6 * i] // 6
                sl = sa = 0.0
                for c in range(3):
                    sl += (u_f[6 * i + c] / sv[6 * g + c]) ** 2
                    sa += (u_f[6 * i + 3 + c] / sv[6 * g + 3 + c]) ** 2
                if untried[g] and math.sqrt(sl) + radius[g] * math.sqrt(sa) < retry:
                    untried[g] = False
                    flow[g] = False
                    rest[g] = True
                    slow = True
            if slow:
                continue
        if mr:
            rhs = rhs_buf[:mr]
            for i in range(mr):
                s = v[r_idx[i]]
                for j in range(mf):
                    s += a[r_idx[i], f_idx[j]] * w[f_idx[j]]
                rhs[i] = s
            min_norm_apply(block_r, rhs, weight_r, mr, kf, lin, perm, x)
            for i in range(mr):
                w[r_idx[i]] = -x[i]
            over = False
            for g in range(ng):
                if not rest[g]:
                    continue
                demand = 0.0
                for c in range(6):
                    demand -= w[6 * g + c] * u_probe[6 * g + c]
                if demand > max(capacity[g], 0.0) * (1.0 + st[sc.ST_CAPACITY_TOL]):
                    rest[g] = False
                    flow[g] = True
                    flowing[g] = True
                    over = True
            if over:
                continue
        break
    _passive_finish(w, v, a, sv, sw, end, w_out)
    return its
