"""First use: the numba cache per user, keyed by sources and versions and shared by every install; the
progress lines while numba compiles."""

from __future__ import annotations

import hashlib
import io
import os
import sys
import time

import numpy as np
import pytest

from rft_mujoco import compiled
from rft_mujoco.compiled import jit

pytestmark = pytest.mark.skipif(not jit.AVAILABLE, reason="numba is not available")


def test_kernels_are_cached_per_user_by_content(monkeypatch, tmp_path):
    from rft_mujoco.compiled import law

    assert jit.PER_USER_CACHE
    assert os.path.basename(jit.cache_dir()) == jit.cache_key()[:16]
    locator_cls = jit._package_cache_locator()
    func = law._element_forces.py_func
    locator = locator_cls.from_function(func, law.__file__)
    assert locator.get_cache_path() == os.path.join(jit.cache_dir(), "compiled")
    with open(law.__file__, "rb") as f:                      # the content, not the path or the mtime
        assert locator.get_source_stamp() == hashlib.sha256(f.read()).hexdigest()
    outside = tmp_path / "user_code.py"
    outside.write_text("def f():\n    return 1\n")
    assert locator_cls.from_function(func, str(outside)) is None     # a user's own kernels: numba's locators
    assert law._element_forces._cache._impl.locator.get_cache_path() == locator.get_cache_path()
    monkeypatch.setenv(jit.CACHE_ENV, str(tmp_path / "elsewhere"))
    assert jit.cache_root() == str(tmp_path / "elsewhere")


def test_progress_lines_while_compiling(monkeypatch):
    stream = io.StringIO()
    progress = compiled._Progress(stream)
    monkeypatch.setattr(progress, "TICK_S", 0.05)
    monkeypatch.setattr(progress, "IDLE_S", 0.3)
    progress.plan(parallel=True)
    progress.start("route.phase1")
    time.sleep(0.2)
    progress.end("route.phase1")
    progress.thread.join(timeout=5)
    lines = stream.getvalue().splitlines()
    assert f"about {jit.COMPILE_SECONDS_PARALLEL:.0f} s" in lines[0] and "a second process" in lines[0]
    assert "; now route.phase1)" in lines[1]
    assert lines[0].startswith("rft_mujoco: compiling the numba kernels, once for this user and version "
                               f"(about {jit.COMPILE_SECONDS_PARALLEL:.0f} s")
    assert any(line.startswith("rft_mujoco: still compiling (") for line in lines[1:-1])
    assert lines[-1].startswith("rft_mujoco: numba kernels compiled (")
    progress.start()                                         # a later burst continues the count
    progress.end()
    progress.thread.join(timeout=5)
    assert "compiling more numba kernels" in stream.getvalue()


def test_progress_is_one_report_while_held(monkeypatch):
    """ensure_compiled holds the report: pauses between numba's compile events do not end it."""
    stream = io.StringIO()
    progress = compiled._Progress(stream)
    monkeypatch.setattr(progress, "TICK_S", 10.0)
    monkeypatch.setattr(progress, "IDLE_S", 0.05)
    progress.hold()
    progress.start()
    progress.end()
    time.sleep(0.3)                                          # idle, but held
    assert "numba kernels compiled" not in stream.getvalue()
    progress.start()
    progress.end()
    thread = progress.thread
    progress.release()
    thread.join(timeout=5)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2 and lines[-1].startswith("rft_mujoco: numba kernels compiled (")


def test_calls_between_kernels_compile_one_plain_specialization():
    """A counter starting at 0 or a constant argument does not compile literal specializations."""
    import numpy as np

    @jit.njit(cache=False)
    def callee(n, flag):
        return n + 1 if flag else n

    @jit.njit(cache=False)
    def caller(a):
        ng = 0
        for i in range(a.shape[0]):
            if a[i]:
                ng += 1
        return callee(ng, True) + callee(ng, a.shape[0] > 5)

    assert caller(np.ones(3, np.bool_)) == 7
    assert [str(t) for t in callee.signatures[0]] == ["int64", "bool"] and len(callee.signatures) == 1


def test_shipped_machine_code_is_copied_once_and_loads_without_compiling(monkeypatch, tmp_path):
    """Machine code compiled under one cache root, shipped, and copied into an empty user cache elsewhere is
    loaded by numba (content stamps, not paths or mtimes); an existing user cache is left alone."""
    from rft_mujoco.compiled import route

    def fresh():                              # a new dispatcher of a package kernel: nothing in memory
        return jit.njit(**jit.JIT)(route.model_changed.py_func)

    args = (np.zeros(7), 0.01, np.zeros(3), np.zeros((1, 3)))
    monkeypatch.setenv(jit.CACHE_ENV, str(tmp_path / "build"))
    shipped_key = jit.cache_dir()
    built = fresh()
    assert built(*args) is True               # the snapshot's length does not match: changed
    assert built.stats.cache_misses and jit.has_index(shipped_key)
    monkeypatch.setattr(jit, "SHIPPED_ROOT", str(tmp_path / "build"))
    monkeypatch.setenv(jit.CACHE_ENV, str(tmp_path / "user"))
    for path in (tmp_path / "build").rglob("*.nb*"):
        os.utime(path, (1, 1))                # a wheel's or a clone's mtimes: irrelevant
    monkeypatch.setenv(jit.NO_SHIPPED_ENV, "1")
    assert jit.seed_from_shipped() == 0
    monkeypatch.delenv(jit.NO_SHIPPED_ENV)
    copied = jit.seed_from_shipped()
    assert copied == len(list((tmp_path / "build").rglob("*.nb*"))) > 0
    assert jit.seed_from_shipped() == 0       # the user's cache has an index now: never overwritten
    loaded = fresh()
    assert loaded(*args) is True
    assert loaded.stats.cache_hits and not loaded.stats.cache_misses
    monkeypatch.setattr(jit.numba.config, "CPU_NAME", "generic")     # another CPU: numba compiles
    other = fresh()
    assert other(*args) is True
    assert other.stats.cache_misses and not other.stats.cache_hits


def test_rest_process_only_when_useful(monkeypatch, tmp_path):
    from rft_mujoco.compiled import warmup

    monkeypatch.setenv(jit.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setenv(warmup.PROCESSES_ENV, "1")
    assert warmup.start_rest_process() is None
    monkeypatch.delenv(warmup.PROCESSES_ENV)
    folder = tmp_path / "cache" / os.path.basename(jit.cache_dir()) / "compiled"
    folder.mkdir(parents=True)
    (folder / "route.rest_phase-300.py311.nbi").write_bytes(b"")
    assert warmup.rest_cached() and warmup.start_rest_process() is None
    monkeypatch.setattr(warmup, "_cores", lambda: 1)
    (folder / "route.rest_phase-300.py311.nbi").unlink()
    assert not warmup.rest_cached() and warmup.start_rest_process() is None


def test_the_second_processs_locked_rest_is_the_one_the_rest_phase_calls():
    """The second compile process compiles ``locks.locked_rest`` for the signature spelled out in
    ``warmup.locked_rest_signature`` before the rest phase: after a warm-up its cache index holds exactly one
    signature for this CPU, that one (a mismatch would compile it twice, the second time for the rest phase)."""
    from rft_mujoco.compiled import locks, warmup

    compiled.ensure_compiled(verbose=False)
    from numba.core.registry import cpu_target

    index = locks.locked_rest._cache._cache_file._load_index()       # numba's index of it in the per-user cache
    here = cpu_target.target_context.codegen().magic_tuple()
    assert [key[0] for key in index if key[1] == here] == [warmup.locked_rest_signature()]


def test_the_inliner_memo_is_shared_only_for_this_packages_functions(monkeypatch):
    """numba's inliner copies a callee's IR blocks with one shared deepcopy memo only when the caller is one
    of rft_mujoco's functions (compiled/jit.py): any other code's inlining is compiled exactly as numba
    does it, a fresh memo per block."""
    import copy
    import types

    from rft_mujoco.compiled import jit

    if not jit.SHARED_INLINE_COPIES:
        pytest.skip("numba's inliner does not have the layout the shared memo relies on")
    seen = []
    deepcopy = copy.deepcopy

    def spy(x, memo=None, _nil=[]):  # noqa: B006
        if type(x).__name__ == "Block":
            seen.append(memo is None)
        return deepcopy(x, memo, _nil)

    monkeypatch.setattr(copy, "deepcopy", spy)
    src = ("import numba\n@numba.njit(inline='always')\ndef f(x):\n    y = x + 1\n    if y > 2:\n        y = y * 2\n"
           "    return y\n@numba.njit\ndef g(x):\n    return f(x) + f(x + 1)\n")
    fresh = {}
    for name in ("user_module_for_inlining", "rft_mujoco.test_module_for_inlining"):
        module = types.ModuleType(name)
        monkeypatch.setitem(sys.modules, name, module)
        exec(compile(src, f"<{name}>", "exec"), module.__dict__)
        seen.clear()
        assert module.g(3.0) == 18.0
        assert seen, "no block was copied: the inliner was not exercised"
        fresh[name] = (sum(seen), len(seen))
    assert fresh["user_module_for_inlining"][0] == fresh["user_module_for_inlining"][1]
    assert fresh["rft_mujoco.test_module_for_inlining"][0] == 0


def test_compile_implicit_also_compiles_the_implicit_solves_native_evaluation(capsys):
    """``python -m rft_mujoco compile --implicit`` leaves the implicit solve's C function loaded (its cache
    index written), as ``--ship`` does for a wheel; without the flag it compiles at the first implicit route."""
    import glob

    from rft_mujoco.compiled import implicit_route, warmup

    assert warmup.main(["--implicit"]) == 0
    assert implicit_route._cfunc and implicit_route.cfunc_address() == implicit_route._cfunc[0].address > 0
    assert glob.glob(os.path.join(jit.cache_dir(), "compiled", "implicit_route.implicit_phase-*.nbi"))
    assert "kernels ready in" in capsys.readouterr().out
