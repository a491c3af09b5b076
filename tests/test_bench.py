"""The speed benchmark's pieces run and produce what README and the plots show (no timing asserted)."""

import math

import numpy as np
import pytest

from rft_mujoco.studies import bench
from rft_mujoco.compiled import elements as fastkernel

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


def test_quick_bench_runs_every_section(tmp_path, capsys):
    """``python -m rft_mujoco bench --quick`` end to end (what ``make bench`` runs, smaller): every table,
    finite positive timings, the default preset's accuracy verdict and the plots. No speed is asserted."""
    res = bench.run(quick=True, out=tmp_path)
    text = capsys.readouterr().out
    for heading in ("1. Element throughput", "2a. Quadruped", "2b. Ant-v5", "2c. RK4 stages",
                    "3. Bodies above the sand", "4. Speed-accuracy"):
        assert heading in text, heading
    assert "default preset: worst error" in text and "%): met" in text      # the 2% accuracy target holds
    assert [f.name for f in res["files"]] == ["throughput.png", "overhead.png", "error_vs_cost.png"]
    quad = res["quadruped"]
    assert len(quad) == 6                                            # 3 resolutions x 2 settings
    assert all(np.isfinite(r["ratio"]) and r["ratio"] > 1.0 for r in quad)    # sand never makes a step cheaper
    assert all(r["cand_elements"] >= 2000 for r in quad)             # the scene size
    ant = res["ant"]
    if ant is not None:
        assert 0.0 < ant["env_fraction"] < 1.5 and 0.0 < ant["fraction"] < 1.5
    assert np.isfinite(res["above"]["per_body_ns"]) and res["above"]["fixed_us"] > 0.0
