"""The rest solve of the batched sand (float64; :func:`rft_mujoco.physics.rest.rest_wrenches`,
:func:`rft_mujoco.physics.rest.pivoted_solve` and the coupling's share of a group's wrench among its bodies),
one thread per world, and the diagnostics of the evaluation."""

from __future__ import annotations

import warp as wp

from rft_mujoco.warp.common import (CAPACITY_TOL, DEPENDENT_TOL, F64, NOT_FINITE, TINY, WEIGHT_FLOOR, cholesky, norm6,
                                    sv32, sv64)


@wp.func
def flow_factor(h: F64, q: F64):
    """rest.flow_factor."""
    if h >= F64(0.0):
        return F64(0.0)
    if q <= F64(0.0):
        return F64(1.0)
    return wp.min(F64(1.0), -h / q)


@wp.func
def pivoted_factor(w: int, a: wp.array3d(dtype=F64), idx: wp.array2d(dtype=int), m: int,
                   weight: wp.array2d(dtype=F64), diag0: wp.array2d(dtype=F64), rem: wp.array2d(dtype=F64),
                   order: wp.array2d(dtype=int), kept: wp.array2d(dtype=int), low: wp.array3d(dtype=F64),
                   gram: wp.array3d(dtype=F64)):
    """rest.pivoted_factor of the matrix a[idx, idx, w] (the first m rows of idx[:, w]): the kept rows in
    ``order[:k, w]``, the Cholesky factor of B D B^T in ``gram``; returns k."""
    for i in range(m):
        d = a[idx[i, w], idx[i, w], w]
        diag0[i, w] = d
        rem[i, w] = d
        kept[i, w] = 0
    k = int(0)
    while k < m:
        p = int(-1)
        best = F64(DEPENDENT_TOL)
        for i in range(m):
            if kept[i, w] == 0 and diag0[i, w] > TINY and rem[i, w] > best * diag0[i, w]:
                best = rem[i, w] / diag0[i, w]
                p = i
        if p < 0:
            break
        kept[p, w] = 1
        order[k, w] = p
        piv = wp.sqrt(rem[p, w])
        for i in range(m):
            if kept[i, w] == 1 and i != p:
                continue
            t = a[idx[i, w], idx[p, w], w]
            for j in range(k):
                t -= low[i, j, w] * low[p, j, w]
            low[i, k, w] = t / piv
        for i in range(m):
            if kept[i, w] == 0:
                rem[i, w] = rem[i, w] - low[i, k, w] * low[i, k, w]
        k += 1
    for r in range(k):                              # B D B^T, B = a[order[:k], :]
        ir = idx[order[r, w], w]
        for c in range(r + 1):
            ic = idx[order[c, w], w]
            t = F64(0.0)
            for j in range(m):
                ij = idx[j, w]
                t += a[ir, ij, w] * weight[j, w] * a[ic, ij, w]
            gram[r, c, w] = t
    cholesky(w, gram, k)
    return k


@wp.func
def pivoted_apply(w: int, a: wp.array3d(dtype=F64), idx: wp.array2d(dtype=int), m: int, k: int,
                  rhs: wp.array2d(dtype=F64), weight: wp.array2d(dtype=F64), order: wp.array2d(dtype=int),
                  gram: wp.array3d(dtype=F64), y: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64)):
    """rest.pivoted_apply: x[:m, w] from rhs[:m, w] and :func:`pivoted_factor`'s (k, order, gram)."""
    for j in range(m):
        x[j, w] = F64(0.0)
    if k == 0:
        return
    for r in range(k):
        t = rhs[order[r, w], w]
        for c in range(r):
            t -= gram[r, c, w] * y[c, w]
        y[r, w] = t / gram[r, r, w]
    for rr in range(k):
        r = k - 1 - rr
        t = y[r, w]
        for c in range(r + 1, k):
            t -= gram[c, r, w] * y[c, w]
        y[r, w] = t / gram[r, r, w]
    for j in range(m):
        ij = idx[j, w]
        t = F64(0.0)
        for r in range(k):
            t += a[idx[order[r, w], w], ij, w] * y[r, w]
        x[j, w] = weight[j, w] * t


@wp.func
def group_sums(w: int, nb: int, slot: wp.array2d(dtype=int), wrench: wp.array2d(dtype=wp.spatial_vector),
               arm: wp.array2d(dtype=wp.vec3d), n6: int, rft_g: wp.array2d(dtype=F64)):
    """rft_g[6 r:6 r + 6, w] := the bodies' wrenches summed about their group's reference point (N, N m)."""
    for i in range(n6):
        rft_g[i, w] = F64(0.0)
    for b in range(nb):
        r = slot[b, w]
        if r < 0:
            continue
        f = sv64(wrench[w, b])
        fl = wp.vec3d(f[0], f[1], f[2])
        tq = wp.vec3d(f[3], f[4], f[5]) + wp.cross(arm[b, w], fl)
        for c in range(3):
            rft_g[6 * r + c, w] = rft_g[6 * r + c, w] + fl[c]
            rft_g[6 * r + 3 + c, w] = rft_g[6 * r + 3 + c, w] + tq[c]


@wp.func
def share(w: int, ng: int, nb: int, slot: wp.array2d(dtype=int), active: wp.array2d(dtype=int),
          group_radius: wp.array(dtype=F64), wrench: wp.array2d(dtype=wp.spatial_vector),
          arm: wp.array2d(dtype=wp.vec3d), rft_g: wp.array2d(dtype=F64), wv: wp.array2d(dtype=F64),
          rest_flag: wp.array2d(dtype=int), size: wp.array2d(dtype=F64), total: wp.array2d(dtype=F64),
          sand: wp.array2d(dtype=wp.spatial_vector)):
    """Each touching body's part of its group's applied wrench ``wv`` (N, N m about the reference point;
    coupling._share): a flowing group's bodies their own wrench scaled as the group's, a resting group's force
    and moment shared by the size of the bodies' wrenches."""
    for r in range(ng):
        total[r, w] = F64(0.0)
    for b in range(nb):
        r = slot[b, w]
        if r < 0:
            continue
        size[b, w] = norm6(sv64(wrench[w, b]), group_radius[active[r, w]])
        total[r, w] = total[r, w] + size[b, w]
    for b in range(nb):
        r = slot[b, w]
        if r < 0 or total[r, w] <= F64(0.0):
            continue
        o = 6 * r
        rad = group_radius[active[r, w]]
        if rest_flag[r, w] == 0:
            gw = wp.spatial_vectord(rft_g[o, w], rft_g[o + 1, w], rft_g[o + 2, w], rft_g[o + 3, w],
                                    rft_g[o + 4, w], rft_g[o + 5, w])
            aw = wp.spatial_vectord(wv[o, w], wv[o + 1, w], wv[o + 2, w], wv[o + 3, w], wv[o + 4, w],
                                    wv[o + 5, w])
            gn = norm6(gw, rad)
            ff = F64(0.0)
            if gn > F64(0.0):
                ff = norm6(aw, rad) / gn
            sand[w, b] = sv32(sv64(wrench[w, b]) * ff)
        else:
            part = size[b, w] / total[r, w]
            sand[w, b] = sv32(wp.spatial_vectord(part * wv[o, w], part * wv[o + 1, w], part * wv[o + 2, w],
                                                 F64(0.0), F64(0.0), F64(0.0)))
    for r in range(ng):
        if rest_flag[r, w] == 0 or total[r, w] <= F64(0.0):
            continue
        o = 6 * r
        mom = wp.vec3d(wv[o + 3, w], wv[o + 4, w], wv[o + 5, w])
        for b in range(nb):
            if slot[b, w] == r:
                sb = sand[w, b]
                mom = mom - wp.cross(arm[b, w], wp.vec3d(F64(sb[0]), F64(sb[1]), F64(sb[2])))
        for b in range(nb):
            if slot[b, w] == r:
                part = size[b, w] / total[r, w]
                sb = sand[w, b]
                sand[w, b] = wp.spatial_vector(sb[0], sb[1], sb[2], float(part * mom[0]),
                                               float(part * mom[1]), float(part * mom[2]))


@wp.func
def commit_diagnostics(w: int, nb: int, stabilize: int, touch: wp.array2d(dtype=int),
                       bound_radius: wp.array(dtype=F64), wrench: wp.array2d(dtype=wp.spatial_vector),
                       slot: wp.array2d(dtype=int), rest_flag: wp.array2d(dtype=int),
                       sand: wp.array2d(dtype=wp.spatial_vector), scale: wp.array2d(dtype=float),
                       resting: wp.array2d(dtype=int), status: wp.array(dtype=int), errors: wp.array(dtype=int)):
    """The diagnostics and the status of the evaluation (SandHandle._commit); a non-finite wrench sets
    NOT_FINITE and the world gets no sand."""
    st = int(0)
    for b in range(nb):
        if touch[w, b] == 0:
            continue
        rb = bound_radius[b]
        rn = norm6(sv64(wrench[w, b]), rb)
        sb = sand[w, b]
        if rn > F64(0.0):
            scale[w, b] = float(norm6(sv64(sb), rb) / rn)
            if stabilize != 0:
                resting[w, b] = rest_flag[slot[b, w], w]
        for c in range(6):
            if not wp.isfinite(sb[c]):
                st = -1
            elif sb[c] != 0.0 and st == 0:
                st = 1
    if st < 0:
        errors[w] = errors[w] | NOT_FINITE
        for b in range(nb):
            sand[w, b] = wp.spatial_vector()
        st = 0
    status[w] = st


@wp.kernel
def rest_solve(
        stabilize: int, passive: int, body_group: wp.array(dtype=int), group_radius: wp.array(dtype=F64),
        bound_radius: wp.array(dtype=F64),
        # from the earlier kernels
        ngroups: wp.array(dtype=int), active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
        touch: wp.array2d(dtype=int), wrench: wp.array2d(dtype=wp.spatial_vector), count: wp.array2d(dtype=int),
        vs: wp.array2d(dtype=F64), a: wp.array3d(dtype=F64), u: wp.array2d(dtype=F64),
        arm: wp.array2d(dtype=wp.vec3d), v_lin: wp.array2d(dtype=wp.vec3), v_ang: wp.array2d(dtype=wp.vec3),
        # work
        rft_g: wp.array2d(dtype=F64), cap: wp.array2d(dtype=F64), capacity: wp.array2d(dtype=F64),
        rest_flag: wp.array2d(dtype=int), flow: wp.array2d(dtype=int), wv: wp.array2d(dtype=F64),
        idx: wp.array2d(dtype=int), rhs: wp.array2d(dtype=F64), weight: wp.array2d(dtype=F64),
        x: wp.array2d(dtype=F64), diag0: wp.array2d(dtype=F64), rem: wp.array2d(dtype=F64),
        order: wp.array2d(dtype=int), kept: wp.array2d(dtype=int), low: wp.array3d(dtype=F64),
        gram: wp.array3d(dtype=F64), y: wp.array2d(dtype=F64), size: wp.array2d(dtype=F64),
        total: wp.array2d(dtype=F64),
        # outputs
        sand: wp.array2d(dtype=wp.spatial_vector), rft: wp.array2d(dtype=wp.spatial_vector),
        scale: wp.array2d(dtype=float), resting: wp.array2d(dtype=int), status: wp.array(dtype=int),
        errors: wp.array(dtype=int)):
    """One thread per world: the applied wrench of every attached body (``sand``, about its COM) from its
    RFT wrench (``wrench``), and the diagnostics (SandHandle._evaluate_rest / _evaluate_naive, _commit)."""
    w = wp.tid()
    nb = touch.shape[1]
    ng = ngroups[w]
    for b in range(nb):
        sand[w, b] = wp.spatial_vector()
        rft[w, b] = wrench[w, b]
        scale[w, b] = 1.0
        resting[w, b] = 0
    status[w] = 0
    if stabilize != 0 and ng == 0:
        return
    if stabilize == 0:
        for b in range(nb):
            if touch[w, b] == 0:
                continue
            f = sv64(wrench[w, b])
            if passive != 0:
                vl = v_lin[w, b]
                va = v_ang[w, b]
                power = (f[0] * F64(vl[0]) + f[1] * F64(vl[1]) + f[2] * F64(vl[2]) + f[3] * F64(va[0])
                         + f[4] * F64(va[1]) + f[5] * F64(va[2]))
                if power > F64(0.0):
                    f = wp.spatial_vectord()
            sand[w, b] = sv32(f)
    else:
        # the groups' RFT wrenches about their reference points
        n6 = 6 * ng
        group_sums(w, nb, slot, wrench, arm, n6, rft_g)
        # rest.rest_wrenches in scaled coordinates: twists (v, R w), wrenches (f, tau / R)
        for r in range(ng):
            rad = group_radius[active[r, w]]
            nonzero = int(0)
            dsum = F64(0.0)
            for c in range(6):
                xc = rft_g[6 * r + c, w]
                if c >= 3:
                    xc = xc / rad
                cap[6 * r + c, w] = xc
                if xc != F64(0.0):
                    nonzero = 1
                dsum -= rft_g[6 * r + c, w] * u[6 * r + c, w]
            capacity[r, w] = wp.max(dsum, F64(0.0))
            rest_flag[r, w] = nonzero
            flow[r, w] = 0
        again = int(1)
        while again == 1:
            for r in range(ng):
                for c in range(6):
                    wv[6 * r + c, w] = F64(0.0)
                if flow[r, w] != 0:
                    h = F64(0.0)
                    q = F64(0.0)
                    for c in range(6):
                        h += cap[6 * r + c, w] * vs[6 * r + c, w]
                        t = F64(0.0)
                        for e in range(6):
                            t += a[6 * r + c, 6 * r + e, w] * cap[6 * r + e, w]
                        q += cap[6 * r + c, w] * t
                    ff = flow_factor(h, q)
                    for c in range(6):
                        wv[6 * r + c, w] = ff * cap[6 * r + c, w]
            m = int(0)
            for r in range(ng):
                if rest_flag[r, w] != 0:
                    for c in range(6):
                        idx[m, w] = 6 * r + c
                        m += 1
            over = int(0)
            if m > 0:
                top = F64(0.0)
                for i in range(m):
                    ii = idx[i, w]
                    s = vs[ii, w]
                    for j in range(n6):
                        s += a[ii, j, w] * wv[j, w]
                    rhs[i, w] = s
                    gi = ii // 6
                    t = F64(0.0)
                    for c in range(6):
                        t += cap[6 * gi + c, w] * cap[6 * gi + c, w]
                    weight[i, w] = t
                    top = wp.max(top, t)
                for i in range(m):
                    weight[i, w] = wp.max(weight[i, w], WEIGHT_FLOOR * top)
                k = pivoted_factor(w, a, idx, m, weight, diag0, rem, order, kept, low, gram)
                pivoted_apply(w, a, idx, m, k, rhs, weight, order, gram, y, x)
                for i in range(m):
                    wv[idx[i, w], w] = -x[i, w]
                for r in range(ng):
                    if rest_flag[r, w] != 0:
                        rad = group_radius[active[r, w]]
                        demand = F64(0.0)
                        for c in range(6):
                            sc = F64(1.0)
                            if c >= 3:
                                sc = rad
                            demand -= wv[6 * r + c, w] * u[6 * r + c, w] * sc
                        if demand > capacity[r, w] * (F64(1.0) + CAPACITY_TOL):
                            rest_flag[r, w] = 0
                            flow[r, w] = 1
                            over = 1
            again = over
        # passivity of the whole impulse (rest.passive_scale)
        h = F64(0.0)
        q = F64(0.0)
        for i in range(n6):
            h += wv[i, w] * vs[i, w]
            t = F64(0.0)
            for j in range(n6):
                t += a[i, j, w] * wv[j, w]
            q += wv[i, w] * t
        pscale = F64(1.0)
        if h + F64(0.5) * q > F64(0.0):
            pscale = F64(0.0)
            if h < F64(0.0):
                pscale = flow_factor(h, q)
        for r in range(ng):
            rad = group_radius[active[r, w]]
            for c in range(6):
                sc = pscale
                if c >= 3:
                    sc = pscale * rad
                wv[6 * r + c, w] = wv[6 * r + c, w] * sc
        share(w, ng, nb, slot, active, group_radius, wrench, arm, rft_g, wv, rest_flag, size, total, sand)
    commit_diagnostics(w, nb, stabilize, touch, bound_radius, wrench, slot, rest_flag, sand, scale, resting, status,
                       errors)
