"""The stability study's matrix (shapes, masses, timesteps, integrators, heights, media), its criteria and its
case and result records: one place, shared by the study (:mod:`rft_mujoco.studies.stability`) and its plots
(:mod:`rft_mujoco.studies.stability_plots`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# --- the matrix: one place ---------------------------------------------------------------------------
SHAPES = {
    # name: (geom attributes, height of the lowest point below the body origin in m)
    "sphere": ("type='sphere' size='0.05'", 0.05),
    "box": ("type='box' size='0.05 0.04 0.03'", 0.03),
    "capsule": ("type='capsule' size='0.02 0.03' euler='0.3 0 0'", 0.03 * math.cos(0.3) + 0.02),
}
MASSES = (0.01, 0.1, 1.0, 10.0, 100.0)
TIMESTEPS = (0.00025, 0.001, 0.002, 0.005, 0.01)
INTEGRATORS = ("Euler", "implicitfast", "RK4")
HEIGHTS = (0.0, 0.03, 0.1, 0.3)
DEFAULT_HEIGHT = 0.1
DEFAULT_MEDIA = "mpm_validation"
RESOLUTION = 0.01
"""Element size in m for every case."""
DURATION = 2.5
"""Simulated seconds of a drop."""
REST_SPEED = 1e-3
"""m/s: at rest below this."""
REST_DEADLINE = 2.0
"""s: a drop with dt <= REST_DT_MAX must be at rest by then."""
REST_DT_MAX = 0.005
TAIL = 0.5
"""s: the window for jitter and creep at the end of a run."""
GAIN_RTOL = 1e-9
"""Energy the sand adds in a step beyond this fraction of the step's energy exchange is a failure."""
SETTLE, LOAD, RELEASE = 0.5, 1.0, 1.5
"""Drag and rotate: seconds to settle (dropped from 0 m), under the load, and after releasing it."""
DRAG_LOADS = (0.1, 1.0)
"""Horizontal pull force in units of the body's weight."""
ROTATE_LOADS = (0.01, 0.2)
"""Torque about the vertical in units of weight x 0.1 m."""
RK4_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
FLOW_FACTOR = 10.0
"""Drag and rotate: steps whose slowest loaded element moves faster than FLOW_FACTOR v_reg are flow."""


@dataclasses.dataclass(frozen=True)
class Case:
    """One run: ``kind`` is "drop", "drag" or "rotate"; ``load`` the drag/rotate load factor."""

    kind: str
    shape: str
    mass: float
    dt: float
    integrator: str
    height: float = DEFAULT_HEIGHT
    media: str = DEFAULT_MEDIA
    stabilize: bool = True
    load: float = 0.0
    group: str = "matrix"

    @property
    def label(self) -> str:
        extra = f" load={self.load:g}" if self.kind != "drop" else f" h={self.height:g}"
        return (f"{self.kind:6s} {self.shape:7s} m={self.mass:<6g} dt={self.dt * 1e3:<5g}ms "
                f"{self.integrator:12s} {self.media:20s}{extra}{'' if self.stabilize else ' NAIVE'}")


@dataclasses.dataclass
class Result:
    case: Case
    nan: bool = False
    observed: int = 0                    # sand evaluations the energy recorder saw (0: nothing measured)
    max_gain: float = -math.inf          # J, largest dE of a step
    max_gain_rel: float = -math.inf      # dE / (|J.v+| + 0.5 J M^-1 J)
    t_rest: float = math.inf             # s
    jitter: float = math.nan             # m/s
    creep: float = math.nan              # m/s
    sinkage: float = math.nan            # m
    static_depth: float = math.nan       # m
    force_err_flow: float = math.nan     # median |F - F_pub| / |F_pub| under load, speed > FLOW_FACTOR v_reg
    force_err_moving: float = math.nan   # the same over all steps under load with speed >= REST_SPEED
    held: bool = False                   # drag/rotate: at rest at the end of the load phase
    i_mac: float = math.nan
    i_micro: float = math.nan
    depth_ratio: float = math.nan
    validity_warnings: int = 0
    steps: int = 0
    wall: float = 0.0
    failures: tuple = ()

    @property
    def sinkage_ratio(self) -> float:
        return self.sinkage / self.static_depth if self.static_depth > 0 else math.nan
