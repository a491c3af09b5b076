"""The deformable surface's grid update on the native route: one C function per evaluation of a handle whose
terrain is a :class:`~rft_mujoco.DeformableSurface`.

Phase 2 of the route (:mod:`rft_mujoco.compiled.route`) evaluates the handle, then, for a deformable handle
that touches and at the first RK4 stage (or another integrator), calls :func:`press_phase` through its
address (the table's header, ``t[7]``): what the dispatcher's Python path runs after its evaluation
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

FIELDS = (("cycles", "f2"), ("reach", "f2"), ("clock", "f1"), ("live", "i1"), ("stats", "f1"), ("pts", "f2"),
          ("nrm", "f2"), ("ar", "f1"), ("mark", "i1"), ("val", "f1"), ("nodes", "i1"), ("low", "f1"), ("rim", "i1"))
"""(name, kind) of the handle's press part of the table: ``cycles``, ``reach`` (ny, nx) and ``clock`` (2,) s of
the MjData's surface, then the buffers of :func:`rft_mujoco.compiled.deform.buffers`."""
_SLACK = 1.0 + tol.TIME_RTOL
_SNAPSHOT = [name for name, _ in rt.BOOK_FIELDS].index("snapshot") * table.SLOT
_HC = {name: i for i, (name, _) in enumerate(rt.ev.HANDLE_FIELDS)}
_WS = {name: i for i, (name, _) in enumerate(rt.ev.WORK_FIELDS)}
_TOUCHING = rt.ev.STATE.index("touching")

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
    n = t[0]
    base = t[rt._HEADER + h]
    hc = rt._hc(t, base)
    ws = rt._ws(t, base + rt._HC_SLOTS)
    dt = rt._f1(t, t[1] + _SNAPSHOT)[0]              # the model's timestep, as the dispatcher last checked it
    cycles, reach, clock, live, stats, pts, nrm, ar, mark, val, nodes, low, rim = _part(t, t[rt._HEADER + 2 * n + h])
    params = hc[35]
    top = press_touching(hc[26], hc[27], cycles, reach, live, clock, time, dt, _SLACK, int(ws[45][2]), ws[0], ws[1],
                         ws[2], hc[21], hc[22], hc[23], hc[4], hc[5], params[0], pts, nrm, ar, mark, val, nodes, low,
                         rim, stats)
    if top == top:                                   # not NaN: the heights changed
        params[0] = top
    return 0


assert tuple(_HC[name] for name in ("cluster_start", "body_clusters", "centroids", "normals", "areas", "tp",
                                    "heights", "params")) == (4, 5, 21, 22, 23, 26, 27, 35)
assert (_WS["touch"], _WS["body_pos"], _WS["body_mat"], _WS["state"], _TOUCHING) == (0, 1, 2, 45, 2)

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
