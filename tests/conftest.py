"""Shared test fixtures and helpers (test modules import the helpers: ``from conftest import numpy_rollout``)."""

import mujoco
import numpy as np
import pytest

import rft_mujoco


@pytest.fixture(autouse=True)
def _detach_everything():
    """Every test leaves no sand attached (the dispatcher is process-wide: a handle left attached would act
    on the next test's models)."""
    yield
    rft_mujoco.detach_all()


def numpy_rollout(xml, media, bodies, terrain, steps, speed, seed=0, **attach_kwargs):
    """Full physics states (``mjSTATE_FULLPHYSICS``), one per step, along a rollout of the model ``xml`` with
    sand on the numpy backend (the reference the compiled paths are compared with), from random initial
    velocities of scale ``speed`` (m/s, rad/s); returns (model, states)."""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qvel[:] = np.random.default_rng(seed).normal(size=model.nv) * speed
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    states = []
    with rft_mujoco.attach(model, media, bodies, terrain, 0.01, monitor=False, backend="numpy", **attach_kwargs):
        for _ in range(steps):
            mujoco.mj_step(model, data)
            state = np.empty(mujoco.mj_stateSize(model, spec))
            mujoco.mj_getState(model, data, state, spec)
            states.append(state)
    return model, states


FLOW_DIRECTIONS = ([1.0, 0.0, 0.0], [0.3, -0.2, -1.0], [1.0, 0.5, -0.4], [0.0, 1.0, 0.2])
"""Directions (not normalized) in which the flow tests move a free body through the sand."""


def buried_free_body(data, seed: int = 1):
    """Put the free body of ``data`` (its first joint) 50 mm below the surface at a random orientation; return the
    unit directions of :data:`FLOW_DIRECTIONS` to move it in."""
    rng = np.random.default_rng(seed)
    data.qpos[2] = -0.05
    q = rng.normal(size=4)
    data.qpos[3:7] = q / np.linalg.norm(q)
    return [np.array(d) / np.linalg.norm(d) for d in FLOW_DIRECTIONS]
