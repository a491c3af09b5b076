"""attach(reuse_tol=...): a body's RFT wrench taken again while its motion's direction, its pose and its depth hold.

The law is rate independent and flat sand is the same everywhere, so a body whose twist direction, gravity
direction (in its frame) and depth have not changed gets the same wrench; ``reuse_tol`` bounds how much
they may have changed (rft_mujoco.compiled.element_pass.wrenches). These tests check that it is reused where
a robot stands, that the answer is the one every element would give, and that nothing leaks across resets.
"""

import math
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import rft_mujoco
import rft_mujoco.envs  # noqa: F401  (registers the sand ids)
from rft_mujoco.models import path
from rft_mujoco.models.quadruped import TrotGait

pytestmark = pytest.mark.skipif(not rft_mujoco.compiled.AVAILABLE, reason="reuse is the compiled backend's")

MEDIA = "li_loose_glass_beads"


@pytest.mark.parametrize("value", [-1e-3, 0.2, math.nan, True, "1e-3", None])
def test_reuse_tol_outside_0_to_0_1_is_refused_with_what_is_allowed(value):
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='0.05'/></body>"
                                           "</worldbody></mujoco>")
    with pytest.raises(ValueError, match="reuse_tol must be a number from 0"):
        rft_mujoco.attach(model, MEDIA, reuse_tol=value)
    handle = rft_mujoco.attach(model, MEDIA)
    try:
        with pytest.raises(ValueError, match="reuse_tol must be a number from 0"):
            handle.reuse_tol = value
        handle.reuse_tol = 1e-3
        assert handle.reuse_tol == 1e-3
    finally:
        handle.detach()


def test_reuse_is_on_by_default_in_attach_and_in_every_task_and_can_be_switched_off():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='0.05'/></body>"
                                           "</worldbody></mujoco>")
    with rft_mujoco.attach(model, MEDIA) as handle:
        assert handle.reuse_tol == rft_mujoco.coupling.handle.REUSE_TOL_DEFAULT == 1e-3
    for env_id in ("rft_mujoco/SandAnt-v0", "rft_mujoco/SandQuadruped-v1"):       # a wrapped env and a task
        for kwargs, expected in (({}, 1e-3), ({"reuse_tol": 0.0}, 0.0), ({"reuse_tol": 0.01}, 0.01)):
            env = gym.make(env_id, **kwargs)
            try:
                assert env.unwrapped.sand.handle.reuse_tol == expected, (env_id, kwargs)
            finally:
                env.close()


def _quadruped_run(reuse_tol: float):
    """The bundled quadruped, every body, default resolution, floor replaced: 1 s standing from ``home``, then
    0.5 s of the scripted trot; (trunk position after standing, after trotting (m), reuses after each)."""
    model = mujoco.MjModel.from_xml_path(str(path("quadruped.xml")))
    data = mujoco.MjData(model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        handle = rft_mujoco.attach(model, MEDIA, monitor=False, reuse_tol=reuse_tol)
    handle.replace_rigid(["floor"])
    try:
        mujoco.mj_resetDataKeyframe(model, data, 0)
        data.ctrl[:] = data.qpos[7:7 + model.nu]
        dt = model.opt.timestep
        for _ in range(int(round(1.0 / dt))):
            mujoco.mj_step(model, data)
        stand, reused_stand = data.qpos[:3].copy(), handle.counters(data).reused_wrenches
        gait = TrotGait.from_model(model)
        for i in range(int(round(0.5 / dt))):
            data.ctrl[:] = gait.targets(i * dt)
            mujoco.mj_step(model, data)
        return stand, data.qpos[:3].copy(), reused_stand, handle.counters(data).reused_wrenches
    finally:
        handle.detach()


def test_a_standing_quadruped_reuses_its_wrenches_and_moves_as_without():
    """Standing, a third of the eight loaded bodies' evaluations in the first second (settling included) are
    reuses (measured 1,265 of 4,000); the trunk stands and trots where it does with every element evaluated,
    to 0.05 mm (measured: the same to 0.1 um)."""
    stand0, trot0, none_stand, none_all = _quadruped_run(0.0)
    stand, trot, reused_stand, reused_all = _quadruped_run(1e-3)
    assert none_stand == none_all == 0                       # 0: off
    assert reused_stand > 1000, reused_stand                 # of 8 bodies x 500 evaluations
    assert reused_all >= reused_stand
    np.testing.assert_allclose(stand, stand0, rtol=0, atol=5e-5)
    np.testing.assert_allclose(trot, trot0, rtol=0, atol=5e-5)
    assert trot[0] - stand[0] > 0.02                         # it really trotted (0.5 s from standing: 38 mm)


def test_the_numpy_reference_evaluates_every_body_every_time():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body pos='0 0 0.02'><freejoint/>"
                                           "<geom type='box' size='0.05 0.05 0.05' mass='2'/></body>"
                                           "</worldbody></mujoco>")
    data = mujoco.MjData(model)
    handle = rft_mujoco.attach(model, MEDIA, monitor=False, backend="numpy", reuse_tol=1e-3)
    try:
        for _ in range(100):
            mujoco.mj_step(model, data)
        assert handle.counters(data).reused_wrenches == 0
        assert handle.diagnostics(data).submerged.sum() > 0           # it did sit in the sand
    finally:
        handle.detach()


def _box_with_and_without_reuse(xml, ctrl=0.0, change=None):
    """The box scene ``xml`` with ``reuse_tol`` 0 and 1e-3: 300 steps at ``ctrl``, then (with ``change``)
    ``change(model, handle)`` and one step more. Returns {tol: (force and RFT force of the box (6,) N, reuses)}."""
    runs = {}
    for tol in (0.0, 1e-3):
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        handle = rft_mujoco.attach(model, MEDIA, monitor=False, reuse_tol=tol)
        try:
            data.ctrl[:] = ctrl
            for _ in range(300):
                mujoco.mj_step(model, data)
            reused = handle.counters(data).reused_wrenches
            if change is not None:
                change(model, handle)
                mujoco.mj_step(model, data)
            diag = handle.diagnostics(data)
            runs[tol] = np.concatenate([diag.force[0], diag.rft_force[0]]), reused
        finally:
            handle.detach()
    return runs


def test_a_box_sliding_steadily_reuses_its_wrench_and_feels_the_published_drag():
    """A box (2 kg, 10 cm) held 8 cm deep by a slider and dragged by a velocity servo: once it slides steadily its
    direction, pose and depth hold, so its wrench is reused; the force equals the fresh evaluation's."""
    xml = ("<mujoco><option timestep='0.002' integrator='implicitfast'/><worldbody><body pos='0 0 -0.03'>"
           "<joint name='x' type='slide' axis='1 0 0'/><geom type='box' size='0.05 0.05 0.05' mass='2'/>"
           "</body></worldbody><actuator><velocity joint='x' kv='1000'/></actuator></mujoco>")
    runs = _box_with_and_without_reuse(xml, ctrl=0.1)
    assert runs[1e-3][1] > 200
    assert runs[0.0][0][0] < -1.0                             # the sand drags it back
    np.testing.assert_allclose(runs[1e-3][0], runs[0.0][0], rtol=1e-6, atol=1e-9)


def test_with_reuse_an_env_reset_repeats_its_rollout_bit_for_bit():
    env = gym.make("rft_mujoco/SandQuadruped-v0", reuse_tol=1e-3)
    try:
        runs = []
        for _ in range(2):
            env.reset(seed=3)
            rng = np.random.default_rng(3)
            qpos = []
            for t in range(150):
                action = np.zeros(env.action_space.shape) if t < 100 else rng.uniform(-1.0, 1.0, env.action_space.shape)
                env.step(action.astype(env.action_space.dtype))
                qpos.append(env.unwrapped.data.qpos.copy())
            runs.append(np.array(qpos))
        assert env.unwrapped.sand.handle.counters(env.unwrapped.data).reused_wrenches > 0
        np.testing.assert_array_equal(runs[0], runs[1])
    finally:
        env.close()


@pytest.mark.parametrize("kind", ["capsule", "cylinder", "ellipsoid", "sphere", "box"])
def test_a_ball_said_to_be_outside_a_geom_holds_no_point_inside_it(kind):
    """``_outside_ball`` (the occlusion test's cluster skip, and reuse's test of other bodies' geoms) against
    ``_inside`` on points sampled in the ball: where it says outside, none is inside; it does say outside
    for balls well away."""
    from rft_mujoco.compiled.elements import _inside, _outside_ball
    k = int(getattr(mujoco.mjtGeom, f"mjGEOM_{kind.upper()}"))
    size = np.array([0.03, 0.08, 0.05])
    hs = np.zeros((0, 4))
    rng = np.random.default_rng(0)
    outside = 0
    for _ in range(400):
        c, r = rng.uniform(-0.2, 0.2, 3), rng.uniform(0.005, 0.05)
        if not _outside_ball(c[0], c[1], c[2], r, k, size[0], size[1], size[2], hs, 0, 0, 1e-4):
            continue
        outside += 1
        d = rng.normal(size=(200, 3))
        pts = c + d / np.linalg.norm(d, axis=1)[:, None] * r * rng.uniform(0, 1, (200, 1)) ** (1 / 3)
        assert not any(_inside(p[0], p[1], p[2], k, size[0], size[1], size[2], hs, 0, 0, 1e-4) for p in pts)
    assert outside > 100


CHANGES = {"media": lambda model, handle: setattr(handle, "media", rft_mujoco.get_media("mpm_validation")),
           "gravity": lambda model, handle: model.opt.gravity.__setitem__(2, -12.0),
           "guards": lambda model, handle: setattr(handle, "guards", rft_mujoco.Guards.all())}


@pytest.mark.parametrize("change", sorted(CHANGES))
def test_a_setting_changed_mid_run_is_felt_at_the_next_step_not_hidden_by_a_reused_wrench(change):
    """A box resting in the sand reuses its wrench; a new medium, a stronger gravity or other guards change the
    law, so the next evaluation must be a full one: the same force as a run that never reuses (a new medium
    was missed before: 116 N held where the new one carries 240 N)."""
    xml = ("<mujoco><option timestep='0.002'/><worldbody><body pos='0 0 0.02'><freejoint/>"
           "<geom type='box' size='0.05 0.05 0.05' mass='2'/></body></worldbody></mujoco>")
    runs = _box_with_and_without_reuse(xml, change=CHANGES[change])
    assert runs[1e-3][1] > 100                                # it was reusing before the change
    np.testing.assert_allclose(runs[1e-3][0], runs[0.0][0], rtol=1e-9, atol=1e-12)
