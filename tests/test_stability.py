"""Stability at the extremes: drops come to rest, the sand never adds energy, flow keeps the
published force, bad input is explained, and the validity monitor warns once."""

import dataclasses
import math
import sys
import warnings

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.studies import stability
from rft_mujoco.studies.stability import Case

from conftest import buried_free_body

MEDIA = rft_mujoco.MPM_VALIDATION



# --- the drop matrix, a representative subset ----------------------------------------------------------
DROPS = [Case("drop", shape, mass, dt, integ)
         for shape in stability.SHAPES
         for mass in (0.01, 100.0)
         for dt, integ in ((0.001, "Euler"), (0.005, "implicitfast"), (0.005, "RK4"))]
DROPS += [Case("drop", "capsule", 1.0, 0.00025, "RK4", height=0.3),
          Case("drop", "box", 10.0, 0.002, "Euler", height=0.0, media="maladen_glass_beads"),
          Case("drop", "sphere", 0.1, 0.002, "implicitfast", media="dem_glass_beads")]


@pytest.mark.parametrize("case", DROPS, ids=lambda c: c.label.replace(" ", ""))
def test_drop_comes_to_rest_without_energy_gain(case):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rft_mujoco.RFTValidityWarning)
        res = stability.run_case(case)
    assert not res.nan
    assert res.max_gain_rel <= stability.GAIN_RTOL, f"the sand added {res.max_gain} J in a step"
    assert res.t_rest <= stability.REST_DEADLINE, f"still moving at {res.jitter} m/s"
    assert res.jitter < 1e-6 and res.creep < 1e-6          # real rest, not slow chatter
    assert res.sinkage_ratio >= 0.9, "the sand held the body above its static depth"
    assert res.failures == ()


def test_naive_coupling_chatters_where_the_stabilized_one_rests():
    case = Case("drop", "capsule", 1.0, 0.002, "RK4")
    naive = stability.run_case(dataclasses.replace(case, stabilize=False))
    stab = stability.run_case(case)
    assert naive.jitter > 1e-3 and naive.t_rest == math.inf
    assert stab.jitter < 1e-9


def test_static_depth_bisection():
    # A 5 cm sphere at the static depth carries its weight with straight-down RFT.
    depth = stability.static_depth("sphere", 1.0, "mpm_validation")
    assert 0.0 < depth < 0.05
    heavier = stability.static_depth("sphere", 10.0, "mpm_validation")
    assert heavier > depth


# --- flow: the published force once the speed is well above the regularization speed -------------------
FREE = "<mujoco><option timestep='{dt}'/><worldbody><body name='b'><freejoint/><geom type='{geom}' " \
       "size='{size}' mass='{mass}'/></body></worldbody></mujoco>"


def make_free(geom="sphere", size="0.05", mass=1.0, dt=0.001):
    model = mujoco.MjModel.from_xml_string(FREE.format(dt=dt, geom=geom, size=size, mass=mass))
    return model, mujoco.MjData(model)


@pytest.mark.parametrize("geom,size", [("sphere", "0.05"), ("box", "0.05 0.04 0.03"),
                                       ("capsule", "0.02 0.03")])
@pytest.mark.parametrize("mass,dt", [(1.0, 0.001), (100.0, 0.001), (1.0, 0.01)])
def test_flow_recovers_published_force_within_one_percent(geom, size, mass, dt):
    model, data = make_free(geom, size, mass, dt)
    sand = rft_mujoco.attach(model, MEDIA, monitor=False)
    for u in buried_free_body(data):
        # Regularization speed: the larger of |a_free| dt and |F_rft| dt / m.
        data.qvel[:] = 0.0
        data.qvel[:3] = u
        mujoco.mj_forward(model, data)
        pub, _ = stability.published_wrench(sand, data)
        v_reg = max(np.linalg.norm(model.opt.gravity), np.linalg.norm(pub[:3]) / mass) * dt
        for ratio in (10.0, 100.0):
            data.qvel[:3] = ratio * v_reg * u
            mujoco.mj_forward(model, data)
            diag = sand.diagnostics(data)
            pub, _ = stability.published_wrench(sand, data)
            assert np.linalg.norm(pub[:3]) > 0.1
            err = np.linalg.norm(diag.force[0] - pub[:3]) / np.linalg.norm(pub[:3])
            assert err < 0.01, f"v = {ratio} v_reg along {u}: force off by {err:.2%}"
            assert np.linalg.norm(diag.torque[0] - pub[3:]) <= 0.01 * np.linalg.norm(pub[:3]) * 0.05 + 1e-12


# --- passivity -----------------------------------------------------------------------------------------
def sand_energy_gain(model, data, sand):
    """dE = J.v+ - 0.5 J M^-1 J of the last Euler step (J the sand's generalized impulse)."""
    diag = sand.diagnostics(data)
    q = np.zeros(model.nv)
    mujoco.mj_applyFT(model, data, diag.force[0].copy(), diag.torque[0].copy(), data.xipos[1].copy(), 1, q)
    j = model.opt.timestep * q
    minv_j = np.zeros(model.nv)
    mujoco.mj_solveM(model, data, minv_j.reshape(1, -1), j.reshape(1, -1))
    power, quad = float(j @ data.qvel), 0.5 * float(j @ minv_j)
    return power - quad, abs(power) + quad


@pytest.mark.parametrize("stabilize", [True, False])
def test_passivity_sand_never_adds_energy_in_a_step(stabilize):
    gains = []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        mass = 10.0 ** rng.uniform(-2, 2)
        model, data = make_free("box", "0.05 0.04 0.03", mass, 10.0 ** rng.uniform(-3.5, -2))
        sand = rft_mujoco.attach(model, MEDIA, stabilize=stabilize, passive=False, monitor=False)
        data.qpos[2] = -rng.uniform(0.0, 0.08)
        q = rng.normal(size=4)
        data.qpos[3:7] = q / np.linalg.norm(q)
        data.qvel[:] = rng.normal(size=6) * 10.0 ** rng.uniform(-4, 0)
        mujoco.mj_step(model, data)
        gain, scale = sand_energy_gain(model, data, sand)
        gains.append(gain / scale if scale > 0 else 0.0)
        sand.detach()
    if stabilize:
        assert max(gains) <= stability.GAIN_RTOL
    else:
        assert max(gains) > 1e-3, "the naive coupling should gain energy somewhere in this sample"


def test_passivity_effect_on_drag_accuracy():
    """Dragged fast (flow), the stabilized force is the published one; below capacity, the body is held."""
    # A pull of three times the weight: above what the sand holds (at 1x weight it now rests, see
    # rest.rest_wrenches: its capacity is the resistance along the impending motion).
    fast = stability.run_case(Case("drag", "capsule", 0.1, 0.002, "implicitfast", load=3.0, group="drag"))
    assert fast.force_err_flow < 1e-3 and fast.max_gain_rel <= stability.GAIN_RTOL and not fast.nan
    held = stability.run_case(Case("drag", "sphere", 10.0, 0.002, "implicitfast", load=0.1, group="drag"))
    assert held.held and held.jitter < 1e-9       # a pull below the sand's capacity is held at rest


# --- bad input never reaches MuJoCo as NaN -------------------------------------------------------------
def test_non_finite_state_and_inputs_name_the_body():
    model, data = make_free()
    rft_mujoco.attach(model, MEDIA, monitor=False)
    data.qpos[2] = -0.03
    data.qvel[0] = np.nan
    with pytest.raises(FloatingPointError, match="'b'"):
        mujoco.mj_forward(model, data)
    data.qvel[:] = 0.0
    data.xfrc_applied[1, 0] = np.inf
    with pytest.raises(FloatingPointError, match="xfrc_applied"):
        mujoco.mj_forward(model, data)
    assert np.all(np.isfinite(data.qacc[np.isfinite(data.qacc)]))


def test_massless_bodies():
    static = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body name='plate'><geom size='.1' mass='0'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="static or mocap"):   # a body without a joint: nothing to move
        rft_mujoco.attach(static, MEDIA)
    with pytest.raises(ValueError, match=r"\['plate'\] are static"):
        rft_mujoco.attach(static, MEDIA, bodies=["plate"])
    # A massless body welded to a massive one is fine: the sand acts on the weld group.
    welded = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body name='leg'><freejoint/><geom size='.05' mass='1'/>"
        "<body name='foot' pos='0 0 -0.06'><geom size='.02' mass='0'/></body></body></worldbody></mujoco>")
    sand = rft_mujoco.attach(welded, MEDIA, bodies=["foot"], monitor=False)
    data = mujoco.MjData(welded)
    data.qpos[2] = -0.01
    data.qvel[2] = -0.1
    mujoco.mj_step(welded, data)
    assert sand.diagnostics(data).force[0, 2] > 0.0 and np.all(np.isfinite(data.qacc))


def test_zero_area_elements_name_the_body():
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body name='speck'><freejoint/><inertial pos='0 0 0' mass='1' "
        "diaginertia='1 1 1'/><geom type='sphere' size='1e-200' mass='0'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="body 'speck'.*area"):
        rft_mujoco.attach(model, MEDIA)


@pytest.mark.parametrize("resolution,match", [(1e-6, "surface elements"), (-0.01, "positive"),
                                              (float("nan"), "positive"), ("superfine", "unknown resolution")])
def test_absurd_resolution(resolution, match):
    model, _ = make_free()
    with pytest.raises(ValueError, match=match):
        rft_mujoco.attach(model, MEDIA, resolution=resolution)


@pytest.mark.parametrize("kwargs", [dict(rho_c=-1.0, mu_int=0.4), dict(rho_c=1500.0, mu_int=float("nan")),
                                    dict(rho_c=1e9, mu_int=0.4), dict(rho_c=1500.0, mu_int=0.4, mu_surf=2.0)])
def test_absurd_media(kwargs):
    with pytest.raises(ValueError, match="must be"):
        rft_mujoco.Media(**kwargs)


# --- the validity monitor ------------------------------------------------------------------------------
def test_validity_numbers():
    media = rft_mujoco.DEM_GLASS_BEADS
    i_mac, i_micro, ratio = rft_mujoco.coupling.monitor.validity_numbers([0.1], [0.05], [0.02], media)
    xi = media.xi_n_at(9.81)
    assert i_mac[0] == pytest.approx(0.1 * math.sqrt(2500.0 / (xi * 0.05)))
    assert i_micro[0] == pytest.approx(0.1 / 0.05 * 3e-3 * math.sqrt(2500.0 / (xi * 0.02)))
    shallow = rft_mujoco.coupling.monitor.validity_numbers([0.1], [0.05], [1e-4], media)[1]
    assert shallow[0] == pytest.approx(0.1 / 0.05 * 3e-3 * math.sqrt(2500.0 / (xi * 3e-3)))  # one grain deep
    assert ratio[0] == pytest.approx(0.4)
    _, no_d, _ = rft_mujoco.coupling.monitor.validity_numbers([0.1], [0.05], [0.02], MEDIA)
    assert math.isnan(no_d[0])


def test_monitor_warns_once_with_the_numbers():
    model, data = make_free(mass=1.0)
    sand = rft_mujoco.attach(model, rft_mujoco.DEM_GLASS_BEADS, monitor=rft_mujoco.ValidityMonitor(every=1))
    data.qpos[2] = 0.06
    data.qvel[2] = -3.0                                  # hits the sand fast: I_mac ~ 0.4
    with pytest.warns(rft_mujoco.RFTValidityWarning, match=r"I_mac = [0-9.]+ \(limit 0.15") as record:
        for _ in range(300):
            mujoco.mj_step(model, data)
    assert sum(issubclass(w.category, rft_mujoco.RFTValidityWarning) for w in record) == 1
    assert sand.monitor.worst["i_mac"][0] > 0.15 and sand.monitor.worst["i_mac"][1] == "b"


def test_monitor_warns_once_of_bodies_the_explicit_solve_often_stops():
    """Diagnostics.scale below LIGHT_SCALE at more than LIGHT_SHARE of a body's checks in flow, once it has
    LIGHT_SAMPLES of them: one SandSetupWarning naming it, with its share; a body stopped less often is not named."""
    from rft_mujoco.coupling import monitor as m
    mon = rft_mujoco.ValidityMonitor()
    n = m.LIGHT_SAMPLES
    light = np.where(np.arange(n) % 2 == 0, 0.2, 1.0)                  # stopped at half of its checks
    heavy = np.where(np.arange(n) % 5 == 0, 0.2, 1.0)                  # at a fifth
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for k in range(n - 1):
            mon.observe_flow(["tail", "trunk"], [light[k], heavy[k]], 0.002)
        assert not record                                               # too few checks yet
        for k in range(n - 1, 2 * n):
            mon.observe_flow(["tail", "trunk"], [light[k % n], heavy[k % n]], 0.002)
    assert len(record) == 1 and issubclass(record[0].category, rft_mujoco.SandSetupWarning)
    text = str(record[0].message)
    assert "'tail' (50% of 50)" in text and "trunk" not in text and "solve='implicit'" in text
    assert mon.flow_checks["trunk"] == [2 * n, 2 * n // 5] and "light" in mon.warned


def validity_warnings(record):
    return [w for w in record if issubclass(w.category, rft_mujoco.RFTValidityWarning)]


@pytest.mark.parametrize("call", ["mj_step", "mj_forward"])
def test_validity_warning_names_the_line_that_stepped(call):
    """The warning is raised inside mjcb_control, which MuJoCo calls from mj_step: it must point here."""
    model, data = make_free(mass=1.0)
    rft_mujoco.attach(model, rft_mujoco.DEM_GLASS_BEADS, monitor=rft_mujoco.ValidityMonitor(every=1))
    data.qpos[2] = -0.02
    data.qvel[2] = -3.0
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always", rft_mujoco.RFTValidityWarning)
        line = sys._getframe().f_lineno + 1
        getattr(mujoco, call)(model, data)
    found = validity_warnings(record)
    assert len(found) == 1 and "I_mac" in str(found[0].message)
    assert (found[0].filename, found[0].lineno) == (__file__, line)


def test_validity_warning_skips_the_library_frames_between_the_user_and_mj_forward():
    """kinematic_rollout calls mj_forward inside the library: the warning names the rollout's caller."""
    from rft_mujoco.coupling.rollout import kinematic_rollout

    model, data = make_free(mass=1.0)
    sand = rft_mujoco.attach(model, rft_mujoco.DEM_GLASS_BEADS, stabilize=False,
                             monitor=rft_mujoco.ValidityMonitor(every=1))
    data.qpos[2] = -0.02
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always", rft_mujoco.RFTValidityWarning)
        line = sys._getframe().f_lineno + 1
        kinematic_rollout(sand, data, "b", (3.0, 0.0, 0.0), duration=0.002)
    found = validity_warnings(record)
    assert len(found) == 1 and (found[0].filename, found[0].lineno) == (__file__, line)


DEEP = "<mujoco><option timestep='0.002'/><worldbody><body name='b' pos='0 0 -0.5'><freejoint/>" \
       "<geom type='sphere' size='0.01' mass='0.05'/></body></worldbody></mujoco>"
"""A 2 cm ball 0.5 m deep: about 17 body sizes (beyond the validated 10)."""


@pytest.mark.parametrize("stabilize, vz, sinking", [(False, -0.05, True), (True, 0.0, False),
                                                      (False, 0.05, False)],
                         ids=["moving-down-in-flow", "held-at-rest", "moving-up"])
def test_depth_warning_says_sinking_only_when_the_body_sinks(stabilize, vz, sinking):
    model = mujoco.MjModel.from_xml_string(DEEP)
    data = mujoco.MjData(model)
    sand = rft_mujoco.attach(model, MEDIA, resolution=0.005, stabilize=stabilize,
                             monitor=rft_mujoco.ValidityMonitor(every=1))
    data.qvel[2] = vz
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always", rft_mujoco.RFTValidityWarning)
        mujoco.mj_forward(model, data)
    found = [w for w in validity_warnings(record) if "body sizes" in str(w.message)]
    assert len(found) == 1
    text = str(found[0].message)
    assert sand.diagnostics(data).resting[0] == (stabilize and vz == 0.0)
    assert ("is sinking through the bed" in text) == sinking
    assert ("deeper than validated" in text) == (not sinking)
    assert "probably" not in text or sinking


def test_monitor_depth_warning_and_switch_off():
    model, data = make_free("capsule", "0.01 0.01", mass=100.0, dt=0.002)
    rft_mujoco.attach(model, MEDIA, monitor=rft_mujoco.ValidityMonitor(every=5))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", rft_mujoco.RFTValidityWarning)
        for _ in range(1000):
            mujoco.mj_step(model, data)
    depth = [w for w in caught if "body sizes" in str(w.message)]
    assert len(depth) == 1 and issubclass(depth[0].category, rft_mujoco.RFTValidityWarning)
    rft_mujoco.detach_all()
    model, data = make_free(mass=1.0)
    rft_mujoco.attach(model, MEDIA, monitor=False)
    data.qpos[2] = 0.06
    data.qvel[2] = -3.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", rft_mujoco.RFTValidityWarning)
        for _ in range(100):
            mujoco.mj_step(model, data)


def test_stability_plots_are_written(tmp_path):
    from rft_mujoco.studies import stability_plots

    results = [stability.run_case(Case("drop", "sphere", m, 0.002, "implicitfast", stabilize=s))
               for m in (0.1, 1.0) for s in (True, False)]
    for fn, name in ((stability_plots.plot, "map.png"), (stability_plots.plot_naive, "naive.png")):
        fn(results, tmp_path / name)
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
