"""The speed benchmark's pieces run and produce what README and the plots show (no timing asserted)."""

import math

import numpy as np
import pytest

from rft_mujoco.studies import bench
from rft_mujoco.studies.bench import plots
from rft_mujoco import compiled

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="numba is not installed")


def test_throughput_rows_are_positive_timings_of_a_loaded_problem():
    (row,) = bench.throughput([300])
    assert row["n"] == 300
    for key in ("law_numpy", "law_numba", "kernel_numpy", "kernel_numba"):
        assert math.isfinite(row[key]) and row[key] > 0.0, key
    assert row["leading"] > 0.0          # the benchmark's elements are loaded: the law really runs


def test_public_law_rows_time_the_three_side_by_side():
    (row,) = bench.public_law([300], rounds=2)
    assert row["n"] == 300
    for key in ("numpy_ns", "kernel_ns", "public_ns", "public_speedup", "kernel_speedup", "public_over_kernel"):
        assert math.isfinite(row[key]) and row[key] > 0.0, key


def test_plots_are_written_from_the_tables(tmp_path):
    thr = [dict(n=n, law_numpy=200.0, law_numba=10.0, kernel_numpy=300.0, kernel_numba=12.0)
           for n in (1e3, 1e4)]
    quad = [dict(resolution=res, setting=setting, motion=motion, bare_us=9.0, sand_us=sand, ratio=sand / 9.0)
            for res in ("coarse", "default") for setting, sand in (("rest", 45.0), ("naive", 30.0))
            for motion in ("standing", "trotting")]
    rates = [dict(env=e, zero_sps=900.0, random_sps=1000.0) for e in ("Ant-v5", "rft_mujoco/SandAnt-v0")]
    acc = [dict(shape=shape, preset=preset, numba_us=us, max_error=err, elements=el)
           for shape, errs in (("sphere", (0.008, 0.004)), ("cube", (0.0, 0.0)))
           for (preset, us, el), err in zip((("coarse", 4.0, 240), ("default", 6.0, 400)), errs)]
    stages = [dict(mode=mode, dt=dt, evaluations=n * round(0.05 / dt), moving_mm_s=e * dt * 1e3,
                   resting_mm_s=2 * e * dt * 1e3) for mode, n, e in (("all", 4, 4.0), ("first", 1, 9.0))
              for dt in (0.01, 0.005)]
    files = plots.all_plots(tmp_path, thr, quad, rates, acc, stages)
    assert [f.name for f in files] == ["throughput.png", "overhead.png", "env_rates.png", "error_vs_cost.png",
                                       "rk4_stages.png"]
    for f in files:
        assert f.stat().st_size > 10_000
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_quick_bench_runs_every_section(tmp_path, capsys):
    """``python -m rft_mujoco bench --quick`` end to end (what ``make bench`` runs, smaller): every table,
    finite positive timings, the default preset's accuracy verdict and the plots. No speed is asserted."""
    res = bench.run(quick=True, out=tmp_path)
    text = capsys.readouterr().out
    for heading in ("1. Element throughput", "1b. The public rft_mujoco.element_forces", "2a. Quadruped", "2b. Env steps per second", "2c. RK4 stages",
                    "3. Bodies above the sand", "4. Speed-accuracy", "culling costs", "5. Mesh robots"):
        assert heading in text, heading
    assert "default preset: worst error" in text and "%): met" in text      # the 2% accuracy target holds
    assert "public element_forces speed-up over the numpy law at N = 1e+05" in text   # 1b's verdict (met or not)
    assert [f.name for f in res["files"]] == ["throughput.png", "overhead.png", "env_rates.png",
                                              "error_vs_cost.png"]
    quad = res["quadruped"]
    assert {(r["setting"], r["motion"]) for r in quad} == {(s, m) for s in ("rest", "no reuse", "naive", "no culling")
                                                           for m in ("standing", "trotting")}
    assert all(np.isfinite(r["ratio"]) and r["ratio"] > 1.0 for r in quad)    # sand never makes a step cheaper
    assert all(r["touch_elements"] >= 500 for r in quad)                        # the robot really is in the sand
    from rft_mujoco.compiled import native
    if native.support()[0]:                      # the phase timings need the native route
        assert "Quadruped standing (default resolution, every body), one evaluation's compiled phases" in text
        split = res["phases"]
        assert [r["setting"] for r in split] == ["rest", "naive"]
        assert all(r["loaded_elements"] >= 500 for r in split)                  # timed standing in the sand
        assert all(np.isfinite(r[k]) and r[k] > 0.0 for r in split for k in ("phase1_us", "phase2_us", "bare_us"))
    rates = res["rates"]
    if rates is not None:
        assert {"Ant-v5", "rft_mujoco/SandAnt-v0", "rft_mujoco/SandQuadruped-v0"} <= {r["env"] for r in rates}
        assert all(r["zero_sps"] > 0 and r["random_sps"] > 0 for r in rates)
        if native.support()[0]:
            assert "SandAnt-v0 standing, one evaluation's compiled phases" in text
    assert np.isfinite(res["above"]["per_body_ns"]) and res["above"]["fixed_us"] > 0.0
    assert {r["name"] for r in res["robots"]} == {"mesh humanoid", "mesh quadruped"}
    assert all(r["ratio"] > 1.0 and 1 / 1.5 <= r["count_ratio"] <= 1.5 for r in res["robots"])


def test_implicit_cost_times_the_quadruped_and_the_swimmer_side_by_side():
    from rft_mujoco.studies.bench.coupling import implicit_cost
    r = implicit_cost(names=("explicit", "implicit"), reps=1, swimmer=("implicit",))
    assert [q["setting"] for q in r["quadruped"]] == ["explicit", "implicit"]
    for q in r["quadruped"]:
        assert q["loaded_elements"] > 0                   # the quadruped stands on the sand
        for key in ("bare_us", "sand_us", "ratio"):
            assert math.isfinite(q[key]) and q[key] > 0.0, key
    (s,) = r["swimmer"]
    assert s["steps"] == 1000 and math.isfinite(s["s_per_step"]) and s["s_per_step"] > 0.0


def test_env_rates_measure_each_solve_side_by_side(capsys):
    """``python -m rft_mujoco bench --solves``: every sand env once per solve in the same rounds, Ant-v5 once,
    and the implicit / explicit table (no speed asserted)."""
    pytest.importorskip("gymnasium")
    rates = bench.coupling.env_rates(5, 1, solves=("explicit", "implicit"))
    keys = {(r["env"], r["solve"]) for r in rates}
    assert ("Ant-v5", "default") in keys
    for env in ("rft_mujoco/SandAnt-v0", "rft_mujoco/SandQuadruped-v0", "rft_mujoco/SandQuadruped-v1"):
        assert {(env, "explicit"), (env, "implicit")} <= keys, env
    assert all(r["zero_sps"] > 0 and r["random_sps"] > 0 for r in rates)
    bench._print_solves(rates)
    text = capsys.readouterr().out
    assert "implicit / explicit steps per second" in text and "rft_mujoco/SandQuadruped-v1" in text


def test_the_standing_scene_holds_its_targets_after_the_trot_left_others():
    """Section 2a times "standing" after the trot ran on the same MjData; mj_setState leaves ctrl alone, so the
    standing runs pass the settled targets (``_hold``): the trunk then stays put (without them it walks off to
    the trot's last targets)."""
    import warnings

    import mujoco

    from rft_mujoco import attach
    from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS
    from rft_mujoco.studies.bench.coupling import _hold, _trot
    from rft_mujoco.studies.bench.timing import quadruped, settled_state, step_time

    model = quadruped()
    data = mujoco.MjData(model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, "coarse", monitor=False)
    handle.replace_rigid(["floor"])
    try:
        stand = settled_state(model, data)
        hold = _hold(data)
        start = data.qpos.copy()
        moved = {}
        for name, ctrl in (("left", None), ("held", hold)):        # "left" first: the trot's last targets
            _trot(model, data, stand)
            step_time(model, data, stand, 1, ctrl=ctrl)
            moved[name] = np.abs(data.qpos[7:] - start[7:]).max()  # rad, the joints after 0.4 s
    finally:
        handle.detach()
    assert moved["held"] < 1e-3 and moved["left"] > 0.05, moved


def test_rk4_stage_modes_cost_accuracy_in_the_order_of_the_stages_they_skip():
    """The RK4-stage study's one-env-step errors (SandAnt-v0, 30 states of a random-action rollout, against
    "all" at 1 ms) measured every state; holding the midpoint's wrench ("midpoint") stays within 1.3x of
    every stage's error and well below holding the first stage's ("first"), and a smaller step converges."""
    pytest.importorskip("gymnasium")
    from rft_mujoco.studies.bench.coupling import RK4_MODES, ant_env_step, ant_states, step_errors

    states = ant_states(30, moving=True)
    assert len(states) == 30 and len({s[0].tobytes() for s in states}) == 30
    ref = ant_env_step(states, "all", 0.001)
    errors = {mode: step_errors(ant_env_step(states, mode, 0.01), ref) for mode in RK4_MODES}
    fine = step_errors(ant_env_step(states, "all", 0.0025), ref)
    for k in (0, 1):                                   # torso position mm, torso velocity mm/s
        assert 0.0 < errors["all"][k] and errors["midpoint"][k] <= 1.3 * errors["all"][k], errors
        assert errors["midpoint"][k] < 0.9 * errors["first"][k], errors
        assert fine[k] < 0.5 * errors["all"][k], (fine, errors)
