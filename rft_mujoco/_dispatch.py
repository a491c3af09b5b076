"""The one process-wide MuJoCo control-callback dispatcher (the package's only module-level mutable state).

MuJoCo callbacks are global to the process, so every attached sand handle of every model goes through
one dispatcher installed with ``mujoco.set_mjcb_control``. It

* chains a control callback the user had installed before (called first, so ``ctrl`` is final);
* routes each evaluation to the handles of that model (several models and datas work independently);
* owns the ``xfrc_applied`` bookkeeping per MjData, so that the row always ends as user wrench + sand
  wrench, whether the user left the row alone (we subtract what we added), zeroed it, or assigned a new
  wrench between steps (a row that differs from what we wrote is taken as the user's new value);
* keeps model compilation working while installed: mujoco 4.0's compiler raises "Python exception
  raised" whenever any Python callback is installed, so the compile entry points
  (``MjModel.from_xml_string / from_xml_path / from_binary_path``, ``MjSpec.compile / recompile``) are
  wrapped to suspend the callback for the duration of the call. The wrappers are removed when the last
  handle detaches.
"""

from __future__ import annotations

import functools
import threading
import weakref

import mujoco
import numpy as np

from . import fastkernel, native

_COMPILE_ENTRY_POINTS = (
    (mujoco.MjModel, "from_xml_string", True),
    (mujoco.MjModel, "from_xml_path", True),
    (mujoco.MjModel, "from_binary_path", True),
    (mujoco.MjSpec, "compile", False),
    (mujoco.MjSpec, "recompile", False),
)


_RK4 = int(mujoco.mjtIntegrator.mjINT_RK4)


class _DataBook:
    """Per-MjData record of what the sand added to ``xfrc_applied`` (rows of all bodies)."""

    __slots__ = ("added", "written", "rows", "model", "sand", "user", "plain", "own", "state", "__weakref__")

    def __init__(self, model, data) -> None:
        nbody = model.nbody
        self.model = weakref.ref(model)
        self.added = np.zeros((nbody, 6))
        self.written = np.zeros((nbody, 6))
        self.rows = np.zeros(0, dtype=np.int64)
        self.sand = np.zeros((nbody, 6))     # the handles' sum of this evaluation (reused buffer)
        self.user = np.zeros((nbody, 6))      # the user's part of xfrc_applied (reused buffer)
        # Addresses for the handles' native calls: (user wrenches, sand) when the user's part is
        # xfrc_applied itself, and when it is ``user`` (MjData's arrays never move).
        self.plain = (data.xfrc_applied.ctypes.data, self.sand.ctypes.data)
        self.own = (self.user.ctypes.data, self.sand.ctypes.data)
        # The flags and the RK4 stage tracking in one array (the native route reads and writes it too):
        # nonzero (``added`` has a non-zero entry), sand_dirty (``sand`` needs zeroing), and for handles with
        # rk4_stages="first" how many stages of the step have been seen (0: none pending) and the time of
        # its first stage (s).
        self.state = np.zeros(4)

    nonzero = native.Slot("state", 0, bool)
    sand_dirty = native.Slot("state", 1, bool)
    stage = native.Slot("state", 2, int)
    stage_time = native.Slot("state", 3, float)


class _NativeEntry:
    """The dispatcher's record of one MjData's native route (``call`` None: the model has a handle that
    does not take the native call), valid while ``generation`` is the dispatcher's."""

    __slots__ = ("data", "model", "generation", "opt", "call", "address", "route")

    def __init__(self, data, model, generation: int, route) -> None:
        self.data = weakref.ref(data)
        self.model = model
        self.generation = generation
        self.opt = model.opt
        self.call = None if route is None else native.route_entry()
        self.address = None if route is None else route.address
        self.route = route                   # keeps the route's arrays alive


class Dispatcher:
    def __init__(self) -> None:
        self._handles: list = []
        self._chained = None
        self._originals: dict = {}
        self._books: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self._routes: dict = {}              # id(model) -> (model, handles, rows), rebuilt on (un)register
        self._lock = threading.RLock()
        # Native routes: id(MjData) -> _NativeEntry, used only while its generation is current
        # (invalidate() bumps it).
        self._native: dict = {}
        self._generation = 0
        self.native_routes = True
        """Make the whole callback one native call (:class:`rft_mujoco.native.Route`) for a model whose
        handles all take the native call; False keeps every evaluation on the Python path (the tests
        compare the two)."""

    # --- registration ---------------------------------------------------------------------------
    def register(self, handle) -> None:
        with self._lock:
            if not self._handles:
                self._install()
            self._handles.append(handle)
            self._routes.clear()
            self.invalidate()

    def unregister(self, handle) -> None:
        with self._lock:
            if handle in self._handles:
                self._handles.remove(handle)
            self._routes.clear()
            self.invalidate()
            if not self._handles:
                self._uninstall()

    def invalidate(self) -> None:
        """Forget the native routes (a handle, a terrain, gravity or a setting changed): the next
        evaluation of each MjData runs in Python and rebuilds its route."""
        self._generation += 1

    @property
    def handles(self) -> tuple:
        return tuple(self._handles)

    def _install(self) -> None:
        current = mujoco.get_mjcb_control()
        self._chained = current if current is not self else None
        mujoco.set_mjcb_control(self)
        for owner, name, static in _COMPILE_ENTRY_POINTS:
            original = owner.__dict__[name] if name in owner.__dict__ else getattr(owner, name)
            self._originals[(owner, name)] = original
            func = original.__func__ if isinstance(original, staticmethod) else original
            wrapped = self._suspending(func)
            setattr(owner, name, staticmethod(wrapped) if static else wrapped)

    def _uninstall(self) -> None:
        if mujoco.get_mjcb_control() is self:
            mujoco.set_mjcb_control(self._chained)
        self._chained = None
        for (owner, name), original in self._originals.items():
            setattr(owner, name, original)
        self._originals.clear()

    def _suspending(self, func):
        @functools.wraps(func)
        def call(*args, **kwargs):
            with self._lock:
                current = mujoco.get_mjcb_control()
                mujoco.set_mjcb_control(None)
                try:
                    return func(*args, **kwargs)
                finally:
                    mujoco.set_mjcb_control(current)
        return call

    # --- xfrc bookkeeping -------------------------------------------------------------------------
    def book(self, model, data) -> _DataBook:
        book = self._books.get(data)
        if book is None or book.added.shape[0] != model.nbody:
            book = self._books[data] = _DataBook(model, data)
        return book

    def user_xfrc(self, model, data) -> np.ndarray:
        """(nbody, 6) the user's own part of ``data.xfrc_applied`` (sand contribution removed)."""
        book = self.book(model, data)
        xfrc = data.xfrc_applied
        user = xfrc.copy()
        rows = book.rows
        if rows.size:
            untouched = np.all(xfrc[rows] == book.written[rows], axis=1)
            r = rows[untouched]
            user[r] -= book.added[r]
        return user

    # --- the callback -----------------------------------------------------------------------------
    def _route(self, model):
        """(handles of ``model``, their body rows) -- cached until a handle is (un)registered."""
        route = self._routes.get(id(model))
        if route is None or route[0] is not model:
            handles = tuple(h for h in self._handles if h.model is model)
            rows = np.unique(np.concatenate([h.body_ids for h in handles])) if handles else None
            route = self._routes[id(model)] = (model, handles, rows)
        return route[1], route[2]

    def __call__(self, model, data) -> None:
        if self._chained is not None:
            self._chained(model, data)
        fast = self._native.get(id(data))
        if fast is not None and fast.call is not None and fast.generation == self._generation \
                and fast.model is model and fast.data() is data:
            opt = fast.opt
            if fast.call(fast.address, data.time, opt.timestep, opt.integrator) == native.ROUTE_DONE:
                return
        self._evaluate(model, data)

    def _evaluate(self, model, data) -> None:
        """One evaluation on the Python path (what the native route does, and its reference)."""
        handles, rows = self._route(model)
        if not handles:
            return
        book = self._books.get(data)
        if book is None or book.added.shape[0] != model.nbody:
            book = self.book(model, data)
        if model.opt.integrator == _RK4 and all(h.rk4_stages == "first" for h in handles):
            if self._later_rk4_stage(book, data.time, model.opt.timestep):
                return                       # xfrc_applied still holds the first stage's user + sand wrench
        else:
            book.stage = 0
        # With nothing added last time, the user's part is the whole row (read-only for the handles).
        fast = fastkernel.ready()
        xfrc = data.xfrc_applied
        if not book.nonzero:
            user, addresses = xfrc, book.plain
        elif fast:
            user, addresses = book.user, book.own
            fastkernel.user_part(xfrc, book.written, book.added, book.rows, user)
        else:
            user, addresses = self.user_xfrc(model, data), None
        sand = book.sand
        if book.sand_dirty:
            sand[:] = 0.0
        book.sand_dirty = True
        any_sand = False
        for h in handles:
            if h._evaluate(data, user, sand, addresses) is not False:
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
                fastkernel.commit(xfrc, user, sand, rows, book.added, book.written)
            else:
                xfrc[rows] = user[rows] + sand[rows]
                book.added[:] = 0.0
                book.added[rows] = sand[rows]
                book.written[rows] = xfrc[rows]
            book.nonzero = any_sand
        book.rows = rows
        if fast and self.native_routes:
            entry = self._native.get(id(data))
            if entry is None or entry.generation != self._generation or entry.data() is not data:
                self._build_route(model, data, book, handles, rows)

    def _build_route(self, model, data, book: _DataBook, handles, rows) -> None:
        """The native route of (model, data), or a record that there is none (a handle that does not take
        the native call), valid until :meth:`invalidate`."""
        route = None
        works = [h._work.get(data) for h in handles]
        if native.route_entry() is not None and all(
                h._gravity_seen is not None and h._takes_native_call(h._g_hat)
                and w is not None and w.native is not None and w.native.source is h._fast
                for h, w in zip(handles, works)):
            for h in handles:
                h._counts[1] = 0 if h.monitor is None else h.monitor.every
            route = native.Route(
                dict(state=book.state, xfrc=data.xfrc_applied, written=book.written, added=book.added,
                     rows=rows, user=book.user, sand=book.sand),
                [dict(table=w.native, g_hat=h._g_hat, gravity=h._gravity_vec,
                      flags=native.flags(h.warm_start, h.guards), counts=h._counts, state=w.state,
                      xi_n=h._media.xi_n_at(h._g_mag), mu_surf=h._media.mu_surf, max_height=h._max_height)
                 for h, w in zip(handles, works)],
                all(h.rk4_stages == "first" for h in handles), handles[0]._opt_gravity)
        for key, entry in list(self._native.items()):       # forget the MjData that are gone
            if entry.data() is None:
                del self._native[key]
        self._native[id(data)] = _NativeEntry(data, model, self._generation, route)

    @staticmethod
    def _later_rk4_stage(book: _DataBook, t: float, dt: float) -> bool:
        """Whether an evaluation at time ``t`` is stage 2, 3 or 4 of the RK4 step whose first stage the
        book saw last (mj_RungeKutta evaluates at t0 + dt/2, t0 + dt/2, t0 + dt after mj_forward at t0);
        otherwise it is a first stage (mj_step's mj_forward, or any mj_forward) and is recorded as one."""
        n = book.stage
        if 1 <= n <= 3 and abs(t - (book.stage_time + native.RK4_STAGE_TIMES[n - 1] * dt)) <= 1e-9 * dt:
            book.stage = n + 1
            return True
        book.stage_time = t
        book.stage = 1
        return False

    def remove_sand(self, model, data, rows: np.ndarray) -> None:
        """Take the sand part out of ``data.xfrc_applied`` rows (used at detach)."""
        book = self._books.get(data)
        if book is None:
            return
        user = self.user_xfrc(model, data)
        data.xfrc_applied[rows] = user[rows]
        book.added[rows] = 0.0
        book.rows = np.setdiff1d(book.rows, rows)

    def datas_of(self, model) -> list:
        """The MjData objects of ``model`` the dispatcher has written to (and that are still alive)."""
        return [d for d, b in list(self._books.items()) if b.model() is model]


DISPATCHER = Dispatcher()
"""The process-wide dispatcher; use :func:`rft_mujoco.attach` rather than this object."""
