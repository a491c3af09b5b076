"""attach() runs the set-up checks (rft_mujoco.coupling.checks) where a user meets them."""

import sys
import warnings

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.coupling.checks import SandSetupWarning

MEDIA = rft_mujoco.LI_LOOSE_GLASS_BEADS
SCENE = """
<mujoco><option timestep="{dt}"/><worldbody>
  <geom name="floor" type="plane" size="1 1 0.1"/>
  <body name="ball" pos="0 0 0.05"><freejoint/><geom type="sphere" size="0.05" mass="1"/></body>
</worldbody></mujoco>
"""


def make(dt=0.002):
    model = mujoco.MjModel.from_xml_string(SCENE.format(dt=dt))
    return model, mujoco.MjData(model)



def setup_warnings(record):
    return [w for w in record if issubclass(w.category, SandSetupWarning)]


def test_attaching_a_body_twice_raises():
    model, _ = make()
    rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    with pytest.raises(ValueError, match=r"\['ball'\] are already attached"):
        rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)


def test_a_long_timestep_warns_at_the_attach_line():
    model, _ = make(dt=0.02)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        line = sys._getframe().f_lineno + 1
        rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    found = setup_warnings(record)
    assert len(found) == 1 and (found[0].filename, found[0].lineno) == (__file__, line)


def test_the_floor_warns_at_the_first_step_unless_replaced():
    model, data = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        line = sys._getframe().f_lineno + 1
        mujoco.mj_step(model, data)
        mujoco.mj_step(model, data)
    found = setup_warnings(record)
    assert len(found) == 1 and "replace_rigid(['floor'])" in str(found[0].message)
    assert (found[0].filename, found[0].lineno) == (__file__, line)
    sand.detach()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    sand.replace_rigid(["floor"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", SandSetupWarning)
        mujoco.mj_step(model, data)


@pytest.mark.parametrize("when", ["before attach", "while stepping"])
def test_the_sand_still_acts_with_actuation_disabled(when):
    """MuJoCo skips mjcb_control under mjDSBL_ACTUATION (a plate then fell 4.9 m in 1 s); the dispatcher's
    passive callback evaluates the sand instead: the ball rests on the sand, carried by it."""
    model, data = make()
    off = int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    if when == "before attach":
        model.opt.disableflags |= off
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    sand.replace_rigid(["floor"])
    for i in range(1500):
        if when == "while stepping" and i == 200:
            model.opt.disableflags |= off
        mujoco.mj_step(model, data)
    d = sand.diagnostics(data)
    assert -0.1 < data.qpos[2] < 0.05 and abs(data.qvel[2]) < 1e-3
    np.testing.assert_allclose(d.force[0, 2], 9.81, rtol=1e-3)


def test_import_rft_mujoco_loads_no_training_or_plotting_stack():
    """The library alone: no gymnasium, torch, matplotlib, stable-baselines3 or warp (issue #20)."""
    import subprocess

    code = ("import sys, rft_mujoco; heavy = {'gymnasium', 'torch', 'matplotlib', 'stable_baselines3', 'warp', "
            "'mujoco_warp'}; print(sorted(heavy & {m.split('.')[0] for m in sys.modules}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
