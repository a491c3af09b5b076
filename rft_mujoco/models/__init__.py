"""The bundled MJCF models (written for rft_mujoco; no third-party assets), shipped as package data."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def path(name: str) -> Path:
    """The file path of a bundled model, e.g. ``path("quadruped.xml")``."""
    found = Path(str(resources.files(__name__).joinpath(name)))
    if not found.is_file():
        names = sorted(p.name for p in Path(str(resources.files(__name__))).glob("*.xml"))
        raise FileNotFoundError(f"no bundled model {name!r}; the bundled models are {names}")
    return found
