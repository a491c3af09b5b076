"""Batched sand on MuJoCo Warp: world-steps per second against the number of worlds, and parity with the CPU path.

``python -m rft_mujoco bench --warp [--device cpu|cuda:0] [--worlds 1 4 16 ...] [--out DIR] [--quick]``
(:func:`main`; also ``python -m rft_mujoco.studies.bench_warp``; ``--nworld`` is an alias of ``--worlds``).
Needs ``rft_mujoco[warp]``. Prints tables and writes ``world_steps.png`` to ``--out`` (default
``out/bench_warp``). Sections:

1. **Parity** (:func:`parity`): N worlds on warp against N MjData on the CPU path, the bundled quadruped from
   its ``home`` keyframe 1-2.5 cm into the sand with perturbed joint targets and velocities, every body
   attached, culling on: relative error of the sand forces at the first step, largest body-position
   difference over 0.1 s (50 steps); with the sand at the feet (surface 0) and knee-deep (surface 0.15 m,
   where the calves' and thighs' surface inside each other at the knees is culled at run time).
2. **Throughput** (:func:`throughput`): world-steps per second (worlds x steps / wall time) of
   ``mujoco_warp.step`` for nworld worlds of the quadruped standing on sand (settled for 0.5 s on the CPU
   path, its floor replaced by the sand): without sand, with sand on the four feet, with sand on every body
   (the CPU bench's case), on every body without culling (``cull=False``) and with the implicit solve
   (``solve="implicit"``: this step's constraint rows linearized, the capacity test); and the CPU path for
   comparison (one MjData stepped with ``mujoco.mj_step`` and the CPU attach, one thread: its world-steps/s
   does not depend on N). Each number is the median of three timed runs after a warm-up (compilation and
   :data:`SETTLE_STEPS` steps excluded); on CUDA the step is replayed from a CUDA graph.

On warp's CPU device the kernels run on the host (numbers show correctness and scaling, not GPU speed).
The issue's goal (quadruped with sand >= 0.5x the world-steps/s of mujoco_warp without sand at 4096 worlds)
needs a GPU: run ``--device cuda:0 --worlds 1 64 512 4096 8192``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach as cpu_attach
from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS
from rft_mujoco.studies.bench.timing import machine, quadruped as _quadruped, settled_state as _settled_state
from rft_mujoco.tables import table as _table
from rft_mujoco.models.quadruped import FOOT_BODIES

CASES = (("no sand", None, {}), ("sand: feet", FOOT_BODIES, {}), ("sand: every body", "all", {}),
         ("sand: every body, cull=False", "all", {"cull": False}),
         ("sand: every body, implicit", "all", {"solve": "implicit"}))
"""Throughput cases: label, the attached bodies (None: no sand; "all": every body with geoms), attach options."""
KNEE_DEEP = 0.15
"""Sand surface (m) of the knee-deep parity case: the quadruped's knees (``home``) at the surface."""
CPU_NWORLD = (1, 4, 16, 64, 256)
"""Default world counts on warp's CPU device (a few minutes on 2 cores)."""
GPU_NWORLD = (1, 16, 256, 1024, 4096, 8192)
"""Default world counts on a GPU."""
SETTLE_STEPS = 50
"""Untimed steps of each throughput case before its timing: with every body attached, the bodies the feet-only
settle left out of the sand first sink a little (the implicit solve's flowing groups cost Newton iterations:
docs/warp.md, "The implicit solve")."""


def _floorless_quadruped():
    model = _quadruped()
    model.geom_contype[0] = model.geom_conaffinity[0] = 0
    return model


def _bodies(case):
    return None if case == "all" else list(case)


def parity(nworld: int = 4, steps: int = 50, resolution: str = "default", device: str = "cpu",
           surface_height: float = 0.0) -> dict:
    """Sand forces at the first step and body positions over ``steps`` steps: warp against the CPU path, every
    body attached, sand surface at ``surface_height`` m; also the occluded (run-time culled) area."""
    import mujoco_warp as mjw
    import warp as wp

    import rft_mujoco.warp as rw

    model = _floorless_quadruped()
    key = model.key("home")
    rng = np.random.default_rng(0)
    datas = []
    for i in range(nworld):
        d = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, d, key.id)
        d.qpos[2] -= 0.01 + 0.005 * (i % 4)
        d.qvel[:] = 0.05 * rng.standard_normal(model.nv)
        d.ctrl[:] = key.ctrl + 0.05 * rng.standard_normal(model.nu)
        datas.append(d)
    with wp.ScopedDevice(device):
        m = mjw.put_model(model)
        dw = mjw.put_data(model, datas[0], nworld=nworld, nconmax=4, njmax=64)
        for field, name in ((dw.qpos, "qpos"), (dw.qvel, "qvel"), (dw.ctrl, "ctrl")):
            field.assign(np.array([getattr(d, name) for d in datas], dtype=np.float32))
        cpu = cpu_attach(model, LI_LOOSE_GLASS_BEADS, None, surface_height, resolution, monitor=False)
        handle = rw.attach(model, m, LI_LOOSE_GLASS_BEADS, None, surface_height, resolution, data=dw)
        try:
            pos_err = force_err = occ_err = occ_max = 0.0
            for k in range(steps):
                for d in datas:
                    mujoco.mj_step(model, d)
                mjw.step(m, dw)
                fc = np.array([cpu.diagnostics(d).force for d in datas])
                oc = np.array([cpu.diagnostics(d).occluded_area for d in datas])
                diag = handle.diagnostics(dw)
                fw = diag.force
                occ_max = max(occ_max, float(oc.sum(axis=1).max()))
                occ_err = max(occ_err, float(np.abs(diag.occluded_area - oc).max()))
                if k == 0:
                    first = np.abs(fw - fc).sum(axis=(1, 2)) / np.abs(fc).sum(axis=(1, 2))
                    first_total = np.abs(fc).sum(axis=(1, 2))
                scale = np.maximum(np.linalg.norm(fc, axis=2).max(axis=1), 1e-9)
                force_err = max(force_err, float((np.linalg.norm(fw - fc, axis=2).max(axis=1) / scale).max()))
                pos_err = max(pos_err, float(np.abs(dw.xpos.numpy() - np.array([d.xpos for d in datas])).max()))
        finally:
            handle.detach()
            cpu.detach()
    return dict(nworld=nworld, steps=steps, surface_height=surface_height, first_force_rel=float(first.max()),
                first_force_total=first_total, force_rel_max=force_err, position_err_m=pos_err,
                elements=handle.n_elements, occluded_max_m2=occ_max, occluded_err_m2=occ_err)


def _time_steps(step, sync, steps: int, repeats: int = 3) -> float:
    """Median seconds per call of ``step`` over ``repeats`` runs of ``steps`` calls."""
    samples = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        sync()
        samples.append((time.perf_counter() - t0) / steps)
    return float(np.median(samples))


def _cpu_rate(model, state, bodies, resolution: str, budget_s: float, options: dict | None = None) -> float:
    """World-steps/s of the CPU path (one MjData, mujoco.mj_step, numba kernels), or of the bare model."""
    data = mujoco.MjData(model)
    handle = None
    if bodies is not None:
        handle = cpu_attach(model, LI_LOOSE_GLASS_BEADS, _bodies(bodies), 0.0, resolution, monitor=False,
                            **(options or {}))
    try:
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        mujoco.mj_setState(model, data, state, spec)
        for _ in range(20):
            mujoco.mj_step(model, data)
        mujoco.mj_setState(model, data, state, spec)
        t1 = _time_steps(lambda: mujoco.mj_step(model, data), lambda: None, 20, 1)
        steps = int(np.clip(budget_s / max(t1, 1e-9), 20, 5000))
        mujoco.mj_setState(model, data, state, spec)
        return 1.0 / _time_steps(lambda: mujoco.mj_step(model, data), lambda: None, steps)
    finally:
        if handle is not None:
            handle.detach()


def throughput(nworlds, device: str = "cpu", resolution: str = "default", budget_s: float = 1.0,
               cpu_budget_s: float = 1.0, settle_steps: int = SETTLE_STEPS) -> list[dict]:
    """Rows (case, nworld, world-steps/s, ms per step) for every case of :data:`CASES` and world count; each
    case steps ``settle_steps`` times untimed after its compile step (the bodies the feet-only settle left out
    come to rest: the cost of standing, not of the first steps after attach)."""
    import mujoco_warp as mjw
    import warp as wp

    import rft_mujoco.warp as rw

    model = _floorless_quadruped()
    data = mujoco.MjData(model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        settle = cpu_attach(model, LI_LOOSE_GLASS_BEADS, list(FOOT_BODIES), 0.0, resolution, monitor=False)
        state = _settled_state(model, data)
        settle.detach()
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    rows = []
    dev = wp.get_device(device)
    with wp.ScopedDevice(dev):
        m = mjw.put_model(model)
        for label, bodies, options in CASES:
            for nw in nworlds:
                mujoco.mj_setState(model, data, state, spec)
                data.xfrc_applied[:] = 0.0
                mujoco.mj_forward(model, data)
                d = mjw.put_data(model, data, nworld=nw, nconmax=4, njmax=64)
                handle = None
                if bodies is not None:
                    handle = rw.attach(model, m, LI_LOOSE_GLASS_BEADS, _bodies(bodies), 0.0, resolution, data=d,
                                       **options)
                try:
                    for _ in range(1 + settle_steps):            # compile and settle (excluded)
                        mjw.step(m, d)
                    wp.synchronize_device(dev)
                    step = lambda: mjw.step(m, d)                # noqa: E731
                    if dev.is_cuda:
                        with wp.ScopedCapture(device=dev) as capture:
                            mjw.step(m, d)
                        graph = capture.graph
                        step = lambda: wp.capture_launch(graph)  # noqa: E731
                    sync = lambda: wp.synchronize_device(dev)    # noqa: E731
                    t1 = _time_steps(step, sync, 2, 1)
                    steps = int(np.clip(budget_s / max(t1, 1e-9), 3, 2000))
                    t = _time_steps(step, sync, steps)
                finally:
                    if handle is not None:
                        handle.detach()
                rows.append(dict(case=label, backend=f"mujoco_warp ({dev})", nworld=nw, ms_per_step=t * 1e3,
                                 world_steps_per_s=nw / t,
                                 elements=0 if handle is None else handle.n_elements))
                print(f"  {label:28s} nworld {nw:5d}: {t * 1e3:9.2f} ms per step, {nw / t:10.0f} world-steps/s",
                      flush=True)
    for label, bodies, options in CASES:
        rate = _cpu_rate(model, state, bodies, resolution, cpu_budget_s, options)
        rows.append(dict(case=label, backend="CPU path (mujoco.mj_step, 1 thread)", nworld=1,
                         ms_per_step=1e3 / rate, world_steps_per_s=rate, elements=None))
        print(f"  {label:28s} CPU path: {1e6 / rate:9.1f} us per step, {rate:10.0f} world-steps/s", flush=True)
    return rows


def plot(rows: list[dict], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    colors = dict(zip([c[0] for c in CASES], ["0.4", "tab:orange", "tab:red", "tab:purple", "tab:green"]))
    warp_rows = [r for r in rows if r["backend"].startswith("mujoco_warp")]
    backend = warp_rows[0]["backend"] if warp_rows else "mujoco_warp"
    nmax = max((r["nworld"] for r in warp_rows), default=1)
    for label, *_ in CASES:
        rr = [r for r in warp_rows if r["case"] == label]
        if rr:
            ax.plot([r["nworld"] for r in rr], [r["world_steps_per_s"] for r in rr], "o-", color=colors[label],
                    label=f"{backend}: {label}")
        cpu = [r for r in rows if r["case"] == label and not r["backend"].startswith("mujoco_warp")]
        if cpu:
            ax.axhline(cpu[0]["world_steps_per_s"], color=colors[label], ls="--", lw=1,
                       label=f"CPU path, 1 thread: {label}")
    bare = {r["nworld"]: r["world_steps_per_s"] for r in warp_rows if r["case"] == CASES[0][0]}
    for r in warp_rows:
        if r["case"] == "sand: feet" and r["nworld"] in bare:
            ax.annotate(f"{r['world_steps_per_s'] / bare[r['nworld']]:.2f}x", (r["nworld"], r["world_steps_per_s"]),
                        textcoords="offset points", xytext=(6, -13), ha="left", fontsize=8, color="tab:orange")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlim(0.7, nmax * 1.4)
    ax.set_xlabel("worlds (nworld)")
    ax.set_ylabel("world-steps per second")
    ax.set_title("quadruped standing on sand (2 ms steps): throughput; ratios sand(feet) / no sand")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "world_steps.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run(nworlds=None, device: str = "cpu", out: str | Path = "out/bench_warp", quick: bool = False,
        plots: bool = True, resolution: str = "default", budget_s: float | None = None,
        parity_steps: int = 50) -> dict:
    """Both sections; ``budget_s``: seconds of timed stepping per case and world count (default 1.5, 0.5 with
    ``quick``); ``parity_steps``: steps of the parity runs (50: 0.1 s)."""
    import warp as wp

    wp.config.quiet = True
    dev = wp.get_device(device)
    if nworlds is None:
        nworlds = GPU_NWORLD if dev.is_cuda else CPU_NWORLD
        if quick:
            nworlds = nworlds[:3]
    print(machine())
    import mujoco_warp
    print(f"mujoco_warp {mujoco_warp.__version__}, warp {wp.__version__}, device {dev}"
          f"{' (kernels run on the host: correctness and scaling, not GPU speed)' if dev.is_cpu else ''}\n")
    span = f"{parity_steps * 2e-3:g} s"
    print("1. Parity: N worlds on warp against N MjData on the CPU path (every body attached, culling on, "
          f"resolution {resolution!r}), {span}")
    pars = [parity(4, parity_steps, resolution, device, h) for h in (0.0, KNEE_DEEP)]
    print(_table(["surface", "worlds", "elements", "first-step force rel. err.", f"force rel. err. (max, {span})",
                  f"body position err. (max, {span})", "occluded area (max) m^2", "occluded area err. m^2"],
                 [[f"{p['surface_height']:g} m", p["nworld"], p["elements"], f"{p['first_force_rel']:.2e}",
                   f"{p['force_rel_max']:.2e}", f"{p['position_err_m'] * 1e3:.4f} mm", f"{p['occluded_max_m2']:.2e}",
                   f"{p['occluded_err_m2']:.1e}"] for p in pars]))
    par = pars[0]
    print(f"\n2. Throughput: quadruped standing on sand, mujoco_warp.step on {dev} (median of 3 runs)")
    budget = budget_s if budget_s is not None else (0.5 if quick else 1.5)
    rows = throughput(nworlds, device, resolution, budget_s=budget, cpu_budget_s=budget)
    bare = {r["nworld"]: r["world_steps_per_s"] for r in rows
            if r["case"] == CASES[0][0] and r["backend"].startswith("mujoco_warp")}
    cpu_bare = [r["world_steps_per_s"] for r in rows if r["case"] == CASES[0][0] and r["backend"].startswith("CPU")]
    table = []
    for r in rows:
        ref = bare.get(r["nworld"]) if r["backend"].startswith("mujoco_warp") else (cpu_bare[0] if cpu_bare else None)
        table.append([r["backend"], r["case"], r["nworld"], r["elements"] if r["elements"] is not None else "-",
                      f"{r['ms_per_step']:.3f}", f"{r['world_steps_per_s']:.0f}",
                      f"{r['world_steps_per_s'] / ref:.2f}x" if ref else "-"])
    print()
    print(_table(["backend", "case", "nworld", "elements/world", "ms per step", "world-steps/s",
                  "vs no sand"], table))
    files = [plot(rows, Path(out))] if plots else []
    if files:
        print("\nwrote " + ", ".join(str(f) for f in files))
    return dict(parity=par, parity_knee_deep=pars[1], throughput=rows, files=files)


def make_parser(command: str = "bench --warp") -> argparse.ArgumentParser:
    """The options of :func:`main` (``python -m rft_mujoco {command} --help``)."""
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="Batched sand on MuJoCo Warp: parity and world-steps/s tables, plot.")
    parser.add_argument("--device", default="cpu", help="warp device: cpu (default) or cuda:0")
    parser.add_argument("--worlds", "--nworld", dest="worlds", type=int, nargs="+", default=None, metavar="N",
                        help=f"world counts (default {CPU_NWORLD} on cpu, {GPU_NWORLD} on a GPU; the first three "
                             "with --quick); --nworld is an alias")
    parser.add_argument("--resolution", default="default", help="element size preset (default: 'default', 10 mm)")
    parser.add_argument("--out", default="out/bench_warp", help="output folder for the plot")
    parser.add_argument("--quick", action="store_true", help="the first three world counts, shorter timings")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    parser.add_argument("--budget", type=float, default=None, metavar="S",
                        help="seconds of timed stepping per case and world count (default 1.5; 0.5 with --quick)")
    parser.add_argument("--parity-steps", type=int, default=50, metavar="K",
                        help="steps of the parity runs (default 50: 0.1 s)")
    return parser


def main(argv: list[str] | None = None, command: str = "bench --warp") -> int:
    """CLI entry: ``python -m rft_mujoco bench --warp [--device D] [--worlds N ...] [--out DIR] [--quick]``."""
    parser = make_parser(command)
    args = parser.parse_args(argv)
    try:
        import mujoco_warp  # noqa: F401
    except ImportError as exc:
        print(f"MuJoCo Warp is not installed ({exc}): pip install 'rft_mujoco[warp]'")
        return 1
    if args.worlds is not None and min(args.worlds) < 1:
        parser.error(f"--worlds values must be >= 1, got {args.worlds}")
    if args.budget is not None and not args.budget > 0:
        parser.error(f"--budget must be > 0 s, got {args.budget}")
    if args.parity_steps < 1:
        parser.error(f"--parity-steps must be >= 1, got {args.parity_steps}")
    run(args.worlds, args.device, args.out, args.quick, not args.no_plots, args.resolution, args.budget,
        args.parity_steps)
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
