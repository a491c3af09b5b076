"""The dispatcher's per-MjData book of what the sand wrote into ``xfrc_applied``, and how a user's writes are
told from it (:mod:`rft_mujoco.coupling.dispatch` owns the books; the native route reads and writes them
through :data:`rft_mujoco.compiled.route.BOOK_FIELDS`)."""

from __future__ import annotations

import weakref

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled import schema as sc

RK4_STAGE_TIMES = (0.5, 0.5, 1.0)
"""Times of RK4 stages 2-4 after the first, in steps (mj_RungeKutta evaluates at t + dt/2, t + dt/2, t + dt)."""
RK4_STAGES = {"all": 4, "midpoint": 2, "first": 1}
"""Values of ``attach(rk4_stages=...)`` and the leading RK4 stages at which each evaluates the sand (the wrench of
the last one is held through the rest of the step)."""


def untouched_components(xfrc: np.ndarray, written: np.ndarray) -> np.ndarray:
    """(n, 6) bool: which components of ``xfrc`` rows (n, 6) the user left as the dispatcher ``written`` them.

    A row equal to what was written is untouched. In a row the user changed, a component still equal to
    what was written counts as untouched only when that value is non-zero: a user who writes one component
    (``xfrc_applied[b, 0] = push``) leaves the others, holding user + sand, alone; a user who zeroes or
    reassigns the row rewrites every component, and a written 0 (the sand exactly cancelling the user's
    previous value, as at rest) is then taken as the user's new 0. Only a user who writes exactly the
    non-zero value the dispatcher wrote, or leaves alone a component that the sand exactly cancels while
    changing others, is misread; values are all the dispatcher can see.
    """
    same = xfrc == written
    return same & (same.all(axis=1, keepdims=True) | (written != 0.0))


class _DataBook:
    """Per-MjData record of what the sand added to ``xfrc_applied`` (rows of all bodies)."""

    __slots__ = ("added", "written", "rows", "model", "sand", "user", "state", "native", "snapshot", "__weakref__")

    def __init__(self, model, data) -> None:
        nbody = model.nbody
        self.model = weakref.ref(model)
        self.added = np.zeros((nbody, 6))
        self.written = np.zeros((nbody, 6))
        self.rows = np.zeros(0, dtype=np.int64)
        self.sand = np.zeros((nbody, 6))     # the handles' sum of this evaluation (reused buffer)
        self.user = np.zeros((nbody, 6))      # the user's part of xfrc_applied (reused buffer)
        # rft_mujoco.compiled.schema.BOOK_STATE: read and written by the native route too
        self.state = np.zeros(len(sc.BOOK_STATE))
        self.state[sc.B_TIME_RTOL] = tol.TIME_RTOL
        self.native = None                    # (generation, Route) of this MjData's native route
        # the model's timestep, gravity and geom sizes as the handles last checked them (None: not yet);
        # the native route hands an evaluation to Python when they differ (compiled.route.model_changed)
        self.snapshot = None

    def user_part(self, xfrc: np.ndarray) -> np.ndarray:
        """(nbody, 6) the user's own part of ``xfrc`` (the data's ``xfrc_applied``: the sand's part removed)."""
        user = xfrc.copy()
        if self.rows.size:
            rows = self.rows
            user[rows] -= np.where(untouched_components(xfrc[rows], self.written[rows]), self.added[rows], 0.0)
        return user

    @property
    def nonzero(self) -> bool:
        return bool(self.state[sc.B_NONZERO])

    @nonzero.setter
    def nonzero(self, value: bool) -> None:
        self.state[sc.B_NONZERO] = float(value)

    @property
    def pending(self) -> int:
        """What the native callback left to the Python path in this evaluation (:data:`rft_mujoco.compiled.route.
        MONITOR` or ``PYTHON``; 0: nothing)."""
        return int(self.state[sc.B_PENDING])

    @pending.setter
    def pending(self, value: int) -> None:
        self.state[sc.B_PENDING] = float(value)

    @property
    def stage(self) -> int:
        """With integrator="RK4": the stage of the last evaluation (1-4; 0: another integrator)."""
        return int(self.state[sc.B_RK4_STAGE])

    @stage.setter
    def stage(self, value: int) -> None:
        self.state[sc.B_RK4_STAGE] = float(value)

    @property
    def stage_time(self) -> float:
        """The time of the first stage of the step (s)."""
        return float(self.state[sc.B_RK4_STAGE_TIME])

    @stage_time.setter
    def stage_time(self, value: float) -> None:
        self.state[sc.B_RK4_STAGE_TIME] = float(value)

    @property
    def sand_dirty(self) -> bool:
        return bool(self.state[sc.B_SAND_DIRTY])

    @sand_dirty.setter
    def sand_dirty(self, value: bool) -> None:
        self.state[sc.B_SAND_DIRTY] = float(value)

    def later_rk4_stage(self, t: float, dt: float) -> bool:
        """Whether an evaluation at time ``t`` is stage 2, 3 or 4 of the RK4 step whose first stage the
        book saw last (mj_RungeKutta evaluates at t0 + dt/2, t0 + dt/2, t0 + dt after mj_forward at t0);
        otherwise it is a first stage (mj_step's mj_forward, or any mj_forward) and is recorded as one."""
        n = self.stage
        if 1 <= n <= 3 and abs(t - (self.stage_time + RK4_STAGE_TIMES[n - 1] * dt)) <= tol.TIME_RTOL * dt:
            self.stage = n + 1
            return True
        self.stage_time = t
        self.stage = 1
        return False
