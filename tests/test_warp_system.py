"""The linearized constraint rows of MuJoCo Warp (rft_mujoco.warp.system) against the numpy reference
(rft_mujoco.coupling.reference.constraint_zones / constrained_free_motion).

Each scene is stepped on the CPU, copied into MuJoCo Warp (two worlds) and run through ``mjw.forward`` so this
step's rows exist; both sides then take the zones at warp's ``qacc`` (world 0: nearly it, world 1: reversed,
plus noise) and the rows' part of ``H`` and ``f``. Warp's row order may differ from MuJoCo C's and its rows are
float32, so the comparisons are order-independent: H and f to RTOL of their largest entry, the quadratic rows per
constraint type, the saturated friction forces.
"""

import types

import mujoco
import numpy as np
import pytest

mjw = pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (pip install 'rft_mujoco[warp]')")
wp = pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'rft_mujoco[warp]')")

from rft_mujoco.coupling.reference import constrained_free_motion, constraint_rows, constraint_zones  # noqa: E402
from rft_mujoco.warp.common import F64  # noqa: E402
from rft_mujoco.warp.system import add_rows, row_zones  # noqa: E402

C = mujoco.mjtConstraint
NTYPE = 8
EXACT_RTOL = 1e-12
"""The port against the reference on warp's own rows: the same float64 arithmetic up to summation order."""
RTOL = 1e-4
"""|warp - MuJoCo C| of H's rows part, relative to its largest entry (float32 rows)."""
F_RTOL = 5e-4
"""|warp - MuJoCo C| of f, relative to its largest entry: aref carries the float32 round-off of warp's kinematics
times the rows' stiffness (measured 1.1e-4 on the resting contacts)."""
F_RTOL_WELD = {"weld": 3e-2, "dense": 5e-3, "sparse": 5e-3}
"""Scenes with welds: MuJoCo Warp's weld rows' aref differ from MuJoCo C's by up to 1.7% (measured, the falling
weld pair), beyond the float32 round-off of their 1e-4 m violations; warp adds a Jdot qvel term (``aref_shift``).
The port itself is checked row by row on warp's own rows (EXACT_RTOL)."""
NWORLD = 2


@pytest.fixture(scope="module", autouse=True)
def _device():
    wp.config.quiet = True
    with wp.ScopedDevice("cpu"):
        yield


@wp.kernel(enable_backward=False)
def _zones_kernel(nefc: wp.array(dtype=int), efc_type: wp.array2d(dtype=int), efc_id: wp.array2d(dtype=int),
                  efc_D: wp.array2d(dtype=float), efc_aref: wp.array2d(dtype=float),
                  efc_frictionloss: wp.array2d(dtype=float), efc_J: wp.array3d(dtype=float),
                  J_rownnz: wp.array2d(dtype=int), J_rowadr: wp.array2d(dtype=int),
                  J_colind: wp.array3d(dtype=int), sparse: int, nv: int, qacc: wp.array3d(dtype=F64),
                  use_prev: int, quad: wp.array2d(dtype=int), cst: wp.array2d(dtype=F64),
                  est: wp.array2d(dtype=F64), h: wp.array3d(dtype=F64), f: wp.array3d(dtype=F64),
                  changed: wp.array(dtype=int)):
    w = wp.tid()
    changed[w] = row_zones(w, nefc[w], efc_type, efc_id, efc_D, efc_aref, efc_frictionloss, efc_J, J_rownnz,
                           J_rowadr, J_colind, sparse, nv, qacc, use_prev, quad, cst, est)
    add_rows(w, nefc[w], efc_D, efc_aref, efc_J, J_rownnz, J_rowadr, J_colind, sparse, nv, quad, cst, h, f)


def _launch(efc, nefc, sparse, nv, qacc, use_prev, quad, const):
    """One launch of the test kernel at qacc (nworld, nv); quad/const (njmax, nworld) warp arrays, updated in
    place. Returns h (nworld, nv, nv) symmetrized from its lower triangle, f (nworld, nv), changed (nworld,)."""
    nw = qacc.shape[0]
    q = wp.array(np.ascontiguousarray(qacc.T[None]), dtype=F64)
    est = wp.zeros(quad.shape, dtype=F64)
    h = wp.zeros((nv, nv, nw), dtype=F64)
    f = wp.zeros((1, nv, nw), dtype=F64)
    changed = wp.zeros(nw, dtype=int)
    wp.launch(_zones_kernel, dim=nw, inputs=[nefc, efc.type, efc.id, efc.D, efc.aref, efc.frictionloss, efc.J,
                                            efc.J_rownnz, efc.J_rowadr, efc.J_colind, int(sparse), nv, q, use_prev,
                                            quad, const, est, h, f, changed])
    low = np.tril(np.moveaxis(h.numpy(), 2, 0))
    sym = low + np.swapaxes(low, 1, 2) - np.einsum("wii->wi", low)[:, :, None] * np.eye(nv)
    return sym, f.numpy()[0].T, changed.numpy()


# --- scenes ---------------------------------------------------------------------------------------------------
_FLOOR = '<geom type="plane" size="5 5 .1" friction="0.8"/>'
_BODIES = """
<body pos="0 0 .1"><freejoint/><geom type="box" size=".1 .1 .1" mass="2"/></body>
<body pos=".5 0 .08"><freejoint/><geom type="sphere" size=".08" mass="1"/></body>
<body pos="1 0 .06" euler="0 0 30"><freejoint/><geom type="box" size=".12 .06 .06" mass="1.5"/></body>"""


def _xml(body: str, option: str = "", extra: str = "") -> str:
    return f"<mujoco><option {option}/><worldbody>{body}</worldbody>{extra}</mujoco>"


LIMIT = _xml("""
<body pos="0 0 1"><joint name="h" type="hinge" axis="0 1 0" range="-30 30"/>
  <geom type="capsule" fromto="0 0 0 .5 0 0" size=".04"/></body>
<body pos="1 0 1"><joint name="s" type="slide" axis="0 0 1" range="-.1 .1"/><geom type="sphere" size=".05"/></body>""")
CONTACT = _xml(_FLOOR + _BODIES)
ELLIPTIC = _xml(_FLOOR + _BODIES, 'cone="elliptic"')
WELD = _xml("""
<body name="a" pos="0 0 1"><freejoint/><geom type="box" size=".1 .05 .05"/></body>
<body name="b" pos=".3 0 1"><freejoint/><geom type="sphere" size=".06"/></body>
<body name="c" pos="1 0 1"><freejoint/><geom type="capsule" fromto="0 0 0 .2 0 0" size=".03"/></body>""",
            extra='<equality><weld body1="a" body2="b"/><weld body1="c"/></equality>')
FRICTION = _xml("""
<body pos="0 0 1"><joint name="stick" type="hinge" axis="0 1 0" frictionloss="50"/>
  <geom type="capsule" fromto="0 0 0 .5 0 0" size=".04" mass="1"/></body>
<body pos="1 0 1"><joint name="slip" type="hinge" axis="0 1 0" frictionloss=".2"/>
  <geom type="capsule" fromto="0 0 0 .5 0 0" size=".04" mass="1"/></body>
<body pos="2 0 1"><joint name="ten" type="hinge" axis="0 1 0"/>
  <geom type="capsule" fromto="0 0 0 .5 0 0" size=".04" mass="1"/></body>""",
               extra='<tendon><fixed frictionloss=".1"><joint joint="ten" coef="1"/></fixed></tendon>')
_MIXED = (_FLOOR + _BODIES + """
<body pos="0 2 1"><joint type="hinge" axis="0 1 0" range="-30 30" frictionloss=".05"/>
  <geom type="capsule" fromto="0 0 0 .5 0 0" size=".04"/></body>
<body name="w" pos="2 2 1"><freejoint/><geom type="box" size=".05 .05 .05"/></body>""")
MIXED_EQ = '<equality><weld body1="w"/></equality>'
CHAIN = _xml(_FLOOR + "".join(
    f'<body pos="{0.4 * k} 1 .06"><freejoint/><geom type="box" size=".06 .06 .06"/></body>' for k in range(6)))
"""36 dofs: MuJoCo Warp picks the sparse layout with jacobian AUTO."""

SCENES = {
    # name: (xml, qpos overrides {index: value}, CPU steps, types with quadratic rows, saturated friction)
    "limit": (LIMIT, {0: np.radians(30.0), 1: -0.1}, 30, {C.mjCNSTR_LIMIT_JOINT}, False),
    "pyramidal": (CONTACT, {}, 30, {C.mjCNSTR_CONTACT_PYRAMIDAL}, False),
    "elliptic": (ELLIPTIC, {}, 30, {C.mjCNSTR_CONTACT_ELLIPTIC}, False),
    "weld": (WELD, {}, 30, {C.mjCNSTR_EQUALITY}, False),
    # two steps from rest: the slipping joints' aref (-b J qvel) is still below their acceleration, so
    # reversing the acceleration reverses their slip
    "frictionloss": (FRICTION, {}, 2, {C.mjCNSTR_FRICTION_DOF}, True),
    "dense": (_xml(_MIXED, 'jacobian="dense"', MIXED_EQ), {21: np.radians(30.0)}, 30,
              {C.mjCNSTR_CONTACT_PYRAMIDAL, C.mjCNSTR_LIMIT_JOINT, C.mjCNSTR_EQUALITY}, False),
    "sparse": (_xml(_MIXED, 'jacobian="sparse" cone="elliptic"', MIXED_EQ), {21: np.radians(30.0)}, 30,
               {C.mjCNSTR_CONTACT_ELLIPTIC, C.mjCNSTR_LIMIT_JOINT, C.mjCNSTR_EQUALITY}, False),
    "auto_sparse": (CHAIN, {}, 30, {C.mjCNSTR_CONTACT_PYRAMIDAL}, False),
}


def _counts(kind, quad) -> np.ndarray:
    return np.bincount(np.asarray(kind)[np.asarray(quad, dtype=bool)], minlength=NTYPE)


def _close(a, b, what, rtol):
    scale = max(np.max(np.abs(b)), 1e-12)
    err = np.max(np.abs(a - b))
    assert err <= rtol * scale, f"{what}: max |warp - reference| {err:.3g} > {rtol} x {scale:.3g}"


def _warp_rows(d, w, nv, sparse):
    """World w's rows as the reference reads them (float64 of warp's float32): a stand-in for MjData's efc
    fields and the dense Jacobian (nefc, nv)."""
    n = int(d.nefc.numpy()[w])
    efc = d.efc
    if sparse:
        rows = np.zeros((n, nv))
        val, col = efc.J.numpy()[w, 0], efc.J_colind.numpy()[w, 0]
        adr, nnz = efc.J_rowadr.numpy()[w], efc.J_rownnz.numpy()[w]
        for i in range(n):
            rows[i, col[adr[i]:adr[i] + nnz[i]]] = val[adr[i]:adr[i] + nnz[i]]
    else:
        rows = efc.J.numpy()[w, :n, :nv].astype(np.float64)
    data = types.SimpleNamespace(**{f"efc_{k}": getattr(efc, k).numpy()[w, :n].astype(np.float64)
                                    for k in ("D", "aref", "frictionloss")},
                                 efc_type=efc.type.numpy()[w, :n], efc_id=efc.id.numpy()[w, :n])
    return data, rows


def _rows_part(data, rows, zones):
    """The rows' part of constrained_free_motion's H and f: Jq^T diag(Dq) Jq, Jq^T (Dq aref_q) + J^T const."""
    quad, const = zones
    dq = data.efc_D * quad
    return rows.T @ (dq[:, None] * rows), rows.T @ (dq * data.efc_aref + const)


def _changed(a, b) -> int:
    return int(not (np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])))


@pytest.mark.parametrize("name", list(SCENES))
def test_rows_match_reference(name):
    xml, qpos, steps, required, saturates = SCENES[name]
    mjm = mujoco.MjModel.from_xml_string(xml)
    mjd = mujoco.MjData(mjm)
    for i, v in qpos.items():
        mjd.qpos[i] = v
    for _ in range(steps):
        mujoco.mj_step(mjm, mjd)
    nv = mjm.nv
    m = mjw.put_model(mjm)
    d = mjw.put_data(mjm, mjd, nworld=NWORLD, nconmax=64, njmax=256)
    mjw.forward(m, d)
    sparse = bool(m.is_sparse)
    assert sparse == (name in ("sparse", "auto_sparse"))
    nj = d.efc.type.shape[1]
    if sparse:
        assert d.efc.J.shape[:2] == (NWORLD, 1) and d.efc.J_colind.shape == d.efc.J.shape
        assert d.efc.J_rowadr.shape == d.efc.J_rownnz.shape == (NWORLD, nj)
    else:
        assert d.efc.J.shape[1] >= nj and d.efc.J.shape[2] >= nv and d.efc.J_rownnz.shape == (NWORLD, 0)
    # the CPU data in warp's state (its float32 qpos/qvel), its rows made by mj_forward
    mjd.qpos[:] = d.qpos.numpy()[0]
    mjd.qvel[:] = d.qvel.numpy()[0]
    mujoco.mj_forward(mjm, mjd)
    nefc = d.nefc.numpy()
    assert np.all(nefc == mjd.nefc) and mjd.nefc > 0
    kind_w, id_w = d.efc.type.numpy(), d.efc.id.numpy()
    for w in range(NWORLD):
        assert np.array_equal(np.sort(kind_w[w, :nefc[w]]), np.sort(mjd.efc_type))
        ell = np.flatnonzero(kind_w[w, :nefc[w]] == C.mjCNSTR_CONTACT_ELLIPTIC)
        for c in np.unique(id_w[w, ell]):              # the rows of one elliptic contact are contiguous
            rows = ell[id_w[w, ell] == c]
            assert rows[-1] - rows[0] + 1 == rows.size == mjm.geom_condim[0]

    # zones at warp's qacc, then (use_prev) at world 0: nearly it, world 1: reversed, both plus noise
    rng = np.random.default_rng(0)
    qacc = d.qacc.numpy().astype(np.float64)
    scale = np.max(np.abs(qacc)) + 1.0
    qacc1 = np.stack([1.05 * qacc[0], -qacc[1]]) + 0.02 * scale * rng.standard_normal((NWORLD, nv))
    quad = wp.zeros((nj, NWORLD), dtype=int)
    const = wp.zeros((nj, NWORLD), dtype=F64)
    h0, f0, ch0 = _launch(d.efc, d.nefc, sparse, nv, qacc, 0, quad, const)
    quad0, const0 = quad.numpy().copy(), const.numpy().copy()
    assert np.all(ch0 == 1)
    h1, f1, ch1 = _launch(d.efc, d.nefc, sparse, nv, qacc1, 1, quad, const)
    quad1, const1 = quad.numpy(), const.numpy()
    assert np.all(quad1[nefc.max():] == 0) and np.all(const1[nefc.max():] == 0.0)

    rows_c = constraint_rows(mjm, mjd)
    mass = np.zeros((nv, nv))
    mujoco.mj_fullM(mjm, mjd, mass)
    zero = np.zeros(nv)
    flips = 0
    for w in range(NWORLD):
        n, kind = nefc[w], kind_w[w, :nefc[w]]
        # the port: the reference on warp's own rows, row by row
        data_w, rows_w = _warp_rows(d, w, nv, sparse)
        own0 = constraint_zones(None, data_w, rows_w, qacc[w])
        own1 = constraint_zones(None, data_w, rows_w, qacc1[w], prev=own0)
        # MuJoCo C's rows (another order, float64)
        ref0 = constraint_zones(mjm, mjd, rows_c, qacc[w])
        ref1 = constraint_zones(mjm, mjd, rows_c, qacc1[w], prev=ref0)
        for (hw, fw, qw, cw, own, ref) in ((h0, f0, quad0, const0, own0, ref0), (h1, f1, quad1, const1, own1, ref1)):
            np.testing.assert_array_equal(qw[:n, w], own[0].astype(int))
            np.testing.assert_array_equal(cw[:n, w], own[1])
            ho, fo = _rows_part(data_w, rows_w, own)
            _close(hw[w], ho, f"{name} H world {w} (warp's rows)", EXACT_RTOL)
            _close(fw[w], fo, f"{name} f world {w} (warp's rows)", EXACT_RTOL)
            hr, fr, _ = constrained_free_motion(mjm, mjd, zero, ref)
            np.testing.assert_array_equal(_counts(kind, qw[:n, w]), _counts(mjd.efc_type, ref[0]))
            np.testing.assert_allclose(np.sort(cw[:n, w]), np.sort(ref[1]), rtol=1e-5, atol=1e-9)
            np.testing.assert_allclose(np.abs(cw[:n, w]).sum(), np.abs(ref[1]).sum(), rtol=1e-5, atol=1e-9)
            _close(hw[w], hr - mass, f"{name} H world {w} (MuJoCo C)", RTOL)
            _close(fw[w], fr, f"{name} f world {w} (MuJoCo C)", F_RTOL_WELD.get(name, F_RTOL))
        assert ch1[w] == _changed(own0, own1) == _changed(ref0, ref1)
        flips += int(np.sum((ref0[1] != 0.0) & ref1[0]))
        counts = _counts(mjd.efc_type, ref0[0])
        for t in required:
            assert counts[int(t)] > 0, f"{name}: no quadratic rows of type {C(t).name}"
    if saturates:
        # slipping joints saturate at qacc; reversed (world 1), their saturated friction sticks (use_prev rule)
        assert np.count_nonzero(const0[:, 0]) > 0 and np.count_nonzero(quad0[:nefc[0], 0] & (kind_w[0, :nefc[0]]
                                                                                            == C.mjCNSTR_FRICTION_DOF))
        assert flips > 0 and ch1[1] == 1


def test_use_prev_rule():
    """row_zones with use_prev on hand-built rows (two dofs, dense J), against the reference's rule."""
    fr_dof, fr_ten, lim, eq = (int(C.mjCNSTR_FRICTION_DOF), int(C.mjCNSTR_FRICTION_TENDON),
                               int(C.mjCNSTR_LIMIT_JOINT), int(C.mjCNSTR_EQUALITY))
    kind = np.array([fr_dof, fr_dof, fr_dof, fr_ten, lim, eq])
    jac = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, -1.0], [1.0, 1.0], [0.0, 1.0], [1.0, -1.0]])
    dd = np.array([1.0, 1.0, 1.0, 2.0, 1.0, 3.0])
    aref = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.25])
    fl = np.array([1.0, 1.0, 1.0, 0.5, 0.0, 0.0])
    # est = -D (J qacc - aref) of rows 0..3: world 0 (2, 0.5, 1.5, 6): row 0 keeps its slip, row 1 drops inside
    # its bound, row 2 flips against its prev -1, the tendon row (quadratic before) saturates at +0.5;
    # world 1 (2, 4, -2, 13): every saturated row keeps its slip and bound, nothing changes
    qacc = np.array([[-2.0, -0.5], [-2.0, -4.0]])
    prev_const = np.array([[1.0, 1.0, -1.0, 0.0, 0.0, 0.0], [1.0, 1.0, -1.0, 0.5, 0.0, 0.0]])
    prev_quad = np.array([[0, 0, 0, 1, 1, 1], [0, 0, 0, 0, 1, 1]])
    n, nv, nw = kind.size, 2, 2
    data = types.SimpleNamespace(efc_type=kind, efc_id=np.arange(n), efc_D=dd, efc_aref=aref, efc_frictionloss=fl)
    pad = 2
    efc = types.SimpleNamespace(
        type=wp.array(np.tile(np.r_[kind, np.zeros(pad, int)], (nw, 1)), dtype=int),
        id=wp.array(np.tile(np.arange(n + pad), (nw, 1)), dtype=int),
        D=wp.array(np.tile(np.r_[dd, np.zeros(pad)], (nw, 1)), dtype=float),
        aref=wp.array(np.tile(np.r_[aref, np.zeros(pad)], (nw, 1)), dtype=float),
        frictionloss=wp.array(np.tile(np.r_[fl, np.zeros(pad)], (nw, 1)), dtype=float),
        J=wp.array(np.tile(np.vstack([jac, np.zeros((pad, nv))])[None], (nw, 1, 1)), dtype=float),
        J_rownnz=wp.zeros((nw, 0), dtype=int), J_rowadr=wp.zeros((nw, 0), dtype=int),
        J_colind=wp.zeros((nw, 0, 0), dtype=int))
    nefc = wp.array([n, n], dtype=int)
    quad = wp.array(np.vstack([prev_quad.T, np.zeros((pad, nw), int)]), dtype=int)
    const = wp.array(np.vstack([prev_const.T, np.zeros((pad, nw))]), dtype=F64)
    h, f, changed = _launch(efc, nefc, False, nv, qacc, 1, quad, const)
    q, c = quad.numpy(), const.numpy()
    for w in range(nw):
        ref = constraint_zones(None, data, jac, qacc[w], prev=(prev_quad[w].astype(bool), prev_const[w]))
        np.testing.assert_array_equal(q[:n, w], ref[0].astype(int))
        np.testing.assert_array_equal(c[:n, w], ref[1])
        dq = dd * ref[0]
        np.testing.assert_allclose(h[w], jac.T @ (dq[:, None] * jac), rtol=1e-12)
        np.testing.assert_allclose(f[w], jac.T @ (dq * aref + ref[1]), rtol=1e-12)
    # world 0: row 0 stays saturated (+1), rows 1 (inside) and 2 (flipped) stick, the tendon row saturates
    np.testing.assert_array_equal(q[:4, 0], [0, 1, 1, 0])
    np.testing.assert_array_equal(c[:4, 0], [1.0, 0.0, 0.0, 0.5])
    np.testing.assert_array_equal(changed, [1, 0])
    np.testing.assert_array_equal(q[:4, 1], [0, 0, 0, 0])
    np.testing.assert_array_equal(c[:4, 1], [1.0, 1.0, -1.0, 0.5])
