"""The implicit solve's law, compiled: the regularized 3D-RFT wrench of each group and its derivative.

:func:`rft_mujoco.physics.elements.body_wrench_jacobians` (the reference, tests/test_fastimplicit.py) split in
two, because the implicit solve (:mod:`rft_mujoco.compiled.implicit`) evaluates the law again and again at one
pose within a step (its Newton iterations):

* :func:`loaded_candidates`: once per evaluation, the elements of the touching bodies that are submerged
  and not inside another body's geom (run-time culling), in the world frame: lever arm from the body's COM,
  normal, depth; and each body's submerged area inside occluders;
* :func:`body_law`: the regularized law at given body twists on those elements (moving and leading ones
  carry stress), with its derivative by forward differences per element (the leading set held), summed
  about each body's COM; :func:`group_law`: the same for groups' twists at their reference points.

The law itself is :func:`rft_mujoco.compiled.law._stress` (the explicit path's); the depth and the culling
tests are :func:`rft_mujoco.compiled.terrain._depth` and :func:`rft_mujoco.compiled.elements._inside`.
Nothing here calls MuJoCo.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.compiled.elements import _inside
from rft_mujoco.compiled.jit import JIT, JIT_LAW, njit
from rft_mujoco.compiled.law import _coef, _stress
from rft_mujoco.compiled.terrain import _depth


@njit(**JIT)
def loaded_candidates(touch, k, centroids, normals, areas, cluster_start, body_clusters, body_pos, body_mat,
                      body_com, g_hat, kind, tp, heights, occ_start, occ_geom, occ_kind, occ_size, occ_hs_start,
                      occ_hs, margin, geom_xpos, geom_xmat, e_slot, e_arm, e_nrm, e_depth, e_area, occluded):
    """The submerged, unculled elements of the bodies ``touch[:k]`` (packed layout of
    :func:`rft_mujoco.compiled.elements.pack`; body j's pose in rows j of ``body_pos`` (3), ``body_mat`` (9),
    ``body_com`` (3)), written to the front of ``e_slot`` (E,) int (the body row j), ``e_arm`` (E, 3) m (from
    the COM, world), ``e_nrm`` (E, 3) unit (world), ``e_depth`` (E,) m, ``e_area`` (E,) m^2; ``occluded`` (k,)
    m^2: the submerged area inside another body's geom (rows ``occ_start[b]:occ_start[b + 1]``). Returns
    their number."""
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    n_e = 0
    for j in range(k):
        b = touch[j]
        occluded[j] = 0.0
        r = body_mat[j]
        px, py, pz = body_pos[j, 0], body_pos[j, 1], body_pos[j, 2]
        cx, cy, cz = body_com[j, 0], body_com[j, 1], body_com[j, 2]
        for q in range(body_clusters[b], body_clusters[b + 1]):
            for i in range(cluster_start[q], cluster_start[q + 1]):
                l0, l1, l2 = centroids[0, i], centroids[1, i], centroids[2, i]
                if l0 != l0:                                   # a padding slot
                    continue
                x = px + (r[0] * l0 + r[1] * l1 + r[2] * l2)
                y = py + (r[3] * l0 + r[4] * l1 + r[5] * l2)
                z = pz + (r[6] * l0 + r[7] * l1 + r[8] * l2)
                d = _depth(x, y, z, g0, g1, g2, kind, tp, heights)
                if not d > 0.0:
                    continue
                hidden = False
                for o in range(occ_start[b], occ_start[b + 1]):
                    gid = occ_geom[o]
                    gm = geom_xmat[gid]
                    ex, ey, ez = x - geom_xpos[gid, 0], y - geom_xpos[gid, 1], z - geom_xpos[gid, 2]
                    if _inside(gm[0] * ex + gm[3] * ey + gm[6] * ez, gm[1] * ex + gm[4] * ey + gm[7] * ez,
                               gm[2] * ex + gm[5] * ey + gm[8] * ez, occ_kind[o], occ_size[o, 0], occ_size[o, 1],
                               occ_size[o, 2], occ_hs, occ_hs_start[o], occ_hs_start[o + 1], margin):
                        hidden = True
                        break
                if hidden:
                    occluded[j] += areas[i]
                    continue
                n0, n1, n2 = normals[0, i], normals[1, i], normals[2, i]
                e_slot[n_e] = j
                e_arm[n_e, 0] = x - cx
                e_arm[n_e, 1] = y - cy
                e_arm[n_e, 2] = z - cz
                e_nrm[n_e, 0] = r[0] * n0 + r[1] * n1 + r[2] * n2
                e_nrm[n_e, 1] = r[3] * n0 + r[4] * n1 + r[5] * n2
                e_nrm[n_e, 2] = r[6] * n0 + r[7] * n1 + r[8] * n2
                e_depth[n_e] = d
                e_area[n_e] = areas[i]
                n_e += 1
    return n_e


@njit(**JIT_LAW)
def body_law(n_e, e_slot, e_arm, e_nrm, e_depth, e_area, k, lin, ang, on, g_hat, xi_n, coef, mu_surf, no_tension,
             no_forward, no_power, tol, speed_scale, fd_step, derivative, wrench, jac, count, max_depth):
    """The regularized wrench of bodies 0..k-1 (rows of ``lin`` (3, m/s, the COM's velocity), ``ang`` (3,
    rad/s)) on the elements of :func:`loaded_candidates`, for the bodies with ``on[j]`` (others: zero).

    Each moving, leading element (speed above ``tol[2]``, ``n.v >= -tol[0] |v|``) carries the published
    stress at its direction times ``xi_n depth area phi(|v|)``, ``phi = |v| / sqrt(|v|^2 + c^2)``,
    ``c = speed_scale`` (m/s). Outputs rows 0..k-1: ``wrench`` (6: N, N m about the COM, world),
    ``count`` (loaded elements), ``max_depth`` (m); with ``derivative``, ``jac`` (6, 6) d wrench /
    d (lin, ang): per element the law's 3x3 derivative by forward differences (a step of ``fd_step`` times
    the element's speed or ``c``, whichever is larger), moved to the body twist through the lever arm."""
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    c = _coef(coef)
    lead_tol, vert_tol, zero_speed = tol[0], tol[1], tol[2]
    cc = speed_scale * speed_scale
    d = np.empty((3, 3))                         # d[i, m] = d f_i / d v_m of one element
    e_ = np.empty((3, 3))                        # [r]x D
    for j in range(k):
        count[j] = 0
        max_depth[j] = 0.0
        for a in range(6):
            wrench[j, a] = 0.0
            if derivative:
                for b in range(6):
                    jac[j, a, b] = 0.0
    for e in range(n_e):
        j = e_slot[e]
        if not on[j]:
            continue
        r0, r1, r2 = e_arm[e, 0], e_arm[e, 1], e_arm[e, 2]
        wx, wy, wz = ang[j, 0], ang[j, 1], ang[j, 2]
        vx = lin[j, 0] + (wy * r2 - wz * r1)
        vy = lin[j, 1] + (wz * r0 - wx * r2)
        vz = lin[j, 2] + (wx * r1 - wy * r0)
        sp = math.sqrt(vx * vx + vy * vy + vz * vz)
        if not sp > zero_speed:
            continue
        n0, n1, n2 = e_nrm[e, 0], e_nrm[e, 1], e_nrm[e, 2]
        if (n0 * vx + n1 * vy + n2 * vz) / sp < -lead_tol:
            continue
        sa = xi_n * (e_depth[e] * e_area[e])
        sx, sy, sz = _stress(n0, n1, n2, vx / sp, vy / sp, vz / sp, g0, g1, g2, c, mu_surf, no_tension, no_forward,
                             no_power, lead_tol, vert_tol)
        ph = sa * (sp / math.sqrt(sp * sp + cc))
        fx, fy, fz = sx * ph, sy * ph, sz * ph
        count[j] += 1
        max_depth[j] = max(max_depth[j], e_depth[e])
        wrench[j, 0] += fx
        wrench[j, 1] += fy
        wrench[j, 2] += fz
        wrench[j, 3] += r1 * fz - r2 * fy
        wrench[j, 4] += r2 * fx - r0 * fz
        wrench[j, 5] += r0 * fy - r1 * fx
        if not derivative:
            continue
        h = fd_step * max(sp, speed_scale)
        for m in range(3):
            ux = vx + (h if m == 0 else 0.0)
            uy = vy + (h if m == 1 else 0.0)
            uz = vz + (h if m == 2 else 0.0)
            s = math.sqrt(ux * ux + uy * uy + uz * uz)
            tx, ty, tz = _stress(n0, n1, n2, ux / s, uy / s, uz / s, g0, g1, g2, c, mu_surf, no_tension,
                                 no_forward, no_power, lead_tol, vert_tol)
            p = sa * (s / math.sqrt(s * s + cc))
            d[0, m] = (tx * p - fx) / h
            d[1, m] = (ty * p - fy) / h
            d[2, m] = (tz * p - fz) / h
        # element velocity v = lin - [r]x ang; its wrench (f, [r]x f): J = [[D, -D[r]x], [[r]x D, -[r]x D [r]x]]
        for m in range(3):
            e_[0, m] = r1 * d[2, m] - r2 * d[1, m]
            e_[1, m] = r2 * d[0, m] - r0 * d[2, m]
            e_[2, m] = r0 * d[1, m] - r1 * d[0, m]
        for i in range(3):
            # row i of X [r]x for X = D, [r]x D: (X[r]x)[i] = (x_i1 r2 - x_i2 r1, x_i2 r0 - x_i0 r2, x_i0 r1 - x_i1 r0)
            jac[j, i, 0] += d[i, 0]
            jac[j, i, 1] += d[i, 1]
            jac[j, i, 2] += d[i, 2]
            jac[j, i, 3] -= d[i, 1] * r2 - d[i, 2] * r1
            jac[j, i, 4] -= d[i, 2] * r0 - d[i, 0] * r2
            jac[j, i, 5] -= d[i, 0] * r1 - d[i, 1] * r0
            jac[j, 3 + i, 0] += e_[i, 0]
            jac[j, 3 + i, 1] += e_[i, 1]
            jac[j, 3 + i, 2] += e_[i, 2]
            jac[j, 3 + i, 3] -= e_[i, 1] * r2 - e_[i, 2] * r1
            jac[j, 3 + i, 4] -= e_[i, 2] * r0 - e_[i, 0] * r2
            jac[j, 3 + i, 5] -= e_[i, 0] * r1 - e_[i, 1] * r0


@njit(**JIT)
def group_law(u, groups_on, ng, k, slot, arm, n_e, e_slot, e_arm, e_nrm, e_depth, e_area, g_hat, xi_n, coef, mu_surf,
              no_tension, no_forward, no_power, tol, speed_scale, fd_step, derivative, lin, ang, on, wrench, jac,
              count, max_depth, f, df):
    """The law of :func:`body_law` for groups 0..ng-1 moving with twists ``u`` (ng, 6) at their reference
    points (m/s, rad/s), for the groups with ``groups_on[g]``: body j (of group ``slot[j]``, its COM at
    ``arm[j]`` (3, m) from the reference point) moves with ``(v + w x arm, w)``. Outputs: ``f`` (ng, 6) the
    groups' wrenches about their reference points (N, N m), with ``derivative`` ``df`` (ng, 6, 6) their
    derivative in ``u``; the bodies' own (``wrench``, ``jac``, ``count``, ``max_depth``) of :func:`body_law`.
    ``lin``, ``ang`` (k, 3) float and ``on`` (k,) bool: work space."""
    for j in range(k):
        g = slot[j]
        on[j] = groups_on[g]
        wx, wy, wz = u[g, 3], u[g, 4], u[g, 5]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
        lin[j, 0] = u[g, 0] + (wy * az - wz * ay)
        lin[j, 1] = u[g, 1] + (wz * ax - wx * az)
        lin[j, 2] = u[g, 2] + (wx * ay - wy * ax)
        ang[j, 0] = wx
        ang[j, 1] = wy
        ang[j, 2] = wz
    body_law(n_e, e_slot, e_arm, e_nrm, e_depth, e_area, k, lin, ang, on, g_hat, xi_n, coef, mu_surf, no_tension,
             no_forward, no_power, tol, speed_scale, fd_step, derivative, wrench, jac, count, max_depth)
    for g in range(ng):
        for a in range(6):
            f[g, a] = 0.0
            if derivative:
                for b in range(6):
                    df[g, a, b] = 0.0
    s = np.zeros((6, 6))                          # S: (v_com, w) = S (v_ref, w)
    t = np.empty((6, 6))
    for j in range(k):
        if not on[j]:
            continue
        g = slot[j]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
        fx, fy, fz = wrench[j, 0], wrench[j, 1], wrench[j, 2]
        f[g, 0] += fx                             # S^T w = (f, tau + arm x f)
        f[g, 1] += fy
        f[g, 2] += fz
        f[g, 3] += wrench[j, 3] + (ay * fz - az * fy)
        f[g, 4] += wrench[j, 4] + (az * fx - ax * fz)
        f[g, 5] += wrench[j, 5] + (ax * fy - ay * fx)
        if not derivative:
            continue
        for a in range(6):
            s[a, a] = 1.0
        s[0, 4], s[0, 5], s[1, 5] = az, -ay, ax
        s[1, 3], s[2, 3], s[2, 4] = -az, ay, -ax
        for a in range(6):                       # t = J S
            for b in range(6):
                x = 0.0
                for m in range(6):
                    x += jac[j, a, m] * s[m, b]
                t[a, b] = x
        for a in range(6):                       # df += S^T t
            for b in range(6):
                x = 0.0
                for m in range(6):
                    x += s[m, a] * t[m, b]
                df[g, a, b] += x
