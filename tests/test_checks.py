"""Set-up checks (rft_mujoco.coupling.checks) and the MuJoCo facts they rest on, on tiny inline models."""

import warnings

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.coupling import checks
from rft_mujoco.coupling.dispatch import DISPATCHER

MEDIA = rft_mujoco.LI_LOOSE_GLASS_BEADS

SCENE = """
<mujoco>
  <option timestep="{dt}">{flags}</option>
  <asset><hfield name="h" nrow="3" ncol="3" size="1 1 0.1 0.1" elevation="0 0 0  0 1 0  0 0 0"/></asset>
  <worldbody>
    {floor}
    <body name="ball" pos="0 0 0.04"><freejoint/><geom name="ball" type="sphere" size="0.05" mass="1" {ball}/></body>
    <body name="brick" pos="0.5 0 0.02"><freejoint/><geom type="box" size="0.03 0.03 0.03" mass="0.5"/></body>
  </worldbody>
  {extra}
</mujoco>
"""
FLOOR = '<geom name="floor" type="plane" size="2 2 0.1" pos="0 0 {z}" {attrs}/>'


def make(floor=FLOOR.format(z=0.0, attrs=""), ball="", extra="", dt=0.002, flags=""):
    model = mujoco.MjModel.from_xml_string(SCENE.format(floor=floor, ball=ball, extra=extra, dt=dt, flags=flags))
    return model, mujoco.MjData(model)



def setup_warnings(record):
    return [w for w in record if issubclass(w.category, checks.SandSetupWarning)]


# --- a. one body, one sand -----------------------------------------------------------------------------
def test_a_body_attached_twice_is_refused_naming_the_handle():
    model, _ = make()
    first = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    ids = [model.body("ball").id, model.body("brick").id]
    with pytest.raises(ValueError) as info:
        checks.check_not_attached(model, ids, DISPATCHER.handles)
    text = str(info.value)
    assert "['ball']" in text and repr(first) in text and "detach" in text and "bodies=" in text
    checks.check_not_attached(model, [model.body("brick").id], DISPATCHER.handles)   # other bodies: fine
    other, _ = make()
    checks.check_not_attached(other, ids, DISPATCHER.handles)                          # other model: fine
    first.detach()
    checks.check_not_attached(model, ids, DISPATCHER.handles)                          # detached: fine


def test_disjoint_regions_may_share_a_body_overlapping_ones_may_not():
    model, _ = make()
    flat = rft_mujoco.FlatSurface(0.0)
    beach = rft_mujoco.SandRegion(flat, (-1.0, 0.0), (-1.0, 1.0))
    rft_mujoco.attach(model, MEDIA, bodies=["ball"], surface_height=beach, resolution=0.02)
    ball = [model.body("ball").id]
    mud = rft_mujoco.SandRegion(flat, (0.0, 1.0), (-1.0, 1.0))      # touching edge, no shared area
    checks.check_not_attached(model, ball, DISPATCHER.handles, terrain=mud)
    for terrain in (rft_mujoco.SandRegion(flat, (-0.5, 1.0), (-1.0, 1.0)), flat, None):
        with pytest.raises(ValueError, match="already attached"):
            checks.check_not_attached(model, ball, DISPATCHER.handles, terrain=terrain)


# --- b. rigid floors: MuJoCo's collision filter, then the check ---------------------------------------
COLLISION_CASES = {
    "default": dict(),
    "floor off": dict(floor=FLOOR.format(z=0.0, attrs='contype="0" conaffinity="0"')),
    "bits do not meet": dict(floor=FLOOR.format(z=0.0, attrs='contype="2" conaffinity="2"')),
    "one way is enough": dict(floor=FLOOR.format(z=0.0, attrs='contype="2" conaffinity="1"'),
                              ball='contype="1" conaffinity="0"'),
    "excluded": dict(extra='<contact><exclude body1="world" body2="ball"/></contact>'),
    "explicit pair": dict(floor=FLOOR.format(z=0.0, attrs='contype="0" conaffinity="0"'),
                          extra='<contact><pair geom1="floor" geom2="ball"/></contact>'),
    "contacts disabled": dict(flags='<flag contact="disable"/>'),
}


@pytest.mark.parametrize("case", sorted(COLLISION_CASES))
def test_can_collide_agrees_with_mujoco(case):
    model, data = make(**COLLISION_CASES[case])
    mujoco.mj_forward(model, data)          # the ball (r 5 cm) is 1 cm into the floor
    floor, ball = model.geom("floor").id, model.geom("ball").id
    touching = any({int(c.geom1), int(c.geom2)} == {floor, ball} for c in data.contact[:data.ncon])
    assert checks.can_collide(model, floor, ball) == touching


def test_a_body_welded_to_the_world_never_collides_with_the_floor():
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="floor" type="plane" size="1 1 0.1"/>'
        '<body name="post"><geom name="post" type="box" size="0.1 0.1 0.1"/></body></worldbody></mujoco>')
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon == 0 and not checks.can_collide(model, model.geom("floor").id, model.geom("post").id)


def floor_warnings(model, bodies=("ball",), terrain=rft_mujoco.FlatSurface(0.0)):
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        names = checks.check_rigid_floor(model, [model.body(b).id for b in bodies], terrain)
    return names, setup_warnings(record)


@pytest.mark.parametrize("z, warned", [(0.0, True), (0.05, True), (-1e-12, True), (-0.1, False)])
def test_a_floor_at_or_above_the_sand_warns_a_rigid_bottom_does_not(z, warned):
    model, _ = make(floor=FLOOR.format(z=z, attrs=""))
    names, found = floor_warnings(model)
    assert (names == ["floor"]) == warned and len(found) == int(warned)
    if warned:
        text = str(found[0].message)
        assert "'floor'" in text and "handle.replace_rigid(['floor'])" in text and "rigid bottom" in text
        assert found[0].filename == __file__, "the warning names the caller's line"


def test_the_lowest_point_of_a_heightfield_surface_decides():
    model, _ = make(floor=FLOOR.format(z=0.02, attrs=""))
    hills = rft_mujoco.HeightfieldSurface(np.array([[0.05, 0.3], [0.1, 0.2]]), (-1, 1), (-1, 1))
    assert floor_warnings(model, terrain=hills)[0] == []          # 2 cm < lowest sand 5 cm: a bottom
    valley = rft_mujoco.HeightfieldSurface(np.array([[0.0, 0.3], [0.1, 0.2]]), (-1, 1), (-1, 1))
    assert floor_warnings(model, terrain=valley)[0] == ["floor"]
    assert floor_warnings(model, terrain=rft_mujoco.SandRegion(valley, (-1, 0), (-1, 0)))[0] == ["floor"]


def test_several_floors_give_one_warning_naming_each():
    floors = FLOOR.format(z=0.0, attrs="") + '<geom name="step" type="plane" size="1 1 0.1" pos="0 0 0.1"/>'
    names, found = floor_warnings(make(floor=floors)[0])
    assert names == ["floor", "step"] and len(found) == 1
    assert "handle.replace_rigid(['floor', 'step'])" in str(found[0].message)


def test_replace_rigid_silences_the_floor_check():
    model, _ = make()
    sand = rft_mujoco.attach(model, MEDIA, bodies=["ball"], resolution=0.02)
    assert floor_warnings(model)[0] == ["floor"]
    sand.replace_rigid(["floor"])
    assert floor_warnings(model) == ([], [])


def test_walls_and_bodies_that_cannot_collide_are_fine_tilted_floors_are_not():
    wall = '<geom name="wall" type="plane" size="1 1 0.1" pos="1 0 0" zaxis="-1 0 0"/>'
    assert floor_warnings(make(floor=wall)[0]) == ([], [])
    tilted = '<geom name="ramp" type="plane" size="1 1 0.1" pos="0 0 -1" zaxis="0.1 0 1"/>'
    names, found = floor_warnings(make(floor=tilted)[0])
    assert names == ["ramp"] and "tilted" in str(found[0].message)
    model, _ = make(ball='contype="0" conaffinity="0"')
    assert floor_warnings(model) == ([], []), "the ball cannot collide with the floor"
    assert floor_warnings(model, bodies=("ball", "brick"))[0] == ["floor"], "the brick can"


def test_the_sand_heightfield_itself_warns_while_it_collides():
    terrain = '<geom name="terrain" type="hfield" hfield="h" {attrs}/>'
    model, _ = make(floor=terrain.format(attrs=""))
    surface = rft_mujoco.HeightfieldSurface.from_model(model, "terrain")
    names, found = floor_warnings(model, terrain=surface)
    assert names == ["terrain"] and "heightfield of the sand surface" in str(found[0].message)
    other = rft_mujoco.HeightfieldSurface(surface.heights + 0.5, surface.x_range, surface.y_range)
    assert floor_warnings(model, terrain=other)[0] == [], "a rigid heightfield that is not the sand's shape"
    model, _ = make(floor=terrain.format(attrs='contype="0" conaffinity="0"'))
    assert floor_warnings(model, terrain=surface) == ([], [])


# --- c. timestep --------------------------------------------------------------------------------------
def test_timestep_beyond_the_stability_study_warns_with_the_numbers():
    for dt, warned in ((0.002, False), (checks.STUDIED_TIMESTEP_MAX, False), (0.02, True)):
        model, _ = make(dt=dt)
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            assert checks.check_timestep(model) == warned
        found = setup_warnings(record)
        assert len(found) == int(warned)
        if warned:
            text = str(found[0].message)
            assert "0.02 s" in text and "up to 0.01 s" in text and "<= 0.005" in text
            assert found[0].filename == __file__


def test_timestep_limits_are_the_studies_ranges():
    from rft_mujoco.studies import loadpaths, stability

    assert checks.STUDIED_TIMESTEP_MAX == max(stability.TIMESTEPS)
    assert checks.ACCURATE_TIMESTEP_MAX == max(loadpaths.TIMESTEPS)


# --- d. mjDSBL_ACTUATION ------------------------------------------------------------------------------
def test_mujoco_skips_mjcb_control_when_actuation_is_disabled():
    """The MuJoCo fact behind the dispatcher's passive hook (mujoco-notes.md); if this fails, MuJoCo changed."""
    model, data = make()
    calls = []
    previous = mujoco.get_mjcb_control()
    mujoco.set_mjcb_control(lambda m, d: calls.append(d.time))
    try:
        mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        assert len(calls) == 2
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        assert len(calls) == 2, "no mjcb_control call with mjDSBL_ACTUATION set"
        model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        mujoco.mj_step(model, data)
        assert len(calls) == 3
    finally:
        mujoco.set_mjcb_control(previous)


def test_mjcb_passive_still_runs_with_actuation_disabled():
    """Where a dispatcher can notice mjDSBL_ACTUATION while mjcb_control is skipped: mjcb_passive still runs
    (unless springs and dampers are both disabled too, when MuJoCo skips it as well)."""
    model, data = make()
    calls = {"control": 0, "passive": 0}
    previous = mujoco.get_mjcb_control(), mujoco.get_mjcb_passive()

    def count(key):
        return lambda m, d: calls.__setitem__(key, calls[key] + 1)

    mujoco.set_mjcb_control(count("control"))
    mujoco.set_mjcb_passive(count("passive"))
    try:
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        mujoco.mj_step(model, data)
        assert calls == {"control": 0, "passive": 1}
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SPRING) | int(mujoco.mjtDisableBit.mjDSBL_DAMPER)
        mujoco.mj_step(model, data)
        assert calls == {"control": 0, "passive": 1}
    finally:
        mujoco.set_mjcb_control(previous[0])
        mujoco.set_mjcb_passive(previous[1])


PLATE = """
<mujoco><option timestep="0.002"/><worldbody>
  <body name="plate"><freejoint/><geom type="box" size="0.05 0.05 0.005" mass="0.2"/></body>
</worldbody></mujoco>
"""


def plate_on_sand(settle_steps: int):
    """A 0.2 kg plate on sand, ``settle_steps`` steps of 2 ms, then mjDSBL_ACTUATION set and 1 s more."""
    model = mujoco.MjModel.from_xml_string(PLATE)
    data = mujoco.MjData(model)
    rft_mujoco.attach(model, MEDIA, resolution=0.01, monitor=False)
    for _ in range(settle_steps):
        mujoco.mj_step(model, data)
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    z0, held = data.qpos[2], data.xfrc_applied[1].copy()
    for _ in range(500):
        mujoco.mj_step(model, data)
    return model, data, float(z0 - data.qpos[2]), held


def test_attach_refuses_a_model_where_no_hook_would_run():
    model, _ = make()
    bit = mujoco.mjtDisableBit
    model.opt.disableflags |= int(bit.mjDSBL_ACTUATION) | int(bit.mjDSBL_SPRING)
    assert not checks.check_actuation_flag(model)
    model.opt.disableflags |= int(bit.mjDSBL_DAMPER)
    assert checks.check_actuation_flag(model)
    with pytest.raises(ValueError, match="mjDSBL_ACTUATION, mjDSBL_SPRING and mjDSBL_DAMPER"):
        rft_mujoco.attach(model, MEDIA, resolution=0.02)


def test_the_sand_acts_with_mjdsbl_actuation():
    """MuJoCo skips mjcb_control under the flag (without the dispatcher's passive hook the plate fell
    g t^2 / 2 = 4.9 m in 1 s, or a settled plate kept its last wrench frozen in xfrc_applied and nothing
    resisted a push). With the hook the sand still carries the plate, set before the first step or after
    settling, and still resists motion."""
    _, _, fall, _ = plate_on_sand(0)
    assert 0.0 < fall < 0.05                                        # it sinks in a little, then rests
    model, data, fall, held = plate_on_sand(250)
    assert abs(fall) < 1e-4 and held[2] == pytest.approx(0.2 * 9.81, rel=1e-3)
    data.qvel[0] = 0.1                                              # a push: the sand stops it
    for _ in range(100):
        mujoco.mj_step(model, data)
    assert abs(data.qvel[0]) < 1e-3
    rft_mujoco.detach_all()


def test_bodies_thinner_than_two_elements_get_a_notice():
    """Issue 26, item 1: the default resolution on small bodies says so (the swimmer's links, 8-14 mm, at
    10 mm elements), and names a resolution that fits; the bundled quadruped (26 mm shins) is not warned."""
    from rft_mujoco.models import path
    from rft_mujoco.studies import swim

    model = swim._model()
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sand = rft_mujoco.attach(model, "li_loose_glass_beads")
    sand.detach()
    found = [w for w in record if "thinner than" in str(w.message)]
    assert len(found) == 1 and issubclass(found[0].category, rft_mujoco.SandSetupWarning)
    text = str(found[0].message)
    assert "'link6' 8 mm" in text and "resolution=0.002" in text
    assert found[0].filename == __file__
    thin = checks.check_resolution(model, [model.body("link6").id], 0.003)
    assert thin == []
    quad = mujoco.MjModel.from_xml_path(str(path("quadruped.xml")))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        rft_mujoco.attach(quad, "li_loose_glass_beads").detach()
    assert not [w for w in record if "thinner than" in str(w.message)]
