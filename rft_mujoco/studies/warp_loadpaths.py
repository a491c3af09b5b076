"""The stability study's load paths on the batched sand, side by side with the CPU path (needs ``rft_mujoco[warp]``).

``python -m rft_mujoco.studies.warp_loadpaths [--scenes joint_limit contact ...] [--integrators Euler ...]
[--timesteps 0.005 ...] [--steps 500] [--solve implicit|explicit]``: each scene of
:data:`rft_mujoco.studies.loadpath_scenes.SCENES` (a load that reaches a sand body through a joint limit, a
contact, a weld, dry friction, ...) stepped from the same start with ``mujoco.mj_step`` and the CPU sand and with
``mujoco_warp.step`` and the warp sand (warp's CPU device, one world): the sand body's depth on both (mm), the
largest difference over the run (mm), the sand's vertical force at the end (N) and whether each rests. Prints a
table; :func:`compare` returns the numbers.
"""

from __future__ import annotations

import argparse
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach as cpu_attach
from rft_mujoco.studies.loadpath_scenes import MEDIA, RESOLUTION, ROCK_PUSH, SCENES
from rft_mujoco.studies.loadpath_scenes import scene as loadpath_scene
from rft_mujoco.tables import table as _table

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")


def compare(scene: str, integrator: str = "implicitfast", dt: float = 0.002, steps: int = 500,
            solve: str = "implicit", device: str = "cpu") -> dict:
    """One scene (a name of SCENES) at one integrator and timestep (s), ``steps`` steps on both paths; returns
    depth_cpu_m, depth_warp_m (the sand body's COM below its start), worst_dz_m (the largest |z_warp - z_cpu|
    over the run), fz_cpu_n, fz_warp_n (the sand's vertical force on the sand bodies at the end), rest_cpu,
    rest_warp (every sand body resting in the last evaluation) and wall_s."""
    import mujoco_warp as mjw
    import warp as wp

    import rft_mujoco.warp as rw

    if scene not in SCENES:
        raise ValueError(f"scene must be one of {sorted(SCENES)}, got {scene!r}")
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    model, d, bodies = loadpath_scene(scene, dt, integrator)
    mujoco.mj_forward(model, d)
    ball = model.body("ball").id if scene == "rock" else -1
    t0 = time.perf_counter()
    with wp.ScopedDevice(device), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = mjw.put_model(model)
        dw = mjw.put_data(model, d, nworld=1, nconmax=16, njmax=64)
        cpu = cpu_attach(model, MEDIA, bodies, resolution=RESOLUTION, solve=solve, monitor=False)
        sand = rw.attach(model, m, MEDIA, bodies, resolution=RESOLUTION, solve=solve, data=dw)
        b = cpu.body_ids[0]
        z0 = float(d.xipos[b, 2])
        worst = 0.0
        try:
            if ball > 0:
                d.xfrc_applied[ball, 0] = ROCK_PUSH
                xf = dw.xfrc_applied.numpy()
                xf[0, ball, 0] = ROCK_PUSH
                dw.xfrc_applied.assign(xf)
            for _ in range(steps):
                mujoco.mj_step(model, d)
                mjw.step(m, dw)
                worst = max(worst, abs(float(dw.xipos.numpy()[0, b, 2]) - float(d.xipos[b, 2])))
            sand.check(dw)
            dc, dg = cpu.diagnostics(d), sand.diagnostics(dw)
            out = dict(scene=scene, integrator=integrator, dt=dt, steps=steps, depth_cpu_m=z0 - float(d.xipos[b, 2]),
                       depth_warp_m=z0 - float(dw.xipos.numpy()[0, b, 2]), worst_dz_m=worst,
                       fz_cpu_n=float(dc.force[:, 2].sum()), fz_warp_n=float(dg.force[0, :, 2].sum()),
                       rest_cpu=bool(np.all(dc.resting)), rest_warp=bool(np.all(dg.resting[0])))
        finally:
            sand.detach()
            cpu.detach()
    out["wall_s"] = time.perf_counter() - t0
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco.studies.warp_loadpaths",
                                     description="The load paths on warp and on the CPU path, side by side.")
    parser.add_argument("--scenes", nargs="+", default=sorted(SCENES), choices=sorted(SCENES))
    parser.add_argument("--integrators", nargs="+", default=["Euler", "implicitfast", "RK4"], choices=INTEGRATORS)
    parser.add_argument("--timesteps", nargs="+", type=float, default=[0.002], metavar="S")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--solve", default="implicit", choices=("explicit", "implicit"))
    args = parser.parse_args(argv)
    if args.steps < 1 or min(args.timesteps) <= 0:
        parser.error(f"--steps must be >= 1 and --timesteps > 0 s, got {args.steps} and {args.timesteps}")
    import warp as wp

    wp.config.quiet = True
    rows = []
    for integrator in args.integrators:
        for dt in args.timesteps:
            for scene in args.scenes:
                r = compare(scene, integrator, dt, args.steps, args.solve)
                print(f"[warp_loadpaths] {scene} {integrator} {dt * 1e3:g} ms: {r['wall_s']:.1f} s", flush=True)
                rows.append([scene, integrator, f"{dt * 1e3:g}", f"{r['depth_cpu_m'] * 1e3:.2f}",
                             f"{r['depth_warp_m'] * 1e3:.2f}", f"{r['worst_dz_m'] * 1e3:.3f}", f"{r['fz_cpu_n']:.3f}",
                             f"{r['fz_warp_n']:.3f}", f"{r['rest_cpu']}/{r['rest_warp']}"])
    print(_table(["scene", "integrator", "dt ms", "depth CPU mm", "depth warp mm", "largest |dz| mm", "Fz CPU N",
                  "Fz warp N", "rest CPU/warp"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
