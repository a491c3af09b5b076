"""The deformable surface in the coupling: each evaluation's bodies press the surface of their MjData.

The physics is :mod:`rft_mujoco.physics.deform`; the state of each MjData is the ``surface`` of the handle's
workspace (:class:`rft_mujoco.coupling.workspace._Workspace`), so it follows the workspace's rules
(docs/architecture.md, "State and copies"): a reset drops it (the next evaluation starts from the initial
surface), a copy for the same model copies it, a copy with a copy of the model starts fresh. Deformable
terrains run on the numpy reference (the compiled kernels read one heightfield per handle, not per MjData,
and no loading memory): ``backend="auto"`` chooses it, ``backend="numba"`` raises. The grid is pressed once per
step while bodies touch the sand; a step without a press (no body touching) unloads every node
(:func:`rft_mujoco.physics.deform.unload`: the next press begins a new loading cycle).
"""

from __future__ import annotations

import numpy as np

from rft_mujoco import tol
from rft_mujoco.physics import deform


def press_touching(handle, data, work, touch: np.ndarray) -> deform.PressResult:
    """Press ``work.surface`` with the elements of the touching bodies ``touch`` (indices into
    ``handle.body_ids``) that are below the surface's highest point, at their poses in ``data``; first unload
    every node when the last press was not the previous step's (``data.time`` against ``work.arrays
    ["surface_clock"]``)."""
    surface = work.surface
    clock = work.arrays["surface_clock"]
    if not 0.0 <= data.time - clock[0] <= handle.model.opt.timestep * (1.0 + tol.TIME_RTOL):
        deform.unload(surface)
    clock[0] = data.time
    sel = np.concatenate([np.arange(handle._elem_slices[i], handle._elem_slices[i + 1]) for i in touch])
    bodies = handle.body_ids[handle.elem_body[sel]]
    rot = data.xmat[bodies].reshape(-1, 3, 3)
    pos = data.xpos[bodies] + np.einsum("eij,ej->ei", rot, handle.local_centroids[sel])
    low = pos[:, 2] < surface.max_height
    nrm = np.einsum("eij,ej->ei", rot[low], handle.local_normals[sel[low]])
    return deform.press(surface, pos[low], nrm, handle.areas[sel[low]])


def snapshot(handle, work) -> deform.DeformedSurface:
    """A copy of the deformed surface of ``work`` (ValueError when the handle's terrain is not deformable)."""
    if work.surface is None:
        raise ValueError(f"handle.surface(data) needs a deformable terrain, but this handle's terrain is "
                         f"{type(handle.terrain).__name__}; attach with surface_height=rft_mujoco.DeformableSurface"
                         "(...) to have footprints")
    return work.surface.copy()
