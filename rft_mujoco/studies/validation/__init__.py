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
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

from rft_mujoco.geometry import surface
from rft_mujoco.physics.media import DEM_GLASS_BEADS, MPM_VALIDATION
from rft_mujoco.studies import overlap
from rft_mujoco.studies.validation import report
from rft_mujoco.studies.validation.protocol import *  # noqa: F401,F403  (the protocol's names, public here)
from rft_mujoco.studies.validation.protocol import (CENTRE_DEPTH, CONVERGENCE_ANGLES_DEG, CONVERGENCE_SHAPES,
                                                    CONVERGENCE_SIZES, CONVERGENCE_TOL, DEPTH_ANGLES_DEG,
                                                    DEPTH_SHAPES, DIRECTIONS_DEG, DOUBLING_RANGE, DRILL_DT,
                                                    DRILL_DURATION, DRILL_OMEGAS, DRILL_SYMMETRY_TOL,
                                                    GUARD_SETTINGS, LINEARITY_TOL, MESH_FIDELITY_TOL,
                                                    MIRROR_ANGLES_DEG, OVERLAP_TOL, QUICK_CONVERGENCE_SIZES,
                                                    QUICK_DIRECTIONS_DEG, QUICK_DRILL_DT, QUICK_DRILL_DURATION,
                                                    QUICK_MIRROR_ANGLES_DEG, QUICK_OVERLAP_CASES, QUICK_SHAPES,
                                                    SAMPLES, SPEED, SYMMETRY_TOL, MESH_SYMMETRY_TOL, WINDOW, BODY,
                                                    Check, Log,
                                                    Results, build_model, depth_forces, drill_rollout,
                                                    guard_change, mesh_forces, mirror_residual, sweep,
                                                    validation_shapes)

def run(*, quick: bool = False, resolution: str | float = "default", out: str | Path = "out/validation",
        plots: bool = True, log: Log | None = None) -> Results:
    """Run the validation set (see the module docstring); write CSVs, summary and plots under ``out``.

    Warnings raised on the way (e.g. the coupling's validity monitor) are collected and listed once each
    at the end of the printed report instead of interleaving with the progress lines.
    """
    log = log or Log()
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


def _run(quick: bool, resolution: str | float, out: Path, plots: bool, log: Log) -> Results:
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
        limit = MESH_SYMMETRY_TOL if name.endswith("ellipsoid") and shape.mesh is not None else SYMMETRY_TOL
        if shape.mirror_x:
            val = mirror_residual(models[name], mirror_angles, size=size, check_y=shape.mirror_y)
            checks.append(Check(f"{name} mirror: Fx(t)=-Fx(180-t), Fz(t)=Fz(180-t)"
                                + (", Fy=0" if shape.mirror_y else ""), val, f"<= {limit:g}", val <= limit))
        elif shape.mirror_y:
            val = float(np.abs(force[name][:, 1]).max() / np.linalg.norm(force[name], axis=1).max())
            checks.append(Check(f"{name} mirror y: Fy = 0", val, f"<= {limit:g}", val <= limit))
    log.progress(f"mirror checks: {time.perf_counter() - t0:.1f} s")

    # Mesh shapes: the coupling (MuJoCo's float32 mesh) against the float64 mesh summed directly.
    for name, shape in shapes.items():
        if shape.mesh is not None:
            ref = mesh_forces(shape, angles, size=size, model=models.get(name))
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

    # Overlapping geoms: the exposed-surface rule against the brute force (rft_mujoco.studies.overlap).
    t0 = time.perf_counter()
    over = overlap.run(QUICK_OVERLAP_CASES if quick else None)
    worst = max(over, key=lambda r: r["error"])
    checks.append(Check(f"overlapping geoms: |F - F_ref|/|F_ref| at the default size, worst "
                        f"({worst['case']}, {worst['motion']})", worst["error"], f"<= {OVERLAP_TOL:g}",
                        worst["error"] <= OVERLAP_TOL))
    log.progress(f"overlapping geoms ({len(over)} cases x motions): {time.perf_counter() - t0:.1f} s")

    res = Results(angles, shapes, force, torque, guarded, change, drill, conv, depth_res, checks, over)
    report.report(res, log, size, quick)
    res.files += report.write_csv(res, out)
    if plots:
        res.files += report.plots(res, out)
    res.seconds = time.perf_counter() - t_start
    return res


def _finish(res: Results, quick: bool, resolution: str | float, out: Path, log: Log) -> Results:
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
