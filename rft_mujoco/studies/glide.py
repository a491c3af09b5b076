"""No glide: a quadruped on slanted lower legs set down on the sand stands still (issue 26, item 3).

``python -m rft_mujoco glide [--duration S] [--solves explicit implicit]``. The robot
(:func:`rft_mujoco.studies.bench.robots.slanted_quadruped`: 62 kg, Spot-sized, lower legs that are slanted
triangle-mesh prisms, sphere feet, stiff PD servos holding the pose) is set down at its standing height, feet
on the surface of loose glass beads, every body attached, and left alone. A public Spot model did this with
the explicit solve: its hind lower legs sank and slid at once, received 16-19% of their RFT wrench (the
whole wrench scaled so as not to reverse the sinking), and the robot glided 1.6 m in 3 s.

Reported per solve (``attach(solve=...)``; the implicit solve on the numpy backend): ``t_rest`` (s, after
which every body moves slower than :data:`REST_SPEED`), the trunk's horizontal drift after that (m, the
target is under :data:`DRIFT_MAX`), over the whole run, its final height and sinkage, and the wall time.
Units: SI.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.tables import Columns

MEDIA = "li_loose_glass_beads"
DURATION = 2.0
"""s simulated."""
REST_SPEED = 1e-3
"""m/s and rad/s: every body slower than this counts as at rest."""
REST_BY = 1.0
"""s: the robot must be at rest by then (it touches at t = 0)."""
DRIFT_MAX = 0.02
"""m: the trunk's horizontal drift after it comes to rest."""
BACKENDS = {"explicit": {}, "implicit": {"solve": "implicit", "backend": "numpy"}}


def stand(solve: str = "explicit", duration: float = DURATION, resolution="default", **robot) -> dict:
    """One run (see the module docstring); returns t_rest_s, drift_after_rest_m, drift_total_m, trunk_x_m
    (track, one per 10 steps), final_height_m, sinkage_m (trunk, from the start), max_speed_end (the largest
    body speed at the end), wall_s."""
    from rft_mujoco.studies.bench.robots import slanted_quadruped

    if solve not in BACKENDS:
        raise ValueError(f"solve must be one of {sorted(BACKENDS)}, got {solve!r}")
    model = slanted_quadruped(**robot)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    trunk = model.body("trunk").id
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sand = attach(model, MEDIA, resolution=resolution, monitor=False, **BACKENDS[solve])
    n = int(round(duration / model.opt.timestep))
    xy = np.empty((n, 2))
    speed = np.empty(n)
    vel = np.zeros(6)
    z0 = float(data.qpos[2])
    t0 = time.perf_counter()
    try:
        for i in range(n):
            mujoco.mj_step(model, data)
            xy[i] = data.qpos[:2]
            s = 0.0
            for b in range(1, model.nbody):
                mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
                s = max(s, float(np.abs(vel).max()))
            speed[i] = s
            if not np.all(np.isfinite(data.qpos)):
                raise FloatingPointError(f"the {solve} solve gave NaN at step {i}")
    finally:
        sand.detach()
    return dict(solve=solve, **rest_and_drift(xy, speed, model.opt.timestep), trunk_x_m=xy[::10, 0].tolist(),
                final_height_m=float(data.qpos[2]), sinkage_m=z0 - float(data.qpos[2]),
                max_speed_end=float(speed[-1]), wall_s=time.perf_counter() - t0)


def rest_and_drift(xy: np.ndarray, speed: np.ndarray, dt: float) -> dict:
    """From the trunk's horizontal track ``xy`` (n, 2) m and the largest speed ``speed`` (n,) after each of n
    steps of ``dt`` s: ``t_rest_s`` (after which every speed stays below :data:`REST_SPEED`; inf if it never
    does), ``drift_after_rest_m`` (nan then) and ``drift_total_m``."""
    n = speed.shape[0]
    moving = np.flatnonzero(speed >= REST_SPEED)
    last = moving[-1] + 1 if moving.size else 0
    t_rest = math.inf if last >= n else last * dt
    after = float(np.linalg.norm(xy[-1] - xy[min(last, n - 1)])) if math.isfinite(t_rest) else math.nan
    return dict(t_rest_s=t_rest, drift_after_rest_m=after, drift_total_m=float(np.linalg.norm(xy[-1] - xy[0])))


def passes(r: dict) -> bool:
    return r["t_rest_s"] <= REST_BY and r["drift_after_rest_m"] < DRIFT_MAX


def main(argv: list[str] | None = None, command: str = "glide") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="A quadruped on slanted mesh lower legs set down on sand: "
                                                 "does it stand still?")
    parser.add_argument("--duration", type=float, default=DURATION, help=f"s (default {DURATION:g})")
    parser.add_argument("--solves", nargs="+", choices=sorted(BACKENDS), default=sorted(BACKENDS))
    args = parser.parse_args(argv)
    if not args.duration > 0:
        parser.error(f"--duration must be > 0 s, got {args.duration}")
    columns = Columns(["solve", "rest by s", "drift after rest mm", "drift total mm", "trunk sinkage mm", "wall s",
                       f"verdict (rest by {REST_BY:g} s, drift < {DRIFT_MAX * 1e3:g} mm)"],
                      widths=[max(map(len, args.solves)), 9, 19, 14, 16, 7, 0], align="<>>>>><")
    print(columns.header())
    for solve in args.solves:
        r = stand(solve, args.duration)
        print(columns.row([solve, f"{r['t_rest_s']:.3g}", f"{r['drift_after_rest_m'] * 1e3:.1f}",
                           f"{r['drift_total_m'] * 1e3:.1f}", f"{r['sinkage_m'] * 1e3:.1f}", f"{r['wall_s']:.0f}",
                           "pass" if passes(r) else "FAIL"]), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
