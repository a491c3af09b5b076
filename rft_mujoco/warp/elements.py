"""The element passes of the batched sand (float32; :func:`rft_mujoco.physics.elements.body_wrenches` and the
compiled :func:`rft_mujoco.compiled.elements.wrenches`): which attached bodies touch the sand, and the 3D-RFT
wrench of each touching body from its elements, run-time culling included (:mod:`rft_mujoco.warp.occlusion`).
One thread per (world, element); per-body sums by atomics."""

from __future__ import annotations

import warp as wp

from rft_mujoco.warp.common import F64, LEADING_TOL, ZERO_SPEED, gravity_of, v3d
from rft_mujoco.warp.law import depth, stress
from rft_mujoco.warp.occlusion import hidden


@wp.kernel
def touch_pass(body_id: wp.array(dtype=int), elem_body: wp.array(dtype=int), centroid: wp.array(dtype=wp.vec3),
               elem_mask: wp.array2d(dtype=int), cand: wp.array2d(dtype=int), xpos: wp.array2d(dtype=wp.vec3),
               xmat: wp.array2d(dtype=wp.mat33), gravity: wp.array(dtype=wp.vec3), kind: int,
               flat_height: wp.array(dtype=float), tp: wp.array(dtype=float), heights: wp.array2d(dtype=float),
               touch: wp.array2d(dtype=int)):
    """touch[w, b] = 1 when an active element of attached body b is below the surface (the CPU broadphase and
    depth pre-pass; the broadphase is only a shortcut there and changes nothing). Elements inside an occluder
    count here, as on the CPU path: culling removes their stress, not the body's contact with the sand."""
    w, e = wp.tid()
    b = elem_body[e]
    if cand[w, b] == 0 or elem_mask[w % elem_mask.shape[0], e] == 0:
        return
    bid = body_id[b]
    p = xpos[w, bid] + xmat[w, bid] * centroid[e]
    g, _mag = gravity_of(gravity, w)
    if depth(p, g, w, kind, flat_height, tp, heights) > 0.0:
        touch[w, b] = 1


@wp.func
def exposed_depth(w: int, b: int, p: wp.vec3, g: wp.vec3, kind: int, flat_height: wp.array(dtype=float),
                  tp: wp.array(dtype=float), heights: wp.array2d(dtype=float), area: float,
                  occ_start: wp.array(dtype=int), occ_geom: wp.array(dtype=int), occ_kind: wp.array(dtype=int),
                  occ_size: wp.array(dtype=wp.vec3), occ_rbound: wp.array(dtype=float),
                  occ_hs_start: wp.array(dtype=int), occ_hs: wp.array(dtype=wp.vec4), margin: float,
                  near: wp.array2d(dtype=int), geom_xpos: wp.array2d(dtype=wp.vec3),
                  geom_xmat: wp.array2d(dtype=wp.mat33), occluded: wp.array2d(dtype=float)):
    """The depth (m) of an element of attached body b at world point ``p`` when it is submerged and not inside
    one of the body's occluders, else 0; a submerged hidden element's ``area`` (m^2) goes to ``occluded[w, b]``."""
    z = depth(p, g, w, kind, flat_height, tp, heights)
    if not (z > 0.0):
        return 0.0
    if hidden(w, b, p, occ_start, occ_geom, occ_kind, occ_size, occ_rbound, occ_hs_start, occ_hs, margin, near,
              geom_xpos, geom_xmat) != 0:
        wp.atomic_add(occluded, w, b, area)
        return 0.0
    return z


@wp.kernel
def force_pass(body_id: wp.array(dtype=int), elem_body: wp.array(dtype=int), centroid: wp.array(dtype=wp.vec3),
               normal: wp.array(dtype=wp.vec3), area: wp.array(dtype=float), elem_mask: wp.array2d(dtype=int),
               xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), xipos: wp.array2d(dtype=wp.vec3),
               gravity: wp.array(dtype=wp.vec3), kind: int, flat_height: wp.array(dtype=float),
               tp: wp.array(dtype=float), heights: wp.array2d(dtype=float), coef: wp.array2d(dtype=F64),
               xi_per_g: wp.array(dtype=float), mu_surf: wp.array(dtype=float), no_tension: int, no_forward: int,
               no_power: int, touch: wp.array2d(dtype=int), v_lin: wp.array2d(dtype=wp.vec3),
               v_ang: wp.array2d(dtype=wp.vec3), wrench: wp.array2d(dtype=wp.spatial_vector),
               count: wp.array2d(dtype=int), max_depth: wp.array2d(dtype=float),
               occ_start: wp.array(dtype=int), occ_geom: wp.array(dtype=int), occ_kind: wp.array(dtype=int),
               occ_size: wp.array(dtype=wp.vec3), occ_rbound: wp.array(dtype=float),
               occ_hs_start: wp.array(dtype=int), occ_hs: wp.array(dtype=wp.vec4), margin: float,
               near: wp.array2d(dtype=int), geom_xpos: wp.array2d(dtype=wp.vec3),
               geom_xmat: wp.array2d(dtype=wp.mat33), occluded: wp.array2d(dtype=float)):
    """Each submerged, moving, leading element's force ``alpha |z| dA`` at the motion of its body's COM
    (``v_lin`` m/s, ``v_ang`` rad/s): summed into wrench[w, b] = (force N, torque N m about the body's COM),
    with the count of loaded elements and the deepest loaded depth (m). A submerged element inside one of
    its body's occluders (``occ_*``, ``near``) carries nothing; its area (m^2) goes to ``occluded[w, b]``."""
    w, e = wp.tid()
    if elem_mask[w % elem_mask.shape[0], e] == 0:
        return
    b = elem_body[e]
    if touch[w, b] == 0:
        return
    bid = body_id[b]
    rot = xmat[w, bid]
    p = xpos[w, bid] + rot * centroid[e]
    g, g_mag = gravity_of(gravity, w)
    z = exposed_depth(w, b, p, g, kind, flat_height, tp, heights, area[e], occ_start, occ_geom, occ_kind,
                      occ_size, occ_rbound, occ_hs_start, occ_hs, margin, near, geom_xpos, geom_xmat, occluded)
    if not (z > 0.0):
        return
    arm = p - xipos[w, bid]
    vel = v_lin[w, b] + wp.cross(v_ang[w, b], arm)
    speed = wp.length(vel)
    if not (speed > ZERO_SPEED):
        return
    v = vel / speed
    n = rot * normal[e]
    if wp.dot(n, v) < -LEADING_TOL:
        return
    xi_n = xi_per_g[w] * g_mag
    s = stress(v3d(n), v3d(v), v3d(g), coef, F64(mu_surf[w]), no_tension, no_forward, no_power)
    f = wp.vec3(float(s[0]), float(s[1]), float(s[2])) * (xi_n * z * area[e])
    wp.atomic_add(wrench, w, b, wp.spatial_vector(f, wp.cross(arm, f)))
    wp.atomic_add(count, w, b, 1)
    wp.atomic_max(max_depth, w, b, z)
