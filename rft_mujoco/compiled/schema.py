"""The compiled evaluation's argument schemas, by name: what each slot of ``md``, ``hc``, ``ws``, ``hc``'s ``params``
and ``ws``'s ``state`` holds, and a named index constant per slot (``hc[H_TP]``, ``ws[W_STATE]``,
``state[S_TOUCHING]``), so that the kernels address their data by name, not by position (issue 30).

The constants are module-level ints, which numba freezes into the compiled code as constants (a tuple or a
table view is then indexed statically, as with a literal); each group is unpacked from ``range(len(schema))``
(a field added without its name fails at import) and ``tests/test_native.py`` checks every name against its
slot. The kernels use them as ``sc.H_TP`` (``from rft_mujoco.compiled import schema as sc``).
"""

from __future__ import annotations

import enum


class Status(enum.IntEnum):
    """What an evaluation returns (:func:`rft_mujoco.compiled.evaluate.evaluate`, the implicit solve's, the
    broadphase's NOT_FINITE_STATE); the kernels use the plain ints of :mod:`rft_mujoco.compiled.share` (numba
    types an IntEnum member as a type of its own)."""

    NO_WRENCH = 0
    """Every wrench is zero."""
    WRENCH = 1
    """A non-zero wrench was added into the caller's sum."""
    NOT_FINITE = -1
    """A wrench came out non-finite; nothing was written."""
    BAD_ACCELERATION = -2
    """The acceleration without sand is not finite (NaN/inf inputs); nothing was written."""
    NOT_FINITE_STATE = -3
    """qpos/qvel are not finite while a body is a candidate (the simulation diverged)."""


class Phase(enum.IntEnum):
    """What a native route phase returns (:func:`rft_mujoco.compiled.route.phase1`, ``phase2``; the plain ints
    of :mod:`rft_mujoco.compiled.route` in the kernels)."""

    DONE = 0
    """Committed and finished."""
    ACTUATE = 1
    """Bodies touch: run ``mj_fwdActuation``, then phase 2."""
    CONTINUE = 2
    """Bodies touch, no stabilized handle among them: phase 2 without actuation."""
    PYTHON = 3
    """Nothing committed: run the Python path."""
    MONITOR = 4
    """Committed: run the due validity checks in Python."""

MJDATA_FIELDS = (
    ("xpos", "f2"), ("xmat", "f2"), ("xipos", "f2"), ("cvel", "f2"), ("subtree_com", "f2"), ("qpos", "f1"),
    ("qvel", "f1"), ("cdof", "f2"), ("qfrc_passive", "f1"), ("qfrc_bias", "f1"), ("qfrc_actuator", "f1"),
    ("qfrc_applied", "f1"), ("qfrc_constraint", "f1"), ("qLD", "f1"), ("qLDiagInv", "f1"), ("geom_xpos", "f2"),
    ("geom_xmat", "f2"))
"""(name, kind) of the MjData arrays of ``md``, in order (float64: MuJoCo's mjtNum, checked at attach)."""

HANDLE_FIELDS = (
    ("ids", "i1"), ("root", "i1"), ("group_of", "i1"), ("group_ref", "i1"), ("cluster_start", "i1"),
    ("body_clusters", "i1"), ("body_rootid", "i1"), ("body_dofnum", "i1"), ("body_dofadr", "i1"),
    ("body_parentid", "i1"), ("dof_parentid", "i1"), ("M_rownnz", "i1"), ("M_rowadr", "i1"), ("M_colind", "i1"),
    ("occ_start", "i1"), ("occ_geom", "i1"), ("occ_kind", "i1"), ("occ_hs_start", "i1"),
    ("bound_center", "f2"), ("bound_radius", "f1"), ("group_radius", "f1"), ("centroids", "f2"),
    ("normals", "f2"), ("areas", "f1"), ("cluster_center", "f2"), ("cluster_radius", "f1"), ("tp", "f1"),
    ("heights", "f2"), ("coef", "f2"), ("tol", "f1"), ("settings", "f1"), ("occ_size", "f2"),
    ("occ_rbound", "f1"), ("occ_hs", "f2"), ("gravity", "f1"), ("params", "f1"))
"""(name, kind) of the arrays of ``hc``, in order; kind: dtype (i int64, f float64, b bool) and ndim."""

WORK_FIELDS = (
    ("touch", "i1"), ("body_pos", "f2"), ("body_mat", "f2"), ("body_com", "f2"), ("v_com", "f2"),
    ("omega", "f2"), ("scratch", "f2"), ("wrench", "f2"), ("count", "i1"), ("depth", "f1"), ("occluded", "f1"),
    ("active", "i1"), ("slot", "i1"), ("idx", "i1"), ("rest", "b1"), ("flow", "b1"), ("zt", "f2"),
    ("minv_jt", "f2"), ("mob", "f2"), ("a", "f2"), ("block", "f2"), ("qacc", "f1"), ("v", "f1"), ("rhs", "f1"),
    ("weight", "f1"), ("twist", "f2"), ("free", "f2"), ("u", "f2"), ("rft_g", "f2"), ("w", "f2"), ("cap", "f2"),
    ("u_lin", "f2"), ("u_ang", "f2"), ("arm", "f2"), ("applied", "f2"), ("size", "f1"), ("total", "f1"),
    ("force", "f2"), ("torque", "f2"), ("submerged", "i1"), ("max_depth", "f1"), ("scale", "f1"),
    ("rft_force", "f2"), ("resting", "b1"), ("occluded_area", "f1"), ("state", "f1"), ("lin", "f2"),
    ("perm", "i1"), ("x", "f1"), ("index", "i2"), ("chain", "i2"), ("keep_active", "i1"), ("keep_rest", "b1"),
    ("lock_i", "i2"), ("lock_f", "f2"), ("lock_z", "f2"), ("lock_chain", "i2"), ("lock_s", "f2"), ("lock_c", "f2"),
    ("lock_r", "f2"), ("lock_x", "f2"), ("lock_mob", "f2"), ("lock_free", "f2"), ("lock_w", "f2"), ("lock_rest", "b1"),
    ("group_tree", "i1"), ("lock_prev", "b1"), ("reuse", "f2"))
"""(name, kind) of the arrays of ``ws``, in order."""


PARAMS = ("max_height", "xi_per_g", "mu_surf", "no_tension", "no_forward", "no_power", "kind", "stabilize",
          "passive", "margin", "monitor_every", "rk4_evaluated", "reuse_tol")
"""Entries of ``hc.params``: highest sand (m), ``xi_n / |g|`` (N/m^3 per m/s^2), surface friction, the
three guards (0/1), terrain kind, stabilize and passive (0/1), occlusion margin (m), evaluations between
validity checks (0: no monitor), the leading RK4 stages evaluated (4, 2 or 1: ``attach(rk4_stages=)``),
``attach(reuse_tol=)`` (0: off)."""
STATE = ("last_time", "clean", "touching", "lagged", "evaluations", "rk4_stage", "kept_groups", "kept_rank",
         "kept_evaluations", "locked_dofs", "locked_evaluations", "newton_iterations", "reused_wrenches")
"""Entries of ``ws.state``: the time of the last evaluation (s), whether the diagnostics are already clear,
the number of touching bodies found by the last broadphase, whether MuJoCo's previous constraint solve
belongs to this motion, evaluations so far; the RK4 stage of this evaluation (written by the caller
before the broadphase: 1-4, 0 for other integrators), the number of groups whose mobility is kept for
the later stages of this step (0: none), the kept rest factor's rank (-1: none, see
:func:`rft_mujoco.compiled.rest.rest_wrenches`), the evaluations that used a kept mobility; the dofs
held by their dry friction in this evaluation's rest solve (:func:`rft_mujoco.physics.rest.locked_rest`)
and the evaluations that held any; the Newton iterations of this evaluation's implicit solve
(``solve="implicit"``); the bodies' RFT wrenches reused so far (``attach(reuse_tol=)``)."""

BOOK_STATE = ("nonzero", "sand_dirty", "rk4_stage", "rk4_stage_time", "time_rtol", "pending")
"""Entries of the dispatcher's book ``state`` (:class:`rft_mujoco.coupling.book._DataBook`, read and written by
the native route): whether the sand's last wrench was non-zero, whether the ``sand`` buffer needs zeroing, the
RK4 stage of the last evaluation (1-4; 0: another integrator), the time of the step's first stage (s),
:data:`rft_mujoco.tol.TIME_RTOL`, and what the native callback left to Python
(:data:`rft_mujoco.compiled.route.MONITOR` or ``PYTHON``; 0: nothing)."""
TABLE_HEADER = ("handles", "book", "md", "rows", "rest_phase", "implicit_phase", "length", "press_phase")
"""The route table's header (:class:`rft_mujoco.compiled.route.Route`): the number of handles, the bases of the
book, of ``md`` and of the constraint rows, the addresses of the rest phase's, the implicit solve's (0: no
implicit handle) and the grid update's (0: no deformable terrain) C functions, and the table's length; one base
per handle, one per handle's implicit part and one per handle's press part follow."""
REGISTRY_HEADER = ("entries", "control_trampoline", "passive_trampoline", "fwd_actuation", "act_dyn", "act_gain",
                   "act_bias", "phase1", "phase2")
"""The native callback's registry header (:mod:`rft_mujoco.compiled.native`): the number of entries, the Python
trampolines of ``mjcb_control`` and ``mjcb_passive``, ``mj_fwdActuation``'s address, the user's
``mjcb_act_dyn`` / ``gain`` / ``bias`` (0: none), the route's phase 1 and phase 2 C functions."""
REGISTRY_ENTRY = ("model", "data", "table", "time", "timestep", "integrator", "disableflags", "length")
"""One registry entry: ``mjModel*``, ``mjData*`` (0: a model without a route yet), the route table's address,
the addresses of ``data.time``, ``opt.timestep``, ``opt.integrator`` and ``opt.disableflags``, the table's
length."""
IMPLICIT_SETTINGS = ("speed_scale", "rest_retry", "newton_iterations", "newton_rtol", "fd_step", "dependent_tol",
                     "weight_floor", "capacity_tol", "tiny", "zone_passes")
"""Entries of the implicit solve's ``st``: :data:`rft_mujoco.physics.implicit.SPEED_SCALE` (m/s), ``REST_RETRY``,
``NEWTON_ITERATIONS``, ``NEWTON_RTOL``, :data:`rft_mujoco.physics.elements.FD_STEP`,
:data:`rft_mujoco.physics.rest.DEPENDENT_TOL`, ``WEIGHT_FLOOR``, ``CAPACITY_TOL``, :data:`rft_mujoco.tol.TINY`
and ``ZONE_PASSES`` (:func:`rft_mujoco.compiled.implicit.settings`)."""

(M_XPOS, M_XMAT, M_XIPOS, M_CVEL, M_SUBTREE_COM, M_QPOS, M_QVEL, M_CDOF, M_QFRC_PASSIVE, M_QFRC_BIAS,
 M_QFRC_ACTUATOR, M_QFRC_APPLIED, M_QFRC_CONSTRAINT, M_QLD, M_QLDIAGINV, M_GEOM_XPOS,
 M_GEOM_XMAT) = range(len(MJDATA_FIELDS))

(H_IDS, H_ROOT, H_GROUP_OF, H_GROUP_REF, H_CLUSTER_START, H_BODY_CLUSTERS, H_BODY_ROOTID, H_BODY_DOFNUM,
 H_BODY_DOFADR, H_BODY_PARENTID, H_DOF_PARENTID, H_M_ROWNNZ, H_M_ROWADR, H_M_COLIND, H_OCC_START, H_OCC_GEOM,
 H_OCC_KIND, H_OCC_HS_START, H_BOUND_CENTER, H_BOUND_RADIUS, H_GROUP_RADIUS, H_CENTROIDS, H_NORMALS, H_AREAS,
 H_CLUSTER_CENTER, H_CLUSTER_RADIUS, H_TP, H_HEIGHTS, H_COEF, H_TOL, H_SETTINGS, H_OCC_SIZE, H_OCC_RBOUND,
 H_OCC_HS, H_GRAVITY, H_PARAMS) = range(len(HANDLE_FIELDS))

(W_TOUCH, W_BODY_POS, W_BODY_MAT, W_BODY_COM, W_V_COM, W_OMEGA, W_SCRATCH, W_WRENCH, W_COUNT, W_DEPTH,
 W_OCCLUDED, W_ACTIVE, W_SLOT, W_IDX, W_REST, W_FLOW, W_ZT, W_MINV_JT, W_MOB, W_A, W_BLOCK, W_QACC, W_V, W_RHS,
 W_WEIGHT, W_TWIST, W_FREE, W_U, W_RFT_G, W_W, W_CAP, W_U_LIN, W_U_ANG, W_ARM, W_APPLIED, W_SIZE, W_TOTAL,
 W_FORCE, W_TORQUE, W_SUBMERGED, W_MAX_DEPTH, W_SCALE, W_RFT_FORCE, W_RESTING, W_OCCLUDED_AREA, W_STATE, W_LIN,
 W_PERM, W_X, W_INDEX, W_CHAIN, W_KEEP_ACTIVE, W_KEEP_REST, W_LOCK_I, W_LOCK_F, W_LOCK_Z, W_LOCK_CHAIN,
 W_LOCK_S, W_LOCK_C, W_LOCK_R, W_LOCK_X, W_LOCK_MOB, W_LOCK_FREE, W_LOCK_W, W_LOCK_REST, W_GROUP_TREE,
 W_LOCK_PREV, W_REUSE) = range(len(WORK_FIELDS))

(P_MAX_HEIGHT, P_XI_PER_G, P_MU_SURF, P_NO_TENSION, P_NO_FORWARD, P_NO_POWER, P_KIND, P_STABILIZE, P_PASSIVE,
 P_MARGIN, P_MONITOR_EVERY, P_RK4_EVALUATED, P_REUSE_TOL) = range(len(PARAMS))

(S_LAST_TIME, S_CLEAN, S_TOUCHING, S_LAGGED, S_EVALUATIONS, S_RK4_STAGE, S_KEPT_GROUPS, S_KEPT_RANK,
 S_KEPT_EVALUATIONS, S_LOCKED_DOFS, S_LOCKED_EVALUATIONS, S_NEWTON_ITERATIONS, S_REUSED_WRENCHES) = range(len(STATE))

(B_NONZERO, B_SAND_DIRTY, B_RK4_STAGE, B_RK4_STAGE_TIME, B_TIME_RTOL, B_PENDING) = range(len(BOOK_STATE))

(T_HANDLES, T_BOOK, T_MD, T_ROWS, T_REST_PHASE, T_IMPLICIT_PHASE, T_LENGTH, T_PRESS_PHASE) = range(len(TABLE_HEADER))

(R_ENTRIES, R_CONTROL_TRAMPOLINE, R_PASSIVE_TRAMPOLINE, R_FWD_ACTUATION, R_ACT_DYN, R_ACT_GAIN, R_ACT_BIAS, R_PHASE1,
 R_PHASE2) = range(len(REGISTRY_HEADER))

(E_MODEL, E_DATA, E_TABLE, E_TIME, E_TIMESTEP, E_INTEGRATOR, E_DISABLEFLAGS, E_LENGTH) = range(len(REGISTRY_ENTRY))

(ST_SPEED_SCALE, ST_REST_RETRY, ST_NEWTON_ITERATIONS, ST_NEWTON_RTOL, ST_FD_STEP, ST_DEPENDENT_TOL, ST_WEIGHT_FLOOR,
 ST_CAPACITY_TOL, ST_TINY, ST_ZONE_PASSES) = range(len(IMPLICIT_SETTINGS))
