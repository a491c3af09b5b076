"""Any mass: the swimmer's wave efficiency from each sand solve against the quasi-static limit.

``python -m rft_mujoco anymass [--quick] [--workers N] [--out DIR]``. 3D-RFT is rate-independent and
quasi-static: a kinematically driven swimmer must swim as its inertia-free limit
(:func:`rft_mujoco.studies.quasistatic.swimmer_limit`) says, whatever it weighs. This study drives the bundled
swimmer as the swim study does (:func:`rft_mujoco.studies.swim.swim`: stiff position servos, the serpenoid at
1 Hz, 4 cycles, speed over the last 2) at the animal's density (:data:`ANIMAL`: 1,100 kg/m^3, 22 g; armature
and joint damping: the bundled model) and at the swim study's 100x (:data:`MASS_SCALED`,
:func:`rft_mujoco.studies.swim.scale_density`), at several timesteps and joint amplitudes, with each sand solve (``attach(solve=...)``), at an element
size where the limit is converged (:data:`ELEMENT_SIZE`), and reports each eta's error against the limit at
the same element size.

Cost: the implicit solve runs on the numpy backend by default (about 0.07 s a step at 3 mm on one core of a
2-core machine; ``--backend numba`` runs it compiled, docs/rest.md "The implicit solve" has its cost).
Measured on this project's 2-core VM with other jobs running: the animal's half of the grid 4,760 s on 2 workers
(the 100x half costs about as much); ``--quick`` (amplitudes 0.5 and 0.9 rad at dt 2 ms) 6 min.
Units: SI (s, m, rad); eta is dimensionless.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import multiprocessing
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from rft_mujoco import tables

AMPLITUDES = (0.3, 0.5, 0.7, 0.9, 1.1, 1.3)
"""rad: the swim study's amplitudes from 0.3 to 1.3 rad."""
TIMESTEPS = (0.002, 0.001, 0.0005)
"""s."""
ANIMAL = 1.0
"""The animal's density over the bundled model's: the bundled model is the animal (0.01 until 2026-12-04, when
it was 100x the animal's; see the model's header)."""
MASS_SCALED = 100.0
"""The swim study's mass-scaled body (:data:`rft_mujoco.studies.swim.DENSITY_SCALE`), over the bundled model's."""
DENSITIES = (ANIMAL, MASS_SCALED)
SOLVES = ("explicit", "implicit")
ELEMENT_SIZE = 0.003
"""m: where the swimmer's quasi-static limit is converged (docs/rest.md, "Quasi-static references")."""
FREQUENCY = 1.0
"""Hz."""
TOLERANCE = 0.05
"""The target: |eta / eta_limit - 1| at most this (issue 26, item 1)."""
BACKENDS = {"explicit": {}, "implicit": {"solve": "implicit", "backend": "numpy"}}
"""attach() options of each solve (the implicit solve on the numpy reference unless ``--backend numba``)."""


def _limit(amplitude: float, element_size: float, frequency: float, cycles: int) -> dict:
    from rft_mujoco.studies.quasistatic import swimmer_limit

    r = swimmer_limit(amplitude, frequency, element_size=element_size, cycles=cycles)
    return dict(kind="limit", amplitude_rad=amplitude, element_size_m=element_size, eta=r["eta"],
                wall_s=r["wall_s"])


def _run(amplitude: float, density_scale: float, timestep: float, solve: str, element_size: float,
         frequency: float, cycles: int, implicit_backend: str = "numpy") -> dict:
    from rft_mujoco.studies.swim import swim

    options = dict(BACKENDS[solve], backend=implicit_backend) if solve == "implicit" else BACKENDS[solve]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = swim(amplitude, frequency, density_scale=density_scale, timestep=timestep, cycles=cycles,
                 resolution=element_size, **options)
    return dict(kind="run", amplitude_rad=amplitude, density_scale=density_scale, timestep_s=timestep,
                solve=solve, element_size_m=element_size, eta=r["eta"], tracking_rms_rad=r["tracking_rms_rad"],
                wall_s=r["wall_s"])


def _single_thread() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ[var] = "1"


def measure(amplitudes=AMPLITUDES, timesteps=TIMESTEPS, densities=DENSITIES, solves=SOLVES,
            element_size: float = ELEMENT_SIZE, frequency: float = FREQUENCY, cycles: int = 4,
            workers: int = 1, progress=None, implicit_backend: str = "numpy") -> dict:
    """Every (density, timestep, amplitude, solve) run and the limit at each amplitude, on ``workers``
    processes (the implicit solve on ``implicit_backend``, "numpy" or "numba"). Returns
    dict(limits={amplitude: eta}, rows=[...]): each row a run with ``eta_limit`` and ``error``
    (eta / eta_limit - 1) added, sorted by density, timestep, amplitude, solve."""
    jobs = [(_limit, (a, element_size, frequency, cycles)) for a in amplitudes]
    jobs += [(_run, (a, rho, dt, s, element_size, frequency, cycles, implicit_backend))
             for rho in densities for dt in timesteps for a in amplitudes for s in solves]
    if not jobs:
        raise ValueError("nothing to measure: give at least one amplitude, timestep, density and solve")
    results, t0 = [], time.perf_counter()
    progress = progress or (lambda line: print(line, flush=True))

    def note(r: dict) -> None:
        results.append(r)
        what = "limit" if r["kind"] == "limit" else \
            f"{r['solve']:<8} density x{r['density_scale']:g} dt {r['timestep_s'] * 1e3:g} ms"
        progress(f"[anymass {len(results)}/{len(jobs)}, {time.perf_counter() - t0:.0f} s] {what} "
                 f"a={r['amplitude_rad']:.1f} rad: eta {r['eta']:.4f} ({r['wall_s']:.0f} s)")

    if workers <= 1:
        for fn, args in jobs:
            note(fn(*args))
    else:
        _single_thread()
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_single_thread) as pool:
            # the longest first (small timesteps, the implicit solve) so that the pool ends together
            order = sorted(jobs, key=lambda j: -(1.0 / j[1][2] * (20 if j[1][3] == "implicit" else 1))
                           if j[0] is _run else 0.0)
            for fut in as_completed([pool.submit(fn, *args) for fn, args in order]):
                note(fut.result())
    limits = {r["amplitude_rad"]: r["eta"] for r in results if r["kind"] == "limit"}
    rows = [r for r in results if r["kind"] == "run"]
    if len(rows) + len(limits) != len(jobs):
        raise RuntimeError(f"measured {len(rows) + len(limits)} of {len(jobs)} cases")
    for r in rows:
        r["eta_limit"] = limits[r["amplitude_rad"]]
        r["error"] = r["eta"] / r["eta_limit"] - 1.0
    rows.sort(key=lambda r: (r["density_scale"], -r["timestep_s"], r["amplitude_rad"], r["solve"]))
    return dict(limits=limits, rows=rows, element_size_m=element_size, frequency_hz=frequency, cycles=cycles)


def table(result: dict) -> list[str]:
    """One line per (density, timestep, amplitude): the limit and each solve's eta and error."""
    solves = sorted({r["solve"] for r in result["rows"]})
    keyed = {(r["density_scale"], r["timestep_s"], r["amplitude_rad"], r["solve"]): r for r in result["rows"]}
    rows = []
    for rho, dt, a in sorted({k[:3] for k in keyed}, key=lambda k: (k[0], -k[1], k[2])):
        row = [f"x{rho:g}", f"{dt * 1e3:g}", f"{a:.1f}", f"{result['limits'][a]:.4f}"]
        for s in solves:
            r = keyed.get((rho, dt, a, s))
            row += [f"{r['eta']:.4f}", f"{r['error'] * 100:.1f}%"] if r else ["-", "-"]
        rows.append(row)
    headers = ["density", "dt ms", "a rad", "limit"] + [h for s in solves for h in (f"{s} eta", "error")]
    return tables.table(headers, rows, align=tables.RIGHT * len(headers)).splitlines()


def worst(result: dict) -> dict:
    """{solve: largest |error|} over the rows."""
    out: dict = {}
    for r in result["rows"]:
        out[r["solve"]] = max(out.get(r["solve"], 0.0), abs(r["error"]))
    return out


def plot(result: dict, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    amps = sorted(result["limits"])
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    ax.plot(amps, [result["limits"][a] for a in amps], "k-", lw=2.5, label="quasi-static limit")
    styles = {"explicit": "--", "implicit": "-"}
    groups = sorted({(r["solve"], r["density_scale"], r["timestep_s"]) for r in result["rows"]})
    for i, (s, rho, dt) in enumerate(groups):
        sel = sorted((r for r in result["rows"] if (r["solve"], r["density_scale"], r["timestep_s"]) == (s, rho, dt)),
                     key=lambda r: r["amplitude_rad"])
        ax.plot([r["amplitude_rad"] for r in sel], [r["eta"] for r in sel], styles.get(s, ":"), marker="o",
                ms=4, color=f"C{i % 10}", label=f"{s}, density x{rho:g}, dt {dt * 1e3:g} ms")
    ax.set_xlabel("joint amplitude (rad)")
    ax.set_ylabel("wave efficiency eta")
    ax.set_title(f"the swimmer at any mass ({result['element_size_m'] * 1e3:g} mm elements, "
                 f"{result['frequency_hz']:g} Hz)", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "anymass.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run(quick: bool = False, workers: int = 2, out: str | Path = "out/anymass", plots: bool = True,
        implicit_backend: str = "numpy", **grid) -> dict:
    """The study; ``grid`` overrides :func:`measure`'s amplitudes, timesteps, densities, solves or frequency
    (None: the default)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(amplitudes=(0.5, 0.9), timesteps=(0.002,)) if quick else {}
    result = measure(workers=workers, implicit_backend=implicit_backend,
                     **{**kw, **{k: v for k, v in grid.items() if v is not None}})
    print("\nwave efficiency against the quasi-static limit "
          f"({result['element_size_m'] * 1e3:g} mm elements, {result['frequency_hz']:g} Hz)")
    print("\n".join(table(result)))
    for s, e in sorted(worst(result).items()):
        print(f"{s}: largest |error| {e * 100:.1f}% (target {TOLERANCE * 100:g}%)")
    path = out / "anymass.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(result["rows"][0]))
        w.writeheader()
        w.writerows(result["rows"])
    (out / "anymass.json").write_text(json.dumps(
        {**result, "limits": {str(k): v for k, v in result["limits"].items()}}, indent=2))
    files = [path, out / "anymass.json"] + ([plot(result, out)] if plots else [])
    print("wrote " + ", ".join(str(f) for f in files))
    return dict(result, files=files)


def main(argv: list[str] | None = None, command: str = "anymass") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="The swimmer at the animal's density and at 100x, each sand "
                                                 "solve against the quasi-static limit.")
    parser.add_argument("--quick", action="store_true", help="amplitudes 0.5 and 0.9 rad at dt 2 ms only")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--out", default="out/anymass", help="output folder (default out/anymass)")
    parser.add_argument("--no-plots", action="store_true", help="tables and CSV only")
    parser.add_argument("--amplitudes", type=float, nargs="+", help="rad (default 0.3 0.5 ... 1.3)")
    parser.add_argument("--timesteps", type=float, nargs="+", help="s (default 0.002 0.001 0.0005)")
    parser.add_argument("--densities", type=float, nargs="+",
                        help="density over the bundled model's, the animal's (default 1 and 100, the swim study's)")
    parser.add_argument("--solves", nargs="+", choices=SOLVES, help="default both")
    parser.add_argument("--frequency", type=float, default=FREQUENCY,
                        help=f"Hz, the serpenoid's (default {FREQUENCY:g}; the law is rate-independent, so the limit "
                             "is the same at any frequency and only the body's inertia changes)")
    parser.add_argument("--backend", choices=("numpy", "numba"), default="numpy",
                        help="the implicit solve's backend (default numpy, the reference; numba: compiled)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if not args.frequency > 0.0:
        parser.error(f"--frequency must be > 0 Hz, got {args.frequency}")
    for name in ("amplitudes", "timesteps", "densities"):
        bad = [v for v in getattr(args, name) or () if not v > 0.0]
        if bad:
            parser.error(f"--{name} must be > 0, got {bad}")
    run(quick=args.quick, workers=args.workers, out=args.out, plots=not args.no_plots, implicit_backend=args.backend,
        amplitudes=args.amplitudes, timesteps=args.timesteps, densities=args.densities, solves=args.solves,
        frequency=args.frequency)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
