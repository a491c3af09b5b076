"""Triangle meshes -> surface elements: subdivision to an element size, topology and orientation checks,
and mesh files (STL, OBJ, PLY, ... through trimesh).

Each triangle is split into ``k^2`` congruent triangles (``k = ceil(longest edge / size)``); degenerate
triangles are dropped; inverted meshes and inconsistently wound faces raise, open meshes warn.
"""

from __future__ import annotations

import warnings

import numpy as np

from rft_mujoco import tol

from rft_mujoco.geometry.elements import Elements, _check_length, as_points

DEGENERATE_TOL = 1e-9
"""A mesh triangle with ``area <= DEGENERATE_TOL * (longest edge)^2`` is degenerate and dropped."""
VOLUME_TOL = 1e-9
"""A mesh whose enclosed volume is below ``-VOLUME_TOL * (bounding-box diagonal)^3`` is inverted."""
MERGE_TOL = 1e-9
"""Mesh vertices closer than ``MERGE_TOL * (bounding-box diagonal)`` count as one for the topology check."""


# --- triangle meshes -------------------------------------------------------------------------------
def _subdivision_centroids(k: int) -> np.ndarray:
    """(k^2, 2) barycentric (u, w) of the centroids of the k^2 congruent sub-triangles of a triangle
    (point = v0 + u (v1 - v0) + w (v2 - v0))."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    i, j = i.ravel(), j.ravel()
    up = i + j <= k - 1
    down = i + j <= k - 2
    return np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], axis=1),
                           np.stack([i[down] + 2 / 3, j[down] + 2 / 3], axis=1)]) / k


def _topology(vertices: np.ndarray, faces: np.ndarray, scale: float) -> tuple[int, int]:
    """(open edges, inconsistently wound edges) after merging coincident vertices."""
    key = np.round(vertices / (MERGE_TOL * scale)).astype(np.int64)
    _, vid = np.unique(key, axis=0, return_inverse=True)
    f = vid.reshape(-1)[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    undirected, count = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    n_open = int(np.count_nonzero(count != 2))
    _, dcount = np.unique(directed, axis=0, return_counts=True)
    # A consistently wound closed mesh uses each directed edge once.
    n_flipped = int(np.count_nonzero(dcount > 1))
    return n_open, n_flipped


def mesh(vertices, faces, size=None, *, name: str = "mesh") -> Elements:
    """Elements of a triangle mesh (counter-clockwise faces seen from outside = outward normals).

    Args:
        vertices: (n, 3) float, m.
        faces: (m, 3) int, vertex indices.
        size: if given, each triangle is split into ``k^2`` congruent triangles with
            ``k = ceil(longest edge / size)``, so all edges are ``<= size``; ``None`` keeps the faces.
        name: how errors and warnings name the mesh.
    Raises:
        ValueError: bad shapes or indices, no non-degenerate face, inverted mesh (negative enclosed
            volume) or inconsistently wound faces.
    Warns:
        UserWarning: once, if the mesh is open (some edge not shared by exactly two faces).
    """
    return _mesh(vertices, faces, size, f"mesh {name!r}")


def _mesh(vertices, faces, size, label: str) -> Elements:
    """:func:`mesh`, with ``label`` naming the mesh in errors and warnings."""
    v = as_points(vertices, "vertices")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ValueError(f"faces of {label} must be a non-empty (m, 3) int array, got shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces of {label} must be integers, got dtype {f.dtype}")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError(f"faces of {label} index vertices 0..{v.shape[0] - 1}, got indices "
                         f"{f.min()}..{f.max()}")
    h = None if size is None else _check_length(size, "size")
    used = v[np.unique(f)]
    scale = float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))   # bounding-box diagonal, m
    if scale <= 0:
        raise ValueError(f"{label} has zero extent")

    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross = np.cross(p1 - p0, p2 - p0)
    double_area = np.linalg.norm(cross, axis=1)
    longest = np.sqrt(np.max(np.stack([((p1 - p0) ** 2).sum(1), ((p2 - p1) ** 2).sum(1),
                                       ((p0 - p2) ** 2).sum(1)]), axis=0))
    keep = 0.5 * double_area > DEGENERATE_TOL * longest**2
    if not np.any(keep):
        raise ValueError(f"{label} has only degenerate (zero-area) faces")

    volume = float(np.einsum("ij,ij->", p0[keep] - used.mean(0), cross[keep]) / 6.0)
    n_open, n_flipped = _topology(v, f[keep], scale)
    if volume < -VOLUME_TOL * scale**3:
        raise ValueError(f"{label} is inverted: its enclosed volume is {volume:.6g} m^3 < 0, so its "
                         "face normals point inward; reverse the vertex order of every face (e.g. "
                         "trimesh's mesh.invert() or swap two indices per face) and reload")
    if n_flipped:
        raise ValueError(f"{label} has inconsistently wound faces ({n_flipped} edges used twice in "
                         "the same direction), so some normals point inward; fix the winding (e.g. "
                         "trimesh.repair.fix_normals) and reload")
    if n_open:
        warnings.warn(f"{label} is open: {n_open} edges are not shared by exactly two faces; sand "
                      "acts only on the outward side of the faces given and the volume check is "
                      "approximate; close the mesh (e.g. trimesh.repair.fill_holes) for a solid intruder",
                      UserWarning, stacklevel=2)

    p0, e1, e2 = p0[keep], (p1 - p0)[keep], (p2 - p0)[keep]
    normal = cross[keep] / double_area[keep, None]
    area = 0.5 * double_area[keep]
    if h is None:
        return Elements(p0 + (e1 + e2) / 3.0, normal, area)
    k = np.maximum(np.ceil(longest[keep] / h - tol.ROUND_RTOL), 1).astype(np.int64)
    parts = []
    for kk in np.unique(k):          # one pass per subdivision level, vectorized over its triangles
        sel = np.flatnonzero(k == kk)
        uw = _subdivision_centroids(int(kk))
        c = (p0[sel, None, :] + uw[None, :, 0, None] * e1[sel, None, :]
             + uw[None, :, 1, None] * e2[sel, None, :])                    # (m_k, k^2, 3)
        m = uw.shape[0]
        parts.append(Elements(c.reshape(-1, 3), np.repeat(normal[sel], m, axis=0),
                              np.repeat(area[sel] / m, m)))
    return Elements.concatenate(parts)


def load_mesh(path, size=None) -> Elements:
    """Elements of a mesh file (any format trimesh reads: STL, OBJ, PLY, GLB, ...), in the file's units
    (MuJoCo's are m); scenes are merged into one mesh. ``size``: as :func:`mesh`.

    Raises:
        ValueError: the file holds no triangles, or the checks of :func:`mesh` fail.
    """
    import trimesh

    loaded = trimesh.load(str(path), force="mesh", process=False)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        raise ValueError(f"mesh file {str(path)!r} holds no triangles (trimesh read {type(loaded).__name__})")
    return _mesh(np.asarray(loaded.vertices, dtype=float), faces, size, f"mesh file {str(path)!r}")
