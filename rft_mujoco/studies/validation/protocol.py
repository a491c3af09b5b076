"""The validation protocol: shapes, directions, media, tolerances, the rollouts, the results' containers."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.studies import shapes as mesh_shapes
from rft_mujoco.geometry import surface
from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics.law import PUBLISHED, Guards, element_forces
from rft_mujoco.physics.media import DEM_GLASS_BEADS, MPM_VALIDATION, Media
from rft_mujoco.coupling.rollout import Rollout, kinematic_rollout


# --- the protocol: one place -------------------------------------------------------------------------
CENTRE_DEPTH = 0.27
"""m, depth of each shape's volume centroid below the free surface (z = 0)."""
SPEED = 0.1
"""m/s, intrusion speed (3D-RFT is rate independent: only the direction matters)."""
DIRECTIONS_DEG = tuple(range(-90, 91, 15))
"""Motion directions in degrees from horizontal +x, positive upward (-90 straight down)."""
QUICK_DIRECTIONS_DEG = (-90, -45, 0, 45, 90)
SAMPLES = 5
"""Samples per direction rollout."""
WINDOW = 0.01
"""s, duration of each direction rollout (centred on the centre depth)."""
BODY = "intruder"

SPHERE_RADIUS = 0.05
ELLIPSOID_RADII = (0.075, 0.045, 0.045)
CUBE_EDGE = 0.075
PRISM_LEG = 0.075
PRISM_LENGTH = 0.075

DRILL_RADIUS = 0.025
DRILL_HALF_LENGTH = 0.07
DRILL_OMEGAS = (0.25 * math.pi, 0.5 * math.pi, math.pi)
"""rad/s about +z (counter-clockwise seen from above)."""
DRILL_SPEED = 0.1
DRILL_CLEARANCE = 0.001
"""m, gap between the cylinder's lowest point and the surface at t = 0."""
DRILL_DURATION = 1.5
DRILL_DT = 0.005
DRILL_TABLE_TIMES = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
QUICK_DRILL_DURATION = 0.3
QUICK_DRILL_DT = 0.01

GUARD_SETTINGS = {
    "no_tension": Guards(no_tension=True),
    "no_fwd_tangential": Guards(no_forward_tangential=True),
    "no_pos_power": Guards(no_positive_power=True),
    "all": Guards.all(),
}

QUICK_SHAPES = ("sphere", "cube_z45", "half_ellipsoid", "quarter_ellipsoid")
MIRROR_ANGLES_DEG = (-90, -60, -30, 0, 30, 60)
QUICK_MIRROR_ANGLES_DEG = (-90, -45, 0)
DEPTH_SHAPES = ("sphere", "cube_y60z45", "quarter_ellipsoid")
DEPTH_ANGLES_DEG = (-90, -45, 0, 90)
CONVERGENCE_SHAPES = ("sphere", "ellipsoid", "cube_y60z45", "quarter_ellipsoid")
CONVERGENCE_ANGLES_DEG = (-90, -45, 0)
CONVERGENCE_SIZES = ("coarse", "default", "fine", "reference")
QUICK_CONVERGENCE_SIZES = ("coarse", "default", "fine")

# --- tolerances: one place ----------------------------------------------------------------------------
SYMMETRY_TOL = 1e-6
"""Mirror residuals, relative to the shape's largest |F|: exact symmetry up to round-off."""
MESH_SYMMETRY_TOL = 2e-3
"""Mirror residuals of the curved mesh shapes (the half and quarter ellipsoids). Their triangulations are not
mirror images of themselves (the diagonals of the quads), and mesh elements gather the pieces of neighbouring
triangles on a grid (:mod:`rft_mujoco.geometry.meshes`), so the mirror image is discretized differently:
measured 5.2e-4 and 1.3e-4 at the default size, against 1e-6 while every triangle was cut on its own."""
LINEARITY_TOL = 1e-9
"""|F(3d) - 2 F(2d) + F(d)| / |F(2d)|: the force is affine in the centre depth once submerged."""
DOUBLING_RANGE = (1.7, 2.3)
"""|F(2d)| / |F(d)| bounds: not exactly 2 because the loaded faces sit above or below the centre."""
CONVERGENCE_TOL = 0.05
"""|F(default) - F(finest)| / |F(finest)| at most this."""
DRILL_SYMMETRY_TOL = 1e-6
"""Drill |F_xy| / max|F| and |M_xy| / max|M| at most this (half-turn symmetry)."""
OVERLAP_TOL = 0.1
"""Largest relative force error of an overlap case at the default element size against the 1 mm
reference (measured worst: the swimmer, 7-8%, whose 7 mm capsules are below the element size)."""
QUICK_OVERLAP_CASES = ("hinge_90", "foot_in_calf", "quadruped_leg")
MESH_FIDELITY_TOL = 1e-5
"""Mesh shapes: |F_mujoco - F_float64| / |F_float64| at most this. MuJoCo stores mesh vertices in float32
(and moves them to the mesh's principal inertia frame), which tilts flat faces by ~1e-8..1e-5 rad; the
force may change by that order, not by a leading/trailing or vertical tie-break flipping."""


# --- shapes -----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Shape:
    """One validation intruder.

    Attributes:
        name: short name (table column).
        description: geometry in words.
        geom: the MJCF ``<geom>`` element in the body frame (body origin = volume centroid).
        asset: MJCF ``<asset>`` children (inline meshes), or "".
        volume: analytic volume in m^3.
        mirror_x: the shape is symmetric under x -> -x (mirror checks apply).
        mirror_y: the shape is symmetric under y -> -y (Fy = 0 for motion in the xz-plane).
        mesh: ``(vertices (n, 3) float m, faces (m, 3) int)`` in the body frame for mesh shapes, else None.
    """

    name: str
    description: str
    geom: str
    asset: str
    volume: float
    mirror_x: bool
    mirror_y: bool
    mesh: tuple[np.ndarray, np.ndarray] | None = None


def _quat(*rotations: tuple[str, float]) -> np.ndarray:
    """Quaternion (w, x, y, z) of rotations about world axes applied in the order given."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, angle in rotations:
        r = np.zeros(4)
        mujoco.mju_axisAngle2Quat(r, np.eye(3)["xyz".index(axis)], angle)
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, r, q)     # later rotation on the left: world-axis composition
        q = out
    return q


def _fmt(values) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(values))


def mesh_facet(size: float) -> float:
    """m, facet edge of the curved validation meshes for element size ``size`` m (half of it)."""
    return 0.5 * size


def validation_shapes(size: float = surface.RESOLUTIONS["default"]) -> dict[str, Shape]:
    """The validation intruders, keyed by name (curved meshes tessellated for element size ``size`` m)."""
    h = CUBE_EDGE / 2
    cube = f'type="box" size="{h} {h} {h}"'
    out = [
        Shape("sphere", "sphere r = 5 cm", f'<geom type="sphere" size="{SPHERE_RADIUS}"/>', "",
              4 / 3 * math.pi * SPHERE_RADIUS**3, True, True),
        Shape("ellipsoid", "ellipsoid semi-axes (7.5, 4.5, 4.5) cm, long axis x",
              f'<geom type="ellipsoid" size="{_fmt(ELLIPSOID_RADII)}"/>', "",
              4 / 3 * math.pi * float(np.prod(ELLIPSOID_RADII)), True, True),
        Shape("cube_z45", "7.5 cm cube, pi/4 about z",
              f'<geom {cube} quat="{_fmt(_quat(("z", math.pi / 4)))}"/>', "", CUBE_EDGE**3, True, True),
        Shape("cube_y60z45", "7.5 cm cube, pi/3 about y then pi/4 about z",
              f'<geom {cube} quat="{_fmt(_quat(("y", math.pi / 3), ("z", math.pi / 4)))}"/>', "",
              CUBE_EDGE**3, False, False),
        Shape("cube_y30z60", "7.5 cm cube, pi/6 about y then pi/3 about z",
              f'<geom {cube} quat="{_fmt(_quat(("y", math.pi / 6), ("z", math.pi / 3)))}"/>', "",
              CUBE_EDGE**3, False, False),
    ]
    prism_volume = mesh_shapes.right_prism_volume(PRISM_LEG, PRISM_LENGTH)
    for orient, words, mx in (("corner", "right angle at lower -x edge, hypotenuse facing +x and up", False),
                              ("keel", "right-angle edge straight down, hypotenuse flat on top", True)):
        v, f = mesh_shapes.right_prism(PRISM_LEG, PRISM_LENGTH, orient)
        out.append(Shape(f"prism_{orient}", f"right-isosceles prism, 7.5 cm legs, 7.5 cm long (y); {words}",
                         f'<geom type="mesh" mesh="prism_{orient}"/>', mesh_shapes.mjcf_mesh(f"prism_{orient}", v, f),
                         prism_volume, mx, True, (v, f)))
    facet = mesh_facet(size)
    v, f = mesh_shapes.half_ellipsoid(ELLIPSOID_RADII, facet)
    out.append(Shape("half_ellipsoid", "ellipsoid (7.5, 4.5, 4.5) cm, part z <= 0 (flat face up)",
                     '<geom type="mesh" mesh="half_ellipsoid"/>', mesh_shapes.mjcf_mesh("half_ellipsoid", v, f),
                     mesh_shapes.half_ellipsoid_volume(ELLIPSOID_RADII), True, True, (v, f)))
    v, f = mesh_shapes.quarter_ellipsoid(ELLIPSOID_RADII, facet)
    out.append(Shape("quarter_ellipsoid", "ellipsoid (7.5, 4.5, 4.5) cm, part z <= 0, x >= 0",
                     '<geom type="mesh" mesh="quarter_ellipsoid"/>',
                     mesh_shapes.mjcf_mesh("quarter_ellipsoid", v, f),
                     mesh_shapes.quarter_ellipsoid_volume(ELLIPSOID_RADII), False, True, (v, f)))
    return {s.name: s for s in out}


def build_model(shape: Shape, centre=(0.0, 0.0, -CENTRE_DEPTH)) -> mujoco.MjModel:
    """A model with one free body :data:`BODY` carrying ``shape``, its origin at ``centre`` (3,) m."""
    asset = f"<asset>{shape.asset}</asset>" if shape.asset else ""
    xml = (f'<mujoco model="validation_{shape.name}"><option timestep="0.001"/>{asset}<worldbody>'
           f'<body name="{BODY}" pos="{_fmt(centre)}"><freejoint/>{shape.geom}</body>'
           "</worldbody></mujoco>")
    return mujoco.MjModel.from_xml_string(xml)


def direction(theta_deg: float) -> np.ndarray:
    """(3,) unit motion direction ``(cos theta, 0, sin theta)`` for ``theta_deg`` from horizontal +x."""
    t = math.radians(theta_deg)
    d = np.array([math.cos(t), 0.0, math.sin(t)])
    d[np.abs(d) < 1e-12] = 0.0      # exact axes at multiples of 90 deg (cos(pi/2) is 6e-17, not 0)
    return d


def sweep(model, angles_deg, *, size: float, guards: Guards = PUBLISHED, depth: float = CENTRE_DEPTH,
          media: Media = MPM_VALIDATION) -> tuple[np.ndarray, np.ndarray]:
    """Mean sand force (D, 3) N and torque about the COM (D, 3) N m for each direction (D,) in degrees.

    Each direction is a :func:`kinematic_rollout` of :data:`SAMPLES` samples over :data:`WINDOW` s whose
    mean position is the centroid ``depth`` m below the surface (published law unless ``guards``).
    """
    angles = np.atleast_1d(np.asarray(angles_deg, dtype=float))
    data = mujoco.MjData(model)
    force = np.zeros((angles.size, 3))
    torque = np.zeros((angles.size, 3))
    with attach(model, media, bodies=[BODY], surface_height=0.0, resolution=size, guards=guards,
                stabilize=False, passive=False) as sand:
        for i, a in enumerate(angles):
            vel = SPEED * direction(a)
            mujoco.mj_resetData(model, data)
            data.qpos[:3] = np.array([0.0, 0.0, -depth]) - 0.5 * WINDOW * vel
            r = kinematic_rollout(sand, data, BODY, vel, duration=WINDOW, dt=WINDOW / (SAMPLES - 1))
            force[i] = r.force.mean(0)
            torque[i] = r.torque.mean(0)
    return force, torque


def drill_model() -> mujoco.MjModel:
    """The cylinder drill: axis along x, lowest point :data:`DRILL_CLEARANCE` above the surface."""
    q = _quat(("y", math.pi / 2))
    shape = Shape("drill", "cylinder 50 mm x 140 mm, axis x",
                  f'<geom type="cylinder" size="{DRILL_RADIUS} {DRILL_HALF_LENGTH}" quat="{_fmt(q)}"/>', "",
                  math.pi * DRILL_RADIUS**2 * 2 * DRILL_HALF_LENGTH, True, True)
    return build_model(shape, centre=(0.0, 0.0, DRILL_RADIUS + DRILL_CLEARANCE))


def drill_rollout(omega: float, *, size: float, duration: float = DRILL_DURATION, dt: float = DRILL_DT,
                  media: Media = DEM_GLASS_BEADS, guards: Guards = PUBLISHED) -> Rollout:
    """The cylinder drill at ``omega`` rad/s about +z descending at :data:`DRILL_SPEED`."""
    model = drill_model()
    data = mujoco.MjData(model)
    with attach(model, media, bodies=[BODY], surface_height=0.0, resolution=size, guards=guards,
                stabilize=False, passive=False) as sand:
        return kinematic_rollout(sand, data, BODY, (0.0, 0.0, -DRILL_SPEED), (0.0, 0.0, float(omega)),
                                 duration=duration, dt=dt)


# --- results ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Check:
    """One sanity check: ``value`` against ``limit`` (``passed`` says whether it holds)."""

    name: str
    value: float
    limit: str
    passed: bool


@dataclasses.dataclass
class Results:
    """Everything :func:`run` computed.

    Attributes:
        angles_deg: (D,) motion directions.
        shapes: the shapes run, in order.
        force, torque: shape name -> (D, 3) N / N m, published law.
        guarded: shape name -> guard name -> (D, 3) N.
        guard_change: shape name -> guard name -> (mean relative change of |F|, max |dF| / |F|).
        drill: omega (rad/s) -> Rollout.
        convergence: shape -> size name -> (A, 3) N over CONVERGENCE_ANGLES_DEG.
        depth: shape -> (3 depths, A, 3) N over DEPTH_ANGLES_DEG.
        checks: the sanity checks.
        overlap: rows of :func:`rft_mujoco.studies.overlap.run` (overlapping geoms against the brute force).
        files: files written.
        seconds: wall time of the run.
    """

    angles_deg: np.ndarray
    shapes: dict[str, Shape]
    force: dict[str, np.ndarray]
    torque: dict[str, np.ndarray]
    guarded: dict[str, dict[str, np.ndarray]]
    guard_change: dict[str, dict[str, tuple[float, float]]]
    drill: dict[float, Rollout]
    convergence: dict[str, dict[str, np.ndarray]]
    depth: dict[str, np.ndarray]
    checks: list[Check]
    overlap: list = dataclasses.field(default_factory=list)
    files: list[Path] = dataclasses.field(default_factory=list)
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)


def guard_change(published: np.ndarray, guarded: np.ndarray) -> tuple[float, float]:
    """(mean over directions of (|F_g| - |F_p|) / |F_p|, max over directions of |F_g - F_p| / |F_p|)
    for (D, 3) forces; directions with F_p = 0 are skipped."""
    norm = np.linalg.norm(published, axis=1)
    ok = norm > 0
    rel = (np.linalg.norm(guarded[ok], axis=1) - norm[ok]) / norm[ok]
    vec = np.linalg.norm(guarded[ok] - published[ok], axis=1) / norm[ok]
    return (float(rel.mean()), float(vec.max())) if ok.any() else (0.0, 0.0)


def mirror_residual(model, angles_deg, *, size: float, check_y: bool) -> float:
    """Largest of ``|Fx(t) + Fx(180 - t)|``, ``|Fz(t) - Fz(180 - t)|`` (and ``|Fy|`` if ``check_y``)
    over ``angles_deg``, relative to the largest |F|, for a shape symmetric under x -> -x."""
    angles = np.asarray(angles_deg, dtype=float)
    f, _ = sweep(model, angles, size=size)
    g, _ = sweep(model, 180.0 - angles, size=size)
    scale = max(np.linalg.norm(f, axis=1).max(), np.linalg.norm(g, axis=1).max())
    res = [np.abs(f[:, 0] + g[:, 0]).max(), np.abs(f[:, 2] - g[:, 2]).max()]
    if check_y:
        res += [np.abs(f[:, 1]).max(), np.abs(g[:, 1]).max()]
    return float(max(res) / scale)


def mesh_forces(shape: Shape, angles_deg, *, size: float, depth: float = CENTRE_DEPTH,
                media: Media = MPM_VALIDATION, guards: Guards = PUBLISHED, model=None) -> np.ndarray:
    """(D, 3) N: the force on a mesh shape's float64 mesh (:func:`rft_mujoco.geometry.surface.mesh`) at the centre
    depth, summed with :func:`rft_mujoco.element_forces` (no MuJoCo): the reference for the coupling.

    ``model``: the shape's MjModel (:func:`build_model`); when given, the float64 mesh is cut into elements in
    the frame MuJoCo moved the mesh to (``mesh_pos``, ``mesh_quat``: its inertia frame), as the coupling cuts
    MuJoCo's float32 copy, and moved back: mesh elements come from a grid in the mesh's frame, so only then
    do the two differ by the float32 round-off alone."""
    if shape.mesh is None:
        raise ValueError(f"shape {shape.name!r} is not a mesh shape")
    v, f = shape.mesh
    if model is None:
        el = surface.mesh(v, f, size, name=shape.name)
    else:
        if model.nmesh != 1:
            raise ValueError(f"model must hold the shape's one mesh, got {model.nmesh} meshes")
        m = 0
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, np.asarray(model.mesh_quat[m], dtype=float))
        rot = rot.reshape(3, 3)
        pos = np.asarray(model.mesh_pos[m], dtype=float)
        el = surface.mesh((np.asarray(v, dtype=float) - pos) @ rot, f, size, name=shape.name).transformed(pos, rot)
    pos = el.centroids + np.array([0.0, 0.0, -depth])
    out = []
    for a in np.atleast_1d(np.asarray(angles_deg, dtype=float)):
        vel = np.broadcast_to(SPEED * direction(a), pos.shape)
        out.append(element_forces(pos, el.normals, el.areas, vel, media, 0.0, (0.0, 0.0, -9.81),
                                  guards=guards).sum(0))
    return np.array(out)


def depth_forces(model, angles_deg, *, size: float, depths) -> np.ndarray:
    """(len(depths), A, 3) N: forces at each centre depth (m) for each direction."""
    return np.stack([sweep(model, angles_deg, size=size, depth=d)[0] for d in depths])


# --- the run ----------------------------------------------------------------------------------------
class Log:
    """Prints lines and keeps them for summary.txt."""

    def __init__(self, stream=None) -> None:
        self.lines: list[str] = []
        self.stream = stream if stream is not None else sys.stdout

    def __call__(self, line: str = "") -> None:
        self.lines.append(line)
        print(line, file=self.stream, flush=True)

    def progress(self, line: str) -> None:
        print(f"[validate] {line}", file=self.stream, flush=True)


