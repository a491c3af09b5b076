"""The implicit sand solve on the batched sand (``rft_mujoco.warp.attach(solve="implicit")``, float64, one thread per
world): :func:`rft_mujoco.physics.implicit.implicit_wrenches` (backward Euler on the regularized law, the resting
groups held inside it) and :func:`rft_mujoco.coupling.reference.implicit_free` (this step's constraint rows
linearized in their zones, or MuJoCo's last constraint forces with ``constraints="lagged"``), with the zone
passes of :func:`rft_mujoco.coupling.reference.evaluate_implicit`.

Launch order (:meth:`rft_mujoco.warp.handle.WarpSandHandle._evaluate_implicit`), after the explicit path's
``user_part``, ``touch_pass``, ``near_occluders`` and MuJoCo Warp's ``fwd_actuation``::

    candidates      (nworld, E)  the submerged, unculled elements; the occluded area
    for each zone pass (ZONE_PASSES with "linearized", 1 with "lagged"):
      implicit_free  (nworld,)   [pass > 0: the zones at the end accelerations; unchanged -> done] free motion
                                 through H = M + Jq^T D Jq (+ dt damping), mobility, the probe twists
      law_pass       (nworld, E) the law at the probe twists (the capacity test)
      implicit_solve (nworld,)   the rest / Newton loop
    final_twists    (nworld,)    each body's motion: the probe (resting groups) or the end twist (flowing)
    law_pass        (nworld, E)  the bodies' law wrenches there
    implicit_finish (nworld,)    the share among the bodies, diagnostics, the flowing groups for the next step

A world whose zones no longer change (``done``) skips the later passes; every launch happens every evaluation
(graph-safe).
"""

from __future__ import annotations

import warp as wp

from rft_mujoco.physics import implicit as _implicit
from rft_mujoco.warp.common import CAPACITY_TOL, F64, TINY, WEIGHT_FLOOR, sv32
from rft_mujoco.warp.implicit_law import SPEED_SCALE, Law, group_law
from rft_mujoco.warp.rest import (commit_diagnostics, flow_factor, group_sums, pivoted_apply, pivoted_factor,
                                  share)
from rft_mujoco.warp.twists import com_motion

wp.set_module_options({"enable_backward": False})      # forward only: no adjoints to compile

NEWTON_ITERATIONS = wp.constant(_implicit.NEWTON_ITERATIONS)
NEWTON_RTOL = wp.constant(F64(_implicit.NEWTON_RTOL))
REST_RETRY = wp.constant(F64(_implicit.REST_RETRY))
ZONE_PASSES = _implicit.ZONE_PASSES


@wp.func
def _radius_scale(w: int, i: int, active: wp.array2d(dtype=int), group_radius: wp.array(dtype=F64)):
    """The scale of row i of the stacked twists (1 for velocities, the group's radius for rotations)."""
    if i % 6 >= 3:
        return group_radius[active[i // 6, w]]
    return F64(1.0)


@wp.func
def lu_solve(w: int, mat: wp.array3d(dtype=F64), n: int, x: wp.array2d(dtype=F64)):
    """x[:n, w] := mat[:n, :n, w]^-1 x[:n, w] by LU with partial pivoting, the row swaps applied to x as they are
    made (mat overwritten; np.linalg.solve)."""
    for c in range(n):
        p = c
        best = wp.abs(mat[c, c, w])
        for r in range(c + 1, n):
            if wp.abs(mat[r, c, w]) > best:
                best = wp.abs(mat[r, c, w])
                p = r
        if p != c:
            for j in range(n):
                t = mat[c, j, w]
                mat[c, j, w] = mat[p, j, w]
                mat[p, j, w] = t
            t = x[c, w]
            x[c, w] = x[p, w]
            x[p, w] = t
        d = mat[c, c, w]
        if wp.abs(d) <= TINY:
            d = TINY
            mat[c, c, w] = d
        for r in range(c + 1, n):
            f = mat[r, c, w] / d
            mat[r, c, w] = f
            for j in range(c + 1, n):
                mat[r, j, w] = mat[r, j, w] - f * mat[c, j, w]
            x[r, w] = x[r, w] - f * x[c, w]
    for cc in range(n):
        c = n - 1 - cc
        t = x[c, w]
        for j in range(c + 1, n):
            t -= mat[c, j, w] * x[j, w]
        x[c, w] = t / mat[c, c, w]


@wp.struct
class Work:
    """The float64 work arrays of one world's solve (rows: the stacked twists of the touching groups)."""

    cap: wp.array2d(dtype=F64)
    uprobe: wp.array2d(dtype=F64)
    capacity: wp.array2d(dtype=F64)
    flow: wp.array2d(dtype=int)
    untried: wp.array2d(dtype=int)
    wall: wp.array2d(dtype=F64)
    ridx: wp.array2d(dtype=int)
    fidx: wp.array2d(dtype=int)
    weight: wp.array2d(dtype=F64)
    diag0: wp.array2d(dtype=F64)
    rem: wp.array2d(dtype=F64)
    order: wp.array2d(dtype=int)
    kept: wp.array2d(dtype=int)
    low: wp.array3d(dtype=F64)
    gram: wp.array3d(dtype=F64)
    y: wp.array2d(dtype=F64)
    x: wp.array2d(dtype=F64)
    rhs: wp.array2d(dtype=F64)
    aeff: wp.array3d(dtype=F64)
    veff: wp.array2d(dtype=F64)
    wvec: wp.array2d(dtype=F64)
    uf: wp.array2d(dtype=F64)
    wf: wp.array2d(dtype=F64)
    res: wp.array2d(dtype=F64)
    step: wp.array2d(dtype=F64)
    ufull: wp.array2d(dtype=F64)
    lw: wp.array2d(dtype=F64)
    lj: wp.array3d(dtype=F64)
    blocks: wp.array3d(dtype=F64)
    mat: wp.array3d(dtype=F64)


@wp.func
def _law(w: int, kf: int, ng: int, lw_: Law, wk: Work, active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
         group_radius: wp.array(dtype=F64)):
    """wk.wf[:kf] := the law's scaled wrench at the flowing rows' scaled twists wk.ufull (and wk.lj its
    derivative blocks)."""
    group_law(w, lw_, wk.flow, slot, active, 6 * ng, group_radius, wk.ufull, wk.lw, wk.lj)
    for i in range(kf):
        wk.wf[i, w] = wk.lw[wk.fidx[i, w], w]


@wp.func
def _residual(w: int, kf: int, wk: Work, u: wp.array2d(dtype=F64), out: wp.array2d(dtype=F64)):
    """out[:kf] := u - v_eff - a_eff wf; returns |out|^2."""
    nrm = F64(0.0)
    for i in range(kf):
        t = u[i, w] - wk.veff[i, w]
        for j in range(kf):
            t -= wk.aeff[i, j, w] * wk.wf[j, w]
        out[i, w] = t
        nrm += t * t
    return nrm


@wp.func
def _wrench_change(w: int, kf: int, wk: Work):
    """implicit.wrench_change(blocks, res, wf)."""
    top = F64(0.0)
    change = F64(0.0)
    for i in range(kf):
        top = wp.max(top, wp.abs(wk.wf[i, w]))
        o = i - i % 6
        t = F64(0.0)
        for j in range(6):
            t += wk.blocks[wk.fidx[i, w], j, w] * wk.res[o + j, w]
        change = wp.max(change, wp.abs(t))
    if top > F64(0.0):
        return change / top
    return F64(1.0e300)


@wp.func
def newton_flow(w: int, kf: int, ng: int, lw_: Law, wk: Work, active: wp.array2d(dtype=int),
                slot: wp.array2d(dtype=int), group_radius: wp.array(dtype=F64)):
    """implicit._newton_flow: Newton's method on ``u - v_eff - a_eff F(u) = 0`` from wk.uf (the flowing rows'
    scaled twists); the answer in wk.uf, its wrenches in wk.wf."""
    for i in range(kf):
        wk.ufull[wk.fidx[i, w], w] = wk.uf[i, w]
    _law(w, kf, ng, lw_, wk, active, slot, group_radius)
    _residual(w, kf, wk, wk.uf, wk.res)
    top0 = F64(0.0)
    for i in range(kf):
        top0 = wp.max(top0, wp.abs(wk.veff[i, w] - wk.uf[i, w]))
    scale = wp.max(top0, SPEED_SCALE) * NEWTON_RTOL
    have_blocks = int(0)
    for _it in range(NEWTON_ITERATIONS):
        top = F64(0.0)
        for i in range(kf):
            top = wp.max(top, wp.abs(wk.res[i, w]))
        if top <= SPEED_SCALE * NEWTON_RTOL:
            break
        if top <= scale and have_blocks == 1:
            if _wrench_change(w, kf, wk) <= NEWTON_RTOL:
                break
        for i in range(kf):                       # the law's slope where this step starts
            for j in range(6):
                wk.blocks[wk.fidx[i, w], j, w] = wk.lj[wk.fidx[i, w], j, w]
        have_blocks = 1
        for i in range(kf):                       # (I - a_eff J) step = -res
            for j in range(kf):
                o = j - j % 6
                t = F64(0.0)
                for l in range(6):
                    t += wk.aeff[i, o + l, w] * wk.lj[wk.fidx[o + l, w], j % 6, w]
                d = F64(0.0)
                if i == j:
                    d = F64(1.0)
                wk.mat[i, j, w] = d - t
            wk.step[i, w] = -wk.res[i, w]
        lu_solve(w, wk.mat, kf, wk.step)
        norm0 = F64(0.0)
        for i in range(kf):
            norm0 += wk.res[i, w] * wk.res[i, w]
        t = F64(1.0)
        while t > F64(1.0e-3):
            for i in range(kf):
                wk.ufull[wk.fidx[i, w], w] = wk.uf[i, w] + t * wk.step[i, w]
            _law(w, kf, ng, lw_, wk, active, slot, group_radius)
            for i in range(kf):
                wk.x[i, w] = wk.ufull[wk.fidx[i, w], w]
            if _residual(w, kf, wk, wk.x, wk.rhs) < norm0:
                break
            t *= F64(0.5)
        for i in range(kf):                       # the accepted try, or the last one
            wk.uf[i, w] = wk.x[i, w]
            wk.res[i, w] = wk.rhs[i, w]


@wp.func
def _eliminate_rest(w: int, m: int, k: int, kf: int, a: wp.array3d(dtype=F64), vs: wp.array2d(dtype=F64),
                    wk: Work):
    """a_eff = A_FF - A_FR P A_RF and v_eff = v_F - A_FR P v_R (P: the rest operator of the m resting rows)."""
    for j in range(kf + 1):
        fj = int(0)
        if j < kf:
            fj = wk.fidx[j, w]
        for i in range(m):
            if j < kf:
                wk.rhs[i, w] = a[wk.ridx[i, w], fj, w]
            else:
                wk.rhs[i, w] = vs[wk.ridx[i, w], w]
        pivoted_apply(w, a, wk.ridx, m, k, wk.rhs, wk.weight, wk.order, wk.gram, wk.y, wk.x)
        for i in range(kf):
            fi = wk.fidx[i, w]
            t = F64(0.0)
            if j < kf:
                t = a[fi, fj, w]
            else:
                t = vs[fi, w]
            for r in range(m):
                t -= a[fi, wk.ridx[r, w], w] * wk.x[r, w]
            if j < kf:
                wk.aeff[i, j, w] = t
            else:
                wk.veff[i, w] = t


@wp.func
def _probe(w: int, ng: int, nb: int, slot: wp.array2d(dtype=int), active: wp.array2d(dtype=int),
           group_radius: wp.array(dtype=F64), probe_wrench: wp.array2d(dtype=wp.spatial_vectord),
           arm: wp.array2d(dtype=wp.vec3d), u: wp.array2d(dtype=F64), wk: Work):
    """The capacity test's quantities at the probe twists ``u``: scaled wrenches wk.cap, scaled twists wk.uprobe,
    capacities, weights; returns nothing (rest flags by the caller)."""
    for i in range(6 * ng):
        wk.cap[i, w] = F64(0.0)
    for b in range(nb):
        r = slot[b, w]
        if r < 0:
            continue
        f = probe_wrench[w, b]
        fl = wp.vec3d(f[0], f[1], f[2])
        tq = wp.vec3d(f[3], f[4], f[5]) + wp.cross(arm[b, w], fl)
        for c in range(3):
            wk.cap[6 * r + c, w] = wk.cap[6 * r + c, w] + fl[c]
            wk.cap[6 * r + 3 + c, w] = wk.cap[6 * r + 3 + c, w] + tq[c]
    for r in range(ng):
        rad = group_radius[active[r, w]]
        cpt = F64(0.0)
        wsum = F64(0.0)
        for c in range(6):
            i = 6 * r + c
            if c >= 3:
                wk.cap[i, w] = wk.cap[i, w] / rad
                wk.uprobe[i, w] = u[i, w] * rad
            else:
                wk.uprobe[i, w] = u[i, w]
            cpt -= wk.cap[i, w] * wk.uprobe[i, w]
            wsum += wk.cap[i, w] * wk.cap[i, w]
        wk.capacity[r, w] = cpt
        wk.wall[r, w] = wsum


@wp.func
def _rest_factor(w: int, ng: int, rest: wp.array2d(dtype=int), a: wp.array3d(dtype=F64), wk: Work):
    """The resting rows (wk.ridx), the flowing rows (wk.fidx), the weights and the rest operator's factor;
    returns (m, k, kf)."""
    m = int(0)
    kf = int(0)
    top = F64(0.0)
    for r in range(ng):
        for c in range(6):
            if rest[r, w] != 0:
                wk.ridx[m, w] = 6 * r + c
                wk.weight[m, w] = wk.wall[r, w]
                top = wp.max(top, wk.wall[r, w])
                m += 1
            elif wk.flow[r, w] != 0:
                wk.fidx[kf, w] = 6 * r + c
                kf += 1
    for i in range(m):
        wk.weight[i, w] = wp.max(wk.weight[i, w], WEIGHT_FLOOR * top)
    k = int(0)
    if m > 0:
        k = pivoted_factor(w, a, wk.ridx, m, wk.weight, wk.diag0, wk.rem, wk.order, wk.kept, wk.low, wk.gram)
    return m, k, kf


@wp.kernel
def implicit_solve(
        pass_index: int, done: wp.array(dtype=int), ngroups: wp.array(dtype=int), use_prior: wp.array(dtype=int),
        prior_flow: wp.array2d(dtype=int), active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
        group_radius: wp.array(dtype=F64), a: wp.array3d(dtype=F64), vs: wp.array2d(dtype=F64),
        u: wp.array2d(dtype=F64), twist: wp.array2d(dtype=F64), start: wp.array2d(dtype=F64),
        probe_wrench: wp.array2d(dtype=wp.spatial_vectord), arm: wp.array2d(dtype=wp.vec3d), lw_: Law, wk: Work,
        rest: wp.array2d(dtype=int), applied: wp.array2d(dtype=F64), endt: wp.array2d(dtype=F64)):
    """One thread per world: implicit.implicit_wrenches. Outputs the applied wrenches (``applied``, N and N m about
    the reference points), the resting groups and the end-of-step twists (``endt``, m/s and rad/s)."""
    w = wp.tid()
    if done[w] != 0:
        return
    ng = ngroups[w]
    n6 = 6 * ng
    nb = slot.shape[0]
    _probe(w, ng, nb, slot, active, group_radius, probe_wrench, arm, u, wk)
    for r in range(ng):
        nz = int(0)
        for c in range(6):
            if wk.cap[6 * r + c, w] != F64(0.0):
                nz = 1
        rest[r, w] = nz
        wk.flow[r, w] = 0
        if nz == 1 and use_prior[w] != 0 and prior_flow[active[r, w], w] == 1:
            wk.flow[r, w] = 1
            rest[r, w] = 0
        wk.untried[r, w] = wk.flow[r, w]
    for _round in range(2 * ng + 2):             # each retry moves a group for good (implicit_wrenches' loop)
        m, k, kf = _rest_factor(w, ng, rest, a, wk)
        for i in range(n6):
            wk.wvec[i, w] = F64(0.0)
        again = int(0)
        if kf > 0:
            _eliminate_rest(w, m, k, kf, a, vs, wk)
            for i in range(kf):
                fi = wk.fidx[i, w]
                base = twist[fi, w]
                if pass_index > 0:
                    base = start[fi, w]
                wk.uf[i, w] = base * _radius_scale(w, fi, active, group_radius)
            newton_flow(w, kf, ng, lw_, wk, active, slot, group_radius)
            for i in range(kf):
                wk.wvec[wk.fidx[i, w], w] = wk.wf[i, w]
            for i in range(0, kf, 6):
                r = wk.fidx[i, w] // 6
                speed = (wp.length(wp.vec3d(wk.uf[i, w], wk.uf[i + 1, w], wk.uf[i + 2, w]))
                         + wp.length(wp.vec3d(wk.uf[i + 3, w], wk.uf[i + 4, w], wk.uf[i + 5, w])))
                if wk.untried[r, w] != 0 and speed < REST_RETRY * SPEED_SCALE:
                    wk.untried[r, w] = 0
                    wk.flow[r, w] = 0
                    rest[r, w] = 1
                    again = 1
        if again == 0 and m > 0:
            for i in range(m):
                t = vs[wk.ridx[i, w], w]
                for j in range(kf):
                    t += a[wk.ridx[i, w], wk.fidx[j, w], w] * wk.wvec[wk.fidx[j, w], w]
                wk.rhs[i, w] = t
            pivoted_apply(w, a, wk.ridx, m, k, wk.rhs, wk.weight, wk.order, wk.gram, wk.y, wk.x)
            for i in range(m):
                wk.wvec[wk.ridx[i, w], w] = -wk.x[i, w]
            for r in range(ng):
                if rest[r, w] == 0:
                    continue
                demand = F64(0.0)
                for c in range(6):
                    demand -= wk.wvec[6 * r + c, w] * wk.uprobe[6 * r + c, w]
                if demand > wp.max(wk.capacity[r, w], F64(0.0)) * (F64(1.0) + CAPACITY_TOL):
                    rest[r, w] = 0
                    wk.flow[r, w] = 1
                    again = 1
        if again == 0:
            break
    h = F64(0.0)                                  # rest.passive_scale
    q = F64(0.0)
    for i in range(n6):
        h += wk.wvec[i, w] * vs[i, w]
        t = F64(0.0)
        for j in range(n6):
            t += a[i, j, w] * wk.wvec[j, w]
        q += wk.wvec[i, w] * t
    pscale = F64(1.0)
    if h + F64(0.5) * q > F64(0.0):
        pscale = F64(0.0)
        if h < F64(0.0):
            pscale = flow_factor(h, q)
    for i in range(n6):
        wk.wvec[i, w] = wk.wvec[i, w] * pscale
    for i in range(n6):
        t = vs[i, w]
        for j in range(n6):
            t += a[i, j, w] * wk.wvec[j, w]
        s = _radius_scale(w, i, active, group_radius)
        endt[i, w] = t / s
        applied[i, w] = wk.wvec[i, w] * s


@wp.kernel
def final_twists(ngroups: wp.array(dtype=int), slot: wp.array2d(dtype=int), active: wp.array2d(dtype=int),
                 body_id: wp.array(dtype=int), group_ref: wp.array(dtype=int), xipos: wp.array2d(dtype=wp.vec3),
                 rest: wp.array2d(dtype=int), u: wp.array2d(dtype=F64), endt: wp.array2d(dtype=F64),
                 arm: wp.array2d(dtype=wp.vec3d), v_lin: wp.array2d(dtype=wp.vec3d),
                 v_ang: wp.array2d(dtype=wp.vec3d), redo: wp.array2d(dtype=int),
                 law_wrench: wp.array2d(dtype=wp.spatial_vectord), count: wp.array2d(dtype=int),
                 max_depth: wp.array2d(dtype=float)):
    """Each touching body's motion at its COM for its final law wrench (reference.evaluate_implicit): a flowing
    group's end-of-step twist (``redo[w, b]`` := 1, its law wrench, count and depth zeroed for the law pass); a
    resting group's is its probe twist, whose wrench the last probe pass left in ``law_wrench`` (``redo`` 0)."""
    w = wp.tid()
    for b in range(body_id.shape[0]):
        redo[w, b] = 0
        r = slot[b, w]
        if r < 0 or ngroups[w] == 0:
            continue
        if rest[r, w] == 0:
            redo[w, b] = 1
            law_wrench[w, b] = wp.spatial_vectord()
            count[w, b] = 0
            max_depth[w, b] = 0.0
            lin, om = com_motion(w, b, r, body_id, group_ref, active, xipos, endt, arm)
            v_lin[w, b] = lin
            v_ang[w, b] = om


@wp.kernel
def implicit_finish(ngroups: wp.array(dtype=int), active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
                    group_radius: wp.array(dtype=F64), bound_radius: wp.array(dtype=F64),
                    touch: wp.array2d(dtype=int), law_wrench: wp.array2d(dtype=wp.spatial_vectord),
                    arm: wp.array2d(dtype=wp.vec3d), rest: wp.array2d(dtype=int), applied: wp.array2d(dtype=F64),
                    prior_flow: wp.array2d(dtype=int), wrench: wp.array2d(dtype=wp.spatial_vector),
                    rft_g: wp.array2d(dtype=F64), size: wp.array2d(dtype=F64), total: wp.array2d(dtype=F64),
                    sand: wp.array2d(dtype=wp.spatial_vector), rft: wp.array2d(dtype=wp.spatial_vector),
                    scale: wp.array2d(dtype=float), resting: wp.array2d(dtype=int), status: wp.array(dtype=int),
                    errors: wp.array(dtype=int)):
    """One thread per world: the bodies' parts of their groups' applied wrenches (coupling._share, on the law
    wrenches at the final twists), the diagnostics, and the groups that flowed (the next evaluation starts them
    in flow when it follows this one; as on the CPU path, an evaluation where no group touches leaves them)."""
    w = wp.tid()
    nb = slot.shape[0]
    ng = ngroups[w]
    if ng > 0:                                   # an evaluation with no touching group keeps the last one's
        for g in range(prior_flow.shape[0]):
            prior_flow[g, w] = -1
    for b in range(nb):
        wrench[w, b] = wp.spatial_vector()
        if slot[b, w] >= 0:
            wrench[w, b] = sv32(law_wrench[w, b])
        sand[w, b] = wp.spatial_vector()
        rft[w, b] = wrench[w, b]
        scale[w, b] = 1.0
        resting[w, b] = 0
    status[w] = 0
    if ng == 0:
        return
    for r in range(ng):
        prior_flow[active[r, w], w] = 1 - rest[r, w]
    group_sums(w, nb, slot, wrench, arm, 6 * ng, rft_g)
    share(w, ng, nb, slot, active, group_radius, wrench, arm, rft_g, applied, rest, size, total, sand)
    commit_diagnostics(w, nb, 1, touch, bound_radius, wrench, slot, rest, sand, scale, resting, status, errors)
