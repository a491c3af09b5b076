"""The implicit solve on the native route: one C function per evaluation of a ``solve="implicit"`` handle.

The route (:mod:`rft_mujoco.compiled.route`) runs every handle of a (model, MjData) in two native phases;
phase 2 calls :func:`implicit_phase` through its address (the table's header, ``t[T_IMPLICIT_PHASE]``) for each touching
handle with ``solve="implicit"``, as it calls ``route.rest_phase`` for the explicit solve. It runs what the
dispatcher's Python path runs (:func:`rft_mujoco.coupling.implicit.evaluate_compiled`): the dofs' implicit
damping from the model now (:func:`rft_mujoco.compiled.system.velocity_damping`), then
:func:`rft_mujoco.compiled.implicit_eval.evaluate_implicit` on the same arrays, so both give the same
numbers bit for bit (tests/test_native.py).

The handle's part of the table (:func:`table_part`, at ``t[_HEADER + n + h]``; 0 for an explicit handle):
the ``iw`` buffers (:data:`rft_mujoco.compiled.implicit_eval.IMPLICIT_FIELDS`), then :data:`EXTRA_FIELDS`:
the damping's buffer, the solve's settings, ``data.M`` (MuJoCo's sparse mass matrix: in MjData's buffer, it
never moves), ``flags`` ([linearized]), the model arrays the damping is computed from (live views, so that
edits are followed) and int32 views of ``model.opt.integrator`` and ``model.opt.jacobian`` (read at every
evaluation: an edit of either after attach is followed, as on the Python path, which calls
``mj_isSparse``). The constraint Jacobian's rows are read through the ``mjData`` pointers located by
:func:`rft_mujoco.compiled.route.efc_layout`, as the friction rows of the explicit solve are.
"""

from __future__ import annotations

import ctypes
import threading

import mujoco
import numpy as np

from rft_mujoco.compiled import implicit_eval as ie
from rft_mujoco.compiled import route as rt
from rft_mujoco.compiled import table
from rft_mujoco.compiled.system import velocity_damping
from rft_mujoco.compiled.jit import INLINE, carray, cfunc, njit
from rft_mujoco.compiled import schema as sc

EXTRA_FIELDS = (("damping", "f1"), ("settings", "f1"), ("m_val", "f1"), ("flags", "f1"), ("dof_damping", "f1"),
                ("jnt_dofadr", "i1"), ("trntype", "j1"), ("trnid", "j2"), ("biastype", "j1"), ("biasprm", "f2"),
                ("gear", "f2"), ("integrator", "j1"), ("jacobian", "j1"))
"""(name, kind) of the table entries after the ``iw`` buffers (kind ``j``: int32)."""
FIELDS = ie.IMPLICIT_FIELDS + EXTRA_FIELDS
"""The handle's implicit part of the table, in order."""
_IMPLICIT = (int(mujoco.mjtIntegrator.mjINT_IMPLICIT), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))
_JAC_SPARSE, _JAC_AUTO = int(mujoco.mjtJacobian.mjJAC_SPARSE), int(mujoco.mjtJacobian.mjJAC_AUTO)
_SPARSE_NV = 60
"""``mj_isSparse``: ``mjJAC_AUTO`` means sparse from this many dofs on (MuJoCo 4.0; tests/test_native.py
checks the native choice against ``mj_isSparse``)."""


_j1, _j2 = rt._j1, rt._j2
if rt.AVAILABLE:
    _iw = table.loader(ie.IMPLICIT_FIELDS)
    """The ``iw`` tuple from the table entries at ``base`` (:data:`rft_mujoco.compiled.implicit_eval.IMPLICIT_FIELDS`)."""
    _md, _hc, _ws = (table.loader(fields) for fields in (rt.ev.MJDATA_FIELDS, rt.ev.HANDLE_FIELDS, rt.ev.WORK_FIELDS))
    """``md``, ``hc``, ``ws`` as tuples (the route's phases take views): ``evaluate_implicit`` is a function of
    its own, compiled once for the tuples of both the Python path and this route."""
else:  # pragma: no cover - without numba the route is never built
    _iw = _md = _hc = _ws = None


@njit(**INLINE)
def _jac_rows(t, base, nv):
    """MjData's constraint Jacobian now: (efc_J, efc_J_rowadr, efc_J_rownnz, efc_J_colind), from the pointers
    at ``t[base + 2 + len(EFC_POINTERS):]`` (:func:`rft_mujoco.compiled.route.efc_layout`). ``efc_J`` spans
    nefc x nv numbers: all of a dense Jacobian, at least what the rows of a sparse one address."""
    d = t[base]
    nefc = carray(rt._as_i4(d + t[base + 1]), (1,))[0]
    o = base + 2 + len(rt.EFC_POINTERS)
    p = carray(rt._as_i8(d + t[o]), (1,))[0]
    jac = carray(rt._as_f8(p), (nefc * nv,))
    p = carray(rt._as_i8(d + t[o + 1]), (1,))[0]
    rowadr = carray(rt._as_i4(p), (nefc,))
    p = carray(rt._as_i8(d + t[o + 2]), (1,))[0]
    rownnz = carray(rt._as_i4(p), (nefc,))
    p = carray(rt._as_i8(d + t[o + 3]), (1,))[0]
    colind = carray(rt._as_i4(p), (nefc * nv,))
    return jac, rowadr, rownnz, colind


def implicit_phase(ptr, h, dt):
    """The evaluation of handle ``h`` of the table at ``ptr`` with the implicit solve, after the
    broadphase and ``mj_fwdActuation``: its wrenches added into the book's ``sand``; the evaluation's status.
    A C function (:func:`cfunc_address`), called by ``route.phase2`` through the table's ``t[T_IMPLICIT_PHASE]``."""
    t = rt._table(ptr)
    n = t[sc.T_HANDLES]
    base = t[rt._HEADER + h]
    ib = t[rt._HEADER + n + h]
    _, _, _, _, user, sand, _, _, _, _ = rt._book(t, t[sc.T_BOOK])
    md = _md(t, t[sc.T_MD])
    nv = md[sc.M_QVEL].shape[0]
    fr = rt._fr(t, t[sc.T_ROWS], nv)
    jac, rowadr, rownnz, colind = _jac_rows(t, t[sc.T_ROWS], nv)
    efc = (jac, rowadr, rownnz, colind, fr[0], fr[1], fr[2], fr[3], fr[4], fr[5])
    s = ib + len(ie.IMPLICIT_FIELDS) * rt.SLOT
    damping, st, m_val, flags = rt._f1(t, s), rt._f1(t, s + 4), rt._f1(t, s + 8), rt._f1(t, s + 12)
    integrator, jacobian = _j1(t, s + 44)[0], _j1(t, s + 48)[0]
    velocity_damping(integrator == _IMPLICIT[0] or integrator == _IMPLICIT[1], rt._f1(t, s + 16), rt._i1(t, s + 20),
                     _j1(t, s + 24), _j2(t, s + 28), _j1(t, s + 32), rt._f2(t, s + 36), rt._f2(t, s + 40), damping)
    sparse = jacobian == _JAC_SPARSE or (jacobian == _JAC_AUTO and nv >= _SPARSE_NV)
    return ie.evaluate_implicit(md, _hc(t, base), _ws(t, base + rt._HC_SLOTS), _iw(t, ib), user, dt, sand,
                                (efc, sparse, m_val, damping, flags[0] != 0.0), st)


_cfunc = []
_lock = threading.Lock()


def cfunc_address() -> int:
    """The address of :func:`implicit_phase` as a C function (route's rest signature), compiled or loaded from
    the cache at the first route with an implicit handle (so that models without one never compile it)."""
    with _lock:
        if not _cfunc:
            _cfunc.append(cfunc(rt._REST_SIG, cache=True)(implicit_phase))
        return _cfunc[0].address


def _int_view(model, value_of, name: str) -> np.ndarray:
    """An int32 (1,) view of the ``model.opt`` field ``name`` (located by writing marker values on it)."""
    offset = option_offset(name)
    view = np.ctypeslib.as_array((ctypes.c_int32 * 1).from_address(model._address + offset))
    if int(view[0]) != int(value_of(model.opt)):
        raise RuntimeError(f"model.opt.{name} does not read back at its offset")
    return view


_offsets: dict = {}


def option_offset(name: str) -> int:
    """Offset in ``mjModel`` of the int ``opt.integrator`` or ``opt.jacobian`` (mujoco 4.0: among the ints
    after ``opt.o_friction``), found on a private model by writing marker values and verified."""
    if name not in _offsets:
        model = mujoco.MjModel.from_xml_string("<mujoco/>")
        base = model._address
        start = model.opt.o_friction.ctypes.data - base + 8 * model.opt.o_friction.size
        markers = {"integrator": (3, 1, 2, 0), "jacobian": (2, 1, 0, 2)}[name]
        hits = None
        for value in markers:
            setattr(model.opt, name, value)
            found = {o for o in range(start, start + 256, 4) if ctypes.c_int32.from_address(base + o).value == value}
            hits = found if hits is None else hits & found
        if not hits or len(hits) != 1:
            raise RuntimeError(f"cannot locate mjModel.opt.{name}")
        _offsets[name] = hits.pop()
    return _offsets[name]


def table_part(handle, iw, data) -> list:
    """[(name, kind, array)] of :data:`FIELDS` for ``handle`` on ``data``, its implicit solve's buffers being ``iw``
    (:class:`rft_mujoco.coupling.implicit.ImplicitWork`)."""
    m = handle.model
    flags = np.array([1.0 if handle.constraints == "linearized" else 0.0])
    extra = (iw.damping, iw.settings, data.M, flags, *iw.model_arrays,
             _int_view(m, lambda o: o.integrator, "integrator"), _int_view(m, lambda o: o.jacobian, "jacobian"))
    return [(name, kind, a) for (name, kind), a in zip(FIELDS, (*iw.tuple, *extra))]
