"""The deformable surface's grid update on the native route: one C function per evaluation of a handle whose
terrain is a :class:`~rft_mujoco.DeformableSurface`.

Phase 2 of the route (:mod:`rft_mujoco.compiled.route`) evaluates the handle, then, for a deformable handle
that touches and at the first RK4 stage (or another integrator), calls :func:`press_phase` through its
address (the table's header, ``t[T_PRESS_PHASE]``): what the dispatcher's Python path runs after its evaluation
(:func:`rft_mujoco.coupling.deformable.press_compiled`), on the same arrays, so both give the same numbers
bit for bit (tests/test_deformable_coupling.py). Without it, a deformable handle took the Python callback and
paid its cost at every step (issue 31's cost: docs/deformable.md).

The handle's part of the table (:func:`table_part`, at ``t[_HEADER + 2 n + h]``; 0 for a handle whose terrain
is not deformable): the MjData's surface state and the grid update's buffers, :data:`FIELDS`.
"""

from __future__ import annotations

import threading

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled import route as rt
from rft_mujoco.compiled import table
from rft_mujoco.compiled.deform import press_touching
from rft_mujoco.compiled.jit import cfunc
from rft_mujoco.compiled import schema as sc

FIELDS = (("cycles", "f2"), ("reach", "f2"), ("clock", "f1"), ("live", "i1"), ("stats", "f1"), ("pts", "f2"),
          ("nrm", "f2"), ("ar", "f1"), ("mark", "i1"), ("val", "f1"), ("nodes", "i1"), ("low", "f1"), ("rim", "i1"))
"""(name, kind) of the handle's press part of the table: ``cycles``, ``reach`` (ny, nx) and ``clock`` (2,) s of
the MjData's surface, then the buffers of :func:`rft_mujoco.compiled.deform.buffers`."""
_SLACK = 1.0 + tol.TIME_RTOL
_SNAPSHOT = [name for name, _ in rt.BOOK_FIELDS].index("snapshot") * table.SLOT

if rt.AVAILABLE:
    _part = table.loader(FIELDS)
    """The press part's arrays (:data:`FIELDS`) at ``base``, a tuple."""
else:  # pragma: no cover - without numba the route is never built
    _part = None


def press_phase(ptr, h, time):
    """The grid update of handle ``h`` (its index in the route) after its evaluation at ``time`` (s), on the
    table at ``ptr``: :func:`rft_mujoco.compiled.deform.press_touching` with the touching bodies of this
    evaluation's broadphase; the surface's highest point (``params[0]``, which the broadphase reads) follows
    the grid. Returns 0. A C function (:func:`cfunc_address`) with the route's rest signature."""
    t = rt._table(ptr)
    n = t[sc.T_HANDLES]
    base = t[rt._HEADER + h]
    hc = rt._hc(t, base)
    ws = rt._ws(t, base + rt._HC_SLOTS)
    dt = rt._f1(t, t[sc.T_BOOK] + _SNAPSHOT)[0]              # the model's timestep, as the dispatcher last checked it
    cycles, reach, clock, live, stats, pts, nrm, ar, mark, val, nodes, low, rim = _part(t, t[rt._HEADER + 2 * n + h])
    params = hc[sc.H_PARAMS]
    packed = (hc[sc.H_CENTROIDS], hc[sc.H_NORMALS], hc[sc.H_AREAS], hc[sc.H_CLUSTER_START], hc[sc.H_BODY_CLUSTERS])
    top = press_touching(hc[sc.H_TP], (hc[sc.H_HEIGHTS], cycles, reach, live), (clock, time, dt, _SLACK),
                         int(ws[sc.W_STATE][sc.S_TOUCHING]), (ws[sc.W_TOUCH], ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT]),
                         packed, params[sc.P_MAX_HEIGHT], (pts, nrm, ar), (mark, val, nodes, low, rim), stats)
    if top == top:                                   # not NaN: the heights changed
        params[sc.P_MAX_HEIGHT] = top
    return 0


_cfunc: list = []
_lock = threading.Lock()


def cfunc_address() -> int:
    """The address of :func:`press_phase` as a C function, compiled or loaded from the cache at the first route
    with a deformable handle (so that models without one never compile it)."""
    with _lock:
        if not _cfunc:
            _cfunc.append(cfunc(rt._REST_SIG, cache=True)(press_phase))
        return _cfunc[0].address


def table_part(work) -> list:
    """[(name, kind, array)] of :data:`FIELDS` for a deformable handle's workspace ``work`` on one MjData (its
    ``arrays`` and ``press`` buffers: :class:`rft_mujoco.coupling.workspace._Workspace`)."""
    a, b = work.arrays, work.press
    arrays = (a["surface_cycles"], a["surface_reach"], a["surface_clock"], *(b[name] for name, _ in FIELDS[3:]))
    return [(name, kind, np.asarray(x)) for (name, kind), x in zip(FIELDS, arrays)]
