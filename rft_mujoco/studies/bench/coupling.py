"""Benchmark sections on the coupling: the quadruped's step with sand against its bare step (standing and
trotting), env steps per second with zero and random actions, RK4 stages, bodies above the sand."""

from __future__ import annotations

import functools
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.book import RK4_STAGES
from rft_mujoco.coupling.handle import attach
from rft_mujoco.geometry import surface
from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS, MPM_VALIDATION
from rft_mujoco.studies.bench.timing import STEPS_PER_RUN, median_time, quadruped, settled_state, state_of, step_time

MOTIONS = ("standing", "trotting")
"""What the quadruped does while it is timed: stands still (servos holding ``home``), or trots (the scripted
gait of :class:`rft_mujoco.models.quadruped.TrotGait`, timed after 1 s of trotting)."""


def _trot(model, data, state) -> tuple[np.ndarray, np.ndarray]:
    """(state after 1 s of trotting from ``state``, the controls of the next STEPS_PER_RUN steps)."""
    from rft_mujoco.models.quadruped import TrotGait

    gait = TrotGait.from_model(model)
    mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    dt = model.opt.timestep
    steps = int(round(1.0 / dt))
    for i in range(steps):
        data.ctrl[:] = gait.targets(i * dt)
        mujoco.mj_step(model, data)
    ctrl = np.array([gait.targets((steps + i) * dt) for i in range(STEPS_PER_RUN)])
    return state_of(model, data), ctrl


def _hold(data) -> np.ndarray:
    """The controls of STEPS_PER_RUN steps holding ``data``'s targets (the standing scene: ``mj_setState`` leaves
    the controls alone, so without them a standing run would chase whatever targets the last run left)."""
    return np.repeat(data.ctrl[None, :], STEPS_PER_RUN, axis=0)


def _touching_elements(handle, data) -> int:
    """Elements of the bodies that touch the sand at ``data``'s state."""
    counts = np.diff(handle.layout.elem_slices)
    d = handle.diagnostics(data)
    return int(counts[(d.submerged > 0) | (d.max_depth > 0)].sum())


def quadruped_overhead(resolutions, settings) -> list[dict]:
    """us per mj_step of the quadruped on sand (every body attached, the floor replaced by the sand)
    against the same model's bare step (no floor, no sand), for each resolution, setting and motion.

    ``settings``: dicts of ``attach`` keywords (``stabilize``, ``backend``, ``cull``), each with a ``name``."""
    rows = []
    for res in resolutions:
        for setting in settings:
            kwargs = {k: v for k, v in setting.items() if k != "name"}
            model = quadruped()
            data = mujoco.MjData(model)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, res, monitor=False, **kwargs)
                handle.replace_rigid(["floor"])
                stand = settled_state(model, data)
                scenes = {"standing": (stand, _hold(data)), "trotting": _trot(model, data, stand)}
                reps = 3 if kwargs.get("backend") == "numpy" else 7
                timed = {}
                for motion, (state, ctrl) in scenes.items():
                    mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
                    mujoco.mj_forward(model, data)
                    touching = _touching_elements(handle, data)
                    timed[motion] = (step_time(model, data, state, reps, ctrl=ctrl), touching)
            handle.detach()
            model.geom_contype[0] = model.geom_conaffinity[0] = 0   # bare: the same model, no floor
            for motion, (state, ctrl) in scenes.items():
                t_bare = step_time(model, data, state, reps, ctrl=ctrl)
                t_sand, touching = timed[motion]
                rows.append(dict(resolution=res, element_size=surface.element_size(res), setting=setting["name"],
                                 motion=motion, elements=handle.n_elements, touch_elements=touching,
                                 bare_us=t_bare * 1e6, sand_us=t_sand * 1e6, ratio=t_sand / t_bare))
    return rows


ENV_IDS = ("Ant-v5", "rft_mujoco/SandAnt-v0", "rft_mujoco/SandQuadruped-v0", "rft_mujoco/SandQuadruped-v1")
"""Envs whose steps per second :func:`env_rates` measures (those registered in this installation)."""


def _env_run(env, actions, seed: int) -> float:
    """Env steps/s of one run of ``actions`` from a reset (resets on termination, not timed apart)."""
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return len(actions) / (time.perf_counter() - t0)


ENV_SETTINGS = {None: {}, "no reuse": {"reuse_tol": 0.0}}
"""``gym.make`` keywords of :func:`env_rates`' named entries other than a solve's name."""


def env_rates(steps: int, rounds: int = 5, solves: tuple = (None,)) -> list[dict] | None:
    """Env steps per second of :data:`ENV_IDS` with zero actions (a robot standing still) and uniform
    random actions; None without gymnasium.

    This machine's speed drifts by 10% within a minute, so every ratio is measured side by side: each of
    ``rounds`` rounds runs every env with both action sets once (``steps`` steps from a reset with seed =
    the round), and a ratio (zero / random, SandAnt / Ant) is the median of its per-round ratios; the
    rates are the medians of the rounds. ``solves``: the sand envs once per entry (None: the envs' default;
    ``"explicit"`` / ``"implicit"``: ``gym.make(..., solve=...)``; ``"no reuse"``: ``reuse_tol=0``,
    :data:`ENV_SETTINGS`), interleaved in the same rounds; each row's ``solve`` says which ("default" for None
    and for Ant-v5)."""
    try:
        import gymnasium as gym

        from rft_mujoco import envs  # noqa: F401  (registers the sand ids)
    except ImportError:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        made = {}
        for env_id in ENV_IDS:
            if env_id not in gym.registry:
                continue
            for solve in solves if env_id.startswith("rft_mujoco/") else (None,):
                env = gym.make(env_id, **ENV_SETTINGS.get(solve, {"solve": solve}))
                n = env.action_space.shape[0]
                rng = np.random.default_rng(0)
                made[env_id, solve] = (env, np.zeros((steps, n)),
                                       rng.uniform(env.action_space.low, env.action_space.high, (steps, n)))
        runs = {key: {"zero": [], "random": []} for key in made}
        for rnd in range(rounds):
            for key, (env, zero, rand) in made.items():
                runs[key]["zero"].append(_env_run(env, zero, rnd))
                runs[key]["random"].append(_env_run(env, rand, rnd))
        rows = []
        bare = runs.get(("Ant-v5", None))
        for (env_id, solve), (env, _, _) in made.items():
            z, r = np.array(runs[env_id, solve]["zero"]), np.array(runs[env_id, solve]["random"])
            sand = getattr(env.unwrapped, "sand", None)
            handle = getattr(sand, "handle", sand)
            over = (float(np.median(r / np.array(bare["random"]))) if bare is not None and "Ant" in env_id
                    else None)
            rows.append(dict(env=env_id, solve=solve or "default", zero_sps=float(np.median(z)),
                             random_sps=float(np.median(r)), zero_over_random=float(np.median(z / r)), over_ant=over,
                             elements=getattr(handle, "n_elements", 0), rounds=rounds))
            env.close()
    return rows


def sand_phases(env_id: str = "rft_mujoco/SandAnt-v0", settle_steps: int = 100, calls: int = 5000) -> list[dict] | None:
    """us per call of the two compiled phases of one evaluation (native route, called in a compiled loop at
    one fixed state: the robot standing after ``settle_steps`` zero-action env steps), with the rest
    treatment at a first RK4 stage and at a later one (the first stage's mobility and rest factor kept),
    and with the naive coupling; None without gymnasium or without a native route."""
    try:
        import gymnasium as gym

        from rft_mujoco import envs  # noqa: F401  (registers the sand ids)
    except ImportError:
        return None
    from rft_mujoco.coupling.dispatch import DISPATCHER

    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, kwargs in (("rest", {}), ("naive", dict(stabilize=False))):
            env = gym.make(env_id, **kwargs)
            env.reset(seed=0)
            for _ in range(settle_steps):
                env.step(np.zeros(env.action_space.shape))
            model, data = env.unwrapped.model, env.unwrapped.data
            book = DISPATCHER._books.get(data)
            if book is None or book.native is None:
                env.close()
                return None
            mujoco.mj_forward(model, data)                # a first stage: the mobility of this state is kept
            stages = ((name, 1.0), (f"{name}, RK4 stages 2-4", 2.0)) if name == "rest" else ((name, 1.0),)
            for setting, stage in stages:
                book.state[2] = stage                     # the stage the callback would record
                phase1, phase2 = _route_phases(book, model, data, calls)
                rows.append(dict(setting=setting, phase1_us=phase1, phase2_us=phase2))
            env.close()
    return rows


def quadruped_phases(calls: int = 3000) -> list[dict] | None:
    """Where the bundled quadruped's standing cost goes: one evaluation's two compiled phases (native route,
    called ``calls`` times in a compiled loop at one fixed state), us per call, with the rest treatment
    (``"rest"``) and with the naive coupling (``"naive"``), beside the bare ``mj_step`` (no floor, no sand) from
    the same state; every body attached, default resolution, the floor replaced by the sand, standing after
    0.5 s (:func:`quadruped_overhead`'s scene). Rows: ``setting``, ``phase1_us``, ``phase2_us``, ``bare_us``,
    ``loaded_elements``. None without a native route."""
    from rft_mujoco.coupling.dispatch import DISPATCHER

    rows = []
    for name in ("rest", "naive"):
        model = quadruped()
        data = mujoco.MjData(model)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, "default", monitor=False,
                            stabilize=name == "rest")
            handle.replace_rigid(["floor"])
            stand = settled_state(model, data)
        book = DISPATCHER._books.get(data)
        if book is None or book.native is None:
            handle.detach()
            return None
        mujoco.mj_forward(model, data)
        phase1, phase2 = _route_phases(book, model, data, calls)
        loaded = int(handle.diagnostics(data).submerged.sum())
        handle.detach()
        model.geom_contype[0] = model.geom_conaffinity[0] = 0   # bare: the same model, no floor
        bare = step_time(model, data, stand, 7)
        rows.append(dict(setting=name, phase1_us=phase1, phase2_us=phase2, bare_us=bare * 1e6,
                         loaded_elements=loaded))
    return rows


def _route_phases(book, model, data, calls: int) -> tuple[float, float]:
    """us per call of the native route's phase 1 alone and of phase 2 (phases 1 + 2 less phase 1) at ``data``'s
    state, each the median of :func:`median_time`'s repeats of ``calls`` calls in a compiled loop."""
    loop = _phase_loop()
    route = book.native[1]
    args = (route.address, data.time, model.opt.timestep)
    timed = {}
    for both in (False, True):
        loop(route.phase1, route.phase2, both, 10, *args)
        timed[both] = median_time(lambda: loop(route.phase1, route.phase2, both, calls, *args)) / calls
    return timed[False] * 1e6, (timed[True] - timed[False]) * 1e6


@functools.lru_cache(maxsize=1)
def _phase_loop():
    """A compiled loop calling the route's phase 1 (and phase 2 with ``both``) ``n`` times."""
    from rft_mujoco.compiled.jit import njit

    @njit
    def loop(f1, f2, both, n, addr, t, dt):
        s = 0
        for _ in range(n):
            s += f1(addr, t, dt)
            if both:
                s += f2(addr, t, dt)
        return s
    return loop


def _sand_ant(mode: str | None = None, dt: float | None = None):
    """A SandAnt-v0 env with step ``dt`` (its env dt kept at 0.05 s) and ``rk4_stages=mode`` (None: the env's)."""
    import gymnasium as gym

    from rft_mujoco import envs  # noqa: F401  (registers the sand ids)
    env = gym.make("rft_mujoco/SandAnt-v0", max_episode_steps=10 ** 6, **({} if mode is None else
                                                                         {"rk4_stages": mode}))
    if dt is not None:
        u = env.unwrapped
        u.model.opt.timestep = dt
        u.frame_skip = int(round(0.05 / dt))
    return env


def _ant_settle(mode: str, dt: float, seed: int, settle_s: float = 2.0) -> tuple[float, float]:
    """SandAnt-v0 (:func:`_sand_ant`) reset with ``seed`` and left ``settle_s`` with zero action:
    (torso height m, wall s)."""
    env = _sand_ant(mode, dt)
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for _ in range(int(round(settle_s / 0.05))):
        env.step(np.zeros(8))
    wall = time.perf_counter() - t0
    z = float(env.unwrapped.data.qpos[2])
    env.close()
    return z, wall


def ant_states(n: int, moving: bool, seed: int = 1) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``n`` SandAnt-v0 states (qpos, qvel, the action of the env step to take from it), at the defaults:
    ``moving``: every 20th env step of one random-action rollout (uniform actions); else touchdown and rest:
    1, 3, 6, 10, 20 and 39 zero-action env steps after each of a series of resets."""
    env = _sand_ant()
    u = env.unwrapped
    rng = np.random.default_rng(seed)
    out = []
    if moving:
        env.reset(seed=seed)
        while len(out) < n:
            for _ in range(20):
                env.step(rng.uniform(-1.0, 1.0, 8))
            out.append((u.data.qpos.copy(), u.data.qvel.copy(), rng.uniform(-1.0, 1.0, 8)))
    reset = seed
    while len(out) < n:                                  # touchdown and rest (moving: full already)
        env.reset(seed=reset)
        reset += 1
        for i in range(40):
            env.step(np.zeros(8))
            if i in (0, 2, 5, 9, 19, 38):
                out.append((u.data.qpos.copy(), u.data.qvel.copy(), np.zeros(8)))
    del out[n:]
    env.close()
    return out


def ant_env_step(states, mode: str, dt: float) -> np.ndarray:
    """(n, nq + nv): the state after one env step (50 ms) of SandAnt-v0 (:func:`_sand_ant`) from each of
    ``states`` (:func:`ant_states`), each after a reset (the sand remembers nothing from another state)."""
    env = _sand_ant(mode, dt)
    u = env.unwrapped
    out = []
    for qpos, qvel, action in states:
        env.reset(seed=0)
        u.set_state(qpos, qvel)
        env.step(action)
        out.append(np.concatenate([u.data.qpos, u.data.qvel]))
    env.close()
    return np.array(out)


def step_errors(got: np.ndarray, ref: np.ndarray, nq: int = 15) -> tuple[float, float]:
    """Mean torso position error (mm) and torso velocity error (mm/s) of :func:`ant_env_step` results."""
    pos = np.linalg.norm(got[:, :3] - ref[:, :3], axis=1)
    vel = np.linalg.norm(got[:, nq:nq + 3] - ref[:, nq:nq + 3], axis=1)
    return 1e3 * float(pos.mean()), 1e3 * float(vel.mean())


RK4_MODES = ("all", "midpoint", "first")


def rk4_stages_accuracy(quick: bool, n_states: int = 60, seeds: int = 3) -> list[dict] | None:
    """``attach(rk4_stages=...)`` on SandAnt-v0 (RK4): "all", "midpoint" and "first" at 10, 5 and 2.5 ms
    steps. Errors of one env step (50 ms) from ``n_states`` states while moving and ``n_states`` at touchdown
    and rest (:func:`ant_states`), against "all" at 0.5 ms: mean torso position mm and velocity mm/s; the
    torso height after 2 s of settling from ``seeds`` resets against "all" at 1 ms (mean, mm: touchdown is
    chaotic, the spread over seeds is tens of mm); cost as wall ms per simulated second of settling."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return None
    if quick:
        n_states, seeds = 12, 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        states = {k: ant_states(n_states, k == "moving") for k in ("moving", "resting")}
        ref = {k: ant_env_step(v, "all", 0.0005) for k, v in states.items()}
        z_ref = [_ant_settle("all", 0.001, s)[0] for s in range(seeds)]
        rows = []
        for dt in (0.01, 0.005, 0.0025):
            for mode in RK4_MODES:
                errs = {k: step_errors(ant_env_step(v, mode, dt), ref[k]) for k, v in states.items()}
                settle = [_ant_settle(mode, dt, s) for s in range(seeds)]
                rows.append(dict(
                    mode=mode, dt=dt, evaluations=RK4_STAGES[mode] * int(round(0.05 / dt)),
                    moving_mm=errs["moving"][0], moving_mm_s=errs["moving"][1],
                    resting_mm=errs["resting"][0], resting_mm_s=errs["resting"][1],
                    settle_err_mm=1e3 * float(np.mean([r[0] - q for r, q in zip(settle, z_ref)])),
                    ms_per_s=1e3 * float(np.mean([r[1] for r in settle])) / 2.0))
    return rows


def above_sand(counts=(1, 1000)) -> dict:
    """Cost of bodies above the sand, per evaluation: N free spheres (r 5 cm, 1 m above the surface), all
    attached. Times the control callback itself (``mujoco.get_mjcb_control()(model, data)``, what MuJoCo
    calls once per evaluation) at N = counts[0] and counts[1]; per body = the slope. Also the mj_step time
    with and without sand at both N (Euler: one evaluation a step)."""
    res = {}
    for n in counts:
        bodies = "".join(f'<body pos="{0.3 * (i % 40)} {0.3 * (i // 40)} 1.0"><freejoint/>'
                         f'<geom type="sphere" size="0.05" mass="1"/></body>' for i in range(n))
        xml = f'<mujoco><option integrator="Euler"/><worldbody>{bodies}</worldbody></mujoco>'
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        state = state_of(model, data)
        t_bare = step_time(model, data, state, 9)
        handle = attach(model, MPM_VALIDATION, None, 0.0, "default", monitor=False)
        callback = mujoco.get_mjcb_control()
        t_cb = median_time(lambda: callback(model, data), 9)
        t_sand = step_time(model, data, state, 9)
        if not (handle.evaluations > 0 and not handle.diagnostics(data).submerged.any()):
            raise RuntimeError("bodies 1 m above the sand were loaded or never evaluated")
        elements = handle.n_elements
        handle.detach()
        res[n] = (t_bare, t_sand, t_cb, elements)
    (n0, (b0, s0, c0, e0)), (n1, (b1, s1, c1, e1)) = sorted(res.items())
    return dict(counts=(n0, n1), bare_us=(b0 * 1e6, b1 * 1e6), sand_us=(s0 * 1e6, s1 * 1e6),
                callback_us=(c0 * 1e6, c1 * 1e6), elements=(e0, e1),
                per_body_ns=(c1 - c0) / (n1 - n0) * 1e9, fixed_us=c0 * 1e6)


IMPLICIT_SETTINGS = {"explicit": {}, "explicit, Python path": {"observe": True}, "implicit": {"solve": "implicit"},
                     "implicit, Python path": {"solve": "implicit", "observe": True},
                     "implicit, numpy": {"solve": "implicit", "backend": "numpy"},
                     "explicit, no reuse": {"reuse_tol": 0.0}}
"""Named settings of :func:`implicit_cost`: the default explicit solve and the implicit solve on the native
route, each also forced onto the dispatcher's Python callback path (a no-op observer), the implicit solve
on the numpy reference, and the explicit solve evaluating every body every time (``attach(reuse_tol=0)``)."""


def implicit_cost(names=("explicit", "explicit, Python path", "implicit", "implicit, Python path"), reps: int = 7,
                  swimmer: tuple = ("implicit",), swimmer_cycles: int = 2) -> dict:
    """The implicit solve's cost, side by side in one process (docs/rest.md, "The implicit solve").

    ``quadruped``: us per ``mj_step`` of the bundled quadruped standing on sand (every body attached, default
    resolution, the floor replaced; settled 0.5 s with that setting), 200 consecutive steps, against a copy
    of the model stepped bare (no floor, no sand) from the same state, the two runs interleaved ``reps`` times
    (medians; ``ratio``: the median of the per-round ratios; ``loaded_elements`` at the end), for each of
    :data:`IMPLICIT_SETTINGS` ``names``; ``swimmer``: s per step of the swimmer driven as the anymass study does (0.5 rad, 1 Hz, dt 2 ms,
    the animal's density, 3 mm elements) for ``swimmer_cycles`` cycles (>= 2), for each named setting."""
    from rft_mujoco.studies import anymass
    from rft_mujoco.studies.swim import swim

    quad = []
    for name in names:
        kwargs = dict(IMPLICIT_SETTINGS[name])
        observe = kwargs.pop("observe", False)
        model = quadruped()
        data = mujoco.MjData(model)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            handle = attach(model, LI_LOOSE_GLASS_BEADS, None, 0.0, "default", monitor=False, **kwargs)
            handle.replace_rigid(["floor"])
            if observe:
                handle.observe(lambda data, wrenches, stage: None)
            stand = settled_state(model, data)
            bare = quadruped()
            bare.geom_contype[0] = bare.geom_conaffinity[0] = 0
            bare_data = mujoco.MjData(bare)
            times = np.array([(step_time(model, data, stand, 1), step_time(bare, bare_data, stand, 1))
                              for _ in range(reps)])
            loaded = int(handle.diagnostics(data).submerged.sum())
        handle.detach()
        quad.append(dict(setting=name, loaded_elements=loaded, bare_us=float(np.median(times[:, 1])) * 1e6,
                         sand_us=float(np.median(times[:, 0])) * 1e6,
                         ratio=float(np.median(times[:, 0] / times[:, 1]))))
    swim_rows = []
    for name in swimmer:
        kwargs = {k: v for k, v in IMPLICIT_SETTINGS[name].items() if k != "observe"}
        r = swim(0.5, anymass.FREQUENCY, density_scale=anymass.ANIMAL, timestep=0.002, cycles=swimmer_cycles,
                 resolution=anymass.ELEMENT_SIZE, **kwargs)
        steps = int(round(swimmer_cycles / anymass.FREQUENCY / 0.002))
        swim_rows.append(dict(setting=name, steps=steps, s_per_step=r["wall_s"] / steps))
    return dict(quadruped=quad, swimmer=swim_rows)


DEFORMABLE_RUNS = ("flat", "deformable", "deformable_numpy")
"""The runs of :func:`deformable_trot`: the demo's flat surface (compiled, native route), the prints study's
deformable surface compiled (the default backend), and the same deformable surface on the numpy reference."""


def deformable_trot(seconds: float = 1.0, reps: int = 3, numpy_seconds: float = 0.2,
                    interval: float | None = None) -> dict:
    """Issue 31's cost target: CPU s (``time.process_time``) per simulated s of the demo quadruped trotting (the
    prints study's scene and gait, :mod:`rft_mujoco.studies.prints`) on its flat surface and on a deformable one
    (updated every ``interval`` s; None: the default), compiled, ``reps`` times in this process (each time a
    fresh pair of demos, stood untimed, then ``seconds`` s of trot timed in alternating chunks of 25 steps:
    :func:`rft_mujoco.studies.prints.side_by_side`, after an untimed pair), and once on the deformable surface
    with numpy
    (``numpy_seconds`` s of trot). Returns {run: [CPU s per simulated s, one per repetition]} over
    :data:`DEFORMABLE_RUNS`."""
    from rft_mujoco.studies.prints import side_by_side

    out = {run: [] for run in DEFORMABLE_RUNS}
    with warnings.catch_warnings():
        side_by_side(DEFORMABLE_RUNS[:2], min(seconds, 0.2), interval=interval)   # the first pair runs unevenly
        for _ in range(reps):
            for run, row in zip(DEFORMABLE_RUNS[:2], side_by_side(DEFORMABLE_RUNS[:2], seconds, interval=interval)):
                out[run].append(row["cpu"])
        if numpy_seconds > 0:
            row = side_by_side(DEFORMABLE_RUNS[2:], numpy_seconds, interval=interval)[0]
            out["deformable_numpy"].append(row["cpu"])
    return out


def interval_sweep(intervals, seconds: float = 2.0) -> list[dict]:
    """The trade of ``DeformableSurface.update_interval``: for each interval (s), one pair of demos (flat and
    deformable, compiled) trotting ``seconds`` s in alternating chunks (:func:`rft_mujoco.studies.prints.
    side_by_side`): ``ratio`` (CPU time,
    deformable / flat), ``deepest`` and ``berm`` (m) of the surface after the run, ``trunk_x`` (m)."""
    from rft_mujoco.studies.prints import side_by_side

    rows = []
    with warnings.catch_warnings():
        side_by_side(DEFORMABLE_RUNS[:2], 0.2)                                 # (untimed, as above)
        for interval in intervals:
            flat, deformable = side_by_side(DEFORMABLE_RUNS[:2], seconds, interval=float(interval))
            rows.append(dict(interval=float(interval), ratio=deformable["cpu"] / flat["cpu"], flat_cpu=flat["cpu"],
                             cpu=deformable["cpu"], deepest=deformable["deepest"], berm=deformable["berm"],
                             trunk_x=deformable["trunk_x"]))
    return rows
