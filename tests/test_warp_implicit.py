"""The implicit solve on the batched sand (rft_mujoco.warp.attach(solve="implicit")) against the CPU path's
(rft_mujoco.attach(solve="implicit")), on warp's CPU device (RFT_WARP_TEST_DEVICE=cuda:0 for a GPU).

The same state: the sand of a first evaluation (no earlier solve on either side) agrees to float32 round-off of
MuJoCo Warp's state. Trajectories: the loads that reach a sand body through a joint limit, a contact, a weld and
dry friction (this step's constraint rows, linearized in their zones on both sides) give the same depth to a
few micrometres over 0.5 s.
"""

import os

import mujoco
import numpy as np
import pytest

mjw = pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (pip install 'rft_mujoco[warp]')")
wp = pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'rft_mujoco[warp]')")

import rft_mujoco  # noqa: E402
import rft_mujoco.warp as rw  # noqa: E402
from rft_mujoco.warp import kernels as K  # noqa: E402
from test_warp import _device, quadruped  # noqa: E402,F401  (the warp device and the floorless quadruped)
from rft_mujoco.models.quadruped import FOOT_BODIES  # noqa: E402

DEVICE = os.environ.get("RFT_WARP_TEST_DEVICE", "cpu")
MEDIA = "li_loose_glass_beads"
FORCE_RTOL = 1e-4
"""The same state: max |F_warp - F_cpu| over bodies relative to the largest body force (the Newton solves stop
on tolerances of 1e-3 of the twist change; float32 state moves where they stop by less than this)."""
DEPTH_TOL = 5e-5
"""m: |z_warp - z_cpu| of a load path's sand body over its trajectory (measured: 0 - 43 micrometres)."""
SNAPSHOT_STEPS = (5, 20, 60, 150, 360)


def _states(model, bodies):
    """States of a CPU stand-up from ``home`` (trunk 1 cm low) with the implicit solve: falling, then resting."""
    handle = rft_mujoco.attach(model, MEDIA, bodies, monitor=False, solve="implicit")
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    d.qpos[2] -= 0.01
    d.ctrl[:] = model.key("home").ctrl
    states = []
    try:
        for k in range(max(SNAPSHOT_STEPS) + 1):
            if k in SNAPSHOT_STEPS:
                states.append((d.qpos.astype(np.float32).astype(float), d.qvel.astype(np.float32).astype(float)))
            mujoco.mj_step(model, d)
    finally:
        handle.detach()
    return states


def _cpu_first_evaluation(model, bodies, state, constraints, media=MEDIA, **kwargs):
    """The CPU implicit sand of one mj_forward at ``state`` on a fresh MjData (no earlier solve)."""
    handle = rft_mujoco.attach(model, media, bodies, monitor=False, solve="implicit", reuse_tol=0.0, **kwargs)
    handle.constraints = constraints
    try:
        d = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
        d.qpos[:], d.qvel[:] = state
        d.ctrl[:] = model.key("home").ctrl
        mujoco.mj_forward(model, d)
        diag = handle.diagnostics(d)
        return diag.force.copy(), diag.resting.copy()
    finally:
        handle.detach()


def _warp_worlds(model, states):
    """A mujoco_warp Data with one world per (qpos, qvel) of ``states``, the ``home`` controls."""
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    dw = mjw.put_data(model, d, nworld=len(states), nconmax=4, njmax=64)
    dw.qpos.assign(np.array([s[0] for s in states], dtype=np.float32))
    dw.qvel.assign(np.array([s[1] for s in states], dtype=np.float32))
    dw.ctrl.assign(np.tile(model.key("home").ctrl, (len(states), 1)).astype(np.float32))
    return dw


@pytest.mark.parametrize("constraints", ["linearized", "lagged"])
@pytest.mark.parametrize("bodies", [None, FOOT_BODIES], ids=["all_bodies", "feet"])
def test_the_same_state_gives_the_cpu_paths_wrenches(quadruped, bodies, constraints):
    model, mjw_model = quadruped
    states = _states(model, bodies)
    dw = _warp_worlds(model, states)
    handle = rw.attach(model, mjw_model, MEDIA, bodies, solve="implicit", constraints=constraints, data=dw)
    try:
        mjw.forward(mjw_model, dw)
        diag = handle.diagnostics(dw)
    finally:
        handle.detach()
    flows = rests = 0
    for i, state in enumerate(states):
        force, resting = _cpu_first_evaluation(model, bodies, state, constraints)
        assert np.abs(force).max() > 1.0
        err = np.abs(diag.force[i] - force).max() / np.abs(force).max()
        assert err < FORCE_RTOL, (i, err)
        assert np.array_equal(diag.resting[i], resting), i
        flows += int((~resting & (np.abs(force).sum(axis=1) > 0)).any())
        rests += int(resting.any())
    assert flows >= 2 and rests >= 1                      # both branches of the solve compared
    assert not diag.errors.any()


@pytest.mark.parametrize("scene,integrator,dt", [("joint_limit", "implicitfast", 0.002), ("contact", "Euler", 0.005),
                                                 ("weld", "implicitfast", 0.002), ("frictionloss", "RK4", 0.002)])
def test_load_paths_sink_as_on_the_cpu_path(scene, integrator, dt):
    """A load through a joint limit, a contact, a weld or dry friction: this step's rows meet the sand on both
    paths; the sand body's depth agrees over 0.5 s and it ends at rest, carrying the load."""
    from rft_mujoco.studies.warp_loadpaths import compare

    r = compare(scene, integrator, dt, steps=int(round(0.5 / dt)), device=DEVICE)
    assert r["depth_cpu_m"] > 0.005                                   # it sank
    assert r["worst_dz_m"] < DEPTH_TOL, r
    assert r["rest_cpu"] and r["rest_warp"]
    assert abs(r["fz_warp_n"] - r["fz_cpu_n"]) < 1e-3 * abs(r["fz_cpu_n"])


def test_a_light_plate_that_sinks_and_slides_ends_the_step_as_on_the_cpu_path():
    """A 0.2 kg plate 10 mm deep, sliding at 0.5 m/s and sinking at 0.05 m/s: in one 2 ms step the explicit
    treatment throws it up at 61 mm/s (F_z 13 N against its 2 N weight); the implicit solve ends the step nearly
    still vertically and keeps a drag, with the CPU path's numbers."""
    xml = """<mujoco><option timestep="0.002"/><worldbody><body name="plate" pos="0 0 -0.01"><freejoint/>
             <geom type="box" size="0.05 0.05 0.005" mass="0.2"/></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(model)
    d.qvel[:3] = (0.5, 0.0, -0.05)
    mjw_model = mjw.put_model(model)
    out = {}
    for solve in ("explicit", "implicit"):
        dw = mjw.put_data(model, d, nworld=1)
        handle = rw.attach(model, mjw_model, MEDIA, ["plate"], resolution=0.005, solve=solve, data=dw)
        try:
            mjw.step(mjw_model, dw)
            out[solve] = (handle.diagnostics(dw).force[0, 0], dw.qvel.numpy()[0, :3].astype(float))
        finally:
            handle.detach()
    cpu = rft_mujoco.attach(model, MEDIA, ["plate"], resolution=0.005, monitor=False, solve="implicit")
    try:
        mujoco.mj_step(model, d)
        force = cpu.diagnostics(d).force[0]
    finally:
        cpu.detach()
    force_w, vel_w = out["implicit"]
    assert np.abs(force_w - force).max() < FORCE_RTOL * np.abs(force).max()
    assert np.abs(vel_w - d.qvel[:3]).max() < 1e-5
    assert out["explicit"][1][2] > 0.05 and abs(vel_w[2]) < 0.005      # thrown up / nearly still
    assert force_w[0] < -4.0                                              # N: the drag kept


def test_attach_checks_solve_and_constraints(quadruped):
    model, mjw_model = quadruped
    with pytest.raises(ValueError, match="solve must be one of"):
        rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, solve="newton")
    with pytest.raises(ValueError, match="constraints must be one of"):
        rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, solve="implicit", constraints="late")


def test_the_swimmer_at_the_animals_density_swims_as_on_the_cpu_path():
    """The any-mass case (issue 26): the bundled swimmer (the animal's density, 22 g) driven by the swim study's
    serpenoid, 3 mm elements, 2 ms: warp's wave efficiency is the CPU path's (docs/warp.md: both within 3.1% of
    the quasi-static limit at every amplitude)."""
    import warnings

    from rft_mujoco.studies.swim import swim
    from rft_mujoco.studies.swim_warp import swim_batched

    (batched,) = swim_batched((0.5,), cycles=2, device=DEVICE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu = swim(0.5, 1.0, density_scale=1.0, timestep=0.002, cycles=2, resolution=0.003, solve="implicit")
    assert cpu["eta"] > 0.05 and batched["steps"] == 1000
    assert abs(batched["eta"] - cpu["eta"]) < 0.02 * cpu["eta"], (batched["eta"], cpu["eta"])
    assert batched["tracking_rms_rad"] < 0.05


def test_the_load_path_comparison_cli_prints_its_table(capsys):
    from rft_mujoco.studies.warp_loadpaths import main

    assert main(["--scenes", "weld", "--integrators", "Euler", "--timesteps", "0.005", "--steps", "20"]) == 0
    out = capsys.readouterr().out
    assert "depth warp mm" in out and "weld" in out
    with pytest.raises(SystemExit):
        main(["--steps", "0"])


def test_the_solve_can_be_switched_between_steps(quadruped):
    """``handle.solve = "implicit"`` after the buffers exist: the next step makes the implicit solve's buffers and
    runs it (the same forces as a handle attached with it); a bad value raises on assignment."""
    model, mjw_model = quadruped
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    d.qpos[2] -= 0.01
    d.ctrl[:] = model.key("home").ctrl
    forces = []
    for switch in (True, False):
        dw = mjw.put_data(model, d, nworld=2, nconmax=4, njmax=64)
        handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw,
                           solve="explicit" if switch else "implicit")
        try:
            if switch:
                assert handle.bind(dw).implicit is None
                handle.solve = "implicit"
                with pytest.raises(ValueError, match="solve must be one of"):
                    handle.solve = "newton"
            mjw.step(mjw_model, dw)
            forces.append(handle.forces(dw))
            assert handle.bind(dw).implicit is not None
        finally:
            handle.detach()
    assert np.abs(forces[0]).max() > 1.0
    assert np.array_equal(forces[0], forces[1])


def test_the_slanted_shin_quadruped_stands_still_on_warp():
    """Issue 26's no-glide robot (62 kg, slanted triangle-mesh shins) set down in two warp worlds with the implicit
    solve: at rest within 0.6 s of touching, drifting under 10 mm in all (the CPU path's glide study: 0.434 s,
    5.2 mm), both worlds the same."""
    from rft_mujoco.studies.glide_warp import stand_batched

    r = stand_batched("implicit", duration=0.6, worlds=2, device=DEVICE)
    assert r["t_rest_s"] < 0.6 and r["drift_total_m"] < 0.010, r
    assert 0.15 < r["sinkage_m"] < 0.25 and r["spread_m"] < 1e-6


def test_a_heightfield_per_world_media_and_a_bad_world(quadruped):
    """The implicit solve with what a batch varies: a heightfield terrain, another medium in one world, NaN input
    in another (that world alone flagged and left without sand, the error naming it and its cause; the
    diagnostics taken before ``check`` keep the flag: they are copies); each good world the CPU path's wrenches."""
    from test_warp import _heightfield

    model, mjw_model = quadruped
    terrain = _heightfield()
    other = rft_mujoco.get_media(MEDIA).replace(rho_c=1700.0, mu_surf=0.3, name="other")
    state = _states(model, FOOT_BODIES)[2]
    expect = [_cpu_first_evaluation(model, FOOT_BODIES, state, "linearized", media=m, surface_height=terrain)[0]
              for m in (MEDIA, other)]
    assert np.abs(expect[1] - expect[0]).max() > 0.05 * np.abs(expect[0]).max()       # the media differ
    dw = _warp_worlds(model, [state] * 3)
    qfrc = np.zeros((3, model.nv), dtype=np.float32)
    qfrc[2, 7] = np.nan
    dw.qfrc_applied.assign(qfrc)
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, surface_height=terrain, solve="implicit", data=dw)
    try:
        handle.set_media(dw, other, worlds=[1])
        mjw.forward(mjw_model, dw)
        diag = handle.diagnostics(dw)
        with pytest.raises(FloatingPointError, match=r"worlds \[2\]: non-finite acceleration without sand in 1 "):
            handle.check(dw)
    finally:
        handle.detach()
    for i in range(2):
        assert np.abs(diag.force[i] - expect[i]).max() < FORCE_RTOL * np.abs(expect[i]).max(), i
    assert diag.errors[0] == diag.errors[1] == 0 and diag.errors[2] & int(K.BAD_ACCELERATION)
    assert np.all(diag.force[2] == 0.0)


def test_a_pile_with_sparse_constraint_rows_moves_as_on_the_cpu_path():
    """Six 0.3 kg boxes in the sand under a 2 kg lid (42 dofs: MuJoCo Warp keeps the rows sparse, MuJoCo C dense;
    60-100 contact rows): the implicit solve's linearized rows on both paths give the same motion over 0.4 s."""
    boxes = "".join(f'<body name="b{i}" pos="{0.12 * (i % 3)} {0.12 * (i // 3)} {0.02 + 0.03 * (i % 2)}"><freejoint/>'
                    '<geom type="box" size="0.04 0.04 0.015" mass="0.3"/></body>' for i in range(6))
    xml = (f'<mujoco><option timestep="0.002" integrator="implicitfast"/><worldbody>{boxes}<body name="lid" '
           'pos="0.12 0.06 0.09"><freejoint/><geom type="box" size="0.2 0.1 0.01" mass="2"/></body></worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    mjw_model = mjw.put_model(model)
    assert mjw_model.is_sparse and not mujoco.mj_isSparse(model)
    dw = mjw.put_data(model, d, nworld=1, nconmax=64, njmax=256)
    bodies = [f"b{i}" for i in range(6)]
    cpu = rft_mujoco.attach(model, MEDIA, bodies, resolution=0.01, monitor=False, solve="implicit")
    handle = rw.attach(model, mjw_model, MEDIA, bodies, resolution=0.01, solve="implicit", data=dw)
    worst, rows = 0.0, 0
    try:
        for _ in range(200):
            mujoco.mj_step(model, d)
            mjw.step(mjw_model, dw)
            worst = max(worst, np.abs(dw.xpos.numpy()[0] - d.xpos).max())
            rows = max(rows, int(dw.nefc.numpy()[0]))
        handle.check(dw)
        resting = (cpu.diagnostics(d).resting, handle.diagnostics(dw).resting[0])
    finally:
        handle.detach()
        cpu.detach()
    assert rows >= 60 and d.xpos[-1, 2] < 0.05                      # the lid came down onto the boxes
    assert worst < 1e-5, worst                                       # m
    assert resting[0].all() and np.array_equal(*resting)


def test_the_implicit_kernels_compile_for_a_gpu(tmp_path):
    """No GPU is lent to this project's test machine: the implicit solve's kernels (and the element pass they
    share) are compiled ahead of time to PTX for sm_90 (an H100/H200) with warp's NVRTC, so that CUDA code
    generation errors (float64 atomics, structs of arrays, the per-world loops) show here."""
    from rft_mujoco.warp import elements, implicit, implicit_free, implicit_law

    for module in (implicit_law, implicit_free, implicit, elements):
        try:
            out = wp.compile_aot_module(module, device=None, arch=90, module_dir=tmp_path, use_ptx=True)
        except RuntimeError as exc:                       # pragma: no cover - a warp build without NVRTC
            if "nvrtc" in str(exc).lower():
                pytest.skip(f"warp cannot compile CUDA here: {exc}")
            raise
        ptx = [p for p in out if p.suffix == ".ptx"]
        assert ptx and ptx[0].stat().st_size > 10_000, (module.__name__, out)
