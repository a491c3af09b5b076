"""The compiled (numba) backend: the coupling's per-evaluation work, the same numbers as the numpy reference.

Modules, each importing only those before it (no cycles):

* :mod:`~rft_mujoco.compiled.jit`: numba, the kernels' settings, the version-keyed on-disk cache;
* :mod:`~rft_mujoco.compiled.terrain`, :mod:`~rft_mujoco.compiled.law`: depth below the free surface, the
  3D-RFT stress (and :func:`~rft_mujoco.compiled.law.element_forces`);
* :mod:`~rft_mujoco.compiled.elements`: packed elements, the broadphase, the element pass, run-time culling;
* :mod:`~rft_mujoco.compiled.rest`: MuJoCo's mass-matrix factor, body Jacobians, the rest solve;
* :mod:`~rft_mujoco.compiled.evaluate`: one handle's evaluation on one MjData (two phases);
* :mod:`~rft_mujoco.compiled.share`: the last step of an evaluation (each body's part, the diagnostics);
* :mod:`~rft_mujoco.compiled.implicit_law`, :mod:`~rft_mujoco.compiled.implicit`,
  :mod:`~rft_mujoco.compiled.implicit_eval`, :mod:`~rft_mujoco.compiled.implicit_route`: the implicit solve
  (``attach(solve="implicit")``): the regularized law and its derivative, the Newton / rest solve with this
  step's constraints linearized, its evaluation, and its C function on the native route;
* :mod:`~rft_mujoco.compiled.table`, :mod:`~rft_mujoco.compiled.route`: every handle of a model as one native
  call per evaluation (the table of its arrays, read in compiled code; the two phases);
* :mod:`~rft_mujoco.compiled.deform`: a deformable surface's grid update (the mirror of
  :func:`rft_mujoco.physics.deform.press`), after each evaluation of a deformable handle.

The rest of the package uses :data:`AVAILABLE`, :func:`ensure_compiled`, :func:`require` and the modules above.
The first use of these sources and versions by a user compiles (about
:data:`~rft_mujoco.compiled.jit.COMPILE_SECONDS` on a 2-core machine) and caches the machine code per user
(:func:`~rft_mujoco.compiled.jit.cache_dir`); while numba compiles, a progress line on stderr says what
happens and for how long (:class:`_Progress`); nothing is printed when the cache has everything.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time

from rft_mujoco.compiled.jit import AVAILABLE, COMPILE_SECONDS, COMPILE_SECONDS_PARALLEL, IMPORT_ERROR

_log = logging.getLogger("rft_mujoco")
_compiled = False
_lock = threading.Lock()


class _Progress:
    """Says on stderr (and the "rft_mujoco" logger) that numba compiles the package's kernels, with the time
    so far every :data:`TICK_S` s, and the total when it is done. numba reports each compile as an event;
    compiles of the package's kernels (``rft_mujoco.compiled``) start the reporter, and :data:`IDLE_S` s
    without one end it, except while :func:`ensure_compiled` holds it (:meth:`hold`): its warm-up is one
    report, pauses between numba's compile events (the C callbacks, machine code) included."""

    TICK_S = 15.0
    IDLE_S = 2.0

    def __init__(self, stream=None):
        self.stream = stream
        self.depth = 0
        self.holding = 0              # > 0 while ensure_compiled runs: no end of the report before it returns
        self.started = None           # perf_counter of the first compile of this burst
        self.last = 0.0               # perf_counter of the last compile event
        self.total = 0.0              # s compiled in earlier bursts
        self.thread = None
        self.cond = threading.Condition()
        self.estimate = COMPILE_SECONDS   # s, for the first line
        self.where = ""                   # how the compile is split, for the first line
        self.current = []                 # the kernels numba compiles now (innermost last), or what is awaited

    def _say(self, msg: str) -> None:
        _log.info(msg)
        print(msg, file=self.stream or sys.stderr, flush=True)

    say = _say

    def plan(self, parallel: bool) -> None:
        """The estimate and the split of the warm-up about to run (phase 2 in a second process or not)."""
        self.estimate = COMPILE_SECONDS_PARALLEL if parallel else COMPILE_SECONDS
        self.where = "; the rest treatment in a second process" if parallel else ""

    def now(self, what: str) -> None:
        """Name what is being waited for (shown on the next progress line)."""
        with self.cond:
            self.current = [what]

    def start(self, name: str = "") -> None:
        with self.cond:
            self.depth += 1
            if name:
                self.current.append(name)
            self.last = time.perf_counter()
            if self.started is not None:
                return
            self.started = self.last
        from rft_mujoco.compiled import jit

        where = jit.cache_dir() if jit.PER_USER_CACHE else "numba's cache"
        if self.total == 0.0:
            self._say(f"rft_mujoco: compiling the numba kernels, once for this user and version (about "
                      f"{self.estimate:.0f} s on a 2-core machine, more on a busy one{self.where}); cached in {where}")
        else:
            self._say(f"rft_mujoco: compiling more numba kernels ({self.total:.0f} s so far)")
        self.thread = threading.Thread(target=self._run, name="rft_mujoco-compile-progress", daemon=True)
        self.thread.start()

    def end(self, name: str = "") -> None:
        with self.cond:
            self.depth = max(self.depth - 1, 0)
            if name in self.current:
                self.current.remove(name)
            self.last = time.perf_counter()
            self.cond.notify_all()

    def hold(self) -> None:
        with self.cond:
            self.holding += 1

    def release(self) -> None:
        with self.cond:
            self.holding = max(self.holding - 1, 0)
            self.last = time.perf_counter()
            self.cond.notify_all()

    def _run(self) -> None:
        next_tick = self.started + self.TICK_S
        with self.cond:
            while True:
                now = time.perf_counter()
                if self.depth == 0 and self.holding == 0 and now - self.last >= self.IDLE_S:
                    break
                if now >= next_tick:
                    doing = f"; now {self.current[-1]}" if self.current else ""
                    self._say(f"rft_mujoco: still compiling ({self.total + now - self.started:.0f} s so far{doing})")
                    next_tick += self.TICK_S
                self.cond.wait(min(next_tick - now, self.IDLE_S, 1.0))
            seconds = self.last - self.started
            self.total += seconds
            self.started, self.thread = None, None
        self._say(f"rft_mujoco: numba kernels compiled ({self.total:.0f} s); later runs load them from the cache")


def _name(func) -> str:
    return f"{func.__module__.rsplit('.', 1)[-1]}.{func.__name__}"


def _install_progress() -> _Progress | None:
    if not AVAILABLE:
        return None
    from numba.core import event

    progress = _Progress()

    class _Listener(event.Listener):
        def on_start(self, ev):
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            if getattr(func, "__module__", "").startswith("rft_mujoco.compiled."):
                progress.start(_name(func))

        def on_end(self, ev):
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            if getattr(func, "__module__", "").startswith("rft_mujoco.compiled."):
                progress.end(_name(func))

    event.register("numba:compile", _Listener())
    return progress


_PROGRESS = _install_progress()

__all__ = ["AVAILABLE", "IMPORT_ERROR", "ensure_compiled", "ready", "require"]


def ready() -> bool:
    """Whether :func:`ensure_compiled` has run in this process (the kernels are loaded)."""
    return _compiled


def require() -> None:
    """Raise RuntimeError when numba is missing; compile (or load) the kernels otherwise."""
    if not AVAILABLE:
        raise RuntimeError(f"numba is not available ({IMPORT_ERROR}); use the numpy reference "
                           "(attach(..., backend='numpy'))")
    ensure_compiled()


def ensure_compiled(verbose: bool = True) -> float:
    """Compile (or load from numba's cache) the coupling's kernels (:mod:`~rft_mujoco.compiled.warmup`: the
    native route and callbacks; the Python path's and ``element_forces``' compile at their first call), once
    per process; returns the seconds it took (0 when already done). Prints progress lines to stderr (and
    logs them on the "rft_mujoco" logger) only when numba actually compiles something."""
    global _compiled
    if _compiled or not AVAILABLE:
        return 0.0
    with _lock:
        if _compiled:
            return 0.0
        from rft_mujoco.compiled import jit, warmup

        t0 = time.perf_counter()
        if not jit.PER_USER_CACHE:
            jit.drop_stale_cache()
        else:
            jit.seed_from_shipped()
        if _PROGRESS is not None and not verbose:
            _PROGRESS.stream = open(os.devnull, "w")  # noqa: SIM115 (kept for the process)
        if _PROGRESS is not None:
            _PROGRESS.hold()
        try:
            warmup.run(_PROGRESS)
        finally:
            if _PROGRESS is not None:
                _PROGRESS.release()
        _compiled = True
        return time.perf_counter() - t0
