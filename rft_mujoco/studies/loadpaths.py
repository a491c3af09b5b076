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
from rft_mujoco.studies.loadpath_scenes import MEDIA, RESOLUTION, ROCK_PUSH, SCENES, expected_force, scene
from rft_mujoco.studies.quasistatic import scene_rest_depth
from rft_mujoco.studies.recorder import StageRecorder

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
    return scene_rest_depth(name)[0]


def run_case(name: str, dt: float, integrator: str, *, stabilize: bool = True, backend: str = "auto",
             solve: str = "explicit") -> Result:
    """One scene at one (dt, integrator); ``stabilize``, ``backend`` and ``solve`` go to :func:`attach`."""
    res = Result(name, dt, integrator, rest_depth=quasi_static_depth(name))
    t0 = time.perf_counter()
    model, data, bodies = scene(name, dt, integrator)
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
