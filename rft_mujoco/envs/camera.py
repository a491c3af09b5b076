"""Render cameras that follow the robot, for Gymnasium MuJoCo envs.

Gymnasium 1.x renders every MujocoEnv without an explicit camera from a *free* camera
(``mjCAMERA_FREE``, reset at each frame), placed once from ``default_camera_config``; a ``trackbodyid``
in that config is ignored, so a walking robot leaves the frame. :func:`track_body` switches such an env
to MuJoCo's tracking camera (``mjCAMERA_TRACKING``: the view keeps its distance, azimuth and elevation
and follows the tracked body's subtree centre of mass).
"""

from __future__ import annotations

import mujoco

TRACKING = int(mujoco.mjtCamera.mjCAMERA_TRACKING)


def root_body(model) -> int:
    """The robot's root: the first child of the world body that has a joint (e.g. a free joint); else
    body 1 (or 0 for a model without bodies)."""
    for b in range(1, model.nbody):
        if model.body_parentid[b] == 0 and model.body_jntnum[b] > 0:
            return b
    return 1 if model.nbody > 1 else 0


def uses_free_camera(env) -> bool:
    """Whether a Gymnasium MujocoEnv (wrapped or not) renders from the free camera (``camera_id == -1``)."""
    renderer = getattr(env.unwrapped, "mujoco_renderer", None)
    return renderer is not None and renderer.camera_id == -1


def track_body(env, body: int | str | None = None) -> bool:
    """Make a Gymnasium MujocoEnv render from a camera that follows ``body``; call before the first render.

    Args:
        env: the env (wrapped or not); anything without a ``mujoco_renderer`` is left alone.
        body: body id or name; default the ``trackbodyid`` of the env's ``default_camera_config``, else
            :func:`root_body`.

    Returns:
        True when the camera was set, False when the env has no MuJoCo renderer or renders from a camera
        of its model (``camera_id``/``camera_name``), which is left as it is.
    """
    u = env.unwrapped
    renderer = getattr(u, "mujoco_renderer", None)
    if renderer is None:
        return False
    config = dict(renderer.default_cam_config or {})
    if renderer.camera_id is None and config.get("type") == TRACKING and body is None:
        return True  # already tracking
    if renderer.camera_id != -1:
        return False
    if body is None:
        body = config.get("trackbodyid", root_body(u.model))
    if isinstance(body, str):
        body = u.model.body(body).id
    if not 0 <= int(body) < u.model.nbody:
        raise ValueError(f"body must be a body id in [0, {u.model.nbody}) or a name, got {body!r}")
    config.pop("lookat", None)  # the tracked body's centre of mass sets it
    renderer.default_cam_config = {**config, "type": TRACKING, "trackbodyid": int(body)}
    renderer.camera_id = None  # the viewer then keeps the camera type it was given (None: no override)
    return True
