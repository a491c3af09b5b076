"""Mesh robots of our own, built in code, with the features of public robot models that matter to the sand:
non-manifold STL links, slanted OBJ lower legs made of long thin triangles, bodies with visual geoms only.

Nothing here is copied from a public model: every mesh is generated below (numpy + trimesh) and handed
to MuJoCo as in-memory assets. Used by the bench (section 5, :func:`standing_cost`) and by
tests/test_mesh_robots.py.

* :func:`mesh_humanoid`: a 34 kg biped, standing by an ankle strategy (:func:`balance_humanoid`: its ankle
  servos answer the torso's tilt, as an IMU would report it; with its servos only holding the joint angles
  it falls on loose sand, like the public humanoids with a pose holder, and lies in it);
  torso, thighs, shins and soles are STL meshes made of two
  closed boxes that share an edge (non-manifold edges, consistently wound, like a humanoid's shipped
  links); the head is a visual-only mesh body; servos hold ``home``.
* :func:`mesh_quadruped`: a 17 kg quadruped; box torso, visual-only hip bodies (an OBJ mesh each), capsule
  thighs and slanted OBJ lower legs: 12-sided prisms 0.3 m long whose side triangles are 0.3 m by
  16 mm; servos hold ``home``.
* :func:`slanted_quadruped`: a 62 kg Spot-sized quadruped on slanted mesh lower legs with sphere feet, set
  down on the sand at its standing height (:mod:`rft_mujoco.studies.glide`).
"""

from __future__ import annotations

import time
import warnings

import mujoco
import numpy as np

__all__ = ["mesh_humanoid", "mesh_quadruped", "slanted_quadruped", "ROBOTS", "standing_cost", "two_box_link", "prism"]


# --- meshes ----------------------------------------------------------------------------------------------
def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A closed box from corner ``lo`` to ``hi`` (m): (8, 3) vertices, (12, 3) outward faces."""
    import trimesh

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    return np.asarray(b.vertices) + 0.5 * (lo + hi), np.asarray(b.faces)


def two_box_link(size, split=0.5) -> tuple[np.ndarray, np.ndarray]:
    """A link mesh of two closed boxes that meet along one edge (non-manifold: that edge has 4 faces, and
    each of its two directions is used twice), each box consistently wound.

    Args:
        size: (3,) m, the full extents of the link along x, y, z (centred at the origin).
        split: where along x and y the two boxes meet, as a fraction of the extent.
    Returns:
        (v, 3) vertices (m) and (f, 3) faces.
    """
    sx, sy, sz = (0.5 * np.asarray(size, float))
    x0, y0 = -sx + 2 * sx * split, -sy + 2 * sy * split
    v1, f1 = _box((-sx, -sy, -sz), (x0, y0, sz))
    v2, f2 = _box((x0, y0, -sz), (sx, sy, sz))
    return np.vstack([v1, v2]), np.vstack([f1, f2 + len(v1)])


def prism(radius: float, length: float, sides: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A closed prism along z (``sides``-gon of circumradius ``radius`` m, ``length`` m, centred): each side is
    two triangles as long as the prism, the caps are fans; outward faces."""
    phi = 2 * np.pi * np.arange(sides) / sides
    ring = np.column_stack([radius * np.cos(phi), radius * np.sin(phi)])
    v = np.vstack([np.column_stack([ring, np.full(sides, -0.5 * length)]),
                   np.column_stack([ring, np.full(sides, 0.5 * length)]),
                   [[0, 0, -0.5 * length], [0, 0, 0.5 * length]]])
    i = np.arange(sides)
    j = (i + 1) % sides
    side = np.vstack([np.column_stack([i, j, j + sides]), np.column_stack([i, j + sides, i + sides])])
    bottom = np.column_stack([np.full(sides, 2 * sides), j, i])
    top = np.column_stack([np.full(sides, 2 * sides + 1), i + sides, j + sides])
    return v, np.vstack([side, bottom, top])


def _stl(v, f) -> bytes:
    import trimesh

    return trimesh.Trimesh(v, f, process=False).export(file_type="stl")


def _obj(v, f) -> bytes:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    return ("\n".join(lines) + "\n").encode()


def _icosphere(radius: float) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces)


# --- robots ----------------------------------------------------------------------------------------------
_VISUAL = 'contype="0" conaffinity="0" group="2"'
_OPTION = '<option timestep="0.002" integrator="implicitfast"/>'


def mesh_humanoid() -> mujoco.MjModel:
    """The biped of the module docstring, standing with its soles on the floor plane at z = 0 (``home``)."""
    assets = {"torso.stl": _stl(*two_box_link((0.22, 0.32, 0.40))),
              "thigh.stl": _stl(*two_box_link((0.10, 0.10, 0.36))),
              "shin.stl": _stl(*two_box_link((0.08, 0.08, 0.36))),
              "sole.stl": _stl(*two_box_link((0.30, 0.16, 0.04), split=0.45)),
              "head.stl": _stl(*_icosphere(0.1))}
    legs = ""
    for side, y in (("left", 0.12), ("right", -0.12)):
        legs += f"""
        <body name="{side}_thigh" pos="0 {y} -0.22">
          <joint name="{side}_hip" axis="0 1 0" range="-1.5 1.5"/>
          <inertial pos="0 0 -0.18" mass="4" diaginertia="0.05 0.05 0.01"/>
          <geom type="mesh" mesh="thigh" pos="0 0 -0.18"/>
          <body name="{side}_shin" pos="0 0 -0.36">
            <joint name="{side}_knee" axis="0 1 0" range="-0.1 2.5"/>
            <inertial pos="0 0 -0.18" mass="3" diaginertia="0.04 0.04 0.01"/>
            <geom type="mesh" mesh="shin" pos="0 0 -0.18"/>
            <body name="{side}_foot" pos="0 0 -0.36">
              <joint name="{side}_ankle" axis="0 1 0" range="-1 1"/>
              <joint name="{side}_ankle_roll" axis="1 0 0" range="-0.5 0.5"/>
              <inertial pos="0 0 -0.02" mass="1.2" diaginertia="0.004 0.006 0.008"/>
              <geom type="mesh" mesh="sole" pos="0 0 -0.02"/>
            </body>
          </body>
        </body>"""
    actuators = "".join(f'<position name="{s}_{j}" joint="{s}_{j}" kp="{kp}" kv="{kv}"/>'
                        for s in ("left", "right") for j, kp, kv in (("hip", 3000, 60), ("knee", 3000, 60),
                                                                     ("ankle", 3000, 60),
                                                                     ("ankle_roll", 3000, 60)))
    xml = f"""
    <mujoco model="mesh_humanoid">
      {_OPTION}
      <asset>
        <mesh name="torso" file="torso.stl"/><mesh name="thigh" file="thigh.stl"/>
        <mesh name="shin" file="shin.stl"/><mesh name="sole" file="sole.stl"/><mesh name="head" file="head.stl"/>
      </asset>
      <worldbody>
        <geom name="floor" type="plane" size="5 5 0.1"/>
        <body name="torso" pos="0 0 0.98">
          <freejoint/>
          <inertial pos="0 0 0" mass="14" diaginertia="0.3 0.25 0.15"/>
          <geom type="mesh" mesh="torso"/>
          <body name="head" pos="0 0 0.32">
            <inertial pos="0 0 0" mass="3" diaginertia="0.01 0.01 0.01"/>
            <geom type="mesh" mesh="head" {_VISUAL}/>
          </body>
          {legs}
        </body>
      </worldbody>
      <actuator>{actuators}</actuator>
      <keyframe><key name="home" qpos="0 0 0.98 1 0 0 0 0 0 0 0 0 0 0 0" ctrl="0 0 0 0 0 0 0 0"/></keyframe>
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(xml, assets)


def _standing(actuators: str, height: float, joints: int) -> str:
    """The actuator block and the ``home`` keyframe of a floating-base robot with ``joints`` servo-held hinges,
    its base at ``height`` m, upright, every joint and servo target at 0."""
    zeros = " ".join(["0"] * joints)
    return (f"<actuator>{actuators}</actuator><keyframe><key name=\"home\" qpos=\"0 0 {height:.5f} 1 0 0 0 {zeros}\" "
            f"ctrl=\"{zeros}\"/></keyframe>")


def mesh_quadruped() -> mujoco.MjModel:
    """The quadruped of the module docstring, standing on its lower legs on the floor plane at z = 0
    (``home``)."""
    shin_len, tilt = 0.30, 0.35                  # m, rad: the lower leg leans back by 20 degrees
    assets = {"shin.obj": _obj(*prism(0.025, shin_len, 12)),
              "hip.obj": _obj(*_box((-0.05, -0.04, -0.04), (0.05, 0.04, 0.04)))}
    legs = ""
    for name, x, y in (("fl", 0.25, 0.12), ("fr", 0.25, -0.12), ("hl", -0.25, 0.12), ("hr", -0.25, -0.12)):
        cx, cz = -0.5 * shin_len * np.sin(tilt), -0.5 * shin_len * np.cos(tilt)
        legs += f"""
        <body name="{name}_hip" pos="{x} {y} 0">
          <joint name="{name}_abd" axis="1 0 0" range="-0.5 0.5"/>
          <inertial pos="0 0 0" mass="0.8" diaginertia="0.002 0.002 0.002"/>
          <geom type="mesh" mesh="hip" {_VISUAL}/>
          <body name="{name}_thigh" pos="0 0 0">
            <joint name="{name}_hip" axis="0 1 0" range="-1.5 1.5"/>
            <inertial pos="0 0 -0.12" mass="1.2" diaginertia="0.01 0.01 0.002"/>
            <geom type="capsule" fromto="0 0 0 0 0 -0.24" size="0.03"/>
            <body name="{name}_shin" pos="0 0 -0.24">
              <joint name="{name}_knee" axis="0 1 0" range="-2.5 2.5"/>
              <inertial pos="{cx:.5f} 0 {cz:.5f}" mass="0.5" diaginertia="0.004 0.004 0.0004"/>
              <geom type="mesh" mesh="shin" pos="{cx:.5f} 0 {cz:.5f}" euler="0 {-tilt:.5f} 0"/>
            </body>
          </body>
        </body>"""
    height = 0.24 + shin_len * np.cos(tilt) + 0.025 * np.sin(tilt)
    actuators = "".join(f'<position joint="{n}_{j}" kp="300" kv="10"/>'
                        for n in ("fl", "fr", "hl", "hr") for j in ("abd", "hip", "knee"))
    xml = f"""
    <mujoco model="mesh_quadruped">
      {_OPTION}
      <asset><mesh name="shin" file="shin.obj"/><mesh name="hip" file="hip.obj"/></asset>
      <worldbody>
        <geom name="floor" type="plane" size="5 5 0.1"/>
        <body name="torso" pos="0 0 {height:.5f}">
          <freejoint/>
          <inertial pos="0 0 0" mass="12" diaginertia="0.1 0.3 0.35"/>
          <geom type="box" size="0.33 0.11 0.06"/>
          {legs}
        </body>
      </worldbody>
      {_standing(actuators, height, 12)}
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(xml, assets)


def slanted_quadruped(trunk_mass: float = 45.0, slant: float = 0.5, foot: float = 0.03, kp: float = 3000.0,
                      lean: float = 0.6) -> mujoco.MjModel:
    """A Spot-sized quadruped (issue 26, item 3) standing with its sphere feet on the surface z = 0 (``home``;
    no floor: the sand is the ground): a ``trunk_mass`` kg box trunk (1.0 x 0.4 x 0.18 m), knees bent
    backward, 0.32 m capsule thighs leaning back 0.6 rad, and lower legs leaning forward 0.5 rad that are OBJ
    meshes: 12-sided prisms 0.36 m long (side triangles 0.36 m by 10 mm), with a 30 mm sphere foot each.
    Stiff PD servos (kp 3000 N m/rad, kv 60 N m s/rad) hold the pose. 62 kg in all."""
    thigh, shin = 0.32, 0.36
    assets = {"shin.obj": _obj(*prism(0.02, shin, 12))}
    kx, kz = -thigh * np.sin(lean), -thigh * np.cos(lean)          # knee from hip
    fx, fz = shin * np.sin(slant), -shin * np.cos(slant)           # foot from knee
    legs = ""
    for name, x, y in (("fl", 0.4, 0.16), ("fr", 0.4, -0.16), ("hl", -0.4, 0.16), ("hr", -0.4, -0.16)):
        legs += f"""
        <body name="{name}_hip" pos="{x} {y} -0.09">
          <joint name="{name}_abd" axis="1 0 0" range="-0.6 0.6"/>
          <geom type="cylinder" size="0.05 0.04" euler="1.5708 0 0" mass="1.5"/>
          <body name="{name}_thigh">
            <joint name="{name}_hip" axis="0 1 0" range="-1.5 1.5"/>
            <geom type="capsule" fromto="0 0 0 {kx:.5f} 0 {kz:.5f}" size="0.035" mass="2"/>
            <body name="{name}_shin" pos="{kx:.5f} 0 {kz:.5f}">
              <joint name="{name}_knee" axis="0 1 0" range="-2.6 2.6"/>
              <inertial pos="{fx / 2:.5f} 0 {fz / 2:.5f}" mass="0.6" diaginertia="0.007 0.007 0.0002"/>
              <geom type="mesh" mesh="shin" pos="{fx / 2:.5f} 0 {fz / 2:.5f}" euler="0 {slant:.5f} 0"/>
              <body name="{name}_foot" pos="{fx:.5f} 0 {fz:.5f}">
                <geom type="sphere" size="{foot}" mass="0.15"/>
              </body>
            </body>
          </body>
        </body>"""
    height = 0.09 - kz - fz + foot
    actuators = "".join(f'<position joint="{n}_{j}" kp="{kp:g}" kv="{kp / 50:g}"/>'
                        for n in ("fl", "fr", "hl", "hr") for j in ("abd", "hip", "knee"))
    xml = f"""
    <mujoco model="slanted_quadruped">
      {_OPTION}
      <asset><mesh name="shin" file="shin.obj"/></asset>
      <worldbody>
        <body name="trunk" pos="0 0 {height:.5f}">
          <freejoint/>
          <geom type="box" size="0.5 0.2 0.09" mass="{trunk_mass:g}"/>
          {legs}
        </body>
      </worldbody>
      {_standing(actuators, height, 12)}
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(xml, assets)


BALANCE_GAIN = 0.4
"""rad per rad: the ankle targets' shift per radian of torso tilt in :func:`balance_humanoid` (torque
``kp * gain`` N m/rad per ankle, kp = 3000 N m/rad; 0.3-0.8 measured to stand on loose glass beads)."""

BALANCE_DAMPING = 0.03
"""s: the ankle targets' shift per rad/s of torso rate in :func:`balance_humanoid` (0.02-0.05 measured to
stand; 0.1 rolls it over: the servos' own lag)."""


def balance_humanoid(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Set the ankle servos' targets of :func:`mesh_humanoid` from the torso's tilt (an ankle strategy): each
    ankle target is its current angle plus ``BALANCE_GAIN`` times the torso's pitch (roll) and
    ``BALANCE_DAMPING`` times its rate, so that the ankles push the body upright whatever the feet's own
    tilt in the sand. Call it before each ``mj_step``. Why it needs one: a statue rests on loose glass beads
    only where its soles resist rocking more than its weight tips it; the soles give about
    alpha sum(A x^2) = 68 N m/rad in pitch against m g h = 230 N m/rad (docs/robots.md)."""
    z = data.xmat[model.body("torso").id].reshape(3, 3)[:, 2]
    pitch, roll = np.arctan2(z[0], z[2]), np.arctan2(-z[1], z[2])
    rate = data.qvel[3:6]                                    # the free joint's angular velocity, torso frame
    for side in ("left", "right"):
        for joint, tilt, w in (("ankle", pitch, rate[1]), ("ankle_roll", roll, rate[0])):
            name = f"{side}_{joint}"
            q = data.qpos[model.jnt_qposadr[model.joint(name).id]]
            data.ctrl[model.actuator(name).id] = q + BALANCE_GAIN * tilt + BALANCE_DAMPING * w


ROBOTS = {"mesh humanoid": mesh_humanoid, "mesh quadruped": mesh_quadruped}
"""The mesh robots of :func:`standing_cost`, by name."""

CONTROLLERS = {"mesh humanoid": balance_humanoid}
"""What sets a robot's servo targets before each step (robots not named hold ``home``)."""


# --- cost ------------------------------------------------------------------------------------------------
def standing_cost(names=None, resolution="default", settle_s: float = 2.5, steps: int = 500,
                  repeats: int = 5) -> list[dict]:
    """Each robot standing on sand (every body attached, the floor replaced, servos holding ``home``, or set by
    the robot's :data:`CONTROLLERS` entry before each step, untimed):
    us per mj_step against the same model's bare step (floor kept, no sand), timed side by side
    (alternating runs of ``steps`` steps from the state reached after ``settle_s`` s; medians of
    ``repeats``), with the element counts and the exposed area.

    Returns:
        one dict per robot: name, elements, area (m^2), count_ratio (elements / (area / size^2)),
        attach_s, bare_us, sand_us, ratio, height (torso, m, after settling), weight_carried (sand force z /
        total weight, after settling), loaded and resting (bodies with submerged elements, and those of
        them held at rest by the rest treatment), speed (torso, m/s, after settling), summary (``handle.summary()``).
    """
    from rft_mujoco.coupling.handle import attach
    from rft_mujoco.geometry import surface
    from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS

    size = surface.element_size(resolution)
    rows = []
    for name in (names or ROBOTS):
        model = ROBOTS[name]()
        bare_model = ROBOTS[name]()
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, resolution, monitor=False)
            handle.replace_rigid(["floor"])
        attach_s = time.perf_counter() - t0
        data, bare = mujoco.MjData(model), mujoco.MjData(bare_model)
        control = CONTROLLERS.get(name, lambda m, d: None)
        for m, d in ((model, data), (bare_model, bare)):
            mujoco.mj_resetDataKeyframe(m, d, 0)
            for _ in range(int(round(settle_s / m.opt.timestep))):
                control(m, d)
                mujoco.mj_step(m, d)
        diag = handle.diagnostics(data)
        weight = float(model.body_subtreemass[1] * -model.opt.gravity[2])
        carried = float(diag.force[:, 2].sum() / weight)
        loaded = diag.submerged > 0
        resting = int(np.count_nonzero(diag.resting & loaded))
        speed = float(np.linalg.norm(data.qvel[:3]))
        sand_t, bare_t = [], []
        state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        bstate = np.empty_like(state)
        mujoco.mj_getState(bare_model, bare, bstate, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        for _ in range(repeats):
            for m, d, s, out in ((model, data, state, sand_t), (bare_model, bare, bstate, bare_t)):
                mujoco.mj_setState(m, d, s, mujoco.mjtState.mjSTATE_FULLPHYSICS)
                spent = 0.0
                for _ in range(steps):
                    control(m, d)                    # not timed: the same Python for both
                    t0 = time.perf_counter()
                    mujoco.mj_step(m, d)
                    spent += time.perf_counter() - t0
                out.append(spent / steps)
        area = float(handle.areas.sum())
        rows.append(dict(name=name, elements=handle.n_elements, area=area,
                         count_ratio=handle.n_elements / (area / size**2), attach_s=attach_s,
                         bare_us=1e6 * float(np.median(bare_t)), sand_us=1e6 * float(np.median(sand_t)),
                         ratio=float(np.median(sand_t) / np.median(bare_t)), height=float(data.qpos[2]),
                         weight_carried=carried, loaded=int(loaded.sum()), resting=resting, speed=speed,
                         summary=handle.summary()))
        handle.detach()
    return rows
