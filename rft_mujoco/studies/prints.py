"""Footprints: the demo quadruped trotting on a deformable surface, drawn and costed (issue 31).

``python -m rft_mujoco prints [--seconds S] [--out DIR] [--no-cost]``. The demo scene
(:mod:`rft_mujoco.studies.demo`: the Go1-class quadruped on loose glass beads, every body attached, its
scripted trot after 0.5 s of standing) with its terrain replaced by a :class:`~rft_mujoco.DeformableSurface`
(2 x 1 m around x = 0.5 m, 1 cm cells, defaults otherwise; compiled backend). Saves ``prints_surface.png``
(the surface from above after the run) and, where offscreen rendering works (``MUJOCO_GL=egl``),
``prints_frame.png``: the last frame, the deformed surface drawn as a MuJoCo heightfield
(:class:`SurfaceDrawing`). With the cost measurement (default), the trot is timed on the demo's own flat
surface and on the deformable one, compiled, in alternating chunks (one repetition of issue 31's benchmark,
``python -m rft_mujoco bench --deformable``), and the whole run once on the flat surface with the numpy
backend; the CPU times per simulated second are printed (``time.process_time``).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.studies.surface_view import GRID, add_surface_hfield, write_surface

STAND_S = 0.5
"""s standing before the trot."""


class SurfaceDrawing:
    """Draws a deformable surface in MuJoCo's renderer: a copy of the model with a heightfield geom over the
    grid (visual only, :func:`add_surface_hfield`), its elevation data rewritten from the surface at every frame
    and uploaded to the renderer's GPU context (``mujoco.mjr_uploadHField``). The simulated model is not
    changed: a separate MjData of the copy takes the simulation's ``qpos`` for each frame.

    Args:
        xml_path: the path of the simulated model's XML.
        grid: the :class:`DeformableSurface`.
        hide: names of geoms to make invisible in the drawing (the floor the heightfield replaces).
        size: (height, width) of the images, pixels.
    """

    def __init__(self, xml_path: str, grid: DeformableSurface, hide=("floor",), size=(368, 640)) -> None:
        spec = mujoco.MjSpec.from_file(xml_path)
        add_surface_hfield(spec, grid)
        self.model = spec.compile()
        for name in hide:
            gid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
            if gid >= 0:
                self.model.geom_rgba[gid, 3] = 0.0
        self.model.vis.quality.offsamples = 0
        self.data = mujoco.MjData(self.model)
        self.grid = grid
        self.renderer = mujoco.Renderer(self.model, *size)

    def frame(self, qpos: np.ndarray, heights: np.ndarray, camera: str | int = -1) -> np.ndarray:
        """An RGB image (h, w, 3) of the pose ``qpos`` over the surface ``heights`` (ny, nx) m."""
        self.data.qpos[:] = qpos
        mujoco.mj_forward(self.model, self.data)
        hid = write_surface(self.model, heights, self.grid)
        mujoco.mjr_uploadHField(self.model, self.renderer._mjr_context, hid)
        self.renderer.update_scene(self.data, camera=camera)
        return self.renderer.render()

    def close(self) -> None:
        self.renderer.close()


def trot(seconds: float, terrain: str = "deformable", draw: bool = False) -> dict:
    """The demo for ``seconds`` s on ``terrain``: "deformable" (compiled), "flat" (the demo's own, compiled),
    or "flat_numpy"; returns cpu_per_sim_s, trunk_x_m, the surface (deformable only) and the last frame (draw)."""
    from rft_mujoco.studies.demo import Demo, scene_path

    if terrain not in ("deformable", "flat", "flat_numpy"):
        raise ValueError(f"terrain must be 'deformable', 'flat' or 'flat_numpy', got {terrain!r}")
    demo = Demo(stand_s=STAND_S, backend="numpy" if terrain == "flat_numpy" else "auto")
    if terrain == "deformable":
        demo.sand.terrain = DeformableSurface(height=float(demo.sand.terrain.max_height), **GRID)
    n = int(round(seconds / demo.model.opt.timestep))
    cpu = time.process_time()
    for _ in range(n):
        demo.step()
    cpu = time.process_time() - cpu
    out = {"cpu_per_sim_s": cpu / seconds, "trunk_x_m": float(demo.data.qpos[0]), "backend": demo.sand.backend}
    if terrain == "deformable":
        out["surface"] = demo.sand.surface(demo.data)
        if draw:
            try:
                drawing = SurfaceDrawing(str(scene_path()), demo.sand.terrain)
            except Exception as exc:  # no GL context: say so and go on
                print(f"frame skipped: offscreen rendering unavailable ({type(exc).__name__}: {exc}); "
                      "set MUJOCO_GL=egl")
            else:
                out["frame"] = drawing.frame(demo.data.qpos, out["surface"].heights, camera="track")
                drawing.close()
    demo.close()
    return out


def trot_demo(run: str, interval: float | None = None):
    """A fresh demo (the prints study's scene and gait) on the surface of ``run`` ("flat", "deformable" or
    "deformable_numpy"; a deformable one updated every ``interval`` s, None: the default), stood for its 0.5 s
    (untimed)."""
    from rft_mujoco.studies.demo import Demo

    warnings.simplefilter("ignore")                  # (the validity monitor's warnings of the trot: not timed here)
    demo = Demo(stand_s=STAND_S, backend="numpy" if run == "deformable_numpy" else "auto")
    if run != "flat":
        grid = GRID if interval is None else dict(GRID, update_interval=interval)
        demo.sand.terrain = DeformableSurface(height=float(demo.sand.terrain.max_height), **grid)
    want = "numpy" if run == "deformable_numpy" else "numba"
    if demo.sand.backend != want:
        raise RuntimeError(f"the {run} run needs the {want} backend, got {demo.sand.backend}")
    for _ in range(int(round(STAND_S / demo.model.opt.timestep))):
        demo.step()
    return demo


def side_by_side(runs: tuple, seconds: float, chunk: int = 25, interval: float | None = None) -> list[dict]:
    """The demo quadruped trotting for ``seconds`` s after its stand (untimed), one fresh demo per run of
    ``runs``, their steps timed in alternating chunks of ``chunk`` steps (so that a machine whose speed drifts,
    as a shared one does, slows every run alike). Per run: ``cpu`` (CPU s per simulated s), ``trunk_x`` (m) and,
    on a deformable surface, ``deepest`` and ``berm`` (m, below and above the initial surface)."""
    demos = [trot_demo(run, interval) for run in runs]
    dt = demos[0].model.opt.timestep
    n = int(round(seconds / dt))
    cpu = [0.0] * len(demos)
    for start in range(0, n, chunk):
        for k, demo in enumerate(demos):
            t = time.process_time()
            for _ in range(min(chunk, n - start)):
                demo.step()
            cpu[k] += time.process_time() - t
    out = []
    for run, demo, c in zip(runs, demos, cpu):
        row = dict(cpu=c / (n * dt), trunk_x=float(demo.data.qpos[0]))
        if run != "flat":
            s = demo.sand.surface(demo.data)
            if np.ptp(s.heights) == 0.0:
                raise RuntimeError(f"the {run} run left its surface flat: it measured no grid update")
            row.update(deepest=float(s.grid.height - s.heights.min()), berm=float(s.heights.max() - s.grid.height))
        demo.close()
        out.append(row)
    return out


def plot_surface(surface, path: Path) -> None:
    """The surface from above (colour: height relative to the initial surface, mm)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.6))
    rel = (surface.heights - surface.grid.height) * 1e3
    lim = max(float(np.abs(rel).max()), 1e-3)
    im = ax.imshow(rel, origin="lower", extent=[surface.x[0], surface.x[-1], surface.y[0], surface.y[-1]],
                   cmap="BrBG", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, label="height change (mm)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("the trotting quadruped's footprints (deformable surface, loose glass beads)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None, command: str = "prints") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="The demo quadruped trotting on a deformable surface: footprints, "
                                                 "a rendered frame, the cost against the flat surface")
    parser.add_argument("--seconds", type=float, default=2.5, help="s simulated (default 2.5: 2 s of trot)")
    parser.add_argument("--out", type=Path, default=Path("out/prints"))
    parser.add_argument("--no-cost", action="store_true", help="skip the flat-surface runs")
    args = parser.parse_args(argv)
    if not args.seconds > STAND_S:
        parser.error(f"--seconds must be > {STAND_S} (the stand), got {args.seconds}")
    args.out.mkdir(parents=True, exist_ok=True)
    r = trot(args.seconds, "deformable", draw=True)
    s = r["surface"]
    rel = s.heights - s.grid.height
    print(f"deformable ({r['backend']}): trunk x {r['trunk_x_m']:.3f} m after {args.seconds:g} s; deepest footprint "
          f"{-rel.min() * 1e3:.1f} mm, highest berm {rel.max() * 1e3:.1f} mm, nodes pressed "
          f"{int(np.count_nonzero(s.preload))}")
    plot_surface(s, args.out / "prints_surface.png")
    print(f"plot: {args.out / 'prints_surface.png'}")
    if "frame" in r:
        import matplotlib.pyplot as plt
        plt.imsave(args.out / "prints_frame.png", r["frame"])
        print(f"frame: {args.out / 'prints_frame.png'}")
    if not args.no_cost:
        with warnings.catch_warnings():
            side_by_side(("flat", "deformable"), 0.2)                  # untimed: the first pair runs unevenly
            flat, deformable = (r["cpu"] for r in side_by_side(("flat", "deformable"), args.seconds - STAND_S))
        flat_numpy = trot(args.seconds, "flat_numpy")["cpu_per_sim_s"]
        print(f"CPU s per simulated s of the trot (flat and deformable in alternating chunks, compiled): flat "
              f"{flat:.2f}, deformable {deformable:.2f} ({deformable / flat:.2f}x); the flat surface on numpy "
              f"{flat_numpy:.2f} (the whole run; deformable compiled / flat numpy {deformable / flat_numpy:.2f}x)",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
