"""The rest treatment's pure functions (rft_mujoco.physics.rest) against plain, independent computations."""

import numpy as np
import pytest

from rft_mujoco.physics import rest


def random_mobility(rng, n_groups, rank=None):
    """A (6G, 6G) symmetric PSD mobility ``J M^-1 J^T`` of ``rank`` (default full)."""
    n = 6 * n_groups
    j = rng.normal(size=(n, rank or n))
    m_inv = np.diag(rng.uniform(0.5, 2.0, j.shape[1]))
    return j @ m_inv @ j.T


# --- pivoted_solve --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 6, 12, 24])
def test_pivoted_solve_equals_a_direct_solve_on_well_conditioned_systems(n):
    rng = np.random.default_rng(n)
    a = random_mobility(rng, 1)[:1, :1] + 1.0 if n == 1 else random_mobility(rng, n // 6) + np.eye(n)
    b = rng.normal(size=n)
    np.testing.assert_allclose(rest.pivoted_solve(a, b, np.ones(b.size), rest.DEPENDENT_TOL, 1e-300), np.linalg.solve(a, b),
                               rtol=1e-9, atol=1e-12)


def test_pivoted_solve_is_the_minimum_norm_solution_of_a_rank_deficient_system():
    """Rank 18 of 24 (four feet on 18 dofs), consistent right-hand side (as free twists are): every row
    holds and the solution is numpy's minimum-norm one."""
    rng = np.random.default_rng(3)
    a = random_mobility(rng, 4, rank=18)
    b = a @ rng.normal(size=24)
    x = rest.pivoted_solve(a, b, np.ones(b.size), rest.DEPENDENT_TOL, 1e-300)
    np.testing.assert_allclose(a @ x, b, rtol=0, atol=1e-8 * np.abs(b).max())
    np.testing.assert_allclose(x, np.linalg.pinv(a, rcond=1e-10) @ b, rtol=1e-6, atol=1e-9 * np.abs(x).max())


def test_pivoted_solve_leaves_out_nearly_implied_rows_instead_of_huge_solutions():
    """A row that is implied by the others up to 1e-6 of its mobility is left out: the solution stays of
    the size of the data, where an exact solve would be a million times larger."""
    rng = np.random.default_rng(4)
    j = rng.normal(size=(3, 6))
    j = np.vstack([j, j[0] + j[1] + 1e-3 * rng.normal(size=6)])   # row 3 ~ row 0 + row 1
    a = j @ j.T
    b = rng.normal(size=4)
    exact = np.linalg.solve(a, b)
    x = rest.pivoted_solve(a, b, np.ones(b.size), rest.DEPENDENT_TOL, 1e-300)
    assert np.abs(exact).max() > 1e4 * np.abs(x).max()
    held = np.abs(a @ x - b) <= 1e-9 * np.abs(b).max()
    assert held.sum() == 3                          # three rows held exactly, the nearly implied one left out


def test_pivoted_solve_shares_in_proportion_to_the_weights():
    """Two rows tied to one degree of freedom: the load splits as the weights."""
    a = np.ones((2, 2))
    x = rest.pivoted_solve(a, np.array([3.0, 3.0]), np.array([1.0, 2.0]), rest.DEPENDENT_TOL, 1e-300)
    np.testing.assert_allclose(x, [1.0, 2.0])


def test_pivoted_solve_skips_rows_without_mobility():
    a = np.diag([2.0, 0.0, 4.0])
    x = rest.pivoted_solve(a, np.array([2.0, 5.0, 8.0]), np.ones(3), rest.DEPENDENT_TOL, 1e-300)
    np.testing.assert_allclose(x, [1.0, 0.0, 2.0])


# --- blend -----------------------------------------------------------------------------------------------
def test_blend_is_the_free_twist_at_rest_and_the_twist_in_flow():
    radius = np.array([0.1])
    free = np.array([[0.0, 0.0, -0.02, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(rest.blend(np.zeros((1, 6)), free, radius), free)
    for ratio in (10.0, 100.0):
        twist = np.array([[0.02 * ratio, 0.0, 0.0, 0.0, 0.0, 0.0]])
        u = rest.blend(twist, twist + free, radius)
        cos = u[0, :3] @ twist[0, :3] / np.linalg.norm(u[0, :3]) / np.linalg.norm(twist[0, :3])
        assert 1.0 - cos < 2.0 / ratio**6, "the direction must be the published one to (s/v)^3"


def test_twist_speed_counts_rotation_over_the_radius():
    np.testing.assert_allclose(rest.twist_speed(np.array([[3.0, 4.0, 0.0, 0.0, 0.0, 2.0]]), np.array([0.5])), [6.0])


# --- rest_wrenches ---------------------------------------------------------------------------------------
def one_body(mass=2.0, inertia=0.01):
    """A free rigid body: mobility diag(1/m, 1/I)."""
    return np.diag([1 / mass] * 3 + [1 / inertia] * 3)


def test_a_body_within_capacity_stops_in_one_step():
    dt, a = 0.002, one_body()
    free = np.array([[0.01, 0.0, -0.03, 0.0, 0.2, 0.0]])            # the load pushes down, sideways, rolls
    rft = np.array([[-50.0, 0.0, 200.0, 0.0, -3.0, 0.0]])             # a large resistance to that motion
    w, resting = rest.rest_wrenches(free, a, rft, free, np.array([0.1]), dt)
    assert resting[0]
    np.testing.assert_allclose(free[0] + dt * a @ w[0], 0.0, atol=1e-12)


def test_a_load_above_capacity_flows_with_the_published_wrench():
    dt, a = 0.002, one_body(mass=2.0)
    free = np.array([[0.0, 0.0, -2.0, 0.0, 0.0, 0.0]])              # falling fast: stopping needs 2000 N
    rft = np.array([[0.0, 0.0, 30.0, 0.0, 0.0, 0.0]])
    w, resting = rest.rest_wrenches(free, a, rft, free, np.array([0.1]), dt)
    assert not resting[0]
    np.testing.assert_allclose(w, rft)                              # the published wrench, unscaled


def test_flow_never_overshoots_and_positive_power_is_dropped():
    dt, a = 0.002, one_body(mass=2.0)
    radius = np.array([0.1])
    # A capacity test that fails (the sand resists little along u) while the RFT impulse would reverse the
    # motion in its own direction: the factor stops at the kinetic-energy minimum.
    free = np.array([[0.01, 0.0, -0.01, 0.0, 0.0, 0.0]])
    rft = np.array([[-2000.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    w, resting = rest.rest_wrenches(free, a, rft, np.array([[0.0, 0.0, -1.0, 0.0, 0.0, 0.0]]), radius, dt)
    assert not resting[0]
    v_after = free[0] + dt * a @ w[0]
    assert v_after[0] == pytest.approx(0.0, abs=1e-12)              # stopped along the wrench, not reversed
    # The fit's artefact: a wrench along the motion (positive power) is not applied.
    w, _ = rest.rest_wrenches(free, a, -rft, np.array([[0.0, 0.0, -1.0, 0.0, 0.0, 0.0]]), radius, dt)
    np.testing.assert_allclose(w, 0.0)


def test_rest_capacity_is_the_resistance_along_the_impending_motion():
    """A sideways pull equal to the weight on a 1 kg body whose sand lifts strongly but drags weakly. The
    stop wrench (-9.81, 0, 9.81) N resists 13.9 N along the impending (45 deg down-sideways) motion; the
    sand resists 11.3 N there, so the body flows, although the RFT wrench is larger than the stop wrench
    in norm (15.0 against 13.9 N). With more drag (17.7 N along the motion) it rests."""
    dt, g = 0.002, 9.81
    a = one_body(mass=1.0)
    free = np.array([[g * dt, 0.0, -g * dt, 0.0, 0.0, 0.0]])
    weak = np.array([[-1.0, 0.0, 15.0, 0.0, 0.0, 0.0]])
    assert np.linalg.norm(weak) > np.sqrt(2.0) * g
    _, resting = rest.rest_wrenches(free, a, weak, free, np.array([0.1]), dt)
    assert not resting[0]
    strong = np.array([[-10.0, 0.0, 15.0, 0.0, 0.0, 0.0]])
    w, resting = rest.rest_wrenches(free, a, strong, free, np.array([0.1]), dt)
    assert resting[0]
    np.testing.assert_allclose(w[0, :3], [-g, 0.0, g], rtol=1e-9)


def test_coupled_groups_rest_together():
    """Two bodies rigidly tied (same mobility rows twice): neither alone can hold the load, together they
    can; the solve shares it and stops both."""
    dt = 0.002
    one = one_body(mass=2.0)
    a = np.block([[one, one], [one, one]])                          # two groups of one rigid body
    free = np.array([[0.0, 0.0, -9.81 * dt, 0.0, 0.0, 0.0]] * 2)
    rft = np.array([[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]] * 2)           # 15 N each, 19.6 N needed
    w, resting = rest.rest_wrenches(free, a, rft, free, np.array([0.1, 0.1]), dt)
    assert resting.all()
    np.testing.assert_allclose(w[:, 2].sum(), 2.0 * 9.81, rtol=1e-6)
    np.testing.assert_allclose(free[0] + dt * one @ (w[0] + w[1]), 0.0, atol=1e-9)


@pytest.mark.parametrize("seed", range(40))
def test_the_sand_never_adds_kinetic_energy(seed):
    """Random groups, mobilities, free twists and RFT wrenches (including the fit's tensile/forward
    artefacts): the kinetic-energy change of the stacked impulse, dt W.Vf + dt^2 W.A.W / 2, is never
    positive."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))
    dt = 10.0 ** rng.uniform(-3.5, -2)
    a = random_mobility(rng, n, rank=int(rng.integers(1, 6 * n + 1)))
    free = rng.normal(size=(n, 6)) * 10.0 ** rng.uniform(-3, 0)
    rft = rng.normal(size=(n, 6)) * 10.0 ** rng.uniform(0, 3)
    u = free + rng.normal(size=(n, 6)) * 0.1 * np.abs(free).max()
    w, _ = rest.rest_wrenches(free, a, rft, u, rng.uniform(0.02, 0.3, n), dt)
    flat = w.reshape(-1)
    gain = dt * flat @ free.reshape(-1) + 0.5 * dt * dt * flat @ a @ flat
    assert gain <= 1e-12 * (abs(dt * flat @ free.reshape(-1)) + 1e-300)


def test_unloaded_groups_get_nothing_and_shapes_are_checked():
    dt, a = 0.002, one_body()
    w, resting = rest.rest_wrenches(np.ones((1, 6)), a, np.zeros((1, 6)), np.ones((1, 6)), np.array([0.1]), dt)
    assert not resting[0] and np.all(w == 0.0)
    with pytest.raises(ValueError, match="mobility"):
        rest.rest_wrenches(np.ones((2, 6)), a, np.ones((2, 6)), np.ones((2, 6)), np.array([0.1, 0.1]), dt)


def test_a_barely_touching_group_beside_a_loaded_one_stays_finite():
    """Capacities 1e-4 N and 10 N on two coupled groups (measured in SandQuadruped-v0: the unfloored
    capacity weights made the rest solve singular and the wrench NaN)."""
    rng = np.random.default_rng(5)
    a = random_mobility(rng, 2, rank=9)
    free = (a @ rng.normal(size=12)).reshape(2, 6) * 1e-2
    rft = np.vstack([rng.normal(size=6) * 1e-4, rng.normal(size=6) * 10.0])
    w, _ = rest.rest_wrenches(free, a, rft, free, np.array([0.03, 0.03]), 0.002)
    assert np.all(np.isfinite(w))


# --- the factor kept for the later stages of an RK4 step --------------------------------------------------
def test_pivoted_factor_then_apply_is_pivoted_solve_bit_for_bit():
    rng = np.random.default_rng(7)
    a = random_mobility(rng, 4, rank=14)
    rhs, weight = a @ rng.normal(size=24), rng.uniform(0.5, 2.0, 24)
    order, g, w = rest.pivoted_factor(a, weight, rest.DEPENDENT_TOL, 1e-300)
    assert 0 < order.size <= 14
    assert np.array_equal(rest.pivoted_apply(a, rhs, order, g, w),
                          rest.pivoted_solve(a, rhs, weight, rest.DEPENDENT_TOL, 1e-300))


def coupled_feet(rng, n_groups=3):
    """Feet on one trunk: a rank-deficient mobility, free twists in its range, capacities far above the
    load (every group rests)."""
    j = rng.normal(size=(6 * n_groups, 6 + 2 * n_groups)) * 0.3
    a = j @ j.T
    free = (j @ rng.normal(size=j.shape[1])).reshape(n_groups, 6) * 0.01
    rft = -free * 1e4
    return a, free, rft


def test_a_kept_factor_stops_the_resting_groups_with_new_free_twists():
    """Stages 2-4: the kept factor (made with other capacities) and new free twists still give wrenches
    that hold every kept rest row of the kept mobility; with the inputs it was made from, the very same
    wrenches as without keeping."""
    rng = np.random.default_rng(3)
    a, free, rft = coupled_feet(rng)
    dt, radius = 0.002, np.full(3, 0.05)
    keep = rest.StepFactor()
    w1, resting1 = rest.rest_wrenches(free, a, rft, free, radius, dt, keep)
    assert resting1.all() and keep.rest is not None
    w0, _ = rest.rest_wrenches(free, a, rft, free, radius, dt)
    assert np.array_equal(w1, w0)
    again, _ = rest.rest_wrenches(free, a, rft, free, radius, dt, keep, reuse=True)
    assert np.array_equal(again, w0)
    free2 = free * 1.3 + (a @ rng.normal(size=a.shape[0])).reshape(free.shape) * 1e-3   # in the range of a
    rft2 = rft * rng.uniform(0.5, 2.0, size=(3, 1))                                      # other capacities
    factor = keep.factor
    w2, resting2 = rest.rest_wrenches(free2, a, rft2, free2, radius, dt, keep, reuse=True)
    assert resting2.all() and keep.factor is factor                  # reused, not made again
    end = free2.reshape(-1) + dt * a @ w2.reshape(-1)                # the groups' twists after the step
    assert np.abs(end).max() < 2e-3 * np.abs(free2).max()            # held to the factor's row tolerance
    fresh, _ = rest.rest_wrenches(free2, a, rft2, free2, radius, dt)
    assert not np.array_equal(w2, fresh)                             # the weights are the kept ones


def test_a_kept_factor_is_not_used_for_other_resting_groups():
    rng = np.random.default_rng(4)
    a, free, rft = coupled_feet(rng)
    dt, radius = 0.002, np.full(3, 0.05)
    keep = rest.StepFactor()
    rest.rest_wrenches(free, a, rft, free, radius, dt, keep)
    rft_one_off = rft.copy()
    rft_one_off[1] = 0.0                                             # group 1 no longer loaded: other rows
    w, resting = rest.rest_wrenches(free, a, rft_one_off, free, radius, dt, keep, reuse=True)
    fresh, fresh_resting = rest.rest_wrenches(free, a, rft_one_off, free, radius, dt)
    assert np.array_equal(resting, fresh_resting) and not resting[1]
    assert np.array_equal(w, fresh)


# --- locked_rest: dofs held by their dry friction --------------------------------------------------------
def locked_system(seed, nv=7, groups=2, locks=(1, 4)):
    """A random mass matrix, Jacobians, forces and the lock matrices C, S, y of ``locks``."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(nv, nv))
    mass = q @ q.T + nv * np.eye(nv)
    jac = rng.normal(size=(6 * groups, nv))
    qvel, qfrc = rng.normal(size=nv), rng.normal(size=nv) * 5
    minv = np.linalg.inv(mass)
    e = np.eye(nv)[list(locks)]
    return dict(minv=minv, jac=jac, qvel=qvel, qfrc=qfrc, e=e, coupling=jac @ minv @ e.T, gram=e @ minv @ e.T,
                acc=e @ minv @ qfrc, free=(jac @ (qvel + 0.01 * minv @ qfrc)).reshape(groups, 6),
                mobility=jac @ minv @ jac.T)


def test_locked_rest_solves_with_the_projected_motion_and_returns_what_it_solved():
    """After the unlocked solve, the rest solve gets the twists and mobility of the motion with the locked
    dofs held: ``P = M^-1 - M^-1 E^T S^-1 E M^-1`` (computed here directly); a lock within capacity holds."""
    s = locked_system(0)
    p = s["minv"] - s["minv"] @ s["e"].T @ np.linalg.inv(s["gram"]) @ s["e"] @ s["minv"]
    seen = []
    w_out = np.full((2, 6), 0.1)

    def solve(free, mob):
        seen.append((free, mob))
        return w_out, np.array([True, False])
    w, resting, locked = rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"], s["acc"],
                                          np.zeros(2), np.full(2, 1e6), 0.01, solve, np.zeros((2, 6)), np.ones(2))
    assert len(seen) == 2 and locked.all() and w is w_out and resting[0] and not resting[1]
    assert seen[0][0] is s["free"] and seen[0][1] is s["mobility"]
    free, mob = seen[1]
    np.testing.assert_allclose(free.reshape(-1), s["jac"] @ (s["qvel"] + 0.01 * p @ s["qfrc"]), rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(mob, s["jac"] @ p @ s["jac"].T, rtol=1e-12, atol=1e-12)


def test_a_lock_the_friction_cannot_hold_is_released_and_the_unlocked_solve_kept():
    """lam = -S^-1 (y + C^T W) is the extra friction force the lock needs; over capacity, the dof is
    released, and with no lock left the unlocked solve is the answer (not solved again; here it takes energy
    from the motion with the dof held, the next test the other case)."""
    s = locked_system(1, locks=(2,))
    w_out = -1e-3 * (s["free"].reshape(-1) - 0.01 * s["coupling"] @ np.linalg.solve(s["gram"], s["acc"])).reshape(2, 6)
    lam = -np.linalg.solve(s["gram"], s["acc"] + s["coupling"].T @ w_out.reshape(-1))
    calls = []

    def solve(free, mob):
        calls.append(mob)
        return w_out, np.ones(2, dtype=bool)
    for force, cap, held in ((0.0, abs(lam[0]) * 1.01, True), (0.0, abs(lam[0]) * 0.99, False),
                             (-lam[0], 1e-9, True)):       # the lagged force already does it
        calls.clear()
        _, _, locked = rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"], s["acc"],
                                        np.array([force]), np.array([cap]), 0.01, solve, np.zeros((2, 6)), np.ones(2))
        assert len(calls) == 2 and bool(locked[0]) == held
    np.testing.assert_allclose(calls[1], s["mobility"] - s["coupling"] @ np.linalg.solve(s["gram"], s["coupling"].T),
                               rtol=1e-10, atol=1e-12)


def test_a_released_dof_slips_at_its_bound_where_the_lagged_force_would_add_energy():
    """A released dof keeps the lagged force unless the answer would add kinetic energy to the motion with the
    dofs held (``A_l``, ``Vf_l``: what MuJoCo's friction does where the answer leaves it within its bound); then
    the locks are tried again with each released dof slipping, its friction at the bound in the direction the
    lock needed (the free twists move by ``dt C (sign(force + lam) capacity - force)``). Issue 26: the lagged
    force let the sand pull down a foot that MuJoCo's friction then held to the falling trunk."""
    s = locked_system(1, locks=(2,))
    held = s["free"].reshape(-1) - 0.01 * s["coupling"] @ np.linalg.solve(s["gram"], s["acc"])
    for sign, slips in ((-1.0, False), (1.0, True)):          # against the held motion, then along it
        w_out = sign * 1e-3 * held.reshape(2, 6)
        need = 0.3 - np.linalg.solve(s["gram"], s["acc"] + s["coupling"].T @ w_out.reshape(-1))[0]
        cap = 0.5 * abs(need)                                   # the lock needs twice the bound: released
        calls = []

        def solve(free, mob):
            calls.append((free, mob))
            return w_out, np.ones(2, dtype=bool)
        _, _, locked = rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"], s["acc"], np.array([0.3]),
                                        np.array([cap]), 0.01, solve, np.zeros((2, 6)), np.ones(2), check=False)
        assert not locked[0] and len(calls) == (4 if slips else 2)
    free, mob = calls[3]
    assert mob is s["mobility"]
    np.testing.assert_allclose(free.reshape(-1), s["free"].reshape(-1) + 0.01 * s["coupling"][:, 0] *
                               (np.sign(need) * cap - 0.3), rtol=1e-12, atol=1e-12)


def test_no_lock_where_the_unlocked_solve_already_holds_the_dofs():
    """When the friction MuJoCo would add under the unlocked wrenches moves no group by more than
    LOCK_TOL of its step's twist change, the unlocked solve is the answer (one solve, nothing locked);
    just above it, or without the check, the lock is tried."""
    s = locked_system(2, locks=(3,))
    w_u = np.zeros((2, 6))
    lam = -np.linalg.solve(s["gram"], s["acc"])
    moved = rest.twist_speed((-0.01 * s["coupling"] @ lam).reshape(2, 6), np.ones(2))
    change = rest.twist_speed(s["free"], np.ones(2))
    ratio = (moved / change).max()
    for factor, n_calls in ((1.01, 1), (0.99, 2)):
        calls = []

        def solve(free, mob):
            calls.append(1)
            return w_u, np.ones(2, dtype=bool)
        tol_ratio = ratio * factor / rest.LOCK_TOL       # scale the twist change so that moved/change = ratio / factor
        _, _, locked = rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"], s["acc"], np.zeros(1),
                                        np.full(1, 1e6), 0.01, solve, s["free"] - s["free"] * tol_ratio, np.ones(2))
        assert len(calls) == n_calls and bool(locked[0]) == (n_calls == 2)
    calls = []                                           # check=False (a dof locked last time): tried anyway
    _, _, locked = rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"], s["acc"], np.zeros(1),
                                    np.full(1, 1e6), 0.01, lambda f, m: calls.append(1) or (w_u, np.ones(2, bool)),
                                    np.zeros((2, 6)) + s["free"] * 0.5, np.ones(2), check=False)
    assert len(calls) == 2 and locked[0]


def test_locked_rest_checks_shapes():
    s = locked_system(2)
    with pytest.raises(ValueError, match="coupling"):
        rest.locked_rest(s["free"], s["mobility"], s["coupling"], s["gram"][:1], s["acc"], np.zeros(2),
                         np.ones(2), 0.01, lambda f, m: None, np.zeros((2, 6)), np.ones(2))


def test_friction_estimate_is_the_unsaturated_row_force():
    d, aref, acc = np.array([2.0, 0.5]), np.array([1.0, -4.0]), np.array([0.25, -2.0])
    np.testing.assert_allclose(rest.friction_estimate(d, aref, acc), [1.5, -1.0])
