"""The compiled implicit solve (rft_mujoco.compiled.implicit*) against the numpy reference: the law and its
derivative, the constraint linearization, the whole solve on random problems, and simulations of the scenes of
tests/test_implicit.py on both backends."""

import warnings

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.compiled import implicit as cimp
from rft_mujoco.compiled import implicit_law
from rft_mujoco.compiled import system as csys
from rft_mujoco.compiled.implicit_eval import efc_arrays
from rft_mujoco.compiled.law import tolerances
from rft_mujoco.coupling import reference
from rft_mujoco.physics import elements, implicit
from rft_mujoco.physics import law as plaw
from rft_mujoco.physics import terrain as terrains
from rft_mujoco.physics.media import f_hat, get_media

MEDIA = get_media("li_loose_glass_beads")
G_HAT, GRAVITY = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, -9.81])


class Problem:
    """Random elements on k bodies (COMs at the origin) in ng groups (body j in group ``slot[j]``, its COM at
    ``arm[j]`` from the group's reference point), under a flat surface at z = 0; the law as the numpy
    reference computes it (reference.evaluate_implicit's closure) and as the compiled one does (``lw``)."""

    def __init__(self, seed, k=3, slot=(0, 0, 1), n=400):
        rng = np.random.default_rng(seed)
        self.k, self.slot, self.ng = k, np.array(slot, dtype=np.int64), max(slot) + 1
        pos = rng.uniform(-0.05, 0.05, size=(n, 3))
        pos[:, 2] = rng.uniform(-0.06, 0.01, size=n)
        nrm = rng.normal(size=(n, 3))
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        self.pos, self.nrm, self.area = pos, nrm, np.full(n, 2e-4)
        self.body = rng.integers(0, k, size=n).astype(np.int64)
        self.arm = rng.uniform(-0.1, 0.1, size=(k, 3))
        sub = np.flatnonzero(-pos[:, 2] > 0.0)
        self.e = (sub.size, self.body[sub].copy(), pos[sub].copy(), nrm[sub].copy(), -pos[sub, 2].copy(),
                  self.area[sub].copy())
        self.xi_n = MEDIA.rho_c * f_hat(MEDIA.mu_int) * 9.81
        self.work = (np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k, dtype=np.bool_),
                     np.zeros((implicit_law.SCRATCH_ROWS, n)), np.zeros(n + 1, dtype=np.int64), np.zeros((k, 6)),
                     np.zeros((k, 6, 6)), np.zeros(k, dtype=np.int64), np.zeros(k))

    def lw(self):
        n_e, es, ea, en, ed, ear = self.e
        return ((self.k, self.slot, self.arm), (n_e, es, ea, en, ed, ear),
                (G_HAT, self.xi_n, plaw.COEFFICIENTS, MEDIA.mu_surf, False, False, False, tolerances()), self.work)

    def numpy_law(self, u, groups=None):
        shift = reference._shift(self.arm)
        ub = np.einsum("kij,kj->ki", shift, u[self.slot])
        z = np.zeros((self.k, 3))
        w_b, j_b, _, _ = elements.body_wrench_jacobians(
            elements.BodySurface(self.pos, self.nrm, self.area, self.body, self.k),
            elements.BodyPose(z, np.broadcast_to(np.eye(3), (self.k, 3, 3)), z), ub[:, :3], ub[:, 3:],
            terrains.as_terrain(0.0), G_HAT, GRAVITY, MEDIA, rft_mujoco.PUBLISHED, implicit.SPEED_SCALE)
        f = np.zeros((self.ng, 6))
        np.add.at(f, self.slot, np.einsum("kji,kj->ki", shift, w_b))
        df = np.zeros((self.ng, 6, 6))
        np.add.at(df, self.slot, np.einsum("kji,kjl,klm->kim", shift, j_b, shift))
        return f, df



def solve_work(ng):
    """:data:`rft_mujoco.compiled.implicit.SOLVE_WORK` for ``ng`` groups, on arenas sized for ``ng + 2`` (views cut
    from larger arenas, as on a handle whose groups do not all touch)."""
    nf, ni, nb = cimp.arena_sizes(ng + 2)
    return cimp.solve_work(np.full(nf, np.nan), np.full(ni, -1, np.int64), np.ones(nb, np.bool_), ng)

def test_constraint_types_are_mujocos():
    c = mujoco.mjtConstraint
    assert (csys.EQUALITY, csys.FRICTION_DOF, csys.FRICTION_TENDON, csys.LIMIT_JOINT, csys.LIMIT_TENDON,
            csys.CONTACT_FRICTIONLESS, csys.CONTACT_PYRAMIDAL, csys.CONTACT_ELLIPTIC) == tuple(
        int(x) for x in (c.mjCNSTR_EQUALITY, c.mjCNSTR_FRICTION_DOF, c.mjCNSTR_FRICTION_TENDON, c.mjCNSTR_LIMIT_JOINT,
                         c.mjCNSTR_LIMIT_TENDON, c.mjCNSTR_CONTACT_FRICTIONLESS, c.mjCNSTR_CONTACT_PYRAMIDAL,
                         c.mjCNSTR_CONTACT_ELLIPTIC))
    assert (csys.TRN_JOINT, csys.BIAS_AFFINE) == (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtBias.mjBIAS_AFFINE))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_group_law_and_derivative_match_the_numpy_law(seed):
    p = Problem(seed)
    rng = np.random.default_rng(100 + seed)
    u = rng.normal(scale=0.05, size=(p.ng, 6))
    u[:, 3:] *= 5.0
    f, df = np.zeros((p.ng, 6)), np.zeros((p.ng, 6, 6))
    on = np.ones(p.ng, dtype=np.bool_)
    cimp._law(p.lw(), u, on, p.ng, cimp.settings(), implicit_law.LAW_AND_DERIVATIVE, f, df)
    f_ref, df_ref = p.numpy_law(u)
    assert np.abs(f_ref).max() > 1e-3
    np.testing.assert_allclose(f, f_ref, rtol=1e-10, atol=1e-12 * np.abs(f_ref).max())
    # the forward differences amplify the law's round-off by 1 / FD_STEP
    np.testing.assert_allclose(df, df_ref, rtol=0, atol=1e-6 * np.abs(df_ref).max())
    off = on.copy()                                   # a group not asked for keeps its rows
    off[0] = False
    f[:] = 7.0
    cimp._law(p.lw(), u, off, p.ng, cimp.settings(), implicit_law.LAW, f, df)
    assert np.all(f[0] == 7.0) and np.allclose(f[1:], f_ref[1:], rtol=1e-10, atol=1e-12 * np.abs(f_ref).max())


@pytest.mark.parametrize("seed", range(3))
def test_derivative_of_the_last_law_is_that_of_one_call(seed):
    # the Newton solve evaluates the law at trial points and its derivative only where it steps from: the law
    # then the derivative of the last law must be one call's numbers, bit for bit
    p = Problem(seed)
    u = np.random.default_rng(200 + seed).normal(scale=0.05, size=(p.ng, 6))
    on = np.ones(p.ng, dtype=np.bool_)
    one = np.zeros((p.ng, 6)), np.zeros((p.ng, 6, 6))
    cimp._law(p.lw(), u, on, p.ng, cimp.settings(), implicit_law.LAW_AND_DERIVATIVE, *one)
    lw = p.lw()
    two = np.zeros((p.ng, 6)), np.zeros((p.ng, 6, 6))
    cimp._law(lw, u * 0.5, on, p.ng, cimp.settings(), implicit_law.LAW_AND_DERIVATIVE, *two)
    cimp._law(lw, u, on, p.ng, cimp.settings(), implicit_law.LAW, *two)
    assert not np.array_equal(two[1], one[1])         # the law alone left the derivative at u / 2 in place
    cimp._law(lw, u, on, p.ng, cimp.settings(), implicit_law.DERIVATIVE_OF_LAST, *two)
    assert np.abs(one[1]).max() > 0.0
    assert np.array_equal(two[0], one[0]) and np.array_equal(two[1], one[1])


@pytest.mark.parametrize("seed", range(6))
def test_implicit_wrenches_match_the_numpy_solve(seed):
    """Random groups, mobility (light and heavy), motions and loads: the compiled solve gives the numpy
    reference's wrenches, rest flags and end twists (the same algorithm; its round-off goes through the
    Newton iterations' stopping test, so the agreement is that of the Newton tolerance at worst)."""
    p = Problem(seed)
    rng = np.random.default_rng(seed)
    j = rng.normal(size=(6 * p.ng, 6 * p.ng + 2))
    mob = j @ j.T * 10.0 ** rng.uniform(-1, 3)
    dt = 0.002
    twist = rng.normal(scale=0.02, size=(p.ng, 6))
    push = rng.normal(scale=5.0, size=6 * p.ng)
    push[2::6] -= 10.0
    free = twist + dt * (mob @ push).reshape(p.ng, 6)
    radius = np.full(p.ng, 0.08)
    for prior in (None, rng.random(p.ng) < 0.5):
        w_ref, rest_ref, end_ref, its_ref = implicit.implicit_wrenches(free, mob, p.numpy_law, twist, radius, dt,
                                                                       prior)
        w, rest, end, probe = (np.zeros((p.ng, 6)), np.zeros(p.ng, dtype=np.bool_), np.zeros((p.ng, 6)),
                               np.zeros((p.ng, 6)))
        its = cimp.implicit_wrenches((free, mob, radius, dt, p.ng), p.lw(), twist,
                                     np.zeros(p.ng, np.bool_) if prior is None else prior, prior is not None,
                                     cimp.settings(), (w, rest, end), probe, np.zeros((p.ng, 6)),
                                     np.zeros((p.ng, 6, 6)), solve_work(p.ng))
        np.testing.assert_array_equal(rest, rest_ref)
        assert its == its_ref
        scale = np.abs(w_ref).max()
        np.testing.assert_allclose(w, w_ref, rtol=0, atol=1e-7 * scale)
        np.testing.assert_allclose(end, end_ref, rtol=0, atol=1e-7 * np.abs(free).max())


@pytest.mark.parametrize("jacobian", ["dense", "sparse"])
@pytest.mark.parametrize("name", ["joint_limit", "contact", "weld_friction", "elliptic"])
def test_constrained_system_matches_the_numpy_linearization(name, jacobian):
    """H and f of this step's constraints linearized, dense and sparse constraint Jacobians, against
    reference.constrained_free_motion (+ the implicit damping term of reference.implicit_free)."""
    from test_implicit import SCENES
    xml = SCENES["contact"].replace("<option timestep='0.002'/>", "<option timestep='0.002' cone='elliptic'/>") \
        if name == "elliptic" else SCENES[name]
    m = mujoco.MjModel.from_xml_string(xml)
    m.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE if jacobian == "sparse" else mujoco.mjtJacobian.mjJAC_DENSE
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    m.dof_damping[:] = 0.3
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    d.xfrc_applied[1:] = rng.normal(scale=0.2, size=(m.nbody - 1, 6))
    for _ in range(150):
        mujoco.mj_step(m, d)
    mujoco.mj_fwdPosition(m, d)
    mujoco.mj_fwdVelocity(m, d)
    assert d.nefc > 0 and bool(mujoco.mj_isSparse(m)) == (jacobian == "sparse")
    qfrc = rng.normal(size=m.nv)
    h_ref, f_ref, _ = reference.constrained_free_motion(m, d, qfrc)
    dt, damping = m.opt.timestep, reference.velocity_damping(m)
    h_ref = h_ref + dt * np.diag(damping)
    h, f = np.zeros((m.nv, m.nv)), qfrc.copy()
    zones = np.empty(d.nefc, np.int64)
    efc = efc_arrays(d)
    mass = (m.M_rowadr.astype(np.int64), m.M_rownnz.astype(np.int64), m.M_colind.astype(np.int64), d.M)
    csys.row_zones(m.nv, jacobian == "sparse", efc, d.qacc, zones, False, zones)
    csys.constrained_system(m.nv, mass, jacobian == "sparse", efc, zones, True, damping, dt, h, f)
    np.testing.assert_allclose(h, h_ref, rtol=1e-12, atol=1e-12 * np.abs(h_ref).max())
    np.testing.assert_allclose(f, f_ref, rtol=1e-12, atol=1e-12 * np.abs(f_ref).max())
    # the zones again at other accelerations, from zones with every dry friction saturated one way or the other
    # (the rule of a later zone pass: a saturated friction stays while its force keeps sign and bound)
    rows = reference.constraint_rows(m, d)
    friction = np.isin(d.efc_type[:d.nefc], [int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF),
                                            int(mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON)])
    assert friction.any() == (name == "weld_friction")
    for trial in range(6):
        prev = np.where(friction, 2 + trial % 2, zones)
        prev_ref = (prev == 1, np.where(prev >= 2, np.where(prev == 2, 1.0, -1.0) * d.efc_frictionloss[:d.nefc], 0.0))
        qacc = d.qacc + rng.normal(scale=10.0 ** (trial // 2 - 1), size=m.nv)
        got = np.empty(d.nefc, np.int64)
        csys.row_zones(m.nv, jacobian == "sparse", efc, qacc, prev, True, got)
        quad, const = reference.constraint_zones(m, d, rows, qacc, prev_ref)
        np.testing.assert_array_equal(got == 1, quad)
        np.testing.assert_array_equal(np.where(got == 2, 1.0, np.where(got == 3, -1.0, 0.0)) * d.efc_frictionloss[
            :d.nefc], const)
    h2, f2 = np.zeros((m.nv, m.nv)), qfrc.copy()       # lagged: the mass matrix alone
    csys.constrained_system(m.nv, mass, jacobian == "sparse", efc, zones, False, damping, dt, h2, f2)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    np.testing.assert_array_equal(h2, full)
    np.testing.assert_array_equal(f2, qfrc)


SAND_SCENES = {   # scene of tests/test_implicit.py: (bodies with sand, sand height m, steps)
    "joint_limit": (["foot"], 0.0, 300),
    "contact": (None, 0.02, 200),
    "weld_friction": (None, 0.08, 200),
}


def _run(xml, bodies, height, steps, backend, integrator=None):
    """qpos, qvel and the diagnostics (force, torque, RFT force, depth, counts, resting) of each step."""
    m = mujoco.MjModel.from_xml_string(xml)
    if integrator is not None:
        m.opt.integrator = integrator
    d = mujoco.MjData(m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = rft_mujoco.attach(m, "li_loose_glass_beads", bodies=bodies, surface_height=height, resolution=0.01,
                              solve="implicit", backend=backend)
    try:
        assert h.backend == backend
        out = {k: [] for k in ("qpos", "qvel", "force", "torque", "rft_force", "max_depth", "submerged", "resting",
                               "occluded_area")}
        for _ in range(steps):
            mujoco.mj_step(m, d)
            diag = h.diagnostics(d)
            out["qpos"].append(d.qpos.copy())
            out["qvel"].append(d.qvel.copy())
            for k in list(out)[2:]:
                out[k].append(np.array(getattr(diag, k), dtype=float))
        return {k: np.array(v) for k, v in out.items()}
    finally:
        h.detach()


TOLERANCE = dict(qpos=1e-8, qvel=1e-6, force=1e-4, torque=1e-4, rft_force=1e-4, max_depth=1e-9, submerged=0.0,
                 resting=0.0, occluded_area=1e-12)
"""Agreement of the compiled implicit simulation with the numpy one: positions to 1e-8 m, velocities to 1e-6 m/s
(the bodies move at up to ~1 m/s), wrenches to 1e-4 of the scene's largest (torques: of its largest force times
5 cm; a sphere's torques are round-off), counts and rest flags exactly. The two run the same algorithms in a
different summation order: while their Newton solves take the same iterations they agree to round-off
(measured 1e-10 of the wrenches); where the residual lies within round-off of the stopping test (NEWTON_RTOL of
the step's twist change) one backend takes one iteration more, and the answers differ by up to the Newton
tolerance (measured in weld_friction with implicitfast: up to 1.9e-7 m/s, 1.2e-5 of the force and 7.6e-5 of
the torque scale, in single steps, not growing; positions 1.1e-9 m)."""


@pytest.mark.parametrize("integrator", ["Euler", "implicitfast", "RK4"])
@pytest.mark.parametrize("name", sorted(SAND_SCENES))
def test_compiled_and_numpy_implicit_simulations_agree(name, integrator):
    from test_implicit import SCENES
    bodies, height, steps = SAND_SCENES[name]
    kind = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
    ref = _run(SCENES[name], bodies, height, steps, "numpy", kind)
    new = _run(SCENES[name], bodies, height, steps, "numba", kind)
    assert np.abs(ref["force"]).max() > 0.1 and ref["resting"].any() and ref["submerged"].max() > 10
    for key, tol in TOLERANCE.items():
        scale = np.abs(ref[key]).max() if key in ("force", "rft_force") else 1.0
        scale = max(np.abs(ref[key]).max(), 0.05 * np.abs(ref["force"]).max()) if key == "torque" else scale
        err = np.abs(new[key] - ref[key]).max()
        print(name, integrator, key, err / scale)
        assert err <= tol * scale, (key, err, scale)


def test_compiled_and_numpy_implicit_glide_agree():
    """tests/test_implicit.py's heavy trunk on light slanted shins, set on the sand moving: the first 0.3 s on
    both backends (the flow, the stop and the rest while it is carried)."""
    from test_implicit import _glide
    xs_ref, resting_ref, z_ref = _glide("implicit", "numpy", 150)
    xs, resting, z = _glide("implicit", "numba", 150)
    assert xs_ref[-1] > 0.01                              # it slid before it stopped
    np.testing.assert_allclose(xs, xs_ref, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(resting, resting_ref)
    assert abs(z - z_ref) < 1e-9


def test_compiled_and_numpy_implicit_agree_on_a_heightfield():
    """The terrain's general depth (a sloped heightfield) in the compiled candidates pass."""
    from test_implicit import SCENES
    hills = rft_mujoco.HeightfieldSurface(np.array([[0.0, 0.04], [0.01, 0.03]]), (-1, 1), (-1, 1))
    ref = _run(SCENES["contact"], None, hills, 150, "numpy")
    new = _run(SCENES["contact"], None, hills, 150, "numba")
    assert np.abs(ref["force"]).max() > 0.1 and ref["submerged"].max() > 10
    for key, tol in TOLERANCE.items():
        scale = np.abs(ref[key]).max() if key in ("force", "rft_force") else 1.0
        scale = max(np.abs(ref[key]).max(), 0.05 * np.abs(ref["force"]).max()) if key == "torque" else scale
        assert np.abs(new[key] - ref[key]).max() <= tol * scale, key


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_copy_of_the_data_continues_bit_for_bit(backend):
    """mj_copyData mid-run, while a loaded body flows: the copy (with a copy of the implicit solve's buffers and
    of the groups that flowed, which set where its solve starts, not its answer) and the original step on
    alike (docs/architecture.md, "State and copies")."""
    from test_implicit import SCENES
    m = mujoco.MjModel.from_xml_string(SCENES["weld_friction"])
    d = mujoco.MjData(m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = rft_mujoco.attach(m, "li_loose_glass_beads", surface_height=0.08, resolution=0.01, solve="implicit",
                              backend=backend)
        try:
            for _ in range(20):
                mujoco.mj_step(m, d)
            diag = h.diagnostics(d)
            assert ((diag.submerged > 0) & ~diag.resting).any()
            assert h.counters(d).newton_iterations >= 1           # a body flows: the solve iterates
            c = mujoco.MjData(m)
            mujoco.mj_copyData(c, m, d)
            for _ in range(30):
                mujoco.mj_step(m, d)
                mujoco.mj_step(m, c)
            np.testing.assert_array_equal(c.qpos, d.qpos)
            np.testing.assert_array_equal(c.qvel, d.qvel)
            assert h.counters(c) == h.counters(d)
        finally:
            h.detach()
