"""The implicit solve's evaluation of one handle on one MjData, compiled: what
:func:`rft_mujoco.coupling.reference.evaluate_implicit` computes (tests/test_compiled_implicit.py compares them).

Run after :func:`rft_mujoco.compiled.evaluate.broadphase` and ``mj_fwdActuation``, as the explicit
treatment's :func:`~rft_mujoco.compiled.evaluate.evaluate`: from Python
(:func:`rft_mujoco.coupling.implicit.evaluate_compiled`) or from the native route's C function
(:func:`rft_mujoco.compiled.implicit_route.implicit_phase`). Arguments: the ``md``, ``hc`` and ``ws`` tuples of
:mod:`rft_mujoco.compiled.evaluate`, the implicit solve's own buffers ``iw`` (:data:`IMPLICIT_FIELDS`,
:func:`build_implicit`), this step's constraint rows ``efc`` (:data:`EFC_FIELDS`), MuJoCo's sparse mass matrix
``m_val`` (``data.M``), the dofs' implicit damping (:func:`rft_mujoco.coupling.reference.velocity_damping`) and
the solve's settings ``st`` (:data:`rft_mujoco.compiled.implicit.SETTINGS`).
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.compiled.evaluate import _gravity
from rft_mujoco.compiled.share import (BAD_ACCELERATION, NOT_FINITE, _share_and_commit, body_arms, group_sums,
                                       group_twists, touching_groups)
from rft_mujoco.compiled.element_pass import law_of, occluders_of, surface_of, terrain_of, wrenches
from rft_mujoco.compiled.implicit import NEED_ELEMENTS, arena_sizes, solve_from_probe, solve_work
from rft_mujoco.compiled.implicit_law import LAW, SCRATCH_ROWS, group_law, loaded_candidates
from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.rest import add_user_wrenches, blend
from rft_mujoco.compiled.system import cholesky, constrained_system, end_acceleration, free_motion, row_zones

IMPLICIT_FIELDS = (("e_slot", "i1"), ("e_arm", "f2"), ("e_nrm", "f2"), ("e_depth", "f1"), ("e_area", "f1"),
                   ("jac", "f3"), ("lin", "f2"), ("ang", "f2"), ("on", "b1"), ("jrows", "f2"), ("h", "f2"),
                   ("f", "f1"), ("y", "f2"), ("end", "f2"), ("probe", "f2"), ("gf", "f2"), ("gdf", "f3"),
                   ("flowing", "b1"), ("prev_active", "b1"), ("prev_flow", "b1"), ("istate", "f1"), ("scr", "f2"),
                   ("pk", "i1"), ("mob", "f1"), ("start", "f2"), ("qacc_end", "f1"), ("sf", "f1"), ("si", "i1"),
                   ("sb", "b1"))
"""(name, kind) of the ``iw`` buffers: the evaluation's elements (:func:`rft_mujoco.compiled.implicit_law.
loaded_candidates`), the law's work space, the free motion's (``jrows`` J, ``h`` H and its factor, ``f``, ``y``),
the solve's outputs, the groups that touched and flowed at the last evaluation (``prev_*``: the
numpy reference's ``work.flowing``), ``istate`` ([whether ``prev_*`` hold an evaluation]), the groups' mobility
(flat, (6 G)^2), the Newton solves' start twists, the end accelerations and the solve's arenas
(:data:`rft_mujoco.compiled.implicit.SOLVE_WORK`)."""
EFC_FIELDS = ("efc_J", "efc_J_rowadr", "efc_J_rownnz", "efc_J_colind", "efc_type", "efc_id", "efc_D", "efc_aref",
              "efc_frictionloss", "qacc")
"""MjData's constraint rows of this step (in its arena: read at every call) and its last ``qacc``."""
SYSTEM = ("efc", "sparse", "m_val", "damping", "linearized")
"""The ``system`` bundle of :func:`evaluate_implicit`: MuJoCo's system of this step. ``efc``: its constraint rows
(:data:`EFC_FIELDS`); ``sparse``: its constraint Jacobian is sparse; ``m_val``: its sparse mass matrix
(``data.M``); ``damping``: the dofs' implicit damping (:func:`rft_mujoco.compiled.system.velocity_damping`);
``linearized``: the solve takes this step's constraints (:func:`rft_mujoco.compiled.system.constrained_system`),
else MuJoCo's previous constraint forces (when they belong to this motion)."""


def build_implicit(n_elements: int, n_bodies: int, n_groups: int, nv: int) -> dict:
    """Zeroed ``iw`` arrays (:data:`IMPLICIT_FIELDS`) for E packed element slots, B bodies, G groups, nv dofs."""
    e, b, g, n6, nv1 = max(n_elements, 1), n_bodies, n_groups, 6 * n_groups, max(nv, 1)
    nf, ni, nb = arena_sizes(g)
    shapes = dict(e_slot=(e,), e_arm=(e, 3), e_nrm=(e, 3), e_depth=(e,), e_area=(e,), jac=(b, 6, 6), lin=(b, 3),
                  ang=(b, 3), on=(b,), jrows=(n6, nv), h=(nv1, nv1), f=(nv,), y=(n6, nv), end=(g, 6), probe=(g, 6),
                  gf=(g, 6), gdf=(g, 6, 6), flowing=(g,), prev_active=(g,), prev_flow=(g,), istate=(1,),
                  scr=(SCRATCH_ROWS, e), pk=(e + 1,), mob=(n6 * n6,), start=(g, 6), qacc_end=(nv,), sf=(nf,), si=(ni,),
                  sb=(nb,))
    dtype = {"i": np.int64, "f": np.float64, "b": np.bool_}
    return {name: np.zeros(shapes[name], dtype=dtype[kind[0]]) for name, kind in IMPLICIT_FIELDS}


def efc_arrays(data) -> tuple:
    """The ``efc`` tuple (:data:`EFC_FIELDS`) of ``data`` now."""
    return tuple(getattr(data, name) for name in EFC_FIELDS)


@njit(**JIT)
def _elements(md, hc, ws, k, g_hat, e_slot, e_arm, e_nrm, e_depth, e_area):
    """:func:`rft_mujoco.compiled.implicit_law.loaded_candidates` of the ``k`` touching bodies into the element
    rows ``e_*`` (and the bodies' occluded area into ``ws``); returns their number."""
    return loaded_candidates(ws[sc.W_TOUCH], k, surface_of(hc),
                             (ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT], ws[sc.W_BODY_COM]), terrain_of(hc, g_hat),
                             occluders_of(hc, md),
                             (e_slot, e_arm, e_nrm, e_depth, e_area, ws[sc.W_OCCLUDED]))


@njit(**JIT)
def _free_system(md, hc, user_xfrc, system, zones, lagged, dt, groups, out):
    """Steps 2-3 of :func:`evaluate_implicit` in one zone pass: the smooth force ``f`` (nv,) of this evaluation (+
    the user's wrenches; + MuJoCo's last constraint forces when ``lagged`` and not ``linearized``), H (this step's
    constraints linearized in ``zones``), its factor, and the groups' free twists and mobility. ``groups`` =
    (ng, ``active``, ``ids``, ``group_ref``); ``out`` = (``jrows``, ``y``, ``twist``, ``free``, ``mob``, ``h``,
    ``f``). False when the accelerations are not finite (or H not positive definite)."""
    xipos, cdof, subtree_com, qvel = md[sc.M_XIPOS], md[sc.M_CDOF], md[sc.M_SUBTREE_COM], md[sc.M_QVEL]
    jac_tree = (hc[sc.H_BODY_ROOTID], hc[sc.H_BODY_DOFNUM], hc[sc.H_BODY_DOFADR], hc[sc.H_BODY_PARENTID],
                hc[sc.H_DOF_PARENTID])                                                  # rest.JAC_TREE
    rownnz, rowadr, colind = hc[sc.H_M_ROWNNZ], hc[sc.H_M_ROWADR], hc[sc.H_M_COLIND]
    efc, sparse, m_val, damping, linearized = system
    jrows, y, twist, free, mob, h, f = out
    nv = qvel.shape[0]
    # 2. the smooth force of this evaluation (+ the user's wrenches; + the last constraint forces when lagged)
    for i in range(nv):
        f[i] = (md[sc.M_QFRC_PASSIVE][i] - md[sc.M_QFRC_BIAS][i] + md[sc.M_QFRC_ACTUATOR][i]
                + md[sc.M_QFRC_APPLIED][i])
        if not linearized and lagged:
            f[i] += md[sc.M_QFRC_CONSTRAINT][i]
    add_user_wrenches(user_xfrc, xipos, cdof, subtree_com, jac_tree, jrows, f)
    # 3. H (this step's constraints linearized), its factor, the free motion and mobility of the groups
    constrained_system(nv, (rowadr, rownnz, colind, m_val), sparse, efc, zones, linearized, damping, dt, h, f)
    if not cholesky(nv, h):
        return False
    free_motion(groups, (xipos, cdof, subtree_com, qvel), jac_tree, h, f, dt, (jrows, y, twist, free, mob))
    for i in range(nv):
        if not math.isfinite(f[i]):
            return False
    return True


@njit(**JIT)
def evaluate_implicit(md, hc, ws, iw, user_xfrc, dt, sand_out, system, st):
    """The implicit solve of the ``state[sc.S_TOUCHING]`` touching bodies of the broadphase: the sand wrenches, the
    diagnostics and the wrenches added to ``sand_out`` (nbody, 6). ``system``: MuJoCo's system of this step,
    :data:`SYSTEM`. Returns 1 (a non-zero wrench), 0 (none), NOT_FINITE or BAD_ACCELERATION (nothing written)."""
    xipos, qvel = md[sc.M_XIPOS], md[sc.M_QVEL]
    ids, group_of, group_ref = hc[sc.H_IDS], hc[sc.H_GROUP_OF], hc[sc.H_GROUP_REF]
    group_radius, params = hc[sc.H_GROUP_RADIUS], hc[sc.H_PARAMS]
    efc, sparse, linearized = system[0], system[1], system[4]
    touch, body_com = ws[sc.W_TOUCH], ws[sc.W_BODY_COM]
    wrench, count, depth_max, occluded = ws[sc.W_WRENCH], ws[sc.W_COUNT], ws[sc.W_DEPTH], ws[sc.W_OCCLUDED]
    active, slot, rest = ws[sc.W_ACTIVE], ws[sc.W_SLOT], ws[sc.W_REST]
    twist, free, w = ws[sc.W_TWIST], ws[sc.W_FREE], ws[sc.W_W]
    arm, total = ws[sc.W_ARM], ws[sc.W_TOTAL]
    state = ws[sc.W_STATE]
    (e_slot, e_arm, e_nrm, e_depth, e_area, jac_b, lin, ang, on, jrows, h, f, y, end, probe, gf, gdf, flowing,
     prev_active, prev_flow, istate, scr, pk, mob_buf, start, qacc_end, sf, si, sb) = iw     # IMPLICIT_FIELDS
    k = int(state[sc.S_TOUCHING])
    state[sc.S_CLEAN] = 0.0
    nv = qvel.shape[0]
    g0, g1, g2, g_mag = _gravity(hc[sc.H_GRAVITY])
    g_hat = np.empty(3)
    g_hat[0] = g0
    g_hat[1] = g1
    g_hat[2] = g2
    xi_n = params[sc.P_XI_PER_G] * g_mag
    lawc = (g_hat,) + law_of(hc, xi_n)                                        # implicit_law.LAW_CONSTANTS
    work = (lin, ang, on, scr, pk, wrench, jac_b, count, depth_max)                        # implicit_law.BODY_WORK
    # 1. the touching groups, in increasing group order, and each touching body's row among them
    ng_all = group_ref.shape[0]
    ng = touching_groups(k, touch, group_of, ng_all, rest, active, slot)
    # 2-5 are repeated while the end accelerations put a constraint row in another zone than the one it was
    #    linearized in (physics.implicit.ZONE_PASSES; reference.evaluate_implicit)
    nefc = efc[4].shape[0]
    zones, zones_end = np.empty(nefc, np.int64), np.empty(nefc, np.int64)    # (this step's number of rows)
    if linearized:
        row_zones(nv, sparse, efc, efc[9], zones, False, zones)
    prior = istate[0] != 0.0 and state[sc.S_LAGGED] != 0.0      # the last evaluation was of this motion
    for g in range(ng_all):
        prior = prior and prev_active[g] == rest[g]
    resting = ws[sc.W_FLOW]                                # (G,) the solve's rest flags (the explicit solve's ``flow``)
    its = NEED_ELEMENTS
    n_e = 0
    body_arms(k, slot, (active, ids, group_ref), body_com, xipos, arm)
    rad_g = total                                   # (G,) the active groups' radii
    for r in range(ng):
        rad_g[r] = group_radius[active[r]]
    solve_buf = solve_work(sf, si, sb, ng)          # the solve's buffers (implicit.SOLVE_WORK)
    mob = mob_buf[:36 * ng * ng].reshape((6 * ng, 6 * ng))
    have_elements = False                           # the evaluation's elements found (the same in every pass)
    for zone_pass in range(int(st[sc.ST_ZONE_PASSES])):
        if not _free_system(md, hc, user_xfrc, system, zones, state[sc.S_LAGGED] != 0.0, dt, (ng, active, ids,
                            group_ref), (jrows, y, twist, free, mob, h, f)):
            return BAD_ACCELERATION
        # 4. the capacity test's twists (the blend of the twists now and the free ones) and the law at them, by
        #    the element pass
        blend(twist, free, rad_g, ng, probe)
        group_twists(probe, None, k, slot, arm, lin, ang, None)         # every group
        wrenches(touch, k, surface_of(hc), (ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT], body_com), (lin, ang),
                 terrain_of(hc, g_hat), law_of(hc, xi_n), occluders_of(hc, md), (ws[sc.W_SCRATCH], ws[sc.W_INDEX]),
                 (wrench, count, depth_max, occluded), st[sc.ST_SPEED_SCALE])
        group_sums(ng, None, k, slot, arm, None, wrench, gf)
        # 5. the solve, started in flow for the groups that flowed at the last evaluation of the same groups (of
        #    this motion: not after a state restore); the elements that may carry stress are found (in the world
        #    frame, for the Newton solve) once, when a group is first to flow; a group that flowed in the last zone
        #    pass starts its Newton solve from that pass's answer (physics.implicit.implicit_wrenches's ``start``)
        for r in range(ng):
            start[r] = end[r] if zone_pass > 0 and not resting[r] else twist[r]
        ready = have_elements
        while True:
            if ready and not have_elements:
                have_elements = True
                n_e = _elements(md, hc, ws, k, g_hat, e_slot, e_arm, e_nrm, e_depth, e_area)
            lw = ((k, slot, arm), (n_e, e_slot, e_arm, e_nrm, e_depth, e_area), lawc, work)
            for r in range(ng):
                flowing[r] = prev_flow[active[r]]
            its = solve_from_probe((free, mob, rad_g, dt, ng), lw, start, flowing, prior, st, (w, resting, end), probe,
                                   gf, gdf, ready, solve_buf)
            if its != NEED_ELEMENTS:
                break
            ready = True
        if not linearized or nefc == 0 or zone_pass == int(st[sc.ST_ZONE_PASSES]) - 1:
            break
        end_acceleration(nv, h, jrows, ng, w, f, qacc_end)
        row_zones(nv, sparse, efc, qacc_end, zones, True, zones_end)
        same = True
        for e in range(nefc):
            same = same and zones[e] == zones_end[e]
            zones[e] = zones_end[e]
        if same:
            break
    for g in range(ng_all):
        prev_active[g] = False
        prev_flow[g] = False
    for r in range(ng):
        prev_active[active[r]] = True
        prev_flow[active[r]] = not resting[r]
    istate[0] = 1.0
    state[sc.S_NEWTON_ITERATIONS] = its
    # 6. the bodies' own law wrenches: at the end twists (flow), at the probe (rest: capacities, sharing); the
    #    groups never in flow still hold the law at the probe from the solve's capacity test
    again = False
    for r in range(ng):
        again = again or flowing[r]
        for c in range(6):
            end[r, c] = probe[r, c] if resting[r] else end[r, c]
    if again:
        group_law(end, flowing, ng, ((k, slot, arm), (n_e, e_slot, e_arm, e_nrm, e_depth, e_area), lawc, work),
                  st[sc.ST_SPEED_SCALE], st[sc.ST_FD_STEP], LAW, gf, gdf)
    # 7. each body's part (reference.share) and the diagnostics (reference.commit)
    return _share_and_commit(k, ng, (rad_g, gf, w, resting), hc, ws, sand_out)
