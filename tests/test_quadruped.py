"""The bundled quadruped (models/quadruped.xml) and its scripted trot (rft_mujoco.models.quadruped) on a rigid floor."""

import dataclasses
import importlib.resources

import mujoco
import numpy as np
import pytest

from rft_mujoco.models import quadruped

TOTAL_MASS_KG = 12.0
STAND_HEIGHT_RANGE_M = (0.2, 0.4)
MIN_TRUNK_HEIGHT_M = 0.15
MIN_UPRIGHT = 0.8
"""Lowest allowed z component of the trunk's z axis (cos of tilt; 0.8 is about 37 degrees)."""


def load():
    path = importlib.resources.files("rft_mujoco.models") / "quadruped.xml"
    with importlib.resources.as_file(path) as xml:
        model = mujoco.MjModel.from_xml_path(str(xml))
    return model, mujoco.MjData(model)


def simulate(model, data, controller, duration_s):
    """Step from the ``home`` keyframe; return (trunk xyz per step (n, 3), trunk z-axis z per step (n,))."""
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    trunk = model.body("trunk").id
    xyz, upright = [], []
    for _ in range(int(round(duration_s / model.opt.timestep))):
        data.ctrl[:] = controller(data.time)
        mujoco.mj_step(model, data)
        xyz.append(data.xpos[trunk].copy())
        upright.append(data.xmat[trunk][8])
    return np.array(xyz), np.array(upright)


def test_model_names_and_structure():
    model, _ = load()
    assert model.opt.timestep == 0.002
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert [model.actuator(i).name for i in range(model.nu)] == list(quadruped.ACTUATOR_NAMES)
    for i, name in enumerate(quadruped.ACTUATOR_NAMES):
        assert model.joint(model.actuator_trnid[i, 0]).name == name + "_joint"
        np.testing.assert_allclose(model.actuator_ctrlrange[i], model.jnt_range[model.actuator_trnid[i, 0]])
    trunk = model.body("trunk")
    assert trunk.jntnum == 1 and model.jnt_type[trunk.jntadr[0]] == mujoco.mjtJoint.mjJNT_FREE
    for leg, foot in zip(quadruped.LEGS, quadruped.FOOT_BODIES):
        body = model.body(foot)
        assert body.jntnum == 0, "feet are welded to the calves"
        assert model.body(int(body.parentid[0])).name == f"{leg}_calf"
    assert model.body_mass.sum() == pytest.approx(TOTAL_MASS_KG, rel=0.05)
    assert model.geom("floor").type == mujoco.mjtGeom.mjGEOM_PLANE
    assert model.camera("track").id >= 0
    assert model.key("home").qpos[2] == pytest.approx(0.30)


def test_geometry_from_model_and_kinematics_match_mujoco():
    model, data = load()
    geometry = quadruped.LegGeometry.from_model(model)
    assert geometry == quadruped.LegGeometry(), "the defaults describe the bundled model"
    rng = np.random.default_rng(0)
    lo, hi = model.jnt_range[1:].T
    q = rng.uniform(lo, hi).reshape(4, 3)
    # leg_ik covers feet below the hip (h > 0); FK is checked over the whole joint range, the round
    # trip over the working range of the gaits.
    q_work = rng.uniform([-0.5, -0.5, -2.6], [0.5, 1.4, -1.0], size=(50, 4, 3))
    below = np.cos(q_work[..., 1]) + np.cos(q_work[..., 1] + q_work[..., 2]) > 0.1   # foot below the hip
    q_work = q_work[below.all(axis=1)]
    assert len(q_work) > 20
    data.qpos[7:] = q.ravel()
    mujoco.mj_kinematics(model, data)
    rot = data.body("trunk").xmat.reshape(3, 3)
    for i, leg in enumerate(quadruped.LEGS):
        foot_hip = rot.T @ (data.body(f"{leg}_foot").xpos - data.body(f"{leg}_hip").xpos)
        np.testing.assert_allclose(quadruped.leg_fk(q[i], quadruped.SIDE[i], geometry), foot_hip, atol=1e-12)
    side = quadruped.SIDE
    np.testing.assert_allclose(quadruped.leg_ik(quadruped.leg_fk(q_work, side, geometry), side, geometry), q_work,
                               atol=1e-9)


def test_jacobian_matches_finite_differences():
    q = np.array([[0.3, 0.9, -1.6], [-0.2, 0.4, -2.2], [0.1, 1.5, -1.0], [-0.5, -0.3, -2.6]])
    jac = quadruped.leg_jacobian(q, quadruped.SIDE)
    h = 1e-6
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = h
        fd = (quadruped.leg_fk(q + dq, quadruped.SIDE) - quadruped.leg_fk(q - dq, quadruped.SIDE)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, j], fd, atol=1e-8)


def test_gait_config():
    plain = quadruped.TrotGait(stride_m=0.0, step_height_m=0.0)
    model, _ = load()
    np.testing.assert_allclose(plain.stand(), model.key("home").ctrl, atol=2e-3)
    assert plain.targets(1.23).shape == (12,)
    trot = quadruped.TrotGait(frequency_hz=2.0, stride_m=0.1, duty_factor=0.5)
    assert trot.nominal_speed_mps == pytest.approx(0.4)
    np.testing.assert_array_equal(trot.stance(0.1), [True, False, False, True])
    with pytest.raises(dataclasses.FrozenInstanceError):
        trot.stride_m = 0.2
    with pytest.raises(ValueError, match="frequency_hz"):
        quadruped.TrotGait(frequency_hz=0.0)
    with pytest.raises(ValueError, match="out of reach"):
        quadruped.TrotGait(hip_height_m=0.42, stride_m=0.2)


def test_home_keyframe_stands():
    model, data = load()
    stand = quadruped.TrotGait.from_model(model).stand()
    xyz, upright = simulate(model, data, lambda t: stand, 2.0)
    assert STAND_HEIGHT_RANGE_M[0] < xyz[:, 2].min() and xyz[:, 2].max() < STAND_HEIGHT_RANGE_M[1]
    assert upright.min() > 0.99
    assert np.abs(xyz[-1, :2] - xyz[0, :2]).max() < 0.05


def test_trot_walks_forward_on_rigid_floor():
    model, data = load()
    trot = quadruped.TrotGait.from_model(model, frequency_hz=2.5, stride_m=0.10, step_height_m=0.06)
    xyz, upright = simulate(model, data, trot.targets, 4.0)
    assert xyz[-1, 0] - xyz[0, 0] > 0.1
    assert xyz[:, 2].min() > MIN_TRUNK_HEIGHT_M
    assert upright.min() > MIN_UPRIGHT
    # 1-4 s, after the start ramp: close to the no-slip speed stride * frequency / duty (0.5 m/s).
    speed = (xyz[-1, 0] - xyz[len(xyz) // 4, 0]) / 3.0
    assert 0.5 * trot.nominal_speed_mps < speed < 1.3 * trot.nominal_speed_mps
