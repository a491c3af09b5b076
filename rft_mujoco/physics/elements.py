"""Surface elements of rigid bodies in motion -> per-body 3D-RFT wrenches (pure numpy, no MuJoCo).

The readable reference of the coupling's element pass; the compiled one
(:func:`rft_mujoco.compiled.elements.wrenches`) must agree with it (tests/test_compiled_element_pass.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rft_mujoco.physics import law
from rft_mujoco.physics.law import Guards
from rft_mujoco.physics.media import Media


FD_STEP = 1e-7
"""The law's derivative in :func:`body_wrench_jacobians`: forward differences over this fraction of an element's
speed (or of the regularization speed, whichever is larger). Newton's method only needs the derivative to a
few digits; the wrench itself is exact."""

LEADING_RAMP = 0.005
"""The leading edge of the implicit solve's regularized law (:func:`body_wrench_jacobians`), on ``c = n . v/|v|``:
an element just past the published leading edge (``-LEADING_RAMP <= c < -LEADING_TOL``, up to 0.3 degrees behind
its tangent plane) carries the stress of its direction projected onto that plane, times a weight that falls
linearly from 1 at ``c = -LEADING_TOL`` to 0 at ``c = -LEADING_RAMP``. The published law jumps where an element
enters or leaves the leading set, and on a finite surface the jumps made Newton's iterates cycle (docs/rest.md,
"Moving robots"). Elements the law loads (``c >= -LEADING_TOL``) carry the published stress; the ramp only adds
force behind the edge: within 1% of the published force in steady flow except where a flat face is within the
ramp of its tangent plane, where the published law itself jumps by that face's tangential force
(tests/test_implicit.py::test_steady_flow_gets_the_published_force)."""


class BodySurface(NamedTuple):
    """The surface elements of ``B`` rigid bodies, in their body frames (what :func:`body_wrenches` and
    :func:`body_wrench_jacobians` press into the sand).

    Attributes:
        local_centroids: (E, 3) float, m, body frame.
        local_normals: (E, 3) float, unit, body frame.
        areas: (E,) float, m^2.
        elem_body: (E,) int, the row of each element's body in the body arrays (:class:`BodyPose`, the twists).
        n_bodies: B, the number of rows of the body arrays.
    """

    local_centroids: np.ndarray
    local_normals: np.ndarray
    areas: np.ndarray
    elem_body: np.ndarray
    n_bodies: int


class BodyPose(NamedTuple):
    """The world poses of ``B`` rigid bodies (rows of MuJoCo's ``xpos``, ``xmat``, ``xipos``).

    Attributes:
        pos: (B, 3) float, body frame origins in world, m.
        mat: (B, 3, 3) float, body orientations (body to world).
        com: (B, 3) float, body centres of mass in world, m.
    """

    pos: np.ndarray
    mat: np.ndarray
    com: np.ndarray


def element_states(local_centroids, local_normals, elem_body, body_pos, body_mat, body_com, v_com, omega):
    """World positions, unit normals and velocities of elements attached to rigid bodies.

    Args:
        local_centroids: (E, 3) float, m, body frame.
        local_normals: (E, 3) float, unit, body frame.
        elem_body: (E,) int, row of each element in the body arrays below.
        body_pos: (B, 3) float, body frame origins in world (MuJoCo ``xpos``), m.
        body_mat: (B, 3, 3) float, body orientations (``xmat``).
        body_com: (B, 3) float, body centres of mass in world (``xipos``), m.
        v_com: (B, 3) float, linear velocity of each centre of mass, m/s, world frame.
        omega: (B, 3) float, angular velocity, rad/s, world frame.
    Returns:
        positions (E, 3) m, normals (E, 3), lever arms from the COM (E, 3) m, velocities (E, 3) m/s.
    """
    rot = body_mat[elem_body]
    pos = body_pos[elem_body] + np.einsum("eij,ej->ei", rot, local_centroids)
    nrm = np.einsum("eij,ej->ei", rot, local_normals)
    arm = pos - body_com[elem_body]
    vel = v_com[elem_body] + np.cross(omega[elem_body], arm)
    return pos, nrm, arm, vel


def loaded_elements(depth, normals, velocities, active=None, lead=law.LEADING_TOL):
    """The elements that carry stress: submerged (``depth`` (E,) m > 0), ``active`` (E,) bool or None, moving
    (speed above :data:`rft_mujoco.physics.law.ZERO_SPEED`) and leading (``n . v >= -lead |v|``: the published
    edge; the implicit solve's law passes :data:`LEADING_RAMP`). Returns their indices (n,) and speeds (n,) m/s."""
    live = depth > 0.0 if active is None else (depth > 0.0) & active
    sub = np.flatnonzero(live)
    speed = np.linalg.norm(velocities[sub], axis=1)
    moving = speed > law.ZERO_SPEED
    sub, speed = sub[moving], speed[moving]
    leading = np.einsum("ij,ij->i", normals[sub], velocities[sub] / speed[:, None]) >= -lead
    return sub[leading], speed[leading]


def ramped_directions(normals: np.ndarray, v_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The directions at which the implicit solve's law takes each element's stress, and the weights it carries
    (:data:`LEADING_RAMP`). ``normals``, ``v_hat``: (n, 3) unit. Returns (n, 3) unit directions (``v_hat`` itself
    on the leading side, ``c >= -LEADING_TOL``; behind it, ``v_hat`` projected onto the element's tangent plane)
    and (n,) weights in [0, 1] (1 on the leading side)."""
    c = np.einsum("ij,ij->i", normals, v_hat)
    behind = np.where(c < -law.LEADING_TOL, c, 0.0)
    u = (v_hat - behind[:, None] * normals) / np.sqrt(1.0 - behind * behind)[:, None]   # unit: n.v_hat = behind
    return u, np.minimum(1.0, (c + LEADING_RAMP) / (LEADING_RAMP - law.LEADING_TOL))


def body_wrenches(surface: BodySurface, pose: BodyPose, v_com, omega, terrain, g_hat, gravity, media: Media,
                  guards: Guards, active=None):
    """3D-RFT wrench about each body's centre of mass.

    Args:
        surface: the bodies' elements (:class:`BodySurface`, E elements on B bodies).
        pose: the bodies' poses (:class:`BodyPose`).
        v_com: (B, 3) float, linear velocity of each centre of mass, m/s, world frame.
        omega: (B, 3) float, angular velocity, rad/s, world frame.
        terrain: object with ``depth(points (n, 3), g_hat) -> (n,)`` in m.
        g_hat: (3,) unit gravity direction; gravity: (3,) m/s^2.
        active: (E,) bool, the elements that can feel sand (False: inside another body's geom), or None.
    Returns:
        wrench (B, 6) [force N, torque N m about the body's COM], submerged leading element count (B,) int,
        maximum depth (B,) m of the loaded elements (0 if none).
    """
    local_centroids, local_normals, areas, elem_body, n_bodies = surface
    pos, nrm, arm, vel = element_states(local_centroids, local_normals, elem_body, *pose, v_com, omega)
    depth = terrain.depth(pos, g_hat)
    wrench = np.zeros((n_bodies, 6))
    count = np.zeros(n_bodies, dtype=np.int64)
    max_depth = np.zeros(n_bodies)
    sub, speed = loaded_elements(depth, nrm, vel, active)
    v_hat = vel[sub] / speed[:, None]
    if sub.size == 0:
        return wrench, count, max_depth
    f = law.stress_per_depth(nrm[sub], v_hat, media, gravity, guards) * (depth[sub] * areas[sub])[:, None]
    b = elem_body[sub]
    tau = np.cross(arm[sub], f)
    for k in range(3):
        wrench[:, k] = np.bincount(b, weights=f[:, k], minlength=n_bodies)
        wrench[:, 3 + k] = np.bincount(b, weights=tau[:, k], minlength=n_bodies)
    count[:] = np.bincount(b, minlength=n_bodies)
    np.maximum.at(max_depth, b, depth[sub])
    return wrench, count, max_depth


def body_wrench_jacobians(surface: BodySurface, pose: BodyPose, v_com, omega, terrain, g_hat, gravity, media: Media,
                          guards: Guards, speed_scale: float, active=None):
    """The regularized 3D-RFT wrench about each body's COM and its derivative in the body's twist.

    The implicit sand solve (:func:`rft_mujoco.physics.implicit.implicit_wrenches`) evaluates the law at the
    motion a step ends with, by Newton's method; it needs the law as a continuous function of the twist. Each
    element's stress is the published one at its direction times ``phi(|v|) = |v| / sqrt(|v|^2 + c^2)``,
    ``c = speed_scale``: the published force above ``10 c`` to within 0.5%, zero at rest; its leading edge is a
    ramp (:data:`LEADING_RAMP`, :func:`ramped_directions`), so that the wrench is continuous in the twist.

    Args:
        (as :func:`body_wrenches`), speed_scale: ``c`` in m/s (> 0).
    Returns:
        wrench (B, 6) [N, N m about each COM], jacobian (B, 6, 6) d wrench / d (v_com, omega) in
        (N s/m, N s, N m s/m, N m s), submerged leading element count (B,) int, maximum depth (B,) m. The
        derivative holds the leading set fixed and differentiates the law's direction dependence by forward
        differences (a step of :data:`FD_STEP` times the element's speed or ``c``, whichever is larger).
    """
    local_centroids, local_normals, areas, elem_body, n_bodies = surface
    pos, nrm, arm, vel = element_states(local_centroids, local_normals, elem_body, *pose, v_com, omega)
    depth = terrain.depth(pos, g_hat)
    wrench = np.zeros((n_bodies, 6))
    jac = np.zeros((n_bodies, 6, 6))
    count = np.zeros(n_bodies, dtype=np.int64)
    max_depth = np.zeros(n_bodies)
    sub, speed = loaded_elements(depth, nrm, vel, active, LEADING_RAMP)
    if sub.size == 0:
        return wrench, jac, count, max_depth
    n, v, scale = nrm[sub], vel[sub], (depth[sub] * areas[sub])

    # the law at v and at v + h e_k (k = x, y, z), in one call
    h = FD_STEP * np.maximum(speed, speed_scale)
    e = sub.size
    vv = np.repeat(v[None], 4, axis=0)
    for k in range(3):
        vv[1 + k, :, k] += h
    vv = vv.reshape(-1, 3)
    s = np.linalg.norm(vv, axis=1)
    phi = s / np.sqrt(s * s + speed_scale * speed_scale)
    nn = np.tile(n, (4, 1))
    u, weight = ramped_directions(nn, vv / s[:, None])
    forces = (law.stress_per_depth(nn, u, media, gravity, guards)
              * (np.tile(scale, 4) * phi * weight)[:, None]).reshape(4, e, 3)
    f = forces[0]
    dfdv = np.empty((e, 3, 3))
    for k in range(3):
        dfdv[:, :, k] = (forces[1 + k] - f) / h[:, None]
    b = elem_body[sub]
    r = arm[sub]
    cross = np.zeros((sub.size, 3, 3))                   # [r]x, so that [r]x a = r x a
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    # element velocity v = v_com - [r]x omega; element wrench about the COM: (f, [r]x f)
    dv = np.concatenate([np.broadcast_to(np.eye(3), (sub.size, 3, 3)), -cross], axis=2)      # (E, 3, 6)
    lever = np.concatenate([np.broadcast_to(np.eye(3), (sub.size, 3, 3)), cross], axis=1)    # (E, 6, 3)
    je = np.matmul(np.matmul(lever, dfdv), dv)
    tau = np.cross(r, f)
    for k in range(3):
        wrench[:, k] = np.bincount(b, weights=f[:, k], minlength=n_bodies)
        wrench[:, 3 + k] = np.bincount(b, weights=tau[:, k], minlength=n_bodies)
    flat = (b[:, None] * 36 + np.arange(36)[None, :]).reshape(-1)
    jac[:] = np.bincount(flat, weights=je.reshape(-1), minlength=36 * n_bodies).reshape(n_bodies, 6, 6)
    count[:] = np.bincount(b, minlength=n_bodies)
    np.maximum.at(max_depth, b, depth[sub])
    return wrench, jac, count, max_depth
