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
