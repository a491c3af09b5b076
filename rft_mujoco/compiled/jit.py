"""numba, its settings for the package's kernels, and the on-disk cache of their machine code.

numba is an optional import: :data:`AVAILABLE` is False when it cannot be imported (the coupling then
runs the numpy reference). Every kernel is ``@njit(cache=True)``; numba keys each function's cache entry
on its own source file only, so a compiled function calling into another module would keep stale machine
code after that module alone changed, and a cache written by another numba, mujoco or numpy version
would be reused. :func:`drop_stale_cache` therefore stamps the cache folder with a key of every kernel
source and of those versions, and removes the cache files when the key differs.
"""

from __future__ import annotations

import glob
import hashlib
import os
import platform

try:  # numba is a dependency, but keep the package importable (and on numpy) without it
    import numba
    from numba import carray, cfunc, njit, types
    AVAILABLE = True
    IMPORT_ERROR: str | None = None
except Exception as exc:  # pragma: no cover - exercised only where numba is missing or broken
    numba = carray = cfunc = types = None
    AVAILABLE = False
    IMPORT_ERROR = f"{type(exc).__name__}: {exc}"

    def njit(*args, **kwargs):  # a no-op decorator so the modules still import
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

JIT = dict(cache=True, fastmath=False, nogil=True, error_model="numpy")
"""Default: IEEE arithmetic, no exception checks on float division (``error_model="numpy"``: a division by
zero gives inf/NaN, masked out afterwards, instead of a Python check that would stop vectorization)."""
INLINE = dict(JIT, inline="always")
"""Scalar building blocks, inlined into the loops that call them."""
JIT_LAW = dict(JIT, fastmath={"contract"})
"""The two element loops: multiply-add fusion (FMA), nothing else; measured 5-7% fewer ns per element,
results within round-off of the numpy law (tests), deterministic run to run."""

COMPILE_SECONDS = 30
"""Rough first-use compile time in s on a 2-core machine, for the notice."""

KERNEL_SOURCES = ("compiled/jit.py", "compiled/terrain.py", "compiled/law.py", "compiled/elements.py",
                  "compiled/element_pass.py", "compiled/rest.py", "compiled/locks.py", "compiled/evaluate.py",
                  "compiled/route.py", "compiled/native.py", "physics/rest.py", "tol.py")
"""Every source file (relative to the package) whose code ends up in compiled machine code."""


def cache_key() -> str:
    """A hash of the kernel sources and of the versions the machine code depends on."""
    import mujoco
    import numpy

    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    digest = hashlib.sha256()
    for name in KERNEL_SOURCES:
        with open(os.path.join(package, name), "rb") as f:
            digest.update(f.read())
    versions = (getattr(numba, "__version__", "-"), mujoco.__version__, numpy.__version__,
                platform.python_version(), platform.machine())
    digest.update(repr(versions).encode())
    return digest.hexdigest()


def drop_stale_cache() -> None:
    """Remove the package's numba cache files when :func:`cache_key` changed since they were written.

    Only for the default cache next to the sources (``compiled/__pycache__``); with ``NUMBA_CACHE_DIR`` set,
    clear that directory after changing the sources or the versions."""
    folder = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    key = cache_key()
    stamp = os.path.join(folder, "rft_mujoco_kernels.key")
    try:
        with open(stamp) as f:
            if f.read().strip() == key:
                return
    except OSError:
        pass
    try:
        os.makedirs(folder, exist_ok=True)
        for path in glob.glob(os.path.join(folder, "*.nb[ic]")):
            os.remove(path)
        with open(stamp, "w") as f:
            f.write(key + "\n")
    except OSError:                  # a read-only install: numba caches elsewhere, keyed by file stamps
        pass
