"""The MuJoCo coupling against the pure law, on tiny inline models."""

import dataclasses

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.geometry import surface
from rft_mujoco.physics import law

MEDIA = rft_mujoco.MPM_VALIDATION

FREE_BODIES = """
<mujoco>
  <option timestep="0.001" integrator="{integrator}"/>
  <worldbody>
    <body name="ball" pos="0 0 0">
      <freejoint/>
      <geom type="sphere" size="0.05" mass="1"/>
    </body>
    <body name="brick" pos="0.3 0 0">
      <freejoint/>
      <geom type="box" size="0.04 0.03 0.02" pos="0.01 0 0" euler="0.2 0.1 0" mass="0.5"/>
      <geom type="capsule" size="0.01 0.03" pos="-0.03 0 0.02" mass="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def make(integrator="Euler"):
    model = mujoco.MjModel.from_xml_string(FREE_BODIES.format(integrator=integrator))
    return model, mujoco.MjData(model)



def random_state(model, data, rng, depth=0.05):
    for j, body in enumerate(("ball", "brick")):
        adr = model.jnt_qposadr[model.body(body).jntadr[0]]
        data.qpos[adr:adr + 3] = [0.3 * j, 0.0, -depth + rng.uniform(-0.02, 0.02)]
        q = rng.normal(size=4)
        data.qpos[adr + 3:adr + 7] = q / np.linalg.norm(q)
    data.qvel[:] = rng.normal(size=model.nv) * 0.3


def expected_wrench(model, data, handle, body_name, size):
    """Sum of the numpy reference's element forces over the body's elements, torque about the COM
    (independent path)."""
    b = model.body(body_name).id
    el = surface.body_elements(model, b, size)
    rot = data.xmat[b].reshape(3, 3)
    pos = data.xpos[b] + el.centroids @ rot.T
    nrm = el.normals @ rot.T
    vel6 = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel6, 0)
    omega, v_com = vel6[:3], vel6[3:]
    vel = v_com + np.cross(omega, pos - data.xipos[b])
    f = law.element_forces(pos, nrm, el.areas, vel, MEDIA, 0.0, model.opt.gravity)
    return f.sum(0), np.cross(pos - data.xipos[b], f).sum(0)


@pytest.mark.parametrize("seed", range(5))
def test_wrench_is_sum_of_element_forces(seed):
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, resolution=0.01, stabilize=False, passive=False)
    rng = np.random.default_rng(seed)
    random_state(model, data, rng)
    mujoco.mj_forward(model, data)
    diag = sand.diagnostics(data)
    for i, name in enumerate(sand.body_names):
        force, torque = expected_wrench(model, data, sand, name, 0.01)
        assert np.linalg.norm(force) > 1.0, "the test state must load the body"
        np.testing.assert_allclose(diag.force[i], force, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(diag.torque[i], torque, rtol=1e-9, atol=1e-9)
        b = model.body(name).id
        np.testing.assert_allclose(data.xfrc_applied[b], np.r_[force, torque], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("ball, brick, per_step", [("all", "all", 4), ("midpoint", "midpoint", 2),
                                                   ("first", "first", 1), ("first", "midpoint", 2),
                                                   ("all", "first", 4)])
def test_rk4_evaluates_the_leading_stages_that_the_handles_ask_for(ball, brick, per_step):
    """With RK4 the sand is evaluated at the first 4, 2 or 1 stages of a step (``rk4_stages`` "all",
    "midpoint", "first"), as many as any handle of the model asks for, and the wrench of the last stage
    evaluated is what the rest of the step applies."""
    model, data = make("RK4")
    handles = [rft_mujoco.attach(model, MEDIA, [name], resolution=0.02, rk4_stages=mode)
               for name, mode in (("ball", ball), ("brick", brick))]
    seen = []
    handles[0].observe(lambda d, wrenches, stage: seen.append((stage, wrenches.copy())))
    data.qpos[2] = data.qpos[9] = -0.03
    data.qvel[:] = 0.2
    mujoco.mj_forward(model, data)
    before = [h.evaluations for h in handles]
    seen.clear()
    mujoco.mj_step(model, data)
    assert [stage for stage, _ in seen] == list(range(1, per_step + 1))
    assert [h.evaluations - n for h, n in zip(handles, before)] == [per_step] * 2
    held = seen[-1][1][0]
    assert np.any(held != 0.0) and not np.array_equal(held, seen[0][1][0]) or per_step == 1
    np.testing.assert_array_equal(data.xfrc_applied[model.body("ball").id], held)
    with pytest.raises(ValueError, match="rk4_stages must be one of"):
        handles[0].rk4_stages = "odd"


def test_body_above_sand_gets_exactly_zero():
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, surface_height=-1.0)
    data.qvel[:] = 1.0
    mujoco.mj_step(model, data)
    assert np.all(data.xfrc_applied == 0.0)
    assert np.all(sand.diagnostics(data).force == 0.0)


@pytest.mark.parametrize("user_action", ["leave", "zero", "assign"])
def test_user_xfrc_is_preserved(user_action):
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02, stabilize=False)
    b = model.body("ball").id
    user = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    data.xfrc_applied[b] = user
    data.qpos[2] = -0.05
    data.qvel[:3] = [0.1, 0.0, -0.2]
    for _ in range(5):
        mujoco.mj_step(model, data)
        if user_action == "zero":
            data.xfrc_applied[b] = 0.0
            user = np.zeros(6)
        elif user_action == "assign":
            user = user + 1.0
            data.xfrc_applied[b] = user
    mujoco.mj_forward(model, data)
    d = sand.diagnostics(data)
    sand_wrench = np.r_[d.force[0], d.torque[0]]
    assert np.linalg.norm(sand_wrench) > 1.0
    np.testing.assert_allclose(data.xfrc_applied[b], user + sand_wrench, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("backend", ["auto", "numpy"])
def test_user_writing_one_component_keeps_the_others(backend):
    """A user who writes only the x force of a row each step (a push): the other five components keep
    user + sand, and the sand is not added again on top of itself (this launched a resting ball before)."""
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02, backend=backend)
    b = model.body("ball").id
    data.qpos[2] = -0.03
    for _ in range(200):
        data.xfrc_applied[b, 0] = 2.0
        mujoco.mj_step(model, data)
    d = sand.diagnostics(data)
    np.testing.assert_allclose(data.xfrc_applied[b], np.r_[2.0 + d.force[0, 0], d.force[0, 1:], d.torque[0]],
                               rtol=1e-12, atol=1e-12)
    assert abs(d.force[0, 2] - 9.81) < 0.05 and abs(data.qvel[2]) < 1e-3, "the ball rests on the sand"


@pytest.mark.parametrize("backend", ["auto", "numpy"])
def test_zeroing_after_the_sand_cancelled_a_push_removes_the_push(backend):
    """At rest the sand cancels a sideways push exactly (that row component reads 0); a user who then zeroes
    xfrc_applied has removed the push, and the sand must stop pushing back."""
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02, backend=backend)
    b = model.body("ball").id
    data.qpos[2] = -0.03
    for _ in range(300):
        data.xfrc_applied[b] = [0.5, 0.0, 0.0, 0.0, 0.002, 0.0]
        mujoco.mj_step(model, data)
    assert sand.diagnostics(data).resting[0]
    for _ in range(3):
        data.xfrc_applied[:] = 0.0
        mujoco.mj_step(model, data)
    d = sand.diagnostics(data)
    assert abs(d.force[0, 0]) < 1e-9 and abs(d.torque[0, 1]) < 1e-9, "no phantom push left"
    np.testing.assert_allclose(data.xfrc_applied[b], np.r_[d.force[0], d.torque[0]], atol=1e-12)


def sinking_ball():
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02, stabilize=False)
    data.qpos[2] = 0.0                                  # the ball's lower half in the sand
    data.qvel[2] = -0.2
    return model, data, sand


def test_diagnostics_is_a_live_view_and_copy_a_snapshot():
    model, data, sand = sinking_ball()
    snapshots = []
    for i in range(5):
        data.qpos[2] = -0.002 * i                       # driven down 2 mm a step
        data.qvel[:] = 0.0
        data.qvel[2] = -0.2
        mujoco.mj_step(model, data)
        if i == 0:
            live = sand.diagnostics(data)
        snapshots.append(sand.diagnostics(data).copy())
    assert sand.diagnostics(data) is live, "one live view per MjData, updated in place"
    forces = [s.force[0, 2] for s in snapshots]
    depths = [s.max_depth[0] for s in snapshots]
    assert len(set(forces)) == len(forces) and len(set(depths)) == len(depths), "each snapshot kept its step"
    assert np.all(np.diff(depths) > 0) and np.all(np.diff(forces) > 0), "deeper every step, more lift"
    for field in dataclasses.fields(live):
        np.testing.assert_array_equal(getattr(live, field.name), getattr(snapshots[-1], field.name))
        assert not any(np.shares_memory(getattr(live, field.name), getattr(s, field.name)) for s in snapshots)


def test_diagnostics_taken_before_the_first_step_is_live():
    model, data, sand = sinking_ball()
    live = sand.diagnostics(data)
    mujoco.mj_step(model, data)
    assert sand.diagnostics(data) is live and live.force[0, 2] > 0.0


def test_detach_restores_plain_model():
    model, data = make()
    plain = mujoco.MjData(model)
    sand = rft_mujoco.attach(model, MEDIA, resolution=0.02)
    for d in (data, plain):
        d.qpos[2] = -0.05
        d.qvel[:3] = [0.2, 0.0, -0.3]
    mujoco.mj_step(model, data)
    assert np.any(data.xfrc_applied != 0)
    sand.detach()
    assert np.all(data.xfrc_applied == 0.0), "detach must take the sand wrench out of xfrc_applied"
    assert mujoco.get_mjcb_control() is None
    mujoco.mj_step(model, plain)
    data2 = mujoco.MjData(model)
    data2.qpos[:] = plain.qpos
    data2.qvel[:] = plain.qvel
    mujoco.mj_step(model, data2)
    mujoco.mj_step(model, plain)
    np.testing.assert_array_equal(plain.qvel, data2.qvel)


def test_two_models_do_not_interfere():
    m1, d1 = make()
    m2, d2 = make()
    s1 = rft_mujoco.attach(m1, MEDIA, bodies=["ball"], resolution=0.02, stabilize=False)
    s2 = rft_mujoco.attach(m2, rft_mujoco.DEM_GLASS_BEADS, bodies=["brick"], surface_height=0.5,
                           resolution=0.02, stabilize=False)
    for d in (d1, d2):
        d.qpos[2] = -0.05
        d.qvel[:] = 0.2
    mujoco.mj_forward(m1, d1)
    mujoco.mj_forward(m2, d2)
    assert np.any(d1.xfrc_applied[m1.body("ball").id] != 0)
    assert np.all(d1.xfrc_applied[m1.body("brick").id] == 0)
    assert np.all(d2.xfrc_applied[m2.body("ball").id] == 0)
    assert np.any(d2.xfrc_applied[m2.body("brick").id] != 0)
    # Each equals its own handle's diagnostics.
    np.testing.assert_array_equal(s1.diagnostics(d1).force[0], d1.xfrc_applied[m1.body("ball").id, :3])
    np.testing.assert_array_equal(s2.diagnostics(d2).force[0], d2.xfrc_applied[m2.body("brick").id, :3])


def test_compiling_a_model_while_attached():
    model, data = make()
    rft_mujoco.attach(model, MEDIA, resolution=0.02)
    other = mujoco.MjModel.from_xml_string(FREE_BODIES.format(integrator="RK4"))
    spec = mujoco.MjSpec.from_string(FREE_BODIES.format(integrator="Euler"))
    spec.compile()
    assert other.nbody == model.nbody
    data.qpos[2] = -0.05
    mujoco.mj_step(model, data)   # the callback is still in place
    assert np.any(data.xfrc_applied != 0)


def test_user_control_callback_is_chained():
    calls = []
    model, data = make()   # compile first: mujoco 4.0 cannot compile under a user's Python callback
    mujoco.set_mjcb_control(lambda m, d: calls.append(1))
    try:
        sand = rft_mujoco.attach(model, MEDIA, resolution=0.02)
        mujoco.mj_step(model, data)
        assert calls
        sand.detach()
        assert mujoco.get_mjcb_control() is not None
    finally:
        mujoco.set_mjcb_control(None)


HFIELD = """
<mujoco>
  <asset><hfield name="h" nrow="3" ncol="3" size="1 1 0.2 0.1"
      elevation="0 0 0  0 1 0  0 0 0"/></asset>
  <worldbody>
    <geom name="terrain" type="hfield" hfield="h" contype="0" conaffinity="0"/>
    <body name="ball" pos="0 0 0.1"><freejoint/><geom type="sphere" size="0.03"/></body>
  </worldbody>
</mujoco>
"""


def test_heightfield_depth():
    model = mujoco.MjModel.from_xml_string(HFIELD)
    hf = rft_mujoco.HeightfieldSurface.from_model(model, "terrain")
    # Centre vertex is at top = 0.2 m; corners at 0; half way between: 0.1 (bilinear).
    g = np.array([0.0, 0.0, -1.0])
    pts = np.array([[0, 0, 0.15], [0.5, 0, 0.0], [1, 1, -0.05], [0.25, 0.25, 0.0]])
    np.testing.assert_allclose(hf.depth(pts, g), [0.05, 0.1, 0.05, 0.2 * 0.75 * 0.75], atol=1e-12)
    data = mujoco.MjData(model)
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], surface_height=hf, stabilize=False)
    data.qpos[2] = 0.19          # 0.01 below the peak of the surface
    data.qvel[2] = -0.1
    mujoco.mj_forward(model, data)
    assert sand.diagnostics(data).force[0, 2] > 0
    data.qpos[:3] = [0.9, 0.9, 0.05]   # above the low corner
    mujoco.mj_forward(model, data)
    assert sand.diagnostics(data).force[0, 2] == 0.0


def test_sand_region_has_no_sand_outside():
    model, data = make()
    region = rft_mujoco.SandRegion(rft_mujoco.FlatSurface(0.0), (-0.1, 0.1), (-1, 1))
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball", "brick"], surface_height=region,
                             stabilize=False)
    data.qpos[2] = -0.05
    data.qpos[9] = -0.05
    data.qvel[:] = -0.1
    mujoco.mj_forward(model, data)
    f = sand.diagnostics(data).force
    assert np.linalg.norm(f[0]) > 0 and np.all(f[1] == 0)


def test_bad_inputs_are_explained():
    model, data = make()
    with pytest.raises(ValueError, match="no body named 'nope'"):
        rft_mujoco.attach(model, MEDIA, bodies=["nope"])
    with pytest.raises(ValueError, match="unknown media preset"):
        rft_mujoco.attach(model, "mud")
    sand = rft_mujoco.attach(model, MEDIA, resolution=0.02)
    data.qpos[2] = -0.05
    data.qvel[0] = np.nan
    with pytest.raises(FloatingPointError, match="ball"):
        mujoco.mj_forward(model, data)
    sand.detach()
