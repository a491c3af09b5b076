"""The implicit solve's law, compiled: the regularized 3D-RFT wrench of each group and its derivative.

:func:`rft_mujoco.physics.elements.body_wrench_jacobians` (the reference, tests/test_compiled_implicit.py) split in
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

from rft_mujoco.compiled.elements import _inside, _outside_ball
from rft_mujoco.compiled.jit import JIT, JIT_LAW, njit
from rft_mujoco.compiled.law import _coef, _law_direction, _stress, stress_guards
from rft_mujoco.compiled.share import group_sums, group_twists
from rft_mujoco.compiled.terrain import _depth


@njit(**JIT)
def loaded_candidates(touch, k, surface, poses, terrain, occluders, out):
    """The submerged, unculled elements of the bodies ``touch[:k]``, written to the front of the rows of ``out``;
    returns their number.

    ``surface`` = (``centroids``, ``normals``, ``areas``, ``cluster_start``, ``cluster_center``,
    ``cluster_radius``, ``body_clusters``): the packed layout of :func:`rft_mujoco.compiled.elements.pack`.
    ``poses`` = (``body_pos`` (3), ``body_mat`` (9), ``body_com`` (3)): body j's pose in rows j. ``terrain`` =
    (``g_hat``, ``max_height`` (m), ``kind``, ``tp``, ``heights``): gravity's unit direction and the terrain's
    kernel form. ``occluders`` = (``occ_start``, ``occ_geom``, ``occ_kind``, ``occ_size``, ``occ_rbound``,
    ``occ_hs_start``, ``occ_hs``, ``margin``, ``geom_xpos``, ``geom_xmat``): the geoms of other bodies that hide
    elements (rows ``occ_start[b]:occ_start[b + 1]`` for body b) and their poses. ``out`` = (``e_slot`` (E,) int
    (the body row j), ``e_arm`` (E, 3) m (from the COM, world), ``e_nrm`` (E, 3) unit (world), ``e_depth`` (E,)
    m, ``e_area`` (E,) m^2, ``occluded`` (k,) m^2: the submerged area inside another body's geom). As the
    element pass (:func:`rft_mujoco.compiled.element_pass.wrenches`), a cluster above ``max_height`` is skipped
    whole, and an occluder is tested only on the clusters its bounding sphere reaches and that none of its faces
    separates from it."""
    centroids, normals, areas, cluster_start, cluster_center, cluster_radius, body_clusters = surface
    body_pos, body_mat, body_com = poses
    g_hat, max_height, kind, tp, heights = terrain
    occ_start, occ_geom, occ_kind, occ_size, occ_rbound, occ_hs_start, occ_hs, margin, geom_xpos, geom_xmat = occluders
    e_slot, e_arm, e_nrm, e_depth, e_area, occluded = out
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    near = np.empty(max(occ_geom.shape[0], 1), np.int64)
    n_e = 0
    for j in range(k):
        b = touch[j]
        occluded[j] = 0.0
        r = body_mat[j]
        px, py, pz = body_pos[j, 0], body_pos[j, 1], body_pos[j, 2]
        cx, cy, cz = body_com[j, 0], body_com[j, 1], body_com[j, 2]
        for q in range(body_clusters[b], body_clusters[b + 1]):
            q0, q1, q2 = cluster_center[q, 0], cluster_center[q, 1], cluster_center[q, 2]
            qx = px + (r[0] * q0 + r[1] * q1 + r[2] * q2)
            qy = py + (r[3] * q0 + r[4] * q1 + r[5] * q2)
            qz = pz + (r[6] * q0 + r[7] * q1 + r[8] * q2)
            if -(qx * g0 + qy * g1 + qz * g2) - cluster_radius[q] > max_height:
                continue                                       # the whole cluster is above the sand
            m = 0                                              # the occluders that may hold its elements
            for o in range(occ_start[b], occ_start[b + 1]):
                gid = occ_geom[o]
                ex, ey, ez = qx - geom_xpos[gid, 0], qy - geom_xpos[gid, 1], qz - geom_xpos[gid, 2]
                reach = occ_rbound[o] + cluster_radius[q]
                if ex * ex + ey * ey + ez * ez >= reach * reach:
                    continue
                gm = geom_xmat[gid]
                if _outside_ball(gm[0] * ex + gm[3] * ey + gm[6] * ez, gm[1] * ex + gm[4] * ey + gm[7] * ez,
                                 gm[2] * ex + gm[5] * ey + gm[8] * ez, cluster_radius[q], occ_kind[o],
                                 occ_size[o, 0], occ_size[o, 1], occ_size[o, 2], occ_hs, occ_hs_start[o],
                                 occ_hs_start[o + 1], margin):
                    continue
                near[m] = o
                m += 1
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
                for a in range(m):
                    o = near[a]
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


SCRATCH_ROWS = 20
"""Rows of :func:`body_law`'s scratch buffer (per loaded element: velocity, speed, normal, stress scale, force,
the law's 3x3 derivative)."""
LAW, LAW_AND_DERIVATIVE, DERIVATIVE_OF_LAST = 0, 1, 2
"""``derivative`` of :func:`body_law` and :func:`group_law`: the law only; the law and its derivative; the
derivative of the law the last call evaluated (same elements, same twists: its loaded elements are still packed
in ``scr`` and ``pk``), leaving the wrenches as that call left them. A Newton solve evaluates the law at each
trial point and its derivative only at the points it steps from: LAW then DERIVATIVE_OF_LAST gives the numbers
of one LAW_AND_DERIVATIVE call, bit for bit."""
_V, _SP, _N, _SA, _F, _D = 0, 3, 4, 7, 8, 11


ELEMENTS = ("n_e", "e_slot", "e_arm", "e_nrm", "e_depth", "e_area")
"""The ``els`` bundle of :func:`body_law` and :func:`group_law`: the candidate elements of
:func:`loaded_candidates` (their number, then per element: body row (int), lever arm from the COM (3, m, world),
unit normal (3, world), depth (m), area (m^2))."""
LAW_CONSTANTS = ("g_hat", "xi_n", "coef", "mu_surf", "no_tension", "no_forward", "no_power", "tol")
"""The ``lawc`` bundle: unit gravity (3,), ``xi_n`` (N/m^3), the (20, 3) coefficient table, the medium's surface
friction, the three guards (bool) and the tolerances (:func:`rft_mujoco.compiled.law.tolerances`)."""
BODY_WORK = ("lin", "ang", "on", "scr", "pk", "wrench", "jac", "count", "max_depth")
"""The ``work`` bundle of :func:`group_law`: the bodies' twists (k, 3) and flags (k,) that it writes, the work space
of :func:`body_law` (``scr``, ``pk``) and its per-body outputs (``wrench``, ``jac``, ``count``, ``max_depth``)."""


@njit(**JIT_LAW)
def body_law(els, lawc, k, lin, ang, on, speed_scale, fd_step, derivative, scr, pk, out):
    """The regularized wrench of bodies 0..k-1 (rows of ``lin`` (3, m/s, the COM's velocity), ``ang`` (3,
    rad/s)) on the elements ``els`` (:data:`ELEMENTS`) with the law ``lawc`` (:data:`LAW_CONSTANTS`), for the
    bodies with ``on[j]`` (other rows untouched); ``out`` = (``wrench``, ``jac``, ``count``, ``max_depth``).

    Each moving element on or near the leading side (speed above ``tol[2]``, ``n.v >= -tol[3] |v|``) carries
    the published stress at its ramped direction times ``xi_n depth area phi(|v|)`` times the ramp's weight
    (:func:`rft_mujoco.compiled.law._law_direction`), ``phi = |v| / sqrt(|v|^2 + c^2)``, ``c = speed_scale`` (m/s).
    Outputs rows j with ``on[j]``: ``wrench`` (6: N, N m about the COM, world), ``count`` (loaded elements),
    ``max_depth`` (m); with ``derivative``, ``jac`` (6, 6) d wrench / d (lin, ang): per element the law's 3x3
    derivative by forward differences (a step of ``fd_step`` times the element's speed or ``c``, whichever is
    larger), moved to the body twist through the lever arm.
    ``derivative``: :data:`LAW`, :data:`LAW_AND_DERIVATIVE` or :data:`DERIVATIVE_OF_LAST` (``True``/``False`` read
    as the first two). ``scr`` (:data:`SCRATCH_ROWS`, >= n_e) float and ``pk`` (> n_e,) int: work space; the
    last slot of ``pk`` keeps the number of loaded elements for :data:`DERIVATIVE_OF_LAST`. As the element pass,
    the loaded elements are packed first and the law runs on them without branches (vectorized)."""
    n_e, e_slot, e_arm, e_nrm, e_depth, e_area = els
    g_hat, xi_n, coef, tol = lawc[0], lawc[1], lawc[2], lawc[7]
    wrench, jac, count, max_depth = out
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    c = _coef(coef)
    lead_tol, zero_speed, ramp = tol[0], tol[2], tol[3]
    guards = stress_guards(lawc[1:])                                          # lawc = (g_hat,) + element_pass.LAW
    law = ((g0, g1, g2), c, guards, lead_tol, ramp)
    last = derivative == DERIVATIVE_OF_LAST
    for j in range(k):
        if on[j]:
            if not last:
                count[j] = 0
                max_depth[j] = 0.0
            for a in range(6):
                if not last:
                    wrench[j, a] = 0.0
                if derivative:
                    for b in range(6):
                        jac[j, a, b] = 0.0
    if last:
        _derivative_sums(pk[pk.shape[0] - 1], e_slot, e_arm, law, speed_scale, fd_step, scr, pk, jac)
        return
    m = 0                                        # 1. the loaded elements, packed
    for e in range(n_e):
        j = e_slot[e]
        r0, r1, r2 = e_arm[e, 0], e_arm[e, 1], e_arm[e, 2]
        wx, wy, wz = ang[j, 0], ang[j, 1], ang[j, 2]
        vx = lin[j, 0] + (wy * r2 - wz * r1)
        vy = lin[j, 1] + (wz * r0 - wx * r2)
        vz = lin[j, 2] + (wx * r1 - wy * r0)
        sp = math.sqrt(vx * vx + vy * vy + vz * vz)
        n0, n1, n2 = e_nrm[e, 0], e_nrm[e, 1], e_nrm[e, 2]
        pk[m] = e
        scr[_V, m] = vx
        scr[_V + 1, m] = vy
        scr[_V + 2, m] = vz
        scr[_SP, m] = sp
        m += on[j] and sp > zero_speed and (n0 * vx + n1 * vy + n2 * vz) / sp >= -ramp
    pk[pk.shape[0] - 1] = m
    for i in range(m):
        e = pk[i]
        scr[_N, i] = e_nrm[e, 0]
        scr[_N + 1, i] = e_nrm[e, 1]
        scr[_N + 2, i] = e_nrm[e, 2]
        scr[_SA, i] = xi_n * (e_depth[e] * e_area[e])
    for i in range(m):                           # 2. the law (no branches)
        vx, vy, vz, sp = scr[_V, i], scr[_V + 1, i], scr[_V + 2, i], scr[_SP, i]
        n0, n1, n2 = scr[_N, i], scr[_N + 1, i], scr[_N + 2, i]
        dx, dy, dz, reg = _law_direction(n0, n1, n2, vx, vy, vz, sp, speed_scale, lead_tol, ramp)
        sx, sy, sz = _stress((n0, n1, n2), (dx, dy, dz), (g0, g1, g2), c, guards)
        ph = scr[_SA, i] * reg
        scr[_F, i] = sx * ph
        scr[_F + 1, i] = sy * ph
        scr[_F + 2, i] = sz * ph
    for i in range(m):                           # 3. sums about each COM
        e = pk[i]
        j = e_slot[e]
        r0, r1, r2 = e_arm[e, 0], e_arm[e, 1], e_arm[e, 2]
        fx, fy, fz = scr[_F, i], scr[_F + 1, i], scr[_F + 2, i]
        count[j] += 1
        max_depth[j] = max(max_depth[j], e_depth[e])
        wrench[j, 0] += fx
        wrench[j, 1] += fy
        wrench[j, 2] += fz
        wrench[j, 3] += r1 * fz - r2 * fy
        wrench[j, 4] += r2 * fx - r0 * fz
        wrench[j, 5] += r0 * fy - r1 * fx
    if derivative:
        _derivative_sums(m, e_slot, e_arm, law, speed_scale, fd_step, scr, pk, jac)


@njit(**JIT_LAW)
def _derivative_sums(m, e_slot, e_arm, law, speed_scale, fd_step, scr, pk, jac):
    """:func:`body_law`'s derivative on its ``m`` packed loaded elements (``scr``, ``pk`` as it left them), added
    to ``jac`` (rows zeroed by the caller); ``law`` = (unit gravity, coefficients, guards: the arguments of
    :func:`rft_mujoco.compiled.law._stress` after the direction; the leading tolerance and ramp)."""
    g, c, guards, lead_tol, ramp = law
    ee = np.empty((3, 3))
    for q in range(3):                           # the law at v + h e_q
        for i in range(m):
            sp = scr[_SP, i]
            h = fd_step * max(sp, speed_scale)
            ux = scr[_V, i] + (h if q == 0 else 0.0)
            uy = scr[_V + 1, i] + (h if q == 1 else 0.0)
            uz = scr[_V + 2, i] + (h if q == 2 else 0.0)
            s = math.sqrt(ux * ux + uy * uy + uz * uz)
            n0, n1, n2 = scr[_N, i], scr[_N + 1, i], scr[_N + 2, i]
            dx, dy, dz, reg = _law_direction(n0, n1, n2, ux, uy, uz, s, speed_scale, lead_tol, ramp)
            tx, ty, tz = _stress((n0, n1, n2), (dx, dy, dz), g, c, guards)
            p = scr[_SA, i] * reg
            scr[_D + q, i] = (tx * p - scr[_F, i]) / h           # d[i_, q] = d f_i_ / d v_q, row-major
            scr[_D + 3 + q, i] = (ty * p - scr[_F + 1, i]) / h
            scr[_D + 6 + q, i] = (tz * p - scr[_F + 2, i]) / h
    for i in range(m):
        e = pk[i]
        j = e_slot[e]
        r0, r1, r2 = e_arm[e, 0], e_arm[e, 1], e_arm[e, 2]
        # element velocity v = lin - [r]x ang; its wrench (f, [r]x f): J = [[D, -D[r]x], [[r]x D, -[r]x D [r]x]]
        for q in range(3):                       # ee = [r]x D
            d0, d1, d2 = scr[_D + q, i], scr[_D + 3 + q, i], scr[_D + 6 + q, i]
            ee[0, q] = r1 * d2 - r2 * d1
            ee[1, q] = r2 * d0 - r0 * d2
            ee[2, q] = r0 * d1 - r1 * d0
        for i_ in range(3):
            # row i_ of X [r]x: (x1 r2 - x2 r1, x2 r0 - x0 r2, x0 r1 - x1 r0) for X = D, [r]x D
            x0, x1, x2 = scr[_D + 3 * i_, i], scr[_D + 3 * i_ + 1, i], scr[_D + 3 * i_ + 2, i]
            jac[j, i_, 0] += x0
            jac[j, i_, 1] += x1
            jac[j, i_, 2] += x2
            jac[j, i_, 3] -= x1 * r2 - x2 * r1
            jac[j, i_, 4] -= x2 * r0 - x0 * r2
            jac[j, i_, 5] -= x0 * r1 - x1 * r0
            y0, y1, y2 = ee[i_, 0], ee[i_, 1], ee[i_, 2]
            jac[j, 3 + i_, 0] += y0
            jac[j, 3 + i_, 1] += y1
            jac[j, 3 + i_, 2] += y2
            jac[j, 3 + i_, 3] -= y1 * r2 - y2 * r1
            jac[j, 3 + i_, 4] -= y2 * r0 - y0 * r2
            jac[j, 3 + i_, 5] -= y0 * r1 - y1 * r0


@njit(**JIT)
def group_law(u, groups_on, ng, law, speed_scale, fd_step, derivative, f, df):
    """The law of :func:`body_law` for groups 0..ng-1 moving with twists ``u`` (ng, 6) at their reference
    points (m/s, rad/s), for the groups with ``groups_on[g]``. ``law`` = (``bodies``, ``els``, ``lawc``, ``work``):
    ``bodies`` = (``k``, ``slot``, ``arm``), body j (of group ``slot[j]``, its COM at ``arm[j]`` (3, m) from the
    reference point) moving with ``(v + w x arm, w)``; ``els`` (:data:`ELEMENTS`) and ``lawc``
    (:data:`LAW_CONSTANTS`) as :func:`body_law`'s; ``work`` (:data:`BODY_WORK`). Outputs: ``f`` (ng, 6) the
    groups' wrenches about their reference points (N, N m), with ``derivative`` ``df`` (ng, 6, 6) their
    derivative in ``u``; the bodies' own (``wrench``, ``jac``, ``count``, ``max_depth`` of ``work``) of
    :func:`body_law`. Rows of groups without ``groups_on`` are left as they were (``f``, ``df`` and the bodies'
    rows)."""
    (k, slot, arm), els, lawc, work = law
    lin, ang, on, scr, pk, wrench, jac, count, max_depth = work
    group_twists(u, groups_on, k, slot, arm, lin, ang, on)
    body_law(els, lawc, k, lin, ang, on, speed_scale, fd_step, derivative, scr, pk, (wrench, jac, count, max_depth))
    group_sums(ng, groups_on, k, slot, arm, on, wrench, f)
    if not derivative:
        return
    for g in range(ng):
        if not groups_on[g]:
            continue
        for a in range(6):
            for b in range(6):
                df[g, a, b] = 0.0
    s = np.zeros((6, 6))                          # S: (v_com, w) = S (v_ref, w)
    t = np.empty((6, 6))
    for j in range(k):
        if not on[j]:
            continue
        g = slot[j]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
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
