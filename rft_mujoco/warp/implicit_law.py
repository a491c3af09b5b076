"""The implicit solve's law on the batched sand (float64): :func:`rft_mujoco.physics.elements.body_wrench_jacobians`
(the regularized 3D-RFT law and its forward-difference derivative) and the compiled
:mod:`rft_mujoco.compiled.implicit_law`'s split into a once-per-evaluation candidate pass and law evaluations.

* :func:`candidates` (nworld, E): the submerged, unculled elements of the touching bodies (their depth in
  ``e_depth``, 0 elsewhere) and each body's submerged area inside another weld group's geom;
* :func:`law_pass` (nworld, E): the regularized law at each body's COM twist, summed into per-body wrenches
  (about the COM), counts and depths: the capacity test's probe and the final wrenches;
* :func:`group_law` (one thread of a world): the law and its derivative at the flowing groups' twists about
  their reference points, in the solve's scaled coordinates (a Newton iteration of
  :mod:`rft_mujoco.warp.implicit`).
"""

from __future__ import annotations

import warp as wp

from rft_mujoco.physics import elements as _elements
from rft_mujoco.physics import implicit as _implicit
from rft_mujoco.warp.common import F64, LEADING_TOL, ZERO_SPEED, gravity_of, v3d
from rft_mujoco.warp.elements import exposed_depth
from rft_mujoco.warp.law import stress

wp.set_module_options({"enable_backward": False})      # forward only: no adjoints to compile

FD_STEP = wp.constant(F64(_elements.FD_STEP))
LEADING_RAMP = wp.constant(F64(_elements.LEADING_RAMP))
SPEED_SCALE = wp.constant(F64(_implicit.SPEED_SCALE))


@wp.struct
class Law:
    """What the law passes read besides the twists: the elements, the poses, gravity, the medium of each world, the
    guards and the candidates' depths (built once per (handle, Data): :mod:`rft_mujoco.warp.implicit_eval`)."""

    body_id: wp.array(dtype=int)
    elem_body: wp.array(dtype=int)
    centroid: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    area: wp.array(dtype=float)
    group_ref: wp.array(dtype=int)
    xpos: wp.array2d(dtype=wp.vec3)
    xmat: wp.array2d(dtype=wp.mat33)
    xipos: wp.array2d(dtype=wp.vec3)
    gravity: wp.array(dtype=wp.vec3)
    coef: wp.array2d(dtype=F64)
    xi_per_g: wp.array(dtype=float)
    mu_surf: wp.array(dtype=float)
    no_tension: int
    no_forward: int
    no_power: int
    e_depth: wp.array2d(dtype=float)


@wp.func
def _m33d(m: wp.mat33):
    return wp.mat33d(F64(m[0, 0]), F64(m[0, 1]), F64(m[0, 2]), F64(m[1, 0]), F64(m[1, 1]), F64(m[1, 2]),
                     F64(m[2, 0]), F64(m[2, 1]), F64(m[2, 2]))


@wp.func
def element_frame(w: int, bid: int, e: int, xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33),
                  centroid: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3)):
    """World position (m) and unit normal of element ``e`` of body ``bid`` in world ``w``, float64."""
    rot = _m33d(xmat[w, bid])
    return v3d(xpos[w, bid]) + rot * v3d(centroid[e]), rot * v3d(normal[e])


@wp.func
def _ramped_force(n: wp.vec3d, vel: wp.vec3d, g: wp.vec3d, coef: wp.array2d(dtype=F64), mu: F64, no_tension: int,
                  no_forward: int, no_power: int, scale: F64):
    """The regularized law's force (N) of one element at velocity ``vel`` (m/s), ``scale`` = xi_n depth area:
    the published stress at the ramped direction (elements.ramped_directions) times phi(|v|) and the ramp's
    weight."""
    s = wp.length(vel)
    vh = vel / s
    c = wp.dot(n, vh)
    behind = F64(0.0)
    if c < -F64(LEADING_TOL):
        behind = c
    u = (vh - behind * n) / wp.sqrt(F64(1.0) - behind * behind)
    weight = wp.min(F64(1.0), (c + LEADING_RAMP) / (LEADING_RAMP - F64(LEADING_TOL)))
    phi = s / wp.sqrt(s * s + SPEED_SCALE * SPEED_SCALE)
    return stress(n, u, g, coef, mu, no_tension, no_forward, no_power) * (scale * phi * weight)


@wp.func
def _loaded(n: wp.vec3d, vel: wp.vec3d):
    """The speed (m/s) of an element that carries stress under the regularized law, else 0 (elements.loaded_elements
    with the ramp)."""
    speed = wp.length(vel)
    if not (speed > F64(ZERO_SPEED)):
        return F64(0.0)
    if wp.dot(n, vel / speed) < -LEADING_RAMP:
        return F64(0.0)
    return speed


@wp.func
def element_jacobian(n: wp.vec3d, vel: wp.vec3d, speed: F64, g: wp.vec3d, coef: wp.array2d(dtype=F64), mu: F64,
                     no_tension: int, no_forward: int, no_power: int, scale: F64):
    """The regularized force (N) of a loaded element and its derivative in the element's velocity (N s/m) by
    forward differences of ``FD_STEP max(speed, SPEED_SCALE)`` (the leading set held)."""
    f = _ramped_force(n, vel, g, coef, mu, no_tension, no_forward, no_power, scale)
    h = FD_STEP * wp.max(speed, SPEED_SCALE)
    d0 = (_ramped_force(n, vel + wp.vec3d(h, F64(0.0), F64(0.0)), g, coef, mu, no_tension, no_forward, no_power,
                        scale) - f) / h
    d1 = (_ramped_force(n, vel + wp.vec3d(F64(0.0), h, F64(0.0)), g, coef, mu, no_tension, no_forward, no_power,
                        scale) - f) / h
    d2 = (_ramped_force(n, vel + wp.vec3d(F64(0.0), F64(0.0), h), g, coef, mu, no_tension, no_forward, no_power,
                        scale) - f) / h
    return f, wp.mat33d(d0[0], d1[0], d2[0], d0[1], d1[1], d2[1], d0[2], d1[2], d2[2])


@wp.kernel
def candidates(body_id: wp.array(dtype=int), elem_body: wp.array(dtype=int), centroid: wp.array(dtype=wp.vec3),
               area: wp.array(dtype=float), elem_mask: wp.array2d(dtype=int), xpos: wp.array2d(dtype=wp.vec3),
               xmat: wp.array2d(dtype=wp.mat33), gravity: wp.array(dtype=wp.vec3), kind: int,
               flat_height: wp.array(dtype=float), tp: wp.array(dtype=float), heights: wp.array2d(dtype=float),
               touch: wp.array2d(dtype=int), occ_start: wp.array(dtype=int), occ_geom: wp.array(dtype=int),
               occ_kind: wp.array(dtype=int), occ_size: wp.array(dtype=wp.vec3), occ_rbound: wp.array(dtype=float),
               occ_hs_start: wp.array(dtype=int), occ_hs: wp.array(dtype=wp.vec4), margin: float,
               near: wp.array2d(dtype=int), geom_xpos: wp.array2d(dtype=wp.vec3),
               geom_xmat: wp.array2d(dtype=wp.mat33), e_depth: wp.array2d(dtype=float),
               occluded: wp.array2d(dtype=float)):
    """``e_depth[w, e]``: the depth (m) of each submerged element of a touching body that is not inside another weld
    group's geom, 0 for every other element; the submerged area inside one (m^2) into ``occluded[w, b]``
    (implicit_law.loaded_candidates; the depth and culling tests of the explicit element pass)."""
    w, e = wp.tid()
    e_depth[w, e] = 0.0
    if elem_mask[w % elem_mask.shape[0], e] == 0:
        return
    b = elem_body[e]
    if touch[w, b] == 0:
        return
    bid = body_id[b]
    p = xpos[w, bid] + xmat[w, bid] * centroid[e]
    g, _mag = gravity_of(gravity, w)
    e_depth[w, e] = exposed_depth(w, b, p, g, kind, flat_height, tp, heights, area[e], occ_start, occ_geom,
                                  occ_kind, occ_size, occ_rbound, occ_hs_start, occ_hs, margin, near, geom_xpos,
                                  geom_xmat, occluded)


@wp.kernel
def law_pass(lw: Law, redo: wp.array2d(dtype=int), v_lin: wp.array2d(dtype=wp.vec3d),
             v_ang: wp.array2d(dtype=wp.vec3d), wrench: wp.array2d(dtype=wp.spatial_vectord),
             count: wp.array2d(dtype=int), max_depth: wp.array2d(dtype=float)):
    """The regularized law of every candidate element at its body's COM twist (``v_lin`` m/s, ``v_ang`` rad/s),
    summed into ``wrench[w, b]`` (N, N m about the COM; zeroed by the caller), the loaded count and the deepest
    loaded depth (m), for the bodies with ``redo[w, b] != 0`` (the others are left alone)."""
    w, e = wp.tid()
    z = lw.e_depth[w, e]
    if z <= 0.0:
        return
    b = lw.elem_body[e]
    if redo[w, b] == 0:
        return
    bid = lw.body_id[b]
    p, n = element_frame(w, bid, e, lw.xpos, lw.xmat, lw.centroid, lw.normal)
    arm = p - v3d(lw.xipos[w, bid])
    vel = v_lin[w, b] + wp.cross(v_ang[w, b], arm)
    if _loaded(n, vel) == F64(0.0):
        return
    g, xi_n = _gravity(w, lw)
    f = _ramped_force(n, vel, g, lw.coef, F64(lw.mu_surf[w]), lw.no_tension, lw.no_forward, lw.no_power,
                      xi_n * F64(z) * F64(lw.area[e]))
    tq = wp.cross(arm, f)
    wp.atomic_add(wrench, w, b, wp.spatial_vectord(f[0], f[1], f[2], tq[0], tq[1], tq[2]))
    wp.atomic_add(count, w, b, 1)
    wp.atomic_max(max_depth, w, b, z)


@wp.func
def _gravity(w: int, lw: Law):
    """World w's unit gravity (float64) and ``xi_n`` (N/m^3) of its medium."""
    gv = lw.gravity[w % lw.gravity.shape[0]]
    mag = wp.length(gv)
    return wp.vec3d(F64(gv[0] / mag), F64(gv[1] / mag), F64(gv[2] / mag)), F64(lw.xi_per_g[w] * mag)


@wp.func
def group_law(w: int, lw: Law, flow: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
              active: wp.array2d(dtype=int), n6: int, group_radius: wp.array(dtype=F64), u: wp.array2d(dtype=F64),
              out_w: wp.array2d(dtype=F64), out_j: wp.array3d(dtype=F64)):
    """The regularized law at the scaled twists ``u[6 r:6 r + 6, w]`` (m/s, rad/s times the radius) of the groups
    r with ``flow[r, w] != 0``, about their reference points: ``out_w[6 r:6 r + 6, w]`` the scaled wrench (N, N m
    over the radius) and ``out_j[6 r + i, j, w]`` its derivative in the scaled twist (elements.body_wrench_jacobians
    shifted to the reference point, implicit._newton_flow's ``sw df / sv``)."""
    g, xi_n = _gravity(w, lw)
    mu = F64(lw.mu_surf[w])
    for i in range(n6):
        out_w[i, w] = F64(0.0)
        for j in range(6):
            out_j[i, j, w] = F64(0.0)
    for e in range(lw.elem_body.shape[0]):
        z = lw.e_depth[w, e]
        if z <= 0.0:
            continue
        b = lw.elem_body[e]
        r = slot[b, w]
        if r < 0:
            continue
        if flow[r, w] == 0:
            continue
        grp = active[r, w]
        rad = group_radius[grp]
        o = 6 * r
        bid = lw.body_id[b]
        p, n = element_frame(w, bid, e, lw.xpos, lw.xmat, lw.centroid, lw.normal)
        arm = p - v3d(lw.xipos[w, lw.body_id[lw.group_ref[grp]]])
        om = wp.vec3d(u[o + 3, w], u[o + 4, w], u[o + 5, w]) / rad
        vel = wp.vec3d(u[o, w], u[o + 1, w], u[o + 2, w]) + wp.cross(om, arm)
        speed = _loaded(n, vel)
        if speed == F64(0.0):
            continue
        f, dfdv = element_jacobian(n, vel, speed, g, lw.coef, mu, lw.no_tension, lw.no_forward, lw.no_power,
                                   xi_n * F64(z) * F64(lw.area[e]))
        tq = wp.cross(arm, f)
        cr = wp.skew(arm)
        dfw = -(dfdv * cr)                    # d f / d omega: v = u_lin - [arm]x omega
        dtv = cr * dfdv
        dtw = cr * dfw
        for i in range(3):
            out_w[o + i, w] = out_w[o + i, w] + f[i]
            out_w[o + 3 + i, w] = out_w[o + 3 + i, w] + tq[i] / rad
            for j in range(3):
                out_j[o + i, j, w] = out_j[o + i, j, w] + dfdv[i, j]
                out_j[o + i, 3 + j, w] = out_j[o + i, 3 + j, w] + dfw[i, j] / rad
                out_j[o + 3 + i, j, w] = out_j[o + 3 + i, j, w] + dtv[i, j] / rad
                out_j[o + 3 + i, 3 + j, w] = out_j[o + 3 + i, 3 + j, w] + dtw[i, j] / (rad * rad)
