"""The 3D-RFT stress law on arrays of surface elements (pure numpy, no MuJoCo).

Model (Agarwal, Goldman & Kamrin, PNAS 2023; restated in ../shared/reference/3d-rft.md): a leading
surface element (outward normal ``n``, unit velocity direction ``v``) at depth ``|z|`` below the free
surface, with area ``dA``, feels the force ``dF = alpha(n, v, g) |z| dA`` where

    alpha     = xi_n [alpha_n_gen + min(mu_surf |alpha_n_gen| / |alpha_t_gen|, 1) alpha_t_gen]
    alpha_gen = f1 n' + f2 v + f3 g,      f_i = cubic polynomials of x1 = g.v, x2 = g.n', x3 = n'.v

``n'`` is ``n`` flipped so that ``g.n' >= 0``; exactly vertical elements take the sign that makes
``n'.v >= 0``.

Conventions this module fixes (each one tested in tests/test_law.py):

* Leading edge: ``n.v >= -LEADING_TOL`` (1e-4) on unit vectors, i.e. the paper's ``n.v >= 0`` with
  elements moving parallel to their own plane (the top of a box sliding sideways) counted as leading,
  robustly under round-off and float32 mesh vertices.
* Elements at speeds below ``ZERO_SPEED`` (m/s) get exactly zero force (the direction is undefined).
* Elements at or above the free surface (depth <= 0) get exactly zero force.
* By default nothing is cleaned up: the published fit's artefacts (tensile normal stress, tangential
  stress along the motion, positive power) reach the result. :class:`Guards` turns on each clean-up.
"""

from __future__ import annotations

import dataclasses
from importlib import resources

import numpy as np

from rft_mujoco.physics.media import Media

# --- tolerances: one place -------------------------------------------------------------------------
LEADING_TOL = 1e-4
"""Unit-vector n.v above -LEADING_TOL counts as leading (the paper's n.v >= 0, robust to the ~1e-8..1e-5
tilt that float32 mesh vertices give flat faces: MuJoCo stores mesh_vert in float32)."""
VERTICAL_TOL = 1e-4
"""|g.n| at or below this (unit vectors) is a vertical element: the n'.v >= 0 tie-break (same reason)."""
ZERO_SPEED = 1e-12
"""Speeds (m/s) at or below this give zero force: the motion direction is undefined."""


def _load_coefficients() -> np.ndarray:
    text = resources.files("rft_mujoco.physics.data").joinpath("agarwal2023_table_s3.csv").read_text()
    rows = [line.split(",") for line in text.splitlines() if line and not line.startswith(("#", "k,"))]
    table = np.array([[float(c) for c in row[2:5]] for row in rows])
    if table.shape != (20, 3):
        raise RuntimeError(f"coefficient table must be 20 x 3, got {table.shape}; the data file is damaged")
    table.setflags(write=False)
    return table


COEFFICIENTS = _load_coefficients()
"""(20, 3) float: columns c1, c2, c3 of the paper's SI Table S3, rows in the order of :func:`cubic_terms`."""


@dataclasses.dataclass(frozen=True)
class Guards:
    """Optional clean-ups of the published fit's artefacts (all off = the published model).

    Attributes:
        no_tension: a tensile normal component (``alpha.n > 0``, pulling the surface outward) is set
            to zero, and with it the friction it would allow. Never reversed.
        no_forward_tangential: a tangential component pointing along the element's motion is set to
            zero.
        no_positive_power: an element stress that would do positive work on the body
            (``alpha.v > 0``) is set to zero.
    """

    no_tension: bool = False
    no_forward_tangential: bool = False
    no_positive_power: bool = False

    @classmethod
    def all(cls) -> "Guards":
        return cls(True, True, True)


PUBLISHED = Guards()
"""No clean-up: the model exactly as published."""


def _as_vectors(name: str, array, n: int | None = None) -> np.ndarray:
    out = np.asarray(array, dtype=float)
    if out.ndim != 2 or out.shape[1] != 3 or (n is not None and out.shape[0] != n):
        want = "(N, 3)" if n is None else f"({n}, 3)"
        raise ValueError(f"{name} must have shape {want}, got {out.shape}")
    if not np.all(np.isfinite(out)):
        bad = np.flatnonzero(~np.all(np.isfinite(out), axis=1))
        raise ValueError(f"{name} has non-finite values at rows {bad[:10].tolist()}"
                         f"{' ...' if bad.size > 10 else ''}; check the inputs (NaN positions or "
                         "velocities usually come from an unstable simulation)")
    return out


def gravity_direction(gravity) -> tuple[np.ndarray, float]:
    """Unit gravity direction (3,) and magnitude in m/s^2 of a gravity vector."""
    g = np.asarray(gravity, dtype=float).reshape(-1)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ValueError(f"gravity must be a finite 3-vector in m/s^2, got {gravity!r}")
    mag = float(np.linalg.norm(g))
    if mag == 0.0:
        raise ValueError("gravity must be non-zero: 3D-RFT stresses are hydrostatic (they scale with "
                         "rho_c |g| depth); set model.opt.gravity or pass gravity=(0, 0, -9.81)")
    return g / mag, mag


def cubic_terms(x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> np.ndarray:
    """The 20 monomials of Table S3, shape (N, 20), in the table's order."""
    return np.stack([
        np.ones_like(x1), x1, x2, x3, x1 * x1, x2 * x2, x3 * x3, x1 * x2, x2 * x3, x3 * x1,
        x1**3, x2**3, x3**3, x1 * x2 * x2, x2 * x1 * x1, x2 * x3 * x3, x3 * x2 * x2, x3 * x1 * x1,
        x1 * x3 * x3, x1 * x2 * x3], axis=-1)


def alpha_gen(normals: np.ndarray, directions: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
    """The universal (media-independent) stress per depth ``f1 n' + f2 v + f3 g``.

    Args:
        normals: (N, 3) float, unit outward normals.
        directions: (N, 3) float, unit velocity directions.
        g_hat: (3,) float, unit gravity direction.
    Returns:
        (N, 3) float, dimensionless (multiply by xi_n and depth for a stress).
    """
    gn = normals @ g_hat
    vn = np.einsum("ij,ij->i", normals, directions)
    sign = np.where(np.abs(gn) > VERTICAL_TOL, np.sign(gn), np.where(vn >= -LEADING_TOL, 1.0, -1.0))
    n_prime = normals * sign[:, None]
    x1 = directions @ g_hat
    x2 = gn * sign
    x3 = vn * sign
    f = cubic_terms(x1, x2, x3) @ COEFFICIENTS
    return f[:, 0:1] * n_prime + f[:, 1:2] * directions + f[:, 2:3] * g_hat[None, :]


def stress_per_depth(normals: np.ndarray, directions: np.ndarray, media: Media, gravity=(0.0, 0.0, -9.81),
                     guards: Guards = PUBLISHED) -> np.ndarray:
    """3D-RFT stress per unit depth ``alpha`` in N/m^3 for unit normals and unit motion directions.

    No leading-edge or depth test here: see :func:`element_forces`.

    Args:
        normals: (N, 3) float, unit outward normals (world frame).
        directions: (N, 3) float, unit velocity directions (world frame).
        media: the granular medium.
        gravity: (3,) gravity vector in m/s^2.
        guards: which artefacts of the fit to clean up.
    Returns:
        (N, 3) float, N/m^3.
    """
    g_hat, g_mag = gravity_direction(gravity)
    a = alpha_gen(normals, directions, g_hat)
    a_n_mag = np.einsum("ij,ij->i", a, normals)          # signed; > 0 is tensile (outward)
    a_t = a - a_n_mag[:, None] * normals
    if guards.no_tension:
        a_n_mag = np.minimum(a_n_mag, 0.0)
    a_t_mag = np.linalg.norm(a_t, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.where(a_t_mag > 0.0, np.minimum(media.mu_surf * np.abs(a_n_mag) / a_t_mag, 1.0), 0.0)
    a_t = a_t * cap[:, None]
    if guards.no_forward_tangential:
        forward = np.einsum("ij,ij->i", a_t, directions) > 0.0
        a_t[forward] = 0.0
    alpha = a_n_mag[:, None] * normals + a_t
    if guards.no_positive_power:
        alpha[np.einsum("ij,ij->i", alpha, directions) > 0.0] = 0.0
    return media.xi_n_at(g_mag) * alpha


def element_forces(centroids, normals, areas, velocities, media: Media, surface_height: float = 0.0,
                   gravity=(0.0, 0.0, -9.81), *, guards: Guards = PUBLISHED) -> np.ndarray:
    """3D-RFT force on each surface element, in newtons (world frame): the numpy reference.

    ``rft_mujoco.element_forces`` (:func:`rft_mujoco.forces.element_forces`) takes the same arguments and
    runs the compiled kernel by default; this function is what it is tested against (and its
    ``backend="numpy"``).

    Args:
        centroids: (N, 3) float, element centroids in m, world frame.
        normals: (N, 3) float, outward normals, world frame; any positive length (normalized here).
        areas: (N,) float, element areas in m^2 (>= 0).
        velocities: (N, 3) float, element velocities in m/s, world frame (only the direction matters).
        media: the granular medium (:class:`rft_mujoco.Media`).
        surface_height: height of the flat free surface in m, measured against gravity (along -g).
        gravity: (3,) gravity vector in m/s^2; depth is measured along it.
        guards: artefact clean-ups (default: none, the published model).
    Returns:
        (N, 3) float forces in N. Zero for elements above the surface, trailing (n.v < 0), or at rest.
    Raises:
        ValueError: on wrong shapes, non-finite input, negative areas or zero normals.
    """
    centroids = _as_vectors("centroids", centroids)
    n = centroids.shape[0]
    normals = _as_vectors("normals", normals, n)
    velocities = _as_vectors("velocities", velocities, n)
    areas = np.asarray(areas, dtype=float).reshape(-1)
    if areas.shape != (n,):
        raise ValueError(f"areas must have shape ({n},), got {np.shape(areas)}")
    if not np.all(np.isfinite(areas)) or np.any(areas < 0):
        raise ValueError("areas must be finite and >= 0 m^2; got min "
                         f"{np.nanmin(areas) if n else 'n/a'} and {np.count_nonzero(~np.isfinite(areas))} "
                         "non-finite values")
    if not np.isfinite(surface_height):
        raise ValueError(f"surface_height must be finite (m), got {surface_height!r}")
    g_hat, _ = gravity_direction(gravity)
    n_len = np.linalg.norm(normals, axis=1)
    if np.any(n_len == 0):
        raise ValueError(f"normals must be non-zero; zero normals at rows {np.flatnonzero(n_len == 0)[:10].tolist()}")
    depth = surface_height + centroids @ g_hat             # along gravity, > 0 below the surface
    speed = np.linalg.norm(velocities, axis=1)
    out = np.zeros((n, 3))
    moving = (speed > ZERO_SPEED) & (depth > 0.0) & (areas > 0.0)
    unit_n = normals[moving] / n_len[moving, None]
    unit_v = velocities[moving] / speed[moving, None]
    leading = np.einsum("ij,ij->i", unit_n, unit_v) >= -LEADING_TOL
    idx = np.flatnonzero(moving)[leading]
    alpha = stress_per_depth(unit_n[leading], unit_v[leading], media, gravity, guards)
    out[idx] = alpha * (depth[idx] * areas[idx])[:, None]
    return out
