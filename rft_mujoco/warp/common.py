"""What every kernel module of the batched sand shares: warp constants from the CPU path's tolerances, error
bits, terrain kinds, and small conversions (float32 <-> float64 spatial vectors, gravity of a world).

Imports nothing of :mod:`rft_mujoco.warp` (the bottom of its import graph).
"""

from __future__ import annotations

import warp as wp

from rft_mujoco import tol
from rft_mujoco.physics import law, rest, terrain_spec

F64 = wp.float64

LEADING_TOL = wp.constant(float(law.LEADING_TOL))
VERTICAL_TOL = wp.constant(float(law.VERTICAL_TOL))
ZERO_SPEED = wp.constant(float(law.ZERO_SPEED))
DEPENDENT_TOL = wp.constant(F64(rest.DEPENDENT_TOL))
WEIGHT_FLOOR = wp.constant(F64(rest.WEIGHT_FLOOR))
CAPACITY_TOL = wp.constant(F64(rest.CAPACITY_TOL))
TINY = wp.constant(F64(tol.TINY))
TIME_RTOL = wp.constant(F64(tol.TIME_RTOL))
TIME_F32_RTOL = wp.constant(F64(4.0e-7))
"""MuJoCo Warp keeps ``time`` in float32: "advanced by at most one step" also allows 4e-7 |t| (about 3 ulp)."""

FLAT = wp.constant(terrain_spec.FLAT)
"""Terrain kinds: :class:`rft_mujoco.physics.terrain_spec.TerrainKind`'s (the kinds warp evaluates)."""
HEIGHTFIELD = wp.constant(terrain_spec.HEIGHTFIELD)

NOT_FINITE = wp.constant(1)
"""Bit of ``errors``: a sand wrench came out non-finite; that world got no sand in that evaluation."""
BAD_ACCELERATION = wp.constant(2)
"""Bit of ``errors``: the acceleration without sand was not finite (NaN/inf in ctrl, forces or state)."""

@wp.func
def gravity_of(gravity: wp.array(dtype=wp.vec3), w: int):
    """Unit gravity direction and magnitude (m/s^2) of world ``w`` (MuJoCo Warp batches opt.gravity)."""
    g = gravity[w % gravity.shape[0]]
    mag = wp.length(g)
    return g / mag, mag


@wp.func
def v3d(x: wp.vec3):
    return wp.vec3d(F64(x[0]), F64(x[1]), F64(x[2]))


@wp.func
def norm6(x: wp.spatial_vectord, r: F64):
    """|(x[:3], x[3:] / r)|."""
    return wp.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]) / (r * r))


@wp.func
def sv64(x: wp.spatial_vector):
    return wp.spatial_vectord(F64(x[0]), F64(x[1]), F64(x[2]), F64(x[3]), F64(x[4]), F64(x[5]))


@wp.func
def sv32(x: wp.spatial_vectord):
    return wp.spatial_vector(float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), float(x[5]))


@wp.func
def cholesky(w: int, a: wp.array3d(dtype=F64), n: int):
    """a[:n, :n, w] := its lower Cholesky factor, in place (lower triangle read and written); a pivot at
    most TINY becomes sqrt(TINY) (the rest solve's rule; never reached by a mass matrix)."""
    for c in range(n):
        t = a[c, c, w]
        for k in range(c):
            t -= a[c, k, w] * a[c, k, w]
        d = wp.sqrt(TINY)
        if t > TINY:
            d = wp.sqrt(t)
        a[c, c, w] = d
        for r in range(c + 1, n):
            s = a[r, c, w]
            for k in range(c):
                s -= a[r, k, w] * a[c, k, w]
            a[r, c, w] = s / d
