"""The native entry point (rft_mujoco.native) against the numba-dispatch path it replaces: the same
compiled functions on the same inputs, so every result must agree bit for bit."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco import fastlimit, law, native
from rft_mujoco.terrain import FlatSurface, HeightfieldSurface

from test_fastkernel import MEDIA, SCENE

pytestmark = pytest.mark.skipif(not rft_mujoco.fastkernel.AVAILABLE, reason="numba is not installed")


def rollout(use_native, integrator="Euler", terrain=0.0, warm_start=False, steps=60, user_wrench=False,
            guards=law.PUBLISHED, datas=1):
    """xfrc_applied and qpos after every step of a sand rollout of SCENE (``datas`` MjData stepped in
    turn), with the native call on or off."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator=integrator))
    ds = [mujoco.MjData(model) for _ in range(datas)]
    for i, d in enumerate(ds):
        d.qvel[:] = np.random.default_rng(i).normal(size=model.nv) * 0.5
    out = []
    with rft_mujoco.attach(model, MEDIA, None, terrain, 0.01, monitor=False, backend="numba", guards=guards,
                           warm_start=warm_start) as handle:
        handle.native = use_native
        for step in range(steps):
            for d in ds:
                if user_wrench:
                    d.xfrc_applied[1, 2] = 3.0 * np.sin(0.1 * step)     # the user's own wrench on the ball
                mujoco.mj_step(model, d)
                out.append(np.concatenate([d.xfrc_applied.ravel(), d.qpos]))
        diag = handle.diagnostics(ds[0])
        last = np.concatenate([diag.force.ravel(), diag.torque.ravel(), diag.scale, diag.max_depth])
    return np.array(out), last


def test_native_is_available():
    assert native.available(), native.error()


@pytest.mark.parametrize("integrator,warm_start", [("Euler", False), ("RK4", False), ("implicitfast", True)])
def test_native_equals_dispatch_bit_for_bit(integrator, warm_start):
    got, got_diag = rollout(True, integrator, warm_start=warm_start)
    ref, ref_diag = rollout(False, integrator, warm_start=warm_start)
    assert np.count_nonzero(ref[:, 6:6 * 5]) > 100        # the sand did act (rows of the world body excluded)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got_diag, ref_diag)


def test_native_with_user_wrenches_heightfield_guards_and_two_datas():
    heights = 0.01 * np.random.default_rng(1).normal(size=(5, 6))
    terrain = HeightfieldSurface(heights, (-0.5, 0.5), (-0.4, 0.6))
    kw = dict(terrain=terrain, user_wrench=True, guards=law.Guards.all(), datas=2, steps=40)
    (got, got_diag), (ref, ref_diag) = rollout(True, **kw), rollout(False, **kw)
    assert np.count_nonzero(ref[:, 6:6 * 5]) > 100
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got_diag, ref_diag)


def test_terrain_replaced_between_steps():
    """The argument table points at the terrain's arrays: replacing the terrain rebuilds it."""
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    runs = []
    for use_native in (True, False):
        data = mujoco.MjData(model)
        with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba") as handle:
            handle.native = use_native
            xs = []
            for step in range(30):
                if step == 15:
                    handle.terrain = FlatSurface(0.02)
                mujoco.mj_step(model, data)
                xs.append(data.xfrc_applied.copy())
            runs.append(np.array(xs))
    assert not np.array_equal(runs[0][14], runs[0][16])
    np.testing.assert_array_equal(runs[0], runs[1])


def test_non_finite_inputs_raise_as_on_the_dispatch_path():
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba") as handle:
        assert handle.native
        mujoco.mj_step(model, data)
        data.qvel[0] = np.nan
        with pytest.raises(FloatingPointError, match="non-finite qpos/qvel"):
            mujoco.mj_forward(model, data)
        mujoco.mj_resetData(model, data)
        data.qfrc_applied[0] = np.inf                       # a bad input makes the free acceleration NaN
        with pytest.raises(FloatingPointError, match="non-finite acceleration without sand.*ball"):
            mujoco.mj_forward(model, data)


def test_decode_and_table_checks():
    for k in (0, 1, 5, 1000):
        for status in (fastlimit.BAD_ACCELERATION, -1, 0, 1):
            if k == 0 and status:
                continue
            code = k * 8 + status + 4
            assert native.decode(code) == (k, status)
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    arrays = {name: np.zeros(2) for name in native.FIELDS}
    native.Table(arrays, model, data, 0, None)
    with pytest.raises(TypeError, match="xpos must be a C-contiguous float64/int64"):
        native.Table({**arrays, "xpos": np.zeros((3, 4))[:, ::2]}, model, data, 0, None)
    with pytest.raises(TypeError, match="float32"):
        native.Table({**arrays, "qvel": np.zeros(2, np.float32)}, model, data, 0, None)
    with pytest.raises(KeyError, match="touch"):
        native.Table({k: v for k, v in arrays.items() if k != "touch"}, model, data, 0, None)


def _rk4_model():
    return mujoco.MjModel.from_xml_string(SCENE.format(integrator="RK4"))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_rk4_first_stage_is_held_through_the_step(backend):
    """rk4_stages="first": one evaluation per RK4 step, at the state the step starts from; the wrench
    stays in xfrc_applied through stages 2-4. "all": four evaluations, the last at stage 4's state."""
    model = _rk4_model()
    for mode, per_step in (("first", 1), ("all", 4)):
        data = mujoco.MjData(model)
        data.qvel[:] = np.random.default_rng(0).normal(size=model.nv) * 0.5
        with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend=backend,
                               rk4_stages=mode) as handle:
            for _ in range(5):
                mujoco.mj_step(model, data)
            changed = 0
            for _ in range(20):
                mujoco.mj_forward(model, data)          # evaluates at the state the next step starts from
                start = data.xfrc_applied.copy()
                n = handle.evaluations
                mujoco.mj_step(model, data)
                assert handle.evaluations - n == per_step
                if mode == "first":
                    np.testing.assert_array_equal(data.xfrc_applied, start)
                else:
                    changed += not np.array_equal(data.xfrc_applied, start)
            assert np.count_nonzero(start[1:]) > 0          # the sand acts
            if mode == "all":
                assert changed == 20


def test_rk4_first_needs_every_handle_and_rk4():
    model = _rk4_model()
    data = mujoco.MjData(model)
    with rft_mujoco.attach(model, MEDIA, ["ball"], 0.0, 0.01, monitor=False, rk4_stages="first") as a, \
            rft_mujoco.attach(model, MEDIA, ["brick"], 0.0, 0.01, monitor=False) as b:
        mujoco.mj_step(model, data)
        assert (a.evaluations, b.evaluations) == (4, 4)       # b evaluates every stage, so a does too
        b.rk4_stages = "first"
        mujoco.mj_step(model, data)
        assert (a.evaluations, b.evaluations) == (5, 5)
    euler = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(euler)
    with rft_mujoco.attach(euler, MEDIA, None, 0.0, 0.01, monitor=False, rk4_stages="first") as h:
        for _ in range(3):
            mujoco.mj_step(euler, data)
        assert h.evaluations == 3
    with pytest.raises(ValueError, match="rk4_stages must be one of"):
        rft_mujoco.attach(euler, MEDIA, None, 0.0, 0.01, rk4_stages="last")


# --- the native route: the whole callback as one native call ---------------------------------------------

def _route_rollout(routes, integrator="Euler", steps=50, events=None, two_handles=False, datas=1, **attach_kw):
    """xfrc_applied and qpos after every step of a sand rollout of SCENE with the dispatcher's native
    routes on or off; ``events`` maps a step to a function of (handles, model, datas) run before it.
    Returns (trajectory, diagnostics of the first MjData, evaluations, Python-path evaluations)."""
    from rft_mujoco._dispatch import DISPATCHER
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator=integrator))
    ds = [mujoco.MjData(model) for _ in range(datas)]
    for i, d in enumerate(ds):
        d.qvel[:] = np.random.default_rng(i).normal(size=model.nv) * 0.5
    kw = {"monitor": False, "backend": "numba", **attach_kw}
    bodies = [["ball", "brick"], ["arm", "hand", "high"]] if two_handles else [None]
    handles = [rft_mujoco.attach(model, MEDIA, b, 0.0, 0.01, **kw) for b in bodies]
    python_calls = [0]
    original = DISPATCHER._evaluate

    def counted(m, d):
        python_calls[0] += 1
        original(m, d)

    DISPATCHER.native_routes, DISPATCHER._evaluate = routes, counted
    out = []
    try:
        for step in range(steps):
            if events and step in events:
                events[step](handles, model, ds)
            for d in ds:
                mujoco.mj_step(model, d)
                out.append(np.concatenate([d.xfrc_applied.ravel(), d.qpos]))
        diag = handles[-1].diagnostics(ds[0])
        last = np.concatenate([diag.force.ravel(), diag.torque.ravel(), diag.scale, diag.max_depth,
                               diag.submerged])
        evaluations = [h.evaluations for h in handles]
    finally:
        DISPATCHER.native_routes = True
        del DISPATCHER._evaluate
        for h in handles:
            if h.attached:
                h.detach()
    return np.array(out), last, evaluations, python_calls[0]


def _user_wrench(step):
    def push(handles, model, ds):
        for d in ds:
            d.xfrc_applied[1, 2] = 3.0 * np.sin(0.1 * step)
            d.xfrc_applied[2, :3] = 0.0 if step % 3 else 1.0
    return push


ROUTE_CASES = {
    "euler": dict(),
    "rk4": dict(integrator="RK4"),
    "rk4 first stage": dict(integrator="RK4", rk4_stages="first"),
    "implicitfast warm start": dict(integrator="implicitfast", warm_start=True),
    "user wrenches, two datas": dict(datas=2, events={s: _user_wrench(s) for s in range(0, 50, 2)}),
    "two handles, guards": dict(two_handles=True, guards=law.Guards.all()),
    "settings changed": dict(two_handles=True, events={
        10: lambda hs, m, ds: setattr(hs[0], "warm_start", True),
        20: lambda hs, m, ds: setattr(hs[1], "terrain", FlatSurface(0.03)),
        25: lambda hs, m, ds: m.opt.gravity.__setitem__(slice(None), (0.0, 0.5, -9.0)),
        30: lambda hs, m, ds: setattr(hs[0], "media", rft_mujoco.get_media("dem_glass_beads")),
        35: lambda hs, m, ds: hs[1].detach(),
        40: lambda hs, m, ds: setattr(m.opt, "timestep", 0.001)}),
    "monitor every 7": dict(monitor=7),
}


class _CountingMonitor(rft_mujoco.monitor.ValidityMonitor):
    def check(self, handle, data, *args) -> None:
        self.times.append(data.time)
        super().check(handle, data, *args)

    def reset(self) -> None:
        super().reset()
        self.times = []


@pytest.mark.parametrize("case", list(ROUTE_CASES))
def test_native_route_equals_the_python_path_bit_for_bit(case):
    runs = []
    for routes in (True, False):
        kw = dict(ROUTE_CASES[case])
        if "monitor" in kw:
            kw["monitor"] = _CountingMonitor(every=kw["monitor"])
        runs.append((_route_rollout(routes, **kw), kw.get("monitor")))
    (got, got_diag, got_n, got_python), got_monitor = runs[0]
    (ref, ref_diag, ref_n, ref_python), ref_monitor = runs[1]
    assert np.count_nonzero(ref[:, 6:6 * 5]) > 100            # the sand did act
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got_diag, ref_diag)
    assert got_n == ref_n
    if got_monitor is not None:
        assert len(ref_monitor.times) == ref_n[0] // 7 and got_monitor.times == ref_monitor.times
        assert got_python <= ref_python / 7 + 3     # Python ran for the monitor checks (and the first call)
    else:
        assert got_python < ref_python / 3          # Python ran to build routes, and after each change


def test_native_route_falls_back_to_python_where_it_must():
    """A user control callback is chained in Python; numpy handles and stabilize=False take no route;
    errors still raise from mj_step with the route in place."""
    from rft_mujoco._dispatch import DISPATCHER
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    data = mujoco.MjData(model)
    seen = []
    mujoco.set_mjcb_control(lambda m, d: seen.append(d.time))
    try:
        with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, backend="numba"):
            for _ in range(5):
                mujoco.mj_step(model, data)
            assert DISPATCHER._native[id(data)].call is not None            # a route was built and used
            assert len(seen) == 5                                       # the user's callback still runs
            data.qvel[0] = np.nan
            with pytest.raises(FloatingPointError, match="non-finite qpos/qvel"):
                mujoco.mj_forward(model, data)         # (mj_step would reset the NaN state first)
    finally:
        mujoco.set_mjcb_control(None)
    for kw in (dict(backend="numpy"), dict(stabilize=False)):
        data = mujoco.MjData(model)
        with rft_mujoco.attach(model, MEDIA, None, 0.0, 0.01, monitor=False, **kw):
            mujoco.mj_step(model, data)
            mujoco.mj_step(model, data)
            assert DISPATCHER._native[id(data)].call is None
