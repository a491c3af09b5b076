"""The swimmer at any mass (issue 26, item 1): the implicit solve reaches the quasi-static limit at the animal's
density; the explicit one does not; the density scaling keeps MuJoCo's subtree COM right."""

import math
import warnings

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.studies import anymass, quasistatic, swim


def test_the_bundled_swimmer_is_the_animal_and_scaling_keeps_the_subtree_com_the_mass_weighted_mean():
    animal = swim._model()
    assert anymass.ANIMAL == 1.0 and animal.body_mass[1:].sum() == pytest.approx(0.0219, rel=0.01)   # 22 g
    model = swim._model(swim.DENSITY_SCALE)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    data.qpos[0] = 0.05
    mujoco.mj_forward(model, data)
    mass = model.body_mass[1:]
    com = (mass[:, None] * data.xipos[1:]).sum(axis=0) / mass.sum()
    np.testing.assert_allclose(data.subtree_com[1], com, atol=1e-12)
    np.testing.assert_allclose(mass, animal.body_mass[1:] * swim.DENSITY_SCALE)
    joints = [animal.joint(f"j{i}").dofadr[0] for i in range(1, 7)]
    np.testing.assert_allclose(model.dof_armature[joints], animal.dof_armature[joints] * swim.DENSITY_SCALE)
    np.testing.assert_allclose(model.dof_damping[joints], animal.dof_damping[joints] * swim.DENSITY_SCALE)
    assert model.dof_armature[:3].tolist() == animal.dof_armature[:3].tolist()   # the planar root: none
    with pytest.raises(ValueError, match="density factor"):
        swim.scale_density(animal, 0.0)


@pytest.mark.slow
def test_the_animal_swims_at_the_quasi_static_limit_with_the_implicit_solve():
    """2 Hz and 3 cycles (the law is rate-independent: the limit does not depend on the frequency), 10 mm
    elements for the limit and the runs alike: the implicit solve (compiled; tests/test_compiled_implicit.py holds it to the
    numpy oracle) within 5%, the explicit one far off (the
    test tells the two apart)."""
    amplitude, f, cycles, size = 0.7, 2.0, 3, 0.01
    limit = quasistatic.swimmer_limit(amplitude, f, element_size=size, cycles=cycles)["eta"]
    assert limit > 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        implicit = swim.swim(amplitude, f, density_scale=anymass.ANIMAL, cycles=cycles, resolution=size,
                             solve="implicit", backend="numba")
        explicit = swim.swim(amplitude, f, density_scale=anymass.ANIMAL, cycles=cycles, resolution=size)
    assert implicit["solve"] == "implicit" and explicit["solve"] == "explicit"
    assert abs(implicit["eta"] / limit - 1.0) < anymass.TOLERANCE, (implicit["eta"], limit)
    assert abs(explicit["eta"] / limit - 1.0) > 0.3, (explicit["eta"], limit)
    # the servos lag by kv / kp = 10 ms (7 degrees at 2 Hz): a phase error of 0.126 a, 0.089 a RMS
    lag = 2 * math.sin(math.atan(2 * math.pi * f * swim.SERVO_KV / swim.SERVO_KP) / 2) * amplitude / math.sqrt(2)
    assert implicit["tracking_rms_rad"] < 1.2 * lag, (implicit["tracking_rms_rad"], lag)


@pytest.mark.parametrize("density, solve, warned", [(1.0, "explicit", True), (100.0, "explicit", False),
                                                   (1.0, "implicit", False)])
def test_the_monitor_says_the_animal_is_light_for_the_explicit_solve(density, solve, warned):
    """A user attaching the bundled swimmer (the animal, 22 g) with the default explicit solve is told that its
    answer misses the quasi-static one and to use the implicit solve; not at the swim study's 100x, nor with
    the implicit solve (the serpenoid at 0.5 rad, 1 Hz, dt 2 ms, 10 mm elements, 3 s)."""
    from rft_mujoco.studies.swim import N_JOINTS
    model = swim._model(density)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sand = rft_mujoco.attach(model, "maladen_glass_beads", surface_height=0.0, solve=solve)
        sand.replace_rigid(["floor"])
        joints = np.arange(N_JOINTS)
        for _ in range(1500):
            t = data.time
            data.ctrl[:] = min(1.0, t) * 0.5 * np.sin(2 * math.pi * t - 2 * math.pi * joints / N_JOINTS)
            mujoco.mj_step(model, data)
        checks = sand.monitor.flow_checks
        sand.detach()
    light = [w for w in record if "explicit sand solve stops" in str(w.message)]
    assert len(light) == int(warned) and all(issubclass(w.category, rft_mujoco.SandSetupWarning) for w in light)
    assert (sum(c[0] for c in checks.values()) >= 7 * 100) == (solve == "explicit")   # it counted


def test_the_table_and_worst_error_report_every_solve():
    result = dict(limits={0.5: 0.1}, element_size_m=0.003, frequency_hz=1.0, rows=[
        dict(density_scale=1.0, timestep_s=0.002, amplitude_rad=0.5, solve="explicit", eta=0.25, error=1.5),
        dict(density_scale=1.0, timestep_s=0.002, amplitude_rad=0.5, solve="implicit", eta=0.102, error=0.02)])
    lines = anymass.table(result)
    assert "explicit eta" in lines[0] and "implicit eta" in lines[0]
    assert "150.0%" in lines[2] and "2.0%" in lines[2] and "0.1000" in lines[2]
    assert anymass.worst(result) == {"explicit": 1.5, "implicit": 0.02}
    with pytest.raises(ValueError, match="nothing to measure"):
        anymass.measure(amplitudes=(), timesteps=(), workers=1)


@pytest.mark.parametrize("argv, message", [(["--frequency", "0"], "--frequency must be > 0 Hz, got 0.0"),
                                           (["--amplitudes", "-0.5"], "--amplitudes must be > 0, got [-0.5]"),
                                           (["--workers", "0"], "--workers must be >= 1, got 0")])
def test_the_command_refuses_what_it_cannot_measure(argv, message, capsys):
    with pytest.raises(SystemExit):
        anymass.main(argv)
    assert message in capsys.readouterr().err
