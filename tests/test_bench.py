"""The speed benchmark's pieces run and produce what README and the plots show (no timing asserted)."""

import math

import numpy as np
import pytest

from rft_mujoco import bench, fastkernel

pytestmark = pytest.mark.skipif(not fastkernel.AVAILABLE, reason="numba is not installed")


def test_throughput_rows_are_positive_timings_of_a_loaded_problem():
    (row,) = bench.throughput([300])
    assert row["n"] == 300
    for key in ("law_numpy", "law_numba", "kernel_numpy", "kernel_numba"):
        assert math.isfinite(row[key]) and row[key] > 0.0, key
    assert row["leading"] > 0.0          # the benchmark's elements are loaded: the law really runs


def test_plots_are_written_from_the_tables(tmp_path):
    thr = [dict(n=n, law_numpy=200.0, law_numba=10.0, kernel_numpy=300.0, kernel_numba=12.0)
           for n in (1e3, 1e4)]
    quad = [dict(resolution=res, backend=backend, stabilize=stab, warm_start=warm, bare_us=9.0, sand_us=sand,
                 ratio=sand / 9.0)
            for res in ("coarse", "default")
            for backend, stab, warm, sand in (("numba", True, True, 250.0), ("numba", False, False, 45.0))]
    acc = [dict(shape=shape, preset=preset, numba_us=us, max_error=err, elements=el)
           for shape, errs in (("sphere", (0.008, 0.004)), ("cube", (0.0, 0.0)))
           for (preset, us, el), err in zip((("coarse", 4.0, 240), ("default", 6.0, 400)), errs)]
    files = bench._plots(tmp_path, thr, quad, acc)
    assert [f.name for f in files] == ["throughput.png", "overhead.png", "error_vs_cost.png"]
    for f in files:
        assert f.stat().st_size > 10_000
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
