"""numba, its settings for the package's kernels, and the on-disk cache of their machine code.

numba is an optional import: :data:`AVAILABLE` is False when it cannot be imported (the coupling then
runs the numpy reference). Every kernel is ``@njit(cache=True)``; numba keys each function's cache entry
on its own source file only, so a compiled function calling into another module would keep stale machine
code after that module alone changed, and a cache written by another numba, mujoco or numpy version
would be reused. The machine code is therefore cached per user, in a folder named by :func:`cache_key`
(a hash of every kernel source and of those versions): :func:`cache_dir`, by default
``~/.cache/rft_mujoco/numba/<key>`` (``$RFT_MUJOCO_CACHE_DIR/<key>`` when set). Every install of the
same sources and versions (a new venv, a read-only site-packages, a wheel) finds the machine code there
and compiles nothing. With ``NUMBA_CACHE_DIR`` set numba's own locations are used instead, and
:func:`drop_stale_cache` guards the in-tree cache.
"""

from __future__ import annotations

import copy as _copy
import glob
import hashlib
import os
import platform
import threading

try:  # numba is a dependency, but keep the package importable (and on numpy) without it
    import numba
    from numba import carray, cfunc, types
    from numba.core.registry import CPUDispatcher
    AVAILABLE = True
    IMPORT_ERROR: str | None = None
except Exception as exc:  # pragma: no cover - exercised only where numba is missing or broken
    numba = carray = cfunc = types = CPUDispatcher = None
    AVAILABLE = False
    IMPORT_ERROR = f"{type(exc).__name__}: {exc}"

    def njit(*args, **kwargs):  # a no-op decorator so the modules still import
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

if AVAILABLE:
    class _Dispatcher(CPUDispatcher):
        """numba's CPU dispatcher, except that a call from compiled code is typed with its arguments' plain
        types: numba compiles a called function once per literal type it meets, those of constant
        arguments (``False``) and the intermediate types of the caller's type inference (``ng = 0``
        before its loop's ``ng += 1`` makes ``Literal[int](0)``), each specialization a whole compile of
        the callee and of everything it calls (profiled: 34 s of the 250 s of CPU the demo's kernels took
        to compile before this dispatcher, docs/performance.md "First use"). The kernels gain nothing from
        literal arguments; LLVM folds the constants it sees."""

        def get_call_template(self, args, kws):
            return super().get_call_template(tuple(types.unliteral(a) for a in args),
                                             {k: types.unliteral(v) for k, v in kws.items()})

    def njit(*args, **kwargs):
        """``numba.njit`` with :class:`_Dispatcher`: one compile per plain signature."""
        made = numba.njit(*args, **kwargs)

        def plain(dispatcher):
            dispatcher.__class__ = _Dispatcher
            return dispatcher
        return plain(made) if isinstance(made, CPUDispatcher) else (lambda f: plain(made(f)))

def _share_inline_copies() -> bool:
    """Make numba's inliner copy a callee's blocks with one ``deepcopy`` memo instead of one per block.

    For every ``inline="always"`` call site numba copies the callee's IR block by block, each block with its
    own ``copy.deepcopy``; every variable holds the function's scope, so each block copies the whole scope
    again (all the callee's variables): quadratic in the callee's size. Profiled on the route's phase 2
    (docs/performance.md "The very first compile"): 115 of its 249 profiled CPU s were these copies. With one
    memo per inlined call the blocks share one copy of the scope, as the original blocks share theirs;
    numba then renames the variables and moves the blocks into the caller's scope, as before. Only calls
    inlined into this package's functions share a memo (numba compiles everyone else's code exactly as
    before); applied only where numba's inliner has the layout this relies on (its one ``copy`` use is that block copy); returns
    whether it was applied."""
    try:
        from numba.core import inline_closurecall as icc
    except ImportError:
        return False
    worker = getattr(icc, "InlineWorker", None)
    if (getattr(icc, "copy", None) is not _copy or worker is None or not hasattr(worker, "inline_ir")
            or getattr(worker.inline_ir, "_rft_shared_memo", False)):
        return False
    local = threading.local()

    class _Copy:
        """The inliner's ``copy`` module: ``deepcopy`` shares the memo of the inlined call being copied."""
        copy = staticmethod(_copy.copy)

        @staticmethod
        def deepcopy(x, memo=None, _nil=[]):  # noqa: B006 (copy.deepcopy's own signature)
            memos = getattr(local, "memos", None)
            if memo is None and memos and memos[-1] is not None:
                memo = memos[-1]
            return _copy.deepcopy(x, memo, _nil)

    original = worker.inline_ir

    def inline_ir(self, caller_ir, *args, **kwargs):
        memos = local.__dict__.setdefault("memos", [])
        ours = str(getattr(getattr(caller_ir, "func_id", None), "modname", "")).startswith("rft_mujoco.")
        memos.append({} if ours else None)          # other code's inlining is left exactly as numba does it
        try:
            return original(self, caller_ir, *args, **kwargs)
        finally:
            memos.pop()

    inline_ir._rft_shared_memo = True
    inline_ir.__doc__ = original.__doc__
    worker.inline_ir = inline_ir
    icc.copy = _Copy
    return True


SHARED_INLINE_COPIES = _share_inline_copies() if AVAILABLE else False
"""Whether :func:`_share_inline_copies` applies (it halves the route's compile)."""

JIT = dict(cache=True, fastmath=False, nogil=True, error_model="numpy")
"""Default: IEEE arithmetic, no exception checks on float division (``error_model="numpy"``: a division by
zero gives inf/NaN, masked out afterwards, instead of a Python check that would stop vectorization)."""
INLINE = dict(JIT, inline="always")
"""Functions inlined by numba into their callers: the per-element scalar helpers of the element loops, the
route's table accessors, and the evaluation's two phases into the route's (as plain calls, the tuples of
120 arrays they take cost 2-5 us a call, measured). numba types, lowers and LLVM optimizes an inlined body
again in each function it is inlined into: a large one belongs in one entry point only (docs/performance.md
"First use")."""
JIT_LAW = dict(JIT, fastmath={"contract"})
"""The two element loops: multiply-add fusion (FMA), nothing else; measured 5-7% fewer ns per element,
results within round-off of the numpy law (tests), deterministic run to run."""

COMPILE_SECONDS = 60
"""First-use compile time in s on a quiet 2-core machine in one process, for the progress line: about the CPU
seconds the demo's first use took in one process (73 at load average 5, docs/performance.md "The very first
compile", third round)."""
COMPILE_SECONDS_PARALLEL = 40
"""The same with the rest treatment compiled in a second process (:mod:`rft_mujoco.compiled.warmup`): the
second process's CPU seconds (35 at load average 5; its compile is the critical path) plus the first's
loading of its result and the warm-up."""

KERNEL_SOURCES = ("compiled/jit.py", "compiled/terrain.py", "compiled/law.py", "compiled/elements.py",
                  "compiled/element_pass.py", "compiled/rest.py", "compiled/locks.py", "compiled/evaluate.py",
                  "compiled/table.py", "compiled/route.py", "compiled/native.py", "compiled/implicit_law.py",
                  "compiled/implicit.py", "compiled/system.py", "compiled/implicit_eval.py", "compiled/deform.py",
                  "compiled/share.py", "compiled/implicit_route.py", "compiled/deform_route.py", "compiled/schema.py",
                  "physics/terrain_spec.py", "physics/rest.py", "tol.py")
"""Every source file (relative to the package) whose code or constants end up in compiled machine code (the
named slots of ``compiled/schema.py`` and ``physics/terrain_spec.py`` are frozen into it)."""


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


CACHE_ENV = "RFT_MUJOCO_CACHE_DIR"
"""Environment variable: parent folder of the per-user cache (default: the user's cache folder)."""


def cache_root() -> str:
    """``$RFT_MUJOCO_CACHE_DIR``, else the user's cache folder + ``rft_mujoco/numba``
    (``~/.cache/rft_mujoco/numba`` on Linux)."""
    if os.environ.get(CACHE_ENV):
        return os.path.abspath(os.path.expanduser(os.environ[CACHE_ENV]))
    from numba.misc.appdirs import AppDirs

    return os.path.join(AppDirs(appname="rft_mujoco", appauthor=False).user_cache_dir, "numba")


_KEY: list[str] = []


def cache_dir() -> str:
    """The folder of this install's machine code: :func:`cache_root` / first 16 hex digits of :func:`cache_key`."""
    if not _KEY:
        _KEY.append(cache_key()[:16])
    return os.path.join(cache_root(), _KEY[0])


def _package_cache_locator():
    """A numba cache locator for the package's own kernels: :func:`cache_dir`, sources stamped by content
    (so that copies of the same file at other paths, in other venvs, share the entries); None when
    numba's internals differ from what it needs (numba's own locators are then used)."""
    try:
        from numba.core import caching
        base = (caching._CacheLocator,)
    except (ImportError, AttributeError):
        return None
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

    class PackageCacheLocator(*base):
        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            sub = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), package)
            self._cache_path = os.path.join(cache_dir(), sub.replace(os.sep, "_"))

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            with open(self._py_file, "rb") as f:
                return hashlib.sha256(f.read()).hexdigest()

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if numba.config.CACHE_DIR or not os.path.isfile(py_file):
                return None
            if os.path.commonpath([package, os.path.abspath(py_file)]) != package:
                return None
            self = cls(py_func, py_file)
            try:
                self.ensure_cache_path()
            except OSError:          # no writable cache folder: numba's own locators decide
                return None
            return self

    return PackageCacheLocator


def _install_locator() -> bool:
    """Put :func:`_package_cache_locator` first in numba's list (only the package's files use it)."""
    if not AVAILABLE:
        return False
    locator = _package_cache_locator()
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)  # numba >= 0.62 / older
    classes = getattr(impl, "_locator_classes", None)
    if locator is None or not isinstance(classes, list):
        return False
    if not any(getattr(c, "__name__", "") == locator.__name__ for c in classes):
        classes.insert(0, locator)
    return True


PER_USER_CACHE = _install_locator()
"""Whether the package's kernels are cached in :func:`cache_dir` (False: numba's own locations)."""


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


SHIPPED_ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "machine_code")
"""Machine code shipped with the package (``python -m rft_mujoco compile --ship`` before building a wheel):
``machine_code/<key>``, laid out as :func:`cache_dir`. Not in the repository; a wheel built after it
carries it."""
NO_SHIPPED_ENV = "RFT_MUJOCO_NO_SHIPPED_CODE"
"""Environment variable: set (to anything but "" or "0") to ignore the shipped machine code (to measure a
first compile)."""


def shipped_dir() -> str:
    """The shipped machine code of these sources and versions: :data:`SHIPPED_ROOT` / the key of :func:`cache_dir`."""
    return os.path.join(SHIPPED_ROOT, os.path.basename(cache_dir()))


def has_index(folder: str) -> bool:
    """Whether ``folder`` (a :func:`cache_dir`) holds any numba cache index."""
    return bool(glob.glob(os.path.join(folder, "*", "*.nbi")))


def seed_from_shipped() -> int:
    """Copy the shipped machine code (:func:`shipped_dir`) into the user's cache when the user's cache of this
    key holds none yet (a first use of these sources and versions); returns the number of files copied.

    Safe wherever it is copied to: the key names the sources and the numba, mujoco, numpy and Python
    versions; numba keeps an entry per signature and CPU (its name and features) and checks the source
    stamps (contents, :func:`_package_cache_locator`), so on another CPU numba compiles as without it."""
    if not PER_USER_CACHE or os.environ.get(NO_SHIPPED_ENV, "0") not in ("", "0"):
        return 0
    source, target = shipped_dir(), cache_dir()
    if not os.path.isdir(source) or has_index(target):
        return 0
    import shutil

    copied = 0
    for sub in sorted(os.listdir(source)):
        files = sorted(glob.glob(os.path.join(source, sub, "*.nb[ic]")))
        try:
            os.makedirs(os.path.join(target, sub), exist_ok=True)
            for path in sorted(files, key=lambda p: p.endswith(".nbi")):   # the indexes last
                tmp = os.path.join(target, sub, f".{os.path.basename(path)}.{os.getpid()}")
                shutil.copyfile(path, tmp)
                os.replace(tmp, os.path.join(target, sub, os.path.basename(path)))
                copied += 1
        except OSError:              # an unwritable cache: numba compiles (and says so) as without it
            return copied
    return copied
