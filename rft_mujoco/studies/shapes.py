"""Closed, outward-wound triangle meshes of the paper's validation shapes, built in numpy.

3D-RFT's validation set (Agarwal, Goldman & Kamrin, PNAS 2023) includes shapes that are not MuJoCo
primitives: half and quarter ellipsoids and right-angle prisms. This module builds them as indexed
triangle meshes ``(vertices (n, 3) float m, faces (m, 3) int)`` with counter-clockwise faces seen from
outside (outward normals), each centred on its volume centroid, and writes them as inline MJCF meshes
(:func:`mjcf_mesh`).

Conventions (all lengths in m):

* half ellipsoid: the part ``z <= 0`` of the ellipsoid ``(x/a)^2 + (y/b)^2 + (z/c)^2 <= 1`` (a dome with
  its flat face on top, normal +z, like a boat hull with its long axis along x when ``a`` is largest);
* quarter ellipsoid: the part ``z <= 0, x >= 0`` (flat faces: top, normal +z, and back, normal -x);
* right-angle prism: a right-isosceles triangle with legs ``leg`` in the xz-plane, extruded along y
  over ``length``; ``orientation="corner"`` puts the right angle at the lower-left (-x, -z) edge (legs
  along +x and +z, hypotenuse facing up and +x), ``"keel"`` puts the right-angle edge straight down
  (legs at +-45 degrees, hypotenuse the horizontal top face).

Curved surfaces are latitude-longitude grids of the ellipsoid (vertices on the surface, so the polyhedron
is inscribed and its volume slightly low: 0.2% at 5 mm facets, 0.8% at 1 cm, on the 7.5/4.5/4.5 cm
ellipsoid);
flat faces are rings of scaled copies of their boundary polygon about an interior point. The pieces are
welded (coincident vertices within :data:`WELD_TOL` merged) and degenerate triangles (the collapsed
quads at the poles) dropped.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

WELD_TOL = 1e-9
"""Vertices closer than ``WELD_TOL * (bounding-box diagonal)`` are one vertex."""
MIN_SEGMENTS = 32
"""Fewest segments around a full ellipse (a multiple of 4 is used, so the grid keeps the x/y mirrors)."""
MIN_MERIDIAN_SEGMENTS = 8
"""Fewest segments from the equator to the pole of a half or quarter ellipsoid."""
PRISM_ORIENTATIONS = ("corner", "keel")


# --- checks ----------------------------------------------------------------------------------------
def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be an (n, 3) float array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be an (m, 3) int array, got shape {f.shape} dtype {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
    return v, f


def _check_radii(radii) -> np.ndarray:
    r = np.asarray(radii, dtype=float)
    if r.shape != (3,) or not np.all(np.isfinite(r) & (r > 0)):
        raise ValueError(f"radii must be 3 positive finite semi-axes in m, got {radii!r}")
    return r


def _check_positive(value, name: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite length in m, got {value!r}")
    return v


# --- mesh properties -------------------------------------------------------------------------------
def volume(vertices, faces) -> float:
    """Signed enclosed volume in m^3 (positive for a closed mesh with outward normals)."""
    v, f = _check_mesh(vertices, faces)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->", p0, np.cross(p1, p2)) / 6.0)


def centroid(vertices, faces) -> np.ndarray:
    """(3,) volume centroid in m of a closed mesh (signed tetrahedra from the origin)."""
    v, f = _check_mesh(vertices, faces)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", p0, np.cross(p1, p2)) / 6.0
    return (vol[:, None] * (p0 + p1 + p2) / 4.0).sum(0) / vol.sum()


def area(vertices, faces) -> float:
    """Total surface area in m^2."""
    v, f = _check_mesh(vertices, faces)
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                      axis=1).sum())


def topology(faces) -> tuple[int, int]:
    """(open edges, repeated directed edges) of an indexed mesh.

    A closed, consistently wound mesh has every undirected edge in exactly two faces and every directed
    edge in exactly one, so both counts are 0.
    """
    f = np.asarray(faces)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, count = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    _, dcount = np.unique(directed, axis=0, return_counts=True)
    return int(np.count_nonzero(count != 2)), int(np.count_nonzero(dcount > 1))


# --- construction helpers --------------------------------------------------------------------------
def _grid_triangles(points: np.ndarray, wrap: bool) -> np.ndarray:
    """Triangles (T, 3, 3) of the quads of a (m, n, 3) grid of points (two per quad); ``wrap`` closes the
    second index into a loop."""
    p = np.concatenate([points, points[:, :1]], axis=1) if wrap else points
    a, b = p[:-1, :-1], p[:-1, 1:]
    c, d = p[1:, 1:], p[1:, :-1]
    return np.concatenate([np.stack([a, b, c], axis=-2).reshape(-1, 3, 3),
                           np.stack([a, c, d], axis=-2).reshape(-1, 3, 3)])


def _rings(boundary: np.ndarray, center, n_rings: int) -> np.ndarray:
    """Triangles (T, 3, 3) filling a flat, convex face: ``n_rings`` scaled copies of its closed boundary
    polygon (N, 3) about the interior point ``center`` (3,)."""
    s = np.linspace(0.0, 1.0, n_rings + 1)[:, None, None]
    center = np.asarray(center, dtype=float)
    return _grid_triangles(center + s * (boundary[None] - center), wrap=True)


def _weld(triangles: np.ndarray, interior) -> tuple[np.ndarray, np.ndarray]:
    """Indexed mesh from a triangle soup (T, 3, 3) of a CONVEX solid: vertices within WELD_TOL merged,
    degenerate triangles dropped, each face wound so its normal points away from ``interior`` (3,)."""
    pts = triangles.reshape(-1, 3)
    scale = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    pairs = cKDTree(pts).query_pairs(WELD_TOL * scale, output_type="ndarray")
    n = len(pts)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_vert, label = connected_components(graph, directed=False)
    vertices = np.zeros((n_vert, 3))
    np.add.at(vertices, label, pts)
    vertices /= np.bincount(label, minlength=n_vert)[:, None]
    faces = label.reshape(-1, 3)
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    p0, p1, p2 = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    outward = np.einsum("ij,ij->i", np.cross(p1 - p0, p2 - p0), (p0 + p1 + p2) / 3.0 - interior) > 0.0
    faces = np.where(outward[:, None], faces, faces[:, [0, 2, 1]])
    return vertices, faces.astype(np.int32)


def _ellipse_segments(radii: np.ndarray, facet: float) -> tuple[int, int]:
    """(segments around the equator, a multiple of 4; segments from equator to pole)."""
    a, b, c = radii
    h = ((a - b) / (a + b)) ** 2
    perimeter = math.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))   # Ramanujan
    n_phi = max(MIN_SEGMENTS, math.ceil(perimeter / facet - 1e-9))
    n_phi = -(-n_phi // 4) * 4
    n_theta = max(MIN_MERIDIAN_SEGMENTS, math.ceil(0.5 * math.pi * max(a, b, c) / facet - 1e-9))
    return n_phi, n_theta


def _surface(radii: np.ndarray, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(len(theta), len(phi), 3) ellipsoid points; theta from +z, phi from +x towards +y."""
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([radii[0] * np.sin(t) * np.cos(p), radii[1] * np.sin(t) * np.sin(p),
                     radii[2] * np.cos(t)], axis=-1)


def _centred(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return vertices - centroid(vertices, faces), faces


# --- shapes ----------------------------------------------------------------------------------------
def half_ellipsoid(radii, facet: float, *, centred: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The part ``z <= 0`` of the ellipsoid with semi-axes ``radii`` ((3,) m); ``facet`` m is the target
    edge length. Returns ``(vertices (n, 3) float, faces (m, 3) int32)``, centred on the volume centroid
    (``centred=False``: on the ellipsoid's centre; the analytic centroid is then ``(0, 0, -3c/8)``)."""
    r = _check_radii(radii)
    h = _check_positive(facet, "facet")
    n_phi, n_theta = _ellipse_segments(r, h)
    theta = np.linspace(0.5 * np.pi, np.pi, n_theta + 1)
    phi = np.arange(n_phi) * (2.0 * np.pi / n_phi)
    dome = _grid_triangles(_surface(r, theta, phi), wrap=True)
    top = _rings(_surface(r, theta[:1], phi)[0], np.zeros(3), n_theta)
    v, f = _weld(np.concatenate([dome, top]), interior=np.array([0.0, 0.0, -0.375 * r[2]]))
    return _centred(v, f) if centred else (v, f)


def quarter_ellipsoid(radii, facet: float, *, centred: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The part ``z <= 0, x >= 0`` of the ellipsoid with semi-axes ``radii`` ((3,) m); ``facet`` m is the
    target edge length. Returns ``(vertices, faces)`` as :func:`half_ellipsoid` (``centred=False``: the
    analytic centroid is ``(3a/8, 0, -3c/8)``)."""
    r = _check_radii(radii)
    h = _check_positive(facet, "facet")
    a, b, c = r
    n_phi, n_theta = _ellipse_segments(r, h)
    n_half = n_phi // 2
    theta = np.linspace(0.5 * np.pi, np.pi, n_theta + 1)
    phi = np.linspace(-0.5 * np.pi, 0.5 * np.pi, n_half + 1)
    n_seg = max(2, math.ceil(2.0 * b / h - 1e-9))
    y_seg = np.linspace(-b, b, n_seg + 1)[1:-1]                         # interior points of the y-segment
    dome = _grid_triangles(_surface(r, theta, phi), wrap=False)
    # Top face z = 0 (x >= 0): equator arc from (0, -b, 0) to (0, b, 0), back along x = 0.
    arc = _surface(r, theta[:1], phi)[0]
    back = np.stack([np.zeros_like(y_seg), y_seg[::-1], np.zeros_like(y_seg)], axis=1)
    top = _rings(np.concatenate([arc, back]), np.array([0.4 * a, 0.0, 0.0]), n_theta)
    # Back face x = 0 (z <= 0): meridian down at phi = +pi/2, up at phi = -pi/2, along z = 0 to the start.
    down = _surface(r, theta, np.array([0.5 * np.pi]))[:, 0]
    up = _surface(r, theta[::-1], np.array([-0.5 * np.pi]))[1:, 0]
    seg = np.stack([np.zeros_like(y_seg), y_seg, np.zeros_like(y_seg)], axis=1)
    wall = _rings(np.concatenate([down, up, seg]), np.array([0.0, 0.0, -0.4 * c]), n_theta)
    v, f = _weld(np.concatenate([dome, top, wall]), interior=np.array([0.375 * a, 0.0, -0.375 * c]))
    return _centred(v, f) if centred else (v, f)


def right_prism(leg: float, length: float, orientation: str = "corner") -> tuple[np.ndarray, np.ndarray]:
    """Right-isosceles triangular prism: legs ``leg`` m in the xz-plane, extruded ``length`` m along y,
    centred on its volume centroid. ``orientation``: ``"corner"`` (right angle at the lower -x edge,
    hypotenuse facing +x and up) or ``"keel"`` (right-angle edge pointing straight down, hypotenuse the
    flat top). Returns ``(vertices (6, 3) float, faces (8, 3) int32)``."""
    L = _check_positive(leg, "leg")
    W = _check_positive(length, "length")
    if orientation == "corner":
        tri = np.array([[0.0, 0.0], [L, 0.0], [0.0, L]])
    elif orientation == "keel":
        s = L / math.sqrt(2.0)
        tri = np.array([[0.0, 0.0], [s, s], [-s, s]])
    else:
        raise ValueError(f"orientation must be one of {PRISM_ORIENTATIONS}, got {orientation!r}")
    tri = tri - tri.mean(0)
    y = np.array([-0.5 * W, 0.5 * W])
    v = np.array([[x, yy, z] for yy in y for x, z in tri])               # 0-2 at -y, 3-5 at +y
    soup = np.array([v[[0, 1, 2]], v[[3, 4, 5]],
                     v[[0, 1, 4]], v[[0, 4, 3]], v[[1, 2, 5]], v[[1, 5, 4]], v[[2, 0, 3]], v[[2, 3, 5]]])
    return _weld(soup, interior=np.zeros(3))


# --- analytic values -------------------------------------------------------------------------------
def half_ellipsoid_volume(radii) -> float:
    """Analytic volume ``(2/3) pi a b c`` in m^3."""
    a, b, c = _check_radii(radii)
    return 2.0 / 3.0 * math.pi * a * b * c


def quarter_ellipsoid_volume(radii) -> float:
    """Analytic volume ``(1/3) pi a b c`` in m^3."""
    a, b, c = _check_radii(radii)
    return math.pi * a * b * c / 3.0


def right_prism_volume(leg: float, length: float) -> float:
    """Analytic volume ``leg^2 length / 2`` in m^3."""
    return 0.5 * _check_positive(leg, "leg") ** 2 * _check_positive(length, "length")


# --- MJCF ------------------------------------------------------------------------------------------
def mjcf_mesh(name: str, vertices, faces) -> str:
    """An inline MJCF ``<mesh>`` asset element (vertices in m, 17 significant digits)."""
    v, f = _check_mesh(vertices, faces)
    vert = " ".join(f"{x:.17g}" for x in v.ravel())
    face = " ".join(str(int(i)) for i in f.ravel())
    return f'<mesh name="{name}" vertex="{vert}" face="{face}"/>'
