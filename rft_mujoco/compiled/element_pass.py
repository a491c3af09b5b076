"""The compiled element pass: body poses and twists -> per-body RFT wrenches.

The same numbers as :func:`rft_mujoco.physics.elements.body_wrenches` (to round-off, tests/test_compiled_element_pass.py),
into buffers the caller owns, on the packed layout of :mod:`rft_mujoco.compiled.elements`. How it is fast:

* It works in each body's own frame. The law is invariant under rotation (every quantity it uses is a dot
  product of the element normal, its velocity and gravity, and it returns a combination of those
  vectors), so with gravity, the body's twist and its COM brought into the body frame once per body,
  elements are never rotated: a world-frame sum is one rotation of the body-frame sum. On a flat surface
  the depth of an element is affine in its body-frame centroid, ``c0 + (R^T g) . l``: three multiply-adds.
* Per cluster (clusters above the sand are skipped whole): the depth of every element (vectorized); the
  indices of the submerged ones (branchless); run-time culling of those inside another body's geom; the
  elements that carry stress (submerged, moving, leading) packed to the front of the scratch buffer,
  either by a vectorized test over the whole cluster or, when few are submerged, a scalar test over the
  submerged ones only (both give the same elements in the same order, so the same numbers); the law
  vectorized on the packed elements only; a short scalar sum.

Everything works on a fixed (:data:`SCRATCH_ROWS`, cluster size) scratch buffer, never on per-element
temporaries.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.compiled.elements import CLUSTER_SIZE, LANES, _inside, _nearest_face, _outside_ball, pack
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.jit import INLINE, JIT, JIT_LAW, njit
from rft_mujoco.compiled.law import _coef, _law_direction, _stress, stress_guards
from rft_mujoco.compiled.terrain import ABOVE, DEFORMABLE, FLAT, _depth, deformed_range
from rft_mujoco.geometry.occlusion import Occluders
from rft_mujoco.physics import terrain_spec as ts

# Scratch rows: per element of the cluster (depth, loaded flag), then per packed (loaded) element: lever
# arm in the body frame, normal, depth, area, force, torque. Index rows: submerged, loaded elements.
_DEPTH, _KEEP = 0, 1
_P_ARM, _P_NRM, _P_DEPTH, _P_AREA, _P_F, _P_T = 2, 5, 8, 9, 10, 13
SCRATCH_ROWS = 16
"""Rows of the element pass's scratch buffer."""
LAW_LANES = 8
"""The law's loop runs over whole vectors of LAW_LANES elements (:func:`_pack`)."""
SPARSE = 4
"""A cluster with under 1/SPARSE of its elements submerged is tested on those (scalar), else all (vectorized)."""
# A body's row of the reuse buffer (``attach(reuse_tol=)``, :func:`wrenches`): at its last full evaluation, the
# unit key of its twist (6), gravity in its frame (3), the flat depth of its origin (m), its wrench summed in its
# frame (6: N, N m about the COM), loaded elements, deepest loaded element (m), occluded area (m^2), valid (0/1),
# a ball holding its submerged elements (centre in its frame, radius; m).
_R_KEY, _R_G, _R_DEPTH, _R_SUM, _R_COUNT, _R_DEEPEST, _R_OCCLUDED, REUSE_VALID, _R_BALL = 0, 6, 9, 10, 16, 17, 18, 19, 20
REUSE_COLUMNS = 24
"""Columns of the reuse buffer (the workspace's ``reuse``, one row per attached body)."""
REUSE_ARM = 0.1
"""m: the twist's key is the unit vector of (v, REUSE_ARM w), v the COM velocity, w the angular velocity."""
REUSE_PAD = 0.002
"""m added to the radius of the ball around a body's submerged elements within which another body's geom stops
its wrench from being reused (elements within ``reuse_tol`` of that pose may have gone in meanwhile)."""
REUSE_DEPTH = 0.01
"""m: a body's origin may move ``reuse_tol * REUSE_DEPTH`` deeper or shallower before its wrench is evaluated again."""
_NO_BOX = (math.inf, math.inf, math.inf, -math.inf, -math.inf, -math.inf)
"""The bounds of no element (:func:`_grow_box`)."""
REUSE_STEADY = 10.0
"""A full evaluation is remembered for reuse only where the body's key, gravity and depth moved by less than
``REUSE_STEADY * reuse_tol`` since its previous one (:func:`_reuse_state`): a moving body's would not be reused,
and the ball around its submerged elements costs a pass over them."""


@njit(**INLINE)
def _lane_max(row, n, lanes):
    """The largest of ``row[:n]`` (>= 0): a running maximum over interleaved lanes (a select, which
    vectorizes; one running variable compiles to a branch that mispredicts as elements get deeper)."""
    for l in range(LANES):
        lanes[l] = 0.0
    full = n // LANES * LANES
    for i0 in range(0, full, LANES):
        for l in range(LANES):
            x = row[i0 + l]
            lanes[l] = x if x > lanes[l] else lanes[l]
    for i in range(full, n):
        x = row[i]
        lanes[i - full] = x if x > lanes[i - full] else lanes[i - full]
    top = 0.0
    for l in range(LANES):
        top = max(top, lanes[l])
    return top


@njit(**INLINE)
def _loaded(arm, nrm, depth, ub, wb, zero_speed2, lead_tol2):
    """Whether an element (body-frame lever arm ``arm``, normal ``nrm``) carries stress: submerged, moving
    (speed above ZERO_SPEED) and leading (``n.v >= -LEADING_TOL |v|``, squared: no square root); ``ub``, ``wb``:
    the body's twist in its frame."""
    l0, l1, l2 = arm
    vx = ub[0] + (wb[1] * l2 - wb[2] * l1)
    vy = ub[1] + (wb[2] * l0 - wb[0] * l2)
    vz = ub[2] + (wb[0] * l1 - wb[1] * l0)
    nv = nrm[0] * vx + nrm[1] * vy + nrm[2] * vz
    sp2 = vx * vx + vy * vy + vz * vz
    return (depth > 0.0) & (sp2 > zero_speed2) & ((nv >= 0.0) | (nv * nv <= lead_tol2 * sp2))


SURFACE = ("centroids", "normals", "areas", "cluster_start", "cluster_center", "cluster_radius", "body_clusters")
"""The ``surface`` bundle: the packed elements of :func:`rft_mujoco.compiled.elements.pack` (``handle_constants``'
``H_CENTROIDS`` ... ``H_BODY_CLUSTERS``)."""
TERRAIN = ("g_hat", "max_height", "kind", "tp", "heights")
"""The ``terrain`` bundle: unit gravity (3,), the surface's highest point (m) and its kernel form
(:func:`rft_mujoco.physics.terrain_spec.terrain_spec`)."""
LAW = ("xi_n", "coef", "mu_surf", "no_tension", "no_forward", "no_power", "tol")
"""The ``law`` bundle: ``xi_n`` (N/m^3), the (20, 3) coefficients, the surface friction, the three guards (bool) and
the tolerances (:func:`rft_mujoco.compiled.law.tolerances`)."""
OCCLUDERS = ("occ_start", "occ_geom", "occ_kind", "occ_size", "occ_rbound", "occ_hs_start", "occ_hs", "margin",
             "geom_xpos", "geom_xmat")
"""The ``occluders`` bundle: the geoms that hide a body's elements (:class:`rft_mujoco.geometry.occlusion.Occluders`,
rows ``occ_start[b]:occ_start[b + 1]`` for body b), the margin (m) and MjData's geom poses."""


@njit(**JIT)
def surface_of(hc):
    """:data:`SURFACE` of the handle constants ``hc`` (:data:`rft_mujoco.compiled.schema.HANDLE_FIELDS`)."""
    return (hc[sc.H_CENTROIDS], hc[sc.H_NORMALS], hc[sc.H_AREAS], hc[sc.H_CLUSTER_START], hc[sc.H_CLUSTER_CENTER],
            hc[sc.H_CLUSTER_RADIUS], hc[sc.H_BODY_CLUSTERS])


@njit(**JIT)
def terrain_of(hc, g_hat):
    """:data:`TERRAIN` of ``hc`` under the unit gravity ``g_hat``."""
    params = hc[sc.H_PARAMS]
    return g_hat, params[sc.P_MAX_HEIGHT], int(params[sc.P_KIND]), hc[sc.H_TP], hc[sc.H_HEIGHTS]


@njit(**JIT)
def law_of(hc, xi_n):
    """:data:`LAW` of ``hc`` with ``xi_n`` (N/m^3, at this gravity)."""
    params = hc[sc.H_PARAMS]
    return (xi_n, hc[sc.H_COEF], params[sc.P_MU_SURF], params[sc.P_NO_TENSION] != 0.0, params[sc.P_NO_FORWARD] != 0.0,
            params[sc.P_NO_POWER] != 0.0, hc[sc.H_TOL])


@njit(**JIT)
def occluders_of(hc, md):
    """:data:`OCCLUDERS` of ``hc`` posed by MjData's ``md`` (:data:`rft_mujoco.compiled.schema.MJDATA_FIELDS`)."""
    return (hc[sc.H_OCC_START], hc[sc.H_OCC_GEOM], hc[sc.H_OCC_KIND], hc[sc.H_OCC_SIZE], hc[sc.H_OCC_RBOUND],
            hc[sc.H_OCC_HS_START], hc[sc.H_OCC_HS], hc[sc.H_PARAMS][sc.P_MARGIN], md[sc.M_GEOM_XPOS],
            md[sc.M_GEOM_XMAT])


_FLAT, _DEFORMED, _GENERAL = 0, 1, 2
"""How the element pass finds depths: affine in the body frame (flat sand), under the deformed surface's local
maximum first (deformable sand, gravity down), or element by element (any other terrain)."""


@njit(**INLINE)
def _terrain_depths(dep, cl, frame, top, deformed, terrain):
    """Step 1 of a cluster on a terrain other than flat sand (on flat sand the depth is affine in the body frame:
    :func:`wrenches`): the depth (m) of each of its elements (body-frame centroids ``cl``, padding slots NaN: never
    submerged) into ``dep``. ``frame`` = (``body_mat[j]``'s nine, px, py, pz); ``deformed``: on deformable sand
    under gravity along -z, where ``top`` is the highest surface around the cluster plus ABOVE."""
    g_hat, _, kind, tp, heights = terrain
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    r0, r1, r2, r3, r4, r5, r6, r7, r8, px, py, pz = frame
    cl0, cl1, cl2 = cl
    n = cl0.shape[0]
    if deformed:                                         # the surface around is nowhere above ``top``: the
        for i in range(n):                               # depth where an element is below it, else <= 0
            dep[i] = top - (pz + (r6 * cl0[i] + r7 * cl1[i] + r8 * cl2[i]))
        for i in range(n):
            if dep[i] > 0.0:
                l0, l1, l2 = cl0[i], cl1[i], cl2[i]
                dep[i] = _depth(px + (r0 * l0 + r1 * l1 + r2 * l2), py + (r3 * l0 + r4 * l1 + r5 * l2),
                                pz + (r6 * l0 + r7 * l1 + r8 * l2), g0, g1, g2, kind, tp, heights)
    else:
        for i in range(n):
            l0, l1, l2 = cl0[i], cl1[i], cl2[i]
            dep[i] = _depth(px + (r0 * l0 + r1 * l1 + r2 * l2), py + (r3 * l0 + r4 * l1 + r5 * l2),
                            pz + (r6 * l0 + r7 * l1 + r8 * l2), g0, g1, g2, kind, tp, heights)


@njit(**INLINE)
def _cluster_place(center, radius, frame, g_hat):
    """A cluster's centre in the world (m; ``center`` in the body frame, ``frame`` the body's) and the depth of its
    lowest point below the plane through the origin normal to gravity, less its ``radius`` (m): ``low``."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8, px, py, pz = frame
    q0, q1, q2 = center[0], center[1], center[2]
    qx = px + (r0 * q0 + r1 * q1 + r2 * q2)
    qy = py + (r3 * q0 + r4 * q1 + r5 * q2)
    qz = pz + (r6 * q0 + r7 * q1 + r8 * q2)
    return qx, qy, qz, -(qx * g_hat[0] + qy * g_hat[1] + qz * g_hat[2]) - radius


@njit(**INLINE)
def _pass_constants(terrain, law, speed_scale):
    """The element pass's constants: the law's coefficients (:func:`rft_mujoco.compiled.law._coef`), its guards
    (:data:`rft_mujoco.compiled.law.STRESS_GUARDS`), the leading tolerance and ramp, (zero speed^2, leading
    edge^2) and how depths are found (:data:`_FLAT`, ``_DEFORMED`` or ``_GENERAL``)."""
    g_hat, _, kind, tp, _ = terrain
    coef, tol = law[1], law[6]
    lead_tol, ramp = tol[0], tol[3]
    edge = ramp if speed_scale > 0.0 else lead_tol                 # the regularized law's leading edge
    mode = _FLAT if kind == FLAT and tp[ts.TP_REGION] == 0.0 else _DEFORMED if kind == DEFORMABLE and g_hat[2] < 0.0 \
        else _GENERAL
    return _coef(coef), stress_guards(law), lead_tol, ramp, (tol[2] * tol[2], edge * edge), mode


@njit(**INLINE)
def _occlude(dep, sub, ms, cl, cluster, frame, surface, occluders, hidden):
    """Step 2 of a cluster: its submerged elements (``sub[:ms]``) inside a geom that hides them (``occluders``,
    :data:`OCCLUDERS` rows ``o0:o1``) get depth -inf; returns ``hidden`` (m^2) plus their area. ``cluster`` =
    (q, its first element s, o0, o1, its centre in the world qx, qy, qz)."""
    cluster_center, cluster_radius, areas = surface[4], surface[5], surface[2]
    occ_geom, occ_kind, occ_size, _, occ_hs_start, occ_hs, margin = occluders[1:8]
    geom_xpos, geom_xmat = occluders[8], occluders[9]
    q, s, o0, o1, qx, qy, qz = cluster
    r0, r1, r2, r3, r4, r5, r6, r7, r8, px, py, pz = frame
    cl0, cl1, cl2 = cl
    q0, q1, q2 = cluster_center[q, 0], cluster_center[q, 1], cluster_center[q, 2]
    for o in range(o0, o1):
        if _clear_of(o, (qx, qy, qz), cluster_radius[q], occluders):
            continue                                     # the geom cannot hide any of the cluster's elements
        gid = occ_geom[o]
        ox, oy, oz = geom_xpos[gid, 0], geom_xpos[gid, 1], geom_xpos[gid, 2]
        gm = geom_xmat[gid]                              # the element in the geom frame: M l + t
        m00, m01, m02 = gm[0] * r0 + gm[3] * r3 + gm[6] * r6, gm[0] * r1 + gm[3] * r4 + gm[6] * r7, \
            gm[0] * r2 + gm[3] * r5 + gm[6] * r8
        m10, m11, m12 = gm[1] * r0 + gm[4] * r3 + gm[7] * r6, gm[1] * r1 + gm[4] * r4 + gm[7] * r7, \
            gm[1] * r2 + gm[4] * r5 + gm[7] * r8
        m20, m21, m22 = gm[2] * r0 + gm[5] * r3 + gm[8] * r6, gm[2] * r1 + gm[5] * r4 + gm[8] * r7, \
            gm[2] * r2 + gm[5] * r5 + gm[8] * r8
        ex, ey, ez = px - ox, py - oy, pz - oz
        t0, t1, t2 = gm[0] * ex + gm[3] * ey + gm[6] * ez, gm[1] * ex + gm[4] * ey + gm[7] * ez, \
            gm[2] * ex + gm[5] * ey + gm[8] * ez
        s0, s1, s2 = occ_size[o, 0], occ_size[o, 1], occ_size[o, 2]
        hs0, hs1, ok = occ_hs_start[o], occ_hs_start[o + 1], occ_kind[o]
        x0, x1, x2 = t0 + (m00 * q0 + m01 * q1 + m02 * q2), t1 + (m10 * q0 + m11 * q1 + m12 * q2), \
            t2 + (m20 * q0 + m21 * q1 + m22 * q2)
        kf = _nearest_face(x0, x1, x2, ok, occ_hs, hs0, hs1)
        for jj in range(ms):
            i = sub[jj]
            if not dep[i] > 0.0:
                continue
            l0, l1, l2 = cl0[i], cl1[i], cl2[i]
            e0, e1, e2 = t0 + (m00 * l0 + m01 * l1 + m02 * l2), t1 + (m10 * l0 + m11 * l1 + m12 * l2), \
                t2 + (m20 * l0 + m21 * l1 + m22 * l2)
            if kf >= 0 and not occ_hs[kf, 0] * e0 + occ_hs[kf, 1] * e1 + occ_hs[kf, 2] * e2 < occ_hs[kf, 3] - margin:
                continue                                 # outside the face nearest the cluster (as _inside)
            if _inside(e0, e1, e2, ok, s0, s1, s2, occ_hs, hs0, hs1, margin):
                hidden += areas[s + i]
                dep[i] = -np.inf
    return hidden


@njit(**JIT_LAW)
def wrenches(bodies, n_on, surface, poses, twists, terrain, law, occluders, work, out, speed_scale, reuse=None):
    """The RFT wrench about each COM of bodies ``bodies[:n_on]`` (b; clusters ``body_clusters[b]:[b + 1]`` of
    ``surface``, :data:`SURFACE`) posed by row j of ``poses`` = (``body_pos`` (3), ``body_mat`` (9), ``body_com``
    (3)), moving with ``twists`` = (``lin`` (3, m/s, of the COM), ``ang`` (3, rad/s)); ``terrain``, ``law``,
    ``occluders``: :data:`TERRAIN`, :data:`LAW`, :data:`OCCLUDERS` (elements inside an occluder carry nothing).
    Into rows j of ``out`` = (``wrench`` (6: N, N m about the COM, world frame), ``count`` (loaded elements),
    ``max_depth`` (m), ``occluded`` (m^2 submerged inside occluders)); ``work`` = (``scratch`` (SCRATCH_ROWS, >=
    cluster size), ``index`` (2, >= cluster size) int). ``speed_scale`` (m/s): 0, the published law; c > 0, the
    implicit solve's (stress times ``|v| / sqrt(|v|^2 + c^2)``, ramped leading edge: ``implicit_law.body_law``).
    ``reuse`` = (buffer (B, REUSE_COLUMNS), tol > 0): on flat sand a body whose last full evaluation still holds
    (:func:`_reuse_state`) gets its wrench and diagnostics again. Returns the number of bodies reused."""
    centroids, normals, areas, cluster_start, cluster_center, cluster_radius, body_clusters = surface
    body_pos, body_mat, body_com = poses
    lin, ang = twists
    g_hat, max_height, _, tp, heights = terrain
    occ_start = occluders[0]
    (scratch, index), (wrench, count, max_depth, occluded) = work, out
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    xi_n = law[0]
    c, guards, lead_tol, ramp, (zs2, lt2), mode = _pass_constants(terrain, law, speed_scale)
    lanes = np.empty(LANES)
    dep, keep = scratch[_DEPTH], scratch[_KEEP]
    sub, load = index[0], index[1]
    reused = 0
    for j in range(n_on):
        b = bodies[j]
        wrench[j, :] = 0.0
        count[j], max_depth[j], occluded[j] = 0, 0.0, 0.0
        ux, uy, uz = lin[j, 0], lin[j, 1], lin[j, 2]
        wx, wy, wz = ang[j, 0], ang[j, 1], ang[j, 2]
        if ux == 0.0 and uy == 0.0 and uz == 0.0 and wx == 0.0 and wy == 0.0 and wz == 0.0:
            continue                         # a body at rest: no element moves, none is loaded
        r = body_mat[j]
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
        px, py, pz = body_pos[j, 0], body_pos[j, 1], body_pos[j, 2]
        frame = (r0, r1, r2, r3, r4, r5, r6, r7, r8, px, py, pz)
        # the body frame: gravity, the COM (lever arms are l - cb), the twist of the COM
        gb0, gb1, gb2 = r0 * g0 + r3 * g1 + r6 * g2, r1 * g0 + r4 * g1 + r7 * g2, r2 * g0 + r5 * g1 + r8 * g2
        dx, dy, dz = body_com[j, 0] - px, body_com[j, 1] - py, body_com[j, 2] - pz
        cb0, cb1, cb2 = r0 * dx + r3 * dy + r6 * dz, r1 * dx + r4 * dy + r7 * dz, r2 * dx + r5 * dy + r8 * dz
        ub = ub0, ub1, ub2 = r0 * ux + r3 * uy + r6 * uz, r1 * ux + r4 * uy + r7 * uz, r2 * ux + r5 * uy + r8 * uz
        wb = wb0, wb1, wb2 = r0 * wx + r3 * wy + r6 * wz, r1 * wx + r4 * wy + r7 * wz, r2 * wx + r5 * wy + r8 * wz
        c0 = tp[ts.TP_HEIGHT] + (px * g0 + py * g1 + pz * g2)            # flat depth of the body origin
        row, tol = _reuse_row(reuse, b, mode == _FLAT, scratch[_DEPTH, :0])   # (empty: not remembered)
        again, steady, now = _reuse_state(row, tol, (ub, wb, (gb0, gb1, gb2), c0), b, frame, g_hat, occluders)
        if again:
            reused += _restore(row, j, r, out)
            continue
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        deepest, box = 0.0, _NO_BOX                              # box: its submerged elements' bounds (_grow_box)
        for q in range(body_clusters[b], body_clusters[b + 1]):
            qx, qy, qz, low = _cluster_place(cluster_center[q], cluster_radius[q], frame, g_hat)
            if low > max_height:                             # the whole cluster is above the sand
                continue
            top = deformed_range(qx, qy, cluster_radius[q], tp, heights)[1] + ABOVE if mode == _DEFORMED else 0.0
            if mode == _DEFORMED and low > top:
                continue                                     # ... above the deformed sand around it
            s = cluster_start[q]
            n = cluster_start[q + 1] - s
            cl = (centroids[0, s:s + n], centroids[1, s:s + n], centroids[2, s:s + n])
            nr0, nr1, nr2 = normals[0, s:s + n], normals[1, s:s + n], normals[2, s:s + n]
            cl0, cl1, cl2 = cl
            # 1. depths (flat sand: affine in the body frame), the submerged indices (branchless)
            if mode == _FLAT:
                for i in range(n):
                    dep[i] = c0 + (gb0 * cl0[i] + gb1 * cl1[i] + gb2 * cl2[i])
            else:
                _terrain_depths(dep, cl, frame, top, mode == _DEFORMED, terrain)
            ms = 0
            for i in range(n):
                sub[ms] = i
                ms += dep[i] > 0.0
            if ms == 0:
                continue
            if steady:
                box = _grow_box(box, sub, ms, cl)
            # 2. the submerged elements inside another body's geom: depth -inf, their area reported
            occluded[j] = _occlude(dep, sub, ms, cl, (q, s, occ_start[b], occ_start[b + 1], qx, qy,
                                   qz), frame, surface, occluders, occluded[j])
            # 3. the loaded elements (submerged, moving, leading), in increasing index, packed to the front
            ml = 0
            if SPARSE * ms < n:
                for jj in range(ms):
                    i = sub[jj]
                    load[ml] = i
                    ml += _loaded((cl0[i] - cb0, cl1[i] - cb1, cl2[i] - cb2), (nr0[i], nr1[i], nr2[i]), dep[i],
                                  ub, wb, zs2, lt2)
            else:
                for i in range(n):
                    keep[i] = 1.0 if _loaded((cl0[i] - cb0, cl1[i] - cb1, cl2[i] - cb2), (nr0[i], nr1[i], nr2[i]),
                                             dep[i], ub, wb, zs2, lt2) else 0.0
                for i in range(n):
                    load[ml] = i
                    ml += keep[i] != 0.0
            if ml == 0:
                continue
            mp = _pack(scratch, load[:ml], cl, (nr0, nr1, nr2), (dep, areas[s:s + n]), (cb0, cb1, cb2))
            # 4. the law on the packed elements (body frame): vectorized, no branches, whole vectors
            for i in range(mp):
                l0, l1, l2 = scratch[_P_ARM, i], scratch[_P_ARM + 1, i], scratch[_P_ARM + 2, i]
                vx = ub0 + (wb1 * l2 - wb2 * l1)
                vy = ub1 + (wb2 * l0 - wb0 * l2)
                vz = ub2 + (wb0 * l1 - wb1 * l0)
                n0, n1, n2 = scratch[_P_NRM, i], scratch[_P_NRM + 1, i], scratch[_P_NRM + 2, i]
                sp = math.sqrt(vx * vx + vy * vy + vz * vz)
                dx, dy, dz, reg = _law_direction(n0, n1, n2, vx, vy, vz, sp, speed_scale, lead_tol, ramp)  # unswitched
                rx, ry, rz = _stress((n0, n1, n2), (dx, dy, dz), (gb0, gb1, gb2), c, guards)
                sa = xi_n * (scratch[_P_DEPTH, i] * scratch[_P_AREA, i]) * reg
                fx, fy, fz = rx * sa, ry * sa, rz * sa
                scratch[_P_F, i] = fx
                scratch[_P_F + 1, i] = fy
                scratch[_P_F + 2, i] = fz
                scratch[_P_T, i] = l1 * fz - l2 * fy
                scratch[_P_T + 1, i] = l2 * fx - l0 * fz
                scratch[_P_T + 2, i] = l0 * fy - l1 * fx
            # 5. sums (body frame)
            for i in range(ml):
                a0 += scratch[_P_F, i]
                a1 += scratch[_P_F + 1, i]
                a2 += scratch[_P_F + 2, i]
                a3 += scratch[_P_T, i]
                a4 += scratch[_P_T + 1, i]
                a5 += scratch[_P_T + 2, i]
            count[j] += ml
            deepest = max(deepest, _lane_max(scratch[_P_DEPTH], ml, lanes))
        max_depth[j] = deepest
        _to_world(wrench, j, r, (a0, a1, a2, a3, a4, a5))                 # back to the world frame
        if row.shape[0] > 0:                                                # remembered for reuse
            _remember(row, now, (a0, a1, a2, a3, a4, a5), count[j], deepest, occluded[j], box, steady)
    return reused


@njit(**INLINE)
def _pack(scratch, load, cl, nr, dep_area, cb):
    """Step 3 of :func:`wrenches`: a cluster's loaded elements ``load`` (body-frame centroids ``cl``, normals ``nr``,
    depths and areas ``dep_area``) packed to the front of ``scratch``'s rows: lever arms about the COM ``cb``,
    normals, depths, areas; then copies of the first at zero depth and area (no force) to whole vectors of LAW_LANES
    (its return): the law's loop takes leftovers one at a time, ~5 lanes each (20 elements 296 ns, 24: 184 ns)."""
    cl0, cl1, cl2 = cl
    nr0, nr1, nr2 = nr
    dep, area = dep_area
    ml = load.shape[0]
    for jj in range(ml):
        i = load[jj]
        scratch[_P_ARM, jj] = cl0[i] - cb[0]
        scratch[_P_ARM + 1, jj] = cl1[i] - cb[1]
        scratch[_P_ARM + 2, jj] = cl2[i] - cb[2]
        scratch[_P_NRM, jj] = nr0[i]
        scratch[_P_NRM + 1, jj] = nr1[i]
        scratch[_P_NRM + 2, jj] = nr2[i]
        scratch[_P_DEPTH, jj] = dep[i]
        scratch[_P_AREA, jj] = area[i]
    mp = min((ml + LAW_LANES - 1) // LAW_LANES * LAW_LANES, scratch.shape[1])
    for jj in range(ml, mp):
        for row in range(_P_ARM, _P_AREA + 1):
            scratch[row, jj] = scratch[row, 0] if row < _P_DEPTH else 0.0
    return mp


@njit(**INLINE)
def _reuse_row(reuse, b, flat, none):
    """(body b's row of the reuse buffer, the tolerance) where ``reuse`` asks for it on flat sand, else (``none``,
    0): see :func:`wrenches`."""
    if reuse is None:
        return none, 0.0
    if reuse[1] > 0.0 and flat:
        return reuse[0][b], reuse[1]
    return none, 0.0


@njit(**INLINE)
def _restore(row, j, r, out):
    """Row j of ``out`` (:func:`wrenches`) from a remembered evaluation ``row`` of a body with rotation ``r``; 1."""
    wrench, count, max_depth, occluded = out
    count[j], max_depth[j], occluded[j] = int(row[_R_COUNT]), row[_R_DEEPEST], row[_R_OCCLUDED]
    _to_world(wrench, j, r, row[_R_SUM:_R_SUM + 6])
    return 1


@njit(**INLINE)
def _grow_box(box, sub, ms, cl):
    """``box`` (min x, y, z, max x, y, z) grown by the elements ``sub[:ms]`` of a cluster (body-frame centroids ``cl``):
    a new tuple (no array on the heap per evaluation)."""
    cl0, cl1, cl2 = cl
    lo0, lo1, lo2, hi0, hi1, hi2 = box
    for jj in range(ms):
        i = sub[jj]
        lo0, lo1, lo2 = min(lo0, cl0[i]), min(lo1, cl1[i]), min(lo2, cl2[i])
        hi0, hi1, hi2 = max(hi0, cl0[i]), max(hi1, cl1[i]), max(hi2, cl2[i])
    return lo0, lo1, lo2, hi0, hi1, hi2


@njit(**INLINE)
def _key(ub, wb):
    """The unit vector of (v, REUSE_ARM w) of a twist in a body's frame (v m/s, w rad/s; not both zero)."""
    k3, k4, k5 = REUSE_ARM * wb[0], REUSE_ARM * wb[1], REUSE_ARM * wb[2]
    inv = 1.0 / math.sqrt(ub[0] * ub[0] + ub[1] * ub[1] + ub[2] * ub[2] + k3 * k3 + k4 * k4 + k5 * k5)
    return ub[0] * inv, ub[1] * inv, ub[2] * inv, k3 * inv, k4 * inv, k5 * inv


@njit(**INLINE)
def _reuse_state(row, tol, motion, b, frame, g_hat, occluders):
    """(reuse body b's remembered evaluation, remember this one, ``now``) for its ``row`` of the reuse buffer (empty:
    no reuse) and ``motion`` = (its twist in its frame (v, w), gravity in its frame, the flat depth of its origin);
    ``now``: the key of its twist (:func:`_key`), gravity and depth. A remembered evaluation is reused while ``now``
    lies within ``tol`` of it (:func:`_near`) and no other body's geom comes near the ball around its submerged
    elements (:func:`_shadowed`); this one is remembered, with a new ball, only while ``now`` lies within
    :data:`REUSE_STEADY` ``* tol`` of the last evaluation and nothing shadows the last ball (a body moving, or
    resting against another body's geom, would not be reused: it skips the ball's pass over its elements)."""
    ub, wb, gb, c0 = motion
    now = (_key(ub, wb) if row.shape[0] > 0 else (0.0,) * 6, gb, c0)
    if row.shape[0] == 0 or not _near(row, now, REUSE_STEADY * tol) or _shadowed(row, b, frame, g_hat, occluders):
        return False, False, now
    return row[REUSE_VALID] != 0.0 and _near(row, now, tol), True, now


@njit(**INLINE)
def _shadowed(row, b, frame, g_hat, occluders):
    """Whether another body's geom comes near the ball kept in ``row`` (around the submerged elements of the last
    evaluation that kept one, in the body frame; radius <= 0: none kept, or nothing was submerged)."""
    rad = row[_R_BALL + 3]
    if not rad > 0.0:
        return False
    qx, qy, qz, _ = _cluster_place(row[_R_BALL:_R_BALL + 3], rad, frame, g_hat)
    occ_start = occluders[0]
    for o in range(occ_start[b], occ_start[b + 1]):                 # another body's geom that could hide elements
        if not _clear_of(o, (qx, qy, qz), rad, occluders):
            return True
    return False


@njit(**INLINE)
def _near(row, now, tol):
    """Whether ``now`` (:func:`_reuse_state`) lies within ``tol`` of the last full evaluation in ``row``: the twist's
    key and gravity (sums of absolute component changes), the origin's depth within ``tol * REUSE_DEPTH`` m."""
    key, gb, c0 = now
    d = 0.0
    for c in range(6):
        d += abs(key[c] - row[_R_KEY + c])
    e = abs(gb[0] - row[_R_G]) + abs(gb[1] - row[_R_G + 1]) + abs(gb[2] - row[_R_G + 2])
    return d < tol and e < tol and abs(c0 - row[_R_DEPTH]) < tol * REUSE_DEPTH


@njit(**INLINE)
def _clear_of(o, centre, radius, occluders):
    """Whether occluder ``o`` (row of ``occluders``, :data:`OCCLUDERS`) cannot hide any point within ``radius`` (m)
    of ``centre`` (world, m): beyond its bounding sphere, or outside it as :func:`_outside_ball` tests."""
    occ_geom, occ_kind, occ_size, occ_rbound, occ_hs_start, occ_hs, margin, geom_xpos, geom_xmat = occluders[1:10]
    gid = occ_geom[o]
    e0, e1, e2 = centre[0] - geom_xpos[gid, 0], centre[1] - geom_xpos[gid, 1], centre[2] - geom_xpos[gid, 2]
    reach = occ_rbound[o] + radius
    if e0 * e0 + e1 * e1 + e2 * e2 >= reach * reach:
        return True
    gm = geom_xmat[gid]                                              # the centre in the geom frame
    x0, x1, x2 = gm[0] * e0 + gm[3] * e1 + gm[6] * e2, gm[1] * e0 + gm[4] * e1 + gm[7] * e2, \
        gm[2] * e0 + gm[5] * e1 + gm[8] * e2
    return _outside_ball(x0, x1, x2, radius, occ_kind[o], occ_size[o, 0], occ_size[o, 1], occ_size[o, 2], occ_hs,
                         occ_hs_start[o], occ_hs_start[o + 1], margin)


@njit(**INLINE)
def _remember(row, now, sums, count, deepest, occluded, box, steady):
    """Body b's full evaluation into its ``row`` of the reuse buffer (:func:`_reuse_state` reads it), reusable only if
    ``steady`` (:data:`REUSE_STEADY`: else just its key, gravity and depth, for the next evaluation's test); ``box``:
    the body-frame bounds of its submerged elements (min x, y, z, max x, y, z; m; empty: none submerged)."""
    key, gb, c0 = now
    for c in range(6):
        row[_R_KEY + c] = key[c]
        row[_R_SUM + c] = sums[c]
    row[_R_G], row[_R_G + 1], row[_R_G + 2], row[_R_DEPTH] = gb[0], gb[1], gb[2], c0
    row[_R_COUNT], row[_R_DEEPEST], row[_R_OCCLUDED] = count, deepest, occluded
    row[REUSE_VALID] = 1.0 if steady else 0.0
    if steady:                                           # else the last ball is kept (box is empty)
        r = 0.0
        for c in range(3):
            row[_R_BALL + c] = 0.5 * (box[c] + box[3 + c]) if box[c] <= box[3 + c] else 0.0
            r += (0.5 * (box[3 + c] - box[c])) ** 2 if box[c] <= box[3 + c] else 0.0
        row[_R_BALL + 3] = math.sqrt(r) + REUSE_PAD if box[0] <= box[3] else -1.0


@njit(**INLINE)
def _to_world(wrench, j, r, sums):
    """``wrench[j]`` from a wrench summed in the frame of a body with rotation ``r`` (9, row-major)."""
    for c in range(0, 6, 3):
        a0, a1, a2 = sums[c], sums[c + 1], sums[c + 2]
        wrench[j, c] = r[0] * a0 + r[1] * a1 + r[2] * a2
        wrench[j, c + 1] = r[3] * a0 + r[4] * a1 + r[5] * a2
        wrench[j, c + 2] = r[6] * a0 + r[7] * a1 + r[8] * a2


# --- the element pass on its own (tests, benchmarks) -----------------------------------------------------
class ElementPass:
    """The compiled element pass of B bodies without occluders, set up once and called per pose: the
    compiled counterpart of :func:`rft_mujoco.physics.elements.body_wrenches` (tests, benchmarks).

    Args:
        surface: the bodies' elements (:class:`rft_mujoco.physics.elements.BodySurface`, E elements on B bodies);
        terrain: FlatSurface, HeightfieldSurface or SandRegion; g_hat: (3,) unit gravity direction; gravity:
        (3,) m/s^2; media, guards: as the law's.
    """

    def __init__(self, surface, terrain, g_hat, gravity, media, guards):
        from rft_mujoco.compiled.law import tolerances
        from rft_mujoco.compiled.terrain import check_gravity
        from rft_mujoco.physics import law

        spec = ts.terrain_spec(terrain)
        if spec is None:
            raise ValueError(f"the compiled element pass supports the terrains with a kernel form (FlatSurface, "
                             f"HeightfieldSurface, SandRegion, DeformableSurface), "
                             f"got {type(terrain).__name__}; use rft_mujoco.physics.elements.body_wrenches")
        self.g_hat = np.ascontiguousarray(g_hat, dtype=float)
        check_gravity(terrain, spec, self.g_hat)
        local_centroids, local_normals, areas, elem_body, n_bodies = surface
        self.n_bodies = int(n_bodies)
        self.packed = pack(local_centroids, local_normals, areas, elem_body, self.n_bodies)
        occ = Occluders.none(self.n_bodies)
        g_mag = float(np.linalg.norm(gravity))
        kind, tp, heights = spec
        self._bodies = np.arange(self.n_bodies, dtype=np.int64)
        self._surface = tuple(self.packed.arrays())
        self._terrain = (self.g_hat, float(terrain.max_height), kind, tp, heights)
        self._law = (media.xi_n_at(g_mag), law.COEFFICIENTS, float(media.mu_surf), guards.no_tension,
                     guards.no_forward_tangential, guards.no_positive_power, tolerances())
        self._occluders = (*occ.arrays(), occ.margin, np.zeros((0, 3)), np.zeros((0, 9)))
        self._work = (np.zeros((SCRATCH_ROWS, CLUSTER_SIZE)), np.zeros((2, CLUSTER_SIZE), np.int64))
        self.wrench = np.zeros((self.n_bodies, 6))
        self.count = np.zeros(self.n_bodies, np.int64)
        self.max_depth = np.zeros(self.n_bodies)
        self._out = (self.wrench, self.count, self.max_depth, np.zeros(self.n_bodies))

    def __call__(self, body_pos, body_mat, body_com, v_com, omega):
        """(wrench (B, 6) [N, N m about the COM], loaded element count (B,), max depth (B,) m) of bodies at
        ``body_pos`` (B, 3) m, ``body_mat`` (B, 3, 3), COM ``body_com`` (B, 3) m moving with ``v_com``
        (B, 3) m/s and ``omega`` (B, 3) rad/s; the arrays are this object's buffers (overwritten per call)."""
        b = self.n_bodies
        f = np.ascontiguousarray
        wrenches(self._bodies, b, self._surface,
                 (f(body_pos, float), f(np.reshape(body_mat, (b, 9)), float), f(body_com, float)),
                 (f(v_com, float), f(omega, float)), self._terrain, self._law, self._occluders, self._work, self._out,
                 0.0)
        return self.wrench, self.count, self.max_depth


def body_wrenches(surface, pose, v_com, omega, terrain, g_hat, gravity, media, guards):
    """:func:`rft_mujoco.physics.elements.body_wrenches` (without ``active``) through the compiled pass:
    the same arguments and results (new arrays)."""
    run = ElementPass(surface, terrain, g_hat, gravity, media, guards)
    return tuple(x.copy() for x in run(*pose, v_com, omega))
