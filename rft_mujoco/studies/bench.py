"""Speed and speed-accuracy benchmarks: ``python -m rft_mujoco bench [--quick] [--out DIR]``.

Prints tables and writes plots to ``out/bench/`` (``--out``). Every time is the median of several repeats
(each repeat long enough for the clock), single thread, on whatever else the machine is doing: compare
numbers from one run, not across machines. Sections:

1. **Element throughput** (ns per element at N = 1e3 ... 1e6): :func:`rft_mujoco.physics.law.element_forces` (numpy,
   the straightforward vectorized baseline) against :func:`rft_mujoco.compiled.elements.element_forces` (numba), and
   the coupling's kernel, :func:`rft_mujoco.physics.elements.body_wrenches` (numpy) against
   :func:`rft_mujoco.compiled.elements.wrenches` (numba, preallocated outputs). Elements: random unit normals,
   all submerged (depth 1..30 cm), random velocities, 8 bodies; about half are leading.
2. **Coupling overhead** against a bare ``mj_step`` of the same model: the quadruped of
   ``models/quadruped.xml`` standing on sand (settled for 0.5 s from its ``home`` keyframe, the floor
   replaced by the sand, every body attached), at three resolutions, with the rest treatment (the
   default), without it (``stabilize=False``), and (full run) with the numpy backend; each timing is the median over runs of :data:`STEPS_PER_RUN`
   consecutive steps from the settled state (the bare model, without its floor, falls meanwhile: its step
   cost does not depend on that). Ant-v5 (gymnasium) env steps per second with and without sand
   (random actions, resets on termination), and the shipped ``rft_mujoco/SandAnt-v0`` (also with
   ``rk4_stages="first"``); the accuracy and cost of ``rk4_stages`` on SandAnt-v0 at 10, 5 and 2.5 ms steps
   against every stage at 1 ms (:func:`rk4_stages_accuracy`).
3. **Bodies above the sand**: N free spheres 1 m above the surface, all attached; the control callback
   MuJoCo calls once per evaluation is timed on its own at N = 1 and N = 1000 bodies (per body: the
   slope), next to the mj_step times with and without sand (Euler: one evaluation per step).
4. **Speed-accuracy**: the paper's validation shapes (sphere r = 5 cm; ellipsoid 7.5/4.5/4.5 cm; 7.5 cm
   cubes in the three rotations; the two right-angle prisms) centred 27 cm deep, and a quadruped foot
   (sphere r = 2 cm) centred 3 cm deep, moving at 0.1 m/s along ``(cos t, 0, sin t)`` for t in
   :data:`DIRECTIONS_DEG`; the error of the total force at each element size against a converged fine
   reference (:data:`REFERENCE_SIZE`), max over directions, and the time of one evaluation of that body
   (compiled kernel; numpy kernel alongside). The curved meshes of the validation set (half and quarter
   ellipsoids) are left out: their facets, not the elements, set their accuracy.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.compiled import elements as fastkernel
from rft_mujoco.physics import elements as kernel
from rft_mujoco.physics import law
from rft_mujoco.geometry import surface
from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS, MPM_VALIDATION
from rft_mujoco.physics.terrain import FlatSurface

DIRECTIONS_DEG = tuple(range(-90, 91, 15))
"""Motion directions (deg from the horizontal +x axis, positive up) of the speed-accuracy study."""
REFERENCE_SIZE = 0.001
"""m: element size of the converged reference of the speed-accuracy study (--quick: 2 mm); half of it for the
2 cm foot."""
SIZES = (0.03, 0.02, 0.015, 0.01, 0.0075, 0.005, 0.004, 0.003, 0.002)
"""m: element sizes of the speed-accuracy study (the presets of surface.RESOLUTIONS are added)."""
TARGET_ERROR = 0.02
"""The default preset must stay within this relative force error on every shape and direction."""
SPEED = 0.1


# --- timing ----------------------------------------------------------------------------------------
def _median_time(fn, repeats: int = 7, min_time: float = 0.02) -> float:
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


def _table(headers, rows) -> str:
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    width = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, width)) for r in cells]
    lines.insert(1, "  ".join("-" * w for w in width))
    return "\n".join(lines)


# --- 1. element throughput -------------------------------------------------------------------------
def _random_elements(n: int, n_bodies: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    local = 0.05 * rng.uniform(-1, 1, (n, 3))
    body = np.sort(rng.integers(0, n_bodies, n))
    return rng, local, nrm, rng.uniform(1e-6, 1e-5, n), body


def throughput(sizes) -> list[dict]:
    """ns per element of the numpy and numba law and kernel at each N."""
    media = MPM_VALIDATION
    out = []
    for n in sizes:
        n = int(n)
        rng, local, nrm, areas, body = _random_elements(n)
        centroids = local + [0.0, 0.0, -0.15]
        vel = rng.normal(size=(n, 3)) * SPEED
        buf = np.empty((n, 3))
        reps = 3 if n >= 1_000_000 else 5
        t_law_np = _median_time(lambda: law.element_forces(centroids, nrm, areas, vel, media), reps)
        t_law_nb = _median_time(lambda: fastkernel.element_forces(centroids, nrm, areas, vel, media, out=buf),
                                reps)
        B = 8
        pos = np.zeros((B, 3))
        pos[:, 2] = -0.15
        pos[:, 0] = np.arange(B) * 0.2
        mat = np.tile(np.eye(3), (B, 1, 1))
        com = pos + 0.001
        v_com = rng.normal(size=(B, 3)) * SPEED
        omega = rng.normal(size=(B, 3))
        octant = kernel.octants(local, np.zeros(3))
        terrain = FlatSurface(0.0)
        g_hat = np.array([0.0, 0.0, -1.0])
        gravity = np.array([0.0, 0.0, -9.81])
        t_ker_np = _median_time(lambda: kernel.body_wrenches(
            local, nrm, areas, body, B, pos, mat, com, v_com, omega, terrain, g_hat, gravity, media,
            law.PUBLISHED, None, None, 0.0, octant), reps)
        packed = fastkernel.pack(local, nrm, areas, body, B, octant)
        bodies = np.arange(B, dtype=np.int64)
        mat9 = mat.reshape(B, 9).copy()
        groups = np.empty((B, 8, 6))
        count = np.empty(B, dtype=np.int64)
        mdep = np.empty(B)
        kind, tp, heights = fastkernel.terrain_spec(terrain)
        tol = fastkernel.tolerances()
        acc = np.zeros((0, 6))
        xi = media.xi_n_at(9.81)
        scratch = np.empty((fastkernel.SCRATCH_ROWS, fastkernel.CLUSTER_SIZE))
        arrays = packed.arrays()

        def compiled_kernel():
            fastkernel.wrenches(bodies, B, *arrays, pos, mat9, com, v_com, omega, acc, 0.0, g_hat, 0.0, kind,
                                tp, heights, xi, law.COEFFICIENTS, media.mu_surf, False, False, False, tol,
                                scratch, groups, count, mdep)
        t_ker_nb = _median_time(compiled_kernel, reps)
        out.append(dict(n=n, law_numpy=t_law_np / n * 1e9, law_numba=t_law_nb / n * 1e9,
                        kernel_numpy=t_ker_np / n * 1e9, kernel_numba=t_ker_nb / n * 1e9,
                        leading=float(np.mean(count.sum() / n))))
    return out


# --- 2. coupling overhead -------------------------------------------------------------------------
STEPS_PER_RUN = 200
"""Consecutive steps per timed run of the quadruped (0.4 s of standing at its 2 ms step)."""


def _quadruped():
    path = Path(__file__).resolve().parent.parent / "models" / "quadruped.xml"
    if not path.exists():
        from importlib import resources
        path = Path(str(resources.files("rft_mujoco.models").joinpath("quadruped.xml")))
    model = mujoco.MjModel.from_xml_path(str(path))
    return model


def _settled_state(model, data, seconds: float = 0.5) -> np.ndarray:
    mujoco.mj_resetDataKeyframe(model, data, 0)
    if model.nu:
        data.ctrl[:] = data.qpos[7:7 + model.nu]
    for _ in range(int(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    return state


def _step_time(model, data, state, repeats=7, steps=STEPS_PER_RUN) -> float:
    """s per mj_step: median over ``repeats`` runs of ``steps`` consecutive steps from ``state`` (a real
    trajectory, so that the limiter's warm start carries over as in use; the restore is not timed)."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    samples = []
    for _ in range(repeats):
        mujoco.mj_setState(model, data, state, spec)
        t0 = time.perf_counter()
        for _ in range(steps):
            mujoco.mj_step(model, data)
        samples.append((time.perf_counter() - t0) / steps)
    return float(np.median(samples))


def _candidates(handle, data) -> tuple[int, int, int]:
    """(candidate bodies, their elements, elements of bodies touching the sand) at ``data``'s state."""
    ids = handle.body_ids
    xmat = data.xmat[ids].reshape(-1, 3, 3)
    centers = data.xpos[ids] + np.einsum("bij,bj->bi", xmat, handle._bound_center)
    cand = np.flatnonzero(-centers[:, 2] - handle._bound_radius < handle.terrain.max_height)
    counts = np.diff(handle._elem_slices)
    diag = handle.diagnostics(data)
    touching = [i for i in cand if diag.max_depth[i] > 0 or diag.submerged[i] > 0]
    return int(cand.size), int(counts[cand].sum()), int(counts[touching].sum())


def quadruped_overhead(resolutions, backends, quick: bool) -> list[dict]:
    """``backends``: (backend, stabilize, warm_start) triples."""
    rows = []
    for res in resolutions:
        for backend, stabilize, warm in backends:
            model = _quadruped()
            data = mujoco.MjData(model)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, res, stabilize=stabilize,
                                backend=backend, monitor=False)
                handle.replace_rigid(["floor"])
                state = _settled_state(model, data)
                mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
                mujoco.mj_forward(model, data)
                n_cand_b, n_cand_e, n_touch_e = _candidates(handle, data)
                reps = 3 if backend == "numpy" else 7
                t_sand = _step_time(model, data, state, reps)
            handle.detach()
            model.geom_contype[0] = model.geom_conaffinity[0] = 0   # bare: the same model, no floor
            t_bare = _step_time(model, data, state, reps)
            rows.append(dict(resolution=res, element_size=surface.element_size(res), backend=backend,
                             stabilize=stabilize, warm_start=warm and stabilize and backend == "numba",
                             elements=handle.n_elements, cand_bodies=n_cand_b,
                             cand_elements=n_cand_e, touch_elements=n_touch_e, bare_us=t_bare * 1e6,
                             sand_us=t_sand * 1e6, ratio=t_sand / t_bare))
    return rows


def ant_overhead(steps: int) -> dict | None:
    try:
        import gymnasium as gym
    except ImportError:
        return None

    def run(env) -> float:
        rng = np.random.default_rng(0)
        env.reset(seed=0)
        actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0]))
        samples = []
        for rep in range(3):
            env.reset(seed=rep)
            t0 = time.perf_counter()
            for a in actions:
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    env.reset()
            samples.append(steps / (time.perf_counter() - t0))
        return float(np.median(samples))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make("Ant-v5")
        bare = run(env)
        handle = attach(env.unwrapped.model, LI_LOOSE_GLASS_BEADS, None, 0.0, "default", monitor=False)
        handle.replace_rigid(["floor"])
        sand = run(env)
        touched = int(np.count_nonzero(handle.diagnostics(env.unwrapped.data).submerged))
        n_el = handle.n_elements
        handle.detach()
        env.close()
        sand_env = None
        try:
            from rft_mujoco import envs  # noqa: F401  (registers the sand ids)
            env = gym.make("rft_mujoco/SandAnt-v0")
            sand_env = run(env)
            env_elements = env.unwrapped.sand.handle.n_elements
            env_size = env.unwrapped.sand.handle.element_size
            env.unwrapped.sand.handle.rk4_stages = "first"
            sand_first = run(env)
            env.close()
        except ImportError:
            env_elements = env_size = sand_first = None
    return dict(bare_sps=bare, sand_sps=sand, fraction=sand / bare, elements=n_el, touched_bodies=touched,
                env_sps=sand_env, env_fraction=None if sand_env is None else sand_env / bare,
                env_elements=env_elements, env_element_size=env_size, first_sps=sand_first,
                first_fraction=None if sand_first is None else sand_first / bare)


def _ant_gait(mode: str, dt: float, seed: int, settle_s: float = 2.0, gait_s: float = 4.0):
    """SandAnt-v0 with step ``dt`` (env dt kept at 0.05 s) and ``rk4_stages=mode``: settle 2 s with zero
    action, then 4 s of a fixed sinusoidal gait (amplitude 0.3, 1 Hz, diagonal legs in phase). Returns
    (torso height after settling m, torso xy displacement during the gait (2,) m, wall s)."""
    import gymnasium as gym

    from rft_mujoco import envs  # noqa: F401  (registers the sand ids)
    env = gym.make("rft_mujoco/SandAnt-v0", max_episode_steps=10 ** 6)
    u = env.unwrapped
    u.sand.handle.rk4_stages = mode
    u.model.opt.timestep = dt
    u.frame_skip = int(round(0.05 / dt))
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for _ in range(int(round(settle_s / 0.05))):
        env.step(np.zeros(8))
    z = float(u.data.qpos[2])
    start = u.data.qpos[:2].copy()
    for i in range(int(round(gait_s / 0.05))):
        ph = 2.0 * np.pi * i * 0.05
        a = 0.3 * np.array([np.sin(ph), np.cos(ph), -np.sin(ph), -np.cos(ph)] * 2)
        env.step(a)
    wall = time.perf_counter() - t0
    disp = u.data.qpos[:2] - start
    env.close()
    return z, disp, wall


def rk4_stages_accuracy(quick: bool) -> list[dict] | None:
    """``attach(rk4_stages=...)`` on SandAnt-v0 (RK4): "all" against "first" at 10, 5 and 2.5 ms steps,
    errors against "all" at 1 ms, averaged over seeds (the reset noise): the torso height after settling
    and the displacement of the gait (:func:`_ant_gait`); cost as wall ms per simulated second."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return None
    seeds = range(2 if quick else 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = [_ant_gait("all", 0.001, s) for s in seeds]
        rows = []
        for dt in (0.01, 0.005, 0.0025):
            for mode in ("all", "first"):
                runs = [_ant_gait(mode, dt, s) for s in seeds]
                rows.append(dict(
                    mode=mode, dt=dt, evaluations=(4 if mode == "all" else 1) * int(round(0.05 / dt)),
                    settle_err_mm=1e3 * float(np.mean([r[0] - q[0] for r, q in zip(runs, ref)])),
                    disp_err_m=float(np.mean([np.linalg.norm(r[1] - q[1]) for r, q in zip(runs, ref)])),
                    ref_disp_m=float(np.mean([np.linalg.norm(q[1]) for q in ref])),
                    ms_per_s=1e3 * float(np.mean([r[2] for r in runs])) / 6.0))
    return rows


def above_sand(counts=(1, 1000)) -> dict:
    """Cost of bodies above the sand, per evaluation: N free spheres (r 5 cm, 1 m above the surface), all
    attached. Times the control callback itself (``mujoco.get_mjcb_control()(model, data)``, what MuJoCo
    calls once per evaluation: dispatcher, broadphase, nothing else) at N = counts[0] and counts[1];
    per body = the slope. Also the mj_step time with and without sand at both N (Euler: one evaluation a
    step)."""
    res = {}
    for n in counts:
        bodies = "".join(f'<body pos="{0.3 * (i % 40)} {0.3 * (i // 40)} 1.0"><freejoint/>'
                         f'<geom type="sphere" size="0.05" mass="1"/></body>' for i in range(n))
        xml = f'<mujoco><option integrator="Euler"/><worldbody>{bodies}</worldbody></mujoco>'
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(model, spec))
        mujoco.mj_getState(model, data, state, spec)
        t_bare = _step_time(model, data, state, 9)
        handle = attach(model, MPM_VALIDATION, None, 0.0, "default", monitor=False)
        callback = mujoco.get_mjcb_control()
        t_cb = _median_time(lambda: callback(model, data), 9)
        t_sand = _step_time(model, data, state, 9)
        assert handle.evaluations > 0 and not handle.diagnostics(data).submerged.any()
        elements = handle.n_elements
        handle.detach()
        res[n] = (t_bare, t_sand, t_cb, elements)
    (n0, (b0, s0, c0, e0)), (n1, (b1, s1, c1, e1)) = sorted(res.items())
    return dict(counts=(n0, n1), bare_us=(b0 * 1e6, b1 * 1e6), sand_us=(s0 * 1e6, s1 * 1e6),
                callback_us=(c0 * 1e6, c1 * 1e6), elements=(e0, e1),
                per_body_ns=(c1 - c0) / (n1 - n0) * 1e9, fixed_us=c0 * 1e6)


# --- 4. speed-accuracy -------------------------------------------------------------------------------
def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {"y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def accuracy_shapes() -> dict:
    """name -> (elements(size) function, rotation (3, 3), centre depth m, description)."""
    from rft_mujoco.studies import shapes as mesh_shapes
    cube = [0.0375] * 3
    out = {
        "sphere": (lambda h: surface.sphere(0.05, h), np.eye(3), 0.27, "sphere r 5 cm"),
        "ellipsoid": (lambda h: surface.ellipsoid([0.075, 0.045, 0.045], h), np.eye(3), 0.27,
                      "ellipsoid 7.5/4.5/4.5 cm"),
        "cube_z45": (lambda h: surface.box(cube, h), _rot("z", math.pi / 4), 0.27, "7.5 cm cube, z pi/4"),
        "cube_y60z45": (lambda h: surface.box(cube, h), _rot("z", math.pi / 4) @ _rot("y", math.pi / 3), 0.27,
                        "7.5 cm cube, y pi/3 then z pi/4"),
        "cube_y30z60": (lambda h: surface.box(cube, h), _rot("z", math.pi / 3) @ _rot("y", math.pi / 6), 0.27,
                        "7.5 cm cube, y pi/6 then z pi/3"),
    }
    for orient in ("corner", "keel"):
        v, f = mesh_shapes.right_prism(0.075, 0.075, orient)
        out[f"prism_{orient}"] = (lambda h, v=v, f=f: surface.mesh(v, f, h), np.eye(3), 0.27,
                                  f"right prism 7.5 cm, {orient}")
    out["foot"] = (lambda h: surface.sphere(0.02, h), np.eye(3), 0.03, "quadruped foot: sphere r 2 cm, 3 cm deep")
    return out


def _forces(el, rot, depth, directions) -> np.ndarray:
    c = el.centroids @ rot.T + [0.0, 0.0, -depth]
    n = el.normals @ rot.T
    out = []
    for t in np.radians(directions):
        v = np.tile([math.cos(t) * SPEED, 0.0, math.sin(t) * SPEED], (len(el), 1))
        out.append(fastkernel.element_forces(c, n, el.areas, v, MPM_VALIDATION).sum(axis=0))
    return np.array(out)


def _evaluation_time(el, rot, depth) -> tuple[float, float]:
    """Seconds per evaluation of one body with these elements: compiled and numpy kernel."""
    n = len(el)
    local, nrm, areas = np.ascontiguousarray(el.centroids), np.ascontiguousarray(el.normals), el.areas.copy()
    body = np.zeros(n, dtype=np.int64)
    pos = np.array([[0.0, 0.0, -depth]])
    mat = rot[None].copy()
    v_com = np.array([[SPEED * math.cos(0.3), 0.0, -SPEED * math.sin(0.3)]])
    omega = np.zeros((1, 3))
    octant = kernel.octants(local, np.zeros(3))
    terrain = FlatSurface(0.0)
    g_hat, gravity = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, -9.81])
    kind, tp, heights = fastkernel.terrain_spec(terrain)
    tol = fastkernel.tolerances()
    groups, count, mdep = np.empty((1, 8, 6)), np.empty(1, dtype=np.int64), np.empty(1)
    arrays = fastkernel.pack(local, nrm, areas, body, 1, octant).arrays()
    bodies = np.zeros(1, dtype=np.int64)
    mat9 = mat.reshape(1, 9).copy()
    acc = np.zeros((0, 6))
    xi = MPM_VALIDATION.xi_n_at(9.81)
    scratch = np.empty((fastkernel.SCRATCH_ROWS, fastkernel.CLUSTER_SIZE))

    def compiled():
        fastkernel.wrenches(bodies, 1, *arrays, pos, mat9, pos, v_com, omega, acc, 0.0, g_hat, 0.0, kind, tp,
                            heights, xi, law.COEFFICIENTS, MPM_VALIDATION.mu_surf, False, False, False, tol,
                            scratch, groups, count, mdep)

    def numpy_kernel():
        kernel.body_wrenches(local, nrm, areas, body, 1, pos, mat, pos, v_com, omega, terrain, g_hat, gravity,
                             MPM_VALIDATION, law.PUBLISHED, None, None, 0.0, octant)
    return _median_time(compiled, 5, 0.01), _median_time(numpy_kernel, 3, 0.01)


def speed_accuracy(quick: bool) -> list[dict]:
    ref_size = 0.002 if quick else REFERENCE_SIZE
    sizes = sorted(set(SIZES) | set(surface.RESOLUTIONS.values()), reverse=True)
    sizes = [h for h in sizes if h > ref_size * 1.01]
    directions = DIRECTIONS_DEG[::2] if quick else DIRECTIONS_DEG
    rows = []
    for name, (make, rot, depth, _) in accuracy_shapes().items():
        h_ref = ref_size / 2 if name == "foot" else ref_size     # the foot is 2.5x smaller
        ref = _forces(make(h_ref), rot, depth, directions)
        ref_check = _forces(make(h_ref * 1.5), rot, depth, directions)
        ref_err = float(np.max(np.linalg.norm(ref_check - ref, axis=1) / np.linalg.norm(ref, axis=1)))
        for h in sizes:
            el = make(h)
            f = _forces(el, rot, depth, directions)
            err = np.linalg.norm(f - ref, axis=1) / np.linalg.norm(ref, axis=1)
            t_nb, t_np = _evaluation_time(el, rot, depth)
            preset = [k for k, v in surface.RESOLUTIONS.items() if v == h]
            rows.append(dict(shape=name, size=h, preset=preset[0] if preset else "", elements=len(el),
                             max_error=float(err.max()), worst_dir=int(directions[int(err.argmax())]),
                             mean_error=float(err.mean()), numba_us=t_nb * 1e6, numpy_us=t_np * 1e6,
                             ref_size=h_ref, ref_error=ref_err))
    return rows


# --- plots ----------------------------------------------------------------------------------------------
def _plots(out: Path, thr, quad, acc) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    n = [r["n"] for r in thr]
    for key, style, label in (("law_numpy", "o--", "element_forces, numpy"),
                              ("law_numba", "o-", "element_forces, numba"),
                              ("kernel_numpy", "s--", "coupling kernel, numpy"),
                              ("kernel_numba", "s-", "coupling kernel, numba")):
        ax.loglog(n, [r[key] for r in thr], style, label=label)
    ax.set_xlabel("elements N")
    ax.set_ylabel("ns per element (single thread)")
    ax.set_title("3D-RFT element throughput")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    files.append(out / "throughput.png")
    fig.savefig(files[-1], dpi=120)
    plt.close(fig)

    if quad:
        fig, ax = plt.subplots(figsize=(12, 4.5))
        labels = [f"{r['resolution']}\n{r['backend']}\n"
                  f"{'no stab.' if not r['stabilize'] else 'warm start' if r['warm_start'] else 'default'}"
                  for r in quad]
        x = np.arange(len(quad))
        ax.bar(x - 0.2, [r["bare_us"] for r in quad], 0.4, label="bare mj_step")
        ax.bar(x + 0.2, [r["sand_us"] for r in quad], 0.4, label="mj_step with sand")
        for i, r in enumerate(quad):
            ax.text(x[i] + 0.2, r["sand_us"], f"{r['ratio']:.0f}x", ha="center", va="bottom", fontsize=7)
        ax.hlines([5.0 * r["bare_us"] for r in quad], x - 0.45, x + 0.45, colors="k", linestyles=":",
                  label="target: 5 x bare")
        ax.set_xticks(x, labels, fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel("us per step")
        ax.set_title("quadruped on sand: cost per step")
        ax.legend()
        ax.grid(True, axis="y", which="both", alpha=0.3)
        fig.tight_layout()
        files.append(out / "overhead.png")
        fig.savefig(files[-1], dpi=120)
        plt.close(fig)

    shapes = list(dict.fromkeys(r["shape"] for r in acc))
    curved = [s for s in shapes if any(r["max_error"] > 1e-9 for r in acc if r["shape"] == s)]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    for s in curved:
        rows = [r for r in acc if r["shape"] == s]
        line, = ax.loglog([r["numba_us"] for r in rows], [r["max_error"] * 100 for r in rows], "o-", label=s,
                          ms=3)
        for r in rows:
            if r["preset"]:
                ax.plot(r["numba_us"], r["max_error"] * 100, "s", color=line.get_color(), ms=7, mfc="none")
                ax.annotate(r["preset"], (r["numba_us"], r["max_error"] * 100), fontsize=7,
                            xytext=(4, 4), textcoords="offset points")
    ax.axhline(TARGET_ERROR * 100, color="k", lw=0.8, ls=":")
    ax.set_xlabel("us per evaluation of the body (numba kernel)")
    ax.set_ylabel("max relative force error over directions (%)")
    flat = [s for s in shapes if s not in curved]
    ax.set_title(f"curved shapes (squares: presets); exact at every size: {', '.join(flat)}", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    for s in shapes:
        rows = [r for r in acc if r["shape"] == s]
        ax2.loglog([r["elements"] for r in rows], [r["numba_us"] for r in rows], "o-", ms=3, label=s)
    ax2.set_xlabel("elements of the body")
    ax2.set_ylabel("us per evaluation (numba kernel)")
    ax2.set_title("cost of one evaluation of one body", fontsize=9)
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    files.append(out / "error_vs_cost.png")
    fig.savefig(files[-1], dpi=120)
    plt.close(fig)
    return files


# --- main ----------------------------------------------------------------------------------------------
def run(quick: bool = False, out: str | Path = "out/bench", plots: bool = True) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    print(machine())
    compile_s = fastkernel.ensure_compiled()
    print(f"numba kernel ready in {compile_s:.2f} s (cache load or compile)\n")

    print("1. Element throughput, ns per element (single thread; median of repeats)")
    thr = throughput([1e3, 1e4, 1e5] if quick else [1e3, 1e4, 1e5, 1e6])
    print(_table(["N", "law numpy", "law numba", "speedup", "kernel numpy", "kernel numba", "speedup"],
                 [[f"{r['n']:.0e}", f"{r['law_numpy']:.1f}", f"{r['law_numba']:.1f}",
                   f"{r['law_numpy'] / r['law_numba']:.1f}x", f"{r['kernel_numpy']:.1f}",
                   f"{r['kernel_numba']:.1f}", f"{r['kernel_numpy'] / r['kernel_numba']:.1f}x"] for r in thr]))

    print("\n2a. Quadruped (models/quadruped.xml) standing on sand, every body attached: us per mj_step")
    backends = [("numba", True, False), ("numba", False, False)] + (
        [] if quick else [("numpy", True, False)])
    quad = quadruped_overhead(["coarse", "default", "fine"], backends, quick)
    print(_table(["resolution", "backend", "stabilize", "warm start", "elements", "cand. bodies",
                  "cand. elements", "touching el.", "bare us", "sand us", "ratio"],
                 [[f"{r['resolution']} ({r['element_size'] * 1000:g} mm)", r["backend"], r["stabilize"],
                   r["warm_start"], r["elements"], r["cand_bodies"], r["cand_elements"], r["touch_elements"],
                   f"{r['bare_us']:.1f}", f"{r['sand_us']:.1f}", f"{r['ratio']:.2f}x"] for r in quad]))

    print("\n2b. Ant-v5 (gymnasium, frame_skip 5, RK4: 20 sand evaluations per env step), env steps/s")
    ant = ant_overhead(300 if quick else 1000)
    if ant is None:
        print("gymnasium not installed: skipped")
    else:
        rows = [["Ant-v5 + attach(resolution='default')", f"{ant['bare_sps']:.0f}", f"{ant['sand_sps']:.0f}",
                 f"{ant['fraction']:.2f}", ant["elements"]]]
        if ant["env_sps"] is not None:
            rows.append([f"rft_mujoco/SandAnt-v0 ({ant['env_element_size'] * 1000:g} mm elements)",
                         f"{ant['bare_sps']:.0f}", f"{ant['env_sps']:.0f}", f"{ant['env_fraction']:.2f}",
                         ant["env_elements"]])
            rows.append(["SandAnt-v0, rk4_stages='first' (see 2c)", f"{ant['bare_sps']:.0f}",
                         f"{ant['first_sps']:.0f}", f"{ant['first_fraction']:.2f}", ant["env_elements"]])
        print(_table(["sand", "Ant-v5", "on sand", "fraction", "elements"], rows))

    print("\n2c. RK4 stages on SandAnt-v0: sand at every stage ('all', default) or at the first only, held "
          "('first');\n    errors against 'all' at 1 ms (mean over seeds): torso height after 2 s of "
          "settling, torso displacement over 4 s of a fixed gait")
    stages = rk4_stages_accuracy(quick)
    if stages is None:
        print("gymnasium not installed: skipped")
    else:
        print(_table(["rk4_stages", "dt ms", "evaluations per env step", "settle err mm", "gait err m",
                      "gait (ref) m", "wall ms per sim s"],
                     [[r["mode"], f"{r['dt'] * 1e3:g}", r["evaluations"], f"{r['settle_err_mm']:+.2f}",
                       f"{r['disp_err_m']:.3f}", f"{r['ref_disp_m']:.3f}", f"{r['ms_per_s']:.0f}"]
                      for r in stages]))

    print("\n3. Bodies above the sand (free spheres r 5 cm, 1 m up; Euler: 1 evaluation per step)")
    above = above_sand()
    n0, n1 = above["counts"]
    print(_table(["bodies", "elements", "callback us (1 evaluation)", "bare mj_step us", "mj_step with sand us"],
                 [[n, above["elements"][i], f"{above['callback_us'][i]:.2f}", f"{above['bare_us'][i]:.2f}",
                   f"{above['sand_us'][i]:.2f}"] for i, n in enumerate((n0, n1))]))
    print(f"per body above the sand: {above['per_body_ns']:.1f} ns per evaluation (slope of the callback time "
          f"from {n0} to {n1} bodies); whole callback with {n0} body above the sand: {above['fixed_us']:.2f} us")

    print(f"\n4. Speed-accuracy: max relative force error over {len(DIRECTIONS_DEG[::2] if quick else DIRECTIONS_DEG)} "
          "directions in the xz-plane against the reference; us per evaluation of the body")
    acc = speed_accuracy(quick)
    print(_table(["shape", "size mm", "preset", "elements", "max err %", "worst dir", "mean err %",
                  "numba us", "numpy us"],
                 [[r["shape"], f"{r['size'] * 1000:g}", r["preset"], r["elements"], f"{r['max_error'] * 100:.3f}",
                   r["worst_dir"], f"{r['mean_error'] * 100:.3f}", f"{r['numba_us']:.2f}", f"{r['numpy_us']:.0f}"]
                  for r in acc]))
    refs = {r["shape"]: (r["ref_size"], r["ref_error"]) for r in acc}
    print("reference: " + "; ".join(f"{s} {h * 1000:g} mm (vs {1.5 * h * 1000:g} mm: {e * 100:.3f}%)"
                                    for s, (h, e) in refs.items()))
    print("\nPresets (surface.RESOLUTIONS): max error % over directions / us per evaluation (numba), per shape")
    shape_names = list(dict.fromkeys(r["shape"] for r in acc))
    preset_rows = []
    for name, h in surface.RESOLUTIONS.items():
        rows = {r["shape"]: r for r in acc if r["size"] == h}
        if rows:
            worst = max(rows.values(), key=lambda r: r["max_error"])
            preset_rows.append([f"{name} ({h * 1000:g} mm)"]
                               + [f"{rows[s]['max_error'] * 100:.2f} / {rows[s]['numba_us']:.1f}" if s in rows
                                  else "-" for s in shape_names]
                               + [f"{worst['max_error'] * 100:.2f} ({worst['shape']})"])
    print(_table(["preset"] + shape_names + ["worst"], preset_rows))
    default = [r for r in acc if r["size"] == surface.RESOLUTIONS["default"]]
    worst = max(r["max_error"] for r in default) if default else float("nan")
    print(f"default preset: worst error {worst * 100:.2f}% (target {TARGET_ERROR * 100:g}%): "
          f"{'met' if worst <= TARGET_ERROR else 'NOT met'}")

    files = _plots(out, thr, quad, acc) if plots else []
    if files:
        print("\nwrote " + ", ".join(str(f) for f in files))
    return dict(throughput=thr, quadruped=quad, ant=ant, stages=stages, above=above, accuracy=acc,
                files=files)


def main(argv: list[str] | None = None, command: str = "bench") -> int:
    """CLI entry: ``python -m rft_mujoco bench [--quick] [--out DIR] [--no-plots]``."""
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="Speed and speed-accuracy benchmarks: tables and plots.")
    parser.add_argument("--quick", action="store_true",
                        help="N up to 1e5, fewer directions, 2 mm reference, no numpy quadruped (~1 min)")
    parser.add_argument("--out", default="out/bench", help="output folder for plots (default: out/bench)")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    args = parser.parse_args(argv)
    if not fastkernel.AVAILABLE:
        print(f"numba is not available ({fastkernel.IMPORT_ERROR}): the benchmarks compare it with numpy")
        return 1
    run(quick=args.quick, out=args.out, plots=not args.no_plots)
    return 0
