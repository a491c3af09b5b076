"""The main job: a Go1-class quadruped standing, then trotting on sand (``python -m rft_mujoco demo``).

Headless. Prints a summary (sinkage, per-foot sand forces, simulated seconds per wall second), saves a
plot and, where offscreen rendering works (``MUJOCO_GL=egl``, or ``osmesa`` with Debian's libosmesa6), a
short video. ``python -m rft_mujoco view`` runs the same scene in the interactive ``mujoco.viewer`` with the
sand forces drawn as arrows (needs a display). Both follow the robot: the video from the model's
``track`` camera, the viewer with a tracking camera on the trunk.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.resources
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

from rft_mujoco.models.quadruped import FOOT_BODIES, TrotGait
from rft_mujoco.coupling.scene import attach_scene
from rft_mujoco.tables import table

SCENE = "quadruped_sand.xml"
DEMO_GAIT = {"frequency_hz": 2.5, "step_height_m": 0.09, "hip_height_m": 0.26}
"""Trot on sand: higher swing (9 cm) and a lower stance than on rigid ground, to lift the feet out of the
5-9 cm they sink (the rigid-ground defaults, 6 cm swing, stumble and sink: measured 5 s runs)."""

ARROW_N_PER_M = 200.0
"""Force arrows in the viewer and video: 1 m of arrow per 200 N."""

VIDEO_CAMERA = "track"
"""The model's camera that follows the robot's centre of mass (``mode="trackcom"``): the video's view."""

VIEW_DISTANCE_M = 1.6
"""Distance of the viewer's tracking camera from the trunk, m."""

VIDEO_FPS = 15
"""Frames per simulated second of the demo video (rendered during the run, not in a second simulation)."""

VIDEO_SIZE = (368, 640)
"""Height and width of the video, pixels (multiples of 16: whole H.264 blocks)."""


def scene_path() -> Path:
    """Path of the embedded default scene (the quadruped on loose glass beads)."""
    return Path(str(importlib.resources.files("rft_mujoco.models") / SCENE))


@dataclasses.dataclass
class DemoLog:
    time: list = dataclasses.field(default_factory=list)
    trunk: list = dataclasses.field(default_factory=list)
    foot_force: list = dataclasses.field(default_factory=list)
    foot_depth: list = dataclasses.field(default_factory=list)
    leg_force: list = dataclasses.field(default_factory=list)
    total_force: list = dataclasses.field(default_factory=list)

    def arrays(self):
        return (np.array(self.time), np.array(self.trunk), np.array(self.foot_force), np.array(self.foot_depth))


class Demo:
    """The scene, its sand and the scripted gait, stepped one control period at a time: standing for ``stand_s`` s,
    then trotting (``gait_kwargs`` over :data:`DEMO_GAIT`); ``deformable``: on a deformable surface drawn as a
    heightfield; ``backend``: the sand's (:func:`rft_mujoco.attach`)."""

    def __init__(self, stand_s: float = 1.0, deformable: bool = False, backend: str = "auto", **gait_kwargs):
        self.grid = None
        if deformable:   # a DeformableSurface, drawn by a visual heightfield in place of the floor
            from rft_mujoco.physics.deform import DeformableSurface
            from rft_mujoco.studies.surface_view import GRID, add_surface_hfield

            spec = mujoco.MjSpec.from_file(str(scene_path()))
            plain = spec.compile()
            height = float(plain.numeric("rft/surface_height").data[0])
            self.grid = DeformableSurface(height=height, **GRID)
            add_surface_hfield(spec, self.grid)
            self.model = spec.compile()
            self.model.geom_rgba[self.model.geom("floor").id, 3] = 0.0
        else:
            self.model = mujoco.MjModel.from_xml_path(str(scene_path()))
        self.sand = attach_scene(self.model, backend=backend)[0]
        if self.grid is not None:
            self.sand.terrain = self.grid
        self.data = mujoco.MjData(self.model)
        mujoco.mj_resetDataKeyframe(self.model, self.data, self.model.key("home").id)
        self.gait = TrotGait.from_model(self.model, **{**DEMO_GAIT, **gait_kwargs})
        self.stand_s = stand_s
        self.feet = [self.sand.body_names.index(f) for f in FOOT_BODIES]
        # each leg's bodies (its hip, thigh, calf and foot: the prefix of its foot's name)
        self.legs = [[i for i, n in enumerate(self.sand.body_names) if n.startswith(f.split("_")[0] + "_")]
                     for f in FOOT_BODIES]
        self.trunk = self.model.body("trunk").id

    def step(self) -> None:
        t = self.data.time
        self.data.ctrl[:] = self.gait.stand() if t < self.stand_s else self.gait.targets(t - self.stand_s)
        mujoco.mj_step(self.model, self.data)

    def record(self, log: DemoLog) -> None:
        d = self.sand.diagnostics(self.data)
        log.time.append(self.data.time)
        log.trunk.append(self.data.xpos[self.trunk].copy())
        log.foot_force.append(d.force[self.feet].copy())
        log.foot_depth.append(d.max_depth[self.feet].copy())
        log.leg_force.append([d.force[leg, 2].sum() for leg in self.legs])
        log.total_force.append(d.force[:, 2].sum())

    def surface_hfield(self) -> int | None:
        """With ``deformable``: write the current surface into the model's heightfield; returns its id (to upload
        to a renderer or viewer), else None."""
        if self.grid is None:
            return None
        from rft_mujoco.studies.surface_view import write_surface
        return write_surface(self.model, self.sand.surface(self.data).heights, self.grid)

    def close(self) -> None:
        self.sand.detach()


def track(cam, body: int, distance_m: float = VIEW_DISTANCE_M, azimuth_deg: float = 120.0,
          elevation_deg: float = -20.0) -> None:
    """Make an MjvCamera follow ``body`` (its subtree's centre of mass; ``mjCAMERA_TRACKING``): the
    viewer keeps the robot in view and the mouse still turns and zooms around it."""
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = int(body)
    cam.distance = float(distance_m)
    cam.azimuth = float(azimuth_deg)
    cam.elevation = float(elevation_deg)


def add_force_arrows(scene, sand, data, scale: float = 1.0 / ARROW_N_PER_M) -> None:
    """Append one arrow per loaded sand body (at its COM, along the sand force) to an MjvScene."""
    diag = sand.diagnostics(data)
    for i, b in enumerate(sand.body_ids):
        f = diag.force[i]
        if not np.any(f) or scene.ngeom >= scene.maxgeom:
            continue
        start = data.xipos[b]
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.zeros(9),
                            np.array([1.0, 0.5, 0.1, 1.0], dtype=np.float32))
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_ARROW, 0.006, start, start + scale * f)
        scene.ngeom += 1


def _plot(log: DemoLog, out: Path, stand_s: float) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, trunk, force, depth = log.arrays()
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax[0].plot(t, trunk[:, 0], label="trunk x (m)")
    ax[0].plot(t, trunk[:, 2], label="trunk z (m)")
    ax[0].axvline(stand_s, color="k", lw=0.5, ls="--")
    ax[0].legend(loc="upper left")
    ax[0].set_title("Quadruped on loose glass beads (3D-RFT): stand, then trot")
    for k, name in enumerate(FOOT_BODIES):
        ax[1].plot(t, force[:, k, 2], lw=0.8, label=name)
        ax[2].plot(t, 1000 * depth[:, k], lw=0.8, label=name)
    ax[1].set_ylabel("vertical sand force (N)")
    ax[1].legend(loc="upper right", ncol=4, fontsize=8)
    ax[2].set_ylabel("foot depth (mm)")
    ax[2].set_xlabel("time (s)")
    fig.tight_layout()
    path = out / "demo_quadruped.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


class _Video:
    """Frames of the demo, rendered while it runs: software rendering (no GPU) is the slow part of the demo,
    so no multisampling, shadows or reflections (measured 0.43 -> 0.10 s per frame at 368 x 640 on this
    project's 2-core machine); ``frame(demo)`` renders one frame."""

    def __init__(self, model, fps: int = VIDEO_FPS):
        model.vis.quality.offsamples = 0                  # the demo's own copy of the model
        self.renderer = mujoco.Renderer(model, *VIDEO_SIZE)
        self.every = max(1, int(round(1.0 / (fps * model.opt.timestep))))
        self.fps = fps
        self.frames = []
        self.seconds = 0.0

    def frame(self, demo: "Demo") -> None:
        start = time.perf_counter()
        hid = demo.surface_hfield()
        if hid is not None:
            mujoco.mjr_uploadHField(demo.model, self.renderer._mjr_context, hid)
        self.renderer.update_scene(demo.data, camera=VIDEO_CAMERA)
        flags = self.renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        add_force_arrows(self.renderer.scene, demo.sand, demo.data)
        self.frames.append(self.renderer.render())
        self.seconds += time.perf_counter() - start

    def save(self, path: Path) -> Path:
        import imageio.v2 as imageio

        self.renderer.close()
        imageio.mimsave(path, self.frames, fps=self.fps)
        return path


def _video_or_none(demo: "Demo") -> "_Video | None":
    try:
        import imageio.v2  # noqa: F401

        return _Video(demo.model)
    except Exception as exc:  # no GL context, no imageio: say so and go on
        print(f"video skipped: offscreen rendering unavailable ({type(exc).__name__}: {exc}); "
              "set MUJOCO_GL=egl, or MUJOCO_GL=osmesa with Debian's libosmesa6")
        return None


def run(seconds: float = 5.0, stand_s: float = 1.0, out: Path = Path("out"), video: bool = True,
        deformable: bool = False) -> dict:
    """Run the demo (``deformable``: on a DeformableSurface, drawn in the video); returns the summary numbers
    (also printed)."""
    out.mkdir(parents=True, exist_ok=True)
    demo = Demo(stand_s=stand_s, deformable=deformable)
    log = DemoLog()
    n = int(round(seconds / demo.model.opt.timestep))
    print(f"scene: {scene_path().name}; {demo.sand!r}")
    print(f"simulating {seconds:.1f} s (stand {stand_s:.1f} s, then trot at "
          f"{demo.gait.nominal_speed_mps:.2f} m/s nominal), dt = {demo.model.opt.timestep * 1e3:.1f} ms")
    video_s = min(seconds, 4.0) if video else 0.0
    recorder = _video_or_none(demo) if video else None
    if recorder is not None:
        print(f"rendering a {video_s:.0f} s video while it runs ({recorder.fps} frames per simulated s)")
    wall = time.perf_counter()
    for i in range(n):
        demo.step()
        demo.record(log)
        if recorder is not None and demo.data.time <= video_s + 1e-9 and i % recorder.every == 0:
            recorder.frame(demo)
        if (i + 1) % int(round(1.0 / demo.model.opt.timestep)) == 0:
            frames = f"  {len(recorder.frames)} frames" if recorder is not None else ""
            print(f"  t = {demo.data.time:4.1f} s  trunk x = {demo.data.qpos[0]:+.3f} m  "
                  f"z = {demo.data.qpos[2]:.3f} m{frames}", flush=True)
    wall = time.perf_counter() - wall - (recorder.seconds if recorder is not None else 0.0)
    demo.close()
    t, trunk, force, depth = log.arrays()
    standing = (t > 0.5 * stand_s) & (t <= stand_s)
    trotting = t > stand_s + 1.0
    z0 = float(demo.model.key("home").qpos[2])
    summary = {
        "sim_seconds_per_wall_second": seconds / wall,
        "standing_trunk_sinkage_m": z0 - float(trunk[standing, 2].mean()),
        "standing_foot_depth_m": depth[standing].mean(0),
        "standing_foot_force_N": force[standing, :, 2].mean(0),
        "standing_leg_force_N": np.array(log.leg_force)[standing].mean(0),
        "standing_total_force_N": float(np.array(log.total_force)[standing].mean()),
        "weight_N": float(demo.model.body_subtreemass[1] * -demo.model.opt.gravity[2]),
        "trot_speed_mps": float(np.polyfit(t[trotting], trunk[trotting, 0], 1)[0]) if trotting.sum() > 2 else 0.0,
        "trot_peak_foot_force_N": np.abs(force[trotting, :, 2]).max(0) if trotting.any() else np.zeros(4),
        "trot_mean_foot_depth_m": depth[trotting].mean(0) if trotting.any() else np.zeros(4),
    }
    print("\n" + table(["per-foot sand load", *FOOT_BODIES], [
        [label, *(f"{scale * v:.1f}" for v in summary[key])]
        for label, key, scale in (("standing vertical force (N)", "standing_foot_force_N", 1.0),
                                  ("... whole leg, foot + calf", "standing_leg_force_N", 1.0),
                                  ("standing foot depth (mm)", "standing_foot_depth_m", 1e3),
                                  ("trotting peak force (N)", "trot_peak_foot_force_N", 1.0),
                                  ("trotting mean depth (mm)", "trot_mean_foot_depth_m", 1e3))]))
    print(f"trunk sinkage while standing: {1e3 * summary['standing_trunk_sinkage_m']:.1f} mm; total sand force "
          f"{summary['standing_total_force_N']:.1f} N against the robot's weight {summary['weight_N']:.1f} N; "
          f"trot speed on sand: {summary['trot_speed_mps']:.3f} m/s")
    print(f"speed: {summary['sim_seconds_per_wall_second']:.2f} simulated s per wall s (rendering not counted)")
    print(f"plot: {_plot(log, out, stand_s)}")
    if recorder is not None:
        path = recorder.save(out / "demo_quadruped.mp4")
        print(f"video: {path} ({len(recorder.frames)} frames, rendered in {recorder.seconds:.1f} s)")
    return summary


def view(seconds: float = 60.0, stand_s: float = 1.0, deformable: bool = False) -> None:
    """The demo in the interactive viewer with force arrows (needs a display); ``deformable``: on a
    DeformableSurface, its heightfield updated every step (``viewer.update_hfield``; not run on this project's
    display-less machine)."""
    import mujoco.viewer

    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise SystemExit("the interactive viewer needs a display (DISPLAY is not set); try "
                         "xvfb-run -s '-screen 0 1280x720x24 +extension GLX' python -m rft_mujoco view, "
                         "or the headless 'python -m rft_mujoco demo'")
    demo = Demo(stand_s=stand_s, deformable=deformable)
    with mujoco.viewer.launch_passive(demo.model, demo.data) as viewer:
        with viewer.lock():
            track(viewer.cam, demo.trunk)
        start = time.perf_counter()
        while viewer.is_running() and demo.data.time < seconds:
            demo.step()
            hid = demo.surface_hfield()
            if hid is not None:
                viewer.update_hfield(hid)
            with viewer.lock():
                viewer.user_scn.ngeom = 0
                add_force_arrows(viewer.user_scn, demo.sand, demo.data)
            viewer.sync()
            lag = demo.data.time - (time.perf_counter() - start)
            if lag > 0:
                time.sleep(lag)
    demo.close()


VIEW_HELP = f"""The demo scene of 'python -m rft_mujoco demo' (a quadruped standing, then trotting on sand) in the
interactive mujoco.viewer, in real time, with the sand forces drawn as arrows (1 m per {ARROW_N_PER_M:g} N).
Needs a display (or xvfb-run); saves nothing.
"""


def parser(command: str = "demo") -> argparse.ArgumentParser:
    """The options of ``python -m rft_mujoco demo`` or, with ``command="view"``, of ``... view``."""
    if command not in ("demo", "view"):
        raise ValueError(f"command must be 'demo' or 'view', got {command!r}")
    p = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                description=__doc__ if command == "demo" else VIEW_HELP,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=5.0 if command == "demo" else 60.0,
                   help="simulated time in s")
    p.add_argument("--stand", type=float, default=1.0, help="standing time before trotting, s")
    p.add_argument("--deformable", action="store_true", help="a deformable surface (footprints; about 3x "
                   "slower; docs/deformable.md)")
    if command == "demo":
        p.add_argument("--out", type=Path, default=None,
                       help="folder for the plot and video (default: out/, replaced on every run; a folder given "
                            "here must not hold them already, unless --overwrite)")
        p.add_argument("--overwrite", action="store_true", help="replace the plot and video in --out")
        p.add_argument("--no-video", action="store_true", help="skip the video")
    return p


def main(argv: list[str] | None = None, command: str = "demo") -> int:
    args = parser(command).parse_args(argv)
    if command == "view":
        view(args.seconds, args.stand, args.deformable)
    else:
        out = Path("out") if args.out is None else args.out
        names = ("demo_quadruped.png",) + (() if args.no_video else ("demo_quadruped.mp4",))
        existing = [str(out / n) for n in names if (out / n).exists()]
        if args.out is not None and existing and not args.overwrite:
            parser(command).error(f"--out {out} already holds {', '.join(existing)}: pass --overwrite to replace "
                                  "them, or choose another folder")
        run(args.seconds, args.stand, out, video=not args.no_video, deformable=args.deformable)
    return 0
