"""The native callbacks (rft_mujoco.compiled.native) against the dispatcher's Python callback.

Rollouts through the native callbacks equal the Python path bit for bit (every integrator, RK4 stages
"all" and "first", the validity monitor, mjDSBL_ACTUATION, several models and datas, the explicit and the
implicit solves); errors still raise
from mj_step naming the bodies; what the native code must not do (call a user's actuator callback, touch a
model being compiled) goes to Python; a MuJoCo it does not know falls back with one message; detach
restores the user's callbacks.
"""

import ctypes
import gc

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco import compiled
from rft_mujoco.coupling.dispatch import DISPATCHER

pytestmark = [pytest.mark.skipif(not compiled.AVAILABLE, reason="numba not importable"),
              pytest.mark.filterwarnings("ignore::rft_mujoco.RFTValidityWarning")]
if compiled.AVAILABLE:
    compiled.ensure_compiled()
    from rft_mujoco.compiled import native, route
    SUPPORTED = native.support()[0]
else:
    SUPPORTED = False
needs_native = pytest.mark.skipif(not SUPPORTED, reason="native callbacks unsupported here")

MEDIA = rft_mujoco.MPM_VALIDATION
SCENE = """
<mujoco>
  <option timestep="0.002" integrator="{integrator}"/>
  <worldbody>
    <body name="ball" pos="0 0 0.0"><freejoint/><geom type="sphere" size="0.05" mass="1"/></body>
    <body name="arm" pos="-0.3 0 0.05">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 -0.12" size="0.012" mass="0.2"/>
      <body name="hand" pos="0.1 0 -0.12"><joint type="hinge" axis="1 0 0"/>
        <geom type="cylinder" size="0.02 0.02" mass="0.1"/></body>
    </body>
  </worldbody>
  <actuator><position joint="hinge" kp="5"/></actuator>
</mujoco>
"""
FRICTION_SCENE = SCENE.replace('axis="0 1 0"/>', 'axis="0 1 0" frictionloss="0.02"/>').replace(
    'axis="1 0 0"/>', 'axis="1 0 0" frictionloss="0.01"/>')
"""Dry friction on both hinges: the route reads MuJoCo's constraint rows through mjData's pointers."""
SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
ROUTED = []
"""Whether each data of the last :func:`rollout` ended on the native route."""


@pytest.fixture(autouse=True)
def _clean():
    yield
    rft_mujoco.detach_all()
    DISPATCHER.native = True


def state(model, data):
    out = np.empty(mujoco.mj_stateSize(model, SPEC))
    mujoco.mj_getState(model, data, out, SPEC)
    return out


def rollout(native, integrator="Euler", steps=150, rk4_stages="all", monitor=True, disable_at=None, datas=1,
            models=1, friction=False, solve="explicit", python_path=False, jacobian_at=None):
    """Final states, xfrc_applied, evaluations and evaluations with dofs locked by their dry friction of
    ``models`` models x ``datas`` datas stepped interleaved. ``python_path``: no route (a no-op observer
    keeps every evaluation on the dispatcher's Python path); ``jacobian_at``: (step, mjtJacobian) an edit of
    ``opt.jacobian`` during the run."""
    DISPATCHER.native = native
    runs = []
    for k in range(models):
        model = mujoco.MjModel.from_xml_string((FRICTION_SCENE if friction else SCENE).format(integrator=integrator))
        handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=monitor, rk4_stages=rk4_stages, solve=solve)
        if python_path:
            handle.observe(lambda data, wrenches, stage: None)
        ds = []
        for j in range(datas):
            data = mujoco.MjData(model)
            data.qvel[:] = np.random.default_rng(10 * k + j).normal(size=model.nv) * 0.5
            ds.append(data)
        runs.append((model, handle, ds))
    assert DISPATCHER.native_installed == ((native and SUPPORTED),) * 2
    for i in range(steps):
        for model, handle, ds in runs:
            if i == disable_at:
                model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
            if jacobian_at is not None and i == jacobian_at[0]:
                model.opt.jacobian = jacobian_at[1]
            for data in ds:
                data.ctrl[:] = np.sin(0.05 * i)
                mujoco.mj_step(model, data)
    out = [(state(m, d), d.xfrc_applied.copy(), h.evaluations, h.counters(d).locked_evaluations) for m, h, ds in runs
           for d in ds]
    assert any(np.abs(x).max() > 0.1 for _, x, _, _ in out)               # the sand acted
    assert solve == "implicit" or all((locked > 0) == friction for *_, locked in out)
    ROUTED[:] = [h.evaluation_path(d) == "native" for _, h, ds in runs for d in ds]
    assert not (python_path and any(ROUTED))
    for _, h, _ in runs:
        h.detach()
    return out


@needs_native
@pytest.mark.parametrize("kwargs", [
    dict(), dict(integrator="RK4"), dict(integrator="RK4", rk4_stages="first"),
    dict(integrator="RK4", rk4_stages="midpoint"), dict(integrator="implicitfast"),
    dict(monitor=False, disable_at=60), dict(datas=2, models=2), dict(friction=True),
    dict(friction=True, integrator="RK4"), dict(solve="implicit", friction=True),
    dict(solve="implicit", integrator="implicitfast")])
def test_native_equals_python_bit_for_bit(kwargs):
    python = rollout(False, **kwargs)
    native_ = rollout(True, **kwargs)
    for (s0, x0, e0, l0), (s1, x1, e1, l1) in zip(python, native_):
        assert np.array_equal(s0, s1) and np.array_equal(x0, x1) and e0 == e1 and l0 == l1


IMPLICIT_CASES = [dict(), dict(integrator="implicitfast"), dict(integrator="RK4"), dict(friction=True),
                  dict(datas=2, models=2), dict(monitor=False, disable_at=60),
                  dict(friction=True, jacobian_at=(70, mujoco.mjtJacobian.mjJAC_SPARSE))]


@needs_native
@pytest.mark.parametrize("kwargs", IMPLICIT_CASES)
def test_the_implicit_solve_on_the_native_route_equals_its_python_path_bit_for_bit(kwargs):
    """``solve="implicit"`` on the native route (compiled.implicit_route) against the dispatcher's Python path
    (coupling.implicit.evaluate_compiled): the same motion, the damping of an implicit integrator, the
    constraint rows read through mjData's pointers, dense and (after an edit of ``opt.jacobian``) sparse."""
    python = rollout(True, solve="implicit", python_path=True, **kwargs)
    native_ = rollout(True, solve="implicit", **kwargs)
    assert ROUTED and all(ROUTED)
    for (s0, x0, e0, _), (s1, x1, e1, _) in zip(python, native_):
        assert np.array_equal(s0, s1) and np.array_equal(x0, x1) and e0 == e1


@needs_native
@pytest.mark.filterwarnings("ignore::rft_mujoco.SandSetupWarning")
def test_the_native_route_reads_a_sparse_jacobian_where_mujoco_chooses_one():
    """``mjJAC_AUTO`` is sparse from 60 dofs on: a 64-link chain dragged through the sand with a joint
    limit hit, on the route and on the Python path (which asks ``mj_isSparse``)."""
    links = "".join(f"<body pos='0.02 0 0'><joint type='hinge' axis='0 0 1' range='-0.2 0.2' limited='true'/>"
                    "<geom type='capsule' fromto='0 0 0 0.02 0 0' size='0.006' mass='0.01'/>" for _ in range(64))
    xml = (f"<mujoco><option timestep='0.002'/><worldbody><body pos='0 0 0.003'><freejoint/>"
           f"<geom type='sphere' size='0.02' mass='0.5'/>{links}{'</body>' * 64}</body></worldbody></mujoco>")
    finals = []
    for python_path in (True, False):
        model = mujoco.MjModel.from_xml_string(xml)
        assert model.nv >= 60 and mujoco.mj_isSparse(model)
        handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, solve="implicit", monitor=False)
        if python_path:
            handle.observe(lambda data, wrenches, stage: None)
        data = mujoco.MjData(model)
        data.qvel[0] = 0.3
        data.qvel[6:] = np.random.default_rng(3).normal(size=model.nv - 6)
        for _ in range(60):
            mujoco.mj_step(model, data)
        assert data.nefc > 0 and handle.diagnostics(data).submerged.sum() > 0
        assert (handle.evaluation_path(data) == "native") != python_path
        finals.append(state(model, data))
        handle.detach()
    assert np.array_equal(*finals)


@needs_native
def test_rollouts_repeat_from_a_reset():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="RK4"))
    data = mujoco.MjData(model)
    rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    finals = []
    for _ in range(2):
        mujoco.mj_resetData(model, data)
        data.qvel[:] = 0.3
        for _ in range(100):
            mujoco.mj_step(model, data)
        finals.append(state(model, data))
    assert np.array_equal(*finals)


@needs_native
def test_errors_raise_from_mj_step_naming_the_bodies():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    for _ in range(5):
        mujoco.mj_step(model, data)
    assert handle.evaluation_path(data) == "native"
    data.qfrc_applied[0] = np.nan
    with pytest.raises(FloatingPointError, match="ball"):
        mujoco.mj_step(model, data)


@needs_native
def test_compiling_while_installed_keeps_the_native_callbacks():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    assert DISPATCHER.native_installed == (True, True)
    other = mujoco.MjModel.from_xml_string(SCENE.format(integrator="RK4"))
    mujoco.MjSpec.from_string(SCENE.format(integrator="Euler")).compile()
    mujoco.mj_step(other, mujoco.MjData(other))                           # a model without sand: untouched
    assert DISPATCHER.native_installed == (True, True)
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)
    assert np.any(data.xfrc_applied != 0)


@needs_native
def test_a_user_callback_keeps_its_slot_python_and_detach_restores_both():
    calls = []
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))

    def control(m, d):
        calls.append(1)
    mujoco.set_mjcb_control(control)
    try:
        handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
        assert DISPATCHER.native_installed == (False, True)
        data = mujoco.MjData(model)
        for _ in range(3):
            mujoco.mj_step(model, data)
        assert len(calls) == 3 and np.any(data.xfrc_applied != 0)
        handle.detach()
        assert mujoco.get_mjcb_control() is control and mujoco.get_mjcb_passive() is None
    finally:
        mujoco.set_mjcb_control(None)


@needs_native
def test_user_actuator_callbacks_run_from_python():
    """With a user mjcb_act_gain installed, mj_fwdActuation could run Python code: the evaluation goes
    through the Python path, where the callback's exceptions raise from mj_step."""
    xml = SCENE.format(integrator="Euler").replace('<position joint="hinge" kp="5"/>',
                                                   '<general joint="hinge" gaintype="user" biastype="none"/>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    for _ in range(3):
        mujoco.mj_step(model, data)
    gains = []

    def gain(m, d, i):
        gains.append(i)
        if len(gains) > 20:
            raise KeyError("user gain")
        return 1.0
    mujoco.set_mjcb_act_gain(gain)
    try:
        with pytest.raises(KeyError, match="user gain"):
            for _ in range(20):
                mujoco.mj_step(model, data)
    finally:
        mujoco.set_mjcb_act_gain(None)
    mujoco.mj_step(model, data)


@needs_native
@needs_native
def test_the_evaluation_path_says_which_path_runs():
    """handle.evaluation_path: "none" before a data's first step, "native" once the route runs it, "python"
    with an observer (the dispatcher's Python callback calls it) and on the numpy backend."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data, other = mujoco.MjData(model), mujoco.MjData(model)
    handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    try:
        assert handle.evaluation_path(data) == "none"
        for _ in range(5):
            mujoco.mj_step(model, data)
        assert handle.evaluation_path(data) == "native" and handle.evaluation_path(other) == "none"
        seen = []
        handle.observe(lambda d, w, stage: seen.append(stage))
        for _ in range(3):
            mujoco.mj_step(model, data)
        assert seen and handle.evaluation_path(data) == "python"
        with pytest.raises(TypeError, match="MjData"):
            handle.evaluation_path(model)
    finally:
        handle.detach()
    numpy_model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    numpy_data = mujoco.MjData(numpy_model)
    slow = rft_mujoco.attach(numpy_model, MEDIA, None, 0.0, 0.01, backend="numpy")
    try:
        for _ in range(3):
            mujoco.mj_step(numpy_model, numpy_data)
        assert slow.evaluation_path(numpy_data) == "python"
    finally:
        slow.detach()


def test_a_collected_data_leaves_the_registry():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
    data = mujoco.MjData(model)
    for _ in range(3):
        mujoco.mj_step(model, data)
    key = (model._address, data._address)
    assert key in DISPATCHER.held()["native_routes"]
    del data
    gc.collect()
    assert key not in DISPATCHER.held()["native_routes"]


_COLLECTED_DURING_REWRITE = """
import gc, mujoco, rft_mujoco
from rft_mujoco.coupling.dispatch import DISPATCHER
from tests.test_native import MEDIA, SCENE
model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
data = mujoco.MjData(model)
for _ in range(3):
    mujoco.mj_step(model, data)
registry = DISPATCHER._registry
key = (model._address, data._address)
assert key in registry.held()[1]
cycle = [data]
cycle.append(cycle)                  # only a collection frees it
del data, cycle
write = registry._write
def write_while_collecting():        # an allocation of the rewrite starts a collection
    gc.collect()
    write()
registry._write = write_while_collecting
registry.models([model])             # the data's finalizer runs inside, in this thread
registry._write = write
assert key not in registry.held()[1], registry.held()
print("dropped")
"""


@needs_native
def test_a_data_collected_while_the_registry_is_rewritten_leaves_it_without_a_deadlock():
    """The data's finalizer runs inside the registry's rewrite (the garbage collector starts where Python
    allocates): its route is dropped when the rewrite ends. With a plain lock this hung: making an env again
    after detaching another one stopped in ``attach``. In a subprocess, so that a hang fails this test only."""
    import os
    import subprocess
    import sys
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        out = subprocess.run([sys.executable, "-c", _COLLECTED_DURING_REWRITE], cwd=root, capture_output=True,
                             text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("the registry deadlocked: a data collected during its rewrite")
    assert out.returncode == 0 and "dropped" in out.stdout, out.stderr[-2000:]


def test_unsupported_mujoco_falls_back_with_one_message(monkeypatch, capsys):
    if compiled.AVAILABLE:
        monkeypatch.setattr(native, "support", lambda: (False, "written for mujoco 9.9.9, found 4.0.0"))
    monkeypatch.setattr(route, "_noticed", [])
    for _ in range(2):
        model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
        handle = rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01)
        assert DISPATCHER.native_installed == (False, False)
        data = mujoco.MjData(model)
        mujoco.mj_step(model, data)
        assert np.any(data.xfrc_applied != 0)
        handle.detach()
    err = capsys.readouterr().err
    if compiled.AVAILABLE:
        assert err.count("native sand callbacks unavailable (written for mujoco 9.9.9") == 1


@needs_native
def test_support_found_the_bindings_library_and_the_struct_offsets():
    ok, info = native.support()
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="RK4"))
    data = mujoco.MjData(model)
    data.time = 0.75
    off = info["offsets"]
    assert ctypes.c_double.from_address(model._address + off["timestep"]).value == model.opt.timestep
    assert ctypes.c_int32.from_address(model._address + off["integrator"]).value == model.opt.integrator
    assert ctypes.c_double.from_address(data._address + off["time"]).value == 0.75
    model = mujoco.MjModel.from_xml_string(FRICTION_SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    layout = route.efc_layout()
    assert data.nefc >= 2 and ctypes.c_int32.from_address(data._address + layout["nefc"]).value == data.nefc
    for name in route.EFC_POINTERS:
        assert ctypes.c_int64.from_address(data._address + layout[name]).value == getattr(data, name).ctypes.data


@needs_native
def test_where_the_constraint_rows_cannot_be_located_the_python_path_gives_the_same_motion(monkeypatch, capsys):
    """No route without mjData's constraint layout: the compiled Python path (which reads the rows through
    the bindings) runs every evaluation, says why once, and steps the very same motion."""
    expected = rollout(True, friction=True)
    monkeypatch.setattr(route, "_layout", "test: constraint rows not located")
    monkeypatch.setattr(route, "_noticed", [])
    got = rollout(True, friction=True)
    for (s0, x0, e0, l0), (s1, x1, e1, l1) in zip(expected, got):
        assert np.array_equal(s0, s1) and np.array_equal(x0, x1) and e0 == e1 and l0 == l1
    assert capsys.readouterr().err.count("test: constraint rows not located") == 1
