"""The implicit sand solve (``attach(solve="implicit")``): backward Euler on the regularized law, the resting
groups held inside it (pure numpy, no MuJoCo; docs/rest.md, "The implicit solve").

The explicit design's pieces it shares (capacity test, rest operator, passivity guard) are in
:mod:`rft_mujoco.physics.rest`.
"""

from __future__ import annotations

import numpy as np

from rft_mujoco import tol
from rft_mujoco.physics.rest import (CAPACITY_TOL, DEPENDENT_TOL, WEIGHT_FLOOR, _scales, blend, passive_scale,
                                     pivoted_apply, pivoted_factor, twist_speed)

SPEED_SCALE = 1e-4
"""m/s: the regularization speed ``c`` of the implicit solve's law (each element's stress times
``|v| / sqrt(|v|^2 + c^2)``, :func:`rft_mujoco.physics.elements.body_wrench_jacobians`): the published force
to within 0.5% above 10 c = 1 mm/s. Rest is not regularized: a group the sand can hold is held exactly. 0.1 mm/s
(1 mm/s before 2026-12-04): slow strokes (a small swimmer's, 1-3 mm/s) get the published force (docs/rest.md,
"Any mass")."""

REST_RETRY = 10.0
"""A group that starts an evaluation in flow (it flowed at the last one) is tried at rest when the flow solve
ends its step slower than this many :data:`SPEED_SCALE` (twist speed): the capacity test then decides."""

NEWTON_ITERATIONS = 40
"""The most Newton iterations of one implicit flow solve."""

ZONE_PASSES = 4
"""The most implicit solves in one evaluation. The constraint rows that reach the sand are linearized in a
zone each (quadratic, a saturated dry friction, inactive: :func:`rft_mujoco.coupling.reference.constraint_zones`),
first at the accelerations of MuJoCo's last solve, then again at the end accelerations of this step's solve
while any row changes zone (a dry friction that the sand's wrench saturates or releases, a limit or a contact
that it loads or unloads): without it a friction held in the linear model beyond its bound lets the sand
hold a body that MuJoCo's own solve then moves."""

NEWTON_RTOL = 1e-3
"""The implicit flow solve stops when the residual of the end-of-step twists is within this fraction of the twist
change the step makes (twist speeds) *and*, through the law's slope where the last Newton step started, moves the
flowing groups' wrenches by less than this fraction of the largest (:func:`wrench_change`: forces, and torques
over the group's radius); or when the residual is below ``SPEED_SCALE * NEWTON_RTOL`` (m/s). Both: the velocity
test alone leaves forces off by its tolerance times the law's slope, which near slow motion grows as
``1 / SPEED_SCALE``; the force test alone, with the slope of the last step's start, stops on iterates where that
slope is wrong (zero where a body moves out of the sand; docs/rest.md, "Any mass")."""


def rest_operator(block: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(m, m) the linear map ``rhs -> x`` of :func:`rft_mujoco.physics.rest.pivoted_solve` on ``block`` (its columns: the solves of
    the unit vectors): the minimum-norm rest wrenches for given twists to cancel."""
    factor = pivoted_factor(block, weight, DEPENDENT_TOL, tol.TINY)
    eye = np.eye(block.shape[0])
    return np.stack([pivoted_apply(block, eye[i], *factor) for i in range(block.shape[0])], axis=1)


def implicit_wrenches(free_twist: np.ndarray, mobility: np.ndarray, law, twist: np.ndarray, radius: np.ndarray,
                      dt: float, flowing: np.ndarray | None = None,
                      start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Sand wrenches of G touching groups, backward Euler on the law: a flowing group gets the law's wrench at
    the twist the step ends with, a group the sand can hold rests, solved together through the mobility.

    The end-of-step twists are ``u = Vf + dt A W``. A resting group has ``u = 0`` and its wrench is the
    capacity-weighted minimum-norm one (as :func:`rft_mujoco.physics.rest.rest_wrenches`); it rests while that wrench passes the
    capacity test of :func:`~rft_mujoco.physics.rest.rest_wrenches` along the direction it would start to move (:func:`blend`). A
    flowing group has ``W = F(u)``, the regularized law at its own end-of-step twist, for every direction at
    once (a body that sinks and slides keeps its drag), solved by Newton's method with the law's derivative,
    the resting groups held (their wrenches follow the flowing ones linearly). For a light body ``dt A`` is
    large and ``u`` tends to the quasi-static balance ``F(u) + load = 0``: the answer does not depend on the
    mass. A group the flow solve slows below the regularization speed has its published force scaled by at
    most ``phi``; the sand never adds energy (:func:`passive_scale` as a final guard).

    Args:
        free_twist: (G, 6) twists at the end of the step without sand (m/s, rad/s).
        mobility: (6G, 6G) ``J M^-1 J^T`` of the groups' reference points.
        law: ``law(u (G, 6), groups (G,) bool) -> (F (G, 6), dF/du (G, 6, 6))``: the regularized law's wrench
            (N, N m) at twists ``u`` and its derivative, for the groups flagged (others may be zero).
        twist: (G, 6) the twists now; radius: (G,) m; dt: s.
        flowing: (G,) bool, groups to start in flow (those that flowed at the last evaluation: a swimmer's
            links flow at every step, and trying them at rest first costs a second Newton solve); None: all
            start at rest. The answer is the same either way while the capacity test agrees.
        start: (G, 6) twists a flowing group's Newton solve starts from (m/s, rad/s; an earlier zone pass's
            answer); None: the twists now.
    Returns:
        wrenches (G, 6) (N, N m), resting (G,) bool, end twists (G, 6) that the wrenches give (m/s, rad/s),
        Newton iterations used.
    """
    vf = np.asarray(free_twist, dtype=float)
    n = vf.shape[0]
    sv, sw = _scales(radius)
    a = dt * (sv.reshape(-1)[:, None] * np.asarray(mobility, dtype=float) * sv.reshape(-1)[None, :])
    v = (vf * sv).reshape(-1)
    probe = blend(twist, vf, radius)
    f0, _ = law(probe, np.ones(n, dtype=bool))
    cap = f0 * sw
    u_probe = probe * sv
    capacity = -np.einsum("ij,ij->i", cap, u_probe)
    rest = np.any(cap != 0.0, axis=1)
    flow = np.zeros(n, dtype=bool)
    if flowing is not None:
        flow = rest & np.asarray(flowing, dtype=bool)
        rest &= ~flow
    untried = flow.copy()                    # started in flow: tried at rest once they are slow (see below)
    weight_all = np.einsum("ij,ij->i", cap, cap)
    u_flow = None
    base = np.asarray(twist if start is None else start, dtype=float)
    iterations = 0
    while True:
        r_idx = np.flatnonzero(np.repeat(rest, 6))
        f_idx = np.flatnonzero(np.repeat(flow, 6))
        if r_idx.size:
            weight = np.repeat(weight_all, 6)[r_idx]
            weight = np.maximum(weight, WEIGHT_FLOOR * weight.max())
            p = rest_operator(a[np.ix_(r_idx, r_idx)], weight)
        else:
            p = np.zeros((0, 0))
        w = np.zeros(6 * n)
        if f_idx.size:
            a_fr = a[np.ix_(f_idx, r_idx)]
            a_eff = a[np.ix_(f_idx, f_idx)] - a_fr @ p @ a[np.ix_(r_idx, f_idx)]
            v_eff = v[f_idx] - a_fr @ p @ v[r_idx]
            u0 = (base * sv).reshape(-1)[f_idx] if u_flow is None else u_flow
            u_flow, w_f, its = _newton_flow(law, flow, a_eff, v_eff, u0, sv, sw, n)
            iterations += its
            w[f_idx] = w_f
            end_f = np.zeros((n, 6))
            end_f[flow] = u_flow.reshape(-1, 6) / sv[flow]
            slow = untried & flow & (twist_speed(end_f, radius) < REST_RETRY * SPEED_SCALE)
            if slow.any():                   # a group started in flow that the step brings to (near) rest
                untried &= ~slow
                flow &= ~slow
                rest |= slow
                u_flow = None
                continue
        if r_idx.size:
            w[r_idx] = -p @ (v[r_idx] + a[np.ix_(r_idx, f_idx)] @ w[f_idx])
            wr = w.reshape(n, 6)
            demand = -np.einsum("ij,ij->i", wr, u_probe)
            over = rest & (demand > np.maximum(capacity, 0.0) * (1.0 + CAPACITY_TOL))
            if over.any():
                u_flow = None                   # the flowing set changed: start again from the twists now
                rest &= ~over
                flow |= over
                continue
        break
    w *= passive_scale(w, v, a)
    end = (v + a @ w).reshape(n, 6) / sv
    return w.reshape(n, 6) / sw, rest, end, iterations


def wrench_change(blocks: np.ndarray, du: np.ndarray, wf: np.ndarray) -> float:
    """The flowing groups' wrench change that twists ``du`` make, as a fraction of the largest wrench:
    ``max |J du| / max |wf|`` with ``blocks`` (k, 6, 6) the law's scaled derivative blocks, ``du`` (6 k,)
    scaled twists (m/s, and rad/s times the radius), ``wf`` (6 k,) scaled wrenches (N, and N m over the
    radius); inf when every wrench is zero. The Newton solve's stopping test with its residual as ``du``."""
    top = float(np.abs(wf).max(initial=0.0))
    change = float(np.abs(np.einsum("kab,kb->ka", blocks, du.reshape(-1, 6))).max(initial=0.0))
    return change / top if top > 0.0 else np.inf


def _newton_flow(law, flow, a_eff, v_eff, start, sv, sw, n):
    """Newton's method on ``u - v_eff - a_eff F(u) = 0`` for the flowing groups (scaled coordinates)."""
    groups = np.flatnonzero(flow)
    k = groups.size

    def evaluate(u):
        full = np.zeros((n, 6))
        full[groups] = u.reshape(k, 6) / sv[groups]
        f, df = law(full, flow)
        wf = (f[groups] * sw[groups]).reshape(-1)
        jac = np.zeros((6 * k, 6 * k))
        for i, g in enumerate(groups):
            jac[6 * i:6 * i + 6, 6 * i:6 * i + 6] = sw[g][:, None] * df[g] / sv[g][None, :]
        return wf, jac

    u = np.array(start, dtype=float)
    wf, jac = evaluate(u)
    res = u - v_eff - a_eff @ wf
    scale = max(float(np.abs(v_eff - u).max()), SPEED_SCALE) * NEWTON_RTOL
    its, blocks = 0, None
    for its in range(1, NEWTON_ITERATIONS + 1):
        top = float(np.abs(res).max())
        if top <= SPEED_SCALE * NEWTON_RTOL or (
                top <= scale and blocks is not None and wrench_change(blocks, res, wf) <= NEWTON_RTOL):
            break                              # blocks: the law's slope where the last step started
        blocks = jac.reshape(k, 6, k, 6)[np.arange(k), :, np.arange(k)]
        step = np.linalg.solve(np.eye(6 * k) - a_eff @ jac, -res)
        t, best = 1.0, None
        norm0 = float(res @ res)
        while t > 1e-3:
            u_try = u + t * step
            wf_try, jac_try = evaluate(u_try)
            res_try = u_try - v_eff - a_eff @ wf_try
            if float(res_try @ res_try) < norm0:
                best = (u_try, wf_try, jac_try, res_try)
                break
            t *= 0.5
        if best is None:
            best = (u_try, wf_try, jac_try, res_try)
        u, wf, jac, res = best
    return u, wf, its
