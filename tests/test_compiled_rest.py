"""The compiled rest evaluation (rft_mujoco.compiled.rest) against MuJoCo and against the numpy reference."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.compiled import locks
from rft_mujoco.compiled import rest as fastrest
from rft_mujoco.coupling.book import RK4_STAGES
from rft_mujoco.physics import law, rest
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface

from conftest import numpy_rollout

MEDIA = rft_mujoco.LI_LOOSE_GLASS_BEADS

SCENE = """
<mujoco>
  <option timestep="0.002" integrator="{integrator}"/>
  <worldbody>
    <body name="ball" pos="0 0 0.03"><freejoint/><geom type="sphere" size="0.05" mass="1"/></body>
    <body name="brick" pos="0.3 0 0.0"><freejoint/>
      <geom type="box" size="0.04 0.03 0.02" euler="0.2 0.1 0" mass="0.5"/>
      <geom type="capsule" size="0.01 0.03" pos="-0.03 0 0.02" mass="0.1"/>
      <body name="brick_lid" pos="0 0 -0.02"><geom type="box" size="0.03 0.03 0.005" mass="0.05"/></body>
    </body>
    <body name="trunk" pos="-0.3 0 0.25"><freejoint/>
      <geom type="box" size="0.1 0.05 0.03" mass="3" contype="0" conaffinity="0"/>
      <body name="leg" pos="0.05 0 -0.03"><joint type="hinge" axis="0 1 0" range="-1 1"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.015" mass="0.2"/>
        <body name="foot" pos="0 0 -0.2"><joint type="slide" axis="0 0 1" range="-0.02 0.02"/>
          <geom type="sphere" size="0.025" mass="0.05"/></body>
      </body>
      <body name="leg2" pos="-0.05 0 -0.03"><joint type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.22" size="0.015" mass="0.2"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
BODIES = ["ball", "brick", "brick_lid", "leg", "foot", "leg2"]      # brick and brick_lid: one weld group



def test_solve_m_equals_mujoco_and_the_layout_check_passes():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    data.qpos[:] = model.qpos0
    data.qvel[:] = rng.normal(size=model.nv)
    mujoco.mj_forward(model, data)
    assert fastrest.check_layout(model, mujoco.MjData(model))
    for _ in range(5):
        y = rng.normal(size=model.nv)
        ref = np.zeros(model.nv)
        mujoco.mj_solveM(model, data, ref.reshape(1, -1), y.reshape(1, -1))
        x = y.copy()
        fastrest.solve_m(model.M_rownnz.astype(np.int64), model.M_rowadr.astype(np.int64),
                         model.M_colind.astype(np.int64), data.qLD, data.qLDiagInv, x)
        np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_jacobian_equals_mj_jacbodycom():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    data.qvel[:] = np.random.default_rng(1).normal(size=model.nv)
    mujoco.mj_forward(model, data)
    i8 = np.int64
    out = np.zeros((6, model.nv))
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for b in range(1, model.nbody):
        p = data.xipos[b]
        tree = tuple(getattr(model, name).astype(i8) for name in fastrest.JAC_TREE)
        fastrest.jacobian(b, p[0], p[1], p[2], data.cdof, data.subtree_com, tree, out, 0)
        mujoco.mj_jacBodyCom(model, data, jacp, jacr, b)
        np.testing.assert_allclose(out[:3], jacp, atol=1e-14)
        np.testing.assert_allclose(out[3:], jacr, atol=1e-14)


def rollout_states(integrator, terrain, steps=60, seed=0):
    """Physics states along a rollout with sand (numpy backend)."""
    return numpy_rollout(SCENE.format(integrator=integrator), MEDIA, BODIES, terrain, steps, 0.3, seed)


def evaluate_at(model, states, backend, terrain, guards):
    """xfrc_applied and diagnostics after one mj_forward at every state (a user wrench on odd states)."""
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    out = []
    with rft_mujoco.attach(model, MEDIA, BODIES, terrain, 0.01, guards=guards, monitor=False,
                           backend=backend, reuse_tol=0.0) as handle:   # the reference never reuses
        assert handle.backend == backend
        for i, state in enumerate(states):
            mujoco.mj_setState(model, data, state, spec)
            data.xfrc_applied[:] = 0.0
            if i % 2:
                data.xfrc_applied[model.body("ball").id] = [0.5, 0.0, -3.0, 0.0, 0.01, 0.0]
            mujoco.mj_forward(model, data)
            d = handle.diagnostics(data)
            out.append((data.xfrc_applied.copy(), np.concatenate([
                d.force, d.torque, d.rft_force, d.max_depth[:, None], d.scale[:, None], d.submerged[:, None],
                d.resting[:, None]], axis=1)))
    return out


@pytest.mark.parametrize("integrator,terrain_kind", [("Euler", "flat"), ("RK4", "heightfield"),
                                                     ("implicitfast", "flat")])
def test_compiled_rest_equals_the_numpy_reference(integrator, terrain_kind):
    if terrain_kind == "flat":
        terrain = FlatSurface(0.0)
    else:
        x = np.linspace(-1, 1, 21)
        terrain = HeightfieldSurface(0.01 * np.sin(3 * x)[None, :] * np.cos(2 * x)[:, None], (-1, 1), (-1, 1))
    guards = law.Guards.all() if integrator == "RK4" else law.PUBLISHED
    model, states = rollout_states(integrator, terrain)
    ref = evaluate_at(model, states, "numpy", terrain, guards)
    got = evaluate_at(model, states, "numba", terrain, guards)
    loaded = resting = 0
    for (x_ref, d_ref), (x_got, d_got) in zip(ref, got):
        scale = max(1.0, np.abs(x_ref).max())
        np.testing.assert_allclose(x_got, x_ref, rtol=1e-8, atol=1e-8 * scale)
        np.testing.assert_allclose(d_got, d_ref, rtol=1e-8, atol=1e-8 * max(1.0, np.abs(d_ref).max()))
        loaded += int(np.count_nonzero(d_ref[:, 2]))
        resting += int(d_ref[:, -1].sum())
    assert loaded > 50 and resting > 5            # many loaded bodies, some of them held at rest


@pytest.mark.parametrize("stages", ["all", "midpoint"])
def test_rk4_later_stages_agree_with_the_reference_and_keep_the_first_stage_mobility(stages):
    """mj_step with RK4: the later stages evaluated (2-4, or 2 with "midpoint") use the first stage's mobility
    and rest factor while the same groups touch (3 of 4, or 1 of 2 evaluations here); the compiled path and
    the numpy reference keep the same and step the same rollout."""
    per_step = RK4_STAGES[stages]
    runs = {}
    for backend in ("numpy", "numba"):
        model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="RK4"))
        data = mujoco.MjData(model)
        data.qvel[:] = np.random.default_rng(0).normal(size=model.nv) * 0.3
        with rft_mujoco.attach(model, MEDIA, BODIES, FlatSurface(0.0), 0.01, monitor=False, rk4_stages=stages,
                               backend=backend, reuse_tol=0.0) as handle:   # the reference never reuses
            path = []
            for _ in range(300):
                mujoco.mj_step(model, data)
                path.append(np.concatenate([data.qpos, data.qvel]))
            kept = handle.counters(data).kept_evaluations
            runs[backend] = np.array(path), kept, handle.evaluations, int(handle.diagnostics(data).resting.sum())
    (ref, kept_ref, n_ref, resting), (got, kept_got, n_got, _) = runs["numpy"], runs["numba"]
    assert n_ref == n_got == 300 * per_step and kept_ref == kept_got
    later = (per_step - 1) / per_step                                # stages 2-4 (or 2) of (nearly) every step
    assert later - 0.05 <= kept_got / n_got <= later
    assert resting >= 5
    np.testing.assert_allclose(got, ref, rtol=0.0, atol=1e-9)     # round-off only ("midpoint": 1.8e-10 at 300 steps)


def test_weld_groups_and_their_shares():
    """Bodies welded together form one group: their wrenches add up to the group's, about its reference
    point, whatever the split (the split only changes the diagnostics)."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    handle = rft_mujoco.attach(model, MEDIA, BODIES, 0.0, 0.01, monitor=False)
    g = handle.groups
    names = handle.body_names
    assert g.of_body[names.index("brick")] == g.of_body[names.index("brick_lid")]
    assert len(set(g.of_body.tolist())) == len(BODIES) - 1
    assert np.all(g.radius > 0.0)


@pytest.mark.parametrize("m, rank, width", [(6, 6, 6), (24, 14, 30), (48, 18, 48), (13, 13, 20), (1, 1, 4)])
def test_min_norm_solve_equals_the_reference_bit_for_bit(m, rank, width):
    """The compiled rest solve (row updates, work buffers, a block inside a wider buffer) gives exactly the
    reference's numbers, full-rank and rank-deficient (rank < m: dependent rows left out), with weights."""
    rng = np.random.default_rng(m * 100 + rank)
    for _ in range(5):
        c = rng.normal(size=(m, rank)) * rng.uniform(0.1, 10.0, rank)
        a_small = c @ c.T
        a_small = 0.5 * (a_small + a_small.T)
        a = np.full((width, width), np.nan)
        a[:m, :m] = a_small
        rhs = rng.normal(size=width)
        weight = rng.uniform(0.01, 3.0, width)
        ref = rest.pivoted_solve(a_small, rhs[:m].copy(), weight[:m].copy(), rest.DEPENDENT_TOL, 1e-300)
        lin = np.full((3 * width + 5, width), np.nan)
        perm = np.full(2 * width, -7, dtype=np.int64)
        x = np.full(width, np.nan)
        fastrest.min_norm_solve(a, rhs, weight, m, rest.DEPENDENT_TOL, 1e-300, lin, perm, x)
        assert np.array_equal(x[:m], ref)
        assert np.abs(ref).max() > 0.0


FRICTION_SCENE = (SCENE.replace('range="-1 1"/>', 'range="-1 1" frictionloss="0.4"/>')
                  .replace('range="-0.02 0.02"/>', 'range="-0.02 0.02" frictionloss="1.5"/>')
                  .replace('<joint type="hinge" axis="0 1 0"/>', '<joint type="hinge" axis="0 1 0" frictionloss="0.2"/>'))


def test_mujoco_friction_rows_in_their_unsaturated_zone_give_the_estimated_force():
    """What the lock test relies on: a frictionloss row's force is -D (qacc - aref) while it is inside its
    bounds (MuJoCo's efc_D, efc_aref, qacc of the same step), and its type code is the compiled one's."""
    assert int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF) == locks.FRICTION_DOF
    model = mujoco.MjModel.from_xml_string(FRICTION_SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    inside = 0
    for _ in range(200):
        mujoco.mj_step(model, data)
        rows = np.flatnonzero(data.efc_type == locks.FRICTION_DOF)
        assert rows.size == 3
        est = rest.friction_estimate(data.efc_D[rows], data.efc_aref[rows], data.qacc[data.efc_id[rows]])
        free = np.abs(data.efc_force[rows]) < data.efc_frictionloss[rows] * (1 - 1e-6)
        np.testing.assert_allclose(est[free], data.efc_force[rows][free], rtol=1e-9, atol=1e-12)
        inside += int(free.sum())
    assert inside > 100


@pytest.mark.parametrize("integrator,steps", [("Euler", 250), ("RK4", 100)])
def test_dofs_held_by_dry_friction_are_locked_alike_by_both_paths(integrator, steps):
    """Rollouts with frictionloss on every joint: the compiled path locks the same dofs in the same
    evaluations as the numpy reference and steps the same motion (round-off grows to 1e-10 by step 100
    of RK4, and to 1e-7 at a transient near step 110, with the same locks: the test stops before it)."""
    runs = {}
    for backend in ("numpy", "numba"):
        model = mujoco.MjModel.from_xml_string(FRICTION_SCENE.format(integrator=integrator))
        data = mujoco.MjData(model)
        data.qvel[:] = np.random.default_rng(1).normal(size=model.nv) * 0.3
        with rft_mujoco.attach(model, MEDIA, BODIES, FlatSurface(0.0), 0.01, monitor=False,
                               backend=backend, reuse_tol=0.0) as handle:   # the reference never reuses
            path = []
            for _ in range(steps):
                mujoco.mj_step(model, data)
                path.append(np.concatenate([data.qpos, data.qvel]))
            counters = handle.counters(data)
            runs[backend] = np.array(path), counters.locked_evaluations, counters.kept_evaluations
    (ref, locked_ref, kept_ref), (got, locked_got, kept_got) = runs["numpy"], runs["numba"]
    assert locked_ref == locked_got and locked_got >= 50
    assert kept_ref == kept_got
    np.testing.assert_allclose(got, ref, rtol=0.0, atol=1e-8)


@pytest.mark.parametrize("dt,integrator", [(0.002, "implicitfast"), (0.005, "Euler")])
def test_a_released_lock_slips_alike_on_both_paths(monkeypatch, dt, integrator):
    """The frictionloss load path through the trunk's landing: where a released lock's lagged force would add
    energy, the dof slips at its bound (physics.rest.locked_rest, step 3); the compiled path steps the same
    motion as the numpy reference, which slips in 2-4 evaluations here."""
    from rft_mujoco.studies import loadpaths
    from rft_mujoco.studies.loadpath_scenes import SCENES

    slips = []
    release = rest._release
    monkeypatch.setattr(rest, "_release", lambda *a: slips.append(a[-1]) or release(*a))
    xml, bodies = SCENES["frictionloss"]
    runs = {}
    for backend in ("numpy", "numba"):
        model = mujoco.MjModel.from_xml_string(xml.format(dt=dt, integrator=integrator))
        data = mujoco.MjData(model)
        with rft_mujoco.attach(model, loadpaths.MEDIA, bodies, resolution=loadpaths.RESOLUTION, monitor=False,
                               backend=backend):
            path = []
            for _ in range(int(round(0.5 / dt))):
                mujoco.mj_step(model, data)
                path.append(np.concatenate([data.qpos, data.qvel]))
        runs[backend] = np.array(path)
    assert 2 <= sum(slips) <= 4
    np.testing.assert_allclose(runs["numba"], runs["numpy"], rtol=0.0, atol=1e-8)
