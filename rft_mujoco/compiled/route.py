"""Every sand handle of one (model, MjData) as one native call per phase: the dispatcher's fast route.

The dispatcher (:mod:`rft_mujoco.coupling.dispatch`) keeps its Python callback, so that errors still raise
from ``mj_step``; inside it, an evaluation of a model whose handles all run compiled is two calls of C
functions (numba ``cfunc`` s) through ctypes, each with one pointer to a table of the arrays' addresses and
shapes (built once per MjData: MjData's arrays and the buffers never move):

1. :func:`phase1`: the user's part of ``xfrc_applied`` (:func:`user_part`), every handle's broadphase;
   with nothing touching, the user's rows are restored and the evaluation is done;
2. (the dispatcher runs ``mj_fwdActuation`` when a stabilized handle touches; MuJoCo computes actuator
   forces only after ``mjcb_control``) :func:`phase2`: every handle's evaluation into the sand sum, and
   :func:`commit` writes ``xfrc_applied = user + sand``.

Nothing here calls MuJoCo, and the compiled functions are those of the Python path
(:mod:`rft_mujoco.compiled.evaluate`), so both give the same numbers bit for bit (tests/test_route.py).
A phase hands back to Python, having committed nothing, on an error (the Python path then raises,
naming the bodies) and after committing when a handle's validity monitor is due.

What it relies on is checked where the table is built (:class:`Route`): every array C-contiguous of the
dtype its schema says (MuJoCo's ``mjtNum`` must be float64), no other Python callback between.
"""

from __future__ import annotations

import ctypes
import logging
import sys
import threading

import numpy as np

from rft_mujoco.compiled import evaluate as ev
from rft_mujoco.compiled import table
from rft_mujoco.compiled.jit import AVAILABLE, INLINE, JIT, carray, cfunc, njit, types
from rft_mujoco.compiled.table import SLOT
from rft_mujoco.compiled import schema as sc

DONE, ACTUATE, CONTINUE, PYTHON, MONITOR = (int(sc.Phase.DONE), int(sc.Phase.ACTUATE), int(sc.Phase.CONTINUE),
                                            int(sc.Phase.PYTHON), int(sc.Phase.MONITOR))
"""Phase results (:class:`rft_mujoco.compiled.schema.Phase`) as the kernels' ints."""
BOOK_FIELDS = (("xfrc", "f2"), ("written", "f2"), ("added", "f2"), ("rows", "i1"), ("user", "f2"),
               ("sand", "f2"), ("state", "f1"), ("snapshot", "f1"), ("gravity", "f1"), ("geom_size", "f2"))
"""The dispatcher's per-MjData book (:class:`rft_mujoco.coupling.dispatch._DataBook`); ``state`` =
(nonzero, sand_dirty, rk4 stage (1-4; 0: another integrator), rk4 stage time, TIME_RTOL, what the native
callback left to Python); ``snapshot``: the model's timestep, gravity and ``geom_size`` the dispatcher last
checked (:func:`model_changed`), ``gravity`` and ``geom_size`` live views of the model's."""
_HEADER = len(sc.TABLE_HEADER)
BOOK_STATE = [name for name, _ in BOOK_FIELDS].index("state")
"""The index of the book's ``state`` among :data:`BOOK_FIELDS`."""
"""Table header: number of handles, base of the book, base of md, base of the constraint rows, the address of
:func:`rest_phase`'s C function, that of the implicit solve's (:func:`rft_mujoco.compiled.implicit_route.
implicit_phase`; 0 when no handle has ``solve="implicit"``), the table's length, the address of the deformable
surface's grid update (:func:`rft_mujoco.compiled.deform_route.press_phase`; 0 when no handle's terrain is
deformable); then one base per handle, one base per handle of its implicit part (0: an explicit handle), one
base per handle of its press part (0: a terrain that is not deformable)."""
EFC_POINTERS = ("efc_type", "efc_id", "efc_D", "efc_aref", "efc_frictionloss", "qacc")
"""The ``mjData`` pointers of the ``fr`` tuple (:data:`rft_mujoco.compiled.evaluate.FRICTION_FIELDS`)."""
JAC_POINTERS = ("efc_J", "efc_J_rowadr", "efc_J_rownnz", "efc_J_colind")
"""The ``mjData`` pointers of the constraint Jacobian (the implicit solve's, after those of ``fr``)."""


@njit(**JIT)
def user_part(xfrc, written, added, rows, user):
    """The dispatcher's user wrench (nbody, 6) into ``user``: ``xfrc`` with the sand ``added`` last time
    taken out of the components of rows ``rows`` the user left alone (the rule of
    :func:`rft_mujoco.coupling.dispatch.untouched_components`). Copied element by element: ``user[:] = xfrc``
    compiles numba's broadcasting assignment and its error messages, 8 of the first use's CPU s (measured)."""
    for r in range(xfrc.shape[0]):
        for k in range(6):
            user[r, k] = xfrc[r, k]
    for r in rows:
        whole = True
        for k in range(6):
            whole = whole and xfrc[r, k] == written[r, k]
        for k in range(6):
            if xfrc[r, k] == written[r, k] and (whole or written[r, k] != 0.0):
                user[r, k] -= added[r, k]


@njit(**JIT)
def model_changed(snapshot, dt, gravity, geom_size):
    """Whether ``dt`` (s), ``gravity`` (3,) m/s^2 or ``geom_size`` (ngeom, 3) m differ from ``snapshot``
    ((4 + 3 ngeom,): timestep, gravity, geom_size as the dispatcher last checked them; NaN never equals)."""
    if snapshot.shape[0] != 4 + 3 * geom_size.shape[0] or not dt == snapshot[0]:
        return True
    for k in range(3):
        if not gravity[k] == snapshot[1 + k]:
            return True
    i = 4
    for g in range(geom_size.shape[0]):
        for k in range(3):
            if not geom_size[g, k] == snapshot[i]:
                return True
            i += 1
    return False


@njit(**JIT)
def commit(xfrc, user, sand, rows, added, written):
    """The dispatcher's write: ``xfrc[rows] = user + sand``, remembering what was added and written."""
    added[:] = 0.0
    for r in rows:
        for k in range(6):
            v = user[r, k] + sand[r, k]
            xfrc[r, k] = v
            added[r, k] = sand[r, k]
            written[r, k] = v


if AVAILABLE:
    from llvmlite import ir
    from numba.extending import intrinsic

    def _cast(target):
        @intrinsic
        def cast(typingctx, addr):
            def codegen(context, builder, signature, args):
                return builder.inttoptr(args[0], context.get_value_type(target))
            return target(types.int64), codegen
        return cast

    @intrinsic
    def _call_rest(typingctx, fn, table, base, dt):
        """Call :func:`rest_phase`'s C function (or the implicit solve's, of the same signature) at address
        ``fn``: through the address, so that phase 2's machine code does not contain (and compile) it: it
        compiles beside, in a second process when cold."""
        def codegen(context, builder, signature, args):
            i64, f64 = ir.IntType(64), ir.DoubleType()
            fnty = ir.FunctionType(i64, [i64.as_pointer(), i64, f64])
            return builder.call(builder.inttoptr(args[0], fnty.as_pointer()), [args[1], args[2], args[3]])
        return types.int64(types.int64, types.CPointer(types.int64), types.int64, types.float64), codegen

    _as_f8 = _cast(types.CPointer(types.float64))
    _as_i8 = _cast(types.CPointer(types.int64))
    _as_i4 = _cast(types.CPointer(types.int32))
    _as_b1 = _cast(types.CPointer(types.boolean))
else:  # pragma: no cover - without numba the route is never built
    _as_f8 = _as_i8 = _as_i4 = _as_b1 = _call_rest = None


if AVAILABLE:
    _f1, _f2, _i1, _i2, _b1, _j1, _j2, _f3 = (table.loader([("", k)], one=True)
                                              for k in ("f1", "f2", "i1", "i2", "b1", "j1", "j2", "f3"))
    _md = table.viewer(ev.MJDATA_FIELDS)
    """The ``md`` arguments (:data:`~rft_mujoco.compiled.evaluate.MJDATA_FIELDS`) at ``base``, a view."""
    _hc = table.viewer(ev.HANDLE_FIELDS)
    """The ``hc`` arguments at ``base``, a view."""
    _ws = table.viewer(ev.WORK_FIELDS)
    """The ``ws`` arguments at ``base``, a view."""
    _book = table.loader(BOOK_FIELDS)
    """The book's arrays (:data:`BOOK_FIELDS`), a tuple."""
else:  # pragma: no cover - without numba the route is never built
    _f1 = _f2 = _i1 = _i2 = _b1 = _j1 = _j2 = _f3 = _md = _hc = _ws = _book = None


@njit(**INLINE)
def _fr(t, base, nv):
    """The ``fr`` tuple from ``mjData`` now (its constraint rows move in the arena with every step)."""
    d = t[base]
    nefc = carray(_as_i4(d + t[base + 1]), (1,))[0]
    p = carray(_as_i8(d + t[base + 2]), (1,))[0]
    efc_type = carray(_as_i4(p), (nefc,))
    p = carray(_as_i8(d + t[base + 3]), (1,))[0]
    efc_id = carray(_as_i4(p), (nefc,))
    p = carray(_as_i8(d + t[base + 4]), (1,))[0]
    efc_d = carray(_as_f8(p), (nefc,))
    p = carray(_as_i8(d + t[base + 5]), (1,))[0]
    efc_aref = carray(_as_f8(p), (nefc,))
    p = carray(_as_i8(d + t[base + 6]), (1,))[0]
    efc_floss = carray(_as_f8(p), (nefc,))
    p = carray(_as_i8(d + t[base + 7]), (1,))[0]
    return efc_type, efc_id, efc_d, efc_aref, efc_floss, carray(_as_f8(p), (nv,))


_HC_SLOTS = len(ev.HANDLE_FIELDS) * SLOT
_PARAMS = [name for name, _ in ev.HANDLE_FIELDS].index("params") * SLOT
_RK4_EVALUATED = ev.PARAMS.index("rk4_evaluated")
_MONITOR_EVERY = ev.PARAMS.index("monitor_every")
_STABILIZE = ev.PARAMS.index("stabilize")
_STATE = _HC_SLOTS + [name for name, _ in ev.WORK_FIELDS].index("state") * SLOT


@njit(**JIT)
def rk4_evaluated(t):
    """The leading RK4 stages at which the route evaluates the sand: the most that any of its handles asks
    for (``attach(rk4_stages=)``: 4, 2 or 1); 4 without handles."""
    n = t[sc.T_HANDLES]
    most = 1.0 if n > 0 else 4.0
    for h in range(n):
        most = max(most, _f1(t, t[_HEADER + h] + _PARAMS)[_RK4_EVALUATED])
    return most


@njit(**INLINE)
def _table(ptr):
    """The table at ``ptr`` (its length from its header)."""
    return carray(ptr, (carray(ptr, (_HEADER,))[sc.T_LENGTH],))


def phase1(ptr, time, dt):
    """User part and every handle's broadphase (see the module docstring) on the table at ``ptr``; returns
    DONE, ACTUATE, CONTINUE or PYTHON (also when the model's timestep, gravity or geom sizes changed:
    :func:`model_changed`). A C function (:func:`cfuncs`), compiled only as such: one compile, not two."""
    t = _table(ptr)
    n = t[sc.T_HANDLES]
    xfrc, written, added, rows, user, sand, state, snapshot, gravity, geom_size = _book(t, t[sc.T_BOOK])
    if model_changed(snapshot, dt, gravity, geom_size):
        return PYTHON
    md = _md(t, t[sc.T_MD])
    user_part(xfrc, written, added, rows, user)
    total = 0
    actuate = False
    for h in range(n):
        base = t[_HEADER + h]
        hc = _hc(t, base)
        ws = _ws(t, base + _HC_SLOTS)
        ws[sc.W_STATE][sc.S_RK4_STAGE] = state[sc.B_RK4_STAGE]   # the RK4 stage (0: another integrator)
        k = ev.broadphase(md, hc, ws, time, dt)
        if k < 0:
            return PYTHON
        if k > 0:
            total += k
            actuate = actuate or hc[sc.H_PARAMS][sc.P_STABILIZE] != 0.0
    if total == 0:
        if state[sc.B_NONZERO] != 0.0:                  # the sand of the last evaluation leaves the rows
            for r in rows:
                for c in range(6):
                    xfrc[r, c] = user[r, c]
                    added[r, c] = 0.0
                    written[r, c] = user[r, c]
            state[sc.B_NONZERO] = 0.0
        return DONE
    return ACTUATE if actuate else CONTINUE


def phase2(ptr, time, dt):
    """Every touching handle's evaluation and the commit, on the table at ``ptr``; returns DONE, MONITOR or
    PYTHON. A C function (:func:`cfuncs`)."""
    t = _table(ptr)
    n = t[sc.T_HANDLES]
    xfrc, written, added, rows, user, sand, state, _, _, _ = _book(t, t[sc.T_BOOK])
    md = _md(t, t[sc.T_MD])
    sand[:] = 0.0
    state[sc.B_SAND_DIRTY] = 1.0                     # the Python path zeroes ``sand`` before use
    nonzero = False
    for h in range(n):
        base = t[_HEADER + h]
        ws = _ws(t, base + _HC_SLOTS)
        if ws[sc.W_STATE][sc.S_TOUCHING] <= 0.0:
            continue
        if t[_HEADER + n + h] != 0:
            status = _call_rest(t[sc.T_IMPLICIT_PHASE], ptr, h, dt)             # implicit_route.implicit_phase
        elif _f1(t, base + _PARAMS)[_STABILIZE] != 0.0:
            status = _call_rest(t[sc.T_REST_PHASE], ptr, base, dt)
        else:
            status = ev.evaluate_naive(md, _hc(t, base), ws, sand)
        if status < 0:
            return PYTHON
        nonzero = nonzero or status == 1
        if t[_HEADER + 2 * n + h] != 0 and ws[sc.W_STATE][sc.S_RK4_STAGE] < 2.0:
            _call_rest(t[sc.T_PRESS_PHASE], ptr, h, time)                    # deform_route.press_phase: the grid update
    commit(xfrc, user, sand, rows, added, written)
    state[sc.B_NONZERO] = 1.0 if nonzero else 0.0
    for h in range(n):
        base = t[_HEADER + h]
        every = _f1(t, base + _PARAMS)[_MONITOR_EVERY]       # (not the whole hc, ws tuples: less to compile)
        st = _f1(t, base + _STATE)
        if every > 0.0 and st[sc.S_TOUCHING] > 0.0 and st[sc.S_EVALUATIONS] % every == 0.0:
            return MONITOR
    return DONE


def rest_phase(ptr, base, dt):
    """Phase 2 of the handle at ``base`` with the rest treatment (:func:`~rft_mujoco.compiled.evaluate.evaluate_rest`)
    on the table at ``ptr``; the evaluation's status. A C function of its own that phase 2 calls through its
    address (``t[T_REST_PHASE]``): half of phase 2's compile, done beside it (:mod:`rft_mujoco.compiled.warmup`)."""
    t = _table(ptr)
    _, _, _, _, user, sand, _, _, _, _ = _book(t, t[sc.T_BOOK])
    md = _md(t, t[sc.T_MD])
    fr = _fr(t, t[sc.T_ROWS], md[sc.M_QVEL].shape[0])
    return ev.evaluate_rest(md, _hc(t, base), _ws(t, base + _HC_SLOTS), user, dt, sand, fr)


_SIG = types.int64(types.CPointer(types.int64), types.float64, types.float64) if AVAILABLE else None
"""The C signature of both phases: (table address, time s, dt s) -> phase result."""
_REST_SIG = types.int64(types.CPointer(types.int64), types.int64, types.float64) if AVAILABLE else None
"""The C signature of :func:`rest_phase`: (table address, handle base, dt s) -> status."""


_CTYPE = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_double, ctypes.c_double)
_entries: list = []
_cfuncs: dict = {}
_entries_lock = threading.Lock()


def cfunc_of(which: str):
    """``"phase1"``, ``"phase2"`` or ``"rest_phase"`` as a numba ``cfunc``, compiled (or loaded from the cache) on
    first use rather than at import, so that importing the package compiles nothing.
    :mod:`~rft_mujoco.compiled.warmup` compiles ``rest_phase`` in a second process when cold."""
    with _entries_lock:
        if which not in _cfuncs:
            _cfuncs[which] = cfunc(_REST_SIG if which == "rest_phase" else _SIG, cache=True)(globals()[which])
        return _cfuncs[which]


def cfuncs() -> tuple:
    """(phase1, phase2, rest_phase) as numba ``cfunc`` s (:func:`cfunc_of`;
    :func:`rft_mujoco.compiled.ensure_compiled` calls this while it reports the compile)."""
    c1, c2, c3 = cfunc_of("phase1"), cfunc_of("phase2"), cfunc_of("rest_phase")
    with _entries_lock:
        if not _entries:
            _entries.extend([c1, c2, c3, _CTYPE(c1.address), _CTYPE(c2.address)])
        return tuple(_entries[:3])


def entries():
    """(phase1, phase2) as ctypes functions (address, time s, dt s) -> int."""
    cfuncs()
    return tuple(_entries[3:])


_DTYPES = {"f": np.float64, "i": np.int64, "b": np.bool_, "j": np.int32}


_layout = None
_POINTERS = EFC_POINTERS + JAC_POINTERS


def efc_layout() -> dict:
    """Offsets in ``mjData`` of ``nefc`` and of the pointers :data:`EFC_POINTERS` and :data:`JAC_POINTERS`, found on private models
    and verified by reading their rows back (mujoco 4.0's layout: ``nefc`` among the sizes just before
    ``time``, the pointers after ``qpos``'s). Raises RuntimeError where they cannot be located: the route
    is then not built, and the Python path computes the same forces."""
    global _layout
    if _layout is None:
        _layout = _find_layout()
    if isinstance(_layout, str):
        raise RuntimeError(_layout)
    return _layout


def layout_available() -> bool:
    """Whether the native route can read MuJoCo's constraint rows here (else the Python path runs; said once)."""
    try:
        efc_layout()
    except RuntimeError as exc:
        say_once(str(exc), f"rft_mujoco: native sand route unavailable ({exc}); every evaluation takes "
                           "the compiled Python path (same forces, a few us more per evaluation)")
        return False
    return True


_noticed: list = []


def say_once(reason: str, msg: str | None = None) -> None:
    """Say once per process why the native callbacks (or, with ``msg``, the native route) are off."""
    if not _noticed:
        _noticed.append(reason)
        msg = msg or (f"rft_mujoco: native sand callbacks unavailable ({reason}); using the Python callback "
                      "(same forces, ~2 us more per evaluation)")
        logging.getLogger("rft_mujoco").info(msg)   # (a warning would be printed twice by logging's last resort)
        print(msg, file=sys.stderr, flush=True)


def _layout_data(k: int):
    """A data with a connect (3 rows), ``k`` frictionloss hinges and a contact, after ``mj_forward``."""
    import mujoco
    chain = "".join(f"<body name='l{i}' pos='0 0 -0.1'><joint type='hinge' axis='0 1 0' frictionloss='0.{i + 1}'/>"
                    "<geom type='capsule' size='.01' fromto='0 0 0 0 0 -.1'/>" for i in range(k)) + "</body>" * k
    xml = ("<mujoco><worldbody><geom type='plane' size='1 1 .1'/><body pos='0 0 .009'><freejoint/>"
           f"<geom size='.01'/></body><body pos='0 0 1'>{chain}</body></worldbody>"
           f"<equality><connect body1='l{k - 1}' anchor='0 0 -.1'/></equality></mujoco>")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def _find_layout():
    import ctypes
    i64 = lambda a: ctypes.c_int64.from_address(a).value      # noqa: E731
    i32 = lambda a: ctypes.c_int32.from_address(a).value      # noqa: E731
    datas = [_layout_data(k)[1] for k in (2, 4, 5)]
    if len({d.nefc for d in datas}) != 3 or min(d.ncon for d in datas) < 1:
        return "the layout models do not have the constraint rows expected"
    found = None
    for d in datas:
        base = d._address
        energy = d.energy.ctypes.data - base
        nefc = {o for o in range(energy - 4, energy - 257, -4) if i32(base + o) == d.nefc}
        qpos, o = d.qpos.ctypes.data, 0
        while i64(base + o) != qpos:                   # the first pointer field (inside the struct)
            o += 8
            if o > 1 << 22:
                return "cannot locate mjData.qpos"
        want = {getattr(d, name).ctypes.data: name for name in _POINTERS}
        if len(want) != len(_POINTERS):
            return "the layout model's constraint arrays share addresses"
        ptrs = {}
        while len(ptrs) < len(want) and o < (1 << 22):
            v = i64(base + o)
            if v in want and want[v] not in ptrs:
                ptrs[want[v]] = o
            o += 8
        mine = (frozenset(nefc), tuple(sorted(ptrs.items())))
        found = mine if found is None else (found[0] & mine[0], found[1] if found[1] == mine[1] else None)
        if found[1] is None:
            return "mjData's constraint pointers are not where this module looks for them"
    if len(found[0]) != 1 or len(found[1]) != len(_POINTERS):
        return "cannot locate mjData.nefc"
    layout = dict(found[1], nefc=next(iter(found[0])))
    model, data = _layout_data(3)                      # read back through the offsets
    base = data._address
    ok = i32(base + layout["nefc"]) == data.nefc
    for name in _POINTERS:
        ok = ok and i64(base + layout[name]) == getattr(data, name).ctypes.data
    return layout if ok else "mjData's constraint offsets do not read back"


class Route:
    """The table of one (model, MjData) and its handles, and the two calls.

    Args:
        book: (name -> array) of :data:`BOOK_FIELDS`.
        md: the ``md`` tuple; handles: [(hc tuple, ws tuple, implicit part, press part)] in the dispatcher's
            order, the implicit part None or [(name, kind, array)] (:func:`rft_mujoco.compiled.implicit_route.
            table_part`), the press part None or the same (:func:`rft_mujoco.compiled.deform_route.table_part`).
        data: the MjData (its constraint rows are read through its pointers, :func:`efc_layout`).
        implicit_address: the implicit solve's C function (needed when a handle has an implicit part).
        press_address: the grid update's C function (needed when a handle has a press part).
    Raises:
        TypeError: an array is not C-contiguous or not of its schema's dtype and rank (say which).
        RuntimeError: the constraint rows cannot be located in this MuJoCo build (:func:`efc_layout`).
    """

    def __init__(self, book: dict, md: tuple, handles: list, data, implicit_address: int = 0,
                 press_address: int = 0) -> None:
        layout = efc_layout()
        entries_ = []
        self._keep = []

        def add(array, name, kind):
            a = array
            want = _DTYPES[kind[0]]
            if not (isinstance(a, np.ndarray) and a.dtype == want and a.ndim == int(kind[1])
                    and a.flags.c_contiguous and a.flags.writeable):
                raise TypeError(f"the native route needs {name} as a writable C-contiguous {np.dtype(want)} array "
                                f"of rank {kind[1]}, got {type(a).__name__} {getattr(a, 'dtype', '')} "
                                f"{getattr(a, 'shape', '')}")
            self._keep.append(a)
            shape = list(a.shape) + [0] * (3 - a.ndim)
            entries_.extend([a.ctypes.data, *shape])

        n = len(handles)
        book_base = _HEADER + 3 * n
        for name, kind in BOOK_FIELDS:
            add(book[name], name, kind)
        md_base = book_base + len(BOOK_FIELDS) * SLOT
        for (name, kind), a in zip(ev.MJDATA_FIELDS, md):
            add(a, name, kind)
        efc_base = book_base + len(entries_)
        entries_.extend([data._address, layout["nefc"], *(layout[name] for name in _POINTERS)])
        bases, implicit_bases, press_bases = [], [], []
        for hc, ws, implicit, press in handles:
            bases.append(book_base + len(entries_))
            for (name, kind), a in zip(ev.HANDLE_FIELDS, hc):
                add(a, name, kind)
            for (name, kind), a in zip(ev.WORK_FIELDS, ws):
                add(a, name, kind)
            for part, part_bases in ((implicit, implicit_bases), (press, press_bases)):
                part_bases.append(0 if part is None else book_base + len(entries_))
                for name, kind, a in part or ():
                    add(a, name, kind)
        if any(implicit_bases) and not implicit_address:
            raise ValueError("a handle with an implicit part needs the implicit solve's C function")
        if any(press_bases) and not press_address:
            raise ValueError("a handle with a press part needs the grid update's C function")
        rest = cfuncs()[2].address
        head = dict(handles=n, book=book_base, md=md_base, rows=efc_base, rest_phase=rest,
                    implicit_phase=implicit_address, length=book_base + len(entries_), press_phase=press_address)
        self.table = np.array([*(head[name] for name in sc.TABLE_HEADER), *bases, *implicit_bases, *press_bases,
                               *entries_], dtype=np.int64)
        self.address = self.table.ctypes.data
        self.phase1, self.phase2 = entries()


def warm_up(model, data) -> None:
    """Compile both phases (a route over no handle)."""
    nbody = model.nbody
    book = dict(xfrc=np.zeros((nbody, 6)), written=np.zeros((nbody, 6)), added=np.zeros((nbody, 6)),
                rows=np.zeros(0, np.int64), user=np.zeros((nbody, 6)), sand=np.zeros((nbody, 6)),
                state=np.zeros(len(sc.BOOK_STATE)),
                snapshot=snapshot(model), gravity=model.opt.gravity, geom_size=model.geom_size)
    route = Route(book, ev.mjdata_arrays(data), [], data)
    route.phase1(route.address, 0.0, 0.001)
    route.phase2(route.address, 0.0, 0.001)


def snapshot(model) -> np.ndarray:
    """(4 + 3 ngeom,) the model's timestep (s), gravity (m/s^2) and ``geom_size`` (m) now (:func:`model_changed`)."""
    return np.concatenate([[model.opt.timestep], model.opt.gravity, model.geom_size.ravel()])
