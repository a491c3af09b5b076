"""Shared test fixtures."""

import pytest

import rft_mujoco


@pytest.fixture(autouse=True)
def _detach_everything():
    """Every test leaves no sand attached (the dispatcher is process-wide: a handle left attached would act
    on the next test's models)."""
    yield
    rft_mujoco.detach_all()
