"""The deformable surface drawn in MuJoCo: a visual heightfield over the grid, rewritten from the surface of an
MjData (the demo's and viewer's ``--deformable``, :mod:`rft_mujoco.studies.prints`'s frames)."""

from __future__ import annotations

import mujoco
import numpy as np

from rft_mujoco.physics.deform import DeformableSurface

GRID = dict(size=(2.0, 1.0), cell=0.01, center=(0.5, 0.0))
"""The grid of the demo's deformable surface (m): 2 x 1 m around x = 0.5 m, 1 cm cells."""


HFIELD = "rft_surface"
"""Name of the visual heightfield (asset and geom) that draws a deformable surface."""
SPAN = 0.1
"""m: the drawn elevation range, +- around the initial height."""


def add_surface_hfield(spec: mujoco.MjSpec, grid: DeformableSurface, span: float = SPAN) -> None:
    """Add to ``spec`` a visual heightfield geom over ``grid`` (no collisions), initially flat at its height."""
    ny, nx = grid.shape
    lx, ly = grid.size
    spec.add_hfield(name=HFIELD, nrow=ny, ncol=nx, size=[lx / 2, ly / 2, 2 * span, 0.01],
                    userdata=list(np.full(ny * nx, 0.5)))
    spec.worldbody.add_geom(name=HFIELD, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=HFIELD,
                            pos=[grid.center[0], grid.center[1], grid.height - span], contype=0, conaffinity=0,
                            rgba=[0.82, 0.72, 0.52, 1.0])


def write_surface(model, heights: np.ndarray, grid: DeformableSurface, span: float = SPAN) -> int:
    """Write ``heights`` (ny, nx) m into the model's :data:`HFIELD` data (clipped to +-span); returns its id (upload
    it to a renderer with ``mujoco.mjr_uploadHField``, or ``viewer.update_hfield``)."""
    hid = model.hfield(HFIELD).id
    adr = model.hfield_adr[hid]
    values = np.clip((heights - (grid.height - span)) / (2 * span), 0.0, 1.0)
    model.hfield_data[adr:adr + values.size] = values.ravel()
    return hid
