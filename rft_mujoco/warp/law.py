"""The 3D-RFT law (float64) and the terrain (float32) in warp: :func:`stress` ports
:func:`rft_mujoco.physics.law.stress_per_depth` (over ``xi_n``), :func:`depth` the terrains of
:mod:`rft_mujoco.physics.terrain` (flat, heightfield, and a sand region of either)."""

from __future__ import annotations

import warp as wp

from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.warp.common import F64, FLAT, LEADING_TOL, VERTICAL_TOL


# --- the law (float64; rft_mujoco.physics.law.stress_per_depth) ---------------------------------------
@wp.func
def _cubic(c: wp.array2d(dtype=F64), j: int, x1: F64, x2: F64, x3: F64):
    """sum_k c[k, j] t_k(x1, x2, x3), the terms in the order of law.cubic_terms."""
    x11 = x1 * x1
    x22 = x2 * x2
    x33 = x3 * x3
    return (c[0, j] + c[1, j] * x1 + c[2, j] * x2 + c[3, j] * x3 + c[4, j] * x11 + c[5, j] * x22
            + c[6, j] * x33 + c[7, j] * (x1 * x2) + c[8, j] * (x2 * x3) + c[9, j] * (x3 * x1)
            + c[10, j] * (x11 * x1) + c[11, j] * (x22 * x2) + c[12, j] * (x33 * x3) + c[13, j] * (x1 * x22)
            + c[14, j] * (x2 * x11) + c[15, j] * (x2 * x33) + c[16, j] * (x3 * x22) + c[17, j] * (x3 * x11)
            + c[18, j] * (x1 * x33) + c[19, j] * (x1 * x2 * x3))


@wp.func
def stress(n: wp.vec3d, v: wp.vec3d, g: wp.vec3d, c: wp.array2d(dtype=F64), mu_surf: F64, no_tension: int,
           no_forward: int, no_power: int):
    """law.stress_per_depth / xi_n of one element: unit normal ``n``, unit direction ``v``, unit gravity ``g``
    (float64: the implicit solve differentiates it by forward differences of 1e-7 of the speed)."""
    gn = wp.dot(n, g)
    vn = wp.dot(n, v)
    sign = F64(1.0)
    if wp.abs(gn) > F64(VERTICAL_TOL):
        if gn <= F64(0.0):
            sign = F64(-1.0)
    elif vn < -F64(LEADING_TOL):
        sign = F64(-1.0)
    x1 = wp.dot(v, g)
    x2 = gn * sign
    x3 = vn * sign
    f0 = _cubic(c, 0, x1, x2, x3)
    f1 = _cubic(c, 1, x1, x2, x3)
    f2 = _cubic(c, 2, x1, x2, x3)
    a = f0 * (n * sign) + f1 * v + f2 * g
    an = wp.dot(a, n)
    t = a - an * n
    if no_tension != 0 and an > F64(0.0):
        an = F64(0.0)
    tmag = wp.length(t)
    cap = F64(0.0)
    if tmag > F64(0.0):
        cap = wp.min(mu_surf * wp.abs(an) / tmag, F64(1.0))
    t = t * cap
    if no_forward != 0 and wp.dot(t, v) > F64(0.0):
        t = wp.vec3d()
    r = an * n + t
    if no_power != 0 and wp.dot(r, v) > F64(0.0):
        r = wp.vec3d()
    return r


# --- terrain (float32; rft_mujoco.physics.terrain) ---------------------------------------------------
@wp.func
def depth(p: wp.vec3, g: wp.vec3, w: int, kind: int, flat_height: wp.array(dtype=float),
          tp: wp.array(dtype=float), heights: wp.array2d(dtype=float)):
    """Depth (m) of world point ``p`` below the free surface of world ``w`` (-inf where there is no sand).

    ``tp``: the shared :func:`rft_mujoco.physics.terrain_spec.terrain_spec`'s parameters in float32, read by their
    named slots (:data:`rft_mujoco.physics.terrain_spec.PARAMS`); a flat surface's height is read from
    ``flat_height`` ((1 or nworld,) m: per world) instead of its ``height`` slot.
    """
    if tp[ts.TP_REGION] != 0.0:
        if not (p[0] >= tp[ts.TP_REGION_X0] and p[0] <= tp[ts.TP_REGION_X1] and p[1] >= tp[ts.TP_REGION_Y0]
                and p[1] <= tp[ts.TP_REGION_Y1]):
            return -wp.inf
    if kind == FLAT:
        return flat_height[w % flat_height.shape[0]] + wp.dot(p, g)
    nrow = heights.shape[0]
    ncol = heights.shape[1]
    u = (p[0] - tp[ts.TP_HF_X0]) / (tp[ts.TP_HF_X1] - tp[ts.TP_HF_X0]) * float(ncol - 1)
    v = (p[1] - tp[ts.TP_HF_Y0]) / (tp[ts.TP_HF_Y1] - tp[ts.TP_HF_Y0]) * float(nrow - 1)
    if not (wp.isfinite(u) and wp.isfinite(v)):
        return -wp.inf
    inside = u >= 0.0 and u <= float(ncol - 1) and v >= 0.0 and v <= float(nrow - 1)
    if tp[ts.TP_HF_OUTSIDE_NONE] != 0.0 and not inside:
        return -wp.inf
    u = wp.clamp(u, 0.0, float(ncol - 1))
    v = wp.clamp(v, 0.0, float(nrow - 1))
    i0 = wp.min(int(wp.floor(v)), nrow - 2)
    j0 = wp.min(int(wp.floor(u)), ncol - 2)
    fu = u - float(j0)
    fv = v - float(i0)
    z = ((1.0 - fv) * ((1.0 - fu) * heights[i0, j0] + fu * heights[i0, j0 + 1])
         + fv * ((1.0 - fu) * heights[i0 + 1, j0] + fu * heights[i0 + 1, j0 + 1]))
    return z - p[2]
