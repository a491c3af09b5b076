"""Stability at the extremes: drop, drag and rotate tests of the sand coupling (``python -m rft_mujoco
stability [--quick]``).

What is tested
--------------
Free bodies (a 5 cm sphere, a 10 x 8 x 6 cm box, a capsule foot of radius 2 cm and 10 cm length tilted
by 0.3 rad) on a flat bed, every combination of mass (10 g .. 100 kg), timestep (0.25 .. 10 ms) and
integrator (Euler, implicitfast, RK4) for the default medium and drop height; sweeps of the drop height
(0 .. 0.3 m, lowest point above the surface) and of every media preset on a subset; dragging (a
constant horizontal pull) and rotating (a constant torque about the vertical) after the body settled,
then releasing it; and the naive coupling (``stabilize=False``) on a subset for comparison.

Per case: NaN; the largest energy the sand added in one step; time to rest; residual jitter; sinkage
creep; final sinkage against the static depth; the largest validity numbers (:mod:`rft_mujoco.coupling.monitor`);
for drag and rotate, the sand force against the published RFT force at the same state.

* Energy the sand adds in a step: with ``J`` the sand's generalized impulse of the step (``dt`` times the
  sand wrenches of the integrator's stages, weighted 1 for Euler/implicitfast and 1/6, 1/3, 1/3, 1/6 for
  RK4, mapped to joint space with ``mj_applyFT``) and ``v+`` the velocity after the step,
  ``dE = J.v+ - 0.5 J.M^-1.J = KE(v+) - KE(v+ - M^-1 J)``: the kinetic energy with the sand's impulse
  minus without it. Passivity means ``dE <= 0``; "beyond round-off" is ``dE > 1e-9 (|J.v+| +
  0.5 J.M^-1.J)``.
* Speed: ``|v_com| + R |omega|`` (R the body's bounding radius), an upper bound of its surface speeds.
  At rest: below 1 mm/s from some time on to the end of the run; that time is the time to rest (inf if
  the body is still moving at the end). Jitter: the largest speed over the last 0.5 s. Creep: COM height
  change over the last 0.5 s divided by 0.5 s.
* Sinkage: depth of the lowest surface element. Static depth: the sinkage at which the RFT force for
  straight-down motion of the body in its initial orientation carries the weight (bisection on depth
  with :func:`rft_mujoco.element_forces`). A drop ends at or below it (ratio >= 1: the body's momentum
  carries it deeper and the sand does not push it back up); well above it (ratio < 0.9) would mean the
  sand carried more than RFT allows.

The treatment tested
--------------------
``attach(stabilize=True)`` (the default): the rest treatment of :mod:`rft_mujoco.physics.rest` (design and
the alternatives measured: docs/rest.md). The naive coupling (``stabilize=False``) applies the published
force at each element's current velocity (zero at zero speed); ``passive=True`` zeroes a body's wrench
when it would do positive work; bodies then chatter on the sand instead of resting. The load-path subset
(:mod:`rft_mujoco.studies.loadpaths`) passes loads to the sand body through MuJoCo's constraints.
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import sys
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.geometry import surface
from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics.law import element_forces
from rft_mujoco.physics.media import PRESETS, get_media
from rft_mujoco.coupling.monitor import RFTValidityWarning
from rft_mujoco.studies.recorder import StageRecorder
from rft_mujoco.studies.stability_cases import (Case, DEFAULT_HEIGHT, DEFAULT_MEDIA, DRAG_LOADS, DURATION,
                                                FLOW_FACTOR, GAIN_RTOL, HEIGHTS, INTEGRATORS, LOAD, MASSES, RELEASE,
                                                RESOLUTION, REST_DEADLINE, REST_DT_MAX, REST_SPEED, RK4_WEIGHTS,
                                                ROTATE_LOADS, Result, SETTLE, SHAPES, TAIL, TIMESTEPS)
from rft_mujoco.tables import table

# --- building blocks ----------------------------------------------------------------------------------
def model_xml(shape: str, mass: float, dt: float, integrator: str, z: float) -> str:
    geom, _ = SHAPES[shape]
    return (f"<mujoco><option timestep='{dt}' integrator='{integrator}'/><worldbody>"
            f"<body name='{shape}' pos='0 0 {z}'><freejoint/><geom {geom} mass='{mass}'/></body>"
            "</worldbody></mujoco>")


@functools.lru_cache(maxsize=None)
def static_depth(shape: str, mass: float, media: str, gravity: float = 9.81) -> float:
    """Depth (m) of the lowest element at which straight-down RFT lift equals the weight (bisection)."""
    model = mujoco.MjModel.from_xml_string(model_xml(shape, mass, 0.001, "Euler", 0.0))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    el = surface.body_elements(model, 1, RESOLUTION)
    rot = data.xmat[1].reshape(3, 3)
    pos = el.centroids @ rot.T
    pos[:, 2] -= pos[:, 2].min()
    nrm = el.normals @ rot.T
    down = np.tile([0.0, 0.0, -1.0], (len(el), 1))
    m = get_media(media)

    def lift(depth):
        return element_forces(pos - [0.0, 0.0, depth], nrm, el.areas, down, m, 0.0, (0, 0, -gravity))[:, 2].sum()

    weight = mass * gravity
    lo, hi = 0.0, 0.01
    while lift(hi) < weight:
        lo, hi = hi, 2.0 * hi
        if hi > 1e3:
            return math.inf
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if lift(mid) < weight else (lo, mid)
    return 0.5 * (lo + hi)


def published_wrench(handle, data, row: int = 0) -> tuple[np.ndarray, float]:
    """The published RFT wrench (6,) [force N, torque N m about the COM] of a handle's body at the state of
    the latest evaluation (element velocities, no regularization), and the smallest speed (m/s) of the
    elements that carry force (inf if none)."""
    b = int(handle.body_ids[row])
    sl = handle.elem_body == row
    rot = data.xmat[b].reshape(3, 3)
    pos = data.xpos[b] + handle.local_centroids[sl] @ rot.T
    nrm = handle.local_normals[sl] @ rot.T
    v6 = np.zeros(6)
    mujoco.mj_objectVelocity(handle.model, data, mujoco.mjtObj.mjOBJ_BODY, b, v6, 0)
    vel = v6[3:] + np.cross(v6[:3], pos - data.xipos[b])
    f = element_forces(pos, nrm, handle.areas[sl], vel, handle.media, handle.terrain.max_height,
                       handle.model.opt.gravity)
    carrying = np.any(f != 0.0, axis=1)
    slowest = float(np.linalg.norm(vel[carrying], axis=1).min()) if carrying.any() else math.inf
    return np.concatenate([f.sum(0), np.cross(pos - data.xipos[b], f).sum(0)]), slowest


def _twist_speed(model, data, wrench, radius: float) -> float:
    """|dv| + radius |domega| of the acceleration (m/s^2) a wrench (6,) at the COM gives body 1."""
    q = np.zeros(model.nv)
    mujoco.mj_applyFT(model, data, np.array(wrench[:3], dtype=float), np.array(wrench[3:], dtype=float),
                      data.xipos[1].copy(), 1, q)
    acc = np.zeros(model.nv)
    mujoco.mj_solveM(model, data, acc.reshape(1, -1), q.reshape(1, -1))
    return float(np.linalg.norm(acc[:3]) + radius * np.linalg.norm(acc[3:6]))


# --- one case -----------------------------------------------------------------------------------------
def run_case(case: Case) -> Result:
    res = Result(case)
    t0 = time.perf_counter()
    _, bottom = SHAPES[case.shape]
    height = case.height if case.kind == "drop" else 0.0
    model = mujoco.MjModel.from_xml_string(model_xml(case.shape, case.mass, case.dt, case.integrator,
                                                     height + bottom))
    data = mujoco.MjData(model)
    dt, g = case.dt, float(np.linalg.norm(model.opt.gravity))
    duration = DURATION if case.kind == "drop" else SETTLE + LOAD + RELEASE
    n = int(round(duration / dt))
    weights = RK4_WEIGHTS if case.integrator == "RK4" else np.ones(1)
    user = np.zeros(6)
    if case.kind == "drag":
        user[0] = case.load * case.mass * g
    elif case.kind == "rotate":
        user[5] = case.load * case.mass * g * 0.1
    speeds, heights = np.empty(n), np.empty(n)
    flow_err, moving_err = [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RFTValidityWarning)
        sand = attach(model, case.media, resolution=RESOLUTION, stabilize=case.stabilize)
        rec = StageRecorder(sand, model)
        try:
            radius = float(sand.layout.bound_radius[0])
            for i in range(n):
                t = i * dt
                loaded = case.kind != "drop" and SETTLE <= t < SETTLE + LOAD
                data.xfrc_applied[1] = user if loaded else 0.0
                rec.q.clear()
                mujoco.mj_step(model, data)
                if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
                    res.nan = True
                    n = i
                    break
                gain = rec.step_gain(model, data, dt, weights)
                if gain is not None:
                    res.max_gain = max(res.max_gain, gain[0])
                    res.max_gain_rel = max(res.max_gain_rel, gain[1])
                speeds[i] = np.linalg.norm(data.qvel[:3]) + radius * np.linalg.norm(data.qvel[3:6])
                heights[i] = data.qpos[2]
                if loaded and speeds[i] >= REST_SPEED:
                    diag = sand.diagnostics(data)
                    pub, slowest = published_wrench(sand, data)
                    fpub = np.linalg.norm(pub[:3]) + np.linalg.norm(pub[3:]) / radius
                    if fpub > 0.0:
                        err = np.linalg.norm(np.r_[diag.force[0] - pub[:3], (diag.torque[0] - pub[3:]) / radius])
                        moving_err.append(err / fpub)
                        # Regularization speed: speed change in one step from the free acceleration
                        # (gravity + load) or from the full published wrench, whichever is larger.
                        v_reg = dt * max(_twist_speed(model, data, user - np.r_[0.0, 0.0, case.mass * g, 0, 0, 0],
                                                      radius),
                                         _twist_speed(model, data, pub, radius))
                        if slowest > FLOW_FACTOR * v_reg:
                            flow_err.append(err / fpub)
            res.steps = n
            if n:
                mujoco.mj_kinematics(model, data)          # poses of the final qpos
                z = (data.xpos[1] + sand.local_centroids @ data.xmat[1].reshape(3, 3).T)[:, 2]
                res.sinkage = float(sand.terrain.max_height - z.min())
            if sand.monitor is not None:
                worst = sand.monitor.worst
                res.i_mac = worst.get("i_mac", (math.nan,))[0]
                res.i_micro = worst.get("i_micro", (math.nan,))[0]
                res.depth_ratio = worst.get("depth_ratio", (math.nan,))[0]
        finally:
            res.observed = rec.evaluations
            sand.detach()
    res.validity_warnings = sum(issubclass(w.category, RFTValidityWarning) for w in caught)
    if n and not res.nan:
        speeds, heights = speeds[:n], heights[:n]
        tail = max(1, int(round(TAIL / dt)))
        moving = np.flatnonzero(speeds >= REST_SPEED)
        start = (SETTLE + LOAD) if case.kind != "drop" else 0.0
        if moving.size == 0:
            res.t_rest = 0.0
        elif moving[-1] < n - 1:
            res.t_rest = max(0.0, (moving[-1] + 1) * dt - start)
        if case.kind != "drop":
            res.held = bool(speeds[min(n, int(round((SETTLE + LOAD) / dt))) - 1] < REST_SPEED)
        res.jitter = float(speeds[-tail:].max())
        res.creep = float(abs(heights[-1] - heights[-tail]) / (tail * dt))
    if case.kind == "drop":
        res.static_depth = static_depth(case.shape, case.mass, case.media)
    if flow_err:
        res.force_err_flow = float(np.median(flow_err))
    if moving_err:
        res.force_err_moving = float(np.median(moving_err))
    res.wall = time.perf_counter() - t0
    res.failures = failures(res)
    return res


def failures(res: Result) -> tuple:
    """The issue's criteria a case fails: NaN or energy gain (every case); for stabilized drops with
    dt <= 5 ms no rest within 2 s, or a final sinkage well above the static depth. (Drag and rotate cases
    report their rest after release but are not held to it: a load above the sand's capacity can spin a
    body up to any speed, and RFT's rate-independent resistance then needs long to stop it.)"""
    case, out = res.case, []
    if res.nan:
        out.append("NaN")
    if res.observed == 0:
        out.append("energy not measured: the observer saw no sand evaluation")
    if res.max_gain_rel > GAIN_RTOL:
        out.append(f"energy gain {res.max_gain:.3g} J")
    if case.kind == "drop" and case.stabilize and case.dt <= REST_DT_MAX + 1e-12 and not res.nan:
        if not res.t_rest <= REST_DEADLINE:
            out.append(f"no rest within {REST_DEADLINE:g} s (jitter {res.jitter:.3g} m/s)")
    if case.kind == "drop" and res.sinkage_ratio < 0.9:
        out.append(f"held above the static depth (ratio {res.sinkage_ratio:.2f})")
    return tuple(out)


# --- the study ----------------------------------------------------------------------------------------
def matrix(quick: bool = False) -> list[Case]:
    """The cases of the full (or quick) study."""
    cases = []
    if quick:
        for shape in SHAPES:
            for mass in (0.01, 100.0):
                for dt, integ in ((0.001, "Euler"), (0.005, "implicitfast"), (0.005, "RK4")):
                    cases.append(Case("drop", shape, mass, dt, integ))
        cases += [Case("drop", "capsule", 1.0, 0.002, "RK4"),
                  Case("drop", "capsule", 1.0, 0.002, "RK4", height=0.3, group="height"),
                  Case("drop", "box", 1.0, 0.002, "Euler", media="dem_glass_beads", group="media"),
                  Case("drop", "capsule", 1.0, 0.002, "RK4", stabilize=False, group="naive"),
                  Case("drag", "box", 1.0, 0.002, "implicitfast", load=1.0, group="drag"),
                  Case("rotate", "capsule", 1.0, 0.002, "implicitfast", load=0.2, group="rotate")]
        return cases
    for shape in SHAPES:
        for mass in MASSES:
            for dt in TIMESTEPS:
                for integ in INTEGRATORS:
                    cases.append(Case("drop", shape, mass, dt, integ))
    for shape in SHAPES:
        for mass in (0.01, 1.0, 100.0):
            for height in HEIGHTS:
                if height == DEFAULT_HEIGHT:
                    continue
                for dt, integ in ((0.001, "Euler"), (0.005, "RK4")):
                    cases.append(Case("drop", shape, mass, dt, integ, height=height, group="height"))
            for media in PRESETS:
                if media == DEFAULT_MEDIA:
                    continue
                cases.append(Case("drop", shape, mass, 0.002, "implicitfast", media=media, group="media"))
            for dt, integ in ((0.001, "Euler"), (0.005, "Euler"), (0.002, "RK4")):
                cases.append(Case("drop", shape, mass, dt, integ, stabilize=False, group="naive"))
    for kind, loads in (("drag", DRAG_LOADS), ("rotate", ROTATE_LOADS)):
        for shape in SHAPES:
            for mass in (0.1, 10.0):
                for load in loads:
                    for integ in INTEGRATORS:
                        cases.append(Case(kind, shape, mass, 0.002, integ, load=load, group=kind))
                    cases.append(Case(kind, shape, mass, 0.002, "implicitfast", load=load, stabilize=False,
                                      group=kind + "-naive"))
    return cases


CSV_FIELDS = ("group", "kind", "shape", "mass_kg", "dt_ms", "integrator", "height_m", "media", "stabilize",
              "load", "nan", "max_gain_J", "max_gain_rel", "t_rest_s", "jitter_m_s", "creep_m_s", "sinkage_m",
              "static_depth_m", "sinkage_ratio", "held", "force_err_flow", "force_err_moving", "i_mac_max", "i_micro_max",
              "depth_ratio_max", "validity_warnings", "steps", "wall_s", "failures")


def _row(r: Result) -> dict:
    c = r.case
    return dict(group=c.group, kind=c.kind, shape=c.shape, mass_kg=c.mass, dt_ms=c.dt * 1e3,
                integrator=c.integrator, height_m=c.height, media=c.media, stabilize=c.stabilize, load=c.load,
                nan=r.nan, max_gain_J=f"{r.max_gain:.4g}", max_gain_rel=f"{r.max_gain_rel:.4g}",
                t_rest_s=f"{r.t_rest:.4g}", jitter_m_s=f"{r.jitter:.4g}", creep_m_s=f"{r.creep:.4g}",
                sinkage_m=f"{r.sinkage:.5g}", static_depth_m=f"{r.static_depth:.5g}",
                sinkage_ratio=f"{r.sinkage_ratio:.4g}", force_err_flow=f"{r.force_err_flow:.4g}",
                held=r.held if c.kind != "drop" else "", force_err_moving=f"{r.force_err_moving:.4g}", i_mac_max=f"{r.i_mac:.3g}", i_micro_max=f"{r.i_micro:.3g}",
                depth_ratio_max=f"{r.depth_ratio:.3g}", validity_warnings=r.validity_warnings, steps=r.steps,
                wall_s=f"{r.wall:.2f}", failures="; ".join(r.failures))


def _fmt(x: float, spec: str = ".2g") -> str:
    return "inf" if x == math.inf else "-" if x != x else format(x, spec)


def summary(results: list[Result]) -> list[str]:
    """Table lines: one line per (group, coupling), with per-integrator, per-shape and per-dt lines of the
    drop matrix."""
    rows = []

    def nanmax(values):
        values = [v for v in values if v == v]
        return max(values) if values else math.nan

    def line(name, rs):
        if not rs:
            return
        drops = [r for r in rs if r.case.kind == "drop"]
        rest_ok = sum(1 for r in rs if r.t_rest <= (REST_DEADLINE if r.case.kind == "drop" else RELEASE))
        ratios = [r.sinkage_ratio for r in drops if r.sinkage_ratio == r.sinkage_ratio]
        moving = [r for r in rs if r.case.kind != "drop"]
        t_rest = nanmax([r.t_rest for r in rs if not r.nan])
        rows.append([
            name, len(rs), sum(r.nan for r in rs), _fmt(max(r.max_gain for r in rs), ".1e"),
            sum(r.max_gain_rel > GAIN_RTOL for r in rs), f"{rest_ok}/{len(rs)}", _fmt(t_rest, ".3g"),
            _fmt(nanmax([r.jitter for r in rs]), ".1e"), _fmt(nanmax([r.creep for r in rs]), ".1e"),
            (_fmt(min(ratios), ".2f") + ".." + _fmt(max(ratios), ".3g")) if ratios else "-",
            f"{sum(r.held for r in moving)}/{len(moving)}" if moving else "-",
            _fmt(nanmax([r.force_err_flow for r in rs]), ".1e"), _fmt(nanmax([r.force_err_moving for r in rs]), ".1e"),
            sum(bool(r.failures) for r in rs)])

    groups = sorted({(r.case.group, r.case.stabilize) for r in results}, key=lambda g: (g[0] != "matrix", g))
    for group, stab in groups:
        rs = [r for r in results if r.case.group == group and r.case.stabilize == stab]
        line(f"{group}{'' if stab else ' (naive)'}", rs)
        if group == "matrix":
            for integ in INTEGRATORS:
                line(f"  {integ}", [r for r in rs if r.case.integrator == integ])
            for shape in SHAPES:
                line(f"  {shape}", [r for r in rs if r.case.shape == shape])
            for mass in MASSES:
                line(f"  m = {mass:g} kg", [r for r in rs if r.case.mass == mass])
            for dt in TIMESTEPS:
                line(f"  dt = {dt * 1e3:g} ms", [r for r in rs if r.case.dt == dt])
    return table(["subset", "cases", "NaN", "max dE (J)", "dE>0", "at rest", "t_rest max", "jitter max", "creep max",
                  "sink/static", "held", "F err flow", "F err slow", "fail"], rows).splitlines()


def run_load_paths(*, quick: bool = False, out: Path, stream=None, solve: str = "explicit") -> list:
    """The load-path subset (:mod:`rft_mujoco.studies.loadpaths`): progress, a table per scene, ``loadpaths.csv``.
    ``solve="implicit"`` runs it with ``attach(solve="implicit")`` (compiled, on the native route); ``stream``: where to print
    (default: ``sys.stdout`` at the call)."""
    from rft_mujoco.studies import loadpaths

    stream = sys.stdout if stream is None else stream

    results = []
    t0 = time.perf_counter()
    todo = loadpaths.cases(quick)
    kw = dict(solve="implicit") if solve == "implicit" else {}
    for k, (name, dt, integ) in enumerate(todo, 1):
        r = loadpaths.run_case(name, dt, integ, **kw)
        results.append(r)
        print(f"[{k:3d}/{len(todo)} {time.perf_counter() - t0:6.0f}s] load path {r.label} t_rest={_fmt(r.t_rest, '.3g')} "
              f"final speed={_fmt(r.final_speed, '.1e')} balance={_fmt(r.balance, '.1e')} "
              f"depth={_fmt(r.sinkage * 1e3, '.1f')} mm (quasi-static {r.rest_depth * 1e3:.1f}) "
              f"{'FAIL: ' + '; '.join(r.failures) if r.failures else ''}", file=stream, flush=True)
    with open(out / "loadpaths.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["scene", "dt_ms", "integrator", "nan", "max_gain_J", "t_rest_s", "final_speed", "balance",
                         "sinkage_m", "quasi_static_depth_m", "wall_s", "failures"])
        for r in results:
            writer.writerow([r.scene, r.dt * 1e3, r.integrator, r.nan, f"{r.max_gain:.4g}", f"{r.t_rest:.4g}",
                             f"{r.final_speed:.4g}", f"{r.balance:.4g}", f"{r.sinkage:.5g}", f"{r.rest_depth:.5g}",
                             f"{r.wall:.2f}",
                             "; ".join(r.failures)])
    print(f"\nLoad paths: rest within {loadpaths.DEADLINE:g} s (every body < {loadpaths.REST_SPEED * 1e3:g} mm/s and "
          f"mrad/s), sand force against the load (balance), largest energy added by the sand in a step, the "
          f"deepest rest against the quasi-static depth (at most {loadpaths.DEPTH_FACTOR:g}x)", file=stream)
    rows = []
    for name in dict.fromkeys(r.scene for r in results):
        rs = [r for r in results if r.scene == name]
        ok = [r for r in rs if not r.nan]
        at_rest = sum(r.t_rest <= loadpaths.DEADLINE for r in rs)
        rows.append([name, len(rs), sum(r.nan for r in rs), f"{at_rest}/{len(rs)}",
                     _fmt(max((r.t_rest for r in ok), default=math.nan), ".3g"),
                     _fmt(max((r.final_speed for r in ok), default=math.nan), ".1e"),
                     _fmt(max((r.balance for r in ok), default=math.nan), ".1e"),
                     _fmt(max(r.max_gain for r in rs), ".1e"),
                     _fmt(max((r.sinkage * 1e3 for r in ok), default=math.nan), ".1f"),
                     f"{rs[0].rest_depth * 1e3:.1f}",
                     sum(bool(r.failures) for r in rs)])
    print(table(["scene", "cases", "NaN", "at rest", "t_rest max", "final speed max", "balance max", "max dE (J)",
                 "depth max mm", "q-s mm", "fail"], rows), file=stream)
    return results


def run(*, quick: bool = False, out: str | Path = "out/stability", plots: bool = True, stream=None):
    """Run the study; print progress and tables (to ``stream``, default ``sys.stdout`` at the call); write CSV
    and plot. Returns the results (the load-path cases of :func:`run_load_paths` are appended as
    ``rft_mujoco.studies.loadpaths.Result`` objects)."""
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = matrix(quick)
    results = []
    t0 = time.perf_counter()
    for k, case in enumerate(cases, 1):
        r = run_case(case)
        results.append(r)
        print(f"[{k:3d}/{len(cases)} {time.perf_counter() - t0:6.0f}s] {case.label} t_rest={_fmt(r.t_rest, '.3g')} "
              f"jitter={_fmt(r.jitter, '.1e')} dE={_fmt(r.max_gain, '.1e')} J "
              f"{'FAIL: ' + '; '.join(r.failures) if r.failures else ''}", file=stream, flush=True)
    with open(out / "stability.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        writer.writeheader()
        for r in results:
            writer.writerow(_row(r))
    print("", file=stream)
    print("Summary. max dE: largest energy the sand added in one step (J; < 0 means it only took energy);"
          " dE>0: cases with a gain beyond round-off; at rest: speed < 1 mm/s to the end, reached within "
          f"{REST_DEADLINE:g} s (drops) or {RELEASE:g} s after release (drag/rotate); sink/static: final "
          "sinkage over the static depth; held: drag/rotate at rest under the load; F err flow / slow: "
          "largest per-case median |F - F_pub| / |F_pub| under load when every loaded element moves faster than 10 v_reg / at any speed "
          ">= 1 mm/s.", file=stream)
    for line in summary(results):
        print(line, file=stream)
    load = run_load_paths(quick=quick, out=out, stream=stream)
    stab_fail = [r for r in results if r.failures and r.case.stabilize]
    naive_fail = [r for r in results if r.failures and not r.case.stabilize]
    load_fail = [r for r in load if r.failures]
    print(f"\nFailures of the stabilized coupling: {len(stab_fail)} of {len(results) - len(naive_fail)} drop, drag "
          f"and rotate cases, {len(load_fail)} of {len(load)} load-path cases", file=stream)
    for r in stab_fail:
        print(f"  {r.case.label}: {'; '.join(r.failures)}", file=stream)
    for r in load_fail:
        print(f"  load path {r.label}: {'; '.join(r.failures)}", file=stream)
    print(f"Naive coupling (for comparison, not a failure of the library): {len(naive_fail)} of "
          f"{sum(not r.case.stabilize for r in results)} cases fail the same criteria", file=stream)
    invalid = [r for r in results if r.validity_warnings]
    print(f"Validity monitor warned in {len(invalid)} of {len(results)} cases (high impact speed or deep "
          "sinking; see i_mac_max, i_micro_max, depth_ratio_max in the CSV)", file=stream)
    if plots:
        from rft_mujoco.studies.stability_plots import plot, plot_naive
        plot(results, out / "stability_map.png")
        plot_naive(results, out / "stability_naive.png")
    print(f"wrote {out / 'stability.csv'}, {out / 'loadpaths.csv'}"
          + (f", {out / 'stability_map.png'} and {out / 'stability_naive.png'}" if plots else "")
          + f" ({time.perf_counter() - t0:.0f} s)", file=stream)
    return results + load


def main(argv: list[str] | None = None, command: str = "stability") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a small representative subset (< 1 min)")
    parser.add_argument("--out", default="out/stability", help="output folder (default: out/stability)")
    parser.add_argument("--no-plots", action="store_true", help="table and CSV only")
    parser.add_argument("--load-paths-only", action="store_true",
                        help="only the loads through MuJoCo's constraints (rft_mujoco.studies.loadpaths)")
    parser.add_argument("--solve", choices=("explicit", "implicit"), default="explicit",
                        help="the sand solve of the load paths (needs --load-paths-only)")
    args = parser.parse_args(argv)
    if args.solve != "explicit" and not args.load_paths_only:
        parser.error("--solve implicit runs the load paths only: add --load-paths-only")
    if args.load_paths_only:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        results = run_load_paths(quick=args.quick, out=out, solve=args.solve)
        print(f"wrote {out / 'loadpaths.csv'}")
        return 1 if any(r.failures for r in results) else 0
    results = run(quick=args.quick, out=args.out, plots=not args.no_plots)
    return 1 if any(r.failures and getattr(getattr(r, "case", None), "stabilize", True) for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
