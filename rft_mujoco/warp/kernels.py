"""Warp kernels of the batched sand: the CPU coupling's evaluation, per world, inside ``mujoco_warp.step``.

Each kernel ports one part of the CPU path and names it; the numbers agree with it to round-off on the
same state (tests/test_warp.py). Precision: MuJoCo Warp keeps its state in float32; the element pass
(law, depth, culling, sums) runs in float32 like the state it reads, the small dense per-world solves (free
twists, mobility, the rest solve) in float64 -- the rank-revealing Cholesky of
:func:`rft_mujoco.physics.rest.pivoted_solve` squares condition numbers, which float32 cannot hold.

The kernels live in modules by what they are (this module gathers them; the import graph has no cycle:
``common`` <- ``law``, ``occlusion`` <- ``elements``; ``common`` <- ``twists``, ``rest``, ``book``):

* :mod:`~rft_mujoco.warp.common`: constants, error bits, conversions;
* :mod:`~rft_mujoco.warp.law`: the 3D-RFT law and the terrains;
* :mod:`~rft_mujoco.warp.occlusion`: run-time culling (inside tests, the near-occluder pass);
* :mod:`~rft_mujoco.warp.elements`: the element passes;
* :mod:`~rft_mujoco.warp.twists`: free twists, mobility, blended twists;
* :mod:`~rft_mujoco.warp.rest`: the rest solve and the diagnostics;
* :mod:`~rft_mujoco.warp.book`: the ``xfrc_applied`` bookkeeping.

The implicit solve (``attach(solve="implicit")``) has its own modules and launch order:
:mod:`~rft_mujoco.warp.implicit` (its docstring), :mod:`~rft_mujoco.warp.implicit_law`,
:mod:`~rft_mujoco.warp.implicit_free`, :mod:`~rft_mujoco.warp.system`; it shares ``user_part``, ``touch_pass``,
``near_occluders`` and ``commit`` with this list, and the rest solve's factor and share
(:mod:`~rft_mujoco.warp.rest`).

Launch order of one evaluation (:meth:`rft_mujoco.warp.handle.WarpSandHandle._evaluate`)::

    user_part        (nworld, B)   xfrc_applied -> the user's part (the dispatcher's book); broadphase; zeroing
    touch_pass       (nworld, E)   depth of every active element: touch[w, b] = 1 if one is submerged
    near_occluders   (nworld, O)   occluders whose bounding sphere reaches a touching body's (cull=True)
    [fwd_actuation]                MuJoCo Warp's own, for this step's qfrc_actuator (stabilize only)
    free_twist       (nworld,)     touching groups, free acceleration, Jacobians, mobility, blended twists
      or body_twist  (nworld, B)   stabilize=False: the bodies' own velocities
    force_pass       (nworld, E)   3D-RFT force of every submerged leading element not inside an occluder
                                   -> per-body wrench sums; the occluded submerged area
    rest_solve       (nworld,)     rest_wrenches + _share + diagnostics (stabilize) or the naive rule
    commit           (nworld, B)   xfrc_applied = user + sand; the book

Work arrays of the one-thread-per-world kernels keep the world index last ((n, w), (n, m, w)): on a GPU the
threads of a warp (consecutive worlds) then read consecutive addresses. Per-body and per-element arrays of
MuJoCo Warp's layout keep it first.

Nothing here allocates or reads back to the host: a whole evaluation can be recorded in a CUDA graph.
Per-element work masks: ``elem_mask`` (1 or nworld, E) int; an element with mask 0 does not exist for
that world (neither touches nor loads).
"""

from __future__ import annotations

from rft_mujoco.warp.book import commit, remove_sand, user_part
from rft_mujoco.warp.common import BAD_ACCELERATION, FLAT, HEIGHTFIELD, NOT_FINITE
from rft_mujoco.warp.elements import force_pass, touch_pass
from rft_mujoco.warp.law import depth, stress
from rft_mujoco.warp.occlusion import inside, near_occluders
from rft_mujoco.warp.rest import rest_solve
from rft_mujoco.warp.twists import body_twist, free_twist

__all__ = ["user_part", "touch_pass", "near_occluders", "free_twist", "body_twist", "force_pass", "rest_solve",
           "commit", "remove_sand", "stress", "depth", "inside", "FLAT", "HEIGHTFIELD", "NOT_FINITE",
           "BAD_ACCELERATION"]
