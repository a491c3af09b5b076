"""The one process-wide MuJoCo control-callback dispatcher (the package's only module-level mutable state).

MuJoCo callbacks are global to the process, so every attached sand handle of every model goes through one dispatcher
installed with ``mujoco.set_mjcb_control``. It

* chains a control callback the user had installed before (called first, so ``ctrl`` is final); also a passive one
  that evaluates the sand when ``mjDSBL_ACTUATION`` makes MuJoCo skip ``mjcb_control``;
* routes each evaluation to the handles of its model (models and datas work independently);
* owns the ``xfrc_applied`` bookkeeping per MjData: the row always ends as user wrench + sand wrench, whatever the
  user wrote between steps (:func:`untouched_components`);
* keeps model compilation working (mujoco 4.0's compiler raises "Python exception raised" while any Python callback is
  installed): the compile entry points are wrapped to suspend the callback, until the last handle detaches;
* keeps the sand's state with the simulation it belongs to while installed (docs/architecture.md, "State and copies"):
  copies of an MjData for the same model get its book and the handles' workspaces; deep copies and pickles of an
  MjData, copies, pickles and ``mj_saveModel`` of an MjModel are of the plain state; ``mj_resetData*`` makes a data
  new; ``set_mjcb_control`` / ``set_mjcb_passive`` set the callback it chains; disableflags that would leave no
  callback are refused; the model's timestep, gravity and geom sizes are compared at every evaluation with what the
  handles last checked (:meth:`SandHandle._check_model`);
* never keeps a model alive: a model's finalizer unregisters its handles (docs/architecture.md, "Lifetime").

Where it can (:func:`rft_mujoco.compiled.native.support`), the dispatcher installs native callbacks
(:mod:`rft_mujoco.compiled.native`) in MuJoCo's place of its Python ones: the bindings still hold the Python callbacks
(``mujoco.get_mjcb_control()`` returns the dispatcher), MuJoCo calls compiled code that runs the native route of each
(model, data) and hands everything else to the bindings' trampoline of the Python callback, so that behaviour and
errors are those of the Python path. A callback the user had installed before keeps its slot Python;
``Dispatcher.native = False`` before the first attach keeps both.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import weakref

import mujoco
import numpy as np

from rft_mujoco import compiled
from rft_mujoco.coupling import implicit as _IMPLICIT
from rft_mujoco.compiled import deform_route as _DEFORM_ROUTE, route as _ROUTE
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.deferred import DeferredLock
from rft_mujoco.coupling.book import RK4_STAGE_TIMES, _DataBook, untouched_components  # noqa: F401  (their home before)
from rft_mujoco.coupling.book import RK4_STAGES

_COMPILE_ENTRY_POINTS = ((mujoco.MjModel, "from_xml_string", True), (mujoco.MjModel, "from_xml_path", True),
                         (mujoco.MjModel, "from_binary_path", True), (mujoco.MjSpec, "compile", False),
                         (mujoco.MjSpec, "recompile", False))

_DATA_COPIES = ((mujoco.MjData, "__copy__"), (mujoco, "mj_copyData"))
"""Copies of an MjData for the same model: the copy gets the original's sand state (:meth:`Dispatcher.copy_state`)."""
_PLAIN_COPIES = ((mujoco.MjData, "__deepcopy__"), (mujoco.MjData, "__getstate__"), (mujoco.MjModel, "__copy__"),
                 (mujoco.MjModel, "__deepcopy__"), (mujoco.MjModel, "__getstate__"), (mujoco, "mj_saveModel"))
"""Copies and saves that carry a model (a new MjModel, a pickle, an .mjb): made of the plain model and data,
without the sand (:meth:`Dispatcher.plain`)."""
_RESETS = ("mj_resetData", "mj_resetDataDebug", "mj_resetDataKeyframe")
"""Resets of an MjData: it starts a new trajectory, without the sand state of the old one (:meth:`Dispatcher.forget`)."""
_SET_CONTROL, _SET_PASSIVE = mujoco.set_mjcb_control, mujoco.set_mjcb_passive
_DISABLEFLAGS = mujoco.MjOption.__dict__["disableflags"]
_RK4 = int(mujoco.mjtIntegrator.mjINT_RK4)
_ACTUATION_OFF = int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)


class Dispatcher:
    def __init__(self) -> None:
        self._handles: list = []
        self._chained = None
        self._chained_passive = None
        self._passive = self.passive          # one bound method: MuJoCo hands back the object it was given
        self._originals: dict = {}
        self._books: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self._routes: dict = {}              # id(model) -> (weakref to model, handles, rows), rebuilt on (un)register
        self._finalizers: dict = {}          # handle -> weakref.finalize of its model (unregisters it)
        self._deferred = DeferredLock()      # its queue: handles whose model was collected while (un)registering
        self._lock = self._deferred.lock
        self._generation = 0                 # bumped whenever a handle's setting changes (native routes)
        self.native = True                   # install native callbacks where possible (read at install)
        self._registry = None                # rft_mujoco.compiled.native.Registry while native callbacks are in
        self._native_slots = (False, False)  # (control, passive) slots holding a native callback

    # --- registration: a handle holds its model weakly, and a finalizer of the model, holding the handle,
    # unregisters it when the model is collected: registered exactly as long as its model lives ----------
    def register(self, handle) -> None:
        with self._changing():
            if not self._handles:
                self._install()
            self._handles = [*self._handles, handle]      # a new list: loops over the old one are unaffected
            gone = self._finalizers[handle] = weakref.finalize(handle._model(), self.collected, handle)
            gone.atexit = False
            self._routes.clear()
            self._generation += 1
            self._registry_models()

    def collected(self, handle) -> None:
        """The model of ``handle`` was garbage collected (called by its finalizer, in whichever thread
        collected it): unregister the handle, now or, when this thread is (un)registering, right after."""
        if not self._deferred.defer(handle):
            handle._collected()

    def _changing(self):
        """The lock, and the collected models' handles unregistered at the end of the outermost block."""
        return self._deferred.changing(self._unregister_collected)

    def _unregister_collected(self) -> None:
        queue = self._deferred.queue
        while queue:
            queue.pop()._collected()

    def invalidate(self) -> None:
        """A handle's setting, terrain or workspace changed: rebuild the native routes before the next use."""
        self._generation += 1
        if self._registry is not None:
            self._registry.clear_routes()

    def unregister(self, handle) -> None:
        with self._changing():
            self._handles = [h for h in self._handles if h is not handle]
            gone = self._finalizers.pop(handle, None)
            if gone is not None:
                gone.detach()
            self._routes.clear()
            self._generation += 1
            if self._registry is not None:
                self._registry.clear_routes()
            self._registry_models()
            if not self._handles:
                self._uninstall()

    @property
    def handles(self) -> tuple:
        """The attached handles (of models still alive), in attach order."""
        return tuple(h for h in self._handles if h._model() is not None)

    def _install(self) -> None:
        current = mujoco.get_mjcb_control()
        self._chained = current if current is not self else None
        _SET_CONTROL(self)
        current = mujoco.get_mjcb_passive()
        self._chained_passive = current if current is not self._passive else None
        _SET_PASSIVE(self._passive)
        for owner, name, static in _COMPILE_ENTRY_POINTS:
            original = owner.__dict__[name] if name in owner.__dict__ else getattr(owner, name)
            self._originals[(owner, name)] = original
            func = original.__func__ if isinstance(original, staticmethod) else original
            wrapped = self._suspending(func)
            setattr(owner, name, staticmethod(wrapped) if static else wrapped)
        self._install_native()
        for owner, name in _DATA_COPIES:
            self._wrap(owner, name, self._copying(getattr(owner, name), owner is mujoco))
        for name in _RESETS:
            self._wrap(mujoco, name, self._resetting(getattr(mujoco, name)))
        for owner, name in _PLAIN_COPIES:
            self._wrap(owner, name, self._plain_during(getattr(owner, name)))
        self._wrap(mujoco, "set_mjcb_control", self._setting_callback(_SET_CONTROL, passive=False))
        self._wrap(mujoco, "set_mjcb_passive", self._setting_callback(_SET_PASSIVE, passive=True))
        self._wrap(mujoco.MjOption, "disableflags", property(_DISABLEFLAGS.fget, self._set_disableflags,
                                                             doc=_DISABLEFLAGS.__doc__))

    def _wrap(self, owner, name, replacement) -> None:
        """Replace ``owner.name`` until the last handle detaches (:meth:`_uninstall` restores it)."""
        self._originals[(owner, name)] = owner.__dict__[name] if name in owner.__dict__ else getattr(owner, name)
        setattr(owner, name, replacement)

    def _install_native(self) -> None:
        """Put the native callbacks in MuJoCo's slots the dispatcher's Python callbacks hold (those not
        chaining a user callback); the bindings keep the Python ones, whose trampolines the native code calls."""
        self._native_slots = (False, False)
        want = (self._chained is None, self._chained_passive is None)
        if not self.native or not any(want) or not compiled.ready():
            return
        from rft_mujoco.compiled import native
        ok, info = native.support()
        if not ok:
            _ROUTE.say_once(info)
            return
        control = ctypes.c_void_p.from_address(info["control"])
        passive = ctypes.c_void_p.from_address(info["passive"])
        if self._registry is None:
            self._registry = native.Registry(info)
        self._registry.set_trampolines(control.value or 0, passive.value or 0)
        self._registry_models()
        if want[0]:
            control.value = info["control_c"]
        if want[1]:
            passive.value = info["passive_c"]
        self._native_slots = want

    def _reinstall_native(self) -> None:
        """After the bindings rewrote the slots (a compile wrapper restoring them): the native callbacks again."""
        if any(self._native_slots):
            info = self._registry.info
            if self._native_slots[0] and mujoco.get_mjcb_control() is self:
                ctypes.c_void_p.from_address(info["control"]).value = info["control_c"]
            if self._native_slots[1] and mujoco.get_mjcb_passive() is self._passive:
                ctypes.c_void_p.from_address(info["passive"]).value = info["passive_c"]

    def _registry_models(self) -> None:
        if self._registry is not None:
            models = (h._model() for h in self._handles)
            self._registry.models({id(m): m for m in models if m is not None}.values())

    def held(self) -> dict:
        """What the dispatcher holds now (leak checks): numbers of ``handles``, their model ``finalizers``, Python
        ``routes`` and ``wrapped`` MuJoCo functions; ``native`` (native callbacks loaded), the ``native_models``
        (addresses) and ``native_routes`` ((model, data) addresses) their table holds."""
        models, routes = self._registry.held() if self._registry is not None else ((), ())
        return {"handles": len(self._handles), "finalizers": len(self._finalizers), "routes": len(self._routes),
                "wrapped": len(self._originals), "native": self._registry is not None, "native_models": models,
                "native_routes": routes}

    @property
    def native_installed(self) -> tuple:
        """(control, passive): whether MuJoCo's slot holds the native callback now."""
        if self._registry is None:
            return (False, False)
        info = self._registry.info
        return (self._native_slots[0] and ctypes.c_void_p.from_address(info["control"]).value == info["control_c"],
                self._native_slots[1] and ctypes.c_void_p.from_address(info["passive"]).value == info["passive_c"])

    def _uninstall(self) -> None:
        if mujoco.get_mjcb_control() is self:
            _SET_CONTROL(self._chained)
        if mujoco.get_mjcb_passive() is self._passive:
            _SET_PASSIVE(self._chained_passive)
        self._chained = None
        self._chained_passive = None
        self._native_slots = (False, False)
        if self._registry is not None:
            self._registry.models(())
        for (owner, name), original in self._originals.items():
            setattr(owner, name, original)
        self._originals.clear()

    # --- what users do around a running simulation: copies, saves, callbacks, flags ---------------------
    def _copying(self, func, module_function: bool):
        """``MjData.__copy__`` / ``mujoco.mj_copyData``, then the copy gets the original's sand state."""
        if module_function:
            @functools.wraps(func)
            def copy_data(dest, m, src):
                func(dest, m, src)
                self.copy_state(src, dest)
            return copy_data

        @functools.wraps(func)
        def copy(src):
            out = func(src)
            self.copy_state(src, out)
            return out
        return copy

    def _resetting(self, func):
        """``mujoco.mj_resetData*``, then the data forgets its sand state (a reset data is a new one)."""
        @functools.wraps(func)
        def reset(m, d, *args, **kwargs):
            func(m, d, *args, **kwargs)
            self.forget(d)
        return reset

    def _plain_during(self, func):
        """A copy or save that carries a model, made while the sand is out (:meth:`plain`)."""
        @functools.wraps(func)
        def call(obj=None, *args, **kwargs):
            if obj is None:                          # mj_saveModel(m=...)
                obj = kwargs.pop("m")
            with self.plain(obj):
                return func(obj, *args, **kwargs)
        return call

    @contextlib.contextmanager
    def plain(self, obj):
        """While in the block, ``obj`` (an MjModel, or an MjData with its model) is as without sand: the
        floors ``replace_rigid`` switched off collide again and an MjData's ``xfrc_applied`` holds the
        user's part only; both are put back bit for bit after."""
        with self._lock:
            data = obj if isinstance(obj, mujoco.MjData) else None
            model = obj.model if data is not None else obj
            undo = []
            if data is not None and self._books.get(data) is not None:
                book = self._books[data]
                owner = book.model()
                if owner is not None and book.rows.size:
                    saved = data.xfrc_applied.copy()
                    data.xfrc_applied[:] = self.user_xfrc(owner, data)
                    undo.append(lambda: data.xfrc_applied.__setitem__(slice(None), saved))
            address = getattr(model, "_address", None)
            for h in self._handles:
                owner = h._model()
                if owner is not None and owner._address == address and h._replaced:
                    saved_type, saved_aff = model.geom_contype.copy(), model.geom_conaffinity.copy()
                    for gid, contype, conaffinity in h._replaced:
                        model.geom_contype[gid] = contype
                        model.geom_conaffinity[gid] = conaffinity
                    undo.append(lambda t=saved_type, a=saved_aff: (model.geom_contype.__setitem__(slice(None), t),
                                                                  model.geom_conaffinity.__setitem__(slice(None), a)))
            try:
                yield
            finally:
                for u in reversed(undo):
                    u()

    def copy_state(self, src, dst) -> None:
        """``dst`` was made a copy of ``src`` (same model): it continues with ``src``'s sand state (what the
        sand added to ``xfrc_applied``, the handles' workspaces), so that both step on identically; a ``src``
        without sand state makes ``dst`` forget its own."""
        with self._lock:
            self.forget(dst)
            book = self._books.get(src)
            owner = book.model() if book is not None else None
            if owner is None or dst.xfrc_applied.shape != src.xfrc_applied.shape:
                return
            new = self._books[dst] = _DataBook(owner, dst)
            for name in ("added", "written", "state"):
                np.copyto(getattr(new, name), getattr(book, name))
            new.pending = 0
            new.rows = book.rows.copy()
            new.snapshot = None if book.snapshot is None else book.snapshot.copy()
            for h in self._handles:
                if h._model() is owner:
                    h._copy_workspace(src, dst)

    def forget(self, data) -> None:
        """Drop what the dispatcher and the handles keep for ``data`` (its contents were replaced)."""
        with self._lock:
            self._books.pop(data, None)
            for h in self._handles:
                h._work.pop(data, None)
            if self._registry is not None:
                self._registry.drop_data(data._address)

    def _setting_callback(self, setter, passive: bool):
        """``mujoco.set_mjcb_control`` / ``set_mjcb_passive`` while sand is attached: the dispatcher keeps the
        slot and chains the new callback (None: none); passing the dispatcher's own callback changes nothing."""
        @functools.wraps(setter)
        def set_callback(callback):
            with self._lock:
                mine = self._passive if passive else self
                if callback is mine:
                    return
                if passive:
                    self._chained_passive = callback
                else:
                    self._chained = callback
                _SET_CONTROL(self)                   # both slots Python again, then native where nothing is chained
                _SET_PASSIVE(self._passive)
                self._install_native()
        return set_callback

    def _set_disableflags(self, opt, value) -> None:
        """``model.opt.disableflags = value`` while sand is attached: refused (ValueError, the flags left as
        they were) when it would leave MuJoCo no callback to evaluate the sand of that model from."""
        old = _DISABLEFLAGS.fget(opt)
        _DISABLEFLAGS.fset(opt, value)
        from rft_mujoco.coupling import checks
        for h in self._handles:
            model = h._model()
            if model is not None and model.opt is opt and checks.check_actuation_flag(model):
                _DISABLEFLAGS.fset(opt, old)
                raise ValueError(f"model.opt.disableflags = {value} refused while sand is attached (kept "
                                 f"{old}): {checks.ACTUATION_DISABLED_MESSAGE} Or detach the sand first.")

    def _suspending(self, func):
        @functools.wraps(func)
        def call(*args, **kwargs):
            if all(self.native_installed):
                return func(*args, **kwargs)     # the native callbacks leave models without sand alone
            with self._lock:
                current, passive = mujoco.get_mjcb_control(), mujoco.get_mjcb_passive()
                _SET_CONTROL(None)
                _SET_PASSIVE(None)
                try:
                    return func(*args, **kwargs)
                finally:
                    _SET_CONTROL(current)
                    _SET_PASSIVE(passive)
                    self._reinstall_native()
        return call

    # --- xfrc bookkeeping -------------------------------------------------------------------------
    def book(self, model, data) -> _DataBook:
        book = self._books.get(data)
        if book is None or book.added.shape[0] != model.nbody:
            book = self._books[data] = _DataBook(model, data)
        return book

    def user_xfrc(self, model, data) -> np.ndarray:
        """(nbody, 6) the user's own part of ``data.xfrc_applied`` (sand contribution removed)."""
        return self.book(model, data).user_part(data.xfrc_applied)

    # --- the callback -----------------------------------------------------------------------------
    def _route(self, model):
        """(handles of ``model``, their body rows) -- cached until a handle is (un)registered."""
        route = self._routes.get(id(model))
        if route is None or route[0]() is not model:
            handles = tuple(h for h in self._handles if h._model() is model)
            rows = np.unique(np.concatenate([h.body_ids for h in handles])) if handles else None
            route = self._routes[id(model)] = (weakref.ref(model), handles, rows)
        return route[1], route[2]

    def __call__(self, model, data) -> None:
        if self._chained is not None:
            self._chained(model, data)
        self._dispatch(model, data)

    def passive(self, model, data) -> None:
        """The passive callback: the user's, then the sand when MuJoCo will skip ``mjcb_control``
        (``mjDSBL_ACTUATION``; the actuator forces are then zero, as MuJoCo computes them)."""
        if self._chained_passive is not None:
            self._chained_passive(model, data)
        if model.opt.disableflags & _ACTUATION_OFF:
            self._dispatch(model, data)

    def _dispatch(self, model, data) -> None:
        """One evaluation of the sand of ``model`` on ``data``."""
        handles, rows = self._route(model)
        if not handles:
            return
        book = self._books.get(data)
        if book is None or book.added.shape[0] != model.nbody:
            book = self.book(model, data)
        if book.snapshot is None or self._model_changed(model, book):
            self._check_model(model, book, handles)
        pending = book.pending
        if pending:                          # left to Python by the native callback (this very evaluation)
            book.pending = 0
            if pending == _ROUTE.MONITOR:
                self._monitor(book.native[1], data)
                return
        if model.opt.integrator != _RK4:
            book.stage = 0
        elif not pending:                    # (a pending evaluation's stage is recorded already)
            later = book.later_rk4_stage(data.time, model.opt.timestep)
            if later and book.stage > max(RK4_STAGES[h.rk4_stages] for h in handles):
                return                       # xfrc_applied still holds the last evaluated stage's user + sand
        if book.native is not None and book.native[0] != self._generation:
            book.native = None
        routable = book.native is None and all(h._native_ok for h in handles) \
            and compiled.ready() and _ROUTE.layout_available()
        if routable and (book.rows is rows or book.rows.size == 0):
            # no rows of detached handles to clear: the native route from this evaluation on, the first of a
            # model included (the Python path's kernels then compile only where it runs)
            for h in handles:                # what the Python path checks at a handle's first evaluation
                h._check_floor()
            book.native = (self._generation, self._build_route(data, book, handles, rows))
            book.rows = rows
            routable = False
        native = book.native
        if native is None or pending or not self._native_call(model, data, native[1]):
            self._evaluate(model, data, book, handles, rows)
        if routable:
            book.native = (self._generation, self._build_route(data, book, handles, rows))
        if self._registry is not None and book.native is not None and book.native[0] == self._generation \
                and not self._registry.routed(model, data):
            self._registry.add(model, data, book.native[1])

    @staticmethod
    def _model_changed(model, book) -> bool:
        """Whether the model's timestep, gravity or geom sizes changed since the handles last checked them."""
        if compiled.ready():
            return _ROUTE.model_changed(book.snapshot, model.opt.timestep, model.opt.gravity, model.geom_size)
        return not np.array_equal(book.snapshot, _ROUTE.snapshot(model))

    @staticmethod
    def _check_model(model, book, handles) -> None:
        """Each handle checks the model's edits since attach (raising on those it cannot follow); then the
        snapshot that the native route compares against is updated in place."""
        for h in handles:
            h._check_model()
        now = _ROUTE.snapshot(model)
        if book.snapshot is None or book.snapshot.shape != now.shape:
            book.snapshot = now
        else:
            book.snapshot[:] = now

    def _native_call(self, model, data, route) -> bool:
        """One evaluation through the native route; False when the Python path must run instead (nothing
        was committed)."""
        code = route.phase1(route.address, data.time, model.opt.timestep)
        if code == _ROUTE.ACTUATE:
            mujoco.mj_fwdActuation(model, data)
            code = route.phase2(route.address, data.time, model.opt.timestep)
        elif code == _ROUTE.CONTINUE:
            code = route.phase2(route.address, data.time, model.opt.timestep)
        if code == _ROUTE.DONE:
            return True
        if code == _ROUTE.MONITOR:
            self._monitor(route, data)
            return True
        return False

    @staticmethod
    def _monitor(route, data) -> None:
        """The validity checks that a native evaluation found due (it committed its wrenches)."""
        for h in route.handles:
            work = h._work.get(data)
            k = int(work.state[sc.S_TOUCHING])
            if h.monitor is not None and k > 0 and int(work.state[sc.S_EVALUATIONS]) % h.monitor.every == 0:
                h._check_validity(data, work, work.arrays["touch"][:k], int(work.state[sc.S_EVALUATIONS]))

    def _build_route(self, data, book, handles, rows):
        """The native route of (model, data) (:class:`rft_mujoco.compiled.route.Route`), with the parts of the
        implicit solve and of the grid update of a deformable surface (``table_part`` of each)."""
        parts = []
        for h in handles:
            h._refresh()
            work = h._workspace(data)
            implicit = _IMPLICIT.table_part(h, work, data) if h.stabilize and h.solve == "implicit" else None
            press = _DEFORM_ROUTE.table_part(work) if work.press is not None else None
            parts.append((work.hc, work.tuple, implicit, press))
        m = handles[0].model
        route = _ROUTE.Route(dict(xfrc=data.xfrc_applied, written=book.written, added=book.added, rows=rows,
                                  user=book.user, sand=book.sand, state=book.state, snapshot=book.snapshot,
                                  gravity=m.opt.gravity, geom_size=m.geom_size), work.md, parts, data,
                             _IMPLICIT.cfunc_address() if any(p[2] is not None for p in parts) else 0,
                             _DEFORM_ROUTE.cfunc_address() if any(p[3] is not None for p in parts) else 0)
        route.handles = handles
        return route

    def _evaluate(self, model, data, book, handles, rows) -> None:
        """One evaluation on the Python path (the native route's reference and fallback)."""
        # With nothing added last time, the user's part is the whole row (read-only for the handles).
        fast = compiled.ready()
        xfrc = data.xfrc_applied
        if not book.nonzero:
            user = xfrc
        elif fast:
            user = book.user
            _ROUTE.user_part(xfrc, book.written, book.added, book.rows, user)
        else:
            user = self.user_xfrc(model, data)
        sand = book.sand
        if book.sand_dirty:
            sand[:] = 0.0
        book.sand_dirty = True
        any_sand = False
        for h in handles:
            if h._evaluate(data, user, sand, book.stage):
                any_sand = True
        if not any_sand and not book.nonzero:
            # Every body above the sand, as before: xfrc_applied already is the user's.
            book.sand_dirty = False
        else:
            if book.rows is not rows:
                stale = np.setdiff1d(book.rows, rows)
                if stale.size:                               # rows of handles detached since the last call
                    xfrc[stale] = user[stale]
            if fast:
                _ROUTE.commit(xfrc, user, sand, rows, book.added, book.written)
            else:
                xfrc[rows] = user[rows] + sand[rows]
                book.added[:] = 0.0
                book.added[rows] = sand[rows]
                book.written[rows] = xfrc[rows]
            book.nonzero = any_sand
        book.rows = rows

    _later_rk4_stage = staticmethod(_DataBook.later_rk4_stage)   # (book, t, dt): its name in compiled/native.py

    def remove_sand(self, model, data, rows: np.ndarray) -> None:
        """Take the sand part out of ``data.xfrc_applied`` rows (used at detach)."""
        book = self._books.get(data)
        if book is None:
            return
        data.xfrc_applied[rows] = self.user_xfrc(model, data)[rows]
        book.added[rows] = 0.0
        book.rows = np.setdiff1d(book.rows, rows)

    def datas_of(self, model) -> list:
        """The MjData objects of ``model`` the dispatcher has written to (and that are still alive)."""
        return [d for d, b in list(self._books.items()) if b.model() is model]


DISPATCHER = Dispatcher()
"""The process-wide dispatcher; use :func:`rft_mujoco.attach` rather than this object."""
