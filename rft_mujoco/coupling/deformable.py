"""The deformable surface in the coupling: each evaluation's bodies press the surface of their MjData.

The physics is :mod:`rft_mujoco.physics.deform`; the state of each MjData is the ``surface`` of the handle's
workspace (:class:`rft_mujoco.coupling.workspace._Workspace`), so it follows the workspace's rules
(docs/architecture.md, "State and copies"): a reset drops it (the next evaluation starts from the initial
surface), a copy for the same model copies it, a copy with a copy of the model starts fresh. The grid is
pressed while bodies touch the sand, every ``update_interval`` (:func:`rft_mujoco.physics.deform.schedule`);
after a step with no body touching, the next press first unloads every node
(:func:`rft_mujoco.physics.deform.unload`: it begins a new loading cycle).

Both backends run it. numpy: :func:`press_touching` (the reference). Compiled (``backend="auto"`` or
``"numba"``): the kernels read this MjData's grid (the workspace's own handle constants, ``work.hc``: the
terrain kind :data:`rft_mujoco.physics.terrain_spec.DEFORMABLE`, heights and preload of this data), and the
compiled mirror of the press (:mod:`rft_mujoco.compiled.deform`) runs after each evaluation: on the native
route through :func:`rft_mujoco.compiled.deform_route.press_phase`, on the dispatcher's Python path (an
observer, the first evaluation) through :func:`press_compiled` (docs/deformable.md "Backends").
"""

from __future__ import annotations

import numpy as np

from rft_mujoco import tol
from rft_mujoco.physics import deform


def press_touching(handle, data, work, touch: np.ndarray) -> deform.PressResult | None:
    """Press ``work.surface`` with the elements of the touching bodies ``touch`` (indices into
    ``handle.body_ids``) that are below the surface's highest point, at their poses in ``data``, when an update
    is due (:func:`rft_mujoco.physics.deform.schedule` of ``data.time`` against ``work.arrays["surface_clock"]``: the
    times of the last update and of the last evaluation with bodies touching; first unloading every node when
    the last step had nothing touching). None when not due."""
    surface = work.surface
    clock = work.arrays["surface_clock"]
    todo = deform.schedule(data.time - clock[0], data.time - clock[1], surface.grid.update_interval,
                           handle.model.opt.timestep)
    clock[1] = data.time
    if todo == deform.SKIP:
        return None
    if todo == deform.RESTART:
        deform.unload(surface)
    clock[0] = data.time
    sel = np.concatenate([np.arange(handle.layout.elem_slices[i], handle.layout.elem_slices[i + 1]) for i in touch])
    bodies = handle.body_ids[handle.elem_body[sel]]
    rot = data.xmat[bodies].reshape(-1, 3, 3)
    pos = data.xpos[bodies] + np.einsum("eij,ej->ei", rot, handle.local_centroids[sel])
    low = pos[:, 2] < surface.max_height
    nrm = np.einsum("eij,ej->ei", rot[low], handle.local_normals[sel[low]])
    return deform.press(surface, pos[low], nrm, handle.areas[sel[low]])


def press_compiled(handle, data, work, k: int) -> None:
    """:func:`press_touching` compiled (:func:`rft_mujoco.compiled.deform.press_touching`), for the ``k`` touching
    bodies of the compiled broadphase of this evaluation; the surface's highest point, which the broadphase
    reads (``work.hc``'s ``params[0]``), follows the grid."""
    from rft_mujoco.compiled import deform as compiled_deform
    from rft_mujoco.compiled import schema as sc
    a, b, hc = work.arrays, work.press, work.hc
    params = hc[sc.H_PARAMS]
    state = (hc[sc.H_HEIGHTS], a["surface_cycles"], a["surface_reach"], b["live"])
    schedule = (a["surface_clock"], data.time, handle.model.opt.timestep, 1.0 + tol.TIME_RTOL)
    packed = (hc[sc.H_CENTROIDS], hc[sc.H_NORMALS], hc[sc.H_AREAS], hc[sc.H_CLUSTER_START], hc[sc.H_BODY_CLUSTERS])
    top = compiled_deform.press_touching(
        hc[sc.H_TP], state, schedule, k, (a["touch"], a["body_pos"], a["body_mat"]), packed, params[sc.P_MAX_HEIGHT],
        (b["pts"], b["nrm"], b["ar"]), tuple(b[name] for name in compiled_deform.SCRATCH), b["stats"])
    if top == top:                                   # not NaN: the heights changed
        params[sc.P_MAX_HEIGHT] = top


def snapshot(handle, work) -> deform.DeformedSurface:
    """A copy of the deformed surface of ``work`` (ValueError when the handle's terrain is not deformable)."""
    _check_deformable(handle, work, "surface")
    return work.surface.copy()


def updated_at(handle, work) -> float:
    """s, the ``data.time`` of the last update of the deformed surface of ``work`` (-inf before the first)."""
    _check_deformable(handle, work, "surface_updated")
    return float(work.arrays["surface_clock"][0])


def _check_deformable(handle, work, method: str) -> None:
    if work.surface is None:
        raise ValueError(f"handle.{method}(data) needs a deformable terrain, but this handle's terrain is "
                         f"{type(handle.terrain).__name__}; attach with surface_height=rft_mujoco.DeformableSurface"
                         "(...) to have footprints")
