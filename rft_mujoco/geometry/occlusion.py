"""Which points lie inside a body's geoms: the occlusion test behind surface culling.

A body's surface elements (:mod:`rft_mujoco.geometry.surface`) are cut from each geom on its own, so where geoms
overlap (capsules meeting at a joint, a foot sphere inside its calf, stacked boxes) part of each geom's
surface lies inside another geom, where no sand can reach it. This module answers, for points in a
geom's or a body's frame, "is this point strictly inside that solid?":

* :func:`inside_geom`: one MuJoCo geom in its own frame (sphere, capsule, cylinder, box, ellipsoid, and a
  mesh as the convex hull given by :func:`mesh_halfspaces`). Planes and heightfields never occlude: they
  are terrain, not part of an intruder.
* :func:`surface_geoms`, :func:`geom_occluders`: the geoms of a body that carry its surface (the rule
  :func:`rft_mujoco.geometry.surface.body_elements` uses) as :class:`Occluder` solids posed in the body frame.
* :func:`occluded`: which points are inside any occluder other than the geom each point belongs to.

"Strictly inside" means deeper than a margin (default :data:`OCCLUSION_TOL`) below the occluder's
surface, so a point lying ON another geom's surface (tangent geoms, coincident faces) is not inside.

Meshes: MuJoCo collides with the convex hull of a mesh geom, so at run time (points of other bodies)
"inside a mesh geom" means inside its convex hull, which is what :func:`inside_geom` tests. The static
same-body test (``exact_mesh=True`` in :func:`occluded`) uses the mesh itself for non-convex meshes,
because the surface elements are cut from the mesh's faces, not from its hull: a point in a concavity
is outside the mesh. That test is a generalized winding number (numpy, no spatial index), cost
``O(points inside the hull x faces)``.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from rft_mujoco.geometry.elements import as_points

# --- tolerances: one place -------------------------------------------------------------------------
OCCLUSION_TOL = 1e-6
"""Default margin (m): a point is inside a geom only if it is deeper than this below its surface.

Elements lie exactly on their own geom's surface, so an element on another geom's surface (tangent
geoms, coincident faces) differs from "on it" only by round-off. 1 um is far above that round-off:
float64 body-frame coordinates of a ~1 m model carry ~1e-15 m, and MuJoCo stores mesh vertices as
float32 (relative 6e-8: 6e-9 m on a 10 cm mesh, 6e-8 m on a 1 m one). It is far below any element
size (>= 1 mm), so moving the intersection curve by 1 um changes an exposed area by ~1e-6 m x the
curve's length, negligible against the element-size error of the culling itself."""
COPLANAR_TOL = 1e-9
"""Hull halfspaces whose unit normals agree within this and whose offsets agree within this times the
hull's bounding-box diagonal are one face (coplanar triangles of the hull); duplicates are dropped."""
CONVEX_TOL = 1e-6
"""A mesh whose enclosed volume is within this fraction of its convex hull's volume is convex: its
static containment test is the hull's (exact for it), not the winding number."""
WINDING_CHUNK = 250_000
"""Point-face pairs per block of the winding-number and distance computations (memory bound)."""

_GEOM = mujoco.mjtGeom
TERRAIN_TYPES = (int(_GEOM.mjGEOM_PLANE), int(_GEOM.mjGEOM_HFIELD))
"""Geom types that are terrain, not intruders: they carry no surface elements and occlude nothing."""
_SIZE_ENTRIES = {int(_GEOM.mjGEOM_SPHERE): 1, int(_GEOM.mjGEOM_CAPSULE): 2, int(_GEOM.mjGEOM_CYLINDER): 2,
                 int(_GEOM.mjGEOM_BOX): 3, int(_GEOM.mjGEOM_ELLIPSOID): 3, int(_GEOM.mjGEOM_MESH): 0}
_OCCLUDING = "sphere, capsule, cylinder, box, ellipsoid, mesh (and plane, hfield: never inside)"


def _type_name(t: int) -> str:
    try:
        return _GEOM(t).name.removeprefix("mjGEOM_").lower()
    except ValueError:
        return str(t)


def _check_type(geom_type) -> int:
    if isinstance(geom_type, (bool, np.bool_)) or not isinstance(geom_type, (int, np.integer, _GEOM)):
        raise ValueError(f"geom_type must be a mujoco.mjtGeom (an int), got {geom_type!r}")
    t = int(geom_type)
    if t in TERRAIN_TYPES or t in _SIZE_ENTRIES:
        return t
    raise ValueError(f"geom_type {_type_name(t)!r} has no inside test (sdf and other geoms have no "
                     f"closed form here); supported: {_OCCLUDING}")


def _check_size(size, t: int) -> np.ndarray:
    s = np.asarray(size, dtype=float)
    need = _SIZE_ENTRIES[t]
    if s.ndim != 1 or not need <= s.shape[0] <= 3:
        raise ValueError(f"size of a {_type_name(t)} must be a 1-D array of {max(need, 1)} to 3 lengths "
                         f"in m (like MuJoCo's geom_size), got shape {s.shape}")
    if not np.all(np.isfinite(s[:need]) & (s[:need] > 0)):
        raise ValueError(f"size of a {_type_name(t)} needs {need} positive finite lengths in m, got "
                         f"{s.tolist()}")
    return s


def _check_margin(margin) -> float:
    try:
        m = float(margin)
    except (TypeError, ValueError):
        raise ValueError(f"margin must be a finite length >= 0 in m, got {margin!r}") from None
    if isinstance(margin, (bool, np.bool_)) or not (math.isfinite(m) and m >= 0):
        raise ValueError(f"margin must be a finite length >= 0 in m, got {margin!r}")
    return m


def _check_halfspaces(h) -> np.ndarray:
    arr = np.asarray(h, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 4 or arr.shape[0] < 4:
        raise ValueError(f"mesh_halfspaces must be a (k, 4) float array with k >= 4 rows [normal, offset] "
                         f"(from mesh_halfspaces(vertices)), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("mesh_halfspaces must be finite, got non-finite values")
    length = np.linalg.norm(arr[:, :3], axis=1)
    if np.any(np.abs(length - 1.0) > 1e-6):
        raise ValueError(f"mesh_halfspaces normals (columns 0-2) must be unit vectors, got lengths in "
                         f"[{length.min()}, {length.max()}]")
    return arr


# --- one geom, in its own frame --------------------------------------------------------------------
def inside_geom(points, geom_type, size, *, mesh_halfspaces=None, margin=OCCLUSION_TOL) -> np.ndarray:
    """Which points are strictly inside a MuJoCo geom: deeper than ``margin`` below its surface.

    Args:
        points: (n, 3) float, points in the GEOM's local frame, m.
        geom_type: a ``mujoco.mjtGeom``: sphere (radius ``size[0]``), capsule (radius ``size[0]``,
            half-length ``size[1]`` of its segment along z), cylinder (radius ``size[0]``, half-length
            ``size[1]`` along z), box (half-extents ``size[:3]``), ellipsoid (semi-axes ``size[:3]``),
            mesh (its convex hull, ``mesh_halfspaces``). Planes and heightfields are terrain and never
            contain a point (all False).
        size: (3,) float, MuJoCo's ``geom_size`` (shorter arrays holding the entries the type uses are
            accepted; a mesh ignores it).
        mesh_halfspaces: (k, 4) float, for a mesh only: rows ``[n, offset]`` with unit outward ``n``,
            ``n . x <= offset`` inside (:func:`mesh_halfspaces`).
        margin: m, >= 0; the depth a point must exceed. The default :data:`OCCLUSION_TOL` keeps points
            on the surface (up to round-off) outside; 0 is the plain open solid.
    Returns:
        (n,) bool.

    The depth test is exact for the sphere, capsule (``r - distance to the segment``), cylinder and box
    (distance to the nearest face plane) and a convex mesh (the nearest facet plane). For an ellipsoid
    it tests the ellipsoid with semi-axes shrunk by ``margin``: every point deeper than ``margin`` passes
    and no point on or outside the surface does; a point less than ``margin`` deep may pass only where
    the surface curves more tightly than ``margin`` (never at :data:`OCCLUSION_TOL` on real geoms).
    """
    p = as_points(points, "points")
    t = _check_type(geom_type)
    m = _check_margin(margin)
    if t in TERRAIN_TYPES:
        return np.zeros(p.shape[0], dtype=bool)
    s = _check_size(size, t)
    if t == _GEOM.mjGEOM_MESH:
        if mesh_halfspaces is None:
            raise ValueError("a mesh geom needs mesh_halfspaces, the (k, 4) convex hull from "
                             "mesh_halfspaces(vertices) in the geom frame")
        h = _check_halfspaces(mesh_halfspaces)
        return np.all(p @ h[:, :3].T < h[:, 3] - m, axis=1)
    if mesh_halfspaces is not None:
        raise ValueError(f"mesh_halfspaces is for mesh geoms only, got it with a {_type_name(t)}")
    if t == _GEOM.mjGEOM_SPHERE:
        return np.linalg.norm(p, axis=1) < s[0] - m
    if t == _GEOM.mjGEOM_CAPSULE:
        axial = p[:, 2] - np.clip(p[:, 2], -s[1], s[1])
        return np.sqrt(p[:, 0] ** 2 + p[:, 1] ** 2 + axial**2) < s[0] - m
    if t == _GEOM.mjGEOM_CYLINDER:
        return (np.hypot(p[:, 0], p[:, 1]) < s[0] - m) & (np.abs(p[:, 2]) < s[1] - m)
    if t == _GEOM.mjGEOM_BOX:
        return np.all(np.abs(p) < s[:3] - m, axis=1)
    # ellipsoid
    shrunk = s[:3] - m
    if np.any(shrunk <= 0):
        return np.zeros(p.shape[0], dtype=bool)
    return np.einsum("ij,ij->i", p / shrunk, p / shrunk) < 1.0


def _spatial():
    """scipy.spatial, imported on first use (only mesh geoms need it)."""
    from scipy import spatial

    return spatial


def mesh_halfspaces(vertices) -> np.ndarray:
    """The convex hull of a mesh's vertices as halfspaces.

    MuJoCo collides with the convex hull of a mesh geom, so this is what "inside a mesh geom" means at
    run time (:func:`inside_geom`).

    Args:
        vertices: (v, 3) float, m, in the frame the points will be given in (the geom frame for
            ``model.mesh_vert``), at least 4 not all on one plane.
    Returns:
        (k, 4) float, rows ``[n, offset]``: unit outward normal ``n``, ``n . x <= offset`` inside;
        coplanar hull triangles give one row (within :data:`COPLANAR_TOL`).
    """
    v = as_points(vertices, "vertices")
    if v.shape[0] < 4:
        raise ValueError(f"vertices must hold at least 4 points spanning a volume, got {v.shape[0]}")
    try:
        hull = _spatial().ConvexHull(v)
    except _spatial().QhullError:
        raise ValueError(f"vertices ({v.shape[0]} points) span no volume (all on one plane or line): a "
                         "flat mesh encloses nothing and occludes nothing") from None
    eq = hull.equations                              # n . x + d <= 0 inside, n unit
    h = np.column_stack([eq[:, :3], -eq[:, 3]])
    scale = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    key = np.round(h / (COPLANAR_TOL * np.array([1.0, 1.0, 1.0, scale]))).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return h[np.sort(first)]


def _winding_numbers(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(n,) generalized winding numbers of a triangle soup ``tris`` (f, 3, 3) at ``points`` (n, 3):
    the sum of the triangles' signed solid angles over 4 pi (Van Oosterom and Strackee's formula); 1
    inside a closed outward-wound mesh, 0 outside."""
    out = np.zeros(points.shape[0])
    step = max(1, WINDING_CHUNK // max(1, tris.shape[0]))
    for i in range(0, points.shape[0], step):
        rel = tris[None, :, :, :] - points[i:i + step, None, None, :]       # (p, f, 3, 3)
        a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
               + np.einsum("pfi,pfi->pf", c, a) * lb)
        out[i:i + step] = 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * np.pi)
    return out


def _near_triangles(points: np.ndarray, tris: np.ndarray, margin: float) -> np.ndarray:
    """(n,) bool: within ``margin`` (m) of some triangle of ``tris`` (f, 3, 3); exact distances for the
    point-triangle pairs whose bounding boxes, grown by ``margin``, overlap."""
    near = np.zeros(points.shape[0], dtype=bool)
    lo, hi = tris.min(axis=1) - margin, tris.max(axis=1) + margin
    step = max(1, WINDING_CHUNK // max(1, tris.shape[0]))
    for i in range(0, points.shape[0], step):
        p = points[i:i + step]
        ip, it = np.nonzero(np.all((p[:, None, :] >= lo) & (p[:, None, :] <= hi), axis=2))
        if ip.size:
            from trimesh import triangles as _tri            # trimesh: a declared dependency
            d = np.linalg.norm(_tri.closest_point(tris[it], p[ip]) - p[ip], axis=1)
            near[i + ip[d <= margin]] = True
    return near


# --- geoms of a body -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Occluder:
    """One geom as a solid that hides surface, posed in some frame (the body frame from
    :func:`geom_occluders`). Arrays are read-only.

    Attributes:
        geom_id: the geom's index in the model.
        geom_type: its ``mujoco.mjtGeom``.
        size: (3,) float, its ``geom_size``, m.
        pos: (3,) float, the geom frame's origin in this frame, m.
        mat: (3, 3) float, the geom frame's axes (columns) in this frame: ``x = pos + mat @ x_geom``.
        halfspaces: (k, 4) float, a mesh's convex hull in the geom frame (:func:`mesh_halfspaces`);
            ``None`` for primitives.
        triangles: (f, 3, 3) float, a NON-convex mesh's faces in the geom frame, for the exact static
            test; ``None`` for primitives and convex meshes (their hull is exact).
    """

    geom_id: int
    geom_type: int
    size: np.ndarray
    pos: np.ndarray
    mat: np.ndarray
    halfspaces: np.ndarray | None = None
    triangles: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("size", "pos", "mat", "halfspaces", "triangles"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.array(arr, dtype=float)
                arr.setflags(write=False)
                object.__setattr__(self, name, arr)

    def __repr__(self) -> str:
        return f"Occluder(geom {self.geom_id}, {_type_name(self.geom_type)}, pos={self.pos.tolist()})"

    def transformed(self, pos, mat) -> "Occluder":
        """The occluder moved rigidly into another frame: ``x' = pos + mat @ x``.

        Args:
            pos: (3,) float, m.
            mat: (3, 3) float rotation, or MuJoCo's flat (9,) ``xmat`` row.
        """
        p = np.asarray(pos, dtype=float)
        r = np.asarray(mat, dtype=float)
        r = r.reshape(3, 3) if r.shape == (9,) else r
        if p.shape != (3,) or r.shape != (3, 3):
            raise ValueError(f"pos must be (3,) and mat (3, 3) or (9,), got shapes {p.shape}, "
                             f"{np.shape(mat)}")
        return dataclasses.replace(self, pos=p + r @ self.pos, mat=r @ self.mat)

    def contains(self, points, *, margin=OCCLUSION_TOL, exact_mesh=False) -> np.ndarray:
        """(n,) bool: which ``points`` ((n, 3) float, m, in this occluder's frame) are deeper than
        ``margin`` inside it. A mesh is its convex hull unless ``exact_mesh`` is set, which tests a
        non-convex mesh itself (winding number, then no face within ``margin``)."""
        p = as_points(points, "points")
        local = (p - self.pos) @ self.mat          # rows: mat^T (x - pos)
        inside = inside_geom(local, self.geom_type, self.size, mesh_halfspaces=self.halfspaces,
                             margin=margin)
        if exact_mesh and self.triangles is not None and inside.any():
            idx = np.flatnonzero(inside)
            keep = _winding_numbers(local[idx], self.triangles) > 0.5
            idx = idx[keep]
            if margin > 0 and idx.size:
                idx = idx[~_near_triangles(local[idx], self.triangles, float(margin))]
            inside = np.zeros_like(inside)
            inside[idx] = True
        return inside


def surface_geoms(model, body_id: int) -> np.ndarray:
    """(k,) int: the geoms of a body that carry its surface, in geom order.

    Planes and heightfields are left out (terrain). When a body has both collidable geoms (``contype``
    or ``conaffinity`` non-zero) and visual-only ones, only the collidable ones count (a visual mesh
    over collision primitives would otherwise count the same surface twice); a body with only visual
    geoms uses all of them. sdf geoms are kept here; :func:`rft_mujoco.geometry.surface.body_elements` warns
    about and skips them and :func:`geom_occluders` skips them.
    """
    b = int(body_id)
    if not 0 <= b < model.nbody:
        raise ValueError(f"body_id must be in 0..{model.nbody - 1}, got {body_id}")
    geoms = np.flatnonzero(np.asarray(model.geom_bodyid) == b)
    collidable = (model.geom_contype[geoms] != 0) | (model.geom_conaffinity[geoms] != 0)
    if collidable.any() and not collidable.all():
        geoms = geoms[collidable]
    return geoms[~np.isin(model.geom_type[geoms], TERRAIN_TYPES)]


def geom_occluders(model, body_id: int) -> list[Occluder]:
    """The geoms of a body that can hide surface, as :class:`Occluder` solids in the BODY frame.

    These are exactly the geoms whose surface the body's elements come from (:func:`surface_geoms`):
    the same collidable/visual rule, because a geom that carries no sand surface should hide none
    either. A visual mesh drawn over collision primitives would otherwise hide the primitives' whole
    surface and leave the body without sand forces; a body of visual geoms only uses them as its
    surface, so they hide each other. sdf geoms (no inside test) and flat meshes (no volume) are left
    out.
    """
    out = []
    for g in surface_geoms(model, body_id):
        t = int(model.geom_type[g])
        if t not in _SIZE_ENTRIES:
            continue
        halfspaces = triangles = None
        if t == _GEOM.mjGEOM_MESH:
            m = int(model.geom_dataid[g])
            va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
            fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
            v = np.asarray(model.mesh_vert[va:va + vn], dtype=float)
            try:
                halfspaces = mesh_halfspaces(v)
            except ValueError:
                continue
            tris = v[np.asarray(model.mesh_face[fa:fa + fn])]
            volume = float(np.einsum("fi,fi->", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])) / 6.0)
            if volume < (1.0 - CONVEX_TOL) * _spatial().ConvexHull(v).volume:
                triangles = tris
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, np.asarray(model.geom_quat[g], dtype=float))
        out.append(Occluder(int(g), t, np.asarray(model.geom_size[g], dtype=float),
                            np.asarray(model.geom_pos[g], dtype=float), mat.reshape(3, 3),
                            halfspaces, triangles))
    return out


def occluded(points, occluders, *, owner=None, margin=OCCLUSION_TOL, exact_mesh=False) -> np.ndarray:
    """Which points are strictly inside an occluder other than the geom each point belongs to.

    Args:
        points: (n, 3) float, m, in the occluders' frame (the body frame for :func:`geom_occluders`;
            move other bodies' occluders in with :meth:`Occluder.transformed`).
        occluders: a sequence of :class:`Occluder`.
        owner: (n,) int, the geom id each point belongs to; that geom is not tested for it. ``None``
            or -1: test every occluder.
        margin: m, >= 0 (see :func:`inside_geom`).
        exact_mesh: test non-convex meshes by their faces (the static same-body test) instead of by
            their convex hull (what MuJoCo collides with; the run-time meaning).
    Returns:
        (n,) bool.
    """
    p = as_points(points, "points")
    if owner is None:
        own = np.full(p.shape[0], -1, dtype=np.int64)
    else:
        own = np.asarray(owner)
        if own.shape != (p.shape[0],) or not np.issubdtype(own.dtype, np.integer):
            raise ValueError(f"owner must be an (n,) int array of geom ids with n = {p.shape[0]} points, "
                             f"got shape {own.shape} and dtype {own.dtype}")
    hidden = np.zeros(p.shape[0], dtype=bool)
    for occ in occluders:
        test = np.flatnonzero((own != occ.geom_id) & ~hidden)
        if test.size:
            hidden[test] = occ.contains(p[test], margin=margin, exact_mesh=exact_mesh)
    return hidden


# --- run-time occluders: the geoms of other bodies a body's surface can get inside of --------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Occluders:
    """For each of B bodies, the geoms of OTHER weld groups whose solid its surface can get inside of (the
    run-time culling of the compiled kernels and of warp: :mod:`rft_mujoco.compiled.elements`).

    Attributes:
        start: (B + 1,) int, body b's occluders are rows ``start[b]:start[b + 1]``.
        geom: (O,) int, MuJoCo geom id (its world pose: ``geom_xpos``/``geom_xmat``).
        kind: (O,) int, ``mjtGeom`` type.
        size: (O, 3) float, ``geom_size`` (m).
        rbound: (O,) float, radius of a sphere about the geom's origin holding it (m).
        hs_start: (O + 1,) int, a mesh's convex-hull halfspaces are rows ``hs_start[o]:hs_start[o + 1]`` of
        halfspaces: (H, 4) float, ``[n, offset]`` in the geom frame, ``n . x <= offset`` inside.
        margin: m, the depth an element must exceed to count as inside (:data:`OCCLUSION_TOL`).
    """

    start: np.ndarray
    geom: np.ndarray
    kind: np.ndarray
    size: np.ndarray
    rbound: np.ndarray
    hs_start: np.ndarray
    halfspaces: np.ndarray
    margin: float = OCCLUSION_TOL

    def arrays(self) -> tuple:
        return (self.start, self.geom, self.kind, self.size, self.rbound, self.hs_start, self.halfspaces)

    @classmethod
    def none(cls, n_bodies: int) -> "Occluders":
        return cls(np.zeros(n_bodies + 1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                   np.zeros((0, 3)), np.zeros(0), np.zeros(1, np.int64), np.zeros((0, 4)))


_RUN_TIME_KINDS = tuple(int(t) for t in (_GEOM.mjGEOM_MESH, _GEOM.mjGEOM_SPHERE, _GEOM.mjGEOM_CAPSULE,
                                          _GEOM.mjGEOM_CYLINDER, _GEOM.mjGEOM_BOX, _GEOM.mjGEOM_ELLIPSOID))


def occluders(model, body_ids) -> Occluders:
    """The run-time occluders of each attached body: every surface geom (:func:`surface_geoms`, terrain
    excluded) of every body of another weld group, the world body's included (a rock), whether attached or
    not. Geoms of the same weld group are culled once, at attach. Each geom's entry (a mesh's hull
    halfspaces included) is built once and shared by every body it occludes."""
    weld = np.asarray(model.body_weldid)
    entries = []                                   # (weld group, geom, kind, size, rbound, halfspaces or None)
    for other in range(model.nbody):
        for g in surface_geoms(model, other):
            t = int(model.geom_type[g])
            if t in TERRAIN_TYPES or t not in _RUN_TIME_KINDS:
                continue
            h = None
            if t == int(_GEOM.mjGEOM_MESH):
                m = int(model.geom_dataid[g])
                va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
                h = mesh_halfspaces(np.asarray(model.mesh_vert[va:va + vn], dtype=float))
            entries.append((int(weld[other]), int(g), t, np.asarray(model.geom_size[g], dtype=float),
                            float(model.geom_rbound[g]), h))
    start, rows = [0], []
    for b in body_ids:
        mine = [e for e in entries if e[0] != weld[b]]
        rows.extend(mine)
        start.append(len(rows))
    hs = [e[5] for e in rows if e[5] is not None]
    hs_start = np.concatenate([[0], np.cumsum([0 if e[5] is None else e[5].shape[0] for e in rows])])
    return Occluders(np.asarray(start, np.int64), np.asarray([e[1] for e in rows], np.int64),
                     np.asarray([e[2] for e in rows], np.int64),
                     np.asarray([e[3] for e in rows], dtype=float).reshape(-1, 3),
                     np.asarray([e[4] for e in rows], dtype=float), hs_start.astype(np.int64),
                     np.vstack(hs) if hs else np.zeros((0, 4)))
