"""MuJoCo geoms and meshes -> flat surface elements (centroid, outward unit normal, area), computed once.

3D-RFT sums a stress over small flat pieces of an intruder's surface. This module cuts each geom into
such pieces, in the geom frame (:func:`geom_elements`) or the body frame (:func:`body_elements`). A
body's elements that lie strictly inside another of its geoms are culled by default
(:func:`body_elements`, :func:`body_elements_with_culled`; the geometry is in :mod:`rft_mujoco.geometry.occlusion`).

Element size is a target edge length in m: a preset name from :data:`RESOLUTIONS` or a float
(:func:`element_size`). Small geoms keep a minimum tessellation (:data:`MIN_CIRCLE_SEGMENTS` around any
circle, :data:`MIN_EDGE_CELLS` along any box edge) so a 1 cm foot at a 1 cm size is still its shape.

Constructions (each tested for convergence in tests/test_surface.py):

* sphere, capsule caps: latitude-longitude cells with their exact spherical areas; the normal is the
  cell's mean normal (direction of the integral of n dA) and the centroid is the surface point with that
  normal. Total area and enclosed volume are exact for the sphere at every size.
* ellipsoid: the same grid in the (theta, phi) parametrization; areas and mean normals by Gauss-Legendre
  quadrature of ``x_theta x x_phi``, centroid at the surface point with the mean normal.
* box, cylinder: flat grid cells (cylinder sides: true normal at the mid angle; caps: polar annular
  sectors with their exact area centroids). Areas and volumes exact at every size.
* mesh (:mod:`rft_mujoco.geometry.meshes`): elements of about ``size^2`` whatever the triangulation
  (triangles cut into small pieces, gathered on a grid of about the element size, split by normal
  direction); degenerate triangles are dropped; winding repaired where it is unambiguous, open and
  non-manifold meshes accepted with a SandSetupWarning; :func:`load_mesh` reads mesh files through trimesh.
"""

from __future__ import annotations

import math
import types
import warnings

import mujoco
import numpy as np

from rft_mujoco import tol

from rft_mujoco.geometry import occlusion
from rft_mujoco.geometry.elements import NORMAL_TOL, ROTATION_TOL, Elements, _check_length, _check_lengths
from rft_mujoco.geometry.meshes import DEGENERATE_TOL, MERGE_TOL, VOLUME_TOL, _mesh, load_mesh, mesh

__all__ = ["Elements", "RESOLUTIONS", "element_size", "sphere", "ellipsoid", "box", "cylinder", "capsule", "mesh",
           "load_mesh", "geom_elements", "body_elements", "body_elements_with_culled", "NORMAL_TOL", "ROTATION_TOL",
           "DEGENERATE_TOL", "VOLUME_TOL", "MERGE_TOL"]

# --- presets and tolerances: one place -------------------------------------------------------------
RESOLUTIONS = types.MappingProxyType({
    "coarse": 0.02,
    "default": 0.01,
    "fine": 0.005,
    "reference": 0.002,
})
"""Named element sizes (target edge length, m). Read-only mapping: pass a float for anything else.

Flat faces are exact at every size (depth is linear over a flat face, so the centroid rule integrates it
exactly); curved ones converge with the angular resolution, which :data:`MIN_CIRCLE_SEGMENTS` keeps up
for small geoms. The error and cost of each preset on the paper's validation shapes and a quadruped foot
are measured by ``python -m rft_mujoco bench`` (section 4) and recorded in docs/performance.md; "default"
is the largest size within the 2% force-error target on all of them, with a margin.
"""

MIN_CIRCLE_SEGMENTS = 20
"""Fewest segments around any circle (sphere/ellipsoid longitudes, cylinder and cap rings; spheres and
ellipsoids get at least half as many latitude bands). It sets the accuracy of small curved geoms, whose
size, not the element size, limits the tessellation: with 12 a 2 cm sphere (a quadruped foot) 3 cm deep
had up to 8% force error at every preset from 15 mm up and 2.5% at 10 mm; with 20 (and latitude bands
in multiples of 4) it has at most 0.9% (240 elements), measured over 13 motion directions against 0.5 mm
elements (``python -m rft_mujoco bench``, section 4)."""
MIN_EDGE_CELLS = 2
"""Fewest cells along any box edge and along a cylinder's or capsule's straight side."""
LATITUDE_BANDS_MULTIPLE = 4
"""Sphere and ellipsoid latitude bands come in multiples of 4, so the equator and the +-45 degree
latitudes are band edges. With an odd number one band straddles the equator and its single mean normal
misplaces the leading-edge boundary of near-horizontal motions: measured up to 6.5% force error on a
2 cm sphere at 10 mm elements (7 bands) against 1.1% with 8; with multiples of 2 the error still jumped
with the size (1.5% at 10 mm, 1.9% at 5 mm), with multiples of 4 it falls steadily (0.86%, 0.67%)
(``python -m rft_mujoco bench``, section 4)."""
QUADRATURE_POINTS = 4
"""Gauss-Legendre points per parameter direction per ellipsoid cell."""

_GEOM = mujoco.mjtGeom
_TERRAIN_TYPES = occlusion.TERRAIN_TYPES
_SUPPORTED = "sphere, ellipsoid, box, cylinder, capsule, mesh"


def element_size(resolution: str | float) -> float:
    """Element size in m: a preset name from :data:`RESOLUTIONS` or a positive finite float (m)."""
    if isinstance(resolution, str):
        if resolution in RESOLUTIONS:
            return float(RESOLUTIONS[resolution])
        raise ValueError(f"unknown resolution {resolution!r}; use one of {sorted(RESOLUTIONS)} "
                         f"({', '.join(f'{k}={v} m' for k, v in RESOLUTIONS.items())}) or an element size "
                         "in m (a positive float)")
    if isinstance(resolution, (bool, np.bool_)) or not isinstance(resolution, (int, float, np.number)):
        raise ValueError(f"resolution must be a preset name {sorted(RESOLUTIONS)} or an element size in m "
                         f"(a positive float), got {resolution!r}")
    v = float(resolution)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"resolution must be a positive finite element size in m, got {resolution!r}; "
                         f"or use a preset name {sorted(RESOLUTIONS)}")
    return v


def _segments(length, size: float, minimum: int, multiple: int = 1) -> np.ndarray:
    """Cells along ``length`` (m, scalar or array): ``ceil(length / size)``, at least ``minimum``, rounded
    up to a multiple of ``multiple``."""
    n = np.maximum(np.ceil(np.asarray(length, dtype=float) / size - tol.ROUND_RTOL), minimum).astype(np.int64)
    return -(-n // multiple) * multiple


# --- latitude-longitude cells (sphere, ellipsoid, capsule caps) ------------------------------------
def _latlong_cells(theta_edges: np.ndarray, ring_radius: float, size: float):
    """Cells ``[theta0, theta1] x [phi0, phi1]``: each band ``theta_edges[i:i+2]`` gets
    ``max(MIN_CIRCLE_SEGMENTS, 2 pi ring_radius sin(theta_mid) / size)`` longitudes, a multiple of 4
    (the grid is then symmetric under x, y mirrors and quarter turns about z). Returns four (n,) arrays."""
    t0, t1 = theta_edges[:-1], theta_edges[1:]
    circumference = 2.0 * np.pi * ring_radius * np.sin(0.5 * (t0 + t1))
    n_phi = _segments(circumference, size, MIN_CIRCLE_SEGMENTS, multiple=4)
    band = np.repeat(np.arange(t0.size), n_phi)
    start = np.repeat(np.cumsum(n_phi) - n_phi, n_phi)
    k = np.arange(band.size) - start                       # longitude index within its band
    dphi = 2.0 * np.pi / n_phi[band]
    return t0[band], t1[band], k * dphi, (k + 1) * dphi


def _spherical_cells(radius: float, center, t0, t1, p0, p1) -> Elements:
    """Exact spherical cells: area ``r^2 dphi (cos t0 - cos t1)``, normal = direction of the cell's
    integral of ``n dA``, centroid = surface point with that normal."""
    area = radius**2 * (p1 - p0) * (np.cos(t0) - np.cos(t1))
    s2 = 0.5 * (t1 - t0) - 0.25 * (np.sin(2 * t1) - np.sin(2 * t0))   # integral of sin^2
    sc = 0.5 * (np.sin(t1) ** 2 - np.sin(t0) ** 2)                   # integral of sin cos
    m = np.stack([s2 * (np.sin(p1) - np.sin(p0)), s2 * (np.cos(p0) - np.cos(p1)), sc * (p1 - p0)], axis=1)
    n = m / np.linalg.norm(m, axis=1, keepdims=True)
    return Elements(np.asarray(center, dtype=float) + radius * n, n, area)


def sphere(radius, size) -> Elements:
    """Sphere of ``radius`` m centred at the origin; ``size`` m is the target element edge length.

    Total area and enclosed volume are exact at every size. The number of latitude bands is even (see
    :data:`LATITUDE_BANDS_MULTIPLE`).
    """
    r, h = _check_length(radius, "radius"), _check_length(size, "size")
    n_theta = int(_segments(np.pi * r, h, MIN_CIRCLE_SEGMENTS // 2, LATITUDE_BANDS_MULTIPLE))
    cells = _latlong_cells(np.linspace(0.0, np.pi, n_theta + 1), r, h)
    return _spherical_cells(r, np.zeros(3), *cells)


def ellipsoid(radii, size) -> Elements:
    """Axis-aligned ellipsoid with semi-axes ``radii`` ((3,) float, m, like MuJoCo's geom_size) at the
    origin; ``size`` m is the target element edge length.

    Areas and mean normals come from Gauss-Legendre quadrature over each (theta, phi) cell; the
    centroid is the surface point whose normal is the cell's mean normal.
    """
    abc = _check_lengths(radii, "radii")
    h = _check_length(size, "size")
    a, b, c = abc
    n_theta = int(_segments(np.pi * abc.max(), h, MIN_CIRCLE_SEGMENTS // 2, LATITUDE_BANDS_MULTIPLE))
    t0, t1, p0, p1 = _latlong_cells(np.linspace(0.0, np.pi, n_theta + 1), max(a, b), h)
    x, w = np.polynomial.legendre.leggauss(QUADRATURE_POINTS)
    u = 0.5 * (x + 1.0)
    ww = 0.25 * np.outer(w, w).ravel()                                  # weights on [0, 1]^2
    uu, vv = np.meshgrid(u, u, indexing="ij")
    theta = t0[:, None] + (t1 - t0)[:, None] * uu.ravel()[None, :]      # (n, q^2)
    phi = p0[:, None] + (p1 - p0)[:, None] * vv.ravel()[None, :]
    jac = ((t1 - t0) * (p1 - p0))[:, None] * ww[None, :]
    st = np.sin(theta)
    # x_theta x x_phi = sin(theta) (b c sin(theta) cos(phi), a c sin(theta) sin(phi), a b cos(theta))
    cross = np.stack([b * c * st * st * np.cos(phi), a * c * st * st * np.sin(phi),
                      a * b * st * np.cos(theta)], axis=-1)             # (n, q^2, 3)
    area = np.einsum("nq,nq->n", np.linalg.norm(cross, axis=-1), jac)
    m = np.einsum("nqk,nq->nk", cross, jac)
    n = m / np.linalg.norm(m, axis=1, keepdims=True)
    d2n = n * abc**2
    centroid = d2n / np.sqrt(np.einsum("ij,ij->i", n, d2n))[:, None]
    return Elements(centroid, n, area)


# --- flat-faced primitives ---------------------------------------------------------------------------
def box(half_extents, size) -> Elements:
    """Axis-aligned box with ``half_extents`` ((3,) float, m, like MuJoCo's geom_size) at the origin;
    each face is a grid of equal rectangles, at least :data:`MIN_EDGE_CELLS` per edge."""
    he = _check_lengths(half_extents, "half_extents")
    h = _check_length(size, "size")
    counts = _segments(2.0 * he, h, MIN_EDGE_CELLS)
    parts = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        ni, nj = counts[i], counts[j]
        ci = (np.arange(ni) + 0.5) / ni * 2.0 * he[i] - he[i]
        cj = (np.arange(nj) + 0.5) / nj * 2.0 * he[j] - he[j]
        gi, gj = np.meshgrid(ci, cj, indexing="ij")
        cell_area = 4.0 * he[i] * he[j] / (ni * nj)
        for sign in (1.0, -1.0):
            c = np.zeros((gi.size, 3))
            c[:, i], c[:, j], c[:, k] = gi.ravel(), gj.ravel(), sign * he[k]
            n = np.zeros((gi.size, 3))
            n[:, k] = sign
            parts.append(Elements(c, n, np.full(gi.size, cell_area)))
    return Elements.concatenate(parts)


def _cylinder_side(radius: float, half_length: float, size: float) -> Elements:
    n_phi = int(_segments(2.0 * np.pi * radius, size, MIN_CIRCLE_SEGMENTS, multiple=4))
    n_z = int(_segments(2.0 * half_length, size, MIN_EDGE_CELLS))
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    z = (np.arange(n_z) + 0.5) / n_z * 2.0 * half_length - half_length
    pp, zz = np.meshgrid(phi, z, indexing="ij")
    n = np.stack([np.cos(pp.ravel()), np.sin(pp.ravel()), np.zeros(pp.size)], axis=1)
    c = radius * n
    c[:, 2] = zz.ravel()
    area = np.full(pp.size, radius * (2.0 * np.pi / n_phi) * (2.0 * half_length / n_z))
    return Elements(c, n, area)


def _disc(radius: float, z: float, sign: float, size: float) -> Elements:
    """Flat disc at height ``z`` with normal ``sign * e_z``: rings of annular sectors, exact areas and
    area centroids."""
    n_r = int(_segments(radius, size, MIN_EDGE_CELLS))
    r_edges = np.linspace(0.0, radius, n_r + 1)
    r0, r1 = r_edges[:-1], r_edges[1:]
    n_phi = _segments(np.pi * (r0 + r1), size, MIN_CIRCLE_SEGMENTS, multiple=4)
    ring = np.repeat(np.arange(n_r), n_phi)
    k = np.arange(ring.size) - np.repeat(np.cumsum(n_phi) - n_phi, n_phi)
    dphi = 2.0 * np.pi / n_phi[ring]
    a0, a1 = r0[ring], r1[ring]
    area = 0.5 * dphi * (a1**2 - a0**2)
    rho = (2.0 / 3.0) * (a1**3 - a0**3) / (a1**2 - a0**2) * np.sin(0.5 * dphi) / (0.5 * dphi)
    phi = (k + 0.5) * dphi
    c = np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full(ring.size, float(z))], axis=1)
    n = np.zeros((ring.size, 3))
    n[:, 2] = sign
    return Elements(c, n, area)


def cylinder(radius, half_length, size) -> Elements:
    """Cylinder of ``radius`` m along the local z axis from ``-half_length`` to ``+half_length`` m, with
    flat caps (MuJoCo's geom_size ``[radius, half_length]``)."""
    r, hl = _check_length(radius, "radius"), _check_length(half_length, "half_length")
    h = _check_length(size, "size")
    return Elements.concatenate([_cylinder_side(r, hl, h), _disc(r, hl, 1.0, h), _disc(r, -hl, -1.0, h)])


def capsule(radius, half_length, size) -> Elements:
    """Capsule: a cylinder of ``radius`` m along local z over ``[-half_length, half_length]`` m with
    hemispherical caps (MuJoCo's geom_size ``[radius, half_length]``)."""
    r, hl = _check_length(radius, "radius"), _check_length(half_length, "half_length")
    h = _check_length(size, "size")
    n_theta = int(_segments(0.5 * np.pi * r, h, MIN_CIRCLE_SEGMENTS // 4))
    top = _latlong_cells(np.linspace(0.0, 0.5 * np.pi, n_theta + 1), r, h)
    bottom = _latlong_cells(np.linspace(0.5 * np.pi, np.pi, n_theta + 1), r, h)
    return Elements.concatenate([_cylinder_side(r, hl, h), _spherical_cells(r, (0.0, 0.0, hl), *top),
                                 _spherical_cells(r, (0.0, 0.0, -hl), *bottom)])


# --- MuJoCo geoms ----------------------------------------------------------------------------------
def _geom_label(model, geom_id: int) -> str:
    name = model.geom(geom_id).name
    return f"geom {name!r} (id {geom_id})" if name else f"geom id {geom_id} (unnamed)"


def _quat_to_mat(q) -> np.ndarray:
    """(3, 3) rotation of a MuJoCo quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def geom_elements(model, geom_id: int, size: float) -> Elements:
    """Surface elements of one geom, in the GEOM frame.

    Args:
        model: the ``mujoco.MjModel``.
        geom_id: geom index, ``0 <= geom_id < model.ngeom``.
        size: target element edge length in m (see :func:`element_size`).
    Raises:
        ValueError: out-of-range id, or a geom type without a surface here (plane, hfield, sdf, ...).
    """
    g = int(geom_id)
    if not 0 <= g < model.ngeom:
        raise ValueError(f"geom_id must be in 0..{model.ngeom - 1}, got {geom_id}")
    h = _check_length(size, "size")
    t = int(model.geom_type[g])
    s = np.asarray(model.geom_size[g], dtype=float)
    if t == _GEOM.mjGEOM_SPHERE:
        return sphere(s[0], h)
    if t == _GEOM.mjGEOM_ELLIPSOID:
        return ellipsoid(s[:3], h)
    if t == _GEOM.mjGEOM_BOX:
        return box(s[:3], h)
    if t == _GEOM.mjGEOM_CYLINDER:
        return cylinder(s[0], s[1], h)
    if t == _GEOM.mjGEOM_CAPSULE:
        return capsule(s[0], s[1], h)
    if t == _GEOM.mjGEOM_MESH:
        m = int(model.geom_dataid[g])
        va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        label = repr(model.mesh(m).name) if model.mesh(m).name else f"id {m}"
        return _mesh(model.mesh_vert[va:va + vn], model.mesh_face[fa:fa + fn], h,
                     f"mesh {label} of {_geom_label(model, g)}", f"mesh {label}")
    try:
        type_name = _GEOM(t).name.removeprefix("mjGEOM_").lower()
    except ValueError:
        type_name = str(t)
    hint = " (planes and heightfields are terrain, not intruders)" if t in _TERRAIN_TYPES else ""
    raise ValueError(f"{_geom_label(model, g)} has type {type_name!r}, which has no surface elements"
                     f"{hint}; supported types: {_SUPPORTED}")


def body_elements(model, body_id: int, size: float, *, cull: bool = True) -> Elements:
    """Surface elements of the geoms of one body, in the BODY frame.

    When a body has both collidable geoms (``contype`` or ``conaffinity`` non-zero) and visual-only
    geoms, only the collidable ones are used (a visual mesh over collision primitives would otherwise
    count the same surface twice); a body with only visual geoms uses all of them
    (:func:`rft_mujoco.geometry.occlusion.surface_geoms`). Each geom's elements are placed by
    ``model.geom_pos`` / ``model.geom_quat``. Plane and hfield geoms are skipped (terrain, not
    intruders); sdf geoms are skipped with a UserWarning. A body without surface geoms gives zero
    elements.

    With ``cull`` (the default), elements of a geom whose centroid is strictly inside ANOTHER geom of
    the same body (deeper than :data:`rft_mujoco.geometry.occlusion.OCCLUSION_TOL`) are removed: no sand reaches
    them. A geom entirely inside another contributes nothing; the outermost surface is always kept
    (points on a surface are not inside it). Where the occluding geom is a non-convex mesh, the test is
    the mesh itself (winding number); the run-time test against other bodies' geoms
    (:func:`rft_mujoco.geometry.occlusion.occluded` without ``exact_mesh``) uses a mesh's convex hull, which is
    what MuJoCo collides with. A body with one geom is returned unchanged.

    Approximated: an element is kept or removed whole, by its centroid, so the exposed area converges
    with the element size: the error is at most about (element size) x (length of the curves where
    geoms' surfaces cross), and smaller in practice as the straddling elements' errors partly cancel.
    Not handled: surfaces that coincide (coplanar flush faces, two identical geoms, faces of two geoms
    pressed together) are on, not inside, each other, so both copies are kept.
    Only same-body overlaps are removed; overlaps with neighbouring bodies' geoms move with the joints
    and are not.

    Args:
        model: the ``mujoco.MjModel``.
        body_id: body index, ``0 <= body_id < model.nbody``.
        size: target element edge length in m.
        cull: remove elements inside the body's other geoms (see above); ``False`` keeps every geom's
            full surface.
    """
    kept, _ = _body_elements(model, body_id, size, cull)
    return kept


def body_elements_with_culled(model, body_id: int, size: float) -> tuple[Elements, Elements]:
    """``(kept, culled)``: :func:`body_elements` with ``cull=True`` and the elements it removed (in the
    BODY frame; ``culled.area()`` is the hidden area in m^2, zero elements when nothing is hidden).
    ``kept`` and ``culled`` together are ``body_elements(..., cull=False)`` (same elements, other order).
    """
    return _body_elements(model, body_id, size, True)


def _body_elements(model, body_id: int, size: float, cull: bool) -> tuple[Elements, Elements]:
    parts, owners, errors = [], [], []
    for g in occlusion.surface_geoms(model, body_id):
        t = int(model.geom_type[g])
        if t == _GEOM.mjGEOM_SDF:
            warnings.warn(f"{_geom_label(model, int(g))} is an sdf geom; sdf surfaces are not supported and "
                          "it feels no sand; add a mesh or primitive geom for it", UserWarning, stacklevel=3)
            continue
        try:
            el = geom_elements(model, int(g), size)
        except ValueError as exc:                # every failing geom of the body in one error
            errors.append(str(exc))
            continue
        parts.append(el.transformed(model.geom_pos[g], _quat_to_mat(model.geom_quat[g])))
        owners.append(np.full(len(el), g, dtype=np.int64))
    if errors:
        raise ValueError("; ".join(errors))
    el = Elements.concatenate(parts)
    none = Elements.concatenate([])
    if not cull or len(parts) < 2:
        return el, none
    hidden = occlusion.occluded(el.centroids, occlusion.geom_occluders(model, body_id),
                                owner=np.concatenate(owners), exact_mesh=True)
    if not hidden.any():
        return el, none
    keep = ~hidden
    return (Elements(el.centroids[keep], el.normals[keep], el.areas[keep]),
            Elements(el.centroids[hidden], el.normals[hidden], el.areas[hidden]))
