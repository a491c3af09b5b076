"""The swim study's kinematic swimmer on the batched sand (MuJoCo Warp): one world per amplitude, the same drive,
model and measurement as :func:`rft_mujoco.studies.swim.swim` (needs the optional extra ``rft_mujoco[warp]``).

What it is for: the any-mass check of the implicit solve on the warp path (issue 26, docs/warp.md, "The implicit
solve"): at the animal's density the wave efficiency must meet the inertia-free limit of
:func:`rft_mujoco.studies.quasistatic.swimmer_limit` as the CPU path's does.

    python -c "from rft_mujoco.studies.swim_warp import swim_batched; print(swim_batched((0.5, 0.9)))"
"""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np

from rft_mujoco.physics.media import MALADEN_GLASS_BEADS
from rft_mujoco.studies import swim as _swim


def swim_batched(amplitudes=(0.5, 0.9), frequency: float = 1.0,
                 *, density_scale: float = 1.0, timestep: float = 0.002, cycles: int = _swim.CYCLES,
                 resolution: str | float = 0.003, solve: str = "implicit", device: str = "cpu",
                 progress=None) -> list[dict]:
    """Swim the bundled swimmer in ``len(amplitudes)`` warp worlds at once (amplitudes in rad, frequency in Hz,
    ``timestep`` s, ``resolution`` m or a name); ``solve`` and the density (times the animal's) as in
    :func:`rft_mujoco.studies.swim.swim`. Returns one dict per amplitude: ``eta`` (speed over frequency times
    wavelength), ``speed_mps``, ``a_over_lambda``, ``tracking_rms_rad``, and the run's ``wall_s`` and
    ``steps``. ``progress``: called with a line every cycle (e.g. ``print``)."""
    import mujoco_warp as mjw
    import warp as wp

    import rft_mujoco.warp as rw

    amps = np.asarray(amplitudes, dtype=float).reshape(-1)
    if amps.size == 0 or not np.all(np.isfinite(amps)):
        raise ValueError(f"amplitudes must be one or more finite angles in rad, got {amplitudes!r}")
    model = _swim._model(density_scale, timestep)
    model.geom_contype[model.geom("floor").id] = model.geom_conaffinity[model.geom("floor").id] = 0
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    n, nj = amps.size, _swim.N_JOINTS
    dt = model.opt.timestep
    steps = int(round(cycles / frequency / dt))
    start = int(round((cycles - _swim.MEASURED_CYCLES) / frequency / dt))
    head = model.body("head").id
    t0 = time.perf_counter()
    with wp.ScopedDevice(device):
        m = mjw.put_model(model)
        d = mjw.put_data(model, data, nworld=n, nconmax=4, njmax=8 * nj)
        sand = rw.attach(model, m, MALADEN_GLASS_BEADS, None, 0.0, resolution, solve=solve, data=d)
        err2, com0 = np.zeros(n), None
        try:
            for k in range(steps):
                ctrl = _swim.serpenoid(amps[:, None], frequency, k * dt)
                d.ctrl.assign(ctrl.astype(np.float32))
                mjw.step(m, d)
                if k == start:
                    com0 = d.subtree_com.numpy()[:, head, :2].astype(float)
                if k >= start:
                    err2 += np.sum((d.qpos.numpy()[:, 3:].astype(float) - ctrl) ** 2, axis=1)
                if progress is not None and (k + 1) % int(round(1.0 / frequency / dt)) == 0:
                    progress(f"swim_batched: cycle {(k + 1) * dt * frequency:.0f}/{cycles} "
                             f"({time.perf_counter() - t0:.0f} s)")
            disp = d.subtree_com.numpy()[:, head, :2].astype(float) - com0
            sand.check(d)
        finally:
            sand.detach()
    wall = time.perf_counter() - t0
    span = _swim.MEASURED_CYCLES / frequency
    out = []
    for i, amp in enumerate(amps):
        ratio, lam, _length = _swim.wave_shape(float(amp))
        speed = float(np.linalg.norm(disp[i]) / span)
        out.append(dict(amplitude_rad=float(amp), density_scale=density_scale, timestep_s=dt, solve=solve,
                        element_size_m=resolution, a_over_lambda=ratio, speed_mps=speed,
                        eta=speed / (frequency * lam),
                        tracking_rms_rad=math.sqrt(err2[i] / max((steps - start) * nj, 1)), wall_s=wall,
                        steps=steps))
    return out
