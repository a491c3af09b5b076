"""Packed elements, run-time occluders, the broadphase and the naive finish of the compiled backend.

* Elements are stored once, at attach, in a packed layout (:func:`pack`): per body, cut into spatially
  compact *clusters* of at most :data:`CLUSTER_SIZE` elements, structure of arrays. A cluster whose
  bounding sphere lies above the highest sand is skipped whole (exact).
* Run-time culling (:class:`rft_mujoco.geometry.occlusion.Occluders`, built at attach): the geoms of other
  bodies that a body's surface can get inside of (capsules meeting at a joint) are tested only against
  clusters whose bounding sphere reaches theirs.
* :func:`touching`: the broadphase (bodies with a submerged element).

The element pass itself is :func:`rft_mujoco.compiled.element_pass.wrenches`
(:class:`rft_mujoco.compiled.element_pass.ElementPass` runs it on its own, for tests and benchmarks).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from rft_mujoco.compiled.jit import INLINE, JIT, JIT_LAW, njit
from rft_mujoco.compiled.terrain import ABOVE, DEFORMABLE, FLAT, _depth, deformed_range
from rft_mujoco.physics import terrain_spec as ts

CLUSTER_SIZE = 128
"""Most elements per cluster (the unit of culling and of the vectorized inner loops)."""
PAD = 16
"""Clusters are padded to a multiple of this many slots, so the vectorized loops (8 float64 lanes, unrolled
twice) never run a scalar remainder; padding slots have NaN centroids and are never loaded."""
LANES = 8
"""Interleaved lanes of the deepest-element maximum (one SIMD register of doubles)."""


_MESH = int(mujoco.mjtGeom.mjGEOM_MESH)
_SPHERE = int(mujoco.mjtGeom.mjGEOM_SPHERE)
_CAPSULE = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
_CYLINDER = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
_BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
_ELLIPSOID = int(mujoco.mjtGeom.mjGEOM_ELLIPSOID)


# --- packed elements ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Packed:
    """Elements of B bodies in the compiled layout.

    Attributes:
        centroids, normals: (3, E) float, body-frame centroids (m) and unit normals, packed order.
        areas: (E,) float, m^2 (0 on padding slots).
        index: (E,) int, the original element index of each packed slot (-1: padding).
        cluster_start: (C + 1,) int, packed range of each cluster (a multiple of :data:`PAD` long).
        cluster_center: (C, 3) float, body-frame centre of each cluster's bounding sphere (m).
        cluster_radius: (C,) float, its radius (m), slightly inflated against round-off.
        body_clusters: (B + 1,) int, the clusters of body b are ``body_clusters[b]:body_clusters[b + 1]``.
    """

    centroids: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    index: np.ndarray
    cluster_start: np.ndarray
    cluster_center: np.ndarray
    cluster_radius: np.ndarray
    body_clusters: np.ndarray

    def arrays(self) -> tuple:
        """The arrays the kernels read, in their argument order."""
        return (self.centroids, self.normals, self.areas, self.cluster_start, self.cluster_center,
                self.cluster_radius, self.body_clusters)


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


def pack(local_centroids, local_normals, areas, elem_body, n_bodies: int, cluster_size: int = CLUSTER_SIZE) -> Packed:
    """Pack elements (E, 3) / (E,) of bodies ``elem_body`` (E,) int in 0..B-1 for the compiled kernels."""
    c = np.asarray(local_centroids, dtype=float).reshape(-1, 3)
    n = np.asarray(local_normals, dtype=float).reshape(-1, 3)
    a = np.asarray(areas, dtype=float).reshape(-1)
    body = np.asarray(elem_body, dtype=np.int64).reshape(-1)
    if not (c.shape[0] == n.shape[0] == a.size == body.size):
        raise ValueError(f"element arrays must agree in length, got {c.shape}, {n.shape}, {a.shape}, {body.shape}")
    pieces, body_clusters = [], [0]
    for b in range(n_bodies):
        idx = np.flatnonzero(body == b)
        if idx.size:
            _split(c, idx, cluster_size, pieces)
        body_clusters.append(len(pieces))
    slots, starts = [], [0]
    center = np.zeros((len(pieces), 3))
    radius = np.zeros(len(pieces))
    for k, p in enumerate(pieces):
        pts = c[p]
        center[k] = 0.5 * (pts.min(0) + pts.max(0))
        radius[k] = float(np.sqrt(((pts - center[k]) ** 2).sum(1).max())) * (1.0 + 1e-9) + 1e-12
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
    return Packed(np.ascontiguousarray(cp.T), np.ascontiguousarray(npk.T), ap, index, np.asarray(starts, np.int64),
                  center, radius, np.asarray(body_clusters, np.int64))


# --- run-time occluders (the set: rft_mujoco.geometry.occlusion.Occluders) -------------------------------
@njit(**INLINE)
def _inside(x, y, z, kind, s0, s1, s2, hs, h0, h1, margin):
    """:func:`rft_mujoco.geometry.occlusion.inside_geom` of one point in the geom frame."""
    if kind == _SPHERE:
        return x * x + y * y + z * z < (s0 - margin) * (s0 - margin) and s0 > margin
    if kind == _CAPSULE:
        a = z - min(max(z, -s1), s1)
        r = s0 - margin
        return r > 0.0 and x * x + y * y + a * a < r * r
    if kind == _CYLINDER:
        r = s0 - margin
        return r > 0.0 and x * x + y * y < r * r and abs(z) < s1 - margin
    if kind == _BOX:
        return abs(x) < s0 - margin and abs(y) < s1 - margin and abs(z) < s2 - margin
    if kind == _ELLIPSOID:
        a, b, c = s0 - margin, s1 - margin, s2 - margin
        if a <= 0.0 or b <= 0.0 or c <= 0.0:
            return False
        return (x / a) * (x / a) + (y / b) * (y / b) + (z / c) * (z / c) < 1.0
    if kind == _MESH:
        for k in range(h0, h1):
            if not hs[k, 0] * x + hs[k, 1] * y + hs[k, 2] * z < hs[k, 3] - margin:
                return False
        return h1 > h0
    return False


@njit(**INLINE)
def _outside_ball(x, y, z, radius, kind, s0, s1, s2, hs, h0, h1, margin):
    """True when no point within ``radius`` of (x, y, z) (geom frame) is inside the geom as :func:`_inside`
    tests it: a cluster of elements that can be skipped whole. Boxes and meshes (one separating face
    suffices), spheres, capsules and cylinders (the distance to the axis or the ends), ellipsoids (their
    largest semi-axis's ball); other kinds answer False (their elements are tested one by one)."""
    if kind == _CAPSULE:
        a = z - min(max(z, -s1), s1)
        r = s0 - margin
        return r <= 0.0 or x * x + y * y + a * a >= (r + radius) * (r + radius)
    if kind == _CYLINDER:
        r = s0 - margin
        return r <= 0.0 or x * x + y * y >= (r + radius) * (r + radius) or abs(z) >= s1 - margin + radius
    if kind == _ELLIPSOID:
        r = max(s0, s1, s2) - margin
        return min(s0, s1, s2) <= margin or x * x + y * y + z * z >= (r + radius) * (r + radius)
    if kind == _BOX:
        return abs(x) >= s0 - margin + radius or abs(y) >= s1 - margin + radius or abs(z) >= s2 - margin + radius
    if kind == _MESH:
        for k in range(h0, h1):
            if hs[k, 0] * x + hs[k, 1] * y + hs[k, 2] * z >= hs[k, 3] - margin + radius:
                return True
        return False
    if kind == _SPHERE:
        r = s0 - margin + radius
        return x * x + y * y + z * z >= r * r
    return False


@njit(**INLINE)
def _nearest_face(x, y, z, kind, hs, h0, h1):
    """The face of a mesh hull (row of ``hs``) whose plane the point (x, y, z) (geom frame, a cluster's
    centre) lies farthest outside of, or farthest inside the least: the face most likely to separate the
    cluster's elements, tested first so that most of them leave :func:`_inside` after one face; -1 for
    other kinds."""
    if kind != _MESH or h1 <= h0:
        return -1
    best, k_best = -np.inf, h0
    for k in range(h0, h1):
        d = hs[k, 0] * x + hs[k, 1] * y + hs[k, 2] * z - hs[k, 3]
        if d > best:
            best, k_best = d, k
    return k_best


# --- the broadphase --------------------------------------------------------------------------------------
@njit(**JIT_LAW)
def touching(bodies, kinematics, surface, terrain, out):
    """Broadphase and depth pre-pass of a handle's bodies from MjData arrays. ``bodies`` = (``ids`` (B,) MuJoCo
    body ids, ``root`` (B,) their root bodies, ``bound_center``, ``bound_radius``); ``kinematics`` = MjData's
    (``xpos``, ``xmat``, ``xipos``, ``cvel``, ``subtree_com``, ``qpos``, ``qvel``); ``surface`` and ``terrain``:
    :data:`rft_mujoco.compiled.element_pass.SURFACE` and ``TERRAIN``; ``out`` = (``touch``, ``body_pos``,
    ``body_mat``, ``body_com``, ``v_com``, ``omega``).

    A body is a candidate when the lowest point of its bounding sphere (centre ``bound_center`` (B, 3)
    in the body frame, radius ``bound_radius`` (B,)) is below ``max_height``; it touches the sand when
    one of its elements has depth > 0 (clusters above the sand are skipped; on a flat surface the depth is
    the element pass's own, affine in the body-frame centroid, counted over a cluster at a time). Touching
    bodies are written, in order, to ``touch`` (handle indices) and row j of ``body_pos``, ``body_mat`` (9),
    ``body_com`` (``xipos``), ``v_com`` (``cvel``'s linear part moved from ``subtree_com[root]`` to ``xipos``)
    and ``omega``. Returns their number, or -1 when some body is a candidate and qpos/qvel are not finite.
    """
    ids, root, bound_center, bound_radius = bodies
    xpos, xmat, xipos, cvel, subtree_com, qpos, qvel = kinematics
    centroids, cluster_start, cluster_center, cluster_radius, body_clusters = (surface[0], surface[3], surface[4],
                                                                               surface[5], surface[6])
    g_hat, max_height, kind, tp, heights = terrain
    touch, body_pos, body_mat, body_com, v_com, omega = out
    g0, g1, g2 = g_hat[0], g_hat[1], g_hat[2]
    flat = kind == FLAT and tp[ts.TP_REGION] == 0.0
    deformed = kind == DEFORMABLE and g2 < 0.0
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
        gb0 = r[0] * g0 + r[3] * g1 + r[6] * g2           # as rft_mujoco.compiled.element_pass.wrenches
        gb1 = r[1] * g0 + r[4] * g1 + r[7] * g2
        gb2 = r[2] * g0 + r[5] * g1 + r[8] * g2
        c0 = tp[ts.TP_HEIGHT] + (px * g0 + py * g1 + pz * g2)
        hit = False
        for q in range(body_clusters[i], body_clusters[i + 1]):
            q0, q1, q2 = cluster_center[q, 0], cluster_center[q, 1], cluster_center[q, 2]
            low = -((px + (r[0] * q0 + r[1] * q1 + r[2] * q2)) * g0 + (py + (r[3] * q0 + r[4] * q1 + r[5] * q2))
                    * g1 + (pz + (r[6] * q0 + r[7] * q1 + r[8] * q2)) * g2) - cluster_radius[q]
            if low > max_height:
                continue
            if deformed:                                  # the deformed surface around the cluster
                lo, hi = deformed_range(px + (r[0] * q0 + r[1] * q1 + r[2] * q2), py + (r[3] * q0 + r[4] * q1
                                        + r[5] * q2), cluster_radius[q], tp, heights)
                if low > hi + ABOVE:
                    continue                              # wholly above it
                if low + 2.0 * cluster_radius[q] < lo - ABOVE:
                    hit = True                            # wholly below it
                    break
            if flat:
                if tp[ts.TP_HEIGHT] - (low + 2.0 * cluster_radius[q]) > 0.0:     # wholly below flat sand
                    hit = True
                    break
                s, e = cluster_start[q], cluster_start[q + 1]
                cx, cy, cz = centroids[0, s:e], centroids[1, s:e], centroids[2, s:e]
                under = 0                                 # (over slices from 0: numba's index wraparound made
                for k in range(cx.shape[0]):              # LLVM gather the centroids: 3.3% of a step, now 2.0%)
                    under += c0 + (gb0 * cx[k] + gb1 * cy[k] + gb2 * cz[k]) > 0.0
                if under > 0:
                    hit = True
                    break
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


@njit(**JIT)
def finish_naive(bodies, n_touch, ids, passive, diagnostics, sand_out):
    """``stabilize=False``: the published wrench of each touching body, dropped when ``passive`` and it would
    do positive work; diagnostics (B, ...) of every row and the wrenches added to ``sand_out`` (nbody, 6).
    ``bodies`` = (``wrench``, ``count``, ``depth_max``, ``occluded``, ``v_com``, ``omega``, ``touch``): the
    touching bodies' rows (``n_touch`` of them, handle indices ``touch``); ``ids``: the handle's MuJoCo body ids;
    ``diagnostics`` = (``force``, ``torque``, ``submerged``, ``max_depth``, ``scale``, ``rft_force``,
    ``resting``, ``occluded_area``). Returns 1 when a wrench is non-zero, 0 when none is, -1 (nothing written)
    when one is not finite."""
    wrench, count, depth_max, occluded, v_com, omega, touch = bodies
    force, torque, submerged, max_depth, scale, rft_force, resting, occluded_area = diagnostics
    for i in range(force.shape[0]):
        for c in range(3):
            force[i, c] = 0.0
            torque[i, c] = 0.0
            rft_force[i, c] = 0.0
        submerged[i] = 0
        max_depth[i] = 0.0
        scale[i] = 1.0
        resting[i] = False
        occluded_area[i] = 0.0
    status = 0
    for j in range(n_touch):
        b = touch[j]
        for c in range(3):
            rft_force[b, c] = wrench[j, c]
        submerged[b] = count[j]
        max_depth[b] = depth_max[j]
        occluded_area[b] = occluded[j]
        power = 0.0
        for c in range(3):
            power += wrench[j, c] * v_com[j, c] + wrench[j, 3 + c] * omega[j, c]
        drop = passive and power > 0.0
        if drop:
            scale[b] = 0.0
        for c in range(3):
            force[b, c] = 0.0 if drop else wrench[j, c]
            torque[b, c] = 0.0 if drop else wrench[j, 3 + c]
        for c in range(6):
            x = 0.0 if drop else wrench[j, c]
            if not math.isfinite(x):
                status = -1
            elif x != 0.0 and status == 0:
                status = 1
    if status < 0:
        return -1
    for j in range(n_touch):
        b = touch[j]
        row = ids[b]
        for c in range(3):
            sand_out[row, c] += force[b, c]
            sand_out[row, 3 + c] += torque[b, c]
    return status
