"""Loads through MuJoCo's constraints rest on sand (rft_mujoco.studies.loadpaths, the stability study's subset)."""

import numpy as np
import pytest

from rft_mujoco.studies import loadpaths


CASES = [(name, 0.002, "implicitfast") for name in loadpaths.SCENES]
CASES += [("contact", 0.0005, "Euler"), ("weld", 0.005, "RK4"), ("joint_limit", 0.005, "Euler"),
          ("chain", 0.001, "implicit"), ("tendon_limit", 0.0005, "RK4"), ("rock", 0.005, "implicit"),
          ("frictionloss", 0.005, "Euler"), ("frictionloss", 0.005, "implicit"), ("frictionloss", 0.001, "implicitfast")]
"""Every scene at 2 ms, and the hardest cases (the frictionloss ones at 5 ms chattered without the locks of
stuck dofs)."""


@pytest.mark.parametrize("name,dt,integrator", CASES)
def test_load_path_rests_and_the_sand_carries_the_load(name, dt, integrator):
    r = loadpaths.run_case(name, dt, integrator)
    assert not r.nan
    assert r.max_gain_rel <= loadpaths.GAIN_RTOL, f"the sand added {r.max_gain} J in a step"
    assert r.t_rest <= loadpaths.DEADLINE, f"still moving at {r.final_speed}"
    assert r.balance <= loadpaths.BALANCE_RTOL
    assert r.failures == ()


IMPLICIT_CASES = [("frictionloss", 0.005, "Euler", "auto"), ("frictionloss", 0.002, "implicitfast", "auto"),
                  ("frictionloss", 0.005, "implicitfast", "numpy")]
"""The implicit solve (``solve="implicit"``) in the frictionloss cases (where the explicit treatment added energy
until a released lock slipped at its bound: :func:`test_a_released_lock_slips_at_its_bound_and_adds_no_energy`),
on the compiled path and the numpy reference (all 144 cases: ``python -m rft_mujoco stability
--load-paths-only --solve implicit``, docs/rest.md)."""


@pytest.mark.parametrize("name,dt,integrator,backend", IMPLICIT_CASES)
def test_the_implicit_solve_rests_where_the_load_comes_through_dry_friction(name, dt, integrator, backend):
    """Before the zone passes (physics.implicit.ZONE_PASSES) the linearized dry friction held the trunk on the
    light foot beyond its 50 N bound: the sand held a foot that MuJoCo's own solve then moved, pulled it down
    as it sank (energy added) and the trunk slid onto the foot and through the sand (12 of 16 cases)."""
    r = loadpaths.run_case(name, dt, integrator, backend=backend, solve="implicit")
    assert r.observed > 0
    assert r.failures == ()
    assert r.max_gain < 0.0
    assert r.sinkage <= loadpaths.DEPTH_FACTOR * r.rest_depth


@pytest.mark.parametrize("dt,integrator", [(0.002, "implicitfast"), (0.005, "Euler")])
def test_a_released_lock_slips_at_its_bound_and_adds_no_energy(dt, integrator):
    """Issue 26, item 4. As the trunk lands, the locked solve (the sand stopping trunk and foot together) needs
    more than the knee's 50 N of dry friction, so the lock is released. The rest solve then saw the knee with
    the previous step's friction (3.4 N at 2 ms, 2.5 N at 5 ms): a foot pushed up by it, which the sand pulled
    down (1.75 N, 0.96 N), while MuJoCo's friction held the knee and the foot went down with the trunk: the
    sand added 1.1e-4 J (2 ms) and 5.3e-4 J (5 ms) in a step. Where the answer would add energy to the motion
    with the knee held, the released dof slips, its friction at the bound (physics.rest.locked_rest, step 3):
    the sand only takes energy, and the case rests sooner (0.31 s, was 0.42-0.45). The numpy reference here;
    the compiled path in the cases above."""
    r = loadpaths.run_case("frictionloss", dt, integrator, backend="numpy")
    assert r.failures == ()
    assert r.max_gain < 0.0
    assert r.t_rest <= 0.32


def test_without_the_previous_constraint_forces_a_payload_sinks_forever(monkeypatch):
    """The regression this design fixes: ignoring MuJoCo's constraint forces (as the earlier treatment
    did), the plate under a 2 kg payload sinks at (M/m) g dt, forever. (The numpy reference, whose time
    continuity check is a method a test can replace; the compiled one runs the same rule.)"""
    from rft_mujoco.coupling import handle as coupling

    monkeypatch.setattr(coupling._Workspace, "follow_time", lambda self, t, dt: False)
    r = loadpaths.run_case("contact", 0.002, "Euler", backend="numpy")
    assert r.t_rest == np.inf
    np.testing.assert_allclose(r.final_speed, 2.0 / 0.2 * 9.81 * 0.002, rtol=0.05)


@pytest.mark.parametrize("backend", ["numpy", "auto"])
def test_a_lock_that_holds_persists_so_dry_friction_carries_the_load_exactly(backend):
    """The frictionloss scene at 1 ms: a lock tried only where the unlocked solve leaves more than
    LOCK_TOL would alternate locked and unlocked steps at that residual (sand force 0.5% off the load,
    measured); a lock that held is tried again, and the sand carries the load to round-off."""
    r = loadpaths.run_case("frictionloss", 0.001, "Euler", backend=backend)
    assert r.t_rest <= loadpaths.DEADLINE
    assert r.balance <= 1e-6


def test_the_energy_recorder_sees_every_evaluation_on_the_default_path():
    """The studies observe the sand through the public observer, which the native route honours: one
    evaluation per step (Euler), four per RK4 step, plus the study's mj_forward before the first step; a run
    that observed nothing is a failure, not a pass."""
    for integrator, per_step in (("Euler", 1), ("RK4", 4)):
        r = loadpaths.run_case("contact", 0.005, integrator)
        assert r.observed == per_step * round(loadpaths.DURATION / 0.005) + 1
        assert np.isfinite(r.max_gain)


def test_a_case_that_observed_nothing_fails(monkeypatch):
    from rft_mujoco.studies import recorder

    monkeypatch.setattr(recorder.StageRecorder, "__call__", lambda self, data, wrenches, stage: None)
    r = loadpaths.run_case("contact", 0.005, "Euler")
    assert r.observed == 0
    assert any("energy not measured" in f for f in r.failures)


def test_every_scene_is_checked_against_its_quasi_static_depth(monkeypatch):
    """The depth a body rests at is part of the answer (issue 26, item 2): reported beside the law's own
    rest depth, and a failure beyond DEPTH_FACTOR times it."""
    r = loadpaths.run_case("joint_limit", 0.005, "implicitfast")
    assert r.failures == ()
    assert r.rest_depth == pytest.approx(0.0649, abs=5e-4)            # the law alone: the foot 65 mm down
    assert r.rest_depth < r.sinkage <= loadpaths.DEPTH_FACTOR * r.rest_depth
    monkeypatch.setattr(loadpaths, "quasi_static_depth", lambda name: 0.01)
    deep = loadpaths.run_case("joint_limit", 0.005, "implicitfast")
    assert deep.sinkage == pytest.approx(r.sinkage)
    assert any("quasi-static 10.0 mm" in f for f in deep.failures), deep.failures


def test_the_stability_cli_runs_the_load_paths_alone_with_either_solve(tmp_path, capsys):
    from rft_mujoco.studies import stability

    with pytest.raises(SystemExit):
        stability.main(["--solve", "implicit", "--out", str(tmp_path)])
    assert "--load-paths-only" in capsys.readouterr().err
    rc = stability.main(["--load-paths-only", "--quick", "--out", str(tmp_path)])
    text = capsys.readouterr().out
    assert "quasi-static" in text and "depth max mm" in text
    import csv
    with (tmp_path / "loadpaths.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(loadpaths.SCENES)
    assert all(float(r["quasi_static_depth_m"]) > 0 for r in rows)
    assert rc == (1 if any(r["failures"] for r in rows) else 0)   # exits 1 on any failure (2 known at 5 ms)
