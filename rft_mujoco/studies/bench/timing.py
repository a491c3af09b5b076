"""Timing helpers of the benchmarks: medians of repeats, the machine line, the quadruped."""

from __future__ import annotations

import os
import platform
import time

import mujoco
import numpy as np

STEPS_PER_RUN = 200
"""Consecutive steps per timed run of a scene (0.4 s of the quadruped at its 2 ms step)."""


def median_time(fn, repeats: int = 7, min_time: float = 0.02) -> float:
    """Median seconds per call of ``fn()`` over ``repeats`` repeats of at least ``min_time`` s each."""
    fn()
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_time or n >= 1 << 20:
            break
        n = max(2 * n, int(n * min_time / max(dt, 1e-9) * 1.2))
    samples = [dt / n]
    for _ in range(repeats - 1):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        samples.append((time.perf_counter() - t0) / n)
    return float(np.median(samples))


def machine() -> str:
    """One line: CPU, cores, OS, and the versions the timings depend on."""
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    cores = os.cpu_count()
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = cores
    try:
        import numba
        nb = numba.__version__
    except Exception:
        nb = "not available"
    return (f"machine: {cpu}, {cores} logical cores ({usable} usable), {platform.system()} "
            f"{platform.machine()}; python {platform.python_version()}, numpy {np.__version__}, numba {nb}, "
            f"mujoco {mujoco.__version__}")


def quadruped() -> mujoco.MjModel:
    """The bundled quadruped (``models/quadruped.xml``: rigid floor, ``home`` keyframe)."""
    from rft_mujoco.models import path
    return mujoco.MjModel.from_xml_path(str(path("quadruped.xml")))


def state_of(model, data) -> np.ndarray:
    """The full physics state of ``data``."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    return state


def settled_state(model, data, seconds: float = 0.5) -> np.ndarray:
    """The state after ``seconds`` of standing from the ``home`` keyframe (servos holding it)."""
    mujoco.mj_resetDataKeyframe(model, data, 0)
    if model.nu:
        data.ctrl[:] = data.qpos[7:7 + model.nu]
    for _ in range(int(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    return state_of(model, data)


def step_time(model, data, state, repeats: int = 7, steps: int = STEPS_PER_RUN, ctrl=None) -> float:
    """s per mj_step: median over ``repeats`` runs of ``steps`` consecutive steps from ``state`` (a real
    trajectory; the restore is not timed). ``ctrl``: optional (steps, nu) controls, one row per step."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    samples = []
    for _ in range(repeats):
        mujoco.mj_setState(model, data, state, spec)
        t0 = time.perf_counter()
        if ctrl is None:
            for _ in range(steps):
                mujoco.mj_step(model, data)
        else:
            for row in ctrl[:steps]:
                data.ctrl[:] = row
                mujoco.mj_step(model, data)
        samples.append((time.perf_counter() - t0) / steps)
    return float(np.median(samples))
