"""State integrity: nothing outside a running simulation changes it silently (docs/architecture.md,
"State and copies").

Copies and saves of MjData and MjModel, other handles attached or detached, callbacks and flags set after
attach, model edits after attach, resets: each either keeps the simulation exactly as it was, or raises.
Tiny inline models; both the default (compiled, native where supported) path and the numpy reference.
"""

import copy
import gc
import os
import pickle
import tempfile
import threading
import time
import weakref

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.coupling.dispatch import DISPATCHER

MEDIA = "li_loose_glass_beads"
BALL = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 .1" pos="0 0 -0.02"/>
    <geom name="rock" type="box" size="0.05 0.05 0.05" pos="1 1 0"/>
    <body name="ball" pos="0 0 0.0"><freejoint/><geom name="ball" type="sphere" size="0.05" mass="1"/></body>
    <body name="arm" pos="-0.3 0 0.05">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 -0.12" size="0.012" mass="0.2"/>
    </body>
    <body name="mocap" mocap="true" pos="0.5 0 0"><geom type="box" size="0.02 0.02 0.02"/></body>
  </worldbody>
  <actuator><position joint="hinge" kp="5"/></actuator>
</mujoco>
"""
BACKENDS = ["auto", "numpy"]



def scene(backend="auto", **kwargs):
    model = mujoco.MjModel.from_xml_string(BALL)
    handle = rft_mujoco.attach(model, MEDIA, ["ball", "arm"], 0.0, 0.01, monitor=False, backend=backend, **kwargs)
    handle.replace_rigid(["floor"])
    return model, mujoco.MjData(model), handle


def run(model, data, steps, start=0):
    for i in range(start, start + steps):
        data.ctrl[:] = np.sin(0.05 * i)
        mujoco.mj_step(model, data)


def z(model, data):
    return float(data.xpos[model.body("ball").id, 2])


# --- copies of MjData ------------------------------------------------------------------------------------
def _mj_copy(model, data):
    out = mujoco.MjData(model)
    mujoco.mj_copyData(out, model, data)
    return out


COPIES = {"mj_copyData": _mj_copy, "copy": lambda m, d: copy.copy(d), "deepcopy": lambda m, d: copy.deepcopy(d),
          "pickle": lambda m, d: pickle.loads(pickle.dumps(d))}


@pytest.mark.parametrize("how", list(COPIES))
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_copy_of_mjdata_lifted_off_the_sand_falls_freely(how, backend):
    model, data, handle = scene(backend)
    run(model, data, 150)                                   # the ball rests: the sand holds its weight
    ball = model.body("ball").id
    assert data.xfrc_applied[ball, 2] > 5.0
    twin = COPIES[how](model, data)
    twin.qpos[2] += 1.0
    mujoco.mj_forward(model, twin)
    z0 = z(model, twin)
    run(model, twin, 100)                                   # 0.2 s of free fall
    assert z(model, twin) == pytest.approx(z0 - 0.5 * 9.81 * 0.2 ** 2, abs=5e-3)
    assert np.all(twin.xfrc_applied == 0.0)
    run(model, data, 10, 150)                               # the original still rests
    assert data.xfrc_applied[ball, 2] > 5.0


@pytest.mark.parametrize("how", list(COPIES))
def test_a_copy_of_mjdata_holds_no_sand_after_detach(how):
    model, data, handle = scene()
    run(model, data, 150)
    twin = COPIES[how](model, data)
    handle.detach()
    for d in (data, twin):
        assert np.all(d.xfrc_applied == 0.0)


@pytest.mark.parametrize("how", ["mj_copyData", "copy"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_copy_for_the_same_model_continues_exactly_as_the_original(how, backend):
    model, data, handle = scene(backend)
    data.qvel[:] = np.random.default_rng(1).normal(size=model.nv) * 0.3
    run(model, data, 60)
    twin = COPIES[how](model, data)
    run(model, data, 60, 60)
    run(model, twin, 60, 60)
    assert np.array_equal(data.qpos, twin.qpos) and np.array_equal(data.qvel, twin.qvel)
    assert np.array_equal(data.xfrc_applied, twin.xfrc_applied)


def test_copying_into_a_data_with_sand_state_replaces_it():
    model, data, handle = scene()
    run(model, data, 150)
    fresh = mujoco.MjData(model)                            # no sand state
    fresh.qpos[2] = 1.0
    mujoco.mj_copyData(data, model, fresh)                  # data now is a fresh data lifted 1 m
    run(model, data, 50)
    assert np.all(data.xfrc_applied[model.body("ball").id] == 0.0)     # the ball falls freely


# --- copies and saves of MjModel ----------------------------------------------------------------------------
def _saved(model):
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "m.mjb")
        mujoco.mj_saveModel(model, path)
        return mujoco.MjModel.from_binary_path(path)


MODEL_COPIES = {"copy": copy.copy, "deepcopy": copy.deepcopy, "pickle": lambda m: pickle.loads(pickle.dumps(m)),
                "mj_saveModel": _saved, "data pickle": lambda m: pickle.loads(pickle.dumps(mujoco.MjData(m))).model}


@pytest.mark.parametrize("how", list(MODEL_COPIES))
def test_copies_and_saves_of_a_model_keep_the_floor_the_sand_replaced(how):
    model, data, handle = scene()
    floor = model.geom("floor").id
    twin = MODEL_COPIES[how](model)
    assert (twin.geom_contype[floor], twin.geom_conaffinity[floor]) == (1, 1)
    assert (model.geom_contype[floor], model.geom_conaffinity[floor]) == (0, 0)   # the original keeps the sand
    handle.detach()
    d = mujoco.MjData(twin)
    d.qpos[2] = 0.2
    mujoco.mj_step(twin, d, nstep=500)                      # the copy's ball lands on its floor
    assert z(twin, d) > -0.05


# --- other handles, settings of other handles --------------------------------------------------------------
def test_attaching_detaching_and_retargeting_other_sand_leaves_a_running_simulation_alone():
    def trajectory(perturb):
        model, data, handle = scene()
        data.qpos[2] = 0.2                                  # nothing touches at the first evaluation
        data.qpos[7] = -1.2
        others = []
        for i in range(0, 300, 20):
            if perturb and i == 100:
                other = mujoco.MjModel.from_xml_string(BALL)
                others.append(rft_mujoco.attach(other, MEDIA, ["ball"], 0.0, 0.02))
            if perturb and i == 140:
                others[0].terrain = rft_mujoco.FlatSurface(0.01)
            if perturb and i == 180:
                others[0].detach()
            if perturb and i == 220:
                others.append(rft_mujoco.attach(mujoco.MjModel.from_xml_string(BALL), MEDIA, ["ball"]))
            run(model, data, 20, i)
        handle.detach()
        for h in others:
            h.detach()
        return data.qpos.copy(), data.qvel.copy()

    q0, v0 = trajectory(False)
    q1, v1 = trajectory(True)
    assert np.array_equal(q0, q1) and np.array_equal(v0, v1)


# --- callbacks and flags set after attach ---------------------------------------------------------------------
def test_a_control_callback_installed_after_attach_is_chained_and_the_sand_stays():
    model, data, handle = scene()
    calls = []
    mujoco.set_mjcb_control(lambda m, d: calls.append(1))
    run(model, data, 150)
    assert calls and z(model, data) > -0.06                 # the callback ran, the ball rests on the sand
    mujoco.set_mjcb_control(None)
    n = len(calls)
    run(model, data, 150, 150)
    assert len(calls) == n and z(model, data) > -0.06
    user = lambda m, d: None                                # noqa: E731
    mujoco.set_mjcb_control(user)
    handle.detach()
    assert mujoco.get_mjcb_control() is user                # the user's latest callback, restored at detach
    mujoco.set_mjcb_control(None)


def test_a_passive_callback_installed_after_attach_is_chained():
    model, data, handle = scene()
    calls = []
    mujoco.set_mjcb_passive(lambda m, d: calls.append(1))
    run(model, data, 150)
    assert calls and z(model, data) > -0.06
    handle.detach()
    mujoco.set_mjcb_passive(None)


def test_flags_that_would_skip_every_sand_callback_are_refused_after_attach():
    model, data, handle = scene()
    bit = mujoco.mjtDisableBit
    model.opt.disableflags |= int(bit.mjDSBL_SPRING) | int(bit.mjDSBL_DAMPER)
    with pytest.raises(ValueError, match="refused while sand is attached"):
        model.opt.disableflags |= int(bit.mjDSBL_ACTUATION)
    assert not model.opt.disableflags & int(bit.mjDSBL_ACTUATION)
    model.opt.disableflags = 0
    model.opt.disableflags |= int(bit.mjDSBL_ACTUATION)    # alone: the passive callback evaluates the sand
    run(model, data, 150)
    assert z(model, data) > -0.06


# --- model edits after attach ---------------------------------------------------------------------------------
EDITS = {
    "zero gravity": lambda m: m.opt.gravity.__setitem__(slice(None), 0.0),
    "NaN gravity": lambda m: m.opt.gravity.__setitem__(2, np.nan),
    "zero timestep": lambda m: setattr(m.opt, "timestep", 0.0),
    "negative timestep": lambda m: setattr(m.opt, "timestep", -0.001),
    "resized ball": lambda m: m.geom_size.__setitem__((m.geom("ball").id, 0), 0.08),
}


@pytest.mark.parametrize("edit", list(EDITS))
@pytest.mark.parametrize("backend", BACKENDS)
def test_model_edits_after_attach_that_the_sand_cannot_follow_raise(edit, backend):
    model, data, handle = scene(backend)
    run(model, data, 100)
    EDITS[edit](model)
    with pytest.raises(ValueError, match="after attach"):
        run(model, data, 2)


BOUNDED = {"region": lambda: rft_mujoco.SandRegion(rft_mujoco.FlatSurface(0.0), (-1.0, 1.0), (-1.0, 1.0)),
           "heightfield": lambda: rft_mujoco.HeightfieldSurface(np.zeros((3, 3)), (-1.0, 1.0), (-1.0, 1.0))}


@pytest.mark.parametrize("terrain", list(BOUNDED))
def test_sideways_gravity_over_a_bounded_sand_region_raises(terrain):
    model = mujoco.MjModel.from_xml_string(BALL)
    handle = rft_mujoco.attach(model, MEDIA, ["ball"], BOUNDED[terrain](), 0.01, monitor=False)
    data = mujoco.MjData(model)
    run(model, data, 50)
    model.opt.gravity[:] = [9.81, 0.0, 0.0]
    with pytest.raises(ValueError, match="after attach"):
        run(model, data, 2)
    handle.detach()


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_new_gravity_or_timestep_is_followed(backend):
    model, data, handle = scene(backend)
    run(model, data, 200)
    model.opt.gravity[2] = -3.71                            # Mars
    model.opt.timestep = 0.001
    run(model, data, 400)
    ball = model.body("ball").id
    assert data.xfrc_applied[ball, 2] == pytest.approx(3.71, rel=0.05)   # the sand holds the new weight


# --- inputs that gave a wrong result or a misleading error -------------------------------------------------------
def test_element_forces_with_huge_direction_vectors_equal_those_of_unit_ones():
    rng = np.random.default_rng(3)
    c = np.column_stack([rng.uniform(-0.1, 0.1, (20, 2)), rng.uniform(-0.05, 0.0, 20)])
    n = rng.normal(size=(20, 3))
    v = rng.normal(size=(20, 3))
    a = np.full(20, 1e-4)
    want = rft_mujoco.element_forces(c, n, a, v, rft_mujoco.LI_LOOSE_GLASS_BEADS)
    assert np.abs(want).max() > 0
    for backend in ("auto", "numpy"):
        got = rft_mujoco.element_forces(c, n * 2.0 ** 700, a, v * 2.0 ** 1000, "li_loose_glass_beads",
                                        backend=backend)               # (exact scalings: the same directions)
        assert np.allclose(got, want, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("bodies", [["mocap"], ["ball", "mocap"]])
def test_static_or_mocap_bodies_named_for_sand_are_refused(bodies):
    model = mujoco.MjModel.from_xml_string(BALL)
    with pytest.raises(ValueError, match="static or mocap"):
        rft_mujoco.attach(model, MEDIA, bodies)


def test_every_body_means_every_movable_body():
    model = mujoco.MjModel.from_xml_string(BALL)
    handle = rft_mujoco.attach(model, MEDIA, None, monitor=False)
    assert handle.body_names == ["ball", "arm"]


@pytest.mark.parametrize("data, match", [('"0 1"', "one number"), ('"0"', None)])
def test_a_scene_surface_height_must_be_one_number(data, match):
    xml = BALL.replace("<worldbody>", f'<custom><text name="rft/media" data="{MEDIA}"/>'
                                      f'<text name="rft/bodies" data="ball"/>'
                                      f'<numeric name="rft/surface_height" data={data}/></custom><worldbody>')
    model = mujoco.MjModel.from_xml_string(xml)
    if match is None:
        assert rft_mujoco.attach_scene(model)[0].terrain.height == 0.0
    else:
        with pytest.raises(ValueError, match=match):
            rft_mujoco.attach_scene(model)


UNCLEAR = {
    "empty bodies": (lambda m: rft_mujoco.attach(m, MEDIA, []), ValueError, "bodies is empty"),
    "float body": (lambda m: rft_mujoco.attach(m, MEDIA, [1.5]), TypeError, r"names \(str\) or ids"),
    "huge surface": (lambda m: rft_mujoco.attach(m, MEDIA, ["ball"], 1e300), ValueError, "surface height"),
    "guards name": (lambda m: rft_mujoco.attach(m, MEDIA, ["ball"], guards="none"), TypeError, "Guards"),
    "diagnostics of a string": (lambda m: rft_mujoco.attach(m, MEDIA, ["ball"]).diagnostics("x"), ValueError,
                                "mujoco.MjData"),
}


@pytest.mark.parametrize("case", list(UNCLEAR))
def test_misuses_get_errors_that_say_what_was_given(case):
    call, kind, match = UNCLEAR[case]
    with pytest.raises(kind, match=match):
        call(mujoco.MjModel.from_xml_string(BALL))


def test_a_terrain_may_be_set_as_a_height_and_a_geom_as_a_name():
    model, data, handle = scene()
    handle.terrain = 0.01
    assert handle.terrain == rft_mujoco.FlatSurface(0.01)
    handle.replace_rigid("rock")
    assert model.geom_contype[model.geom("rock").id] == 0
    handle.detach()
    assert model.geom_contype[model.geom("rock").id] == 1


# --- resets -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_reset_data_steps_as_a_new_one(backend):
    model, data, handle = scene(backend)
    fresh = mujoco.MjData(model)
    data.qvel[:] = 0.4
    run(model, data, 120)
    mujoco.mj_resetData(model, data)
    run(model, data, 120)
    run(model, fresh, 120)
    assert np.array_equal(data.qpos, fresh.qpos) and np.array_equal(data.xfrc_applied, fresh.xfrc_applied)


# --- lifetime: the sand never keeps a model alive -------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_models_with_sand_never_detached_are_freed_when_the_user_drops_them(backend):
    control, passive = mujoco.get_mjcb_control(), mujoco.get_mjcb_passive()
    models = []
    for _ in range(50):                                     # attach to fresh models; never detach
        model, data, handle = scene(backend)
        run(model, data, 5)
        models.append(weakref.ref(model))
        del model, data, handle
    gc.collect()
    assert all(m() is None for m in models)
    assert rft_mujoco.attached_handles() == () and DISPATCHER.handles == ()
    held = DISPATCHER.held()                               # the native callbacks keep no model's address
    assert (held["handles"], held["finalizers"], held["routes"], held["native_models"], held["native_routes"]) \
        == (0, 0, 0, (), ())
    # the last model gone, the dispatcher is out, as after the last detach
    assert mujoco.get_mjcb_control() is control and mujoco.get_mjcb_passive() is passive
    assert not hasattr(mujoco.mj_copyData, "__wrapped__") and DISPATCHER.held()["wrapped"] == 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_sand_whose_handle_is_not_kept_holds_the_ball_while_the_model_lives(backend):
    model = mujoco.MjModel.from_xml_string(BALL)
    rft_mujoco.attach(model, MEDIA, ["ball", "arm"], 0.0, 0.01, monitor=False, backend=backend).replace_rigid("floor")
    data = mujoco.MjData(model)
    gc.collect()
    assert len(rft_mujoco.attached_handles()) == 1
    run(model, data, 300)                                   # 0.6 s: free fall would be 1.8 m
    assert z(model, data) > -0.06 and abs(data.qvel[2]) < 1e-3
    model_ref = weakref.ref(model)
    del model, data
    gc.collect()
    assert model_ref() is None and rft_mujoco.attached_handles() == ()


def test_a_handle_kept_after_its_model_was_collected_says_so():
    model = mujoco.MjModel.from_xml_string(BALL)
    handle = rft_mujoco.attach(model, MEDIA, ["ball"], 0.0, 0.01, monitor=False)
    del model
    gc.collect()
    assert not handle.attached and rft_mujoco.attached_handles() == ()
    assert handle.evaluator.constants is None              # no views of the collected model's memory kept
    with pytest.raises(ReferenceError, match="garbage collected.*Keep a reference to the model"):
        handle.model
    handle.detach()                                         # nothing left to detach
    assert "attached=False" in repr(handle)


def test_models_collected_in_another_thread_leave_a_running_simulation_alone():
    def trajectory(churn):
        model, data, handle = scene()
        data.qvel[:] = 0.3
        go, made = threading.Semaphore(0), []

        def attach_and_drop():                              # sand on fresh models, dropped and collected here
            while go.acquire() and len(made) < 8:
                other = mujoco.MjModel.from_xml_string(BALL)
                d = mujoco.MjData(other)
                rft_mujoco.attach(other, MEDIA, ["ball"], 0.0, 0.02, monitor=False)
                mujoco.mj_step(other, d, nstep=3)
                made.append(weakref.ref(other))
                del other, d
                gc.collect()
        # one model per round, made and collected while that round's 100 steps run (the thread used to spin
        # through models for the whole run: its full collections, each over the whole test process, cost
        # about 30 s of CPU; one per round is what the assertion below reads)
        thread = threading.Thread(target=attach_and_drop)
        if churn:
            thread.start()
        for i in range(8):
            while churn and len(made) < i:
                time.sleep(0.005)
            if churn:
                go.release()
            run(model, data, 100, 100 * i)
        if churn:
            go.release()                                    # (made is full: the thread returns)
            thread.join()
        assert not churn or (len(made) == 8 and all(m() is None for m in made[:-1]))
        return data.qpos.copy(), data.qvel.copy()

    q0, v0 = trajectory(False)
    q1, v1 = trajectory(True)
    assert np.array_equal(q0, q1) and np.array_equal(v0, v1)
    gc.collect()
    assert rft_mujoco.attached_handles() == ()               # the scenes too: their models are gone


def test_a_model_collected_while_sand_is_attached_or_detached_is_unregistered_right_after():
    model = mujoco.MjModel.from_xml_string(BALL)
    rft_mujoco.attach(model, MEDIA, ["ball"], 0.0, 0.01, monitor=False)
    kept = mujoco.MjModel.from_xml_string(BALL)
    handle = rft_mujoco.attach(kept, MEDIA, ["ball"], 0.0, 0.01, monitor=False)
    with DISPATCHER._changing():                            # as if the collection came inside attach or detach
        del model
        gc.collect()
        assert DISPATCHER.held()["handles"] == 2            # waits for the end of that call
    assert DISPATCHER.held()["handles"] == 1 and rft_mujoco.attached_handles() == (handle,)   # unregistered
