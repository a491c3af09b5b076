"""Run-time culling in warp: which elements lie inside a geom of another weld group (float32).

The CPU path's test (:func:`rft_mujoco.compiled.elements._inside`, the numba port of
:func:`rft_mujoco.geometry.occlusion.inside_geom`) on the same occluder list
(:func:`rft_mujoco.compiled.elements.occluders`: every surface geom of every body of another weld group,
the world's included, terrain excluded) and margin (``Occluders.margin``,
:data:`rft_mujoco.geometry.occlusion.OCCLUSION_TOL`); meshes by their convex hull's halfspaces. The device
arrays (:func:`device_arrays`) are made once at attach; per evaluation :func:`near_occluders` keeps, for each
world, the occluders whose bounding sphere reaches the bounding sphere of a touching body (the CPU path's
per-cluster sphere test, per body here), and the element pass (:func:`rft_mujoco.warp.elements.force_pass`)
tests each submerged element against those only. Both are shortcuts: the result is the full test's.
"""

from __future__ import annotations

import mujoco
import numpy as np
import warp as wp

from rft_mujoco.warp.common import F64

_G = mujoco.mjtGeom
SPHERE = wp.constant(int(_G.mjGEOM_SPHERE))
CAPSULE = wp.constant(int(_G.mjGEOM_CAPSULE))
CYLINDER = wp.constant(int(_G.mjGEOM_CYLINDER))
BOX = wp.constant(int(_G.mjGEOM_BOX))
ELLIPSOID = wp.constant(int(_G.mjGEOM_ELLIPSOID))
MESH = wp.constant(int(_G.mjGEOM_MESH))


def device_arrays(occ, n_bodies: int, device) -> dict:
    """Warp arrays of a :class:`rft_mujoco.geometry.occlusion.Occluders` (``occ``) of ``n_bodies`` bodies: the
    kernels' ``occ_*`` arguments (empty tables get one unused row: warp arrays are never empty here)."""
    n = int(occ.geom.size)
    start = np.ascontiguousarray(occ.start, dtype=np.int32)
    body = np.repeat(np.arange(n_bodies, dtype=np.int32), np.diff(start))
    rows = max(n, 1)
    pad = lambda x, shape, dtype: np.zeros(shape, dtype) if n == 0 else np.ascontiguousarray(x, dtype)  # noqa: E731
    hs = occ.halfspaces if occ.halfspaces.shape[0] else np.zeros((1, 4))
    i4 = lambda x: wp.array(x, dtype=int, device=device)  # noqa: E731
    return dict(
        n=n, occ_start=i4(start), occ_body=i4(pad(body, rows, np.int32)), occ_geom=i4(pad(occ.geom, rows, np.int32)),
        occ_kind=i4(pad(occ.kind, rows, np.int32)),
        occ_size=wp.array(pad(occ.size, (rows, 3), np.float32), dtype=wp.vec3, device=device),
        occ_rbound=wp.array(pad(occ.rbound, rows, np.float32), dtype=float, device=device),
        occ_hs_start=i4(np.ascontiguousarray(occ.hs_start, dtype=np.int32)),
        occ_hs=wp.array(np.ascontiguousarray(hs, dtype=np.float32), dtype=wp.vec4, device=device),
        margin=float(occ.margin))


@wp.func
def inside(x: wp.vec3, kind: int, s: wp.vec3, hs: wp.array(dtype=wp.vec4), h0: int, h1: int, margin: float):
    """1 when ``x`` (m, in the geom's frame) is deeper than ``margin`` inside the geom (type ``kind``, MuJoCo
    ``geom_size`` ``s``; a mesh: halfspaces ``hs[h0:h1]`` = (n, offset), n . x <= offset inside), else 0."""
    if kind == SPHERE:
        r = s[0] - margin
        if r > 0.0 and wp.dot(x, x) < r * r:
            return 1
        return 0
    if kind == CAPSULE:
        a = x[2] - wp.clamp(x[2], -s[1], s[1])
        r = s[0] - margin
        if r > 0.0 and x[0] * x[0] + x[1] * x[1] + a * a < r * r:
            return 1
        return 0
    if kind == CYLINDER:
        r = s[0] - margin
        if r > 0.0 and x[0] * x[0] + x[1] * x[1] < r * r and wp.abs(x[2]) < s[1] - margin:
            return 1
        return 0
    if kind == BOX:
        if wp.abs(x[0]) < s[0] - margin and wp.abs(x[1]) < s[1] - margin and wp.abs(x[2]) < s[2] - margin:
            return 1
        return 0
    if kind == ELLIPSOID:
        a = s[0] - margin
        b = s[1] - margin
        c = s[2] - margin
        if a <= 0.0 or b <= 0.0 or c <= 0.0:
            return 0
        if (x[0] / a) * (x[0] / a) + (x[1] / b) * (x[1] / b) + (x[2] / c) * (x[2] / c) < 1.0:
            return 1
        return 0
    if kind == MESH:
        if h1 <= h0:
            return 0
        for k in range(h0, h1):
            h = hs[k]
            if not (h[0] * x[0] + h[1] * x[1] + h[2] * x[2] < h[3] - margin):
                return 0
        return 1
    return 0


@wp.func
def hidden(w: int, b: int, p: wp.vec3, occ_start: wp.array(dtype=int), occ_geom: wp.array(dtype=int),
           occ_kind: wp.array(dtype=int), occ_size: wp.array(dtype=wp.vec3), occ_rbound: wp.array(dtype=float),
           occ_hs_start: wp.array(dtype=int), occ_hs: wp.array(dtype=wp.vec4), margin: float,
           near: wp.array2d(dtype=int), geom_xpos: wp.array2d(dtype=wp.vec3), geom_xmat: wp.array2d(dtype=wp.mat33)):
    """1 when world point ``p`` (an element of attached body b in world w) is inside one of b's occluders."""
    out = int(0)
    for o in range(occ_start[b], occ_start[b + 1]):
        if near[w, o] == 0:
            continue
        gid = occ_geom[o]
        d = p - geom_xpos[w, gid]
        rb = occ_rbound[o]
        if wp.dot(d, d) >= rb * rb:                     # outside the geom's bounding sphere
            continue
        if inside(wp.transpose(geom_xmat[w, gid]) * d, occ_kind[o], occ_size[o], occ_hs, occ_hs_start[o],
                  occ_hs_start[o + 1], margin) != 0:
            out = 1
            break
    return out


@wp.kernel
def near_occluders(body_id: wp.array(dtype=int), bound_center: wp.array(dtype=wp.vec3),
                   bound_radius: wp.array(dtype=F64), occ_body: wp.array(dtype=int), occ_geom: wp.array(dtype=int),
                   occ_rbound: wp.array(dtype=float), xpos: wp.array2d(dtype=wp.vec3),
                   xmat: wp.array2d(dtype=wp.mat33), geom_xpos: wp.array2d(dtype=wp.vec3),
                   touch: wp.array2d(dtype=int), near: wp.array2d(dtype=int)):
    """near[w, o] = 1 when occluder o's bounding sphere reaches the bounding sphere of its body (touching in w)."""
    w, o = wp.tid()
    b = occ_body[o]
    near[w, o] = 0
    if touch[w, b] == 0:
        return
    bid = body_id[b]
    d = xpos[w, bid] + xmat[w, bid] * bound_center[b] - geom_xpos[w, occ_geom[o]]
    reach = float(bound_radius[b]) + occ_rbound[o]
    if wp.dot(d, d) < reach * reach:
        near[w, o] = 1
