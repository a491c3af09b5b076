"""Sand that remembers: a box's footprint, set back into it, and loaded twice as much (issue 31).

``python -m rft_mujoco footprint [--plot PATH]``. A 5 kg box (10 x 10 x 4 cm, free joint) on loose glass
beads (``li_loose_glass_beads``) with a :class:`~rft_mujoco.DeformableSurface` (0.4 x 0.4 m, 5 mm cells,
defaults otherwise: reload ratio 20, no compaction, berm 5 cm wide), compiled backend (``--backend numpy``: the
reference), timestep 1 ms.

Every load is applied quasi-statically: the box starts touching the surface, held by an upward force at its
COM equal to its weight, and that support is ramped to zero over :data:`RAMP` s, then held :data:`HOLD` s
(a box dropped from contact would overshoot to about twice its static sinkage, as a spring does; 3D-RFT
is a quasi-static law). Extra load is a downward force at the COM ramped the same way. Sinkage is measured
from the initial surface to the box's bottom face.

1. Fresh bed, weight W: the box rests at sinkage ``s1``; the surface of ``handle.surface(data)`` under the
   box's outline (the nodes within its bottom face) is ``s1`` deep within :data:`DEPTH_TOL`; the nodes more
   than ``s1 / 2`` deep span the box's outline within one cell; the net volume change over the grid is
   within :data:`VOLUME_TOL` of the footprint volume.
2. The box lifted out and set back in its footprint (bottom face on the footprint's bottom, the same
   sand state), weight W ramped on again: sinkage ``s_back``, at most :data:`BACK_TOL` more than ``s1``.
3. Then twice the weight (an extra W ramped on): sinkage ``s2``, within :data:`TWICE_TOL` of ``s2_fresh``,
   the same box on a fresh bed loaded with 2 W the same way.
For reference the sinkages on the undeformable flat surface (W and 2 W) are printed too. Units: SI
(printed in mm).
"""

from __future__ import annotations

import argparse
import time
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.physics import deform
from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.tables import Columns

MEDIA = "li_loose_glass_beads"
MASS = 5.0
"""kg."""
HALF = (0.05, 0.05, 0.02)
"""m, the box's half-sizes (10 x 10 x 4 cm)."""
TIMESTEP = 0.001
RAMP = 2.0
"""s over which a load is ramped on."""
HOLD = 0.2
"""s the load is held before the sinkage is read."""
GRID = dict(size=(0.4, 0.4), cell=0.005)
DEPTH_TOL = 0.002
"""m: footprint depth against s1 (issue 31)."""
VOLUME_TOL = 0.05
"""Net volume change over footprint volume."""
BACK_TOL = 0.20
"""Set back in its footprint with the same load: sinkage at most this fraction more than s1."""
TWICE_TOL = 0.10
"""Twice the load in the footprint against a fresh bed with twice the weight, relative."""

XML = f"""<mujoco><option timestep="{TIMESTEP}"/><worldbody>
<body name="box" pos="0 0 {HALF[2]}"><freejoint/>
<geom type="box" size="{HALF[0]} {HALF[1]} {HALF[2]}" mass="{MASS}"/></body></worldbody></mujoco>"""


class Bed:
    """The box on a fresh bed (deformable, or flat with ``deformable=False``)."""

    def __init__(self, deformable: bool = True, backend: str = "auto") -> None:
        self.model = mujoco.MjModel.from_xml_string(XML)
        terrain = DeformableSurface(**GRID) if deformable else 0.0
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.handle = attach(self.model, MEDIA, surface_height=terrain, backend=backend, monitor=False)
        self.data = mujoco.MjData(self.model)
        self.body = self.model.body("box").id
        self.weight = MASS * float(-self.model.opt.gravity[2])

    def sinkage(self) -> float:
        """m, from the initial surface (z = 0) to the bottom face."""
        return HALF[2] - float(self.data.qpos[2])

    def load(self, start: float, end: float) -> float:
        """Ramp the net load (N, down, weight included) from ``start`` to ``end`` over RAMP s and hold HOLD s;
        returns the sinkage (m)."""
        n_ramp, n_hold = int(round(RAMP / TIMESTEP)), int(round(HOLD / TIMESTEP))
        for i in range(n_ramp + n_hold):
            f = start + (end - start) * min((i + 1) / n_ramp, 1.0)
            self.data.xfrc_applied[self.body, 2] = self.weight - f      # support (+) or extra load (-)
            mujoco.mj_step(self.model, self.data)
        return self.sinkage()

    def set_at(self, bottom: float) -> None:
        """Put the box (still, level, at x = y = 0) with its bottom face at height ``bottom`` m."""
        self.data.qpos[:3] = (0.0, 0.0, bottom + HALF[2])
        self.data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)


def outline_error(surface: deform.DeformedSurface, depth: float) -> float:
    """m, the largest distance between the extent of the nodes deeper than ``depth`` and the box's outline."""
    deep = surface.heights < -depth
    if not deep.any():
        return float("inf")
    xs, ys = surface.x[deep.any(axis=0)], surface.y[deep.any(axis=1)]
    return float(max(abs(xs.min() + HALF[0]), abs(xs.max() - HALF[0]), abs(ys.min() + HALF[1]),
                     abs(ys.max() - HALF[1])))


def run(references: bool = True, backend: str = "auto") -> dict:
    """The three measurements and (``references``, default True) the flat references (module docstring); every
    length in m. ``references=False`` skips the two flat runs (``flat_s1``, ``flat_s2`` absent), which only
    the printed table shows and no criterion reads: a third of the study's steps (tests/test_footprint.py).
    ``backend``: of every bed (``attach``'s; "auto": compiled)."""
    t0 = time.perf_counter()
    bed = Bed(backend=backend)
    w = bed.weight
    s1 = bed.load(0.0, w)
    surf = bed.handle.surface(bed.data)
    x, y = surf.x, surf.y
    under = (np.abs(x)[None, :] <= HALF[0] + 1e-9) & (np.abs(y)[:, None] <= HALF[1] + 1e-9)
    first = surf.copy()
    r = {"s1": s1, "footprint_depth_min": float(-surf.heights[under].max()),
         "footprint_depth_max": float(-surf.heights[under].min()),
         "outline_error": outline_error(surf, s1 / 2), "cell": float(surf.grid.spacing[0]),
         "footprint_volume": deform.footprint_volume(surf), "volume_change": deform.volume_change(surf),
         "berm_max": float(surf.heights.max())}
    bed.set_at(bed.data.qpos[2] + 0.05 - HALF[2])            # lifted out: 5 cm up
    for _ in range(5):
        bed.data.xfrc_applied[bed.body, 2] = w
        mujoco.mj_step(bed.model, bed.data)
    bed.set_at(float(surf.heights[under].max()))             # back on the footprint's bottom
    r["s_back"] = bed.load(0.0, w)
    r["s2"] = bed.load(w, 2 * w)
    r["surface_after"] = bed.handle.surface(bed.data)
    r["surface_first"] = first
    r["s2_fresh"] = Bed(backend=backend).load(0.0, 2 * w)
    if references:
        r["flat_s1"] = Bed(deformable=False, backend=backend).load(0.0, w)
        r["flat_s2"] = Bed(deformable=False, backend=backend).load(0.0, 2 * w)
    r["wall_s"] = time.perf_counter() - t0
    return r


def checks(r: dict) -> dict[str, bool]:
    """The done-when criteria of issue 31 (module docstring), each True or False; every one fails on a run that
    measured nothing (no sinkage, no footprint)."""
    s1 = r["s1"]
    return {
        "footprint s1 deep": s1 > 0.0 and max(abs(r["footprint_depth_min"] - s1),
                                              abs(r["footprint_depth_max"] - s1)) <= DEPTH_TOL,
        "footprint outline": r["outline_error"] <= r["cell"],
        "volume conserved": r["footprint_volume"] > 0.0
        and abs(r["volume_change"]) <= VOLUME_TOL * r["footprint_volume"],
        "set back: same load": s1 > 0.0 and r["s_back"] - s1 <= BACK_TOL * s1,
        "twice the load: virgin": r["s2_fresh"] > 0.0 and abs(r["s2"] - r["s2_fresh"]) <= TWICE_TOL * r["s2_fresh"],
    }


def plot(r: dict, path: str) -> None:
    """Sections y = 0 of the surface after step 1 and after step 3, with the box's sinkages marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    for surf, label in ((r["surface_first"], "after weight W (s1)"), (r["surface_after"], "after 2 W in it")):
        i = int(np.argmin(np.abs(surf.y)))
        ax.plot(surf.x * 1e3, surf.heights[i] * 1e3, label=label)
    for s, ls in ((r["s1"], ":"), (r["s2"], "--")):
        ax.hlines(-s * 1e3, -HALF[0] * 1e3, HALF[0] * 1e3, colors="k", linestyles=ls, lw=1)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("surface height (mm)")
    ax.set_title("5 kg box on loose glass beads: surface at y = 0; box bottom at W dotted, at 2 W dashed",
                 fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None, command: str = "footprint") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="A 5 kg box's footprint in a deformable surface, set back into it "
                                                 "and loaded twice as much (issue 31)")
    parser.add_argument("--plot", default=None, help="also save the surface sections to this PNG")
    parser.add_argument("--backend", default="auto", choices=("auto", "numba", "numpy"),
                        help="attach's backend (default auto: compiled)")
    args = parser.parse_args(argv)
    r = run(backend=args.backend)
    mm = lambda v: f"{v * 1e3:.2f}"                                 # noqa: E731
    table = Columns(["quantity", "mm (or ratio)"], widths=[52, 14])
    print(table.header())
    for name, value in (("s1, weight W on a fresh bed", mm(r["s1"])),
                        ("footprint depth under the box, min..max",
                         f"{mm(r['footprint_depth_min'])}..{mm(r['footprint_depth_max'])}"),
                        ("outline error (extent of nodes deeper than s1/2)", mm(r["outline_error"])),
                        ("net volume change / footprint volume", f"{r['volume_change'] / r['footprint_volume']:.2e}"),
                        ("berm top", mm(r["berm_max"])),
                        ("s_back, set back in the footprint, weight W", mm(r["s_back"])),
                        ("(s_back - s1) / s1", f"{(r['s_back'] - r['s1']) / r['s1']:.3f}"),
                        ("s2, then 2 W in the footprint", mm(r["s2"])),
                        ("s2_fresh, 2 W on a fresh bed", mm(r["s2_fresh"])),
                        ("(s2 - s2_fresh) / s2_fresh", f"{(r['s2'] - r['s2_fresh']) / r['s2_fresh']:.3f}"),
                        ("flat, undeformable surface: W", mm(r["flat_s1"])),
                        ("flat, undeformable surface: 2 W", mm(r["flat_s2"]))):
        print(table.row([name, value]))
    print()
    verdicts = checks(r)
    for name, ok in verdicts.items():
        print(f"{name}: {'pass' if ok else 'FAIL'}")
    print(f"wall time {r['wall_s']:.0f} s", flush=True)
    if args.plot:
        plot(r, args.plot)
        print(f"plot: {args.plot}")
    return 0 if all(verdicts.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
