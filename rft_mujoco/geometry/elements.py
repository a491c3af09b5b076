"""Flat surface elements (centroid, outward unit normal, area): the container every geometry module fills."""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

NORMAL_TOL = 1e-6
"""Normals whose length differs from 1 by more than this are rejected by :class:`Elements`."""
ROTATION_TOL = 1e-6
"""``mat`` in :meth:`Elements.transformed` must satisfy ``|mat^T mat - I| <= ROTATION_TOL``."""


class SandSetupWarning(UserWarning):
    """The scene runs, but its set-up keeps the sand from acting as intended, or approximates what was given
    (an open or non-manifold mesh, a body whose sand surface is its visual geoms; see
    :mod:`rft_mujoco.coupling.checks`). Defined here, the lowest module that warns with it; public as
    ``rft_mujoco.SandSetupWarning``."""


# --- elements --------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Elements:
    """Flat surface elements of a closed surface; arrays are read-only float64 copies.

    Attributes:
        centroids: (N, 3) float, element centroids in m.
        normals: (N, 3) float, unit outward normals.
        areas: (N,) float, element areas in m^2, all > 0.
    """

    centroids: np.ndarray
    normals: np.ndarray
    areas: np.ndarray

    def __post_init__(self) -> None:
        c = as_points(self.centroids, "centroids")
        n = as_points(self.normals, "normals")
        a = np.array(self.areas, dtype=float)
        if a.ndim != 1 or a.shape[0] != c.shape[0] or n.shape[0] != c.shape[0]:
            raise ValueError(f"centroids (N, 3), normals (N, 3) and areas (N,) must agree in N, got shapes "
                             f"{c.shape}, {n.shape}, {a.shape}")
        if not np.all(np.isfinite(a) & (a > 0)):
            raise ValueError(f"areas must be finite and > 0 (m^2), got min {a.min()!r}")
        length = np.linalg.norm(n, axis=1)
        if np.any(np.abs(length - 1.0) > NORMAL_TOL):
            raise ValueError(f"normals must be unit vectors (within {NORMAL_TOL}), got lengths in "
                             f"[{length.min()}, {length.max()}]")
        for name, arr in (("centroids", c), ("normals", n), ("areas", a)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.areas.shape[0])

    def __repr__(self) -> str:
        return f"Elements(n={len(self)}, area={self.area():.6g} m^2)"

    def area(self) -> float:
        """Total area in m^2."""
        return float(self.areas.sum())

    def enclosed_volume(self) -> float:
        """Enclosed volume in m^3 by the divergence theorem, ``(1/3) sum (c . n) A``.

        Positive for a closed surface with outward normals; independent of the origin only when the
        surface is closed (``sum n A = 0``).
        """
        return float(np.einsum("ij,ij,i->", self.centroids, self.normals, self.areas) / 3.0)

    def transformed(self, pos, mat) -> "Elements":
        """The elements moved rigidly: ``x' = pos + mat @ x``, ``n' = mat @ n``.

        Args:
            pos: (3,) float, translation in m.
            mat: (3, 3) float, a rotation matrix (orthonormal, det +1); a flat (9,) array such as
                MuJoCo's ``xmat`` rows is accepted.
        """
        p = np.asarray(pos, dtype=float)
        r = np.asarray(mat, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"pos must be a finite (3,) float array, got shape {p.shape}")
        if r.shape == (9,):
            r = r.reshape(3, 3)
        if r.shape != (3, 3):
            raise ValueError(f"mat must be a (3, 3) rotation matrix, got shape {r.shape}")
        if not (np.all(np.abs(r.T @ r - np.eye(3)) <= ROTATION_TOL) and np.linalg.det(r) > 0):
            raise ValueError(f"mat must be a rotation (orthonormal, det +1), got {r.tolist()}; "
                             "scale geometry before making elements, not through transformed()")
        return Elements(self.centroids @ r.T + p, self.normals @ r.T, self.areas)

    @staticmethod
    def concatenate(parts: Sequence["Elements"]) -> "Elements":
        """All elements of ``parts`` in order; an empty sequence gives zero elements."""
        parts = list(parts)
        if not parts:
            return Elements(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        return Elements(np.concatenate([p.centroids for p in parts]),
                        np.concatenate([p.normals for p in parts]),
                        np.concatenate([p.areas for p in parts]))


# --- argument checks -------------------------------------------------------------------------------
def as_points(x, name: str) -> np.ndarray:
    """``x`` as a new finite (n, 3) float array; ValueError naming ``name`` otherwise."""
    arr = np.array(x, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be an (n, 3) float array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got non-finite values")
    return arr


def _check_length(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive finite length in m, got {value!r}") from None
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite length in m, got {value!r}")
    return v


def _check_lengths(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a (3,) float array of lengths in m, got shape {arr.shape}")
    if not np.all(np.isfinite(arr) & (arr > 0)):
        raise ValueError(f"{name} must be positive finite lengths in m, got {arr.tolist()}")
    return arr
