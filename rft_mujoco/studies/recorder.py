"""The sand's generalized force at every evaluation, recorded through the public observer
(:meth:`rft_mujoco.coupling.handle.SandHandle.observe`): what the studies measure the sand's work with."""

from __future__ import annotations

import mujoco
import numpy as np


class StageRecorder:
    """The generalized force (nv,) of a handle's sand at every evaluation (integrator stage) since the last
    :meth:`clear`, all its bodies together, on every path (the native route included).

    ``q``: the forces of the current step's evaluations; ``evaluations``: how many were observed in all
    (a study that observed none measured nothing and must say so: :meth:`require`)."""

    def __init__(self, handle, model) -> None:
        self.q: list = []
        self.evaluations = 0
        self._model = model
        self._ids = handle.body_ids
        self._handle = handle
        handle.observe(self)

    def __call__(self, data, wrenches, stage) -> None:
        q = np.zeros(self._model.nv)
        for b, w in zip(self._ids, wrenches):
            if np.any(w != 0.0):
                mujoco.mj_applyFT(self._model, data, w[:3].copy(), w[3:].copy(), data.xipos[b].copy(), int(b), q)
        self.q.append(q)
        self.evaluations += 1

    def clear(self) -> None:
        self.q.clear()

    def close(self) -> None:
        self._handle.unobserve(self)

    def step_gain(self, model, data, dt: float, weights: np.ndarray) -> tuple[float, float] | None:
        """(dE J, dE relative to the step's energy exchange) that the sand's impulse of the last step adds to
        the kinetic energy at the step's end velocity, or None when the sand did nothing this step.

        The impulse ``j = dt sum_s w_s q_s`` (RK4's stage weights; one stage otherwise) changes the kinetic
        energy by ``j.qvel - j.M^-1.j / 2`` measured at the velocity after it. With RK4 and fewer than four
        evaluations (``attach(rk4_stages="midpoint" or "first")``) the last one's force stands for the stages
        that held it."""
        if not self.q:
            return None
        q = self.q
        if len(weights) == 4 and len(q) < 4:
            q = [q[min(s, len(q) - 1)] for s in range(4)]
        w = weights if len(q) == len(weights) else np.ones(len(q)) / len(q)
        jimp = dt * np.einsum("s,sn->n", w, np.array(q))
        if not np.any(jimp != 0.0):
            return None
        minv_j = np.zeros(model.nv)
        mujoco.mj_solveM(model, data, minv_j.reshape(1, -1), jimp.reshape(1, -1))
        power = float(jimp @ data.qvel)
        quad = 0.5 * float(jimp @ minv_j)
        return power - quad, (power - quad) / (abs(power) + quad)
