"""The first and last steps of an evaluation, shared by the explicit (:mod:`rft_mujoco.compiled.evaluate`) and
the implicit (:mod:`rft_mujoco.compiled.implicit_eval`) solves: the touching groups; each touching body's part of
its group's sand wrench, the diagnostics and the wrenches added into the caller's sum; the status codes.
Nothing here calls MuJoCo.
"""

from __future__ import annotations

import math

from rft_mujoco.compiled.jit import INLINE, JIT, njit
from rft_mujoco.compiled import schema as sc

NOT_FINITE, BAD_ACCELERATION, NOT_FINITE_STATE = (int(sc.Status.NOT_FINITE), int(sc.Status.BAD_ACCELERATION),
                                                  int(sc.Status.NOT_FINITE_STATE))
"""The error statuses (:class:`rft_mujoco.compiled.schema.Status`) as the kernels' ints."""


@njit(**JIT)
def _norm6(x, r):
    """|(x[:3], x[3:] / r)|."""
    return math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
                     + (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]) / (r * r))


@njit(**JIT)
def _clear(force, torque, submerged, max_depth, scale, rft_force, resting, occluded_area):
    """Diagnostics of an evaluation without sand: zero wrenches, counts and depths, scale 1, none resting."""
    force[:] = 0.0
    torque[:] = 0.0
    submerged[:] = 0
    max_depth[:] = 0.0
    scale[:] = 1.0
    rft_force[:] = 0.0
    resting[:] = False
    occluded_area[:] = 0.0


@njit(**INLINE)
def touching_groups(k, touch, group_of, ng_all, mark, active, slot):
    """The groups of the touching bodies ``touch[:k]``, in increasing group order, into ``active``; each
    touching body's row among them into ``slot``; ``mark`` (ng_all,) bool: whether a group touches.
    Returns their number. Shared by the explicit and the implicit evaluations."""
    for g in range(ng_all):
        mark[g] = False
    for j in range(k):
        mark[group_of[touch[j]]] = True
    ng = 0
    for g in range(ng_all):
        if mark[g]:
            active[ng] = g
            ng += 1
    for j in range(k):
        gj = group_of[touch[j]]
        for r in range(ng):
            if active[r] == gj:
                slot[j] = r
    return ng


@njit(**INLINE)
def _share_and_commit(k, ng, groups, hc, ws, sand_out):
    """Each touching body's part of its group's sand wrench (``applied``: a flowing group's law wrench scaled
    per body, a resting group's wrench shared by size), the diagnostics into ``ws`` and the wrenches added to
    ``sand_out``; returns the evaluation's status. Shared by the explicit and the implicit evaluations.
    ``groups`` = (``rad_g`` (ng,) m, ``rft_g`` (ng, 6) the groups' law wrenches, ``w`` (ng, 6) their sand
    wrenches (N, N m), ``rest`` (ng,) bool); the bodies' rows are the workspace's (``ws``: ``W_SLOT``,
    ``W_WRENCH``, ``W_ARM``, ``W_SIZE``, ``W_CAP``, ``W_APPLIED``, ``W_TOUCH``, ``W_COUNT``, ``W_DEPTH``,
    ``W_OCCLUDED``), the bodies' radii and ids the handle's (``hc``)."""
    rad_g, rft_g, w, rest = groups
    slot, wrench, arm, size, cap = ws[sc.W_SLOT], ws[sc.W_WRENCH], ws[sc.W_ARM], ws[sc.W_SIZE], ws[sc.W_CAP]
    applied, touch, count, depth_max = ws[sc.W_APPLIED], ws[sc.W_TOUCH], ws[sc.W_COUNT], ws[sc.W_DEPTH]
    occluded, bound_radius, ids = ws[sc.W_OCCLUDED], hc[sc.H_BOUND_RADIUS], hc[sc.H_IDS]
    # 7. each body's part (coupling._share)
    for j in range(k):
        size[j] = _norm6(wrench[j], rad_g[slot[j]])
    for r in range(ng):
        cap[r, 0] = 0.0                             # reuses ``cap`` column 0 as the groups' total size
    for j in range(k):
        cap[slot[j], 0] += size[j]
    for j in range(k):
        r = slot[j]
        for c in range(6):
            applied[j, c] = 0.0
        if cap[r, 0] <= 0.0:
            continue
        if not rest[r]:
            gn = _norm6(rft_g[r], rad_g[r])
            f = _norm6(w[r], rad_g[r]) / gn if gn > 0.0 else 0.0
            for c in range(6):
                applied[j, c] = wrench[j, c] * f
        else:
            share = size[j] / cap[r, 0]
            for c in range(3):
                applied[j, c] = share * w[r, c]
    for r in range(ng):
        if not rest[r] or cap[r, 0] <= 0.0:
            continue
        mx, my, mz = w[r, 3], w[r, 4], w[r, 5]
        for j in range(k):
            if slot[j] == r:
                ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
                fx, fy, fz = applied[j, 0], applied[j, 1], applied[j, 2]
                mx -= ay * fz - az * fy
                my -= az * fx - ax * fz
                mz -= ax * fy - ay * fx
        for j in range(k):
            if slot[j] == r:
                share = size[j] / cap[r, 0]
                applied[j, 3] = share * mx
                applied[j, 4] = share * my
                applied[j, 5] = share * mz
    # 8. diagnostics and the wrenches into sand_out (SandHandle._commit)
    force, torque, submerged, max_depth = ws[sc.W_FORCE], ws[sc.W_TORQUE], ws[sc.W_SUBMERGED], ws[sc.W_MAX_DEPTH]
    scale, rft_force = ws[sc.W_SCALE], ws[sc.W_RFT_FORCE]
    resting, occluded_area = ws[sc.W_RESTING], ws[sc.W_OCCLUDED_AREA]
    _clear(force, torque, submerged, max_depth, scale, rft_force, resting, occluded_area)
    status = 0
    for j in range(k):
        i = touch[j]
        rb = bound_radius[i]
        rn = _norm6(wrench[j], rb)
        for c in range(3):
            force[i, c] = applied[j, c]
            torque[i, c] = applied[j, 3 + c]
            rft_force[i, c] = wrench[j, c]
        submerged[i] = count[j]
        max_depth[i] = depth_max[j]
        occluded_area[i] = occluded[j]
        if rn > 0.0:
            scale[i] = _norm6(applied[j], rb) / rn
            resting[i] = rest[slot[j]]
        for c in range(6):
            x = applied[j, c]
            if not math.isfinite(x):
                status = NOT_FINITE
            elif x != 0.0 and status == 0:
                status = 1
    if status == NOT_FINITE:
        return NOT_FINITE
    for j in range(k):
        row = ids[touch[j]]
        for c in range(6):
            sand_out[row, c] += applied[j, c]
    return status


@njit(**INLINE)
def body_arms(k, slot, groups, body_com, xipos, arm):
    """``arm`` (k, 3) m: each touching body's COM (``body_com`` rows) from its group's reference point (the COM of
    body ``ids[group_ref[active[slot[j]]]]``; ``groups`` = (``active``, ``ids``, ``group_ref``))."""
    active, ids, group_ref = groups
    for j in range(k):
        b_ref = ids[group_ref[active[slot[j]]]]
        for c in range(3):
            arm[j, c] = body_com[j, c] - xipos[b_ref, c]


@njit(**INLINE)
def group_twists(u, groups_on, k, slot, arm, lin, ang, on):
    """Each body's twist at its COM from its group's ``u`` (ng, 6) at the reference point: ``lin``, ``ang``
    (k, 3) m/s, rad/s; ``on`` (k,): whether its group is on (``groups_on`` (ng,) bool; both None: every group,
    nothing recorded)."""
    for j in range(k):
        g = slot[j]
        if on is not None:
            on[j] = groups_on[g]
        wx, wy, wz = u[g, 3], u[g, 4], u[g, 5]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
        lin[j, 0] = u[g, 0] + (wy * az - wz * ay)
        lin[j, 1] = u[g, 1] + (wz * ax - wx * az)
        lin[j, 2] = u[g, 2] + (wx * ay - wy * ax)
        ang[j, 0] = wx
        ang[j, 1] = wy
        ang[j, 2] = wz


@njit(**INLINE)
def group_sums(ng, groups_on, k, slot, arm, on, wrench, f):
    """``f`` (ng, 6): the groups' wrenches about their reference points (N, N m) from their bodies' rows of
    ``wrench`` (about each COM, at ``arm`` from the reference point), for the groups with ``groups_on`` and the
    bodies with ``on`` (both None: all; the explicit evaluation's use)."""
    for g in range(ng):
        if groups_on is not None:
            if not groups_on[g]:
                continue
        for a in range(6):
            f[g, a] = 0.0
    for j in range(k):
        if on is not None:
            if not on[j]:
                continue
        g = slot[j]
        ax, ay, az = arm[j, 0], arm[j, 1], arm[j, 2]
        fx, fy, fz = wrench[j, 0], wrench[j, 1], wrench[j, 2]
        f[g, 0] += fx                             # S^T w = (f, tau + arm x f)
        f[g, 1] += fy
        f[g, 2] += fz
        f[g, 3] += wrench[j, 3] + (ay * fz - az * fy)
        f[g, 4] += wrench[j, 4] + (az * fx - ax * fz)
        f[g, 5] += wrench[j, 5] + (ax * fy - ay * fx)


@njit(**JIT)
def take_out_rows(xfrc, rows, force, torque, saved):
    """Rows ``rows`` of ``xfrc`` (nbody, 6: MjData's ``xfrc_applied``) into ``saved`` (B, 6), then less ``force``
    (B, 3) N and ``torque`` (B, 3) N m: a handle's sand wrench taken out for one MuJoCo call
    (:meth:`rft_mujoco.envs.SandBed.post_constraint`); :func:`put_back_rows` restores them bit for bit."""
    for i in range(rows.shape[0]):
        b = rows[i]
        for c in range(3):
            saved[i, c] = xfrc[b, c]
            saved[i, 3 + c] = xfrc[b, 3 + c]
            xfrc[b, c] -= force[i, c]
            xfrc[b, 3 + c] -= torque[i, c]


@njit(**JIT)
def put_back_rows(xfrc, rows, saved):
    """Rows ``rows`` of ``xfrc`` as :func:`take_out_rows` saved them."""
    for i in range(rows.shape[0]):
        for c in range(6):
            xfrc[rows[i], c] = saved[i, c]
