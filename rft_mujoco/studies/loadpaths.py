"""Loads that reach a sand body through MuJoCo's constraints: the rest cases of ``python -m rft_mujoco stability``.

MuJoCo solves contacts, equalities, joint and tendon limits and frictionloss after ``mjcb_control``, where
the sand is computed. Each scene here passes its load to the sand body through one of them, and a case
asks what a user would ask of it: does the body come to rest on the sand (every body slower than
1 mm/s and 1 mrad/s within :data:`DEADLINE`), without NaN and without the sand ever adding kinetic
energy in a step, does the sand then carry the load (its total force against the load the scene
puts on it, within :data:`BALANCE_RTOL`), and at the right depth (no deeper than :data:`DEPTH_FACTOR` times
the depth at which the law first carries that load, :func:`quasi_static_depth`)?

Scenes (SI units; sand: :data:`MEDIA`, flat surface at z = 0, elements of :data:`RESOLUTION`):

=================  ===============================================================================
``contact``        a 0.2 kg plate (10 x 10 x 1 cm) in the sand, a 2 kg box resting on it by contact
``weld``           the same, the box welded to the plate (``<weld>``)
``connect``        the same, the box held by a ball-joint equality (``<connect>``) at its centre
``chain``          a closed chain: a 3 kg trunk on a vertical slide, two hinged legs, a 0.2 kg foot
                   bar hinged to one leg and connected (``<connect>``) to the other
``joint_limit``    a 0.05 kg sphere foot (r 2 cm) on a slide joint held at its range limit by a 3 kg
                   trunk on a vertical slide (the upper limit, engaged from the start; the scene first had the foot at its lower
                   limit, and the trunk fell 50 mm onto the upper one: an impact, 2.3x the
                   quasi-static depth)
``tendon_limit``   the same, the slide held by the range of a fixed tendon instead
``actuator_limit`` the same foot pushed down by a position servo saturated at its force range (20 N)
                   from a fixed frame
``frictionloss``   the same foot held by the dry friction (``frictionloss`` 50 N) of its slide joint
                   under the 3 kg trunk. MuJoCo's frictionloss is soft: with its default impedance the
                   trunk slips through it at 0.63 m/s even with the foot welded to the world (measured),
                   so the scene sets ``solimpfriction`` d = 0.9999 (0.6 mm/s of MuJoCo's own creep left)
``rock``           a 1 kg sphere (r 3 cm) in the sand pushed sideways (10 N) against a rigid rock that
                   sticks out of the sand (frictionless contact: the rock takes the push, the sand the
                   weight)
=================  ===============================================================================

Each runs with Euler, implicitfast, implicit and RK4 at dt = 0.5, 1, 2 and 5 ms, for 3 s, from rest with
the sand body on the surface.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.studies.recorder import StageRecorder

MEDIA = "li_loose_glass_beads"
RESOLUTION = 0.01
"""Element size in m."""
DURATION = 3.0
"""Simulated seconds per case."""
DEADLINE = 3.0
"""s: every body must be at rest by then (and stay at rest)."""
REST_SPEED = 1e-3
"""m/s and rad/s: at rest below this, for every body's linear and angular speed."""
BALANCE_RTOL = 0.01
"""The sand's total force must match the load to this fraction at the end."""
DEPTH_FACTOR = 2.0
"""A body must rest no deeper than this times its quasi-static rest depth (:func:`quasi_static_depth`): the depth
at which the sand first carries the load; a load set down suddenly overshoots it at most twice (a linear
spring's dynamic factor), anything deeper is the solve's error (issue 26, item 2)."""
GAIN_RTOL = 1e-9
"""Energy gains beyond this fraction of a step's energy exchange are failures (as the drop study)."""
INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
RK4_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
"""The stage weights of MuJoCo's RK4 (the sand's impulse of a step)."""
TIMESTEPS = (0.0005, 0.001, 0.002, 0.005)

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


@dataclasses.dataclass
class Result:
    scene: str
    dt: float
    integrator: str
    nan: bool = False
    observed: int = 0                    # sand evaluations the energy recorder saw (0: nothing measured)
    max_gain: float = -math.inf          # J, largest dE of a step (see rft_mujoco.studies.stability)
    max_gain_rel: float = -math.inf
    t_rest: float = math.inf             # s, every body slower than REST_SPEED from then on
    final_speed: float = math.nan        # m/s or rad/s, the largest body speed at the end
    balance: float = math.nan            # |F_sand - F_load| / |F_load| on the checked components
    sinkage: float = math.nan            # m, depth of the sand body's reference point below its start
    rest_depth: float = math.nan         # m, the quasi-static depth under the scene's load (quasi_static_depth)
    wall: float = 0.0
    failures: tuple = ()

    @property
    def label(self) -> str:
        return f"{self.scene:14s} dt={self.dt * 1e3:<4g}ms {self.integrator:12s}"


@functools.lru_cache(maxsize=None)
def quasi_static_depth(name: str) -> float:
    """m: the depth at which the sand first carries the scene's load on its sand body, moving straight down
    (:func:`rft_mujoco.studies.quasistatic.scene_rest_depth`: the law alone, this study's medium and elements),
    measured as :attr:`Result.sinkage` is."""
    from rft_mujoco.studies.quasistatic import scene_rest_depth

    return scene_rest_depth(name)[0]


def run_case(name: str, dt: float, integrator: str, *, stabilize: bool = True, backend: str = "auto",
             solve: str = "explicit") -> Result:
    """One scene at one (dt, integrator); ``stabilize``, ``backend`` and ``solve`` go to :func:`attach`."""
    xml, bodies = SCENES[name]
    res = Result(name, dt, integrator, rest_depth=quasi_static_depth(name))
    t0 = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(xml.format(dt=dt, integrator=integrator))
    data = mujoco.MjData(model)
    if model.nu:
        data.ctrl[:] = -1.0                       # the actuator_limit servo: a target far below (saturated)
    n = int(round(DURATION / dt))
    speeds = np.empty(n)
    vel = np.zeros(6)
    import warnings

    from rft_mujoco.coupling.monitor import RFTValidityWarning
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RFTValidityWarning)
        sand = attach(model, MEDIA, bodies=bodies, resolution=RESOLUTION, stabilize=stabilize, backend=backend,
                      solve=solve)
        rec = StageRecorder(sand, model)
        try:
            ball = model.body("ball").id if name == "rock" else -1
            start = data.qpos.copy()
            mujoco.mj_forward(model, data)
            z0 = data.xipos[sand.body_ids[0], 2]
            for i in range(n):
                if ball > 0:
                    data.xfrc_applied[ball, 0] = ROCK_PUSH
                rec.q.clear()
                mujoco.mj_step(model, data)
                if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
                    res.nan = True
                    n = i
                    break
                gain = rec.step_gain(model, data, dt, RK4_WEIGHTS)
                if gain is not None:
                    res.max_gain = max(res.max_gain, gain[0])
                    res.max_gain_rel = max(res.max_gain_rel, gain[1])
                s = 0.0
                for b in range(1, model.nbody):
                    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
                    s = max(s, float(np.abs(vel).max()))
                speeds[i] = s
            del start
            if n and not res.nan:
                moving = np.flatnonzero(speeds[:n] >= REST_SPEED)
                res.t_rest = 0.0 if moving.size == 0 else (moving[-1] + 1) * dt if moving[-1] < n - 1 else math.inf
                res.final_speed = float(speeds[n - 1])
                load, mask = expected_force(name, model)
                got = sand.diagnostics(data).force.sum(axis=0)
                res.balance = float(np.linalg.norm((got - load)[mask]) / np.linalg.norm(load[mask]))
                res.sinkage = float(z0 - data.xipos[sand.body_ids[0], 2])
        finally:
            res.observed = rec.evaluations
            sand.detach()
    res.wall = time.perf_counter() - t0
    out = []
    if res.nan:
        out.append("NaN")
    if res.observed == 0:
        out.append("energy not measured: the observer saw no sand evaluation")
    if res.max_gain_rel > GAIN_RTOL:
        out.append(f"energy gain {res.max_gain:.3g} J")
    if not res.nan and not res.t_rest <= DEADLINE:
        out.append(f"no rest within {DEADLINE:g} s (final speed {res.final_speed:.3g})")
    if not res.nan and not res.balance <= BALANCE_RTOL:
        out.append(f"sand force off the load by {res.balance:.3g}")
    if not res.nan and not res.sinkage <= DEPTH_FACTOR * res.rest_depth:
        out.append(f"rests {res.sinkage * 1e3:.1f} mm deep, {res.sinkage / res.rest_depth:.2f}x the quasi-static "
                   f"{res.rest_depth * 1e3:.1f} mm (at most {DEPTH_FACTOR:g}x)")
    res.failures = tuple(out)
    return res


def cases(quick: bool = False) -> list[tuple[str, float, str]]:
    """(scene, dt, integrator) of the full study or of its quick subset."""
    if quick:
        return [(name, 0.005, "implicitfast") for name in SCENES]
    return [(name, dt, integ) for name in SCENES for dt in TIMESTEPS for integ in INTEGRATORS]
