"""Plots of the benchmark tables (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rft_mujoco.studies.bench.kernels import TARGET_ERROR


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def throughput(out: Path, thr) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    n = [r["n"] for r in thr]
    for key, style, label in (("law_numpy", "o--", "element_forces, numpy"),
                              ("law_numba", "o-", "element_forces, numba"),
                              ("kernel_numpy", "s--", "element pass, numpy"),
                              ("kernel_numba", "s-", "element pass, numba")):
        ax.loglog(n, [r[key] for r in thr], style, label=label)
    ax.set_xlabel("elements N")
    ax.set_ylabel("ns per element (single thread)")
    ax.set_title("3D-RFT element throughput")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = out / "throughput.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def overhead(out: Path, quad) -> Path:
    """Bars: us per step with sand, standing and trotting, per resolution and setting; the 5x-bare target."""
    plt = _pyplot()
    keys = list(dict.fromkeys((r["resolution"], r["setting"]) for r in quad))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(keys) + 2), 4.5))
    x = np.arange(len(keys))
    width = 0.27
    for k, (motion, color) in enumerate((("standing", "C0"), ("trotting", "C1"))):
        rows = [next((r for r in quad if (r["resolution"], r["setting"]) == key and r["motion"] == motion), None)
                for key in keys]
        ys = [r["sand_us"] if r else np.nan for r in rows]
        ax.bar(x + (k - 0.5) * width, ys, width, color=color, label=f"with sand, {motion}")
        for i, r in enumerate(rows):
            if r:
                ax.text(x[i] + (k - 0.5) * width, r["sand_us"], f"{r['ratio']:.1f}x", ha="center", va="bottom",
                        fontsize=7)
    bare = [np.mean([r["bare_us"] for r in quad if (r["resolution"], r["setting"]) == key]) for key in keys]
    ax.bar(x + 1.5 * width, bare, width, color="0.6", label="bare mj_step")
    ax.hlines([5.0 * b for b in bare], x - 0.45, x + 0.6, colors="k", linestyles=":", label="target: 5 x bare")
    ax.set_xticks(x, [f"{res}\n{setting}" for res, setting in keys], fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("us per mj_step")
    ax.set_title("quadruped on sand, every body attached: cost per step (ratio to bare)")
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    path = out / "overhead.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def env_rates(out: Path, rates) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(rates))
    ax.bar(x - 0.2, [r["zero_sps"] for r in rates], 0.4, label="zero action (standing)")
    ax.bar(x + 0.2, [r["random_sps"] for r in rates], 0.4, label="random actions")
    ax.set_xticks(x, [r["env"].replace("rft_mujoco/", "") for r in rates], fontsize=8)
    ax.set_ylabel("env steps per second (single thread)")
    ax.set_title("env speed, standing still and moving (single thread)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "env_rates.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def error_vs_cost(out: Path, acc) -> Path:
    plt = _pyplot()
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
    ax.set_xlabel("us per evaluation of the body (numba element pass)")
    ax.set_ylabel("max relative force error over directions (%)")
    flat = [s for s in shapes if s not in curved]
    ax.set_title(f"curved shapes (squares: presets); exact at every size: {', '.join(flat)}", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    for s in shapes:
        rows = [r for r in acc if r["shape"] == s]
        ax2.loglog([r["elements"] for r in rows], [r["numba_us"] for r in rows], "o-", ms=3, label=s)
    ax2.set_xlabel("elements of the body")
    ax2.set_ylabel("us per evaluation (numba element pass)")
    ax2.set_title("cost of one evaluation of one body", fontsize=9)
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    path = out / "error_vs_cost.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def rk4_stages(out: Path, stages) -> Path:
    """Section 2c: one env step's torso velocity error against the sand evaluations per env step, for each
    ``rk4_stages`` mode (a line through its steps), moving and at touchdown and rest."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    for ax, key, title in zip(axes, ("moving_mm_s", "resting_mm_s"),
                              ("moving (random actions)", "touchdown and rest (zero action)")):
        for mode in dict.fromkeys(r["mode"] for r in stages):
            rows = [r for r in stages if r["mode"] == mode]
            line, = ax.loglog([r["evaluations"] for r in rows], [r[key] for r in rows], "o-", label=mode, ms=4)
            for r in rows:
                ax.annotate(f"{r['dt'] * 1e3:g} ms", (r["evaluations"], r[key]), fontsize=7, color=line.get_color(),
                            xytext=(4, 3), textcoords="offset points")
        ticks = sorted({r["evaluations"] for r in stages})
        ax.set_xticks(ticks, [str(t) for t in ticks])
        ax.minorticks_off()
        ax.set_xlabel("sand evaluations per env step (50 ms)")
        ax.set_title(f"SandAnt-v0, one env step, {title}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, title="rk4_stages", title_fontsize=8)
    axes[0].set_ylabel("torso velocity error against 'all' at 0.5 ms (mm/s)")
    fig.suptitle("rk4_stages: the sand's cost follows the evaluations, MuJoCo's own the step (5 ms: twice 10 ms's)",
                 fontsize=9)
    fig.tight_layout()
    path = out / "rk4_stages.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def all_plots(out: Path, thr, quad, rates, acc, stages=None) -> list[Path]:
    """Every plot of one benchmark run (those whose table is not empty)."""
    files = [throughput(out, thr)]
    if quad:
        files.append(overhead(out, quad))
    if rates:
        files.append(env_rates(out, rates))
    files.append(error_vs_cost(out, acc))
    if stages:
        files.append(rk4_stages(out, stages))
    return files
