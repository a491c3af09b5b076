"""The static part of a batched sand: which bodies, their surface elements, weld groups and radii (numpy).

Built with the CPU coupling's own helpers, so that the warp path cuts the same elements (same-body culling
included: :func:`rft_mujoco.geometry.surface.body_elements`, ``cull=True``), forms the same weld groups and
uses the same radii as :class:`rft_mujoco.SandHandle` (tests/test_warp.py compares them).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import Groups, _body_id, _check_element_count, _groups
from rft_mujoco.geometry import surface

_TERRAIN_GEOMS = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """Elements and groups of the attached bodies (B bodies, E elements, G weld groups).

    Attributes:
        body_ids: (B,) int, MuJoCo ids of the attached bodies.
        body_names: their names.
        centroids: (E, 3) float, m, body frame. normals: (E, 3) unit, body frame. areas: (E,) m^2.
        elem_body: (E,) int, row of each element's body in ``body_ids``; elements of a body are contiguous.
        bound_center: (B, 3) m, body frame; bound_radius: (B,) m: the bodies' bounding spheres (the CPU
            broadphase's; here they only scale torques in the diagnostics).
        groups: the weld groups (:class:`rft_mujoco.coupling.handle.Groups`).
        element_size: m.
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

    @property
    def n_elements(self) -> int:
        return int(self.areas.size)


def default_bodies(model) -> list[int]:
    """Every body but the world that has a non-terrain geom (``rft_mujoco.attach(bodies=None)``)."""
    return [b for b in range(1, model.nbody)
            if any(model.geom_bodyid[g] == b and model.geom_type[g] not in _TERRAIN_GEOMS for g in range(model.ngeom))]


def build(model, bodies: Sequence[str | int] | None, resolution: str | float) -> Layout:
    """The layout of ``bodies`` (names or ids; None: :func:`default_bodies`) at ``resolution``."""
    size = surface.element_size(resolution)
    if bodies is None:
        ids = default_bodies(model)
    else:
        if isinstance(bodies, (str, int, np.integer)):
            bodies = [bodies]
        ids = [_body_id(model, b) for b in bodies]
        if len(set(ids)) != len(ids):
            raise ValueError(f"bodies lists a body twice: {list(bodies)}")
    if not ids:
        raise ValueError("no bodies to attach sand to: the model has no body with surface geoms")
    names = [model.body(int(b)).name for b in ids]
    parts, counts = [], []
    for b, name in zip(ids, names):
        _check_element_count(model, int(b), name, size)
        try:
            el = surface.body_elements(model, int(b), size)
        except ValueError as exc:
            raise ValueError(f"cannot cut body {name!r} into surface elements: {exc}. Check the sizes of its "
                             "geoms or leave the body out of bodies=") from None
        if len(el) and model.body_subtreemass[model.body_weldid[b]] <= 0:
            raise ValueError(f"body {name!r} has zero mass (its weld group's); give it a mass or leave it out "
                             "of bodies=")
        parts.append(el)
        counts.append(len(el))
    if sum(counts) == 0:
        raise ValueError(f"bodies {names} have no surface geoms (planes and heightfields are terrain, not "
                         "intruders); choose bodies with sphere/capsule/box/... geoms")
    el = surface.Elements.concatenate(parts)
    centroids = np.ascontiguousarray(el.centroids, dtype=float)
    elem_body = np.repeat(np.arange(len(ids)), counts)
    bound_center = np.zeros((len(ids), 3))
    bound_radius = np.full(len(ids), size)
    for i, c in enumerate(counts):
        if c:
            pts = centroids[elem_body == i]
            center = 0.5 * (pts.min(0) + pts.max(0))
            bound_center[i] = center
            bound_radius[i] = np.linalg.norm(pts - center, axis=1).max() + size
    ids = np.asarray(ids, dtype=np.int64)
    return Layout(ids, names, centroids, np.ascontiguousarray(el.normals, dtype=float),
                  np.ascontiguousarray(el.areas, dtype=float), elem_body, bound_center, bound_radius,
                  _groups(model, ids, centroids, elem_body, size), size)
