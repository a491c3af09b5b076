"""The validation run's output: the printed report, the CSVs and the plots."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from rft_mujoco.physics.media import DEM_GLASS_BEADS, MPM_VALIDATION
from rft_mujoco.geometry import surface
from rft_mujoco.studies import overlap
from rft_mujoco.studies.validation.protocol import *  # noqa: F401,F403
from rft_mujoco.studies.validation.protocol import Log, Results
from rft_mujoco.tables import table

def report(res: Results, log: Log, size: float, quick: bool) -> None:
    m = MPM_VALIDATION
    log(f"3D-RFT validation intrusions (Agarwal et al. 2023){' [quick]' if quick else ''}: element size "
        f"{size * 1000:g} mm, published law")
    log(f"media {m.name}: rho_c {m.rho_c:g} kg/m^3, mu_int {m.mu_int:g}, mu_surf {m.mu_surf:g}, "
        f"xi_n {m.xi_n:.4g} N/m^3; centroid {CENTRE_DEPTH * 100:g} cm deep, {SPEED} m/s along "
        "(cos t, 0, sin t), t from horizontal +x, -90 = straight down")
    log()
    for name, s in res.shapes.items():
        log(f"  {name:<18} {s.description}")
    names = list(res.shapes)
    for k, label in ((0, "Fx"), (2, "Fz")):
        log()
        log(f"{label} (N), mean of {SAMPLES} samples over {WINDOW * 1000:g} ms")
        rows = [[f"{a:+.0f}"] + [f"{res.force[n][i, k]:.1f}" for n in names] for i, a in enumerate(res.angles_deg)]
        for line in table(["deg"] + names, rows).splitlines():
            log(line)
    log()
    log("rows at exactly 0 and +-90 deg include faces with n.v = 0 (flat tops and bottoms sliding sideways, "
        "vertical sides moving vertically), which the library counts as leading (law.LEADING_TOL)")
    log()
    log("artefact guards vs published: mean over directions of (|F_g| - |F|)/|F| in %, "
        "[max over directions of |F_g - F|/|F| in % @ its direction]")
    rows = []
    for n in names:
        row = [n]
        for g in GUARD_SETTINGS:
            mean, mx = res.guard_change[n][g]
            p, q = res.force[n], res.guarded[n][g]
            worst = res.angles_deg[int(np.argmax(np.linalg.norm(q - p, axis=1) / np.linalg.norm(p, axis=1)))]
            row.append(f"{100 * mean:+.2f} [{100 * mx:.1f}" + (f" @{worst:+.0f}]" if mx > 0 else "]"))
        rows.append(row)
    for line in table(["shape"] + list(GUARD_SETTINGS), rows).splitlines():
        log(line)
    if res.convergence:
        log()
        sizes = list(next(iter(res.convergence.values())))
        log(f"convergence: |F| (N) at directions {list(CONVERGENCE_ANGLES_DEG)} deg for element sizes "
            + ", ".join(f"{s} {surface.RESOLUTIONS[s] * 1000:g} mm" for s in sizes)
            + f" (curved meshes: facets of half the size); [max |F - F_{sizes[-1]}|/|F_{sizes[-1]}| %]")
        rows = []
        for n, per in res.convergence.items():
            ref = per[sizes[-1]]
            for s in sizes:
                err = np.linalg.norm(per[s] - ref, axis=1) / np.linalg.norm(ref, axis=1)
                rows.append([n, s] + [f"{x:.1f}" for x in np.linalg.norm(per[s], axis=1)]
                            + [f"{100 * err.max():.2f}"])
        headers = ["shape", "size"] + [f"{a:+d}" for a in CONVERGENCE_ANGLES_DEG] + ["err %"]
        for line in table(headers, rows).splitlines():
            log(line)
    log()
    d = DEM_GLASS_BEADS
    log(f"cylinder drill: 50 mm x 140 mm cylinder, axis horizontal (x), spun about +z, {DRILL_SPEED} m/s down "
        f"from {DRILL_CLEARANCE * 1000:g} mm above the surface; media {d.name} (xi_n {d.xi_n:.4g} N/m^3)")
    rows = []
    for omega, r in res.drill.items():
        for t in DRILL_TABLE_TIMES:
            i = int(np.argmin(np.abs(r.time - t)))
            if abs(r.time[i] - t) > 1e-9:
                continue
            bottom = -(r.position[i, 2] - DRILL_RADIUS)
            rows.append([f"{omega / math.pi:g} pi", f"{t:.2f}", f"{100 * bottom:.1f}", f"{r.force[i, 2]:.2f}",
                         f"{np.hypot(r.force[i, 0], r.force[i, 1]):.2e}", f"{r.torque[i, 2]:.4f}",
                         f"{np.hypot(r.torque[i, 0], r.torque[i, 1]):.2e}"])
    for line in table(["omega rad/s", "t s", "bottom cm", "Fz N", "|Fxy| N", "Mz N m", "|Mxy| N m"], rows).splitlines():
        log(line)
    log("bunny drill: skipped (needs the Stanford-bunny mesh, which this project does not ship)")
    log()
    if res.overlap:
        log(f"overlapping geoms (rft_mujoco.studies.overlap): the coupling at the default element size, with and "
            f"without culling, against the brute-force exposed surface at {overlap.REFERENCE_SIZE * 1000:g} mm; "
            f"{overlap.SPEED} m/s, fully submerged; 'hidden': share of the surface inside another geom")
        for line in overlap.table_lines(res.overlap):
            log(line)
        log()
    log("sanity checks")
    for c in res.checks:
        log(f"  {'PASS' if c.passed else 'FAIL'}  {c.name}: {c.value:.3g} ({c.limit})")


def write_csv(res: Results, out: Path) -> list[Path]:
    files = []
    p = out / "directions.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["shape", "law", "theta_deg", "Fx_N", "Fy_N", "Fz_N", "Mx_Nm", "My_Nm", "Mz_Nm"])
        for n in res.shapes:
            for i, a in enumerate(res.angles_deg):
                w.writerow([n, "published", a, *res.force[n][i], *res.torque[n][i]])
            for g, f in res.guarded[n].items():
                for i, a in enumerate(res.angles_deg):
                    w.writerow([n, g, a, *f[i], "", "", ""])
    files.append(p)
    p = out / "guards.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["shape", "guard", "mean_rel_change_absF", "max_rel_change_F"])
        for n, per in res.guard_change.items():
            for g, (mean, mx) in per.items():
                w.writerow([n, g, mean, mx])
    files.append(p)
    p = out / "drill.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["omega_rad_s", "t_s", "z_com_m", "Fx_N", "Fy_N", "Fz_N", "Mx_Nm", "My_Nm", "Mz_Nm"])
        for omega, r in res.drill.items():
            for i in range(r.time.size):
                w.writerow([omega, r.time[i], r.position[i, 2], *r.force[i], *r.torque[i]])
    files.append(p)
    if res.overlap:
        p = out / "overlap.csv"
        with p.open("w", newline="") as fh:
            w = csv.writer(fh)
            keys = ["case", "motion", "hidden_fraction", "error", "error_no_cull", "overcount", "area_error"]
            w.writerow(keys + ["Fx_ref_N", "Fy_ref_N", "Fz_ref_N", "Fx_N", "Fy_N", "Fz_N", "Fx_no_cull_N",
                               "Fy_no_cull_N", "Fz_no_cull_N"])
            for row in res.overlap:
                w.writerow([row[k] for k in keys] + row["force_ref"] + row["force"] + row["force_no_cull"])
        files.append(p)
    p = out / "checks.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["check", "value", "limit", "passed"])
        for c in res.checks:
            w.writerow([c.name, c.value, c.limit, c.passed])
    files.append(p)
    return files


LOG_FLOOR = 1e-18
"""Smallest value drawn on the drill plot's log axis (exact zeros before contact sit on it)."""


def plots(res: Results, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    names = list(res.shapes)
    ncol = 3
    nrow = -(-len(names) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False, sharex=True)
    for ax, n in zip(axes.flat, names):
        f, g = res.force[n], res.guarded[n]["all"]
        ax.plot(res.angles_deg, f[:, 0], "o-", color="C0", label="Fx")
        ax.plot(res.angles_deg, f[:, 2], "s-", color="C3", label="Fz")
        ax.plot(res.angles_deg, g[:, 0], ":", color="C0", label="Fx, all guards")
        ax.plot(res.angles_deg, g[:, 2], ":", color="C3", label="Fz, all guards")
        ax.axhline(0, color="0.7", lw=0.5)
        ax.set_title(n, fontsize=10)
        ax.set_xticks(np.arange(-90, 91, 45))
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("direction (deg from +x, -90 = down)")
    for ax in axes[:, 0]:
        ax.set_ylabel("force (N)")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"3D-RFT, {MPM_VALIDATION.name}, centroid {CENTRE_DEPTH * 100:g} cm deep, {SPEED} m/s")
    fig.tight_layout()
    p = out / "directions.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharex=True)
    for omega, r in res.drill.items():
        label = f"omega = {omega / math.pi:g} pi rad/s"
        line, = axes[0].plot(r.time, r.force[:, 2], label=label)
        axes[1].plot(r.time, r.torque[:, 2], color=line.get_color())
        axes[2].semilogy(r.time, np.maximum(np.hypot(r.force[:, 0], r.force[:, 1]), LOG_FLOOR), "-",
                         color=line.get_color(), lw=0.8)
        axes[2].semilogy(r.time, np.maximum(np.hypot(r.torque[:, 0], r.torque[:, 1]), LOG_FLOOR), ":",
                         color=line.get_color(), lw=0.8)
    axes[0].set_ylabel("Fz (N)")
    axes[1].set_ylabel("Mz (N m)")
    axes[2].set_ylabel("|F_xy| (N, solid), |M_xy| (N m, dotted)")
    axes[2].set_title("zero up to round-off (half-turn symmetry)", fontsize=9)
    axes[2].set_ylim(LOG_FLOOR / 2, 1.0)
    for ax in axes:
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"cylinder drill (50 x 140 mm, axis horizontal), {DRILL_SPEED} m/s down from the surface, "
                 f"{DEM_GLASS_BEADS.name}")
    fig.tight_layout()
    p = out / "drill.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(names)), 3.8))
    width = 0.8 / len(GUARD_SETTINGS)
    x = np.arange(len(names))
    for j, g in enumerate(GUARD_SETTINGS):
        ax.bar(x + (j - 1.5) * width, [100 * res.guard_change[n][g][0] for n in names], width, label=g)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("mean change of |F| (%)")
    ax.axhline(0, color="k", lw=0.5)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title("artefact guards vs the published law")
    fig.tight_layout()
    p = out / "guards.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    if res.convergence:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        for n, per in res.convergence.items():
            sizes = list(per)
            ref = per[sizes[-1]]
            h = [surface.RESOLUTIONS[s] for s in sizes[:-1]]
            err = [np.max(np.linalg.norm(per[s] - ref, axis=1) / np.linalg.norm(ref, axis=1)) for s in sizes[:-1]]
            ax.loglog(h, np.maximum(err, 1e-16), "o-", label=n)
        ax.set_xlabel("element size (m)")
        ax.set_ylabel(f"max |F - F_{sizes[-1]}| / |F_{sizes[-1]}|")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        fig.tight_layout()
        p = out / "convergence.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(p)
    return files


