"""The compiled (numba) backend: the coupling's per-evaluation work, the same numbers as the numpy reference.

Modules, each importing only those before it (no cycles):

* :mod:`~rft_mujoco.compiled.jit`: numba, the kernels' settings, the version-keyed on-disk cache;
* :mod:`~rft_mujoco.compiled.terrain`, :mod:`~rft_mujoco.compiled.law`: depth below the free surface, the
  3D-RFT stress (and :func:`~rft_mujoco.compiled.law.element_forces`);
* :mod:`~rft_mujoco.compiled.elements`: packed elements, the broadphase, the element pass, run-time culling;
* :mod:`~rft_mujoco.compiled.rest`: MuJoCo's mass-matrix factor, body Jacobians, the rest solve;
* :mod:`~rft_mujoco.compiled.evaluate`: one handle's evaluation on one MjData (two phases);
* :mod:`~rft_mujoco.compiled.route`: every handle of a model as one native call per evaluation.

The rest of the package uses :data:`AVAILABLE`, :func:`ensure_compiled`, :func:`require` and the modules above.
The first use on a machine compiles (about :data:`~rft_mujoco.compiled.jit.COMPILE_SECONDS`) and caches the
machine code; :func:`ensure_compiled` says so on stderr only when it actually compiles.
"""

from __future__ import annotations

import logging
import sys
import threading
import time

from rft_mujoco.compiled.jit import AVAILABLE, COMPILE_SECONDS, IMPORT_ERROR

_log = logging.getLogger("rft_mujoco")
_compiled = False
_lock = threading.Lock()

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
    """Compile (or load from numba's cache) every kernel for the argument types the package passes, once per
    process; returns the seconds it took (0 when already done). Prints one line to stderr (and logs it on
    the "rft_mujoco" logger) only when numba actually compiles something."""
    global _compiled
    if _compiled or not AVAILABLE:
        return 0.0
    with _lock:
        if _compiled:
            return 0.0
        from numba.core import event

        from rft_mujoco.compiled import jit, warmup

        shown = []

        class _Notice(event.Listener):
            def on_start(self, ev):
                if not shown and verbose:
                    shown.append(True)
                    msg = f"rft_mujoco: compiling the numba kernels (first use, ~{COMPILE_SECONDS} s; cached afterwards)"
                    _log.info(msg)
                    print(msg, file=sys.stderr, flush=True)

            def on_end(self, ev):
                pass

        t0 = time.perf_counter()
        jit.drop_stale_cache()
        with event.install_listener("numba:compile", _Notice()):
            warmup.run()
        _compiled = True
        seconds = time.perf_counter() - t0
        if shown:
            _log.info("rft_mujoco: numba kernels compiled in %.1f s", seconds)
        return seconds
