"""Triangle meshes -> surface elements at a requested size, whatever the triangulation; the orientation
checks and repairs meshes need as they are shipped; mesh files (STL, OBJ, PLY, ... through trimesh).

Elements (:func:`mesh` with a ``size``) are made in two passes, both vectorized:

1. pieces: each triangle is cut into small flat pieces whose extent is at most ``PIECE_FRACTION * size``
   (:func:`_pieces`): a long thin triangle is cut along its length only, a triangle already smaller
   than that stays whole, others into congruent sub-triangles;
2. clusters: pieces are gathered into cells of a grid of edge ``VOXEL_SCALE * size`` (a cell centred on
   the middle of the mesh, the grid turned against the mesh frame: :data:`GRID_ANGLE`), one cluster per
   cell and normal direction (a cube map, :data:`COARSE_NORMAL_BINS`, so the two sides of a thin plate
   and the faces of a sharp edge stay apart); a cluster whose normals spread
   more than :data:`SPREAD_TOL` (a small curved feature, an edge sharper than the cube map sees) is
   split by finer normal directions (:data:`FINE_NORMAL_BINS`). An element is a cluster: its area is
   the sum of its pieces' areas, its normal the direction of the sum of ``n dA`` and its centroid the
   area centroid (the conventions of the primitives' curved cells in :mod:`rft_mujoco.geometry.surface`).

So the element count follows the area: about ``area / size^2`` (0.75-1.3x on flat faces: the cells a
plane crosses depend on its tilt; measured for the test robots in tests/test_mesh_robots.py), for fine
visual meshes of tiny triangles and for slivers 0.5 m long alike.

Orientation (:func:`orientation`): edges are counted after merging coincident vertices. An edge shared
by exactly two faces (manifold) tells whether they agree (opposite directions) or one is flipped (the
same direction); an edge on one face is open; an edge on three or more faces (non-manifold: two parts
meeting at an edge, a fin) says nothing about winding, and is not counted as a flip. Where faces
disagree across manifold edges they are re-wound to agree with their neighbours; each patch connected
through manifold edges then takes the orientation with a positive enclosed volume when it is closed (its
own faces use each of their edges twice), or that of the larger area of its faces as given when it is
open; a mesh every edge of which has two or
more faces and whose volume is negative is turned outside in. Errors only where that answer is not
unique: a patch that cannot be wound consistently (one-sided, like a Moebius strip), an open patch
wound half one way and half the other, an open mesh whose volume is negative. Whatever was repaired or
approximated is said once per mesh with a :class:`~rft_mujoco.geometry.elements.SandSetupWarning`.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from rft_mujoco import tol

from rft_mujoco.geometry.elements import Elements, SandSetupWarning, _check_length, as_points

# --- tolerances and construction constants: one place ----------------------------------------------------
DEGENERATE_TOL = 1e-9
"""A mesh triangle with ``area <= DEGENERATE_TOL * (longest edge)^2`` is degenerate and dropped."""
VOLUME_TOL = 1e-9
"""A mesh whose enclosed volume is below ``-VOLUME_TOL * (bounding-box diagonal)^3`` is inverted."""
MERGE_TOL = 1e-9
"""Mesh vertices closer than ``MERGE_TOL * (bounding-box diagonal)`` count as one for the topology check."""
TIE_TOL = 1e-9
"""An open patch whose faces are wound one way and the other over areas equal within this fraction of
its area has no majority orientation (an error)."""
PIECE_FRACTION = 0.5
"""Pieces (the first pass) extend at most this fraction of the element size along each triangle's long
and short directions, so that the grid of the second pass, not the triangulation, shapes the elements."""
VOXEL_SCALE = 1.15
"""Cell edge of the clustering grid, in element sizes. A flat face of area A crosses about
``A (|n_x| + |n_y| + |n_z|) / (VOXEL_SCALE size)^2`` cells (1 to 1.73 times ``A / (VOXEL_SCALE size)^2``
as its tilt goes from an axis to a diagonal), so 1.15 keeps the count within 0.75-1.3 times
``A / size^2``: the size means what it means for primitives (cells of about ``size^2``)."""
SPREAD_TOL = 0.02
"""A cluster whose normals spread, ``1 - |sum n dA| / sum dA``, more than this is split (a cap of
half-angle a has spread ``(1 - cos a) / 2``: 0.02 is a = 16 degrees, cells of about 32 degrees, near the
18-degree cells that :data:`rft_mujoco.geometry.surface.MIN_CIRCLE_SEGMENTS` gives small primitives)."""
def _rotation(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


GRID_AXIS, GRID_ANGLE = (1.0, 2.0, 3.0), 0.7
"""The clustering grid is turned by GRID_ANGLE rad about GRID_AXIS against the mesh frame, so that its cell
layers are not horizontal when the mesh stands upright in the sand: cells cut by the waterline then
straddle it at every height around the body, and their centroid-rule errors cancel instead of adding up.
Measured on a 5 cm ball, 13 depths of its waterline, 1 cm elements, pulled straight up: worst 33% and mean
9.4% force error with an axis-aligned grid, 5.8% and 1.6% turned (the primitive sphere: 22% and 3.3%)."""
_GRID_AXES = _rotation(GRID_AXIS, GRID_ANGLE)

COARSE_NORMAL_BINS = 2
"""Clusters are first split by a cube map of this many bins per face edge: 2 puts the planes ``n_x = 0``,
``n_y = 0``, ``n_z = 0`` of the mesh frame between clusters, as the primitives put their equators between
latitude bands (:data:`rft_mujoco.geometry.surface.LATITUDE_BANDS_MULTIPLE`): a cluster straddling the
leading-edge boundary of a motion along a mesh axis misplaces it. Measured on a 5 cm ball, waterline 1 cm
and 2 cm below its top, 1 cm elements, pulled straight up: 13% and 9% force error with 1 bin per face."""
FINE_NORMAL_BINS = 4
"""A cluster spread more than :data:`SPREAD_TOL` is split by a cube map of this many bins per face edge
(18-27 degrees each) within its grid cell: a small curved feature gets cells like a small primitive's, a
sharp edge inside a cell splits it in two."""


# --- orientation ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Orientation:
    """What :func:`orientation` found and did (counts after merging coincident vertices).

    Attributes:
        faces: (m, 3) int, the faces given, with the re-wound ones reversed (same vertex indices).
        open_edges: edges of one face only (the rims of holes).
        nonmanifold_edges: edges shared by three or more faces.
        flipped_edges: edges of two faces that use them in the same direction (as given).
        rewound: faces reversed to agree with their neighbours or to give their closed patch a positive
            volume (0 when all agree).
        inverted: True when every face was reversed (the mesh was inside out).
        volume: enclosed volume after the repair, m^3 (approximate for open meshes).
    """

    faces: np.ndarray
    open_edges: int
    nonmanifold_edges: int
    flipped_edges: int
    rewound: int
    inverted: bool
    volume: float

    def notes(self) -> list[str]:
        """What was repaired or approximated, one phrase each (empty for a clean closed mesh)."""
        out = []
        if self.inverted:
            out.append("it was inside out (negative enclosed volume): every face was reversed")
        elif self.rewound:
            out.append(f"{self.rewound} faces were wound against their neighbours ({self.flipped_edges} edges "
                       "used twice in the same direction) and were reversed")
        if self.nonmanifold_edges:
            out.append(f"{self.nonmanifold_edges} edges are shared by 3 or more faces (non-manifold): every "
                       "face counts as outer surface, so walls inside the solid, if any, feel sand too")
        if self.open_edges:
            out.append(f"{self.open_edges} edges bound one face only (open: holes or a surface): sand acts on "
                       "the outward side of the faces given, and the volume and the inside test that culls "
                       "overlapping geoms treat the mesh as if it were closed")
        return out


def _edges(f: np.ndarray):
    """Edge uses of faces ``f`` (m, 3): (edge id per use (3m,), face per use, forward per use, use counts
    per edge). Use ``u = k m + i`` is edge ``(f[i, k], f[i, k + 1])``."""
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    und = np.sort(directed, axis=1)
    _, edge, count = np.unique(und[:, 0] * (int(f.max()) + 1) + und[:, 1], return_inverse=True,
                               return_counts=True)            # one int64 key per edge (fast unique)
    return edge.reshape(-1), np.tile(np.arange(f.shape[0]), 3), directed[:, 0] < directed[:, 1], count


def _signed_volumes(p: np.ndarray, faces: np.ndarray, label: np.ndarray, n: int) -> np.ndarray:
    """(n,) enclosed volume per label (m^3) of faces (m, 3) of points ``p`` (already centred)."""
    t = p[faces]
    return np.bincount(label, np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0, minlength=n)


def orientation(vertices, faces, *, name: str = "mesh") -> Orientation:
    """Check and repair the winding of a triangle mesh (see the module docstring for the rules).

    Args:
        vertices: (n, 3) float, m.
        faces: (m, 3) int, non-degenerate faces (counter-clockwise seen from outside = outward normals).
        name: how errors name the mesh.
    Raises:
        ValueError: naming the mesh, where no single orientation follows from the faces (a one-sided
            patch; an open patch wound half each way; an open mesh with a negative volume).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    v = as_points(vertices, "vertices")
    f = np.asarray(faces, dtype=np.int64)
    m = f.shape[0]
    used = v[np.unique(f)]
    scale = float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))
    key = np.round(v / (MERGE_TOL * max(scale, tol.TINY))).astype(np.int64)
    order = np.lexsort(key.T)
    new = np.ones(key.shape[0], dtype=bool)
    new[1:] = np.any(key[order[1:]] != key[order[:-1]], axis=1)
    vid = np.empty(key.shape[0], dtype=np.int64)
    vid[order] = np.cumsum(new) - 1                      # the same id for coincident vertices
    g = vid.reshape(-1)[f]
    alive = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 2] != g[:, 0])
    live = np.flatnonzero(alive)
    edge, face, forward, count = _edges(g[live])
    n_open = int(np.count_nonzero(count == 1))
    n_nonmanifold = int(np.count_nonzero(count >= 3))
    # manifold edges: their two uses, adjacent in the order sorted by edge
    order = np.argsort(edge, kind="stable")
    e_sorted = edge[order]
    first = order[:-1][(e_sorted[:-1] == e_sorted[1:]) & (count[e_sorted[:-1]] == 2)]
    second = order[1:][(e_sorted[:-1] == e_sorted[1:]) & (count[e_sorted[:-1]] == 2)]
    fa, fb = face[first], face[second]
    same = forward[first] == forward[second]            # the two faces disagree across this edge
    _, one = np.unique(np.minimum(fa, fb) * (m + 1) + np.maximum(fa, fb), return_index=True)
    la, lb, lsame = fa[one], fb[one], same[one]         # one link per pair of faces (for the BFS)
    n_flipped = int(np.count_nonzero(same))
    k = live.size
    graph = coo_matrix((np.ones(fa.size), (fa, fb)), shape=(k, k))
    n_comp, comp = connected_components(graph, directed=False)
    flip = np.zeros(k, dtype=bool)
    if n_flipped:
        # parity of each face relative to its patch's first face: one BFS from a virtual root
        roots = np.unique(comp, return_index=True)[1]
        rows = np.concatenate([la, lb, np.full(roots.size, k)])
        cols = np.concatenate([lb, la, roots])
        w = np.concatenate([lsame, lsame, np.zeros(roots.size, bool)]).astype(np.int8) + 1
        adj = coo_matrix((w, (rows, cols)), shape=(k + 1, k + 1)).tocsr()
        bfs, pred = breadth_first_order(adj, k, directed=True, return_predecessors=True)
        bfs = bfs[1:]
        step = np.asarray(adj[pred[bfs], bfs]).ravel() == 2
        parity = np.zeros(k + 1, dtype=bool)
        for node, p_node, s in zip(bfs.tolist(), pred[bfs].tolist(), step.tolist()):
            parity[node] = parity[p_node] ^ s
        flip = parity[:k]
        bad = np.flatnonzero((flip[fa] ^ flip[fb]) != same)
        if bad.size:
            raise ValueError(f"{name} cannot be wound consistently: {np.unique(comp[fa[bad]]).size} of its "
                             "patches are one-sided (each face's neighbours ask for opposite windings, like a "
                             "Moebius strip), so no outward side exists; remesh it as a closed surface and "
                             "reload")
    p = v - used.mean(axis=0)
    tri = p[g[live]]
    dbl = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    # a patch is closed when its own faces use each of their edges exactly twice (so a closed part that
    # meets another part at a non-manifold edge is still closed)
    _, inverse, uses = np.unique(comp[face] * count.size + edge, return_inverse=True, return_counts=True)
    comp_open = np.bincount(comp[face], uses[inverse.reshape(-1)] != 2, minlength=n_comp) > 0
    fixed = np.where(flip[:, None], f[live][:, ::-1], f[live])
    vol = _signed_volumes(p, fixed, comp, n_comp)
    turn = ~comp_open & (vol < 0)                          # closed patches: outward = positive volume
    if n_flipped:
        a_flip = np.bincount(comp, dbl * flip, minlength=n_comp)
        a_keep = np.bincount(comp, dbl * ~flip, minlength=n_comp)
        tie = comp_open & (np.abs(a_flip - a_keep) <= TIE_TOL * (a_flip + a_keep)) & (a_flip > 0)
        if tie.any():
            raise ValueError(f"{name} has {int(tie.sum())} open patches wound half one way and half the other "
                             "(equal areas), so their outward side is not defined; fix the winding of those "
                             "faces in a mesh editor and reload")
        turn |= comp_open & (a_flip > a_keep)              # open patches: the majority as given
    flip ^= turn[comp]
    fixed = np.where(flip[:, None], f[live][:, ::-1], f[live])
    volume = float(_signed_volumes(p, fixed, np.zeros(k, dtype=np.int64), 1)[0])
    if volume < -VOLUME_TOL * scale**3:
        if n_open:
            raise ValueError(f"{name} is inverted: its enclosed volume is {volume:.6g} m^3 < 0 and it is open "
                             f"({n_open} edges on one face only), so which side is outward is not clear; reverse "
                             "the vertex order of every face (e.g. trimesh's mesh.invert() or swap two indices "
                             "per face) and reload")
        flip = ~flip
        volume = -volume
    inverted = bool(np.all(flip))
    out = np.array(f, copy=True)
    out[live] = np.where(flip[:, None], f[live][:, ::-1], f[live])
    return Orientation(out, n_open, n_nonmanifold, n_flipped, 0 if inverted else int(flip.sum()), inverted,
                       volume)


# --- elements at a size --------------------------------------------------------------------------------
def _pieces(t: np.ndarray, area: np.ndarray, size: float):
    """Cut triangles ``t`` (m, 3, 3) (areas (m,), m^2) into flat pieces at most ``size`` m across.

    A well-shaped triangle is cut into ``k^2`` congruent triangles, ``k = ceil(longest edge / size)`` (a
    cut that does not depend on the order of its vertices: mirror images give mirror pieces). A thin one
    (where that would give more than twice the pieces of the strips below) is parametrized from its tip
    ``T`` (the vertex opposite its shortest edge ``PQ``) as ``x(s, w) = T + s ((P - T) + w (Q - P))`` on
    ``[0, 1]^2``, area density ``2 A s``, and cut along an ``m x n`` grid, ``m = ceil(max(|TP|, |TQ|) /
    size)``, ``n = ceil(|PQ| / size)``: strips across its long direction. Piece areas and centroids are
    exact (strips: area ``A (s1^2 - s0^2) (w1 - w0)``, centroid at ``s = (2/3)(s1^3 - s0^3) / (s1^2 - s0^2)``,
    ``w = (w0 + w1) / 2``).

    Returns:
        centroids (N, 3) m, areas (N,) m^2, triangle index (N,) int.
    """
    opposite = np.stack([np.linalg.norm(t[:, 1] - t[:, 2], axis=1), np.linalg.norm(t[:, 2] - t[:, 0], axis=1),
                         np.linalg.norm(t[:, 0] - t[:, 1], axis=1)], axis=1)
    tip = np.argmin(opposite, axis=1)
    r = np.arange(t.shape[0])
    T, P, Q = t[r, tip], t[r, (tip + 1) % 3], t[r, (tip + 2) % 3]
    long = np.maximum(np.linalg.norm(P - T, axis=1), np.linalg.norm(Q - T, axis=1))
    m = np.maximum(np.ceil(long / size - tol.ROUND_RTOL), 1).astype(np.int64)
    n = np.maximum(np.ceil(opposite[r, tip] / size - tol.ROUND_RTOL), 1).astype(np.int64)
    k = np.maximum(np.ceil(opposite.max(axis=1) / size - tol.ROUND_RTOL), 1).astype(np.int64)
    thin = k * k > 2 * m * n
    parts = []
    for kk in np.unique(k[~thin]):                       # congruent sub-triangles, one pass per k
        sel = np.flatnonzero(~thin & (k == kk))
        uw = _subdivision_centroids(int(kk))
        e1, e2 = t[sel, 1] - t[sel, 0], t[sel, 2] - t[sel, 0]
        c = t[sel, None, 0] + uw[None, :, 0, None] * e1[:, None] + uw[None, :, 1, None] * e2[:, None]
        parts.append((c.reshape(-1, 3), np.repeat(area[sel] / uw.shape[0], uw.shape[0]),
                      np.repeat(sel, uw.shape[0])))
    sel = np.flatnonzero(thin)
    per = (m * n)[sel]
    tri = np.repeat(sel, per)
    local = np.arange(tri.size) - np.repeat(np.cumsum(per) - per, per)
    i, j = local // n[tri], local % n[tri]
    s0, s1 = i / m[tri], (i + 1) / m[tri]
    w0, w1 = j / n[tri], (j + 1) / n[tri]
    d2 = s1**2 - s0**2
    s = (2.0 / 3.0) * (s1**3 - s0**3) / d2
    w = 0.5 * (w0 + w1)
    c = T[tri] + s[:, None] * ((P - T)[tri] + w[:, None] * (Q - P)[tri])
    parts.append((c, area[tri] * d2 * (w1 - w0), tri))
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]))


def _subdivision_centroids(k: int) -> np.ndarray:
    """(k^2, 2) barycentric (u, w) of the centroids of the k^2 congruent sub-triangles of a triangle
    (point = v0 + u (v1 - v0) + w (v2 - v0))."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    i, j = i.ravel(), j.ravel()
    up = i + j <= k - 1
    down = i + j <= k - 2
    return np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], axis=1),
                           np.stack([i[down] + 2 / 3, j[down] + 2 / 3], axis=1)]) / k


def _normal_bins(n: np.ndarray, per_face: int) -> np.ndarray:
    """(N,) int cube-map bin of unit normals ``n`` (N, 3): the dominant axis and its sign, and with
    ``per_face > 1`` a ``per_face x per_face`` grid over the other two components (over the dominant one)."""
    axis = np.argmax(np.abs(n), axis=1)
    r = np.arange(n.shape[0])
    dom = n[r, axis]
    key = 2 * axis + (dom < 0)
    if per_face > 1:
        u = n[r, (axis + 1) % 3] / np.abs(dom)
        v = n[r, (axis + 2) % 3] / np.abs(dom)
        iu = np.clip(np.floor((u + 1.0) * 0.5 * per_face), 0, per_face - 1).astype(np.int64)
        iv = np.clip(np.floor((v + 1.0) * 0.5 * per_face), 0, per_face - 1).astype(np.int64)
        key = (key * per_face + iu) * per_face + iv
    return key


def _clusters(c: np.ndarray, n: np.ndarray, a: np.ndarray, size: float) -> Elements:
    """Elements from pieces (centroids ``c`` (N, 3) m, unit normals ``n`` (N, 3), areas ``a`` (N,) m^2):
    the grid clusters of the module docstring."""
    out_c, out_n, out_a = [], [], []
    rest = np.arange(a.size)
    # cells centred on the middle of the pieces' bounding box: a mesh symmetric about its middle gets a
    # symmetric grid, and its mid-planes (where piece centroids of symmetric meshes lie) are no cell
    # boundaries, so float32 round-off of MuJoCo's vertices does not move pieces between cells there
    mid = 0.5 * (c.min(axis=0) + c.max(axis=0))
    vox = np.floor((c - mid) @ _GRID_AXES / (VOXEL_SCALE * size) + 0.5).astype(np.int64)
    vox -= vox.min(axis=0)
    span = vox.max(axis=0) + 1
    for per_face in (COARSE_NORMAL_BINS, FINE_NORMAL_BINS):
        if rest.size == 0:
            break
        last = per_face == FINE_NORMAL_BINS
        key = _normal_bins(n[rest], per_face)
        for d in range(3):                               # one int64 key per (normal bin, cell)
            key = key * span[d] + vox[rest, d]
        _, group = np.unique(key, return_inverse=True)
        group = group.reshape(-1)
        k = int(group.max()) + 1
        ga = np.bincount(group, a[rest], minlength=k)
        gn = np.stack([np.bincount(group, a[rest] * n[rest, d], minlength=k) for d in range(3)], axis=1)
        gc = np.stack([np.bincount(group, a[rest] * c[rest, d], minlength=k) for d in range(3)], axis=1)
        length = np.linalg.norm(gn, axis=1)
        done = last | (1.0 - length / ga <= SPREAD_TOL)
        out_c.append(gc[done] / ga[done, None])
        out_n.append(gn[done] / length[done, None])
        out_a.append(ga[done])
        rest = rest[~done[group]]
    return Elements(np.concatenate(out_c), np.concatenate(out_n), np.concatenate(out_a))


def mesh(vertices, faces, size=None, *, name: str = "mesh") -> Elements:
    """Elements of a triangle mesh (counter-clockwise faces seen from outside = outward normals).

    Args:
        vertices: (n, 3) float, m.
        faces: (m, 3) int, vertex indices.
        size: element size in m: elements of about ``size^2`` whatever the triangulation (the module
            docstring); ``None`` keeps one element per face.
        name: how errors and warnings name the mesh.
    Raises:
        ValueError: bad shapes or indices, no non-degenerate face, or an orientation that cannot be told
            (:func:`orientation`).
    Warns:
        SandSetupWarning: once, when the mesh is open or non-manifold or was repaired, saying what.
    """
    return _mesh(vertices, faces, size, f"mesh {name!r}")


def _mesh(vertices, faces, size, label: str, notice: str | None = None) -> Elements:
    """:func:`mesh`, with ``label`` naming the mesh in errors and ``notice`` (default ``label``) in the
    warning (the same mesh asset used by several geoms gives the same warning text, shown once)."""
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
    double_area = np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    longest = np.sqrt(np.max(np.stack([((p1 - p0) ** 2).sum(1), ((p2 - p1) ** 2).sum(1),
                                       ((p0 - p2) ** 2).sum(1)]), axis=0))
    keep = 0.5 * double_area > DEGENERATE_TOL * longest**2
    if not np.any(keep):
        raise ValueError(f"{label} has only degenerate (zero-area) faces")
    o = orientation(v, f[keep], name=label)
    notes = o.notes()
    if notes:
        warnings.warn(f"rft_mujoco: {notice or label} is used as given, approximated: " + "; ".join(notes)
                      + ". To silence "
                      "this, repair the mesh (e.g. trimesh: mesh.merge_vertices(); trimesh.repair.fix_normals(mesh); "
                      "trimesh.repair.fill_holes(mesh)) or filter SandSetupWarning", SandSetupWarning, stacklevel=3)
    t = v[o.faces]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    dbl = np.linalg.norm(cross, axis=1)
    normal = cross / dbl[:, None]
    if h is None:
        return Elements(t.mean(axis=1), normal, 0.5 * dbl)
    c, a, tri = _pieces(t, 0.5 * dbl, PIECE_FRACTION * h)
    return _clusters(c, normal[tri], a, h)


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
