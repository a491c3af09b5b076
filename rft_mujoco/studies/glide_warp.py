"""No glide on the batched sand: the glide study's slanted-shin quadruped (:mod:`rft_mujoco.studies.glide`) set down
on the sand in MuJoCo Warp worlds (needs ``rft_mujoco[warp]``).

``python -m rft_mujoco.studies.glide_warp [--duration S] [--solves implicit explicit] [--device cpu]``: one world
per solve's run; a world is at rest once every joint speed is below :data:`rft_mujoco.studies.glide.REST_SPEED`
(m/s and rad/s of ``qvel``: the glide study measures body speeds with ``mj_objectVelocity``, which MuJoCo Warp
does not offer per step; both are zero together). Prints when each solve's robot came to rest, the trunk's
horizontal drift after that and in all, and its sinkage; :func:`stand_batched` returns them.
"""

from __future__ import annotations

import argparse
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.studies import glide as _glide
from rft_mujoco.tables import table as _table


def stand_batched(solve: str = "implicit", duration: float = _glide.DURATION, worlds: int = 1,
                  device: str = "cpu", resolution="default") -> dict:
    """The robot set down in ``worlds`` identical worlds with ``rft_mujoco.warp.attach(solve=...)`` for
    ``duration`` s; returns t_rest_s (s, inf if it never rests), drift_after_rest_m, drift_total_m (m, the trunk's
    horizontal motion, world 0), sinkage_m (the trunk's, from the start), spread_m (the largest trunk position
    difference between worlds at the end: 0 when the worlds agree) and wall_s."""
    import mujoco_warp as mjw
    import warp as wp

    import rft_mujoco.warp as rw
    from rft_mujoco.studies.bench.robots import slanted_quadruped

    if solve not in ("explicit", "implicit"):
        raise ValueError(f"solve must be 'explicit' or 'implicit', got {solve!r}")
    if not duration > 0 or worlds < 1:
        raise ValueError(f"duration must be > 0 s and worlds >= 1, got {duration!r} and {worlds!r}")
    model = slanted_quadruped()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    n = int(round(duration / model.opt.timestep))
    xy, speed = np.empty((n, 2)), np.empty(n)
    z0 = float(data.qpos[2])
    t0 = time.perf_counter()
    with wp.ScopedDevice(device), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = mjw.put_model(model)
        d = mjw.put_data(model, data, nworld=worlds, nconmax=16, njmax=128)
        sand = rw.attach(model, m, _glide.MEDIA, None, 0.0, resolution, solve=solve, data=d)
        try:
            for i in range(n):
                mjw.step(m, d)
                qpos, qvel = d.qpos.numpy(), d.qvel.numpy()
                xy[i] = qpos[0, :2]
                speed[i] = float(np.abs(qvel).max())
            sand.check(d)
        finally:
            sand.detach()
    if not np.all(np.isfinite(qpos)):
        raise FloatingPointError(f"the {solve} solve gave NaN on warp")
    return dict(solve=solve, **_glide.rest_and_drift(xy, speed, model.opt.timestep), sinkage_m=z0 - float(qpos[0, 2]),
                spread_m=float(np.abs(qpos[:, :3] - qpos[:1, :3]).max()), wall_s=time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco.studies.glide_warp",
                                     description="The slanted-shin quadruped set down on warp's sand: does it "
                                                 "stand still?")
    parser.add_argument("--duration", type=float, default=_glide.DURATION, help="s (default %(default)g)")
    parser.add_argument("--solves", nargs="+", choices=("explicit", "implicit"), default=["implicit", "explicit"])
    parser.add_argument("--device", default="cpu", help="warp device (default cpu)")
    args = parser.parse_args(argv)
    if not args.duration > 0:
        parser.error(f"--duration must be > 0 s, got {args.duration}")
    import warp as wp

    wp.config.quiet = True
    rows = []
    for solve in args.solves:
        r = stand_batched(solve, args.duration, device=args.device)
        rows.append([solve, f"{r['t_rest_s']:.3g}", f"{r['drift_after_rest_m'] * 1e3:.2f}",
                     f"{r['drift_total_m'] * 1e3:.1f}", f"{r['sinkage_m'] * 1e3:.1f}", f"{r['wall_s']:.0f}",
                     "pass" if _glide.passes(r) else "FAIL"])
        print(f"[glide_warp] {solve}: {r['wall_s']:.0f} s", flush=True)
    print(_table(["solve", "rest by s", "drift after rest mm", "drift total mm", "trunk sinkage mm", "wall s",
                  f"verdict (rest by {_glide.REST_BY:g} s, drift < {_glide.DRIFT_MAX * 1e3:g} mm)"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
