"""The scenes of the load-path study (:mod:`rft_mujoco.studies.loadpaths`, described there) and the load each puts
on the sand: shared by the study and by its quasi-static reference (:mod:`rft_mujoco.studies.quasistatic`)."""

from __future__ import annotations

import numpy as np

MEDIA = "li_loose_glass_beads"
RESOLUTION = 0.01
"""Element size in m."""

_PLATE = "<body name='plate' pos='0 0 0.005'><freejoint/><geom type='box' size='0.05 0.05 0.005' mass='0.2'/>"
_FOOT = "<geom type='sphere' size='0.02' mass='0.05' contype='0' conaffinity='0'/>"
_TRUNK = ("<body name='trunk' pos='0 0 0.12'><joint name='lift' type='slide' axis='0 0 1'/>"
          "<geom type='box' size='0.05 0.05 0.02' mass='3' contype='0' conaffinity='0'/>")


def _scene(body: str, extra: str = "") -> str:
    return ("<mujoco><option timestep='{dt}' integrator='{integrator}'/><worldbody>" + body + "</worldbody>"
            + extra + "</mujoco>")


SCENES = {
    "contact": (_scene(_PLATE + "</body><body name='payload' pos='0 0 0.03'><freejoint/>"
                       "<geom type='box' size='0.04 0.04 0.02' mass='2'/></body>"), ["plate"]),
    "weld": (_scene(_PLATE + "</body><body name='payload' pos='0 0 0.03'><freejoint/>"
                    "<geom type='box' size='0.04 0.04 0.02' mass='2' contype='0' conaffinity='0'/></body>",
                    "<equality><weld body1='plate' body2='payload'/></equality>"), ["plate"]),
    "connect": (_scene(_PLATE + "</body><body name='payload' pos='0 0 0.03'><freejoint/>"
                       "<geom type='box' size='0.04 0.04 0.02' mass='2' contype='0' conaffinity='0'/></body>",
                       "<equality><connect body1='payload' body2='plate' anchor='0 0 0'/></equality>"),
                ["plate"]),
    "chain": (_scene(
        "<body name='trunk' pos='0 0 0.22'><joint name='lift' type='slide' axis='0 0 1'/>"
        "<geom type='box' size='0.08 0.03 0.02' mass='3' contype='0' conaffinity='0'/>"
        "<body name='leg_a' pos='-0.05 0 0'><joint type='hinge' axis='0 1 0' damping='0.1'/>"
        "<geom type='capsule' fromto='0 0 0 0 0 -0.2' size='0.01' mass='0.1' contype='0' conaffinity='0'/>"
        "<body name='foot' pos='0 0 -0.2'><joint type='hinge' axis='0 1 0' damping='0.1'/>"
        "<geom type='box' pos='0.05 0 -0.01' size='0.07 0.03 0.01' mass='0.2' contype='0' conaffinity='0'/>"
        "</body></body>"
        "<body name='leg_b' pos='0.05 0 0'><joint type='hinge' axis='0 1 0' damping='0.1'/>"
        "<geom type='capsule' fromto='0 0 0 0 0 -0.2' size='0.01' mass='0.1' contype='0' conaffinity='0'/>"
        "</body></body>",
        "<equality><connect body1='leg_b' body2='foot' anchor='0 0 -0.2'/></equality>"), ["foot"]),
    "joint_limit": (_scene(_TRUNK + "<body name='foot' pos='0 0 -0.1'><joint name='knee' type='slide' "
                           "axis='0 0 1' range='-0.05 0'/>" + _FOOT + "</body></body>"), ["foot"]),
    "tendon_limit": (_scene(_TRUNK + "<body name='foot' pos='0 0 -0.1'><joint name='knee' type='slide' "
                            "axis='0 0 1'/>" + _FOOT + "</body></body>",
                            "<tendon><fixed name='t' range='-0.05 0'><joint joint='knee' coef='1'/></fixed>"
                            "</tendon>"), ["foot"]),
    "actuator_limit": (_scene("<body name='frame' pos='0 0 0.12'><geom type='box' size='0.05 0.05 0.02' "
                              "contype='0' conaffinity='0'/><body name='foot' pos='0 0 -0.1'><joint name='knee' "
                              "type='slide' axis='0 0 1'/>" + _FOOT + "</body></body>",
                              "<actuator><position joint='knee' kp='10000' ctrlrange='-1 0' "
                              "forcerange='-20 20'/></actuator>"), ["foot"]),
    "frictionloss": (_scene(_TRUNK + "<body name='foot' pos='0 0 -0.1'><joint name='knee' type='slide' "
                            "axis='0 0 1' frictionloss='50' solimpfriction='0.9999 0.9999 0.001'/>" + _FOOT + "</body></body>"), ["foot"]),
    "rock": (_scene("<geom name='rock' type='box' pos='0.08 0 0' size='0.05 0.1 0.05' condim='1'/>"
                    "<body name='ball' pos='0 0 0.03'><freejoint/><geom type='sphere' size='0.03' mass='1' "
                    "condim='1'/></body>"), ["ball"]),
}
"""name -> (MJCF template with {dt} and {integrator}, sand bodies)."""

ACTUATOR_FORCE = 20.0
"""N: the saturated servo force of the ``actuator_limit`` scene."""
ROCK_PUSH = 10.0
"""N: the sideways push (+x) on the ball of the ``rock`` scene (xfrc_applied, the user's load)."""


def scene(name: str, dt: float, integrator: str):
    """(model, data, sand bodies) of scene ``name`` at timestep ``dt`` (s) and ``integrator`` (a MuJoCo name), the
    data at the scene's start: the ``actuator_limit`` servo's target far below (saturated at its force range)."""
    import mujoco

    xml, bodies = SCENES[name]
    model = mujoco.MjModel.from_xml_string(xml.format(dt=dt, integrator=integrator))
    data = mujoco.MjData(model)
    if model.nu:
        data.ctrl[:] = -1.0
    return model, data, bodies


def expected_force(name: str, model) -> np.ndarray:
    """(3,) the force (N) the sand must carry at rest, and a (3,) mask of the components checked."""
    g = -float(model.opt.gravity[2])
    if name == "actuator_limit":
        return np.array([0.0, 0.0, ACTUATOR_FORCE + 0.05 * g]), np.array([False, False, True])
    if name == "rock":   # the rock takes the push (frictionless contact); the sand the weight
        return np.array([0.0, 0.0, 1.0 * g]), np.array([False, False, True])
    # The slide joint to the world of the scenes with a trunk can react sideways, never vertically.
    lateral = name in ("contact", "weld", "connect")
    return np.array([0.0, 0.0, float(model.body_subtreemass[0]) * g]), np.array([lateral, lateral, True])
