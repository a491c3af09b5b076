"""Plots of the stability study (:mod:`rft_mujoco.studies.stability`): the stability map and the naive coupling's."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from rft_mujoco.studies.stability_cases import (DEFAULT_HEIGHT, DEFAULT_MEDIA, INTEGRATORS, MASSES, REST_DEADLINE,
                                                REST_SPEED, SHAPES, TIMESTEPS, Result)


def plot(results: list[Result], path: Path) -> None:
    """Stability map: time to rest over mass x timestep, one panel per shape and integrator."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    drops = [r for r in results if r.case.group == "matrix"]
    if not drops:
        return
    fig, axes = plt.subplots(len(SHAPES), len(INTEGRATORS), figsize=(12, 9), squeeze=False,
                             sharex=True, sharey=True)
    masses, dts = list(MASSES), list(TIMESTEPS)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="red")
    for i, shape in enumerate(SHAPES):
        for j, integ in enumerate(INTEGRATORS):
            ax = axes[i][j]
            grid = np.full((len(masses), len(dts)), np.nan)
            jit = np.full_like(grid, np.nan)
            for r in drops:
                c = r.case
                if c.shape == shape and c.integrator == integ and c.mass in masses and c.dt in dts:
                    grid[masses.index(c.mass), dts.index(c.dt)] = r.t_rest if not r.nan else np.nan
                    jit[masses.index(c.mass), dts.index(c.dt)] = r.jitter
            im = ax.imshow(np.ma.masked_invalid(np.where(np.isinf(grid), np.nan, grid)), origin="lower",
                           cmap=cmap, vmin=0.0, vmax=REST_DEADLINE, aspect="auto")
            for a in range(len(masses)):
                for b in range(len(dts)):
                    t = grid[a, b]
                    txt = "never" if t == math.inf else "-" if t != t else f"{t:.2f}s"
                    ax.text(b, a, f"{txt}\n{jit[a, b]:.0e}", ha="center", va="center", fontsize=6,
                            color="white" if t == t and t < 1.2 else "black")
            ax.set_title(f"{shape}, {integ}", fontsize=9)
            ax.set_xticks(range(len(dts)), [f"{d * 1e3:g}" for d in dts])
            ax.set_yticks(range(len(masses)), [f"{m:g}" for m in masses])
            if i == len(SHAPES) - 1:
                ax.set_xlabel("timestep (ms)")
            if j == 0:
                ax.set_ylabel("mass (kg)")
    fig.colorbar(im, ax=axes, label="time to rest (s); text: time to rest / jitter (m/s) over the last 0.5 s")
    fig.suptitle(f"Drop tests on {DEFAULT_MEDIA}, h = {DEFAULT_HEIGHT} m, stabilize=True")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_naive(results: list[Result], path: Path) -> None:
    """Jitter (largest speed over the last 0.5 s) and largest energy gain per step of the naive coupling
    against the stabilized one, for the drop cases run both ways."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stab = {dataclasses.replace(r.case, stabilize=True, group=""): r for r in results if r.case.stabilize}
    pairs = [(r, stab.get(dataclasses.replace(r.case, stabilize=True, group="")))
             for r in results if not r.case.stabilize and r.case.kind == "drop"]
    pairs = [(n, s_) for n, s_ in pairs if s_ is not None]
    if not pairs:
        return
    floor = 1e-18
    x = np.arange(len(pairs))
    fig, ax = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    ax[0].bar(x - 0.2, [max(n.jitter, floor) for n, _ in pairs], 0.4, label="naive (stabilize=False)")
    ax[0].bar(x + 0.2, [max(s_.jitter, floor) for _, s_ in pairs], 0.4, label="stabilized (default)")
    ax[0].axhline(REST_SPEED, color="k", lw=0.8, ls="--", label="rest threshold 1 mm/s")
    ax[0].set_yscale("log")
    ax[0].set_ylabel("jitter over the last 0.5 s (m/s)")
    ax[0].legend(fontsize=8)
    ax[1].bar(x - 0.2, [max(n.max_gain, floor) for n, _ in pairs], 0.4)
    ax[1].bar(x + 0.2, [max(s_.max_gain, floor) for _, s_ in pairs], 0.4)
    ax[1].set_yscale("log")
    ax[1].set_ylabel("largest energy added by the sand in a step (J)\n(floor 1e-18: none)")
    ax[1].set_xticks(x, [f"{n.case.shape} {n.case.mass:g}kg {n.case.dt * 1e3:g}ms {n.case.integrator}"
                         for n, _ in pairs], rotation=70, fontsize=7)
    fig.suptitle("Naive coupling against the stabilized one (drops from 0.1 m on mpm_validation)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
