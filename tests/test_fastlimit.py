"""The compiled stabilized evaluation (rft_mujoco.fastlimit) against MuJoCo and the numpy reference path."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco import fastlimit, kernel, law
from rft_mujoco.terrain import FlatSurface

from test_fastkernel import MEDIA, SCENE, trajectory

pytestmark = pytest.mark.skipif(not rft_mujoco.fastkernel.AVAILABLE, reason="numba is not installed")

TREE = """
<mujoco>
  <worldbody>
    <body name="free" pos="0 0 0.3">
      <freejoint/>
      <geom type="box" size="0.1 0.05 0.02" mass="2"/>
      <body name="welded" pos="0.1 0 0">
        <geom type="sphere" size="0.03" mass="0.3"/>
        <body name="hinge" pos="0.05 0 0">
          <joint type="hinge" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.1 0 -0.1" size="0.01" mass="0.2"/>
          <body name="ball" pos="0.1 0 -0.1">
            <joint type="ball"/>
            <geom type="cylinder" size="0.02 0.02" mass="0.1"/>
            <body name="slide" pos="0 0 -0.03">
              <joint type="slide" axis="1 0 0"/>
              <geom type="sphere" size="0.015" mass="0.05"/>
            </body>
          </body>
        </body>
      </body>
    </body>
    <body name="fixed" pos="1 0 0">
      <geom type="sphere" size="0.05" mass="1"/>
    </body>
    <body name="arm" pos="-0.5 0 0.2">
      <joint type="hinge" axis="1 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0.1 0" size="0.01" mass="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def random_state(model, seed):
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    data.qpos[:] = rng.normal(size=model.nq) * 0.3
    data.qpos[3:7] /= np.linalg.norm(data.qpos[3:7])
    data.qpos[10:14] /= np.linalg.norm(data.qpos[10:14])
    data.qvel[:] = rng.normal(size=model.nv)
    mujoco.mj_forward(model, data)
    return data


def tree(model):
    return tuple(np.ascontiguousarray(a, dtype=np.int64) for a in (
        model.body_rootid, model.body_dofnum, model.body_dofadr, model.body_parentid, model.dof_parentid))


@pytest.mark.parametrize("seed", range(3))
def test_body_jacobians_equal_mujoco(seed):
    """Free, ball, hinge and slide joints, a body welded to its parent, a fixed body, a second tree."""
    model = mujoco.MjModel.from_xml_string(TREE)
    data = random_state(model, seed)
    bids = np.arange(1, model.nbody, dtype=np.int64)
    jac = np.full((bids.size, 6, model.nv), np.nan)
    fastlimit.body_jacobians(bids, bids.size, data.xipos, data.cdof, data.subtree_com, *tree(model), jac)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for i, b in enumerate(bids):
        mujoco.mj_jacBodyCom(model, data, jacp, jacr, int(b))
        np.testing.assert_allclose(jac[i, :3], jacp, rtol=0, atol=1e-12, err_msg=model.body(int(b)).name)
        np.testing.assert_allclose(jac[i, 3:], jacr, rtol=0, atol=1e-12, err_msg=model.body(int(b)).name)
    assert np.all(jac[bids.tolist().index(model.body("fixed").id)] == 0.0)


@pytest.mark.parametrize("seed", range(3))
def test_free_acceleration_equals_mujoco(seed):
    """M^-1 (smooth forces + user xfrc_applied) against mj_applyFT and mj_solveM; NaN input is reported."""
    model = mujoco.MjModel.from_xml_string(TREE)
    data = random_state(model, seed)
    rng = np.random.default_rng(seed)
    data.qfrc_applied[:] = rng.normal(size=model.nv)
    user = np.zeros((model.nbody, 6))
    user[[2, 4, 7]] = rng.normal(size=(3, 6))                  # welded, ball and the second tree
    mujoco.mj_forward(model, data)
    qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
    for b in (2, 4, 7):
        mujoco.mj_applyFT(model, data, user[b, :3].copy(), user[b, 3:].copy(), data.xipos[b].copy(), b, qfrc)
    ref = np.empty(model.nv)
    mujoco.mj_solveM(model, data, ref.reshape(1, -1), qfrc.reshape(1, -1))
    minv = np.empty((model.nv, model.nv))
    mujoco.mj_solveM(model, data, minv, np.eye(model.nv))
    qacc = np.empty(model.nv)
    args = (data.xipos, data.cdof, data.subtree_com, *tree(model), data.qfrc_passive, data.qfrc_bias,
            data.qfrc_actuator, data.qfrc_applied, minv, qacc, np.empty(7 * model.nv), np.empty(1, np.int64))
    assert fastlimit.free_acceleration(user, *args)
    np.testing.assert_allclose(qacc, ref, rtol=1e-10, atol=1e-10)
    user[4, 2] = np.nan
    assert not fastlimit.free_acceleration(user, *args)


# --- the whole stabilized evaluation against the numpy limiter ----------------------------------------------
def energy_after(model, data, wrench_rows, handle):
    """Kinetic energy after the step (J) when the sand wrenches (B, 6) act, from the data's free motion."""
    dt = model.opt.timestep
    mujoco.mj_fwdActuation(model, data)
    qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for i, b in enumerate(handle.body_ids):
        mujoco.mj_jacBodyCom(model, data, jacp, jacr, int(b))
        qfrc = qfrc + jacp.T @ wrench_rows[i, :3] + jacr.T @ wrench_rows[i, 3:]
    qacc = np.empty(model.nv)
    mujoco.mj_solveM(model, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
    v = data.qvel + dt * qacc
    return 0.5 * v @ np.linalg.solve(_minv(model, data), v)


def _minv(model, data):
    out = np.empty((model.nv, model.nv))
    mujoco.mj_solveM(model, data, out, np.eye(model.nv))
    return out


def sand_wrenches(model, states, compiled, warm_start, terrain, guards):
    """Per state: the applied sand wrenches (B, 6), the octant-group diagnostics, and the energy after the
    step, evaluated with mj_forward in sequence (the warm start follows the states)."""
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    out = []
    with rft_mujoco.attach(model, MEDIA, None, terrain, 0.01, guards=guards, monitor=False,
                           backend="numba", warm_start=warm_start) as handle:
        assert handle.warm_start is warm_start
        handle.compiled_limiter = compiled
        for state in states:
            mujoco.mj_setState(model, data, state, spec)
            mujoco.mj_forward(model, data)
            d = handle.diagnostics(data)
            w = np.concatenate([d.force, d.torque], axis=1)
            out.append((w, d.rft_force.copy(), d.submerged.copy(), energy_after(model, data, w, handle),
                        energy_after(model, data, np.zeros_like(w), handle)))
    return out


@pytest.mark.parametrize("integrator,terrain_i", [("Euler", 0), ("RK4", 1), ("implicitfast", 2)])
def test_compiled_limiter_equals_numpy_limiter(integrator, terrain_i):
    """Cold-started, the compiled path solves the same QP from the same start with the same sweeps (its
    factor A differs from the numpy one by an orthogonal transform, which leaves every iterate unchanged up
    to round-off, which the sweep cap can amplify): the RFT wrenches agree to round-off, the kinetic energy
    after the step to 1e-4 of the energy removed (measured: at most 6e-6)."""
    terrain = [FlatSurface(0.0), FlatSurface(0.02), FlatSurface(-0.01)][terrain_i]
    guards = law.Guards.all() if terrain_i == 1 else law.PUBLISHED
    model, states = trajectory(integrator, terrain, True, guards, steps=60)
    ref = sand_wrenches(model, states, False, False, terrain, guards)
    got = sand_wrenches(model, states, True, False, terrain, guards)
    limited = 0
    for (w_r, f_r, n_r, e_r, e0), (w_g, f_g, n_g, e_g, _) in zip(ref, got):
        np.testing.assert_allclose(f_g, f_r, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(f_r).max()))
        np.testing.assert_array_equal(n_g, n_r)
        removed = max(e0 - e_r, 1e-12)
        assert abs(e_g - e_r) <= 1e-4 * removed + 1e-12, (e_g, e_r, e0)
        limited += int(np.any(np.abs(w_r[:, :3]) < np.abs(f_r) - 1e-9))
    assert limited > 5                                   # the limiter did bind along the rollout


def test_warm_start_is_as_good_as_cold():
    """On a settling rollout the warm-started solves (LIMITER_WARM_ITERATIONS sweeps, LIMITER_WARM_ENERGY_TOL)
    leave about as much kinetic energy as the cold ones (LIMITER_ITERATIONS): beyond them by a median
    under 1e-4 and at most 1e-2 of what the sand removes (measured here: median 1.6e-6, largest 1.1e-3), and
    never add energy."""
    terrain = FlatSurface(0.0)
    model, states = trajectory("Euler", terrain, True, law.PUBLISHED, steps=80)
    cold = sand_wrenches(model, states, True, False, terrain, law.PUBLISHED)
    warm = sand_wrenches(model, states, True, True, terrain, law.PUBLISHED)
    excess = []
    for (_, _, _, e_c, e0), (_, _, _, e_w, _) in zip(cold, warm):
        assert e_w <= e0 + 1e-12
        if e0 - e_c > 1e-9:
            excess.append((e_w - e_c) / (e0 - e_c))
    assert len(excess) > 20
    assert np.median(excess) <= 1e-4
    assert max(excess) <= 1e-2


def test_warm_start_restarts_cold_after_a_reset():
    """Time running back (a reset) or jumping ahead by more than a step starts the limiter cold: rollouts
    from a reset repeat bit for bit, and equal the cold-started evaluation at their first step."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba",
                           warm_start=True) as handle:
        runs = []
        for _ in range(2):
            mujoco.mj_resetData(model, data)
            data.qvel[:] = np.random.default_rng(3).normal(size=model.nv) * 0.5
            xfrc = []
            for _ in range(40):
                mujoco.mj_step(model, data)
                xfrc.append(data.xfrc_applied.copy())
            runs.append(np.array(xfrc))
        np.testing.assert_array_equal(runs[0], runs[1])
        # a jump ahead in time: the same as a cold start at that state
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(model, spec))
        mujoco.mj_getState(model, data, state, spec)
        data.time += 1.0
        mujoco.mj_forward(model, data)
        jumped = data.xfrc_applied.copy()
        handle.warm_start = False
        mujoco.mj_forward(model, data)
        np.testing.assert_array_equal(data.xfrc_applied, jumped)


def test_solver_settings_follow_the_kernel_module(monkeypatch):
    monkeypatch.setattr(kernel, "LIMITER_WARM_ITERATIONS", 7)
    monkeypatch.setattr(kernel, "REST_COLUMNS", 2)
    monkeypatch.setattr(kernel, "LIMITER_WARM_ENERGY_TOL", 1e-6)
    s = fastlimit.solver_settings()
    assert s[6] == 7 and s[4] == 2 and s[7] == 1e-6 and s[0] == kernel.LIMITER_ITERATIONS


def test_cholesky_factor_matches_numpy_and_survives_singular_input():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(7, 7))
    M = a @ a.T + 0.1 * np.eye(7)
    np.testing.assert_allclose(fastlimit._cholesky(M, np.full((7, 7), np.nan)), np.linalg.cholesky(M), rtol=1e-12,
                               atol=1e-12)
    singular = np.outer(a[0], a[0])                       # rank 1: LAPACK would raise
    C = fastlimit._cholesky(singular, np.empty((7, 7)))
    assert np.all(np.isfinite(C))
    np.testing.assert_allclose(C @ C.T, singular, atol=1e-6 * np.abs(singular).max())


@pytest.mark.parametrize("integrator", ["Euler", "implicitfast"])
def test_stabilized_evaluation_reads_nothing_stale_from_its_buffers(integrator):
    """Every working array of the stabilized evaluation is a view into two per-MjData buffers
    (fastlimit.arena_sizes). Filling them with garbage before every step must not change a bit of the
    rollout: each evaluation writes what it reads. Settling bodies (the limiter's rest rounds run)."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator=integrator))
    runs, limited = [], 0
    for poison in (False, True):
        data = mujoco.MjData(model)
        with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba") as handle:
            data.qvel[:] = np.random.default_rng(5).normal(size=model.nv) * 0.3
            qpos = []
            for _ in range(150):
                if poison and data in handle._work:
                    work = handle._work[data]
                    work.arena[:] = np.nan
                    work.iarena[:] = -123456789
                mujoco.mj_step(model, data)
                qpos.append(data.qpos.copy())
                limited += int(np.any(handle.diagnostics(data).scale < 1.0))
            assert handle._work[data].arena.size > 0
        runs.append(np.array(qpos))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert limited > 0                                      # the limiter did scale wrenches down


def test_buffers_are_as_long_as_the_evaluation_uses():
    """fastlimit.arena_sizes covers every view the evaluation carves (numba does not check bounds): with the
    buffers followed by a guard zone, a limited one-body evaluation (every body touching: the largest
    carve) leaves the guard untouched. (It caught the int buffer one word short: the rest rounds' flags
    were written past its end.)"""
    model = mujoco.MjModel.from_xml_string("""
    <mujoco><option timestep="0.002"/><worldbody>
      <body name="ball" pos="0 0 0.02"><freejoint/><geom type="sphere" size="0.05" mass="1"/></body>
    </worldbody></mujoco>""")
    data = mujoco.MjData(model)
    guard = 64
    with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba") as handle:
        handle.native = False                       # the dispatched call: it rebuilds its arguments below
        mujoco.mj_step(model, data)
        work = handle._work[data]
        n_float, n_int = fastlimit.arena_sizes(1, model.nv, int(handle._solver[4]))
        assert (work.arena.size, work.iarena.size) == (n_float, n_int)
        padded = np.full(n_float + guard, np.nan), np.full(n_int + guard, -7, dtype=np.int64)
        work.arena, work.iarena = padded[0][:n_float], padded[1][:n_int]
        work.args = None
        limited = 0
        for _ in range(300):
            mujoco.mj_step(model, data)
            limited += int(handle.diagnostics(data).scale[0] < 1.0)
        assert limited > 0                                      # the limiter and its rest rounds ran
        assert np.all(np.isnan(padded[0][n_float:])) and np.all(padded[1][n_int:] == -7)
