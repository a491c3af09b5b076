"""First use: the numba cache per user, keyed by sources and versions and shared by every install; the
progress lines while numba compiles."""

from __future__ import annotations

import hashlib
import io
import os
import time

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
    progress.start()
    time.sleep(0.2)
    progress.end()
    progress.thread.join(timeout=5)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("rft_mujoco: compiling the numba kernels, once for this user and version "
                               f"(about {jit.COMPILE_SECONDS / 60:.1f} min")
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
