"""The stabilized evaluation as one native call: no numba dispatch, and MuJoCo's C API called from inside.

``SandHandle._evaluate`` with the numba backend and ``stabilize=True`` makes, per evaluation, a broadphase
call (:func:`rft_mujoco.fastkernel.touching`, 27 arguments), two MuJoCo calls (``mj_fwdActuation`` and
``mj_solveM`` for the inverse mass matrix) and the stabilized call (:func:`rft_mujoco.fastlimit.stabilized`,
68 arguments). numba's dispatcher looks at the type of every argument at every call: measured on
SandAnt-v0 (2-core AMD EPYC, 1000 random-action env steps), those calls took 18.5 us per evaluation
(broadphase 2.5, MuJoCo 1.6, stabilized 14.4), the native call doing the same work 9.8 us; SandAnt
evaluates 20 times per env step (RK4, frame_skip 5).

Here the same work is one C function (a numba ``cfunc``) called through ctypes with one pointer to a table
of the arguments' addresses and shapes (built once per MjData and handle: MjData's arrays and the
workspace buffers never move) and the few per-call scalars. Inside, it calls ``touching``; when a body
touches the sand, ``mj_fwdActuation`` and ``mj_solveM`` straight from ``libmujoco`` (their symbols are
given to LLVM at load time), then ``stabilized``. The compiled functions are the same as on the dispatch
path, so the results are bit for bit the same (tests/test_native.py); only the calling changes.

A second cfunc, the route (:func:`_route`, :class:`Route`), is the dispatcher's whole callback for one
(model, MjData) whose handles all take the native call: the bookkeeping of ``xfrc_applied``, the RK4
stage tracking, the warm-start time check and every handle's evaluation. The dispatcher builds it after
an evaluation on the Python path and calls it through ctypes with the time, timestep and integrator;
it hands back to Python (having committed nothing) for a monitor check, a gravity change or an error.
On SandAnt-v0 it took the callback's Python from ~3 us to ~1 us per evaluation (the Python callback
itself stays, so that errors raise from ``mj_step``).

Everything is optional: if ``libmujoco`` or numba's cfunc support cannot be loaded, :func:`available` is
False and the coupling keeps the dispatch path.
"""

from __future__ import annotations

import ctypes
import os
import threading

import numpy as np

from . import fastkernel, fastlimit, law

FIELDS = (
    # MjData (live views)
    "xpos", "xmat", "xipos", "cvel", "subtree_com", "qpos", "qvel", "cdof", "qfrc_passive", "qfrc_bias",
    "qfrc_actuator", "qfrc_applied",
    # the handle (fixed per attach)
    "ids", "root", "bound_center", "bound_radius", "body_rootid", "body_dofnum", "body_dofadr",
    "body_parentid", "dof_parentid", "settings", "centroids", "normals", "areas", "cluster_start",
    "cluster_octant", "cluster_center", "cluster_radius", "body_clusters", "tp", "heights", "coef", "tol",
    # the workspace (per MjData)
    "touch", "body_pos", "body_mat", "body_com", "v_com", "omega", "minv", "eye", "warm", "warm_rounds",
    "scratch", "groups", "count", "max_depth", "col_v", "col_w", "col_groups", "col_count", "col_max_depth",
    "jac", "qacc", "limited", "force", "torque", "submerged", "depth_max", "scale", "rft_force", "arena",
    "iarena",
)
"""The table's arrays, in order; each takes SLOT int64 entries: address, then up to 4 dimensions."""
SLOT = 5
_TAIL = len(FIELDS) * SLOT
"""After the arrays: the mjModel and mjData addresses, nv and the terrain kind."""
TABLE_SIZE = _TAIL + 4
(_XPOS, _XMAT, _XIPOS, _CVEL, _SUBTREE_COM, _QPOS, _QVEL, _CDOF, _QFRC_PASSIVE, _QFRC_BIAS, _QFRC_ACTUATOR,
 _QFRC_APPLIED, _IDS, _ROOT, _BOUND_CENTER, _BOUND_RADIUS, _BODY_ROOTID, _BODY_DOFNUM, _BODY_DOFADR,
 _BODY_PARENTID, _DOF_PARENTID, _SETTINGS, _CENTROIDS, _NORMALS, _AREAS, _CLUSTER_START, _CLUSTER_OCTANT,
 _CLUSTER_CENTER, _CLUSTER_RADIUS, _BODY_CLUSTERS, _TP, _HEIGHTS, _COEF, _TOL, _TOUCH, _BODY_POS, _BODY_MAT,
 _BODY_COM, _V_COM, _OMEGA, _MINV, _EYE, _WARM, _WARM_ROUNDS, _SCRATCH, _GROUPS, _COUNT, _MAX_DEPTH, _COL_V,
 _COL_W, _COL_GROUPS, _COL_COUNT, _COL_MAX_DEPTH, _JAC, _QACC, _LIMITED, _FORCE, _TORQUE, _SUBMERGED,
 _DEPTH_MAX, _SCALE, _RFT_FORCE, _ARENA, _IARENA) = (SLOT * i for i in range(len(FIELDS)))

# Flags (the last argument of the call).
WARM_START, NO_TENSION, NO_FORWARD, NO_POWER = 1, 2, 4, 8
NOT_FINITE_STATE = -1
"""Returned when a body is a broadphase candidate and qpos/qvel are not finite (nothing computed)."""
_STATUS_OFFSET = 4
"""Otherwise the call returns ``k * 8 + status + 4``: k touching bodies (``touch[:k]``), and the status
of :func:`rft_mujoco.fastlimit.stabilized` (0 when k is 0)."""


def decode(code: int) -> tuple[int, int]:
    """(k, status) of a call's return value (not :data:`NOT_FINITE_STATE`)."""
    return code >> 3, (code & 7) - _STATUS_OFFSET


_lock = threading.Lock()
_entry = None            # the ctypes functions, once built
_route_entry = None
_cfunc = _route_cfunc = None
_error: str | None = None


def _library_path() -> str:
    import mujoco
    folder = os.path.dirname(mujoco.__file__)
    names = sorted(n for n in os.listdir(folder)
                   if n.startswith("libmujoco.so") or (n.startswith("libmujoco.") and n.endswith(".dylib"))
                   or n == "mujoco.dll")
    if not names:
        raise OSError(f"no libmujoco shared library in {folder}")
    return os.path.join(folder, names[-1])


try:  # numba is optional (fastkernel.AVAILABLE); without it this module is inert
    import numba
    from numba import types
    from numba.extending import intrinsic
except Exception:  # pragma: no cover - exercised only where numba is missing
    numba = None

if numba is not None:
    _F64P = types.CPointer(types.float64)
    _I64P = types.CPointer(types.int64)
    # Resolved by symbol name when the cfunc is compiled or loaded from the cache (after _build's add_symbol).
    _fwd_actuation = types.ExternalFunction("mj_fwdActuation", types.void(types.voidptr, types.voidptr))
    _solve_m = types.ExternalFunction("mj_solveM", types.void(types.voidptr, types.voidptr, _F64P, _F64P,
                                                              types.intc))

    def _cast(target):
        @intrinsic
        def cast(typingctx, addr):
            def codegen(context, builder, signature, args):
                return builder.inttoptr(args[0], context.get_value_type(target))
            return target(types.int64), codegen
        return cast

    _as_f64, _as_i64, _as_void = _cast(_F64P), _cast(_I64P), _cast(types.voidptr)
    _carray = numba.carray

    @numba.njit(inline="always")
    def _f1(t, s):
        return _carray(_as_f64(t[s]), (t[s + 1],))

    @numba.njit(inline="always")
    def _f2(t, s):
        return _carray(_as_f64(t[s]), (t[s + 1], t[s + 2]))

    @numba.njit(inline="always")
    def _f3(t, s):
        return _carray(_as_f64(t[s]), (t[s + 1], t[s + 2], t[s + 3]))

    @numba.njit(inline="always")
    def _f4(t, s):
        return _carray(_as_f64(t[s]), (t[s + 1], t[s + 2], t[s + 3], t[s + 4]))

    @numba.njit(inline="always")
    def _i1(t, s):
        return _carray(_as_i64(t[s]), (t[s + 1],))

    @numba.njit(inline="always")
    def _i2(t, s):
        return _carray(_as_i64(t[s]), (t[s + 1], t[s + 2]))

    _touching, _stabilized = fastkernel.touching, fastlimit.stabilized
    _user_part, _commit = fastkernel.user_part, fastkernel.commit


def _evaluate(t, user_addr, sand_addr, g_addr, dt, xi_n, mu_surf, max_height, flags):
    """The entry point's body (compiled as a cfunc by :func:`_build`): ``t`` the table, ``user_addr`` /
    ``sand_addr`` the (nbody, 6) user and sand wrench arrays, ``g_addr`` the (3,) gravity direction, ``dt``
    s, ``xi_n`` and ``mu_surf`` the medium's, ``max_height`` m the terrain's, ``flags`` see WARM_START."""
    nbody = t[_XPOS + 1]
    g_hat = _carray(_as_f64(g_addr), (3,))
    kind = t[_TAIL + 3]
    touch = _i1(t, _TOUCH)
    k = _touching(_i1(t, _IDS), _i1(t, _ROOT), _f2(t, _XPOS), _f2(t, _XMAT), _f2(t, _XIPOS), _f2(t, _CVEL),
                  _f2(t, _SUBTREE_COM), _f1(t, _QPOS), _f1(t, _QVEL), _f2(t, _BOUND_CENTER),
                  _f1(t, _BOUND_RADIUS), _f2(t, _CENTROIDS), _i1(t, _CLUSTER_START), _f2(t, _CLUSTER_CENTER),
                  _f1(t, _CLUSTER_RADIUS), _i1(t, _BODY_CLUSTERS), g_hat, max_height, kind, _f1(t, _TP),
                  _f2(t, _HEIGHTS), touch, _f2(t, _BODY_POS), _f2(t, _BODY_MAT), _f2(t, _BODY_COM),
                  _f2(t, _V_COM), _f2(t, _OMEGA))
    if k < 0:
        return NOT_FINITE_STATE
    if k == 0:
        return _STATUS_OFFSET
    m, d, nv = _as_void(t[_TAIL]), _as_void(t[_TAIL + 1]), t[_TAIL + 2]
    _fwd_actuation(m, d)
    if nv > 0:
        _solve_m(m, d, _as_f64(t[_MINV]), _as_f64(t[_EYE]), nv)
    status = _stabilized(
        touch, k, _i1(t, _IDS), _carray(_as_f64(user_addr), (nbody, 6)), _f2(t, _XIPOS), _f2(t, _CDOF),
        _f2(t, _SUBTREE_COM), _f1(t, _QVEL), _f1(t, _QFRC_PASSIVE), _f1(t, _QFRC_BIAS), _f1(t, _QFRC_ACTUATOR),
        _f1(t, _QFRC_APPLIED), _f2(t, _MINV), _i1(t, _BODY_ROOTID), _i1(t, _BODY_DOFNUM), _i1(t, _BODY_DOFADR),
        _i1(t, _BODY_PARENTID), _i1(t, _DOF_PARENTID), dt, _f1(t, _BOUND_RADIUS), _f4(t, _WARM),
        _i1(t, _WARM_ROUNDS), (flags & WARM_START) != 0, _f1(t, _SETTINGS), _f2(t, _CENTROIDS),
        _f2(t, _NORMALS), _f1(t, _AREAS), _i1(t, _CLUSTER_START), _i2(t, _CLUSTER_OCTANT),
        _f2(t, _CLUSTER_CENTER), _f1(t, _CLUSTER_RADIUS), _i1(t, _BODY_CLUSTERS), _f2(t, _BODY_POS),
        _f2(t, _BODY_MAT), _f2(t, _BODY_COM), _f2(t, _V_COM), _f2(t, _OMEGA), g_hat, max_height, kind,
        _f1(t, _TP), _f2(t, _HEIGHTS), xi_n, _f2(t, _COEF), mu_surf, (flags & NO_TENSION) != 0,
        (flags & NO_FORWARD) != 0, (flags & NO_POWER) != 0, _f1(t, _TOL), _f2(t, _SCRATCH), _f3(t, _GROUPS),
        _i1(t, _COUNT), _f1(t, _MAX_DEPTH), _f2(t, _COL_V), _f2(t, _COL_W), _f3(t, _COL_GROUPS),
        _i1(t, _COL_COUNT), _f1(t, _COL_MAX_DEPTH), _f3(t, _JAC), _f1(t, _QACC), _f2(t, _LIMITED),
        _f2(t, _FORCE), _f2(t, _TORQUE), _i1(t, _SUBMERGED), _f1(t, _DEPTH_MAX), _f1(t, _SCALE),
        _f2(t, _RFT_FORCE), _f1(t, _ARENA), _i1(t, _IARENA), _carray(_as_f64(sand_addr), (nbody, 6)))
    return k * 8 + status + _STATUS_OFFSET


if numba is not None:
    _evaluate_nb = numba.njit(_evaluate)


# --- the whole control callback of one (model, MjData) as one native call ------------------------------
ROUTE_DONE, ROUTE_PYTHON = 0, 1
"""Return values of the route call: everything was done natively, or the Python dispatcher must do this
evaluation (nothing was committed)."""
ROUTE_HEAD = 16
"""Entries of a route table before its per-handle blocks."""
ROUTE_HANDLE = 8
"""Entries of one handle's block."""
ROUTE_FLOATS = 3
"""Float entries per handle in the route's float table: xi_n N/m^3, mu_surf, max_height m."""
RK4_STAGE_TIMES = (0.5, 0.5, 1.0)
"""Times of RK4 stages 2-4 after the first, in steps (MuJoCo's mj_RungeKutta tableau): how the dispatcher
and the route recognize a later stage."""


class Slot:
    """An attribute kept in entry ``index`` of the object's numpy array attribute ``array`` (state the
    native route reads and writes too), read back as ``kind``."""

    def __init__(self, array: str, index: int, kind=float, doc: str | None = None) -> None:
        self.array, self.index, self.kind, self.__doc__ = array, index, kind, doc

    def __get__(self, obj, owner=None):
        return self if obj is None else self.kind(getattr(obj, self.array)[self.index])

    def __set__(self, obj, value) -> None:
        getattr(obj, self.array)[self.index] = value


if numba is not None:
    @numba.njit(inline="always")
    def _cold(t):
        """Clear a table's limiter warm start."""
        _i1(t, _WARM_ROUNDS)[:] = 0
        _f4(t, _WARM)[:] = 0.0


def _route(r, time, dt, integrator):
    """The route call's body (compiled as a cfunc by :func:`_build`): the dispatcher's
    ``Dispatcher.__call__`` for one (model, MjData) whose handles all take the native call, on the route
    table ``r`` (see :class:`Route`). Returns :data:`ROUTE_PYTHON`, having committed nothing and counted
    no evaluation, whenever the Python path must run: a monitor check is due, gravity changed, the state
    is not finite or a wrench is not (the Python path then raises, naming the bodies)."""
    n_handles = r[0]
    st = _carray(_as_f64(r[1]), (4,))              # the book: nonzero, sand_dirty, stage, stage_time
    nbody = r[3]
    floats = _carray(_as_f64(r[12]), (n_handles * ROUTE_FLOATS,))
    live_g = _carray(_as_f64(r[11]), (3,))
    for i in range(n_handles):
        b = ROUTE_HEAD + i * ROUTE_HANDLE
        counts = _carray(_as_i64(r[b + 4]), (2,))    # evaluations, monitor every (0: no monitor)
        if counts[1] > 0 and (counts[0] + 1) % counts[1] == 0:
            return ROUTE_PYTHON
        seen = _carray(_as_f64(r[b + 2]), (3,))
        if live_g[0] != seen[0] or live_g[1] != seen[1] or live_g[2] != seen[2]:
            return ROUTE_PYTHON
    if r[10] != 0 and integrator == r[13]:            # every handle holds the first RK4 stage's wrench
        n = int(st[2])
        if 1 <= n <= 3 and abs(time - (st[3] + RK4_STAGE_TIMES[n - 1] * dt)) <= 1e-9 * dt:
            st[2] = n + 1
            return ROUTE_DONE
        st[3] = time
        st[2] = 1
    else:
        st[2] = 0
    xfrc = _carray(_as_f64(r[2]), (nbody, 6))
    written = _carray(_as_f64(r[4]), (nbody, 6))
    added = _carray(_as_f64(r[5]), (nbody, 6))
    rows = _carray(_as_i64(r[6]), (r[7],))
    user = _carray(_as_f64(r[8]), (nbody, 6))
    sand = _carray(_as_f64(r[9]), (nbody, 6))
    nonzero = st[0] != 0.0
    if nonzero:
        _user_part(xfrc, written, added, rows, user)
        user_addr = r[8]
    else:
        user_addr = r[2]
    if st[1] != 0.0:
        sand[:] = 0.0
    st[1] = 1.0
    any_sand = False
    for i in range(n_handles):
        b = ROUTE_HEAD + i * ROUTE_HANDLE
        t = _carray(_as_i64(r[b]), (TABLE_SIZE,))
        ws = _carray(_as_f64(r[b + 5]), (2,))        # the workspace: clean, last_time
        if not 0.0 <= time - ws[1] <= dt * (1.0 + 1e-9):       # coupling._follow_time
            _cold(t)
        ws[1] = time
        code = _evaluate_nb(t, user_addr, r[9], r[b + 1], dt, floats[i * ROUTE_FLOATS],
                            floats[i * ROUTE_FLOATS + 1], floats[i * ROUTE_FLOATS + 2], r[b + 3])
        if code == NOT_FINITE_STATE:
            return ROUTE_PYTHON
        k = code >> 3
        status = (code & 7) - _STATUS_OFFSET
        if k == 0:
            if ws[0] == 0.0:                          # coupling._nothing_touches
                _f2(t, _FORCE)[:] = 0.0
                _f2(t, _TORQUE)[:] = 0.0
                _i1(t, _SUBMERGED)[:] = 0
                _f1(t, _DEPTH_MAX)[:] = 0.0
                _f1(t, _SCALE)[:] = 1.0
                _f2(t, _RFT_FORCE)[:] = 0.0
                _cold(t)
                ws[0] = 1.0
        else:
            ws[0] = 0.0
            if status < 0:
                return ROUTE_PYTHON
            if status != 0:
                any_sand = True
    for i in range(n_handles):
        _carray(_as_i64(r[ROUTE_HEAD + i * ROUTE_HANDLE + 4]), (2,))[0] += 1
    if not any_sand and not nonzero:
        st[1] = 0.0
        return ROUTE_DONE
    _commit(xfrc, user, sand, rows, added, written)
    st[0] = 1.0 if any_sand else 0.0
    return ROUTE_DONE


def _build():
    """Give LLVM the two MuJoCo symbols, compile (or load from numba's cache) the cfunc; return it as a
    ctypes function."""
    import llvmlite.binding as llvm

    lib = ctypes.CDLL(_library_path())
    for name in ("mj_fwdActuation", "mj_solveM"):
        llvm.add_symbol(name, ctypes.cast(getattr(lib, name), ctypes.c_void_p).value)
    sig = types.int64(_I64P, types.int64, types.int64, types.int64, types.float64, types.float64, types.float64,
                      types.float64, types.int64)
    compiled = numba.cfunc(sig, cache=True, nopython=True)(_evaluate)
    proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
                             ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_int64)
    routed = numba.cfunc(types.int64(_I64P, types.float64, types.float64, types.int64), cache=True,
                         nopython=True)(_route)
    route_proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                   ctypes.c_int64)
    global _cfunc, _route_cfunc, _route_entry
    _cfunc, _route_cfunc = compiled, routed      # own the machine code the ctypes functions point to
    _route_entry = route_proto(routed.address)
    return proto(compiled.address)


def build() -> None:
    """Build the entry point now (called by :func:`rft_mujoco.fastkernel.ensure_compiled`, inside its
    compile notice); a failure is kept in :func:`error`, not raised."""
    global _entry, _error
    with _lock:
        if _entry is None and _error is None:
            try:
                if numba is None:
                    raise ImportError(f"numba is not available ({fastkernel.IMPORT_ERROR})")
                _entry = _build()
            except Exception as exc:  # no libmujoco, no cfunc support: the dispatch path stays
                _error = f"{type(exc).__name__}: {exc}"


def entry():
    """The native entry point (a ctypes function), built on first use; None when it cannot be built
    (:func:`error` says why)."""
    if _entry is None and _error is None:
        fastkernel.ensure_compiled()      # builds it with the other kernels
        build()                           # (a no-op unless ensure_compiled had run before this module)
    return _entry


def available() -> bool:
    """Whether the native entry point can be used (builds it on first call)."""
    return entry() is not None


def error() -> str | None:
    """Why :func:`available` is False (None when it is True or was not asked yet)."""
    return _error


class Table:
    """The argument table of one (handle, MjData) pair; keeps every array it points to alive."""

    __slots__ = ("ints", "arrays", "address", "source")

    def __init__(self, arrays: dict, model, data, kind: int, source) -> None:
        missing = set(FIELDS) - set(arrays)
        if missing:
            raise KeyError(f"native table lacks {sorted(missing)}")
        ints = np.zeros(TABLE_SIZE, dtype=np.int64)
        kept = []
        for i, name in enumerate(FIELDS):
            a = arrays[name]
            if a.dtype not in (np.float64, np.int64) or not a.flags.c_contiguous or a.ndim > SLOT - 1:
                raise TypeError(f"native table: {name} must be a C-contiguous float64/int64 array of at most "
                                f"{SLOT - 1} dimensions, got {a.dtype} {a.shape}")
            kept.append(a)
            ints[i * SLOT] = a.ctypes.data
            ints[i * SLOT + 1:i * SLOT + 1 + a.ndim] = a.shape
        ints[_TAIL:] = (model._address, data._address, model.nv, kind)
        self.ints = ints
        self.arrays = kept
        self.address = ints.ctypes.data
        self.source = source          # what the table was built from (rebuilt when it changes)


class Route:
    """The route table of one (model, MjData): what ``Dispatcher.__call__`` reads and writes, for a model
    whose every handle takes the native call (keeps every array it points to alive).

    Layout (int64): 0 the number of handles H; 1 the book's state (float64: nonzero, sand_dirty, RK4 stage,
    RK4 stage time s); 2 ``xfrc_applied``; 3 nbody; 4, 5 the book's ``written`` and ``added``; 6, 7 the
    route's body rows and their count; 8, 9 the book's user and sand buffers; 10 whether every handle
    holds the first RK4 stage; 11 the model's live gravity (3,); 12 the float table (H x ROUTE_FLOATS);
    13 MuJoCo's id of the RK4 integrator.
    Then per handle (ROUTE_HANDLE entries from ROUTE_HEAD): its native :class:`Table`, its gravity
    direction (3,), the gravity it was computed from (3,), its flag word, its evaluation counter (int64:
    evaluations, monitor period or 0), its workspace's state (float64: clean, last time s).
    """

    __slots__ = ("ints", "floats", "keep", "address")

    def __init__(self, book: dict, handles: list[dict], all_first: bool, gravity: np.ndarray) -> None:
        import mujoco
        keep = []

        def address(a, dtype, shape=None):
            if a.dtype != dtype or not a.flags.c_contiguous or (shape is not None and a.shape != shape):
                raise TypeError(f"native route: expected a C-contiguous {np.dtype(dtype)} array of shape "
                                f"{shape}, got {a.dtype} {a.shape}")
            keep.append(a)
            return a.ctypes.data

        nbody = book["xfrc"].shape[0]
        ints = np.zeros(ROUTE_HEAD + ROUTE_HANDLE * len(handles), dtype=np.int64)
        floats = np.zeros(ROUTE_FLOATS * len(handles))
        ints[:ROUTE_HEAD - 2] = (
            len(handles), address(book["state"], np.float64, (4,)), address(book["xfrc"], np.float64),
            nbody, address(book["written"], np.float64, (nbody, 6)), address(book["added"], np.float64, (nbody, 6)),
            address(book["rows"], np.int64), book["rows"].size, address(book["user"], np.float64, (nbody, 6)),
            address(book["sand"], np.float64, (nbody, 6)), int(all_first), address(gravity, np.float64, (3,)),
            address(floats, np.float64), int(mujoco.mjtIntegrator.mjINT_RK4))
        for i, h in enumerate(handles):
            table = h["table"]
            keep.append(table)
            ints[ROUTE_HEAD + i * ROUTE_HANDLE:ROUTE_HEAD + (i + 1) * ROUTE_HANDLE] = (
                table.address, address(h["g_hat"], np.float64, (3,)), address(h["gravity"], np.float64, (3,)),
                h["flags"], address(h["counts"], np.int64, (2,)), address(h["state"], np.float64, (2,)), 0, 0)
            floats[i * ROUTE_FLOATS:(i + 1) * ROUTE_FLOATS] = (h["xi_n"], h["mu_surf"], h["max_height"])
        self.ints, self.floats, self.keep = ints, floats, keep
        self.address = ints.ctypes.data


def route_entry():
    """The route call (a ctypes function ``(route address, time s, timestep s, integrator) -> int``), or
    None when the native entry points cannot be built."""
    return _route_entry if entry() is not None else None


def flags(warm_start: bool, guards: law.Guards) -> int:
    """The call's flag word."""
    return ((WARM_START if warm_start else 0) | (NO_TENSION if guards.no_tension else 0)
            | (NO_FORWARD if guards.no_forward_tangential else 0) | (NO_POWER if guards.no_positive_power else 0))
