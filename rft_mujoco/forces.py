"""The public per-element 3D-RFT force, ``rft_mujoco.element_forces``: the compiled kernel where numba is.

:func:`element_forces` takes the arguments of the numpy reference :func:`rft_mujoco.physics.law.element_forces`
(the readable one, which the tests compare against) and runs :func:`rft_mujoco.compiled.law.element_forces`
(~20x faster; the two side by side: ``python -m rft_mujoco bench --law``) unless ``backend="numpy"``. Both give the same forces to
round-off and raise the same errors for bad input (tests/test_forces.py). This module sits above
``physics/`` and ``compiled/`` so that neither imports the other's caller.
"""

from __future__ import annotations

import warnings

import numpy as np

from rft_mujoco import compiled
from rft_mujoco.coupling.callers import user_stacklevel
from rft_mujoco.physics import law
from rft_mujoco.physics.law import PUBLISHED, Guards
from rft_mujoco.physics.media import Media, get_media

BACKENDS = ("auto", "numba", "numpy")
"""Values of ``element_forces(backend=...)``: "auto" (numba when it imports and compiles, else numpy),
"numba" (compiled, an error without numba) or "numpy" (the reference)."""
DIRECTION_SCALE_MAX = 1e150
"""Rows of ``normals`` and ``velocities`` (whose length does not matter) with a component beyond this are
scaled by a power of two first (exactly, the direction unchanged): their squared length would overflow."""


def element_forces(centroids, normals, areas, velocities, media: Media | str, surface_height: float = 0.0,
                   gravity=(0.0, 0.0, -9.81), *, guards: Guards = PUBLISHED, backend: str = "auto",
                   out: np.ndarray | None = None) -> np.ndarray:
    """3D-RFT force on each surface element, in newtons (world frame).

    Args:
        centroids: (N, 3) float, element centroids in m, world frame.
        normals: (N, 3) float, outward normals, world frame; any positive length (normalized here).
        areas: (N,) float, element areas in m^2 (>= 0).
        velocities: (N, 3) float, element velocities in m/s, world frame (only the direction matters).
        media: the granular medium (:class:`rft_mujoco.Media`) or a preset name (``rft_mujoco.PRESETS``).
        surface_height: height of the flat free surface in m, measured against gravity (along -g).
        gravity: (3,) gravity vector in m/s^2; depth is measured along it.
        guards: artefact clean-ups (default: none, the published model).
        backend: "auto" (default), "numba" or "numpy" (:data:`BACKENDS`). The first call with numba
            compiles the kernels once per machine (~20 s, cached afterwards).
        out: optional (N, 3) float64 C-contiguous array to write the forces into.
    Returns:
        (N, 3) float forces in N (``out`` when given). Zero for elements above the surface, trailing
        (n.v < 0), or at rest.
    Raises:
        ValueError: on wrong shapes, non-finite input, negative areas or zero normals (the messages of
            :func:`rft_mujoco.physics.law.element_forces`), a bad ``out``, an unknown backend, or
            backend="numba" without numba.
    """
    if isinstance(media, str):
        media = get_media(media)
    normals, velocities = _scaled_directions(normals), _scaled_directions(velocities)
    if _use_numba(backend):
        from rft_mujoco.compiled import law as fastlaw

        return fastlaw.element_forces(centroids, normals, areas, velocities, media, surface_height, gravity,
                                         guards=guards, out=out)
    forces = law.element_forces(centroids, normals, areas, velocities, media, surface_height, gravity,
                                guards=guards)
    if out is None:
        return forces
    n = forces.shape[0]
    if out.shape != (n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float64 array of shape ({n}, 3), got {out.shape} "
                         f"{out.dtype}")
    out[...] = forces
    return out


def _scaled_directions(vectors):
    """``vectors`` with rows beyond :data:`DIRECTION_SCALE_MAX` scaled exactly by a power of two (other
    input unchanged, bad input left for the law's own checks)."""
    try:
        a = np.asarray(vectors, dtype=float)
    except (TypeError, ValueError):
        return vectors
    if a.ndim != 2 or a.shape[1] != 3 or a.size == 0:
        return vectors
    # the common case in two flat passes without temporaries (a per-row max over 3 columns costs ~240 ns
    # per element, twice the compiled law); NaN fails both comparisons and goes on to the check below
    if -DIRECTION_SCALE_MAX <= a.min() and a.max() <= DIRECTION_SCALE_MAX:
        return vectors
    if not np.all(np.isfinite(a)):
        return vectors
    big = np.abs(a).max(axis=1, initial=0.0) > DIRECTION_SCALE_MAX
    if not big.any():
        return vectors
    a = a.copy()
    _, exponent = np.frexp(np.abs(a[big]).max(axis=1))
    a[big] = np.ldexp(a[big], -exponent[:, None])
    return a


def _use_numba(backend: str) -> bool:
    """Whether ``backend`` runs the compiled kernel (raises for a bad name or numba requested but missing)."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "numpy" or (backend == "auto" and not compiled.AVAILABLE):
        return False
    if not compiled.AVAILABLE:
        raise ValueError(f"backend='numba' needs numba, which failed to import ({compiled.IMPORT_ERROR}); "
                         "use backend='auto' or 'numpy'")
    try:
        compiled.ensure_compiled()
    except Exception as exc:  # a broken numba/LLVM install must not break the law
        if backend == "numba":
            raise
        warnings.warn(f"rft_mujoco: the numba kernel failed to compile ({type(exc).__name__}: {exc}); "
                      "element_forces uses numpy (slower). Pass backend='numpy' to silence this.",
                      RuntimeWarning, stacklevel=user_stacklevel())
        return False
    return True
