"""Ruts: the sand wheel rig driven over its own track several times on a deformable surface (issue 31).

``python -m rft_mujoco ruts [--passes N] [--slip S] [--plot PATH]``. The bundled wheel rig
(``models/sand_wheel.xml``: wheel 0.10 m radius, 0.06 m wide, 30 N on the axle) on loose glass beads
(``li_loose_glass_beads``, element size 0.015 m as the SandWheel env), a
:class:`~rft_mujoco.DeformableSurface` 1.0 x 0.3 m with 5 mm cells (defaults otherwise), compiled backend
(``--backend numpy``: the reference), timestep 2 ms (``--repose`` sets its angle of repose, ``none`` for no slope flow). Each pass the wheel is
set down (still) at x = 0 on the surface as the previous passes left it, spun at :data:`WHEEL_SPEED` rad/s with the carriage servoed to ``w r (1 - slip)`` (the SandWheel env's
slip drive), and driven :data:`TRAVEL` m (``--reload-sinkage`` sets the surface's plastic sinkage per
reload; 0 makes reloading elastic). Reported per pass: the wheel's mean sinkage below the *initial*
surface over the middle of the track (:data:`WINDOW`), the rut depth left under the wheel's centre line
there, and the drawbar pull (N, the force the carriage servo needs to hold the speed: positive pulls
forward). Units: SI (printed in mm and N).
"""

from __future__ import annotations

import argparse
import importlib.resources
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.tables import Columns

MEDIA = "li_loose_glass_beads"
RADIUS = 0.10
"""m, the rig's wheel radius."""
WHEEL_SPEED = 2.0
"""rad/s."""
SLIP = 0.2
TRAVEL = 0.45
"""m driven per pass."""
WINDOW = (0.15, 0.40)
"""m of carriage x over which a pass's sinkage and pull are averaged (after the start transient)."""
GRID = dict(size=(1.0, 0.3), cell=0.005, center=(0.35, 0.0))


def rig(repose_angle: float | None = 30.0, reload_sinkage: float | None = None, backend: str = "auto"):
    """The wheel rig with deformable sand on its wheel (``repose_angle``: of the DeformableSurface, degrees or
    None; ``reload_sinkage``: its plastic sinkage per reload, None for the default; ``backend``: attach's):
    (model, data, handle)."""
    path = str(importlib.resources.files("rft_mujoco.models") / "sand_wheel.xml")
    model = mujoco.MjModel.from_xml_path(path)
    extra = {} if reload_sinkage is None else {"reload_sinkage": reload_sinkage}
    for name, kv in (("wheel_speed", 50.0), ("carriage_speed", 2000.0)):
        act = model.actuator(name)
        act.gainprm[0] = kv
        act.biasprm[2] = -kv
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        handle = attach(model, MEDIA, bodies=["wheel"],
                        surface_height=DeformableSurface(**GRID, repose_angle=repose_angle, **extra),
                        resolution=0.015, backend=backend, monitor=False)
        handle.replace_rigid("floor")
    return model, mujoco.MjData(model), handle


def drive_pass(model, data, handle, slip: float = SLIP) -> dict:
    """Set the wheel down still at x = 0 on the current surface and drive it TRAVEL m; returns the pass's mean
    sinkage (m, below the initial surface), mean drawbar pull (N) over WINDOW, and its track (x, sinkage)."""
    x_j, z_j, spin = (model.joint(n).qposadr[0] for n in ("carriage_x", "axle_z", "wheel_spin"))
    carriage = model.actuator("carriage_speed").id
    surface = handle.surface(data)
    row = int(np.argmin(np.abs(surface.y)))
    data.qvel[:] = 0.0
    data.qpos[x_j] = 0.0
    data.qpos[spin] = 0.0
    # lowest point on the highest surface node under the wheel (x in +-r/2), so the wheel starts above the sand
    data.qpos[z_j] = float(surface.heights[row, np.abs(surface.x) <= RADIUS / 2].max())
    data.ctrl[:] = 0.0
    data.ctrl[model.actuator("wheel_speed").id] = WHEEL_SPEED
    data.ctrl[carriage] = WHEEL_SPEED * RADIUS * (1.0 - slip)
    xs, sink, pull = [], [], []
    while data.qpos[x_j] < TRAVEL and data.time < 60.0:
        mujoco.mj_step(model, data)
        xs.append(float(data.qpos[x_j]))
        sink.append(-float(data.qpos[z_j]))
        pull.append(-float(data.actuator_force[carriage]))
    xs, sink, pull = np.array(xs), np.array(sink), np.array(pull)
    w = (xs >= WINDOW[0]) & (xs <= WINDOW[1])
    return {"sinkage": float(sink[w].mean()) if w.any() else float("nan"),
            "pull": float(pull[w].mean()) if w.any() else float("nan"), "x": xs, "track": sink}


def run(passes: int = 3, slip: float = SLIP, repose_angle: float | None = 30.0,
        reload_sinkage: float | None = None, backend: str = "auto") -> dict:
    """``passes`` passes (module docstring); per pass its sinkage (m), rut depth (m, below the initial
    surface under the centre line, mean over WINDOW), pull (N); the surfaces after each pass."""
    t0 = time.perf_counter()
    model, data, handle = rig(repose_angle, reload_sinkage, backend)
    out = {"sinkage": [], "rut": [], "pull": [], "surfaces": [], "tracks": []}
    for _ in range(passes):
        p = drive_pass(model, data, handle, slip)
        s = handle.surface(data)
        row = int(np.argmin(np.abs(s.y)))
        w = (s.x >= WINDOW[0]) & (s.x <= WINDOW[1])
        out["sinkage"].append(p["sinkage"])
        out["pull"].append(p["pull"])
        out["rut"].append(float(-s.heights[row, w].mean()))
        out["surfaces"].append(s)
        out["tracks"].append((p["x"], p["track"]))
    handle.detach()
    out["wall_s"] = time.perf_counter() - t0
    return out


def plot(r: dict, path: str) -> None:
    """The surface along the track's centre line after each pass."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    for i, s in enumerate(r["surfaces"]):
        row = int(np.argmin(np.abs(s.y)))
        ax.plot(s.x * 1e3, s.heights[row] * 1e3, label=f"after pass {i + 1}")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("surface height at y = 0 (mm)")
    ax.set_title("sand wheel rig: the surface along the track after each pass", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None, command: str = "ruts") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="The sand wheel rig driven over its own rut (issue 31)")
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--slip", type=float, default=SLIP)
    parser.add_argument("--repose", default="30", help="angle of repose of the surface, degrees, or 'none' (no "
                        "slope flow; default 30)")
    parser.add_argument("--reload-sinkage", type=float, default=None,
                        help="the surface's plastic sinkage per reload, a fraction of the preload (default: "
                        "DeformableSurface's, 0.1; 0: elastic reloading)")
    parser.add_argument("--plot", default=None, help="also save the rut sections to this PNG")
    parser.add_argument("--backend", default="auto", choices=("auto", "numba", "numpy"),
                        help="attach's backend (default auto: compiled)")
    args = parser.parse_args(argv)
    repose = None if args.repose.lower() == "none" else float(args.repose)
    if args.passes < 1 or not -1.0 <= args.slip <= 1.0:
        parser.error(f"--passes must be >= 1 and --slip in [-1, 1], got {args.passes}, {args.slip}")
    if args.reload_sinkage is not None and not args.reload_sinkage >= 0.0:
        parser.error(f"--reload-sinkage must be >= 0 (a fraction of the preload), got {args.reload_sinkage}")
    r = run(args.passes, args.slip, repose, args.reload_sinkage, args.backend)
    table = Columns(["pass", "wheel sinkage mm", "increment mm", "rut depth mm", "drawbar pull N"])
    print(table.header())
    prev = 0.0
    for i, (s, rut, pull) in enumerate(zip(r["sinkage"], r["rut"], r["pull"])):
        print(table.row([i + 1, f"{s * 1e3:.2f}", f"{(s - prev) * 1e3:.2f}", f"{rut * 1e3:.2f}", f"{pull:.2f}"]))
        prev = s
    print(f"wall time {r['wall_s']:.0f} s", flush=True)
    if args.plot:
        plot(r, args.plot)
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
