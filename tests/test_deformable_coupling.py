"""A DeformableSurface attached to a model: per-MjData surfaces, resets, copies, the backend it takes."""

import copy
import pickle

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.physics import deform

BOX = """<mujoco><option timestep="0.002"/><worldbody>
<body name="box" pos="{x} 0 0.0201"><freejoint/><geom type="box" size="0.05 0.05 0.02" mass="5"/></body>
</worldbody></mujoco>"""
GRID = dict(size=(0.3, 0.3), cell=0.005)


def scene(x=0.0, terrain=None, backend="auto"):
    model = mujoco.MjModel.from_xml_string(BOX.format(x=x))
    handle = rft_mujoco.attach(model, rft_mujoco.LI_LOOSE_GLASS_BEADS, backend=backend,
                               surface_height=rft_mujoco.DeformableSurface(**GRID) if terrain is None else terrain)
    return model, handle


def run(model, data, steps=150):
    for _ in range(steps):
        mujoco.mj_step(model, data)


def test_footprint_of_a_resting_box_and_its_backend():
    model, handle = scene()
    assert handle.backend == "numba"                   # compiled by default (rft_mujoco.compiled.deform)
    data = mujoco.MjData(model)
    run(model, data)
    assert handle.evaluation_path(data) == "native"   # the grid update runs in the native route's phase 2
    sinkage = 0.02 - data.qpos[2]
    s = handle.surface(data)
    assert s.heights.shape == (61, 61) and s.x.shape == (61,) and s.y.shape == (61,)
    under = (np.abs(s.x)[None, :] <= 0.05 + 1e-9) & (np.abs(s.y)[:, None] <= 0.05 + 1e-9)
    assert sinkage > 0.01
    np.testing.assert_allclose(-s.heights[under], sinkage, atol=0.002)         # the box's outline, s1 deep
    assert np.all(s.heights[~under] >= 0.0)
    assert abs(deform.volume_change(s)) <= 1e-9 * deform.footprint_volume(s)
    # on virgin sand the memory makes the depth the undeformed one: the box rests as on the flat surface
    flat_model, flat = scene(terrain=0.0)
    flat_data = mujoco.MjData(flat_model)
    run(flat_model, flat_data)
    assert abs(flat_data.qpos[2] - data.qpos[2]) < 5e-4
    with pytest.raises(ValueError, match="deformable terrain"):
        flat.surface(flat_data)
    with pytest.raises(ValueError, match="surface_updated.*deformable terrain"):
        flat.surface_updated(flat_data)
    assert 0.0 <= handle.surface_updated(data) <= data.time       # updated in this run, by its clock
    handle.detach()
    flat.detach()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_both_backends_are_taken_when_asked(backend):
    model, handle = scene(backend=backend)
    assert handle.backend == backend
    handle.detach()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_two_datas_deform_independently_and_reset_restores(backend):
    model, handle = scene(x=0.06, backend=backend)
    a, b = mujoco.MjData(model), mujoco.MjData(model)
    b.qpos[0] = -0.06                                  # b's box elsewhere
    run(model, a)
    run(model, b, 50)
    sa, sb = handle.surface(a), handle.surface(b)
    assert sa.heights[30, 42] < -0.01 and sb.heights[30, 42] >= 0.0       # x = +0.06: a's footprint only
    assert sb.heights[30, 18] < -0.01 and sa.heights[30, 18] >= 0.0
    mujoco.mj_resetData(model, a)
    np.testing.assert_array_equal(handle.surface(a).heights, np.zeros((61, 61)))
    np.testing.assert_array_equal(handle.surface(a).preload, np.zeros((61, 61)))
    assert handle.surface(b).cycles.max() >= 1.0                           # loading cycles counted, ...
    np.testing.assert_array_equal(handle.surface(a).cycles, np.zeros((61, 61)))      # ... and reset with the rest
    np.testing.assert_array_equal(handle.surface(a).reach, np.zeros((61, 61)))
    np.testing.assert_array_equal(handle.surface(b).heights, sb.heights)   # b untouched by a's reset
    run(model, a)                                                          # the episode repeats exactly
    np.testing.assert_array_equal(handle.surface(a).heights, sa.heights)
    handle.detach()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("how", ["copy", "mj_copyData"])
def test_copies_for_the_same_model_keep_the_surface(how, backend):
    model, handle = scene(backend=backend)
    data = mujoco.MjData(model)
    run(model, data, 40)                               # still sinking: the surface changes after the copy
    if how == "copy":
        twin = copy.copy(data)
    else:
        twin = mujoco.MjData(model)
        mujoco.mj_copyData(twin, model, data)
    np.testing.assert_array_equal(handle.surface(twin).heights, handle.surface(data).heights)
    run(model, data, 60)
    run(model, twin, 60)
    for name in ("heights", "preload", "cycles", "reach"):
        np.testing.assert_array_equal(getattr(handle.surface(twin), name), getattr(handle.surface(data), name))
    np.testing.assert_array_equal(twin.qpos, data.qpos)
    assert handle.surface(data).heights.min() < -0.01
    handle.detach()


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copies_with_the_model_start_from_the_initial_surface(how):
    model, handle = scene()
    data = mujoco.MjData(model)
    run(model, data, 40)
    twin = copy.deepcopy(data) if how == "deepcopy" else pickle.loads(pickle.dumps(data))
    assert handle.surface(data).heights.min() < -0.005
    np.testing.assert_array_equal(handle.surface(twin).heights, np.zeros((61, 61)))
    handle.detach()


def test_a_new_terrain_starts_every_data_fresh():
    model, handle = scene()
    data = mujoco.MjData(model)
    run(model, data, 40)
    handle.terrain = rft_mujoco.DeformableSurface(height=0.001, **GRID)
    np.testing.assert_array_equal(handle.surface(data).heights, np.full((61, 61), 0.001))
    handle.detach()


def test_env_deformable_option_deforms_and_resets():
    gym = pytest.importorskip("gymnasium")
    import rft_mujoco.envs  # noqa: F401  (registers the tasks)

    env = gym.make("rft_mujoco/SandWheel-v0", drive="slip", deformable=True)
    env.reset(seed=0)
    handle, data = env.unwrapped.sand.handle, env.unwrapped.data
    assert isinstance(handle.terrain, rft_mujoco.DeformableSurface) and handle.backend == "numba"
    for _ in range(30):
        env.step(np.array([0.2], np.float32))
    assert handle.surface(data).heights.min() < -0.01              # the wheel's rut
    env.reset(seed=0)
    np.testing.assert_array_equal(handle.surface(data).heights, np.zeros(handle.terrain.shape))
    env.close()
    with pytest.raises(TypeError, match="deformable must be"):
        gym.make("rft_mujoco/SandWheel-v0", deformable="yes")


def test_attach_scene_declares_a_deformable_surface():
    model = mujoco.MjModel.from_xml_string("""<mujoco><option timestep="0.002"/>
    <custom><text name="rft/media" data="li_loose_glass_beads"/><numeric name="rft/surface_height" data="0.01"/>
    <numeric name="rft/deformable" data="0.3 0.2 0.005 0.05 0"/></custom>
    <worldbody><body name="box" pos="0 0 0.0301"><freejoint/><geom type="box" size="0.05 0.05 0.02" mass="5"/>
    </body></worldbody></mujoco>""")
    (handle,) = rft_mujoco.attach_scene(model)
    grid = handle.terrain
    assert isinstance(grid, rft_mujoco.DeformableSurface)
    assert (grid.height, grid.size, grid.cell, grid.center) == (0.01, (0.3, 0.2), 0.005, (0.05, 0.0))
    data = mujoco.MjData(model)
    run(model, data, 100)
    assert handle.surface(data).heights.min() < 0.0
    handle.detach()
    bad = mujoco.MjModel.from_xml_string("""<mujoco><custom><text name="rft/media" data="li_loose_glass_beads"/>
    <numeric name="rft/deformable" data="0.3 0.2"/></custom><worldbody><body><freejoint/>
    <geom type="sphere" size="0.05"/></body></worldbody></mujoco>""")
    with pytest.raises(ValueError, match="rft/deformable"):
        rft_mujoco.attach_scene(bad)


def test_demo_on_a_deformable_surface_fills_its_heightfield():
    """demo/view --deformable: the scene gets a visual heightfield (no collisions) whose data follow the surface."""
    from rft_mujoco.studies import surface_view as prints
    from rft_mujoco.studies.demo import Demo

    demo = Demo(stand_s=0.5, deformable=True)
    assert demo.sand.backend == "numba" and isinstance(demo.sand.terrain, rft_mujoco.DeformableSurface)
    geom = demo.model.geom(prints.HFIELD)
    assert geom.contype[0] == 0 and geom.conaffinity[0] == 0
    for _ in range(40):
        demo.step()
    hid = demo.surface_hfield()
    adr, n = demo.model.hfield_adr[hid], demo.model.hfield_nrow[hid] * demo.model.hfield_ncol[hid]
    drawn = demo.model.hfield_data[adr:adr + n]
    heights = demo.sand.surface(demo.data).heights.ravel()
    span = prints.SPAN
    np.testing.assert_allclose(drawn, np.clip((heights - (demo.grid.height - span)) / (2 * span), 0, 1), atol=1e-6)
    assert drawn.min() < 0.5                                   # the feet's prints are drawn
    demo.close()
