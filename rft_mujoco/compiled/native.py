"""The sand as native MuJoCo callbacks: numba ``cfunc`` s installed as ``mjcb_control`` / ``mjcb_passive``.

With the dispatcher's Python callback, every evaluation pays the bindings' trampoline, the Python call and
the ctypes calls of the route (about 2 us). Here MuJoCo calls compiled code directly:

* :func:`control` / :func:`passive` get the raw ``mjModel*`` / ``mjData*``, look the pair up in the
  :class:`Registry` (a table the Python side maintains; its address sits in the global symbol
  :data:`SYMBOL`, registered with LLVM so that the cached machine code finds it) and run the route's
  phases (:mod:`rft_mujoco.compiled.route`) with ``mj_fwdActuation`` in between;
* a model without sand is left alone (so model compilation, which runs callbacks on a temporary model,
  works while they are installed); anything else goes to the bindings' own trampoline of the dispatcher's
  Python callback, exactly as if it were installed: the first evaluation of an (model, data) pair (it
  builds the route), an error (the Python path raises it, naming the bodies, from ``mj_step``), a due
  validity check (``state[5]`` of the book says which), and any user actuator callback ``mjcb_act_*``
  (``mj_fwdActuation`` could then run Python code; it is never called natively then).

What it relies on is checked once (:func:`support`): the mujoco version it was written for, ``mjtNum`` =
float64, the symbols of the bindings' own MuJoCo library (proved by setting a callback through the
bindings and reading it back), and the offsets of ``opt.timestep``, ``opt.integrator``,
``opt.disableflags`` in ``mjModel`` and of ``time`` in ``mjData`` (found next to fields the bindings
expose as arrays, and verified by writing marker values on a private model). Otherwise the dispatcher
keeps its Python callback and says why once. The cached machine code is keyed by the kernel sources and
the numba, mujoco, numpy and Python versions (:func:`rft_mujoco.compiled.jit.drop_stale_cache`).

The one MuJoCo function called natively is ``mj_fwdActuation``, and only while no ``mjcb_act_*`` callback
is installed. Without user callbacks its one error path is the arena allocation of ``nu`` numbers for
the clamped controls (bad controls are MuJoCo *warnings*, which return), which fails only when the arena
is already exhausted, where MuJoCo's own ``mj_fwdActuation`` of the same step, right after the callback,
would fail too. Every path that can raise (a user callback, the sand's own checks, a non-finite state)
runs in Python, through the bindings, where errors become Python exceptions.
"""

from __future__ import annotations

import ctypes
import glob
import os
import threading

import mujoco
import numpy as np

from rft_mujoco.compiled import route as rt
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.deferred import DeferredLock
from rft_mujoco.compiled.jit import AVAILABLE, INLINE, JIT, carray, cfunc, njit, types

MUJOCO_VERSION = "4.0.0"
"""The mujoco version whose struct layout and callback semantics this module was written and tested for."""
SYMBOL = "rft_mujoco_native_registry"
"""Global symbol holding the address of the registry array."""
HEAD, ENTRY = len(sc.REGISTRY_HEADER), len(sc.REGISTRY_ENTRY)
"""Registry: a header of HEAD int64 (:data:`rft_mujoco.compiled.schema.REGISTRY_HEADER`), then ENTRY int64 per
entry (:data:`rft_mujoco.compiled.schema.REGISTRY_ENTRY`)."""
_RK4 = int(mujoco.mjtIntegrator.mjINT_RK4)
_ACTUATION_OFF = int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
_CELL = ctypes.c_int64(0)               # the registry's address: what SYMBOL names

if AVAILABLE:
    import llvmlite.binding as _llvm
    from llvmlite import ir
    from numba.extending import intrinsic

    _llvm.add_symbol(SYMBOL, ctypes.addressof(_CELL))

    @intrinsic
    def _registry_address(typingctx):
        def codegen(context, builder, signature, args):
            gv = builder.module.globals.get(SYMBOL)
            if gv is None:
                gv = ir.GlobalVariable(builder.module, ir.IntType(64), name=SYMBOL)
                gv.linkage = "external"
            return builder.load(gv)
        return types.int64(), codegen

    @intrinsic
    def _address(typingctx, ptr):
        def codegen(context, builder, signature, args):
            return builder.ptrtoint(args[0], ir.IntType(64))
        return types.int64(types.voidptr), codegen

    @intrinsic
    def _call(typingctx, fn, m, d):
        """Call the C function at address ``fn`` as ``void (*)(const mjModel*, mjData*)``."""
        def codegen(context, builder, signature, args):
            vp = ir.IntType(8).as_pointer()
            fnty = ir.FunctionType(ir.VoidType(), [vp, vp])
            f = builder.inttoptr(args[0], fnty.as_pointer())
            builder.call(f, [builder.inttoptr(args[1], vp), builder.inttoptr(args[2], vp)])
            return context.get_dummy_value()
        return types.void(types.int64, types.int64, types.int64), codegen

    @intrinsic
    def _phase(typingctx, fn, table, time, dt):
        """Call the route's phase at address ``fn`` (:func:`rft_mujoco.compiled.route.entries`) on the table at
        address ``table``: a call through the address, so that this module's machine code does not contain
        (and compile again) the phases' own."""
        def codegen(context, builder, signature, args):
            i64, f64 = ir.IntType(64), ir.DoubleType()
            fnty = ir.FunctionType(i64, [i64.as_pointer(), f64, f64])
            f = builder.inttoptr(args[0], fnty.as_pointer())
            return builder.call(f, [builder.inttoptr(args[1], i64.as_pointer()), args[2], args[3]])
        return types.int64(types.int64, types.int64, types.float64, types.float64), codegen

    _as_i4 = rt._cast(types.CPointer(types.int32))
    _as_i8, _as_f8 = rt._as_i8, rt._as_f8


@njit(**INLINE)
def _i4(addr):
    return carray(_as_i4(addr), (1,))[0]


@njit(**INLINE)
def _i8(addr):
    return carray(_as_i8(addr), (1,))[0]


@njit(**INLINE)
def _f8(addr):
    return carray(_as_f8(addr), (1,))[0]


@njit(**JIT)
def _later_rk4_stage(state, t, dt):
    """:meth:`rft_mujoco.coupling.dispatch.Dispatcher._later_rk4_stage` on the book's state (stage in
    ``state[B_RK4_STAGE]``, its first time in ``state[B_RK4_STAGE_TIME]``, TIME_RTOL in ``state[B_TIME_RTOL]``)."""
    n = int(state[sc.B_RK4_STAGE])
    if 1 <= n <= 3:
        frac = 0.5 if n < 3 else 1.0
        if abs(t - (state[sc.B_RK4_STAGE_TIME] + frac * dt)) <= state[sc.B_TIME_RTOL] * dt:
            state[sc.B_RK4_STAGE] = n + 1
            return True
    state[sc.B_RK4_STAGE_TIME] = t
    state[sc.B_RK4_STAGE] = 1.0
    return False


_RUN_SIG = types.void(types.Array(types.int64, 1, "C"), types.int64, types.int64, types.int64) if AVAILABLE else None


@njit(_RUN_SIG, **JIT)                                # one signature: not one per literal ``passive``
def run(reg, m, d, passive):
    """One callback: the route of (``m``, ``d``) natively, or the Python trampoline, or nothing."""
    n = reg[sc.R_ENTRIES]
    model = -1
    entry = -1
    for e in range(n):
        base = HEAD + ENTRY * e
        if reg[base + sc.E_MODEL] == m:
            model = base
            if reg[base + sc.E_DATA] == d:
                entry = base
                break
    if model < 0:
        return                                       # no sand on this model (e.g. one being compiled)
    off = (_i4(reg[model + sc.E_DISABLEFLAGS]) & _ACTUATION_OFF) != 0
    if passive != 0 and not off:
        return                                       # mjcb_control evaluates the sand
    trampoline = reg[sc.R_PASSIVE_TRAMPOLINE if passive != 0 else sc.R_CONTROL_TRAMPOLINE]
    if entry < 0 or _i8(reg[sc.R_ACT_DYN]) != 0 or _i8(reg[sc.R_ACT_GAIN]) != 0 or _i8(reg[sc.R_ACT_BIAS]) != 0:
        _call(trampoline, m, d)                      # the Python path (builds the route, user act callbacks)
        return
    size = reg[entry + sc.E_LENGTH]
    t = carray(_as_i8(reg[entry + sc.E_TABLE]), (size,))
    state = rt._book(t, t[sc.T_BOOK])[rt.BOOK_STATE]
    time = _f8(reg[entry + sc.E_TIME])
    dt = _f8(reg[entry + sc.E_TIMESTEP])
    if _i4(reg[entry + sc.E_INTEGRATOR]) == _RK4:
        if _later_rk4_stage(state, time, dt) and state[sc.B_RK4_STAGE] > rt.rk4_evaluated(t):
            return                                   # xfrc_applied holds the last evaluated stage's user + sand
    else:
        state[sc.B_RK4_STAGE] = 0.0
    table = reg[entry + sc.E_TABLE]
    code = _phase(reg[sc.R_PHASE1], table, time, dt)
    if code == rt.ACTUATE:
        _call(reg[sc.R_FWD_ACTUATION], m, d)         # no user actuator callback installed
        code = _phase(reg[sc.R_PHASE2], table, time, dt)
    elif code == rt.CONTINUE:
        code = _phase(reg[sc.R_PHASE2], table, time, dt)
    if code == rt.MONITOR or code == rt.PYTHON:
        state[sc.B_PENDING] = code                              # what the Python side is to do
        _call(trampoline, m, d)


if AVAILABLE:
    _SIG = types.void(types.voidptr, types.voidptr)

    @cfunc(_SIG, cache=True)
    def _control_c(m, d):
        reg = carray(_as_i8(_registry_address()), (HEAD,))
        reg = carray(_as_i8(_registry_address()), (HEAD + ENTRY * reg[sc.R_ENTRIES],))
        run(reg, _address(m), _address(d), 0)

    @cfunc(_SIG, cache=True)
    def _passive_c(m, d):
        reg = carray(_as_i8(_registry_address()), (HEAD,))
        reg = carray(_as_i8(_registry_address()), (HEAD + ENTRY * reg[sc.R_ENTRIES],))
        run(reg, _address(m), _address(d), 1)


# --- what it relies on ----------------------------------------------------------------------------------
_CB = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)
_support = None
_lock = threading.Lock()


def _library():
    """The bindings' own MuJoCo library (ctypes), proved by a callback set through the bindings."""
    folder = os.path.dirname(os.path.abspath(mujoco.__file__))
    names = sorted(glob.glob(os.path.join(folder, "libmujoco.so*")) + glob.glob(os.path.join(folder, "libmujoco*.dylib"))
                   + glob.glob(os.path.join(folder, "mujoco.dll")))
    if not names:
        raise RuntimeError(f"no MuJoCo library next to the bindings in {folder}")
    lib = ctypes.CDLL(names[0])
    glob_control = ctypes.c_void_p.in_dll(lib, "mjcb_control")
    probe = _CB(lambda m, d: None)
    set_control = getattr(mujoco.set_mjcb_control, "__wrapped__", mujoco.set_mjcb_control)  # not the dispatcher's
    saved = mujoco.get_mjcb_control()
    try:
        set_control(probe)
        same = glob_control.value == ctypes.cast(probe, ctypes.c_void_p).value
    finally:
        set_control(saved)
    if not same:
        raise RuntimeError(f"{names[0]} is not the library the mujoco bindings use")
    return lib


def _find(read, base, window, field, setter, markers, kind) -> int:
    """The offset in ``window`` (relative to ``base``) where ``read`` sees ``setter``'s marker values."""
    hits = None
    for value in markers:
        setter(value)
        found = {o for o in window if read(base + o) == value}
        hits = found if hits is None else hits & found
    if not hits or len(hits) != 1:
        raise RuntimeError(f"cannot locate {field} ({kind}) in the MuJoCo structs")
    return hits.pop()


def _offsets() -> dict:
    """Offsets of the scalars the callbacks read, found and verified on a private model and data."""
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='.1'/></body>"
                                           "</worldbody></mujoco>")
    data = mujoco.MjData(model)
    f64 = lambda a: ctypes.c_double.from_address(a).value       # noqa: E731
    i32 = lambda a: ctypes.c_int32.from_address(a).value        # noqa: E731
    opt, mbase, dbase = model.opt, model._address, data._address
    grav = opt.gravity.ctypes.data - mbase
    fric = opt.o_friction.ctypes.data - mbase + 8 * opt.o_friction.size
    energy = data.energy.ctypes.data - dbase

    def setter(obj, name):
        return lambda v: setattr(obj, name, v)
    out = dict(
        timestep=_find(f64, mbase, range(grav - 8, grav - 257, -8), "opt.timestep", setter(opt, "timestep"),
                       (0.00123456789, 0.0987654321), "double"),
        integrator=_find(i32, mbase, range(fric, fric + 256, 4), "opt.integrator", setter(opt, "integrator"),
                         (3, 2, 1), "int"),
        disableflags=_find(i32, mbase, range(fric, fric + 256, 4), "opt.disableflags",
                           setter(opt, "disableflags"), (0x5A5A5, 0x2B2B2), "int"),
        time=_find(f64, dbase, range(energy - 8, energy - 257, -8), "mjData.time", setter(data, "time"),
                   (12.3456789, 98.7654321), "double"))
    return out


def support() -> tuple:
    """(True, addresses) when the native callbacks can be installed here, else (False, reason)."""
    global _support
    with _lock:
        if _support is None:
            _support = _check()
        return _support


def _check() -> tuple:
    if not AVAILABLE:
        return False, "numba is not available"
    if mujoco.__version__ != MUJOCO_VERSION:
        return False, f"written for mujoco {MUJOCO_VERSION}, found {mujoco.__version__}"
    data = mujoco.MjData(mujoco.MjModel.from_xml_string("<mujoco/>"))
    if data.qpos.dtype != np.float64:
        return False, "MuJoCo's mjtNum is not float64"
    try:
        lib = _library()
        offsets = _offsets()
        rt.efc_layout()                              # the routes read mjData's constraint rows
        addr = lambda name: ctypes.addressof(ctypes.c_void_p.in_dll(lib, name))      # noqa: E731
        symbols = dict(control=addr("mjcb_control"), passive=addr("mjcb_passive"), act_dyn=addr("mjcb_act_dyn"),
                       act_gain=addr("mjcb_act_gain"), act_bias=addr("mjcb_act_bias"),
                       fwd_actuation=ctypes.cast(lib.mj_fwdActuation, ctypes.c_void_p).value,
                       control_c=_control_c.address, passive_c=_passive_c.address,
                       phase1_c=rt.cfuncs()[0].address, phase2_c=rt.cfuncs()[1].address)
    except Exception as exc:  # a MuJoCo build this module does not know
        return False, f"{type(exc).__name__}: {exc}"
    return True, dict(symbols, offsets=offsets)


# --- the registry -----------------------------------------------------------------------------------------
class Registry:
    """The table the native callbacks read: models with sand and the routes of their datas.

    Rewritten whole (a new array, then one aligned store of its address into the cell) so that a callback
    running in another thread sees either the old or the new table; old arrays are kept a while.

    A data's route is dropped by the data's finalizer, also when that runs inside a rewrite (its allocations
    can start a collection): queued then, and made before the rewrite ends (:mod:`rft_mujoco.compiled.deferred`)."""

    def __init__(self, info: dict) -> None:
        self.info = info
        self._models: dict = {}          # model address -> disableflags address
        self._routes: dict = {}          # (model address, data address) -> (route, model, data addresses...)
        self._old: list = []
        self._lock = DeferredLock()      # its queue: addresses of datas collected during a rewrite
        self.trampolines = (0, 0)
        self._write()

    def _changing(self):
        """The lock for a change; the table is written at the end of the outermost block."""
        return self._lock.changing(self._flush)

    def _flush(self) -> None:
        self._write()
        queue = self._lock.queue
        while queue:                                 # datas collected meanwhile (during the write too: once more)
            gone = set(queue)
            queue.clear()
            self._routes = {k: v for k, v in self._routes.items() if k[1] not in gone}
            self._write()

    def held(self) -> tuple[tuple, tuple]:
        """(model addresses, (model, data) address pairs): what the native callbacks hold now."""
        with self._lock.lock:
            return tuple(self._models), tuple(self._routes)

    def set_trampolines(self, control: int, passive: int) -> None:
        with self._changing():
            self.trampolines = (int(control), int(passive))

    def models(self, models) -> None:
        """The models with sand attached (routes of others are dropped)."""
        with self._changing():
            off = self.info["offsets"]
            self._models = {m._address: m._address + off["disableflags"] for m in models}
            self._routes = {k: v for k, v in self._routes.items() if k[0] in self._models}

    def clear_routes(self) -> None:
        with self._changing():
            self._routes.clear()

    def add(self, model, data, route) -> None:
        """Route ``route`` for (model, data); dropped again when ``data`` is garbage collected."""
        import weakref
        with self._changing():
            if model._address not in self._models:
                return
            key = (model._address, data._address)
            if key not in self._routes:
                weakref.finalize(data, self.drop_data, data._address)
            off = self.info["offsets"]
            self._routes[key] = (route, data._address + off["time"], model._address + off["timestep"],
                                 model._address + off["integrator"], model._address + off["disableflags"])

    def drop_data(self, address: int) -> None:
        """The finalizer of the data at ``address``: its routes leave the table (queued while rewriting)."""
        if not self._lock.defer(address):
            with self._changing():
                self._routes = {k: v for k, v in self._routes.items() if k[1] != address}

    def routed(self, model, data) -> bool:
        return (model._address, data._address) in self._routes

    def _write(self) -> None:
        info = self.info
        entries = []
        for (m, d), (r, t_time, t_step, t_int, t_flags) in self._routes.items():
            entries.append(dict(model=m, data=d, table=r.address, time=t_time, timestep=t_step, integrator=t_int,
                                disableflags=t_flags, length=r.table.size))
        for m, flags in self._models.items():
            entries.append(dict(model=m, data=0, table=0, time=0, timestep=0, integrator=0, disableflags=flags,
                                length=0))
        reg = np.zeros(HEAD + ENTRY * len(entries), dtype=np.int64)
        control, passive = self.trampolines
        head = dict(entries=len(entries), control_trampoline=control, passive_trampoline=passive,
                    fwd_actuation=info["fwd_actuation"], act_dyn=info["act_dyn"], act_gain=info["act_gain"],
                    act_bias=info["act_bias"], phase1=info["phase1_c"], phase2=info["phase2_c"])
        reg[:HEAD] = [head[name] for name in sc.REGISTRY_HEADER]
        for e, values in enumerate(entries):
            reg[HEAD + ENTRY * e:HEAD + ENTRY * (e + 1)] = [values[name] for name in sc.REGISTRY_ENTRY]
        self._old.append(reg)
        _CELL.value = reg.ctypes.data
        del self._old[:-16]
