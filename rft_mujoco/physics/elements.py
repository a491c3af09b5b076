"""Per-evaluation element kernel: body poses and velocities -> per-body sand wrenches (pure numpy).

This is the readable reference of the coupling's element pass; the compiled one
(:func:`rft_mujoco.compiled.elements.wrenches`) must agree with it (tests/test_fastkernel.py).
"""

from __future__ import annotations

import numpy as np

from rft_mujoco.physics import law
from rft_mujoco.physics.law import Guards
from rft_mujoco.physics.media import Media

GROUPS_PER_BODY = 8
"""Each body's elements are split into the 8 octants of its body frame (about its bounding-box centre) and
their wrenches summed per octant (the compiled kernel's clusters are sorted by octant)."""


def octants(local_centroids: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Octant index 0..7 of each (E, 3) body-frame centroid relative to ``center`` (3,)."""
    rel = local_centroids - center
    return ((rel[:, 0] > 0).astype(np.int64) + 2 * (rel[:, 1] > 0) + 4 * (rel[:, 2] > 0))


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


def body_wrenches(local_centroids, local_normals, areas, elem_body, n_bodies, body_pos, body_mat, body_com,
                  v_com, omega, terrain, g_hat, gravity, media: Media, guards: Guards,
                  a_com=None, alpha=None, dt=0.0, elem_octant=None):
    """3D-RFT wrench about each body's centre of mass, split by body-frame octant.

    The motion direction of each element is its velocity ``v``; when ``dt > 0`` and free accelerations
    are given, the direction is ``v + w a dt`` with ``w = (|a| dt)^2 / (|v|^2 + (|a| dt)^2)``: at
    speeds well above ``|a| dt`` this is ``v`` (published direction, relative change ~ (|a| dt / |v|)^3),
    and at rest it is the direction the element would move in this step without sand.

    Args:
        (element and body arrays as in :func:`element_states`), areas (E,) m^2, n_bodies B.
        terrain: object with ``depth(points (n, 3), g_hat) -> (n,)`` in m.
        g_hat: (3,) unit gravity direction; gravity: (3,) m/s^2.
        a_com, alpha: (B, 3) free linear (m/s^2) and angular (rad/s^2) accelerations, or None.
        dt: the step in s used for the predicted direction (0 disables it).
        elem_octant: (E,) int in 0..7 (see :func:`octants`), or None (all in octant 0).
    Returns:
        wrench (B, 8, 6) [force N, torque N m about the body's COM] per octant (sum over axis 1 for the
        body), submerged leading element count (B,) int, maximum depth (B,) m (0 if none submerged).
    """
    pos, nrm, arm, vel = element_states(local_centroids, local_normals, elem_body, body_pos, body_mat,
                                        body_com, v_com, omega)
    depth = terrain.depth(pos, g_hat)
    wrench = np.zeros((n_bodies * GROUPS_PER_BODY, 6))
    count = np.zeros(n_bodies, dtype=np.int64)
    max_depth = np.zeros(n_bodies)
    sub = np.flatnonzero(depth > 0.0)
    if sub.size == 0:
        return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth
    v = vel[sub]
    if dt > 0.0 and a_com is not None:
        b = elem_body[sub]
        acc = a_com[b] + np.cross(alpha[b], arm[sub])
        step = acc * dt
        s2 = np.einsum("ij,ij->i", step, step)
        v2 = np.einsum("ij,ij->i", v, v)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(s2 > 0.0, s2 / (v2 + s2), 0.0)
        v = v + w[:, None] * step
    speed = np.linalg.norm(v, axis=1)
    moving = speed > law.ZERO_SPEED
    sub, v, speed = sub[moving], v[moving], speed[moving]
    v_hat = v / speed[:, None]
    n_hat = nrm[sub]
    leading = np.einsum("ij,ij->i", n_hat, v_hat) >= -law.LEADING_TOL
    sub, v_hat, n_hat = sub[leading], v_hat[leading], n_hat[leading]
    if sub.size == 0:
        return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth
    alpha_s = law.stress_per_depth(n_hat, v_hat, media, gravity, guards)
    f = alpha_s * (depth[sub] * areas[sub])[:, None]
    b = elem_body[sub]
    grp = b * GROUPS_PER_BODY + (0 if elem_octant is None else elem_octant[sub])
    n_groups = n_bodies * GROUPS_PER_BODY
    for k in range(3):
        wrench[:, k] = np.bincount(grp, weights=f[:, k], minlength=n_groups)
    tau = np.cross(arm[sub], f)
    for k in range(3):
        wrench[:, 3 + k] = np.bincount(grp, weights=tau[:, k], minlength=n_groups)
    count[:] = np.bincount(b, minlength=n_bodies)
    np.maximum.at(max_depth, b, depth[sub])
    return wrench.reshape(n_bodies, GROUPS_PER_BODY, 6), count, max_depth
