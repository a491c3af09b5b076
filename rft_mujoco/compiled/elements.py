"""Compiled (numba) versions of the per-evaluation kernel: the same numbers as :mod:`rft_mujoco.physics.elements`.

:mod:`rft_mujoco.physics.elements` and :mod:`rft_mujoco.physics.law` are the readable numpy reference; this module computes
what they compute (to round-off: tests/test_fastkernel.py) without numpy temporaries, into buffers the
caller owns:

* :func:`element_forces` -- :func:`rft_mujoco.physics.law.element_forces` (per-element forces, flat surface);
* :func:`body_wrenches` -- :func:`rft_mujoco.physics.elements.body_wrenches` (element kinematics, terrain depth,
  predicted motion direction, the law with its guards, octant-group wrench sums, counts, max depth);
* the coupling's fast path (:func:`touching`, :func:`wrenches`, :func:`finish`): broadphase and depth
  pre-pass straight from MuJoCo's ``xpos``/``xmat``/``cvel`` arrays, the kernel over the bodies that touch
  the sand, and the diagnostics and ``xfrc`` sums, into preallocated per-MjData buffers of the SandHandle.

How it is fast. Elements are stored once, at attach, in a packed layout (:func:`pack`): per body, sorted
by octant group and cut into spatially compact *clusters* of at most :data:`CLUSTER_SIZE` elements, in
structure-of-arrays form. Each evaluation walks the clusters of the touching bodies; a cluster whose
bounding sphere lies above the highest sand is skipped whole (exact: none of its elements can be
submerged). Inside a cluster one pass computes positions, lever arms and depths, a second pass computes
velocity, predicted direction, leading test and the stress of every element without branches (the
element masks become selects), which LLVM vectorizes (SIMD) without reassociation; a third, short
scalar pass adds the loaded elements into the cluster's octant group. All three work on a fixed
(SCRATCH_ROWS, CLUSTER_SIZE) scratch buffer, never on per-element temporaries.

Terrains: :class:`~rft_mujoco.physics.terrain.FlatSurface`, :class:`~rft_mujoco.physics.terrain.HeightfieldSurface` and
:class:`~rft_mujoco.physics.terrain.SandRegion` are compiled (:func:`terrain_spec`); anything else makes the
coupling fall back to numpy. The rest evaluation around these kernels lives in :mod:`rft_mujoco.compiled.rest`;
:func:`ensure_compiled` compiles it with the rest.

Compilation: every function is ``@njit(cache=True)``, with ``fastmath`` off but for multiply-add fusion in the
two element loops (:data:`_JIT_LAW`) and reassociated sums in the limiter's solver (:mod:`rft_mujoco.physics.elements`).
The first use on a machine
compiles (:data:`COMPILE_SECONDS`) and saves the machine code next to this file (or in ``NUMBA_CACHE_DIR``);
later processes load it in a fraction of a second. :func:`ensure_compiled` prints one line to stderr when a
compilation actually happens (cache loads are silent). numba is an optional import: :data:`AVAILABLE` is
False when it cannot be imported, and the coupling then uses numpy. Tolerances and coefficients are
passed at run time (numba would freeze module globals into its on-disk cache, which does not notice
edits of law.py).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import sys
import threading
import time

import numpy as np

from rft_mujoco.physics import law
from rft_mujoco.physics.law import Guards
from rft_mujoco.physics.media import Media
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion

GROUPS_PER_BODY = 8
"""Octant groups per body; the same as :data:`rft_mujoco.physics.elements.GROUPS_PER_BODY`."""
SCRATCH_ROWS = 11
"""Rows of the element kernel's scratch buffer: lever arms and depth (0-3), the law's outputs (4-10)."""
CLUSTER_SIZE = 128
"""Most elements per cluster (the unit of culling and of the vectorized inner loops)."""
PAD = 16
"""Clusters are padded to a multiple of this many slots, so the vectorized loops (8 float64 lanes, unrolled
twice) never run a scalar remainder."""
CHUNK = 256
"""Elements per chunk of :func:`element_forces`."""
COMPILE_SECONDS = 30
"""Rough first-use compile time in s on a 2-core machine (measured 17-25 s, rounded up), for the notice."""

# Terrain kinds of :func:`terrain_spec` (the compiled depth switches on them).
FLAT = 0
HEIGHTFIELD = 1

_log = logging.getLogger("rft_mujoco")

try:  # numba is a dependency, but keep the package importable (and on numpy) without it
    import numba
    from numba import njit
    AVAILABLE = True
    IMPORT_ERROR: str | None = None
except Exception as exc:  # pragma: no cover - exercised only where numba is missing or broken
    AVAILABLE = False
    IMPORT_ERROR = f"{type(exc).__name__}: {exc}"

    def njit(*args, **kwargs):  # a no-op decorator so the module still imports
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

# error_model="numpy": float division by zero gives inf/nan (masked out afterwards) instead of a Python
# exception check per division, which would stop vectorization.
_JIT = dict(cache=True, fastmath=False, nogil=True, error_model="numpy")
_INLINE = dict(_JIT, inline="always")
_JIT_LAW = dict(_JIT, fastmath={"contract"})
"""For the two element loops (:func:`_element_forces`, :func:`wrenches`): lets LLVM fuse multiply-adds
(FMA), nothing else; 5-7% fewer ns per element measured. The results stay within round-off of the numpy
law (tests/test_fastkernel.py), deterministic run to run."""


def tolerances() -> np.ndarray:
    """(3,) [LEADING_TOL, VERTICAL_TOL, ZERO_SPEED] of :mod:`rft_mujoco.physics.law`, for the kernels."""
    return np.array([law.LEADING_TOL, law.VERTICAL_TOL, law.ZERO_SPEED])


_TOLERANCES = tolerances()   # element_forces passes it every call (writable: numba types read-only arrays apart)


# --- scalar building blocks (inlined) ----------------------------------------------------------------
@njit(**_INLINE)
def _coef(C):
    """The (20, 3) coefficient table as a 60-tuple (column-major), hoisted out of the element loops."""
    return (C[0, 0], C[1, 0], C[2, 0], C[3, 0], C[4, 0], C[5, 0], C[6, 0], C[7, 0], C[8, 0], C[9, 0],
            C[10, 0], C[11, 0], C[12, 0], C[13, 0], C[14, 0], C[15, 0], C[16, 0], C[17, 0], C[18, 0], C[19, 0],
            C[0, 1], C[1, 1], C[2, 1], C[3, 1], C[4, 1], C[5, 1], C[6, 1], C[7, 1], C[8, 1], C[9, 1],
            C[10, 1], C[11, 1], C[12, 1], C[13, 1], C[14, 1], C[15, 1], C[16, 1], C[17, 1], C[18, 1], C[19, 1],
            C[0, 2], C[1, 2], C[2, 2], C[3, 2], C[4, 2], C[5, 2], C[6, 2], C[7, 2], C[8, 2], C[9, 2],
            C[10, 2], C[11, 2], C[12, 2], C[13, 2], C[14, 2], C[15, 2], C[16, 2], C[17, 2], C[18, 2], C[19, 2])


@njit(**_INLINE)
def _cubic(c, o, x1, x2, x3, x11, x22, x33):
    """sum_k C[k, j] T_k(x1, x2, x3) for the column starting at ``o`` of the 60-tuple (law.cubic_terms)."""
    return (c[o] + c[o + 1] * x1 + c[o + 2] * x2 + c[o + 3] * x3 + c[o + 4] * x11 + c[o + 5] * x22
            + c[o + 6] * x33 + c[o + 7] * (x1 * x2) + c[o + 8] * (x2 * x3) + c[o + 9] * (x3 * x1)
            + c[o + 10] * (x11 * x1) + c[o + 11] * (x22 * x2) + c[o + 12] * (x33 * x3) + c[o + 13] * (x1 * x22)
            + c[o + 14] * (x2 * x11) + c[o + 15] * (x2 * x33) + c[o + 16] * (x3 * x22) + c[o + 17] * (x3 * x11)
            + c[o + 18] * (x1 * x33) + c[o + 19] * (x1 * x2 * x3))


@njit(**_INLINE)
def _stress(nx, ny, nz, vx, vy, vz, g0, g1, g2, c, mu_surf, no_tension, no_forward, no_power, lead_tol,
            vert_tol):
    """:func:`rft_mujoco.physics.law.stress_per_depth` / xi_n of one element (unit n, unit v), without branches."""
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
    f0 = _cubic(c, 0, x1, x2, x3, x11, x22, x33)
    f1 = _cubic(c, 20, x1, x2, x3, x11, x22, x33)
    f2 = _cubic(c, 40, x1, x2, x3, x11, x22, x33)
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


@njit(**_JIT)
def _depth(px, py, pz, g0, g1, g2, kind, tp, heights):
    """Depth (m) of a world point below the terrain: :meth:`FlatSurface.depth`,
    :meth:`HeightfieldSurface.depth`, :meth:`SandRegion.depth`, with ``tp`` from :func:`terrain_spec`."""
    if tp[6] != 0.0:  # bounded region
        if not (px >= tp[7] and px <= tp[8] and py >= tp[9] and py <= tp[10]):
            return -np.inf
    if kind == FLAT:
        return tp[0] + (px * g0 + py * g1 + pz * g2)
    nrow = heights.shape[0]
    ncol = heights.shape[1]
    u = (px - tp[1]) / (tp[2] - tp[1]) * (ncol - 1)
    w = (py - tp[3]) / (tp[4] - tp[3]) * (nrow - 1)
    if u != u or w != w:
        return -np.inf
    inside = u >= 0 and u <= ncol - 1 and w >= 0 and w <= nrow - 1
    if tp[5] != 0.0 and not inside:  # outside == "none"
        return -np.inf
    u = min(max(u, 0.0), ncol - 1.0)
    w = min(max(w, 0.0), nrow - 1.0)
    i0 = min(int(math.floor(w)), nrow - 2)
    j0 = min(int(math.floor(u)), ncol - 2)
    fu = u - j0
    fw = w - i0
    z = ((1 - fw) * ((1 - fu) * heights[i0, j0] + fu * heights[i0, j0 + 1])
         + fw * ((1 - fu) * heights[i0 + 1, j0] + fu * heights[i0 + 1, j0 + 1]))
    return z - pz


# --- element_forces ------------------------------------------------------------------------------------
@njit(**_JIT_LAW)
def _element_forces(centroids, normals, areas, velocities, height, g_hat, xi_n, coef, mu_surf,
                    no_tension, no_forward, no_power, tol, scratch, out):
    """Fill ``out`` (N, 3); return 0, or 1 on non-finite input / negative area / zero normal (the caller
    then lets the numpy reference raise its error). ``scratch``: (9, CHUNK) float.

    ``centroids``, ``normals``, ``velocities`` and ``out`` are the flat (3N,) views of the (N, 3) arrays.
    Each chunk is gathered into ``scratch`` (rows: depth, normal, velocity, area, input check), the law runs
    on it, and the forces are scattered back. Indexing flat per-chunk slices at ``3 i + k`` gives LLVM a
    constant stride and indices it can prove non-negative, so the copies vectorize (2.9 -> 1.3 ns per
    element measured for the gather); the input check is a per-element number (``x - x`` is 0 for finite x,
    NaN otherwise), not a boolean reduction.
    """
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    c = _coef(coef)
    lead_tol, vert_tol, zero_speed = tol[0], tol[1], tol[2]
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
            rx, ry, rz = _stress(nx, ny, nz, vx, vy, vz, g0, g1, g2, c, mu_surf, no_tension, no_forward,
                                 no_power, lead_tol, vert_tol)
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
    _require()
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
    status = _element_forces(c.reshape(-1), nrm.reshape(-1), a, vel.reshape(-1), float(surface_height), g_hat,
                             media.xi_n_at(g_mag), law.COEFFICIENTS, float(media.mu_surf), guards.no_tension,
                             guards.no_forward_tangential, guards.no_positive_power, _TOLERANCES,
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


# --- packed elements ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Packed:
    """Elements of B bodies in the compiled kernel's layout (see the module docstring).

    Attributes:
        centroids, normals: (3, E) float, body-frame centroids (m) and unit normals, structure of arrays,
            in packed order.
        areas: (E,) float, m^2.
        index: (E,) int, the original element index of each packed slot.
        cluster_start: (C + 1,) int, packed range of each cluster (a multiple of :data:`PAD` long: the
            slots after its last element are padding, NaN centroids that are never loaded).
        cluster_octant: (C, 9) int, cluster q's elements of octant group o are the packed slots
            ``cluster_octant[q, o]:cluster_octant[q, o + 1]`` (sorted by octant inside the cluster).
        cluster_center: (C, 3) float, body-frame centre of the cluster's bounding sphere (m).
        cluster_radius: (C,) float, its radius (m), slightly inflated against round-off.
        body_clusters: (B + 1,) int, clusters of body b are ``body_clusters[b]:body_clusters[b + 1]``.
    """

    centroids: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    index: np.ndarray
    cluster_start: np.ndarray
    cluster_octant: np.ndarray
    cluster_center: np.ndarray
    cluster_radius: np.ndarray
    body_clusters: np.ndarray

    def arrays(self) -> tuple:
        return (self.centroids, self.normals, self.areas, self.cluster_start, self.cluster_octant,
                self.cluster_center, self.cluster_radius, self.body_clusters)


def _split(points: np.ndarray, idx: np.ndarray, size: int, out: list) -> None:
    """Cut ``idx`` into spatially compact pieces of at most ``size`` (halving along the longest axis)."""
    stack = [idx]
    while stack:
        part = stack.pop()
        if part.size <= size:
            out.append(part)
            continue
        p = points[part]
        axis = int(np.argmax(p.max(0) - p.min(0)))
        order = part[np.argsort(p[:, axis], kind="stable")]
        half = order.size // 2
        stack.append(order[half:])
        stack.append(order[:half])


def pack(local_centroids, local_normals, areas, elem_body, n_bodies: int, elem_octant=None,
         cluster_size: int = CLUSTER_SIZE) -> Packed:
    """Pack elements (E, 3) / (E,) of bodies ``elem_body`` (E,) int in 0..B-1 for the compiled kernel."""
    c = np.asarray(local_centroids, dtype=float).reshape(-1, 3)
    n = np.asarray(local_normals, dtype=float).reshape(-1, 3)
    a = np.asarray(areas, dtype=float).reshape(-1)
    body = np.asarray(elem_body, dtype=np.int64).reshape(-1)
    octant = np.zeros(body.size, np.int64) if elem_octant is None else np.asarray(elem_octant, np.int64)
    if not (c.shape[0] == n.shape[0] == a.size == body.size == octant.size):
        raise ValueError(f"element arrays must agree in length, got {c.shape}, {n.shape}, {a.shape}, "
                         f"{body.shape}, {octant.shape}")
    pieces, body_clusters = [], [0]
    for b in range(n_bodies):
        idx = np.flatnonzero(body == b)
        if idx.size:
            _split(c, idx, cluster_size, pieces)
        body_clusters.append(len(pieces))
    slots, starts, segments = [], [0], []
    center = np.zeros((len(pieces), 3))
    radius = np.zeros(len(pieces))
    for k, p in enumerate(pieces):
        p = p[np.argsort(octant[p], kind="stable")]
        pts = c[p]
        center[k] = 0.5 * (pts.min(0) + pts.max(0))
        radius[k] = float(np.sqrt(((pts - center[k]) ** 2).sum(1).max())) * (1.0 + 1e-9) + 1e-12
        segments.append(starts[-1] + np.searchsorted(octant[p], np.arange(GROUPS_PER_BODY + 1)))
        width = -(-p.size // PAD) * PAD
        slots.append(np.concatenate([p, np.full(width - p.size, -1)]))
        starts.append(starts[-1] + width)
    index = np.concatenate(slots).astype(np.int64) if slots else np.zeros(0, np.int64)
    real = index >= 0
    cp = np.full((index.size, 3), np.nan)
    cp[real] = c[index[real]]
    npk = np.zeros((index.size, 3))
    npk[real] = n[index[real]]
    ap = np.zeros(index.size)
    ap[real] = a[index[real]]
    return Packed(np.ascontiguousarray(cp.T), np.ascontiguousarray(npk.T), ap, index,
                  np.asarray(starts, np.int64), np.asarray(segments, np.int64).reshape(-1, GROUPS_PER_BODY + 1),
                  center, radius, np.asarray(body_clusters, np.int64))


# --- body wrenches ---------------------------------------------------------------------------------------
LANES = 8
"""Interleaved lanes of :func:`_count_positive`'s maximum (one SIMD register of doubles)."""


@njit(**_INLINE)
def _count_positive(row, n, lanes):
    """Number of positive entries of ``row[:n]``; ``lanes[l]``: the largest ``row[i]`` with i = l mod LANES
    (or 0).

    A running maximum over one variable compiles to a branch that mispredicts when the maximum keeps
    rising (deeper and deeper elements along a cluster: +6 ns per element measured at 1e5 elements); per
    lane it is a select, which vectorizes. The maximum is exact in any order. No NaN may be passed.
    """
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
    kept = 0
    for i in range(n):
        kept += 1 if row[i] > 0.0 else 0
    return kept


@njit(**_JIT_LAW)
def wrenches(bodies, n_on, centroids, normals, areas, cluster_start, cluster_octant, cluster_center,
             cluster_radius, body_clusters, body_pos, body_mat, body_com, v_com, omega, acc, dt, g_hat,
             max_height, kind, tp, heights, xi_n, coef, mu_surf, no_tension, no_forward, no_power, tol,
             scratch, groups, count, max_depth):
    """The element loop of :func:`rft_mujoco.physics.elements.body_wrenches` over the bodies ``bodies[:n_on]``.

    Row j < n_on of every per-body array (``body_pos`` (>= n_on, 3), ``body_mat`` (>= n_on, 9),
    ``body_com``, ``v_com``, ``omega``, the outputs ``groups`` (>= n_on, 8, 6), ``count``, ``max_depth``,
    and ``acc`` (n_on, 6) = [free linear acceleration of the COM, angular acceleration]) belongs to body
    ``b = bodies[j]``, whose elements are the clusters ``body_clusters[b]:body_clusters[b + 1]`` of the
    packed arrays (:func:`pack`). With ``acc`` of fewer rows than n_on or ``dt <= 0``, elements move along
    their velocity (no predicted direction). ``scratch``: (SCRATCH_ROWS, >= cluster size) float. Output rows
    0..n_on-1 are overwritten. Returns the number of non-zero octant groups.
    """
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    c = _coef(coef)
    lead_tol, vert_tol, zero_speed = tol[0], tol[1], tol[2]
    pred = acc.shape[0] >= n_on and dt > 0.0
    flat = kind == FLAT and tp[6] == 0.0
    h0 = tp[0]
    n_active = 0
    seg = np.empty(GROUPS_PER_BODY + 1, dtype=np.int64)
    sub_normals = np.empty((3, scratch.shape[1]))       # the submerged elements of a cluster, packed
    sub_areas = np.empty(scratch.shape[1])
    lanes = np.empty(LANES)
    for j in range(n_on):
        b = bodies[j]
        for o in range(groups.shape[1]):
            for k in range(6):
                groups[j, o, k] = 0.0
        count[j] = 0
        max_depth[j] = 0.0
        r = body_mat[j]
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
        px, py, pz = body_pos[j, 0], body_pos[j, 1], body_pos[j, 2]
        cx, cy, cz = body_com[j, 0], body_com[j, 1], body_com[j, 2]
        wx, wy, wz = omega[j, 0], omega[j, 1], omega[j, 2]
        ux, uy, uz = v_com[j, 0], v_com[j, 1], v_com[j, 2]
        ddt = dt if pred else 0.0
        lax = acc[j, 0] if pred else 0.0
        lay = acc[j, 1] if pred else 0.0
        laz = acc[j, 2] if pred else 0.0
        aax = acc[j, 3] if pred else 0.0
        aay = acc[j, 4] if pred else 0.0
        aaz = acc[j, 5] if pred else 0.0
        if not pred and ux == 0.0 and uy == 0.0 and uz == 0.0 and wx == 0.0 and wy == 0.0 and wz == 0.0:
            continue                         # a body at rest: no element moves, no element is loaded
        for q in range(body_clusters[b], body_clusters[b + 1]):
            q0, q1, q2 = cluster_center[q, 0], cluster_center[q, 1], cluster_center[q, 2]
            low = -((px + (r0 * q0 + r1 * q1 + r2 * q2)) * g0 + (py + (r3 * q0 + r4 * q1 + r5 * q2)) * g1
                    + (pz + (r6 * q0 + r7 * q1 + r8 * q2)) * g2) - cluster_radius[q]
            if low > max_height:                             # the whole cluster is above the sand
                continue
            # flat sand: the whole cluster is in it when its highest point is below the surface h0
            whole = flat and h0 - (low + 2.0 * cluster_radius[q]) > 0.0
            s = cluster_start[q]
            n = cluster_start[q + 1] - s
            # 1. positions, lever arms, depths
            for i in range(n):
                l0, l1, l2 = centroids[0, s + i], centroids[1, s + i], centroids[2, s + i]
                ex = px + (r0 * l0 + r1 * l1 + r2 * l2)
                ey = py + (r3 * l0 + r4 * l1 + r5 * l2)
                ez = pz + (r6 * l0 + r7 * l1 + r8 * l2)
                scratch[0, i] = ex - cx
                scratch[1, i] = ey - cy
                scratch[2, i] = ez - cz
                scratch[3, i] = h0 + (ex * g0 + ey * g1 + ez * g2)
            if not flat:                                     # heightfield / region: scalar depth
                for i in range(n):
                    l0, l1, l2 = centroids[0, s + i], centroids[1, s + i], centroids[2, s + i]
                    scratch[3, i] = _depth(px + (r0 * l0 + r1 * l1 + r2 * l2), py + (r3 * l0 + r4 * l1 + r5 * l2),
                                           pz + (r6 * l0 + r7 * l1 + r8 * l2), g0, g1, g2, kind, tp, heights)
            # 2. only the submerged elements go on, octant by octant (seg[o]:seg[o + 1]): a cluster wholly in
            # the sand as it is (its padding slots have NaN depths: never loaded), another packed to the
            # front of scratch (lever arms, depths) and into sub_normals / sub_areas.
            if whole:
                n_sub = n
                nrm, area, off = normals, areas, s
                for o in range(GROUPS_PER_BODY + 1):
                    seg[o] = cluster_octant[q, o] - s
            else:
                nrm, area, off = sub_normals, sub_areas, 0
                n_sub = 0
                for o in range(GROUPS_PER_BODY):
                    seg[o] = n_sub
                    for i in range(cluster_octant[q, o] - s, cluster_octant[q, o + 1] - s):
                        if scratch[3, i] > 0.0:
                            scratch[0, n_sub] = scratch[0, i]
                            scratch[1, n_sub] = scratch[1, i]
                            scratch[2, n_sub] = scratch[2, i]
                            scratch[3, n_sub] = scratch[3, i]
                            sub_normals[0, n_sub] = normals[0, s + i]
                            sub_normals[1, n_sub] = normals[1, s + i]
                            sub_normals[2, n_sub] = normals[2, s + i]
                            sub_areas[n_sub] = areas[s + i]
                            n_sub += 1
                seg[GROUPS_PER_BODY] = n_sub
                if n_sub == 0:
                    continue
            # 3. velocity, predicted direction, leading test, stress: no branches (vectorized)
            for i in range(n_sub):
                hx, hy, hz, depth = scratch[0, i], scratch[1, i], scratch[2, i], scratch[3, i]
                m0, m1, m2 = nrm[0, off + i], nrm[1, off + i], nrm[2, off + i]
                nx = r0 * m0 + r1 * m1 + r2 * m2
                ny = r3 * m0 + r4 * m1 + r5 * m2
                nz = r6 * m0 + r7 * m1 + r8 * m2
                vx = ux + (wy * hz - wz * hy)
                vy = uy + (wz * hx - wx * hz)
                vz = uz + (wx * hy - wy * hx)
                if pred:                                     # loop-invariant: LLVM unswitches it
                    sx = (lax + (aay * hz - aaz * hy)) * ddt
                    sy = (lay + (aaz * hx - aax * hz)) * ddt
                    sz = (laz + (aax * hy - aay * hx)) * ddt
                    s2 = sx * sx + sy * sy + sz * sz
                    v2 = vx * vx + vy * vy + vz * vz
                    wgt = s2 / (v2 + s2)
                    wgt = wgt if s2 > 0.0 else 0.0
                    vx = vx + wgt * sx
                    vy = vy + wgt * sy
                    vz = vz + wgt * sz
                speed = math.sqrt(vx * vx + vy * vy + vz * vz)
                inv = 1.0 / speed
                vx *= inv
                vy *= inv
                vz *= inv
                keep = (depth > 0.0) & (speed > zero_speed) & (nx * vx + ny * vy + nz * vz >= -lead_tol)
                rx, ry, rz = _stress(nx, ny, nz, vx, vy, vz, g0, g1, g2, c, mu_surf, no_tension, no_forward,
                                     no_power, lead_tol, vert_tol)
                sa = depth * area[off + i]
                fx = (xi_n * rx) * sa if keep else 0.0
                fy = (xi_n * ry) * sa if keep else 0.0
                fz = (xi_n * rz) * sa if keep else 0.0
                scratch[4, i] = fx
                scratch[5, i] = fy
                scratch[6, i] = fz
                scratch[7, i] = hy * fz - hz * fy if keep else 0.0
                scratch[8, i] = hz * fx - hx * fz if keep else 0.0
                scratch[9, i] = hx * fy - hy * fx if keep else 0.0
                scratch[10, i] = depth if keep else 0.0          # > 0 exactly for the loaded elements
            # 4. each octant segment into its group (elements not loaded add exact zeros): register sums
            for o in range(GROUPS_PER_BODY):
                lo = seg[o]
                hi = seg[o + 1]
                if lo == hi:
                    continue
                a0 = groups[j, o, 0]
                a1 = groups[j, o, 1]
                a2 = groups[j, o, 2]
                a3 = groups[j, o, 3]
                a4 = groups[j, o, 4]
                a5 = groups[j, o, 5]
                for i in range(lo, hi):
                    a0 += scratch[4, i]
                    a1 += scratch[5, i]
                    a2 += scratch[6, i]
                    a3 += scratch[7, i]
                    a4 += scratch[8, i]
                    a5 += scratch[9, i]
                groups[j, o, 0] = a0
                groups[j, o, 1] = a1
                groups[j, o, 2] = a2
                groups[j, o, 3] = a3
                groups[j, o, 4] = a4
                groups[j, o, 5] = a5
            count[j] += _count_positive(scratch[10], n_sub, lanes)
            for l in range(LANES):
                max_depth[j] = max(max_depth[j], lanes[l])
        for o in range(groups.shape[1]):
            for k in range(6):
                if groups[j, o, k] != 0.0:
                    n_active += 1
                    break
    return n_active


_NO_HEIGHTS = np.zeros((2, 2))


def terrain_spec(terrain) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(kind, params (11,) float, heights (nrow, ncol) float)`` for the compiled depth, or None for a
    terrain the compiled kernel does not know (the caller falls back to numpy).

    params: ``[flat height, x0, x1, y0, y1, outside_none, is_region, rx0, rx1, ry0, ry1]``.
    """
    tp = np.zeros(11)
    inner = terrain
    if type(terrain) is SandRegion:
        tp[6] = 1.0
        tp[7:11] = (*terrain.x_range, *terrain.y_range)
        inner = terrain.surface
    if type(inner) is FlatSurface:
        tp[0] = inner.height
        return FLAT, tp, _NO_HEIGHTS
    if type(inner) is HeightfieldSurface:
        tp[1:5] = (*inner.x_range, *inner.y_range)
        tp[5] = 1.0 if inner.outside == "none" else 0.0
        return HEIGHTFIELD, tp, np.array(inner.heights, dtype=np.float64, order="C")
    return None


def check_gravity(terrain, spec, g_hat: np.ndarray) -> None:
    """The numpy terrains' own check: heightfields and bounded regions need gravity along -z (raises the
    terrain's ValueError)."""
    kind, tp, _ = spec
    if (kind != FLAT or tp[6] != 0.0) and g_hat[2] > -1.0 + 1e-9:
        terrain.depth(np.zeros((1, 3)), g_hat)


def body_wrenches(local_centroids, local_normals, areas, elem_body, n_bodies, body_pos, body_mat, body_com,
                  v_com, omega, terrain, g_hat, gravity, media: Media, guards: Guards,
                  a_com=None, alpha=None, dt=0.0, elem_octant=None):
    """Compiled :func:`rft_mujoco.physics.elements.body_wrenches`: the same arguments and results (packs the elements
    on every call; the coupling packs them once).

    Returns:
        wrench (B, 8, 6), count (B,) int, max_depth (B,) m -- as the numpy kernel.
    Raises:
        ValueError: for a terrain the compiled kernel does not support (use the numpy kernel).
    """
    _require()
    spec = terrain_spec(terrain)
    if spec is None:
        raise ValueError(f"the compiled kernel supports FlatSurface, HeightfieldSurface and SandRegion, got "
                         f"{type(terrain).__name__}; use rft_mujoco.physics.elements.body_wrenches")
    g_hat = _as_c(g_hat)
    check_gravity(terrain, spec, g_hat)
    packed = pack(local_centroids, local_normals, areas, elem_body, n_bodies, elem_octant)
    pred = dt > 0.0 and a_com is not None
    acc = np.hstack([a_com, alpha]) if pred else np.zeros((0, 6))
    _, g_mag = law.gravity_direction(gravity)
    groups = np.empty((n_bodies, GROUPS_PER_BODY, 6))
    count = np.empty(n_bodies, dtype=np.int64)
    max_depth = np.empty(n_bodies)
    wrenches(np.arange(n_bodies, dtype=np.int64), n_bodies, *packed.arrays(), _as_c(body_pos),
             _as_c(body_mat).reshape(n_bodies, 9), _as_c(body_com), _as_c(v_com), _as_c(omega), _as_c(acc),
             float(dt), g_hat, float(terrain.max_height), *spec, media.xi_n_at(g_mag), law.COEFFICIENTS,
             float(media.mu_surf), guards.no_tension, guards.no_forward_tangential, guards.no_positive_power,
             tolerances(), np.empty((SCRATCH_ROWS, CLUSTER_SIZE)), groups, count, max_depth)
    return groups, count, max_depth


# --- the coupling's fast path --------------------------------------------------------------------------
@njit(**_JIT)
def touching(ids, root, xpos, xmat, xipos, cvel, subtree_com, qpos, qvel, bound_center, bound_radius,
             centroids, cluster_start, cluster_center, cluster_radius, body_clusters, g_hat, max_height, kind,
             tp, heights, touch, body_pos, body_mat, body_com, v_com, omega):
    """Broadphase and depth pre-pass of a handle's bodies (``ids`` (B,) MuJoCo body ids) from MjData arrays.

    A body is a candidate when the lowest point of its bounding sphere (centre ``bound_center`` (B, 3)
    in the body frame, radius ``bound_radius`` (B,)) is below ``max_height``; it touches the sand when
    one of its elements has depth > 0 (clusters above the sand are skipped). Touching bodies are written,
    in order, to ``touch`` (handle indices) and row j of ``body_pos``, ``body_mat`` (9), ``body_com``
    (``xipos``), ``v_com`` (``cvel``'s linear part moved from ``subtree_com[root]`` to ``xipos``) and
    ``omega``. Returns their number, or -1 when some body is a candidate and qpos/qvel are not finite.
    """
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    n_touch = 0
    checked = False
    for i in range(ids.shape[0]):
        bid = ids[i]
        r = xmat[bid]
        px, py, pz = xpos[bid, 0], xpos[bid, 1], xpos[bid, 2]
        bc0, bc1, bc2 = bound_center[i, 0], bound_center[i, 1], bound_center[i, 2]
        low = -((px + (r[0] * bc0 + r[1] * bc1 + r[2] * bc2)) * g0 + (py + (r[3] * bc0 + r[4] * bc1 + r[5] * bc2))
                * g1 + (pz + (r[6] * bc0 + r[7] * bc1 + r[8] * bc2)) * g2) - bound_radius[i]
        if not low < max_height:
            continue
        if not checked:
            checked = True
            for q in range(qpos.shape[0]):
                if not math.isfinite(qpos[q]):
                    return -1
            for q in range(qvel.shape[0]):
                if not math.isfinite(qvel[q]):
                    return -1
        hit = False
        for q in range(body_clusters[i], body_clusters[i + 1]):
            q0, q1, q2 = cluster_center[q, 0], cluster_center[q, 1], cluster_center[q, 2]
            low = -((px + (r[0] * q0 + r[1] * q1 + r[2] * q2)) * g0 + (py + (r[3] * q0 + r[4] * q1 + r[5] * q2))
                    * g1 + (pz + (r[6] * q0 + r[7] * q1 + r[8] * q2)) * g2) - cluster_radius[q]
            if low > max_height:
                continue
            for k in range(cluster_start[q], cluster_start[q + 1]):
                l0, l1, l2 = centroids[0, k], centroids[1, k], centroids[2, k]
                ex = px + (r[0] * l0 + r[1] * l1 + r[2] * l2)
                ey = py + (r[3] * l0 + r[4] * l1 + r[5] * l2)
                ez = pz + (r[6] * l0 + r[7] * l1 + r[8] * l2)
                if _depth(ex, ey, ez, g0, g1, g2, kind, tp, heights) > 0.0:
                    hit = True
                    break
            if hit:
                break
        if not hit:
            continue
        n = n_touch
        touch[n] = i
        for k in range(9):
            body_mat[n, k] = r[k]
        rt = root[i]
        for k in range(3):
            body_pos[n, k] = xpos[bid, k]
            body_com[n, k] = xipos[bid, k]
            omega[n, k] = cvel[bid, k]
        dx = xipos[bid, 0] - subtree_com[rt, 0]
        dy = xipos[bid, 1] - subtree_com[rt, 1]
        dz = xipos[bid, 2] - subtree_com[rt, 2]
        wx, wy, wz = cvel[bid, 0], cvel[bid, 1], cvel[bid, 2]
        v_com[n, 0] = cvel[bid, 3] + (wy * dz - wz * dy)
        v_com[n, 1] = cvel[bid, 4] + (wz * dx - wx * dz)
        v_com[n, 2] = cvel[bid, 5] + (wx * dy - wy * dx)
        n_touch += 1
    return n_touch


@njit(**_JIT)
def clear_diagnostics(force, torque, submerged, max_depth, scale, rft_force):
    """Diagnostics of an evaluation without sand: zero wrenches, counts and depths, scale 1."""
    force[:] = 0.0
    torque[:] = 0.0
    submerged[:] = 0
    max_depth[:] = 0.0
    scale[:] = 1.0
    rft_force[:] = 0.0


@njit(**_JIT)
def finish(groups, count, depth_max, v_com, omega, limited, passive, touch, n_touch, ids, force, torque,
           submerged, max_depth, scale, rft_force, sand_out):
    """The end of ``SandHandle._evaluate`` for the touching bodies (rows j < n_touch, body ``touch[j]``).

    Sums each body's octant groups (n_touch, 8, 6) into its RFT wrench; the applied wrench is row j of
    ``limited`` (n_touch, 6) (the impulse limiter's result) when it has n_touch rows, else the RFT wrench,
    zeroed when ``passive`` and it would do positive work. Fills the diagnostics (B, ...) (all rows) and
    adds the applied wrenches into ``sand_out`` (nbody, 6) at rows ``ids[touch[j]]``.

    Returns 1 when an applied wrench is non-zero, 0 when none is, and -1 (``sand_out`` untouched) when one
    is not finite.
    """
    clear_diagnostics(force, torque, submerged, max_depth, scale, rft_force)
    use_limited = limited.shape[0] >= n_touch
    w = np.empty(6)
    status = 0
    for j in range(n_touch):
        b = touch[j]
        for k in range(6):
            w[k] = 0.0
        for o in range(groups.shape[1]):
            for k in range(6):
                w[k] += groups[j, o, k]
        for k in range(3):
            rft_force[b, k] = w[k]
        submerged[b] = count[j]
        max_depth[b] = depth_max[j]
        loaded = False
        for k in range(6):
            if w[k] != 0.0:
                loaded = True
        if not loaded:
            continue
        if use_limited:
            rft_norm = 0.0
            new_norm = 0.0
            for k in range(6):
                rft_norm += w[k] * w[k]
                w[k] = limited[j, k]
                new_norm += w[k] * w[k]
            scale[b] = math.sqrt(new_norm) / math.sqrt(rft_norm)
        elif passive:
            power = (w[0] * v_com[j, 0] + w[1] * v_com[j, 1] + w[2] * v_com[j, 2]) + \
                (w[3] * omega[j, 0] + w[4] * omega[j, 1] + w[5] * omega[j, 2])
            if power > 0.0:
                scale[b] = 0.0
                continue
        for k in range(3):
            force[b, k] = w[k]
            torque[b, k] = w[3 + k]
        for k in range(6):
            if not math.isfinite(w[k]):
                status = -1
            elif w[k] != 0.0 and status == 0:
                status = 1
    if status < 0:
        return -1
    for j in range(n_touch):
        b = touch[j]
        row = ids[b]
        for k in range(3):
            sand_out[row, k] += force[b, k]
            sand_out[row, 3 + k] += torque[b, k]
    return status


@njit(**_JIT)
def user_part(xfrc, written, added, rows, user):
    """The dispatcher's user wrench (nbody, 6) into ``user``: ``xfrc`` with the sand ``added`` last time
    taken out of the components of rows ``rows`` the user left alone (the rule of
    :func:`rft_mujoco.coupling.dispatch.untouched_components`)."""
    user[:] = xfrc
    for r in rows:
        whole = True
        for k in range(6):
            whole = whole and xfrc[r, k] == written[r, k]
        for k in range(6):
            if xfrc[r, k] == written[r, k] and (whole or written[r, k] != 0.0):
                user[r, k] -= added[r, k]


@njit(**_JIT)
def commit(xfrc, user, sand, rows, added, written):
    """The dispatcher's write: ``xfrc[rows] = user + sand``, remembering what was added and written."""
    added[:] = 0.0
    for r in rows:
        for k in range(6):
            v = user[r, k] + sand[r, k]
            xfrc[r, k] = v
            added[r, k] = sand[r, k]
            written[r, k] = v


def ready() -> bool:
    """Whether :func:`ensure_compiled` has run in this process (the compiled kernels are loaded)."""
    return _compiled


# --- compilation on first use ------------------------------------------------------------------------
_compiled = False
_compile_lock = threading.Lock()


def _require() -> None:
    if not AVAILABLE:
        raise RuntimeError(f"numba is not available ({IMPORT_ERROR}); use the numpy kernel "
                           "(rft_mujoco.physics.elements) or attach(..., backend='numpy')")
    ensure_compiled()


def ensure_compiled(verbose: bool = True) -> float:
    """Compile (or load from numba's cache) every kernel of this module and the rest evaluation
    (:mod:`rft_mujoco.compiled.rest`), for the argument types the package uses, once per process. Returns the seconds it took (0 when already done).

    Prints one line to stderr (and logs it on the "rft_mujoco" logger) only when numba actually compiles
    something -- on the first use on a machine, or after the source changed; cache loads are silent.
    """
    global _compiled
    if _compiled or not AVAILABLE:
        return 0.0
    with _compile_lock:
        if _compiled:
            return 0.0
        from numba.core import event

        shown = []

        class _Notice(event.Listener):
            def on_start(self, ev):
                if not shown and verbose:
                    shown.append(True)
                    msg = (f"rft_mujoco: compiling the numba kernel (first use, ~{COMPILE_SECONDS} s; "
                           "cached afterwards)")
                    _log.info(msg)
                    print(msg, file=sys.stderr, flush=True)

            def on_end(self, ev):
                pass

        t0 = time.perf_counter()
        _drop_stale_cache()
        with event.install_listener("numba:compile", _Notice()):
            _warm_up()
        _compiled = True
        seconds = time.perf_counter() - t0
        if shown:
            _log.info("rft_mujoco: numba kernel compiled in %.1f s", seconds)
        return seconds


_KERNEL_MODULES = ("compiled/elements", "compiled/rest", "physics/elements", "physics/law", "physics/rest")
"""The modules whose compiled functions call one another (the package's numba cache)."""


def _drop_stale_cache() -> None:
    """numba keys each function's cache entry on its own source file only, so a compiled function that
    calls into another module would keep stale machine code after that module alone changed (an edit, a
    ``git checkout``). The package therefore stamps its cache with a hash of all the kernel modules and
    drops the cache files when the hash differs. (Only for the default cache next to the sources; with
    ``NUMBA_CACHE_DIR`` set, clear that directory after changing the sources.)"""
    import glob
    import hashlib
    import os

    here = os.path.dirname(os.path.abspath(__file__))
    folder = os.path.join(here, "__pycache__")
    package = os.path.dirname(here)
    digest = hashlib.sha256()
    for name in _KERNEL_MODULES:
        with open(os.path.join(package, name + ".py"), "rb") as f:
            digest.update(f.read())
    stamp = os.path.join(folder, "rft_mujoco_kernels.sha256")
    try:
        with open(stamp) as f:
            if f.read().strip() == digest.hexdigest():
                return
    except OSError:
        pass
    try:
        os.makedirs(folder, exist_ok=True)
        for name in ("elements", "rest"):
            for path in glob.glob(os.path.join(folder, f"{name}.*.nb[ic]")):
                os.remove(path)
        with open(stamp, "w") as f:
            f.write(digest.hexdigest() + "\n")
    except OSError:                  # a read-only install: numba caches elsewhere, keyed by file stamps
        pass


def _warm_up() -> None:
    """Call every kernel once on tiny inputs of exactly the types the package passes."""
    i8 = np.int64
    c3 = np.zeros((2, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    g = np.array([0.0, 0.0, -1.0])
    coef = law.COEFFICIENTS
    tol = tolerances()
    _element_forces(c3.reshape(-1), nrm.reshape(-1), np.ones(2), (c3 + 1.0).reshape(-1), 0.0, g, 1.0, coef, 0.4,
                    False, False, False, tol, np.zeros((9, CHUNK)), np.zeros(6))
    packed = pack(c3, nrm, np.ones(2), np.zeros(2, i8), 1)
    B = 1
    ids = np.ones(B, dtype=i8)
    xb, xm, cv = np.zeros((2, 3)), np.zeros((2, 9)), np.zeros((2, 6))
    pos, mat, com, vcom, om = (np.zeros((B, 3)), np.zeros((B, 9)), np.zeros((B, 3)), np.zeros((B, 3)),
                               np.zeros((B, 3)))
    touch = np.zeros(B, dtype=i8)
    groups = np.zeros((B, GROUPS_PER_BODY, 6))
    count = np.zeros(B, dtype=i8)
    mdep = np.zeros(B)
    scratch = np.zeros((SCRATCH_ROWS, CLUSTER_SIZE))
    for kind, tp, heights in ((FLAT, np.zeros(11), _NO_HEIGHTS), (HEIGHTFIELD, np.zeros(11), np.zeros((3, 3)))):
        touching(ids, np.zeros(B, dtype=i8), xb, xm, xb, cv, xb, np.zeros(7), np.zeros(6), np.zeros((B, 3)),
                 np.zeros(B), packed.centroids, packed.cluster_start, packed.cluster_center,
                 packed.cluster_radius, packed.body_clusters, g, 0.0, kind, tp, heights, touch, pos, mat, com,
                 vcom, om)
        wrenches(touch, 0, *packed.arrays(), pos, mat, com, vcom, om, np.zeros((0, 6)), 0.0, g, 0.0, kind, tp,
                 heights, 1.0, coef, 0.4, False, False, False, tol, scratch, groups, count, mdep)
        from rft_mujoco.compiled import rest as fastrest   # the rest evaluation around these kernels
        fastrest.warm_up(packed.arrays(), kind, tp, heights, coef, tol)
    finish(groups, count, mdep, vcom, om, np.zeros((0, 6)), False, touch, 0, ids, np.zeros((B, 3)),
           np.zeros((B, 3)), np.zeros(B, dtype=i8), np.zeros(B), np.ones(B), np.zeros((B, 3)), np.zeros((2, 6)))
    x6 = np.zeros((2, 6))
    user_part(x6, x6.copy(), x6.copy(), ids, x6.copy())
    commit(x6, x6.copy(), x6.copy(), ids, x6.copy(), x6.copy())
