"""The 3D-RFT law compiled: per-element stress (inlined into the element loops) and ``element_forces``.

The same numbers as :func:`rft_mujoco.physics.law.element_forces` (to round-off, tests/test_compiled_element_pass.py)
without numpy temporaries. Tolerances and coefficients are passed at run time: numba would freeze module
globals into its on-disk cache, which does not see edits of physics/law.py.
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np

from rft_mujoco.compiled.jit import INLINE, JIT_LAW, njit
from rft_mujoco.physics import elements, law
from rft_mujoco.physics.law import Guards
from rft_mujoco.physics.media import Media

CHUNK = 256
"""Elements per chunk of :func:`element_forces`."""


def tolerances() -> np.ndarray:
    """(4,) [LEADING_TOL, VERTICAL_TOL, ZERO_SPEED] of :mod:`rft_mujoco.physics.law` and the implicit solve's
    :data:`rft_mujoco.physics.elements.LEADING_RAMP`, for the kernels."""
    return np.array([law.LEADING_TOL, law.VERTICAL_TOL, law.ZERO_SPEED, elements.LEADING_RAMP])


_TOLERANCES = tolerances()   # element_forces passes it every call (writable: numba types read-only arrays apart)


# --- scalar building blocks (inlined) ----------------------------------------------------------------
@njit(**INLINE)
def _coef(C):
    """The (20, 3) coefficient table as a 60-tuple (column-major), hoisted out of the element loops."""
    return (C[0, 0], C[1, 0], C[2, 0], C[3, 0], C[4, 0], C[5, 0], C[6, 0], C[7, 0], C[8, 0], C[9, 0],
            C[10, 0], C[11, 0], C[12, 0], C[13, 0], C[14, 0], C[15, 0], C[16, 0], C[17, 0], C[18, 0], C[19, 0],
            C[0, 1], C[1, 1], C[2, 1], C[3, 1], C[4, 1], C[5, 1], C[6, 1], C[7, 1], C[8, 1], C[9, 1],
            C[10, 1], C[11, 1], C[12, 1], C[13, 1], C[14, 1], C[15, 1], C[16, 1], C[17, 1], C[18, 1], C[19, 1],
            C[0, 2], C[1, 2], C[2, 2], C[3, 2], C[4, 2], C[5, 2], C[6, 2], C[7, 2], C[8, 2], C[9, 2],
            C[10, 2], C[11, 2], C[12, 2], C[13, 2], C[14, 2], C[15, 2], C[16, 2], C[17, 2], C[18, 2], C[19, 2])


@njit(**INLINE)
def _cubic(c, o, x1, x2, x3, x11, x22, x33, x12, x23, x31):
    """sum_k C[k, j] T_k(x1, x2, x3) for the column starting at ``o`` of the 60-tuple (law.cubic_terms), as six
    short partial sums (one chain of 20 multiply-adds would make every element wait on its latency)."""
    p0 = c[o] + c[o + 1] * x1 + c[o + 2] * x2 + c[o + 3] * x3
    p1 = c[o + 4] * x11 + c[o + 5] * x22 + c[o + 6] * x33
    p2 = c[o + 7] * x12 + c[o + 8] * x23 + c[o + 9] * x31
    p3 = c[o + 10] * (x11 * x1) + c[o + 11] * (x22 * x2) + c[o + 12] * (x33 * x3) + c[o + 19] * (x12 * x3)
    p4 = c[o + 13] * (x1 * x22) + c[o + 14] * (x2 * x11) + c[o + 15] * (x2 * x33)
    p5 = c[o + 16] * (x3 * x22) + c[o + 17] * (x3 * x11) + c[o + 18] * (x1 * x33)
    return (p0 + p1) + (p2 + p3) + (p4 + p5)


@njit(**INLINE)
def _ramped(n0, n1, n2, vx, vy, vz, lead_tol, ramp):
    """:func:`rft_mujoco.physics.elements.ramped_directions` of one element (unit normal, unit direction): the
    direction the stress is taken at and its weight (``lead_tol``, ``ramp``: ``tol[0]``, ``tol[3]``)."""
    c = n0 * vx + n1 * vy + n2 * vz
    b = c if c < -lead_tol else 0.0
    inv = 1.0 / math.sqrt(1.0 - b * b)
    return (vx - b * n0) * inv, (vy - b * n1) * inv, (vz - b * n2) * inv, min(1.0, (c + ramp) / (ramp - lead_tol))


@njit(**INLINE)
def _law_direction(n0, n1, n2, vx, vy, vz, sp, speed_scale, lead_tol, ramp):
    """The unit direction at which an element moving with ``v`` (m/s, speed ``sp`` > 0) takes its stress, and the
    factor the stress carries: the published law's ``(v/|v|, 1)`` with ``speed_scale`` 0; with
    ``speed_scale = c > 0`` the implicit solve's regularized law's (:func:`_ramped`, the weight times
    ``|v| / sqrt(|v|^2 + c^2)``). The element pass and the implicit solve's law (its forward differences too)
    take their stress through this one function."""
    inv = 1.0 / sp
    dx, dy, dz = vx * inv, vy * inv, vz * inv
    if speed_scale > 0.0:
        dx, dy, dz, w = _ramped(n0, n1, n2, dx, dy, dz, lead_tol, ramp)
        return dx, dy, dz, w * (sp / math.sqrt(sp * sp + speed_scale * speed_scale))
    return dx, dy, dz, 1.0


STRESS_GUARDS = ("mu_surf", "no_tension", "no_forward", "no_power", "lead_tol", "vert_tol")
"""The ``guards`` bundle of :func:`_stress`: the surface friction, the three guards (bool) and the leading and
vertical tolerances (:func:`tolerances`' first two)."""


@njit(**INLINE)
def stress_guards(law):
    """:data:`STRESS_GUARDS` of the ``law`` bundle (:data:`rft_mujoco.compiled.element_pass.LAW`)."""
    _, _, mu_surf, no_tension, no_forward, no_power, tol = law
    return mu_surf, no_tension, no_forward, no_power, tol[0], tol[1]


@njit(**INLINE)
def _stress(n, v, g, c, guards):
    """:func:`rft_mujoco.physics.law.stress_per_depth` / xi_n of one element, without branches: unit normal ``n``,
    unit direction ``v`` and unit gravity ``g`` (3-tuples), ``c`` the coefficients (:func:`_coef`), ``guards`` =
    :data:`STRESS_GUARDS`."""
    nx, ny, nz = n
    vx, vy, vz = v
    g0, g1, g2 = g
    mu_surf, no_tension, no_forward, no_power, lead_tol, vert_tol = guards
    gn = nx * g0 + ny * g1 + nz * g2
    vn = nx * vx + ny * vy + nz * vz
    s_g = 1.0 if gn > 0.0 else -1.0
    s_v = 1.0 if vn >= -lead_tol else -1.0
    sign = s_g if abs(gn) > vert_tol else s_v
    x1 = vx * g0 + vy * g1 + vz * g2
    x2 = gn * sign
    x3 = vn * sign
    x11 = x1 * x1
    x22 = x2 * x2
    x33 = x3 * x3
    x12 = x1 * x2
    x23 = x2 * x3
    x31 = x3 * x1
    f0 = _cubic(c, 0, x1, x2, x3, x11, x22, x33, x12, x23, x31)
    f1 = _cubic(c, 20, x1, x2, x3, x11, x22, x33, x12, x23, x31)
    f2 = _cubic(c, 40, x1, x2, x3, x11, x22, x33, x12, x23, x31)
    ax = f0 * (nx * sign) + f1 * vx + f2 * g0
    ay = f0 * (ny * sign) + f1 * vy + f2 * g1
    az = f0 * (nz * sign) + f1 * vz + f2 * g2
    an = ax * nx + ay * ny + az * nz
    tx = ax - an * nx
    ty = ay - an * ny
    tz = az - an * nz
    an_c = an if an < 0.0 else 0.0
    an = an_c if no_tension else an
    tmag = math.sqrt(tx * tx + ty * ty + tz * tz)
    ratio = mu_surf * abs(an) / tmag
    ratio = ratio if ratio < 1.0 else 1.0
    cap = ratio if tmag > 0.0 else 0.0
    tx *= cap
    ty *= cap
    tz *= cap
    fwd = no_forward and (tx * vx + ty * vy + tz * vz > 0.0)
    tx = 0.0 if fwd else tx
    ty = 0.0 if fwd else ty
    tz = 0.0 if fwd else tz
    rx = an * nx + tx
    ry = an * ny + ty
    rz = an * nz + tz
    pos = no_power and (rx * vx + ry * vy + rz * vz > 0.0)
    return (0.0 if pos else rx), (0.0 if pos else ry), (0.0 if pos else rz)


# --- element_forces ------------------------------------------------------------------------------------
@njit(**JIT_LAW)
def _element_forces(elements, height, g_hat, law, scratch, out):
    """Fill ``out`` (N, 3); return 0, or 1 on non-finite input / negative area / zero normal (the caller
    then lets the numpy reference raise its error). ``elements`` = (``centroids``, ``normals``, ``areas``,
    ``velocities``); ``law``: :data:`rft_mujoco.compiled.element_pass.LAW`; ``scratch``: (9, CHUNK) float.

    ``centroids``, ``normals``, ``velocities`` and ``out`` are the flat (3N,) views of the (N, 3) arrays.
    Each chunk is gathered into ``scratch`` (rows: depth, normal, velocity, area, input check), the law runs
    on it, and the forces are scattered back. Indexing flat per-chunk slices at ``3 i + k`` gives LLVM a
    constant stride and indices it can prove non-negative, so the copies vectorize (2.9 -> 1.3 ns per
    element measured for the gather); the input check is a per-element number (``x - x`` is 0 for finite x,
    NaN otherwise), not a boolean reduction.
    """
    centroids, normals, areas, velocities = elements
    xi_n, coef, tol = law[0], law[1], law[6]
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    c = _coef(coef)
    lead_tol, zero_speed = tol[0], tol[2]
    guards = stress_guards(law)
    n_all = areas.shape[0]
    chunk = scratch.shape[1]
    for s in range(0, n_all, chunk):
        n = min(chunk, n_all - s)
        cen, nrm = centroids[3 * s:3 * (s + n)], normals[3 * s:3 * (s + n)]
        vel, ar = velocities[3 * s:3 * (s + n)], areas[s:s + n]
        for i in range(n):                                   # gather (AoS -> SoA) and check
            cx, cy, cz = cen[3 * i], cen[3 * i + 1], cen[3 * i + 2]
            nx, ny, nz = nrm[3 * i], nrm[3 * i + 1], nrm[3 * i + 2]
            vx, vy, vz = vel[3 * i], vel[3 * i + 1], vel[3 * i + 2]
            area = ar[i]
            finite = ((cx - cx) + (cy - cy) + (cz - cz) + (nx - nx) + (ny - ny) + (nz - nz) + (vx - vx)
                      + (vy - vy) + (vz - vz) + (area - area))
            scratch[0, i] = height + (cx * g0 + cy * g1 + cz * g2)
            scratch[1, i] = nx
            scratch[2, i] = ny
            scratch[3, i] = nz
            scratch[4, i] = vx
            scratch[5, i] = vy
            scratch[6, i] = vz
            scratch[7, i] = area
            scratch[8, i] = finite if area >= 0.0 else 1.0   # 0 for a valid element
        for i in range(n):                                   # the law, vectorized
            depth, area = scratch[0, i], scratch[7, i]
            nx, ny, nz = scratch[1, i], scratch[2, i], scratch[3, i]
            vx, vy, vz = scratch[4, i], scratch[5, i], scratch[6, i]
            nlen = math.sqrt(nx * nx + ny * ny + nz * nz)
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            inv = 1.0 / nlen
            nx *= inv
            ny *= inv
            nz *= inv
            inv = 1.0 / speed
            vx *= inv
            vy *= inv
            vz *= inv
            keep = (speed > zero_speed) & (depth > 0.0) & (area > 0.0) & \
                (nx * vx + ny * vy + nz * vz >= -lead_tol)
            rx, ry, rz = _stress((nx, ny, nz), (vx, vy, vz), (g0, g1, g2), c, guards)
            sa = depth * area
            scratch[1, i] = (xi_n * rx) * sa if keep else 0.0
            scratch[2, i] = (xi_n * ry) * sa if keep else 0.0
            scratch[3, i] = (xi_n * rz) * sa if keep else 0.0
            scratch[4, i] = nlen
        bad = False
        res = out[3 * s:3 * (s + n)]
        for i in range(n):                                   # scatter (SoA -> AoS)
            res[3 * i] = scratch[1, i]
            res[3 * i + 1] = scratch[2, i]
            res[3 * i + 2] = scratch[3, i]
            bad |= (scratch[4, i] == 0.0) | (scratch[8, i] != 0.0)
        if bad:
            return 1
    return 0


def _as_c(x, dtype=np.float64) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=dtype)


def element_forces(centroids, normals, areas, velocities, media: Media, surface_height: float = 0.0,
                   gravity=(0.0, 0.0, -9.81), *, guards: Guards = law.PUBLISHED, out=None) -> np.ndarray:
    """Compiled :func:`rft_mujoco.physics.law.element_forces`: the same arguments, result and errors.

    Args:
        (as :func:`rft_mujoco.physics.law.element_forces`); out: optional (N, 3) float64 C-contiguous buffer.
    Returns:
        (N, 3) float forces in N (``out`` when given).
    """
    from rft_mujoco import compiled

    compiled.require()
    c = _as_c(centroids)
    n = c.shape[0] if c.ndim == 2 else -1
    nrm, vel, a = _as_c(normals), _as_c(velocities), _as_c(areas).reshape(-1)
    if (c.ndim != 2 or c.shape[1] != 3 or nrm.shape != (n, 3) or vel.shape != (n, 3) or a.shape != (n,)
            or not math.isfinite(surface_height)):
        return law.element_forces(centroids, normals, areas, velocities, media, surface_height, gravity,
                                  guards=guards)  # raises the reference's error
    g_hat, g_mag = _gravity(gravity if type(gravity) is tuple else tuple(np.ravel(gravity).tolist()))
    if out is None:
        out = np.empty((n, 3))
    elif out.shape != (n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float64 array of shape ({n}, 3), got {out.shape} "
                         f"{out.dtype}")
    status = _element_forces((c.reshape(-1), nrm.reshape(-1), a, vel.reshape(-1)), float(surface_height), g_hat,
                             (media.xi_n_at(g_mag), law.COEFFICIENTS, float(media.mu_surf), guards.no_tension,
                              guards.no_forward_tangential, guards.no_positive_power, _TOLERANCES),
                             _scratch((9, CHUNK)), out.reshape(-1))
    if status:
        law.element_forces(centroids, normals, areas, velocities, media, surface_height, gravity,
                           guards=guards)  # raises the reference's error message
        raise ValueError("invalid element input")  # pragma: no cover - the reference raises first
    return out


@functools.lru_cache(maxsize=16)
def _gravity(gravity: tuple) -> tuple[np.ndarray, float]:
    """:func:`rft_mujoco.physics.law.gravity_direction` of a gravity tuple, cached (it costs microseconds)."""
    g_hat, g_mag = law.gravity_direction(gravity)
    return g_hat, g_mag


_SCRATCH = threading.local()


def _scratch(shape) -> np.ndarray:
    """A per-thread scratch buffer of ``shape`` (reused between calls)."""
    buf = getattr(_SCRATCH, "buf", None)
    if buf is None or buf.shape != shape:
        buf = _SCRATCH.buf = np.empty(shape)
    return buf
