"""Scripted (kinematic) rollouts: drive a free body with a prescribed motion and record the sand wrench.

The body's pose is integrated from the prescribed velocity; dynamics play no part. Each sample runs
``mj_forward`` so the wrench is exactly what the coupling would apply at that state.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import SandHandle

Vec = np.ndarray | tuple[float, float, float] | Callable[[float], np.ndarray]


@dataclasses.dataclass(frozen=True)
class Rollout:
    """Time series of a scripted rollout.

    Attributes:
        time: (T,) s.
        position: (T, 3) m, body COM in world.
        force: (T, 3) N, sand force on the body, world frame.
        torque: (T, 3) N m, sand torque about the body's COM, world frame.
        max_depth: (T,) m, deepest loaded element.
        submerged: (T,) int, loaded element count.
    """

    time: np.ndarray
    position: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    max_depth: np.ndarray
    submerged: np.ndarray


def _vector(value: Vec, t: float, name: str) -> np.ndarray:
    v = np.asarray(value(t) if callable(value) else value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector (or a function of time returning one), got {v!r}")
    return v


def kinematic_rollout(handle: SandHandle, data, body: str, velocity: Vec, angular_velocity: Vec = (0, 0, 0),
                      *, duration: float, dt: float | None = None) -> Rollout:
    """Move ``body`` (which must have a free joint) at a prescribed velocity and record its sand wrench.

    Args:
        handle: the attached sand (use ``stabilize=False`` to record the published force).
        data: an MjData of ``handle.model``; its current qpos is the start pose.
        body: body name; its first joint must be a free joint.
        velocity: (3,) m/s of the body's COM in the world frame, or a function ``t -> (3,)``.
        angular_velocity: (3,) rad/s in the world frame, or a function ``t -> (3,)``.
        duration: s.
        dt: sample interval in s (default: the model's timestep).
    """
    model = handle.model
    b = model.body(body).id
    jnt = model.body_jntadr[b]
    if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"body {body!r} needs a free joint to be driven kinematically")
    if b not in handle.body_ids:
        raise ValueError(f"body {body!r} is not attached to this sand handle ({handle.body_names})")
    dt = float(model.opt.timestep if dt is None else dt)
    if not (np.isfinite(duration) and duration > 0 and dt > 0):
        raise ValueError(f"duration and dt must be > 0 s, got duration={duration!r}, dt={dt!r}")
    row = list(handle.body_ids).index(b)
    vadr = model.jnt_dofadr[jnt]
    n = int(round(duration / dt)) + 1
    out = {k: [] for k in ("time", "position", "force", "torque", "max_depth", "submerged")}
    qvel = np.zeros(model.nv)
    for i in range(n):
        t = i * dt
        v = _vector(velocity, t, "velocity")
        w = _vector(angular_velocity, t, "angular_velocity")
        data.time = t
        mujoco.mj_kinematics(model, data)
        rot = data.xmat[b].reshape(3, 3)
        # Free joint: linear velocity of the joint origin (body frame origin) in world, angular in body frame.
        arm = data.xipos[b] - data.xpos[b]
        data.qvel[:] = 0.0
        data.qvel[vadr:vadr + 3] = v - np.cross(w, arm)
        data.qvel[vadr + 3:vadr + 6] = rot.T @ w
        mujoco.mj_forward(model, data)
        d = handle.diagnostics(data)
        out["time"].append(t)
        out["position"].append(data.xipos[b].copy())
        out["force"].append(d.force[row].copy())
        out["torque"].append(d.torque[row].copy())
        out["max_depth"].append(d.max_depth[row])
        out["submerged"].append(d.submerged[row])
        qvel[:] = data.qvel
        mujoco.mj_integratePos(model, data.qpos, qvel, dt)
    return Rollout(**{k: np.asarray(v) for k, v in out.items()})
