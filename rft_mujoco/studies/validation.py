"""The paper's validation intrusions as scripted rollouts: ``python -m rft_mujoco validate``.

Reproduces the validation set of Agarwal, Goldman & Kamrin, PNAS 2023 (see the project's
``3d-rft.md``, "The paper's own validation cases") with :func:`rft_mujoco.coupling.rollout.kinematic_rollout`
and the published law (``stabilize=False, passive=False``), prints tables and writes CSVs and plots to
``out/validation/`` (``--out``).

Directions. Each shape is centred (its volume centroid, which is also its body origin and COM)
:data:`CENTRE_DEPTH` below a flat free surface at z = 0 and moved at :data:`SPEED` along
``d(theta) = (cos theta, 0, sin theta)``: ``theta`` in degrees from the horizontal +x axis, positive
upward, so -90 is straight down, 0 is horizontal along +x and +90 straight up. Each direction is a short
rollout (:data:`SAMPLES` samples over :data:`WINDOW` s) centred on the centre depth; the table gives the
mean force (N, world frame; Fz > 0 is lift). Medium :data:`rft_mujoco.MPM_VALIDATION`
(rho_c = 3000 kg/m^3, mu_int = mu_surf = 0.4).

Shapes (:func:`validation_shapes`; lengths in cm in the names' descriptions):

* ``sphere``: radius 5 cm.
* ``ellipsoid``: semi-axes (7.5, 4.5, 4.5) cm, long axis along x (in the plane of motion).
* ``cube_z45``, ``cube_y60z45``, ``cube_y30z60``: 7.5 cm cubes rotated pi/4 about z; pi/3 about y then
  pi/4 about z (``R = Rz Ry``, world axes); pi/6 about y then pi/3 about z.
* ``prism_corner``, ``prism_keel``: right-isosceles triangular prisms, 7.5 cm legs in the xz-plane, 7.5 cm
  long along y; "corner": right angle at the lower -x edge (flat bottom, vertical back face at -x,
  hypotenuse facing +x and up); "keel": the right-angle edge straight down (legs at +-45 deg, hypotenuse
  the horizontal top).
* ``half_ellipsoid``: the part z <= 0 of the ellipsoid above (dome down, flat face up).
* ``quarter_ellipsoid``: the part z <= 0, x >= 0 (flat faces up and towards -x).

Prisms and partial ellipsoids are closed triangle meshes from :mod:`rft_mujoco.studies.shapes`, inline in the
MJCF; curved meshes use facets of half the element size (volume within ~1% of the analytic value at
the coarse size, 0.2% at the default).

Cylinder drill: a 50 mm diameter, 140 mm long cylinder, axis along x, spun about the vertical axis
through its centre at each of :data:`DRILL_OMEGAS` (counter-clockwise seen from above) while descending
at 0.1 m/s from 1 mm above the surface, for 1.5 s, in :data:`rft_mujoco.DEM_GLASS_BEADS`. The paper's
bunny drill needs the Stanford-bunny mesh, which this project does not ship: it is skipped.

Artefact guards: for every shape, the relative change of |F| (mean over directions, and the largest
relative change of the force vector) with each of ``Guards(no_tension=True)``,
``Guards(no_forward_tangential=True)``, ``Guards(no_positive_power=True)`` and ``Guards.all()``
against the published law.

Sanity checks (printed, PASS/FAIL; the exit status is 1 if one fails): mirror symmetry of the
x-symmetric shapes (``Fx(theta) = -Fx(180 - theta)``, ``Fz(theta) = Fz(180 - theta)``, ``Fy = 0``), the
sphere's zero side force going straight down, hydrostatic scaling (force exactly affine in the centre
depth once submerged, so doubling the centre depth roughly doubles it), convergence with the element
size, the drill's vanishing horizontal force and tilting moment (the cylinder is symmetric under a
half turn about the vertical axis), and "mesh fidelity": each mesh shape's coupling force (MuJoCo stores
mesh vertices in float32, moved to the mesh's inertia frame) against its float64 mesh summed directly
with :func:`rft_mujoco.element_forces`. Faces exactly parallel to the motion (n.v = 0) and exactly
vertical faces are ties of the law; the library's tie tolerances must absorb float32 round-off for
these to agree.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import sys
import time
import warnings
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
LINEARITY_TOL = 1e-9
"""|F(3d) - 2 F(2d) + F(d)| / |F(2d)|: the force is affine in the centre depth once submerged."""
DOUBLING_RANGE = (1.7, 2.3)
"""|F(2d)| / |F(d)| bounds: not exactly 2 because the loaded faces sit above or below the centre."""
CONVERGENCE_TOL = 0.05
"""|F(default) - F(finest)| / |F(finest)| at most this."""
DRILL_SYMMETRY_TOL = 1e-6
"""Drill |F_xy| / max|F| and |M_xy| / max|M| at most this (half-turn symmetry)."""
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
                media: Media = MPM_VALIDATION, guards: Guards = PUBLISHED) -> np.ndarray:
    """(D, 3) N: the force on a mesh shape's float64 mesh (:func:`rft_mujoco.geometry.surface.mesh`) at the centre
    depth, summed with :func:`rft_mujoco.element_forces` (no MuJoCo): the reference for the coupling."""
    if shape.mesh is None:
        raise ValueError(f"shape {shape.name!r} is not a mesh shape")
    el = surface.mesh(*shape.mesh, size, name=shape.name)
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
class _Log:
    """Prints lines and keeps them for summary.txt."""

    def __init__(self, stream=None) -> None:
        self.lines: list[str] = []
        self.stream = stream if stream is not None else sys.stdout

    def __call__(self, line: str = "") -> None:
        self.lines.append(line)
        print(line, file=self.stream, flush=True)

    def progress(self, line: str) -> None:
        print(f"[validate] {line}", file=self.stream, flush=True)


def _table(headers, rows, widths=None) -> list[str]:
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    w = widths or [max(len(r[i]) for r in cells) for i in range(len(headers))]
    line = lambda r: "  ".join(c.rjust(w[i]) if i else c.ljust(w[i]) for i, c in enumerate(r))  # noqa: E731
    return [line(cells[0]), "  ".join("-" * x for x in w)] + [line(r) for r in cells[1:]]


def run(*, quick: bool = False, resolution: str | float = "default", out: str | Path = "out/validation",
        plots: bool = True, log: _Log | None = None) -> Results:
    """Run the validation set (see the module docstring); write CSVs, summary and plots under ``out``.

    Warnings raised on the way (e.g. the coupling's validity monitor) are collected and listed once each
    at the end of the printed report instead of interleaving with the progress lines.
    """
    log = log or _Log()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = _run(quick, resolution, Path(out), plots, log)
    seen = []
    for w in caught:
        text = f"{w.category.__name__}: {w.message}"
        if text not in seen:
            seen.append(text)
    if seen:
        log(f"warnings raised during the run ({len(seen)} distinct):")
        for text in seen:
            log(f"  {text}")
    return _finish(res, quick, resolution, Path(out), log)


def _run(quick: bool, resolution: str | float, out: Path, plots: bool, log: _Log) -> Results:
    t_start = time.perf_counter()
    size = surface.element_size(resolution)
    out.mkdir(parents=True, exist_ok=True)
    angles = np.asarray(QUICK_DIRECTIONS_DEG if quick else DIRECTIONS_DEG, dtype=float)
    all_shapes = validation_shapes(size)
    names = QUICK_SHAPES if quick else tuple(all_shapes)
    shapes = {n: all_shapes[n] for n in names}
    models = {}
    force, torque, guarded, change = {}, {}, {}, {}
    for name, shape in shapes.items():
        t0 = time.perf_counter()
        model = models[name] = build_model(shape)
        n_el = len(surface.body_elements(model, model.body(BODY).id, size))
        force[name], torque[name] = sweep(model, angles, size=size)
        guarded[name] = {g: sweep(model, angles, size=size, guards=gd)[0] for g, gd in GUARD_SETTINGS.items()}
        change[name] = {g: guard_change(force[name], f) for g, f in guarded[name].items()}
        log.progress(f"{name:<18} {n_el:6d} elements, {angles.size} directions x {1 + len(GUARD_SETTINGS)} "
                     f"laws: {time.perf_counter() - t0:.1f} s")

    checks: list[Check] = []
    # Sphere straight down: no side force.
    if "sphere" in shapes:
        f = sweep(models["sphere"], [-90.0], size=size)[0][0]
        val = float(np.hypot(f[0], f[1]) / np.linalg.norm(f))
        checks.append(Check("sphere straight down: |F_xy| / |F|", val, f"<= {SYMMETRY_TOL:g}",
                            val <= SYMMETRY_TOL))
    t0 = time.perf_counter()
    mirror_angles = QUICK_MIRROR_ANGLES_DEG if quick else MIRROR_ANGLES_DEG
    for name, shape in shapes.items():
        if shape.mirror_x:
            val = mirror_residual(models[name], mirror_angles, size=size, check_y=shape.mirror_y)
            checks.append(Check(f"{name} mirror: Fx(t)=-Fx(180-t), Fz(t)=Fz(180-t)"
                                + (", Fy=0" if shape.mirror_y else ""), val, f"<= {SYMMETRY_TOL:g}",
                                val <= SYMMETRY_TOL))
        elif shape.mirror_y:
            val = float(np.abs(force[name][:, 1]).max() / np.linalg.norm(force[name], axis=1).max())
            checks.append(Check(f"{name} mirror y: Fy = 0", val, f"<= {SYMMETRY_TOL:g}", val <= SYMMETRY_TOL))
    log.progress(f"mirror checks: {time.perf_counter() - t0:.1f} s")

    # Mesh shapes: the coupling (MuJoCo's float32 mesh) against the float64 mesh summed directly.
    for name, shape in shapes.items():
        if shape.mesh is not None:
            ref = mesh_forces(shape, angles, size=size)
            err = np.linalg.norm(force[name] - ref, axis=1) / np.linalg.norm(ref, axis=1)
            worst = int(np.argmax(err))
            checks.append(Check(f"mesh fidelity {name}: |F_mujoco - F_float64|/|F_float64| (worst at "
                                f"{angles[worst]:+.0f} deg)", float(err[worst]), f"<= {MESH_FIDELITY_TOL:g}",
                                bool(err[worst] <= MESH_FIDELITY_TOL)))

    # Hydrostatic scaling.
    t0 = time.perf_counter()
    depths = (CENTRE_DEPTH, 2 * CENTRE_DEPTH, 3 * CENTRE_DEPTH)
    depth_res = {}
    for name in [n for n in DEPTH_SHAPES if not quick or n in shapes]:
        model = models.get(name) or build_model(all_shapes[name])
        fd = depth_res[name] = depth_forces(model, DEPTH_ANGLES_DEG, size=size, depths=depths)
        ratio = np.linalg.norm(fd[1], axis=1) / np.linalg.norm(fd[0], axis=1)
        lin = float((np.linalg.norm(fd[2] - 2 * fd[1] + fd[0], axis=1) / np.linalg.norm(fd[1], axis=1)).max())
        ok = bool(np.all((ratio >= DOUBLING_RANGE[0]) & (ratio <= DOUBLING_RANGE[1])))
        checks.append(Check(f"{name} |F(2d)|/|F(d)|, d = {CENTRE_DEPTH} m, dirs {list(DEPTH_ANGLES_DEG)}: "
                            + " ".join(f"{r:.3f}" for r in ratio), float(ratio.min()),
                            f"in [{DOUBLING_RANGE[0]}, {DOUBLING_RANGE[1]}]", ok))
        checks.append(Check(f"{name} affine in depth: |F(3d)-2F(2d)+F(d)|/|F(2d)|", lin,
                            f"<= {LINEARITY_TOL:g}", lin <= LINEARITY_TOL))
    log.progress(f"depth scaling: {time.perf_counter() - t0:.1f} s")

    # Convergence with element size.
    t0 = time.perf_counter()
    conv = {}
    sizes = QUICK_CONVERGENCE_SIZES if quick else CONVERGENCE_SIZES
    conv_shapes = [n for n in CONVERGENCE_SHAPES if not quick or n in shapes]
    per_size_shapes = {s: validation_shapes(surface.RESOLUTIONS[s]) for s in sizes}
    for name in conv_shapes:
        conv[name] = {s: sweep(build_model(per_size_shapes[s][name]), CONVERGENCE_ANGLES_DEG,
                               size=surface.RESOLUTIONS[s])[0] for s in sizes}
        ref = conv[name][sizes[-1]]
        err = float((np.linalg.norm(conv[name]["default"] - ref, axis=1) / np.linalg.norm(ref, axis=1)).max())
        checks.append(Check(f"{name} convergence: |F(default) - F({sizes[-1]})| / |F({sizes[-1]})|", err,
                            f"<= {CONVERGENCE_TOL:g}", err <= CONVERGENCE_TOL))
    log.progress(f"convergence ({', '.join(sizes)}): {time.perf_counter() - t0:.1f} s")

    # Cylinder drill.
    drill = {}
    for omega in DRILL_OMEGAS:
        t0 = time.perf_counter()
        drill[omega] = drill_rollout(omega, size=size,
                                     duration=QUICK_DRILL_DURATION if quick else DRILL_DURATION,
                                     dt=QUICK_DRILL_DT if quick else DRILL_DT)
        r = drill[omega]
        fxy = float(np.hypot(r.force[:, 0], r.force[:, 1]).max() / max(np.abs(r.force).max(), 1e-300))
        mxy = float(np.hypot(r.torque[:, 0], r.torque[:, 1]).max() / max(np.abs(r.torque).max(), 1e-300))
        val = max(fxy, mxy)
        checks.append(Check(f"drill omega = {omega / math.pi:g} pi: max |F_xy|/max|F|, |M_xy|/max|M|", val,
                            f"<= {DRILL_SYMMETRY_TOL:g}", val <= DRILL_SYMMETRY_TOL))
        log.progress(f"drill omega = {omega / math.pi:g} pi rad/s: {r.time.size} samples, "
                     f"{time.perf_counter() - t0:.1f} s")

    res = Results(angles, shapes, force, torque, guarded, change, drill, conv, depth_res, checks)
    _report(res, log, size, quick)
    res.files += _write_csv(res, out)
    if plots:
        res.files += _plots(res, out)
    res.seconds = time.perf_counter() - t_start
    return res


def _finish(res: Results, quick: bool, resolution: str | float, out: Path, log: _Log) -> Results:
    size = surface.element_size(resolution)
    failed = [c for c in res.checks if not c.passed]
    log(f"run time {res.seconds:.1f} s; checks: {len(res.checks) - len(failed)} PASS, {len(failed)} FAIL")
    summary = out / "summary.txt"
    summary.write_text("\n".join(log.lines) + "\n")
    config = out / "config.json"
    config.write_text(json.dumps({"quick": quick, "resolution": resolution, "element_size_m": size,
                                  "centre_depth_m": CENTRE_DEPTH, "speed_m_s": SPEED, "samples": SAMPLES,
                                  "window_s": WINDOW, "angles_deg": res.angles_deg.tolist(),
                                  "shapes": {n: s.description for n, s in res.shapes.items()},
                                  "media": MPM_VALIDATION.name, "drill_media": DEM_GLASS_BEADS.name,
                                  "seconds": res.seconds}, indent=2))
    res.files += [summary, config]
    return res


# --- output -----------------------------------------------------------------------------------------
def _report(res: Results, log: _Log, size: float, quick: bool) -> None:
    m = MPM_VALIDATION
    log(f"3D-RFT validation intrusions (Agarwal et al. 2023){' [quick]' if quick else ''}: element size "
        f"{size * 1000:g} mm, published law")
    log(f"media {m.name}: rho_c {m.rho_c:g} kg/m^3, mu_int {m.mu_int:g}, mu_surf {m.mu_surf:g}, "
        f"xi_n {m.xi_n:.4g} N/m^3; centroid {CENTRE_DEPTH * 100:g} cm deep, {SPEED} m/s along "
        "(cos t, 0, sin t), t from horizontal +x, -90 = straight down")
    log()
    for name, s in res.shapes.items():
        log(f"  {name:<18} {s.description}")
    names = list(res.shapes)
    for k, label in ((0, "Fx"), (2, "Fz")):
        log()
        log(f"{label} (N), mean of {SAMPLES} samples over {WINDOW * 1000:g} ms")
        rows = [[f"{a:+.0f}"] + [f"{res.force[n][i, k]:.1f}" for n in names] for i, a in enumerate(res.angles_deg)]
        for line in _table(["deg"] + names, rows):
            log(line)
    log()
    log("rows at exactly 0 and +-90 deg include faces with n.v = 0 (flat tops and bottoms sliding sideways, "
        "vertical sides moving vertically), which the library counts as leading (law.LEADING_TOL)")
    log()
    log("artefact guards vs published: mean over directions of (|F_g| - |F|)/|F| in %, "
        "[max over directions of |F_g - F|/|F| in % @ its direction]")
    rows = []
    for n in names:
        row = [n]
        for g in GUARD_SETTINGS:
            mean, mx = res.guard_change[n][g]
            p, q = res.force[n], res.guarded[n][g]
            worst = res.angles_deg[int(np.argmax(np.linalg.norm(q - p, axis=1) / np.linalg.norm(p, axis=1)))]
            row.append(f"{100 * mean:+.2f} [{100 * mx:.1f}" + (f" @{worst:+.0f}]" if mx > 0 else "]"))
        rows.append(row)
    for line in _table(["shape"] + list(GUARD_SETTINGS), rows):
        log(line)
    if res.convergence:
        log()
        sizes = list(next(iter(res.convergence.values())))
        log(f"convergence: |F| (N) at directions {list(CONVERGENCE_ANGLES_DEG)} deg for element sizes "
            + ", ".join(f"{s} {surface.RESOLUTIONS[s] * 1000:g} mm" for s in sizes)
            + f" (curved meshes: facets of half the size); [max |F - F_{sizes[-1]}|/|F_{sizes[-1]}| %]")
        rows = []
        for n, per in res.convergence.items():
            ref = per[sizes[-1]]
            for s in sizes:
                err = np.linalg.norm(per[s] - ref, axis=1) / np.linalg.norm(ref, axis=1)
                rows.append([n, s] + [f"{x:.1f}" for x in np.linalg.norm(per[s], axis=1)]
                            + [f"{100 * err.max():.2f}"])
        for line in _table(["shape", "size"] + [f"{a:+d}" for a in CONVERGENCE_ANGLES_DEG] + ["err %"], rows):
            log(line)
    log()
    d = DEM_GLASS_BEADS
    log(f"cylinder drill: 50 mm x 140 mm cylinder, axis horizontal (x), spun about +z, {DRILL_SPEED} m/s down "
        f"from {DRILL_CLEARANCE * 1000:g} mm above the surface; media {d.name} (xi_n {d.xi_n:.4g} N/m^3)")
    rows = []
    for omega, r in res.drill.items():
        for t in DRILL_TABLE_TIMES:
            i = int(np.argmin(np.abs(r.time - t)))
            if abs(r.time[i] - t) > 1e-9:
                continue
            bottom = -(r.position[i, 2] - DRILL_RADIUS)
            rows.append([f"{omega / math.pi:g} pi", f"{t:.2f}", f"{100 * bottom:.1f}", f"{r.force[i, 2]:.2f}",
                         f"{np.hypot(r.force[i, 0], r.force[i, 1]):.2e}", f"{r.torque[i, 2]:.4f}",
                         f"{np.hypot(r.torque[i, 0], r.torque[i, 1]):.2e}"])
    for line in _table(["omega rad/s", "t s", "bottom cm", "Fz N", "|Fxy| N", "Mz N m", "|Mxy| N m"], rows):
        log(line)
    log("bunny drill: skipped (needs the Stanford-bunny mesh, which this project does not ship)")
    log()
    log("sanity checks")
    for c in res.checks:
        log(f"  {'PASS' if c.passed else 'FAIL'}  {c.name}: {c.value:.3g} ({c.limit})")


def _write_csv(res: Results, out: Path) -> list[Path]:
    files = []
    p = out / "directions.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["shape", "law", "theta_deg", "Fx_N", "Fy_N", "Fz_N", "Mx_Nm", "My_Nm", "Mz_Nm"])
        for n in res.shapes:
            for i, a in enumerate(res.angles_deg):
                w.writerow([n, "published", a, *res.force[n][i], *res.torque[n][i]])
            for g, f in res.guarded[n].items():
                for i, a in enumerate(res.angles_deg):
                    w.writerow([n, g, a, *f[i], "", "", ""])
    files.append(p)
    p = out / "guards.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["shape", "guard", "mean_rel_change_absF", "max_rel_change_F"])
        for n, per in res.guard_change.items():
            for g, (mean, mx) in per.items():
                w.writerow([n, g, mean, mx])
    files.append(p)
    p = out / "drill.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["omega_rad_s", "t_s", "z_com_m", "Fx_N", "Fy_N", "Fz_N", "Mx_Nm", "My_Nm", "Mz_Nm"])
        for omega, r in res.drill.items():
            for i in range(r.time.size):
                w.writerow([omega, r.time[i], r.position[i, 2], *r.force[i], *r.torque[i]])
    files.append(p)
    p = out / "checks.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["check", "value", "limit", "passed"])
        for c in res.checks:
            w.writerow([c.name, c.value, c.limit, c.passed])
    files.append(p)
    return files


LOG_FLOOR = 1e-18
"""Smallest value drawn on the drill plot's log axis (exact zeros before contact sit on it)."""


def _plots(res: Results, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    names = list(res.shapes)
    ncol = 3
    nrow = -(-len(names) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False, sharex=True)
    for ax, n in zip(axes.flat, names):
        f, g = res.force[n], res.guarded[n]["all"]
        ax.plot(res.angles_deg, f[:, 0], "o-", color="C0", label="Fx")
        ax.plot(res.angles_deg, f[:, 2], "s-", color="C3", label="Fz")
        ax.plot(res.angles_deg, g[:, 0], ":", color="C0", label="Fx, all guards")
        ax.plot(res.angles_deg, g[:, 2], ":", color="C3", label="Fz, all guards")
        ax.axhline(0, color="0.7", lw=0.5)
        ax.set_title(n, fontsize=10)
        ax.set_xticks(np.arange(-90, 91, 45))
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("direction (deg from +x, -90 = down)")
    for ax in axes[:, 0]:
        ax.set_ylabel("force (N)")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"3D-RFT, {MPM_VALIDATION.name}, centroid {CENTRE_DEPTH * 100:g} cm deep, {SPEED} m/s")
    fig.tight_layout()
    p = out / "directions.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharex=True)
    for omega, r in res.drill.items():
        label = f"omega = {omega / math.pi:g} pi rad/s"
        line, = axes[0].plot(r.time, r.force[:, 2], label=label)
        axes[1].plot(r.time, r.torque[:, 2], color=line.get_color())
        axes[2].semilogy(r.time, np.maximum(np.hypot(r.force[:, 0], r.force[:, 1]), LOG_FLOOR), "-",
                         color=line.get_color(), lw=0.8)
        axes[2].semilogy(r.time, np.maximum(np.hypot(r.torque[:, 0], r.torque[:, 1]), LOG_FLOOR), ":",
                         color=line.get_color(), lw=0.8)
    axes[0].set_ylabel("Fz (N)")
    axes[1].set_ylabel("Mz (N m)")
    axes[2].set_ylabel("|F_xy| (N, solid), |M_xy| (N m, dotted)")
    axes[2].set_title("zero up to round-off (half-turn symmetry)", fontsize=9)
    axes[2].set_ylim(LOG_FLOOR / 2, 1.0)
    for ax in axes:
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"cylinder drill (50 x 140 mm, axis horizontal), {DRILL_SPEED} m/s down from the surface, "
                 f"{DEM_GLASS_BEADS.name}")
    fig.tight_layout()
    p = out / "drill.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(names)), 3.8))
    width = 0.8 / len(GUARD_SETTINGS)
    x = np.arange(len(names))
    for j, g in enumerate(GUARD_SETTINGS):
        ax.bar(x + (j - 1.5) * width, [100 * res.guard_change[n][g][0] for n in names], width, label=g)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("mean change of |F| (%)")
    ax.axhline(0, color="k", lw=0.5)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title("artefact guards vs the published law")
    fig.tight_layout()
    p = out / "guards.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    if res.convergence:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        for n, per in res.convergence.items():
            sizes = list(per)
            ref = per[sizes[-1]]
            h = [surface.RESOLUTIONS[s] for s in sizes[:-1]]
            err = [np.max(np.linalg.norm(per[s] - ref, axis=1) / np.linalg.norm(ref, axis=1)) for s in sizes[:-1]]
            ax.loglog(h, np.maximum(err, 1e-16), "o-", label=n)
        ax.set_xlabel("element size (m)")
        ax.set_ylabel(f"max |F - F_{sizes[-1]}| / |F_{sizes[-1]}|")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        fig.tight_layout()
        p = out / "convergence.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(p)
    return files


def main(argv: list[str] | None = None, command: str = "validate") -> int:
    """CLI entry: ``python -m rft_mujoco validate [--quick] [--resolution R] [--out DIR] [--no-plots]``."""
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="The 3D-RFT paper's validation intrusions: force tables, "
                                                 "sanity checks and plots.")
    parser.add_argument("--quick", action="store_true",
                        help=f"{len(QUICK_SHAPES)} shapes, {len(QUICK_DIRECTIONS_DEG)} directions, short drill")
    parser.add_argument("--resolution", default="default",
                        help=f"element size: {', '.join(f'{k} ({v} m)' for k, v in surface.RESOLUTIONS.items())} "
                             "or a size in m (default: default)")
    parser.add_argument("--out", default="out/validation", help="output folder (default: out/validation)")
    parser.add_argument("--no-plots", action="store_true", help="tables and CSVs only")
    args = parser.parse_args(argv)
    resolution: str | float = args.resolution
    if resolution not in surface.RESOLUTIONS:
        try:
            resolution = float(resolution)
        except ValueError:
            parser.error(f"--resolution must be one of {sorted(surface.RESOLUTIONS)} or a size in m, "
                         f"got {args.resolution!r}")
    try:
        surface.element_size(resolution)
    except ValueError as exc:
        parser.error(str(exc))
    res = run(quick=args.quick, resolution=resolution, out=args.out, plots=not args.no_plots)
    print(f"wrote {len(res.files)} files to {Path(args.out)}: " + ", ".join(p.name for p in res.files))
    return 0 if res.passed else 1
