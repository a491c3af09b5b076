"""The static part of an attached sand: which bodies, their surface elements, weld groups, radii and run-time
occluders (numpy), built once at attach.

One builder for both paths: :class:`rft_mujoco.SandHandle` (``handle.layout``: its numpy reference and its
compiled constants read it) and the batched warp path (:class:`rft_mujoco.warp.WarpSandHandle`), so that both cut
the same elements (culled at attach inside the body's other geoms and inside geoms welded to it), form the same
weld groups, use the same radii and test the same occluders at run time (tests/test_warp.py).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from rft_mujoco.coupling import setup
from rft_mujoco.coupling.setup import Groups
from rft_mujoco.geometry import surface
from rft_mujoco.geometry.occlusion import Occluders, occluders


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """Elements and groups of the attached bodies (B bodies, E elements, G weld groups).

    Attributes:
        body_ids: (B,) int, MuJoCo ids of the attached bodies.
        body_names: their names.
        centroids: (E, 3) float, m, body frame. normals: (E, 3) unit, body frame. areas: (E,) m^2.
        elem_body: (E,) int, row of each element's body in ``body_ids``; elements of a body are contiguous.
        bound_center: (B, 3) m, body frame; bound_radius: (B,) m: the bodies' bounding spheres, grown by the
            element size (the broadphase's; -inf for a body without elements: never a candidate).
        groups: the weld groups (:class:`rft_mujoco.coupling.setup.Groups`).
        element_size: m.
        cull: culling on (at attach and at run time), as ``rft_mujoco.attach(cull=...)``.
        culled_area: (B,) m^2 of each body's surface culled at attach.
        occluders: the run-time occluders of each body (:class:`rft_mujoco.geometry.occlusion.Occluders`; none
            when ``cull`` is False).
        elem_slices: (B + 1,) int, the elements of body row i are ``elem_slices[i]:elem_slices[i + 1]``.
        root: (B,) int, each body's root body (``model.body_rootid``).
    """

    body_ids: np.ndarray
    body_names: list
    centroids: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    elem_body: np.ndarray
    bound_center: np.ndarray
    bound_radius: np.ndarray
    groups: Groups
    element_size: float
    cull: bool = True
    culled_area: np.ndarray | None = None
    occluders: Occluders | None = None
    elem_slices: np.ndarray | None = None
    root: np.ndarray | None = None

    @property
    def n_elements(self) -> int:
        return int(self.areas.size)


def build(model, bodies: Sequence[str | int] | None, resolution: str | float, cull: bool = True) -> Layout:
    """The layout of ``bodies`` (names or ids; None: :func:`rft_mujoco.coupling.setup.body_ids`) at ``resolution``, culled as
    ``rft_mujoco.attach(cull=cull)`` culls."""
    size = surface.element_size(resolution)
    ids = setup.body_ids(model, bodies)
    names = [model.body(int(b)).name for b in ids]
    ids = np.asarray(ids, dtype=np.int64)
    cull = bool(cull)
    s = setup.surfaces(model, ids, names, size, cull)
    centroids = np.ascontiguousarray(s.centroids, dtype=float)
    bound_center, bound_radius = setup.bounding_spheres(centroids, s.elem_body, len(ids), size)
    slices = np.concatenate([[0], np.cumsum(np.bincount(s.elem_body, minlength=len(ids)))])
    return Layout(ids, names, centroids, np.ascontiguousarray(s.normals, dtype=float),
                  np.ascontiguousarray(s.areas, dtype=float), s.elem_body, bound_center, bound_radius,
                  setup.groups(model, ids, centroids, s.elem_body, size), size, cull, s.culled_area,
                  occluders(model, ids) if cull else Occluders.none(len(ids)),
                  np.ascontiguousarray(slices, dtype=np.int64),
                  np.ascontiguousarray(model.body_rootid[ids], dtype=np.int64))
