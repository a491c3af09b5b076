"""Sand declared in MJCF <custom> fields, and the demo scene."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.studies import demo

SCENE = """
<mujoco>
  <custom>
    <text name="rft/beach/media" data="maladen_glass_beads"/>
    <text name="rft/beach/bodies" data="a"/>
    <numeric name="rft/beach/surface_height" data="0.1"/>
    <numeric name="rft/mud/media" data="1800 0.5 0.3"/>
    <text name="rft/mud/bodies" data="b"/>
    <numeric name="rft/mud/region" data="0.5 1.5 -1 1"/>
    <numeric name="rft/mud/resolution" data="0.02"/>
    <text name="rft/mud/replaces" data="floor"/>
  </custom>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="a"><freejoint/><geom type="sphere" size="0.05"/></body>
    <body name="b" pos="1 0 0"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>
  </worldbody>
</mujoco>
"""



def test_attach_scene_reads_every_field():
    model = mujoco.MjModel.from_xml_string(SCENE)
    handles = {h.body_names[0]: h for h in rft_mujoco.attach_scene(model)}
    a, b = handles["a"], handles["b"]
    assert a.media == rft_mujoco.MALADEN_GLASS_BEADS
    assert a.terrain == rft_mujoco.FlatSurface(0.1)
    assert (b.media.rho_c, b.media.mu_int, b.media.mu_surf) == (1800.0, 0.5, 0.3)
    assert isinstance(b.terrain, rft_mujoco.SandRegion) and b.terrain.x_range == (0.5, 1.5)
    assert b.element_size == 0.02
    assert model.geom("floor").contype == 0 and model.geom("floor").conaffinity == 0
    b.detach()
    assert model.geom("floor").contype == 1, "detach restores the rigid floor"


def test_attach_scene_errors():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
    with pytest.raises(ValueError, match="declares no sand"):
        rft_mujoco.attach_scene(model)
    bad = SCENE.replace("rft/mud/region", "rft/mud/regoin")
    with pytest.raises(ValueError, match="unknown sand field 'rft/mud/regoin'"):
        rft_mujoco.attach_scene(mujoco.MjModel.from_xml_string(bad))
    assert not rft_mujoco.coupling.dispatch.DISPATCHER.handles, "a failed attach_scene leaves nothing attached"


def test_demo_stands_and_trots(tmp_path):
    summary = demo.run(seconds=2.0, stand_s=0.8, out=tmp_path, video=False)
    assert (tmp_path / "demo_quadruped.png").exists()
    # Stands in the sand (sinks a few cm, does not fall through) and trots forward.
    assert 0.02 < summary["standing_trunk_sinkage_m"] < 0.15
    # Standing, the sand carries the whole robot (the split among the legs is statically indeterminate).
    assert abs(summary["standing_total_force_N"] - summary["weight_N"]) < 0.01 * summary["weight_N"]
    assert summary["standing_leg_force_N"].sum() > 0.9 * summary["weight_N"]
    assert summary["trot_speed_mps"] > 0.1


def test_view_has_its_own_options(monkeypatch, capsys):
    from rft_mujoco.studies import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["view", "--help"])
    text = capsys.readouterr().out
    assert exit_.value.code == 0 and text.startswith("usage: python -m rft_mujoco view")
    assert "--seconds" in text and "--stand" in text and "viewer" in text
    assert "--out" not in text and "--no-video" not in text
    with pytest.raises(SystemExit) as exit_:
        cli.main(["view", "--no-video"])
    assert exit_.value.code == 2 and "unrecognized arguments: --no-video" in capsys.readouterr().err
    calls = []
    monkeypatch.setattr(demo, "view", lambda *args: calls.append(args))
    assert cli.main(["view", "--seconds", "3", "--stand", "0.5"]) == 0
    assert cli.main(["view", "--deformable"]) == 0
    assert calls == [(3.0, 0.5, False), (60.0, 1.0, True)]
    with pytest.raises(SystemExit):
        cli.main(["demo", "--help"])
    text = capsys.readouterr().out
    assert "--out" in text and "--no-video" in text


def test_viewer_camera_tracks_the_trunk():
    """The viewer's camera (demo.track) looks at the trunk's subtree centre of mass wherever it goes."""
    scene = demo.Demo()
    model, data = scene.model, scene.data
    cam = mujoco.MjvCamera()
    demo.track(cam, scene.trunk)
    opt, pert, scn = mujoco.MjvOption(), mujoco.MjvPerturb(), mujoco.MjvScene(model, maxgeom=1000)
    for dx in (0.0, 2.0):
        data.qpos[0] += dx
        mujoco.mj_forward(model, data)
        mujoco.mjv_updateScene(model, data, opt, pert, cam, mujoco.mjtCatBit.mjCAT_ALL, scn)
        np.testing.assert_allclose(cam.lookat, data.subtree_com[scene.trunk], atol=1e-12)
    assert cam.distance == demo.VIEW_DISTANCE_M
    scene.close()


def test_demo_refuses_to_overwrite_an_explicit_out(tmp_path, capsys):
    """``demo --out DIR`` never replaces a plot or video already there without ``--overwrite`` (the default
    out/ is the demo's own folder and is replaced)."""
    from rft_mujoco.studies import demo
    (tmp_path / "demo_quadruped.png").write_bytes(b"mine")
    with pytest.raises(SystemExit) as exc:
        demo.main(["--out", str(tmp_path), "--no-video", "--seconds", "0.01"])
    assert exc.value.code == 2 and "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "demo_quadruped.png").read_bytes() == b"mine"
