"""The batched sand on MuJoCo Warp (rft_mujoco.warp) against the CPU coupling (rft_mujoco.attach).

Runs on warp's CPU device (RFT_WARP_TEST_DEVICE=cuda:0 to run on a GPU). The first test pays MuJoCo Warp's
and the sand kernels' compilation (~25 s cold, ~2 s from warp's kernel cache); the rest reuse the models.

Tolerances: MuJoCo Warp keeps its state in float32, so "the same numbers" means float32 round-off of the
largest wrench (FORCE_RTOL); the issue's parity targets are PARITY_FORCE_RTOL and PARITY_TRAJECTORY_M.
"""

import os

import mujoco
import numpy as np
import pytest

mjw = pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (pip install 'rft_mujoco[warp]')")
wp = pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'rft_mujoco[warp]')")

import rft_mujoco  # noqa: E402
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion  # noqa: E402
from rft_mujoco.models.quadruped import FOOT_BODIES  # noqa: E402
from rft_mujoco.warp import kernels as K  # noqa: E402
from rft_mujoco.coupling import layout as wlayout  # noqa: E402

import rft_mujoco.warp as rw  # noqa: E402

DEVICE = os.environ.get("RFT_WARP_TEST_DEVICE", "cpu")
MEDIA = "li_loose_glass_beads"
FORCE_RTOL = 2e-5
"""Same state, same evaluation: max |F_warp - F_cpu| over bodies, relative to the largest body force."""
PARITY_FORCE_RTOL = 0.01
PARITY_TRAJECTORY_M = 0.002
CPU_SNAPSHOT_STEPS = (5, 20, 60, 150, 360)
"""Steps of a CPU stand-up from the home keyframe (2 ms): falling into the sand (flow) ... resting."""


@pytest.fixture(scope="module", autouse=True)
def _device():
    wp.config.quiet = True
    with wp.ScopedDevice(DEVICE):
        yield


@pytest.fixture(scope="module")
def quadruped():
    """The bundled quadruped with its floor replaced by sand, and its MuJoCo Warp model."""
    path = os.path.join(os.path.dirname(rft_mujoco.__file__), "models", "quadruped.xml")
    model = mujoco.MjModel.from_xml_path(os.path.abspath(path))
    model.geom_contype[0] = model.geom_conaffinity[0] = 0
    return model, mjw.put_model(model)


def _warp_data(model, states, ctrl=None):
    """A mujoco_warp Data with one world per state dict (qpos, qvel, qfrc_constraint, time)."""
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    dw = mjw.put_data(model, d, nworld=len(states), nconmax=4, njmax=64)
    for name, field in (("qpos", dw.qpos), ("qvel", dw.qvel), ("qfrc_constraint", dw.qfrc_constraint),
                        ("time", dw.time)):
        field.assign(np.array([s[name] for s in states], dtype=np.float32))
    dw.ctrl.assign(np.tile(model.key("home").ctrl if ctrl is None else ctrl, (len(states), 1)).astype(np.float32))
    return dw


def _cpu_snapshots(model, bodies, steps=CPU_SNAPSHOT_STEPS, **kwargs):
    """States before the given steps of a CPU run from ``home`` (trunk 1 cm low) and the sand forces of each."""
    handle = rft_mujoco.attach(model, MEDIA, bodies, monitor=False, reuse_tol=0.0, **kwargs)  # warp never reuses
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    d.qpos[2] -= 0.01
    d.ctrl[:] = model.key("home").ctrl
    states, forces, torques, resting = [], [], [], []
    try:
        for k in range(max(steps) + 1):
            if k in steps:
                states.append(dict(qpos=d.qpos.copy(), qvel=d.qvel.copy(), qfrc_constraint=d.qfrc_constraint.copy(),
                                   time=d.time))
            mujoco.mj_step(model, d)
            if k in steps:
                diag = handle.diagnostics(d)
                forces.append(diag.force.copy())
                torques.append(diag.torque.copy())
                resting.append(diag.resting.copy())
    finally:
        handle.detach()
    return states, np.array(forces), np.array(torques), np.array(resting)


def _evaluate_warp(model, mjw_model, states, bodies, lagged=True, **kwargs):
    """The warp sand of one forward pass over worlds made from ``states`` (previous evaluation one step earlier
    when ``lagged``, as in the CPU run)."""
    dw = _warp_data(model, states)
    handle = rw.attach(model, mjw_model, MEDIA, bodies, data=dw, **kwargs)
    try:
        if lagged:
            handle.bind(dw).last_time.assign(np.array([s["time"] - model.opt.timestep for s in states],
                                                      dtype=np.float32))
        mjw.forward(mjw_model, dw)
        return handle.diagnostics(dw)
    finally:
        handle.detach()


def _rel(a, b):
    return np.abs(a - b).max() / max(np.abs(b).max(), 1e-12)


# --- static layout ------------------------------------------------------------------------------------
def test_layout_is_the_cpu_handles(quadruped):
    model, _ = quadruped
    cpu = rft_mujoco.attach(model, MEDIA, None, resolution="coarse", monitor=False)
    try:
        lay = wlayout.build(model, None, "coarse")
        assert np.array_equal(lay.body_ids, cpu.body_ids)
        assert np.array_equal(lay.centroids, cpu.local_centroids)
        assert np.array_equal(lay.normals, cpu.local_normals)
        assert np.array_equal(lay.areas, cpu.areas)
        assert np.array_equal(lay.elem_body, cpu.elem_body)
        assert np.array_equal(lay.groups.of_body, cpu.groups.of_body)
        assert np.array_equal(lay.groups.radius, cpu.groups.radius)
        assert np.allclose(lay.bound_radius, cpu.layout.bound_radius)
        assert np.array_equal(lay.culled_area, cpu.culled_area)
        for name in ("start", "geom", "kind", "size", "rbound", "hs_start", "halfspaces"):
            assert np.array_equal(getattr(lay.occluders, name), getattr(cpu.layout.occluders, name)), name
        assert lay.occluders.margin == cpu.layout.occluders.margin
        assert lay.occluders.geom.size > 0
    finally:
        cpu.detach()
    cpu = rft_mujoco.attach(model, MEDIA, None, resolution="coarse", monitor=False, cull=False)
    try:
        lay = wlayout.build(model, None, "coarse", cull=False)
        assert np.array_equal(lay.centroids, cpu.local_centroids) and lay.occluders.geom.size == 0
        assert lay.n_elements > cpu.n_elements - 1 and not lay.culled_area.any()
    finally:
        cpu.detach()


# --- the same state: the port agrees to round-off -----------------------------------------------------
@pytest.mark.parametrize("bodies", [None, FOOT_BODIES], ids=["all_bodies", "feet"])
def test_rest_treatment_matches_cpu_on_the_same_state(quadruped, bodies):
    model, mjw_model = quadruped
    states, forces, torques, resting = _cpu_snapshots(model, bodies)
    assert resting[0].sum() == 0 and resting[-1].sum() >= 4           # flow at first, then at rest
    diag = _evaluate_warp(model, mjw_model, states, bodies)
    for i in range(len(states)):
        assert _rel(diag.force[i], forces[i]) < FORCE_RTOL, (i, diag.force[i], forces[i])
        assert np.abs(diag.torque[i] - torques[i]).max() < FORCE_RTOL * np.abs(forces[i]).max() * 0.5
    assert np.array_equal(diag.resting, resting)
    assert not diag.errors.any()


def test_naive_coupling_matches_cpu(quadruped):
    model, mjw_model = quadruped
    states, forces, _, _ = _cpu_snapshots(model, FOOT_BODIES, steps=(5, 20, 60), stabilize=False)
    diag = _evaluate_warp(model, mjw_model, states, FOOT_BODIES, stabilize=False)
    for i in range(len(states)):
        assert _rel(diag.force[i], forces[i]) < FORCE_RTOL


def _heightfield():
    x, y = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 7))
    return HeightfieldSurface(0.01 * np.sin(3 * x) * np.cos(2 * y) + 0.005, (-1.0, 1.0), (-1.0, 1.0))


@pytest.mark.parametrize("terrain", [_heightfield(), SandRegion(FlatSurface(0.0), (0.0, 1.0), (-1.0, 1.0)),
                                     SandRegion(_heightfield(), (-1.0, 1.0), (-1.0, 0.0))],
                         ids=["heightfield", "flat_region_front_feet", "heightfield_region_right_feet"])
def test_terrains_match_cpu(quadruped, terrain):
    model, mjw_model = quadruped
    states, forces, _, _ = _cpu_snapshots(model, FOOT_BODIES, steps=(20, 60), surface_height=terrain)
    diag = _evaluate_warp(model, mjw_model, states, FOOT_BODIES, surface_height=terrain)
    assert np.abs(forces).max() > 1.0
    for i in range(len(states)):
        assert _rel(diag.force[i], forces[i]) < FORCE_RTOL


def _cpu_forward(model, media, bodies, state):
    """The CPU sand of one mj_forward at ``state`` (a first evaluation: no previous constraint solve)."""
    handle = rft_mujoco.attach(model, media, bodies, monitor=False)
    try:
        d = mujoco.MjData(model)
        d.qpos[:], d.qvel[:], d.time = state["qpos"], state["qvel"], state["time"]
        d.ctrl[:] = model.key("home").ctrl
        mujoco.mj_forward(model, d)
        return handle.diagnostics(d).force.copy()
    finally:
        handle.detach()


def test_per_world_media(quadruped):
    model, mjw_model = quadruped
    other = rft_mujoco.get_media(MEDIA).replace(rho_c=1700.0, mu_surf=0.3, name="other")
    state = _cpu_snapshots(model, FOOT_BODIES, steps=(20,))[0][0]
    expect = [_cpu_forward(model, MEDIA, FOOT_BODIES, state), _cpu_forward(model, other, FOOT_BODIES, state)]
    assert np.abs(expect[1] - expect[0]).max() > 0.05 * np.abs(expect[0]).max()     # the media differ
    dw = _warp_data(model, [state, state])
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw)
    try:
        handle.set_media(dw, other, worlds=[1])
        assert [m.name for m in handle.media(dw)] == [MEDIA, "other"]
        mjw.forward(mjw_model, dw)
        f = handle.forces(dw)
    finally:
        handle.detach()
    for i in range(2):
        assert _rel(f[i], expect[i]) < FORCE_RTOL


def test_per_world_surface_height(quadruped):
    model, mjw_model = quadruped
    state = _cpu_snapshots(model, FOOT_BODIES, steps=(20,))[0][0]
    expect = _cpu_forward(model, MEDIA, FOOT_BODIES, state)
    handle = rft_mujoco.attach(model, MEDIA, FOOT_BODIES, surface_height=0.004, monitor=False)
    try:
        d = mujoco.MjData(model)
        d.qpos[:], d.qvel[:], d.time = state["qpos"], state["qvel"], state["time"]
        d.ctrl[:] = model.key("home").ctrl
        mujoco.mj_forward(model, d)
        expect_high = handle.diagnostics(d).force.copy()
    finally:
        handle.detach()
    dw = _warp_data(model, [state, state])
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw)
    try:
        handle.set_surface_height(dw, 0.004, worlds=[1])
        assert np.allclose(handle.surface_height(dw), [0.0, 0.004])
        mjw.forward(mjw_model, dw)
        f = handle.forces(dw)
    finally:
        handle.detach()
    assert _rel(f[0], expect) < FORCE_RTOL and _rel(f[1], expect_high) < FORCE_RTOL
    assert np.abs(expect_high).sum() > 1.2 * np.abs(expect).sum()


def test_element_mask_removes_a_foot(quadruped):
    model, mjw_model = quadruped
    three = FOOT_BODIES[1:]
    states, forces, _, _ = _cpu_snapshots(model, three, steps=(20, 150))
    dw = _warp_data(model, states)
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw)
    try:
        mask = np.ones((len(states), handle.n_elements), dtype=bool)
        mask[:, handle.layout.elem_body == 0] = False               # no FL_foot in any world
        handle.set_element_mask(dw, mask)
        handle.bind(dw).last_time.assign(np.array([s["time"] - model.opt.timestep for s in states],
                                                  dtype=np.float32))
        mjw.forward(mjw_model, dw)
        f = handle.forces(dw)
    finally:
        handle.detach()
    assert np.all(f[:, 0] == 0.0)
    for i in range(len(states)):
        assert _rel(f[i, 1:], forces[i]) < FORCE_RTOL


SCRATCH_FLOATS = ("mf", "qacc", "jac", "minv_jt", "twist", "free", "u", "vs", "a", "low", "gram", "rft_g", "cap",
                  "wv", "rhs", "weight", "x", "diag0", "rem", "y", "capacity", "total", "size", "arm")
"""The float work arrays of the per-world solves (rft_mujoco.warp.handle._State)."""


@pytest.mark.parametrize("nworld", [4, 20])
def test_work_buffers_hold_nothing_stale(quadruped, nworld):
    """Fewer and more worlds than dofs (18), every float work array NaN-filled before the evaluation: the same
    wrenches, bit for bit, as with fresh buffers (a kernel that reads what it did not write this evaluation,
    or loops over the world axis instead of another, fails)."""
    model, mjw_model = quadruped
    states, forces, _, _ = _cpu_snapshots(model, None)
    states = (states * 4)[:nworld]
    clean = _evaluate_warp(model, mjw_model, states, None).force
    dw = _warp_data(model, states)
    handle = rw.attach(model, mjw_model, MEDIA, None, data=dw)
    try:
        st = handle.bind(dw)
        st.last_time.assign(np.array([s["time"] - model.opt.timestep for s in states], dtype=np.float32))
        for name in SCRATCH_FLOATS:
            arr = getattr(st, name)
            arr.assign(np.full(arr.numpy().shape, np.nan))
        mjw.forward(mjw_model, dw)
        dirty = handle.forces(dw)
    finally:
        handle.detach()
    assert np.array_equal(dirty, clean)
    for i in range(min(nworld, len(CPU_SNAPSHOT_STEPS))):
        assert _rel(clean[i], forces[i]) < FORCE_RTOL


# --- parity over a trajectory (the targets) ----------------------------------------------------
def _trajectory_parity(model, mjw_model, datas, bodies, steps=50, **kwargs):
    """Step N MjData on the CPU path and N warp worlds made from them together: (first-step force error per
    world, sum |F| over bodies, largest body-position difference m, first-step occluded area CPU and warp)."""
    dw = mjw.put_data(model, datas[0], nworld=len(datas), nconmax=4, njmax=64)
    for field, name in ((dw.qpos, "qpos"), (dw.qvel, "qvel"), (dw.ctrl, "ctrl")):
        field.assign(np.array([getattr(d, name) for d in datas], dtype=np.float32))
    cpu = rft_mujoco.attach(model, MEDIA, bodies, monitor=False, **kwargs)
    handle = rw.attach(model, mjw_model, MEDIA, bodies, data=dw, **kwargs)
    try:
        worst = 0.0
        for k in range(steps):
            for d in datas:
                mujoco.mj_step(model, d)
            mjw.step(mjw_model, dw)
            if k == 0:
                fc = np.array([cpu.diagnostics(d).force for d in datas])
                occ_cpu = np.array([cpu.diagnostics(d).occluded_area for d in datas])
                diag = handle.diagnostics(dw)
                total = np.abs(fc).sum(axis=(1, 2))
                err = np.abs(diag.force - fc).sum(axis=(1, 2)) / total
                occ_warp = diag.occluded_area
            worst = max(worst, np.abs(dw.xpos.numpy() - np.array([d.xpos for d in datas])).max())
    finally:
        handle.detach()
        cpu.detach()
    return err, total, worst, occ_cpu, occ_warp


KNEE_DEEP = 0.15
"""Sand surface (m) at the quadruped's knees in ``home``: calves enter their thighs inside the sand."""


@pytest.mark.parametrize("surface", [0.0, KNEE_DEEP], ids=["feet_in_sand", "knee_deep"])
def test_trajectories_match_cpu_over_0p1_s(quadruped, surface):
    """N worlds on warp against N MjData on the CPU path, every body attached, culling on: quadruped from
    ``home`` 1-2 cm into the sand, joint targets and velocities perturbed per world, 50 steps (0.1 s). Knee
    deep, the calves' and thighs' surface inside each other at the knees is culled at run time."""
    model, mjw_model = quadruped
    rng = np.random.default_rng(0)
    key = model.key("home")
    datas = []
    for i in range(3):
        d = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, d, key.id)
        d.qpos[2] -= 0.01 + 0.005 * i
        d.qvel[:] = 0.05 * rng.standard_normal(model.nv)
        d.ctrl[:] = key.ctrl + 0.05 * rng.standard_normal(model.nu)
        datas.append(d)
    err, total, worst, occ_cpu, occ_warp = _trajectory_parity(model, mjw_model, datas, None, surface_height=surface)
    assert total.sum() > 10.0
    assert err.max() < PARITY_FORCE_RTOL, err
    assert worst < PARITY_TRAJECTORY_M, worst
    assert np.allclose(occ_warp, occ_cpu, rtol=1e-3, atol=1e-7)
    if surface == KNEE_DEEP:
        assert np.all(occ_cpu.sum(axis=1) > 1e-3)                  # culling at work in every world


HINGE_CHAIN = """
<mujoco model="hinge_chain">
  <option timestep="0.002" integrator="implicitfast"/>
  <worldbody>
    <body name="a" pos="0 0 0.002">
      <freejoint/>
      <geom type="capsule" size="0.025" fromto="0 0 0 0.2 0 0"/>
      <body name="b" pos="0.2 0 0">
        <joint name="hinge" type="hinge" axis="0 0 1" damping="0.02"/>
        <geom type="capsule" size="0.018" fromto="0 0 0 0.2 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
"""Two capsules lying half in the sand, hinged at a's end inside a's end sphere (other radii: no shared surface)."""
HINGE_ANGLES = (0.0, 0.6, 1.3, 2.1)


@pytest.fixture(scope="module")
def hinge_chain():
    model = mujoco.MjModel.from_xml_string(HINGE_CHAIN)
    return model, mjw.put_model(model)


def _hinge_datas(model, angles=HINGE_ANGLES, speed=1.5):
    datas = []
    for angle in angles:
        d = mujoco.MjData(model)
        d.qpos[7] = angle
        d.qvel[6] = -speed if angle > 1.0 else speed              # the joint sweeps: the overlap changes
        datas.append(d)
    return datas


def test_hinge_chain_culling_matches_cpu(hinge_chain):
    """Each capsule's surface inside the other's near the hinge is culled at run time, at several angles
    (one per world), while the hinge turns: forces within 1% at the first step, positions within 2 mm over 0.1 s."""
    model, mjw_model = hinge_chain
    err, total, worst, occ_cpu, occ_warp = _trajectory_parity(model, mjw_model, _hinge_datas(model), None)
    assert total.min() > 1.0
    assert err.max() < PARITY_FORCE_RTOL, err
    assert worst < PARITY_TRAJECTORY_M, worst
    assert np.all(occ_cpu > 1e-5), occ_cpu                      # both capsules, every angle
    assert np.allclose(occ_warp, occ_cpu, rtol=1e-3, atol=1e-7)


def test_culling_matters_and_cull_false_matches_cpu(quadruped, hinge_chain):
    """On the same states (knee-deep quadruped from the CPU run; the hinge chain): warp with culling matches the
    CPU path with culling to round-off, without culling the CPU path without it, and the two settings differ."""
    model, mjw_model = quadruped
    snap = {}
    for cull in (True, False):
        states, forces, _, resting = _cpu_snapshots(model, None, steps=(5, 20, 60), surface_height=KNEE_DEEP,
                                                    cull=cull)
        diag = _evaluate_warp(model, mjw_model, states, None, surface_height=KNEE_DEEP, cull=cull)
        for i in range(len(states)):
            assert _rel(diag.force[i], forces[i]) < FORCE_RTOL, (cull, i)
        assert np.array_equal(diag.resting, resting)
        assert (diag.occluded_area.sum(axis=1) > 1e-3).all() if cull else not diag.occluded_area.any()
        snap[cull] = states
    other = _evaluate_warp(model, mjw_model, snap[True], None, surface_height=KNEE_DEEP, cull=False)
    culled = _evaluate_warp(model, mjw_model, snap[True], None, surface_height=KNEE_DEEP)
    assert _rel(other.force, culled.force) > 0.05
    model, mjw_model = hinge_chain
    datas = _hinge_datas(model)
    states = [dict(qpos=d.qpos.copy(), qvel=d.qvel.copy(), qfrc_constraint=d.qfrc_constraint.copy(), time=0.0)
              for d in datas]
    for cull in (True, False):
        expect = []
        cpu = rft_mujoco.attach(model, MEDIA, None, monitor=False, cull=cull)
        try:
            for d in datas:
                mujoco.mj_forward(model, d)
                expect.append(cpu.diagnostics(d).force.copy())
        finally:
            cpu.detach()
        dw = mjw.put_data(model, datas[0], nworld=len(datas), nconmax=4, njmax=64)
        for field, name in (("qpos", dw.qpos), ("qvel", dw.qvel)):
            name.assign(np.array([s[field] for s in states], dtype=np.float32))
        handle = rw.attach(model, mjw_model, MEDIA, None, data=dw, cull=cull)
        try:
            mjw.forward(mjw_model, dw)
            f = handle.forces(dw)
        finally:
            handle.detach()
        for i in range(len(datas)):
            assert _rel(f[i], expect[i]) < FORCE_RTOL, (cull, i)
        snap[cull] = f
    assert _rel(snap[False], snap[True]) > 0.02


# --- xfrc_applied is shared with the user ---------------------------------------------------------------
def test_user_wrench_survives_and_detach_restores_it(quadruped):
    model, mjw_model = quadruped
    states, _, _, _ = _cpu_snapshots(model, FOOT_BODIES, steps=(60,))
    dw = _warp_data(model, states * 2)
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw)
    foot = int(handle.body_ids[0])
    trunk = model.body("trunk").id
    user = np.zeros((2, model.nbody, 6), dtype=np.float32)
    user[:, foot] = [1.0, 2.0, 3.0, 0.1, 0.2, 0.3]
    user[:, trunk, 2] = 5.0
    dw.xfrc_applied.assign(user)
    try:
        mjw.forward(mjw_model, dw)
        sand = handle.bind(dw).sand.numpy()
        assert np.abs(sand[:, 0]).max() > 0.1
        x = dw.xfrc_applied.numpy()
        assert np.allclose(x[:, foot], user[:, foot] + sand[:, 0], atol=1e-5)
        assert np.array_equal(x[:, trunk], user[:, trunk])
        mjw.forward(mjw_model, dw)                        # left alone: still user + sand, never twice the sand
        sand = handle.bind(dw).sand.numpy()
        assert np.allclose(dw.xfrc_applied.numpy()[:, foot], user[:, foot] + sand[:, 0], atol=1e-5)
        x = dw.xfrc_applied.numpy()
        x[1, foot] = 0.0                                   # world 1: the user zeroes the row
        dw.xfrc_applied.assign(x)
        mjw.forward(mjw_model, dw)
        sand = handle.bind(dw).sand.numpy()
        x = dw.xfrc_applied.numpy()
        assert np.allclose(x[0, foot], user[0, foot] + sand[0, 0], atol=1e-5)
        assert np.allclose(x[1, foot], sand[1, 0], atol=1e-6)
    finally:
        handle.detach()
    x = dw.xfrc_applied.numpy()
    assert np.allclose(x[0, foot], user[0, foot], atol=1e-5) and np.allclose(x[1, foot], 0.0, atol=1e-6)
    assert mjw_model.callback.control is None


def test_nan_input_flags_only_that_world(quadruped):
    model, mjw_model = quadruped
    states, _, _, _ = _cpu_snapshots(model, FOOT_BODIES, steps=(60,))
    dw = _warp_data(model, states * 2)
    qfrc = np.zeros((2, model.nv), dtype=np.float32)
    qfrc[1, 7] = np.nan
    dw.qfrc_applied.assign(qfrc)
    handle = rw.attach(model, mjw_model, MEDIA, FOOT_BODIES, data=dw)
    try:
        mjw.forward(mjw_model, dw)
        diag = handle.diagnostics(dw)
        assert diag.errors[0] == 0 and diag.errors[1] & int(K.BAD_ACCELERATION)
        assert np.abs(diag.force[0]).max() > 0.1 and np.all(diag.force[1] == 0.0)
        with pytest.raises(FloatingPointError, match=r"worlds \[1\]"):
            handle.check(dw)
        handle.check(dw)                                   # cleared
    finally:
        handle.detach()


def test_attach_errors(quadruped):
    model, mjw_model = quadruped
    with pytest.raises(TypeError, match="mujoco_warp.Model"):
        rw.attach(model, model, MEDIA)
    handle = rw.attach(model, mjw_model, MEDIA, ["FL_foot"])
    try:
        with pytest.raises(ValueError, match="already have sand"):
            rw.attach(model, mjw_model, MEDIA, ["FL_foot", "FR_foot"])
        with pytest.raises(ValueError, match="no body named"):
            rw.attach(model, mjw_model, MEDIA, ["nope"])
    finally:
        handle.detach()
    assert mjw_model.callback.control is None


def test_core_library_does_not_import_warp():
    import subprocess
    import sys

    code = ("import sys, rft_mujoco, rft_mujoco.coupling.handle, rft_mujoco.studies.bench_warp, rft_mujoco.studies.cli; "
            "sys.exit(('warp' in sys.modules) + 2 * ('mujoco_warp' in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --- the benchmark's command line -----------------------------------------------------------------------
def test_bench_warp_parser_takes_worlds_and_the_nworld_alias():
    from rft_mujoco.studies import bench_warp

    parser = bench_warp.make_parser()
    assert parser.parse_args(["--worlds", "1", "8"]).worlds == [1, 8]
    assert parser.parse_args(["--nworld", "4"]).worlds == [4]
    assert parser.parse_args([]).worlds is None


def test_bench_warp_cli_runs(tmp_path, capsys):
    """``python -m rft_mujoco bench --warp ...`` through the CLI dispatcher, as small as it goes."""
    from rft_mujoco.studies import cli

    rc = cli.main(["bench", "--warp", "--device", DEVICE, "--quick", "--worlds", "1", "2", "--budget", "0.01",
                   "--parity-steps", "2", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "1. Parity" in out and "2. Throughput" in out and "world-steps/s" in out
    for case in ("no sand", "sand: feet", "sand: every body", "cull=False", "CPU path"):
        assert case in out, case
    assert (tmp_path / "world_steps.png").stat().st_size > 10_000
