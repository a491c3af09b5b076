"""Benchmark sections on the law alone: element throughput, and the speed-accuracy trade of the element size."""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.geometry import surface
from rft_mujoco.physics import elements as kernel
from rft_mujoco.physics import law
from rft_mujoco.physics.media import MPM_VALIDATION
from rft_mujoco.physics.terrain import FlatSurface
from rft_mujoco.studies.bench.timing import median_time

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
"""m/s: speed of every benchmark element or body."""

_DOWN = np.array([0.0, 0.0, -1.0])
_GRAVITY = np.array([0.0, 0.0, -9.81])


def _random_elements(n: int, n_bodies: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    local = 0.05 * rng.uniform(-1, 1, (n, 3))
    body = np.sort(rng.integers(0, n_bodies, n))
    return rng, local, nrm, rng.uniform(1e-6, 1e-5, n), body


def throughput(sizes) -> list[dict]:
    """ns per element at each N of the law (numpy :func:`rft_mujoco.physics.law.element_forces` against the
    compiled :func:`rft_mujoco.compiled.law.element_forces`) and of the element pass (numpy
    :func:`rft_mujoco.physics.elements.body_wrenches` against :class:`rft_mujoco.compiled.element_pass.ElementPass`).
    Elements: random unit normals, all submerged (depth 10-20 cm), 8 bodies moving at random; about half lead."""
    from rft_mujoco.compiled import element_pass as fast
    from rft_mujoco.compiled import law as fastlaw

    media = MPM_VALIDATION
    out = []
    for n in sizes:
        n = int(n)
        rng, local, nrm, areas, body = _random_elements(n)
        centroids = local + [0.0, 0.0, -0.15]
        vel = rng.normal(size=(n, 3)) * SPEED
        buf = np.empty((n, 3))
        reps = 3 if n >= 1_000_000 else 5
        t_law_np = median_time(lambda: law.element_forces(centroids, nrm, areas, vel, media), reps)
        t_law_nb = median_time(lambda: fastlaw.element_forces(centroids, nrm, areas, vel, media, out=buf), reps)
        B = 8
        pos = np.zeros((B, 3))
        pos[:, 2] = -0.15
        pos[:, 0] = np.arange(B) * 0.2
        mat = np.tile(np.eye(3), (B, 1, 1))
        com = pos + 0.001
        v_com = rng.normal(size=(B, 3)) * SPEED
        omega = rng.normal(size=(B, 3))
        terrain = FlatSurface(0.0)
        bodies, pose = kernel.BodySurface(local, nrm, areas, body, B), kernel.BodyPose(pos, mat, com)
        t_ker_np = median_time(lambda: kernel.body_wrenches(bodies, pose, v_com, omega, terrain, _DOWN, _GRAVITY, media,
                                                            law.PUBLISHED), reps)
        run = fast.ElementPass(bodies, terrain, _DOWN, _GRAVITY, media, law.PUBLISHED)
        t_ker_nb = median_time(lambda: run(pos, mat, com, v_com, omega), reps)
        out.append(dict(n=n, law_numpy=t_law_np / n * 1e9, law_numba=t_law_nb / n * 1e9,
                        kernel_numpy=t_ker_np / n * 1e9, kernel_numba=t_ker_nb / n * 1e9,
                        leading=float(run.count.sum() / n)))
    return out


def public_law(sizes, rounds: int = 5) -> list[dict]:
    """ns per element at each N of the public :func:`rft_mujoco.element_forces` (its default backend, the
    compiled one, with its input checks and conversions) against the numpy law
    (:func:`rft_mujoco.physics.law.element_forces`) and the compiled kernel alone
    (:func:`rft_mujoco.compiled.law.element_forces`), on :func:`throughput`'s elements. The three are timed
    side by side in ``rounds`` interleaved rounds (the machine's speed drifts); each time is the median over
    the rounds, each speed-up the median of the per-round ratios."""
    import rft_mujoco
    from rft_mujoco.compiled import law as fastlaw

    media = MPM_VALIDATION
    out = []
    for n in sizes:
        n = int(n)
        rng, local, nrm, areas, _ = _random_elements(n)
        centroids = local + [0.0, 0.0, -0.15]
        vel = rng.normal(size=(n, 3)) * SPEED
        calls = {"numpy": lambda: law.element_forces(centroids, nrm, areas, vel, media),
                 "kernel": lambda: fastlaw.element_forces(centroids, nrm, areas, vel, media),
                 "public": lambda: rft_mujoco.element_forces(centroids, nrm, areas, vel, media)}
        times = {k: [] for k in calls}
        for _ in range(rounds):
            for key, call in calls.items():
                times[key].append(median_time(call, 3) / n * 1e9)
        ratio = lambda a, b: float(np.median(np.array(times[a]) / np.array(times[b])))  # noqa: E731
        out.append(dict(n=n, numpy_ns=float(np.median(times["numpy"])), kernel_ns=float(np.median(times["kernel"])),
                        public_ns=float(np.median(times["public"])), public_speedup=ratio("numpy", "public"),
                        kernel_speedup=ratio("numpy", "kernel"), public_over_kernel=ratio("public", "kernel")))
    return out


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
    from rft_mujoco.compiled import law as fastlaw

    c = el.centroids @ rot.T + [0.0, 0.0, -depth]
    n = el.normals @ rot.T
    out = []
    for t in np.radians(directions):
        v = np.tile([math.cos(t) * SPEED, 0.0, math.sin(t) * SPEED], (len(el), 1))
        out.append(fastlaw.element_forces(c, n, el.areas, v, MPM_VALIDATION).sum(axis=0))
    return np.array(out)


def _evaluation_time(el, rot, depth) -> tuple[float, float]:
    """Seconds per evaluation of one body with these elements: compiled and numpy element pass."""
    from rft_mujoco.compiled import element_pass as fast

    local, nrm, areas = np.ascontiguousarray(el.centroids), np.ascontiguousarray(el.normals), el.areas.copy()
    body = np.zeros(len(el), dtype=np.int64)
    pos = np.array([[0.0, 0.0, -depth]])
    mat = rot[None].copy()
    v_com = np.array([[SPEED * math.cos(0.3), 0.0, -SPEED * math.sin(0.3)]])
    omega = np.zeros((1, 3))
    terrain = FlatSurface(0.0)
    bodies, pose = kernel.BodySurface(local, nrm, areas, body, 1), kernel.BodyPose(pos, mat, pos)
    run = fast.ElementPass(bodies, terrain, _DOWN, _GRAVITY, MPM_VALIDATION, law.PUBLISHED)

    def numpy_pass():
        kernel.body_wrenches(bodies, pose, v_com, omega, terrain, _DOWN, _GRAVITY, MPM_VALIDATION, law.PUBLISHED)
    return median_time(lambda: run(pos, mat, pos, v_com, omega), 5, 0.01), median_time(numpy_pass, 3, 0.01)


def speed_accuracy(quick: bool) -> list[dict]:
    """Per shape and element size: max and mean relative force error over the directions against the
    converged reference, and us per evaluation of the body (compiled and numpy)."""
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
