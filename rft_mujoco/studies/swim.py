"""Sand-swimming against experiments: ``python -m rft_mujoco swim [--quick] [--out DIR]``.

The bundled swimmer (``models/sand_swimmer.xml``: 7 capsules, 0.13 m, planar root) is driven kinematically
(stiff position servos, :data:`SERVO_KP`; the tracking error is reported) through a single-period
travelling wave, ``q_i(t) = a sin(2 pi f t - 2 pi i / 6)`` on its 6 joints, head to tail. For each joint
amplitude ``a`` the body's shape gives the wave's amplitude-to-wavelength ratio A/lambda (:func:`wave_shape`:
the midline's half lateral extent and its length along the mean axis, averaged over a period), and the run
gives the swimming speed (the centre of mass's displacement over the last :data:`MEASURED_CYCLES` cycles, along
whatever heading the body took while the wave ramped up in the first cycle; the yaw drift over the measured
cycles is reported). Reported: the wave
efficiency ``eta = v / (f lambda)`` (forward speed over wave speed) and body lengths per cycle, at two or
more frequencies, with the exposed-surface culling (``attach(cull=True)``, the default) and without it.

The medium is :data:`rft_mujoco.MALADEN_GLASS_BEADS` as sourced (no tuning to the targets). Published points
on the plot (not fitted): the sandfish, eta ~ 0.5 near A/lambda ~ 0.2 (Maladen et al., Science 325, 2009;
J. R. Soc. Interface 8, 2011: the sandfish's A/lambda ~ 0.2 is near the optimum of resistive-force models);
the sand-swimming robot, eta = 0.34 +- 0.02 (Maladen et al., IJRR 30, 2011). 3D-RFT was fitted to
intrusions from a free surface, not to bodies fully submerged and moving sideways; where it lands is a
prediction, not a fit.

Also measured (:func:`mass_check`): the study's 100x density scaling (:data:`DENSITY_SCALE`, which the explicit
sand solve needs on this body), against the real density (the bundled model's, the animal's), at two timesteps.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics.media import MALADEN_GLASS_BEADS
from rft_mujoco.tables import RIGHT, table

N_JOINTS = 6
SERVO_KP = 100.0
"""N m/rad: the stiff servos' gain (the model's own is 0.5); damping :data:`SERVO_KV`, no force limit."""
SERVO_KV = 1.0
"""N m s/rad."""
JOINT_RANGE = 2.5
"""rad: joint ranges widened to +-this for the large amplitudes."""
AMPLITUDES = (0.3, 0.5, 0.7, 0.9, 1.1, 1.3, 1.5, 1.7, 1.8)
"""Joint amplitudes a (rad) of the sweep (A/lambda from about 0.05 to 0.4)."""
FREQUENCIES = (0.5, 1.0)
"""Hz."""
CYCLES = 4
"""Wave periods per run: the first ramps the amplitude up, speeds are taken over the last ones."""
MEASURED_CYCLES = 2
DENSITY_SCALE = 100.0
"""The study's density over the bundled model's, which is the animal's (see the model's header): 100x, the
quasi-static mass scaling the explicit sand solve needs on this body (the study's default runs are explicit);
``swim(..., density_scale=1.0, solve="implicit")`` runs the animal."""
PUBLISHED = {
    "sandfish (Maladen et al. 2009)": (0.2, 0.5),
}
"""(A/lambda, eta) points; the robot's eta (Maladen et al. IJRR 2011) is :data:`ROBOT_ETA`."""
ROBOT_ETA = (0.34, 0.02)
"""eta, its +- (the sand-swimming robot, Maladen et al., IJRR 2011)."""


def _model(density_scale: float = 1.0, timestep: float | None = None) -> mujoco.MjModel:
    from rft_mujoco.models import path

    spec = mujoco.MjSpec.from_file(str(path("sand_swimmer.xml")))
    for j in spec.joints:
        if j.name.startswith("j"):
            j.range = [-JOINT_RANGE, JOINT_RANGE]
    model = spec.compile()
    for a in range(model.nu):
        model.actuator_gainprm[a, 0] = SERVO_KP
        model.actuator_biasprm[a, 1] = -SERVO_KP
        model.actuator_biasprm[a, 2] = -SERVO_KV
        model.actuator_forcelimited[a] = 0
        model.actuator_ctrlrange[a] = [-JOINT_RANGE, JOINT_RANGE]
    if density_scale != 1.0:
        scale_density(model, density_scale)
    if timestep is not None:
        model.opt.timestep = timestep
    return model


def scale_density(model: mujoco.MjModel, factor: float) -> None:
    """Scale the swimmer's density by ``factor`` in place: every body's mass and inertia, and the body joints'
    armature and damping (the model's header scales them with the density), then recompute the constants
    derived from the masses (``mj_setConst``: ``body_subtreemass``, hence ``subtree_com``). Without that last
    step MuJoCo's ``subtree_com`` stays weighted by the old subtree masses and is off by ``factor``: every
    speed measured from it is too (the swim study's mass check gave eta 0.002 at the animal's density that way)."""
    if not factor > 0.0:
        raise ValueError(f"density factor must be > 0, got {factor!r}")
    body_dofs = np.array([model.jnt_dofadr[j] for j in range(model.njnt)
                          if model.joint(j).name not in ("root_x", "root_y", "root_yaw")], dtype=int)
    model.body_mass[1:] *= factor
    model.body_inertia[1:] *= factor
    model.dof_armature[body_dofs] *= factor
    model.dof_damping[body_dofs] *= factor
    mujoco.mj_setConst(model, mujoco.MjData(model))


def wave_shape(amplitude: float, phases: int = 16) -> tuple[float, float, float]:
    """(A/lambda, lambda m, body length m) of the midline of the swimmer bent by ``amplitude`` (rad),
    averaged over ``phases`` phases of one period. The midline: the joint points and both tips, each link
    0.017 m (the head 0.025 m); A is half its lateral extent about its mean axis, lambda its extent
    along that axis (one period along the body)."""
    links = [0.025] + [0.017] * N_JOINTS
    ratios, lams = [], []
    for k in range(phases):
        phase = 2 * math.pi * k / phases
        q = amplitude * np.sin(phase - 2 * math.pi * np.arange(N_JOINTS) / N_JOINTS)
        heading, pts = 0.0, [np.zeros(2)]
        for i, length in enumerate(links):
            if i > 0:
                heading += q[i - 1]
            pts.append(pts[-1] + length * np.array([-math.cos(heading), -math.sin(heading)]))
        p = np.array(pts) - np.mean(pts, axis=0)
        _, _, vt = np.linalg.svd(p, full_matrices=False)
        along, across = p @ vt[0], p @ vt[1]
        lam = float(along.max() - along.min())
        ratios.append(0.5 * float(across.max() - across.min()) / lam)
        lams.append(lam)
    return float(np.mean(ratios)), float(np.mean(lams)), float(sum(links))


def serpenoid(amplitude, frequency: float, t: float) -> np.ndarray:
    """The joint targets (rad) of the study's drive at time ``t`` (s): ``ramp a sin(2 pi f t - 2 pi i / 6)`` for
    joints i, the amplitude ramped in over the first period. ``amplitude``: rad, a number or an (n, 1) column
    (one row of targets each)."""
    ramp = min(1.0, t * frequency)
    return ramp * amplitude * np.sin(2 * math.pi * frequency * t - 2 * math.pi * np.arange(N_JOINTS) / N_JOINTS)


def swim(amplitude: float, frequency: float, *, cull: bool = True, density_scale: float = DENSITY_SCALE,
         timestep: float | None = None, cycles: int = CYCLES, resolution: str | float = "default",
         **attach_kwargs) -> dict:
    """One kinematic run; returns speeds (m/s), eta, body lengths per cycle, tracking error (rad), wall s.
    ``density_scale`` multiplies the bundled model's (the animal's) density (:func:`scale_density`; default
    :data:`DENSITY_SCALE`, the explicit solve's mass scaling); ``resolution`` and
    ``attach_kwargs`` (e.g. ``solve``, ``backend``) go to :func:`rft_mujoco.attach`."""
    model = _model(density_scale, timestep)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    sand = attach(model, MALADEN_GLASS_BEADS, None, 0.0, resolution, cull=cull, monitor=False, **attach_kwargs)
    sand.replace_rigid(["floor"])
    head = model.body("head").id
    dt = model.opt.timestep
    steps = int(round(cycles / frequency / dt))
    start = int(round((cycles - MEASURED_CYCLES) / frequency / dt))
    err2, n_err, com0 = 0.0, 0, None
    t0 = time.perf_counter()
    try:
        for k in range(steps):
            data.ctrl[:] = serpenoid(amplitude, frequency, data.time)
            mujoco.mj_step(model, data)
            if k == start:
                com0 = data.subtree_com[head, :2].copy()
                yaw0 = float(data.qpos[2])
            if k >= start:
                err2 += float(np.sum((data.qpos[3:] - data.ctrl) ** 2))
                n_err += N_JOINTS
        disp = data.subtree_com[head, :2] - com0
    finally:
        sand.detach()
    span = MEASURED_CYCLES / frequency
    ratio, lam, length = wave_shape(amplitude)
    speed = float(np.linalg.norm(disp) / span)
    forward = float(disp[0] / span)
    return dict(amplitude_rad=amplitude, frequency_hz=frequency, cull=cull, density_scale=density_scale,
                timestep_s=dt, resolution=resolution, solve=attach_kwargs.get("solve", "explicit"),
                a_over_lambda=ratio, wavelength_m=lam, speed_mps=speed, forward_mps=forward,
                eta=speed / (frequency * lam), body_lengths_per_cycle=speed / (frequency * length),
                tracking_rms_rad=math.sqrt(err2 / max(n_err, 1)), yaw_drift_rad=float(data.qpos[2]) - yaw0,
                wall_s=time.perf_counter() - t0)


def sweep(amplitudes=AMPLITUDES, frequencies=FREQUENCIES, culls=(True, False), progress=print) -> list[dict]:
    rows = []
    for cull in culls:
        for f in frequencies:
            for a in amplitudes:
                r = swim(a, f, cull=cull)
                rows.append(r)
                progress(f"[swim] cull={cull!s:<5} f={f:g} Hz a={a:.2f} rad: A/lambda {r['a_over_lambda']:.3f} "
                         f"eta {r['eta']:.3f} ({r['wall_s']:.1f} s)")
    return rows


def mass_check(amplitude: float = 0.8, frequency: float = 1.0, timesteps=(0.002, 0.0005)) -> list[dict]:
    """eta with the study's 100x density and with the real (the bundled model's) density, at each timestep
    (culling on, the default explicit solve)."""
    return [swim(amplitude, frequency, density_scale=scale, timestep=dt)
            for scale in (DENSITY_SCALE, 1.0) for dt in timesteps]


def _table(rows, keys, fmt) -> list[str]:
    """Columns ``keys`` of ``rows`` (dicts), each value formatted with its spec in ``fmt``, as table lines."""
    return table(keys, [[format(r[k], f) for k, f in zip(keys, fmt)] for r in rows],
                 align=RIGHT * len(keys)).splitlines()


def plot(rows, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.8))
    for (cull, f), style in zip([(c, f) for c in (True, False) for f in sorted({r["frequency_hz"] for r in rows})],
                                ("o-", "s-", "o--", "s--", "^-", "^--")):
        sel = [r for r in rows if r["cull"] == cull and r["frequency_hz"] == f]
        if sel:
            ax.plot([r["a_over_lambda"] for r in sel], [r["eta"] for r in sel], style,
                    color="C0" if cull else "C3", alpha=1.0 if f == min(r["frequency_hz"] for r in rows) else 0.6,
                    label=f"3D-RFT, {'exposed surface (cull)' if cull else 'every geom whole (no cull)'}, {f:g} Hz")
    for name, (x, y) in PUBLISHED.items():
        ax.plot(x, y, "k*", ms=14, label=name)
    eta, pm = ROBOT_ETA
    ax.axhspan(eta - pm, eta + pm, color="0.5", alpha=0.25, label="robot, eta 0.34 +- 0.02 (Maladen et al. 2011)")
    ax.set_xlabel("amplitude / wavelength A/lambda")
    ax.set_ylabel("wave efficiency eta = v / v_wave")
    ax.set_title("sand-swimming: the bundled swimmer in Maladen's glass beads", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "swim.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run(quick: bool = False, out: str | Path = "out/swim", plots: bool = True) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    amplitudes = AMPLITUDES[::2] if quick else AMPLITUDES
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = sweep(amplitudes)
        mass = mass_check(timesteps=(0.002,) if quick else (0.002, 0.0005))
    keys = ["cull", "frequency_hz", "amplitude_rad", "a_over_lambda", "forward_mps", "eta",
            "body_lengths_per_cycle", "tracking_rms_rad"]
    print("\nkinematic travelling waves (eta = forward speed / wave speed)")
    print("\n".join(_table(rows, keys, ["", "g", ".2f", ".3f", ".4f", ".3f", ".3f", ".3f"])))
    best = {c: max((r for r in rows if r["cull"] == c), key=lambda r: r["eta"]) for c in (True, False)}
    for c, r in best.items():
        print(f"best eta {'with' if c else 'without'} culling: {r['eta']:.3f} at A/lambda {r['a_over_lambda']:.3f} "
              f"({r['frequency_hz']:g} Hz)")
    freqs = sorted({r["frequency_hz"] for r in rows})
    spread = max(abs(a["eta"] - b["eta"]) for a in rows for b in rows
                 if a["cull"] and b["cull"] and a["amplitude_rad"] == b["amplitude_rad"]
                 and a["frequency_hz"] == freqs[0] and b["frequency_hz"] == freqs[-1])
    print(f"frequency dependence (cull): largest |eta({freqs[0]:g} Hz) - eta({freqs[-1]:g} Hz)| = {spread:.4f}")
    print("\nmass scaling (A/lambda {:.3f}, 1 Hz): the study's 100x density against the real one (the bundled "
          "model's)".format(
        mass[0]["a_over_lambda"]))
    print("\n".join(_table(mass, ["density_scale", "timestep_s", "eta", "tracking_rms_rad", "wall_s"],
                           [".2g", "g", ".4f", ".4f", ".1f"])))
    path = out / "swim.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows + mass)
    files = [path]
    (out / "swim.json").write_text(json.dumps(dict(rows=rows, mass=mass, frequency_spread=spread), indent=2))
    files.append(out / "swim.json")
    if plots:
        files.append(plot(rows, out))
    print("wrote " + ", ".join(str(f) for f in files))
    return dict(rows=rows, mass=mass, files=files, frequency_spread=spread)


def main(argv: list[str] | None = None, command: str = "swim") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="Sand-swimming: wave efficiency against A/lambda, with and "
                                                 "without culling, against published experiments.")
    parser.add_argument("--quick", action="store_true", help="every other amplitude, one timestep in the mass check")
    parser.add_argument("--out", default="out/swim", help="output folder (default out/swim)")
    parser.add_argument("--no-plots", action="store_true", help="tables and CSV only")
    args = parser.parse_args(argv)
    run(quick=args.quick, out=args.out, plots=not args.no_plots)
    return 0
