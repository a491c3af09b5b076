"""The quasi-static references (rft_mujoco.studies.quasistatic): rest depths against a hand calculation of the
published law, and the swimmer's inertia-free limit (zero at zero amplitude, mirror symmetric, converged in
its time steps). Coarse settings, results cached in the module."""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np
import pytest

from rft_mujoco.physics.media import LI_LOOSE_GLASS_BEADS, f_hat
from rft_mujoco.studies import quasistatic as qs

# Coarse swimmer settings: 10 mm elements, 2 periods (the first ramps up), the last one measured.
COARSE = dict(element_size=0.01, cycles=2, measured_cycles=1)


@functools.lru_cache(maxsize=None)
def _swim(amplitude: float, steps: int, mirror: bool = False) -> dict:
    return qs.swimmer_limit(amplitude, 1.0, steps_per_cycle=steps, mirror=mirror, **COARSE)


def _table_coefficients() -> np.ndarray:
    """(20, 3) c1, c2, c3 of the paper's Table S3, read from the data file (not through law.py)."""
    from importlib import resources
    text = resources.files("rft_mujoco.physics.data").joinpath("agarwal2023_table_s3.csv").read_text()
    rows = [line.split(",") for line in text.splitlines() if line and not line.startswith(("#", "k,"))]
    return np.array([[float(c) for c in r[2:5]] for r in rows])


def _box_hand_lift(half, size: float, d: float, media) -> float:
    """Upward force (N) of the law on an axis-aligned box (half-extents ``half`` m, cut by
    :func:`rft_mujoco.geometry.surface.box` into ``size`` m elements) pushed straight down with its bottom ``d`` m
    below the surface, by hand from the coefficient table (not through law.py):

    * bottom face: n = v = g, so x1 = x2 = x3 = 1, every monomial is 1 and alpha = sum(c) n' (sum over all 60
      coefficients; n' = g = -z, so the lift per unit depth and area is -sum(c) ~ 0.875);
    * side faces: n horizontal, v = g, so x1 = 1, x2 = x3 = 0 (the monomials 1, x1, x1^2, x1^3) and
      alpha = f1 n + (f2 + f3) g: the normal part is horizontal (it cancels between opposite faces), the
      tangential part (f2 + f3) g is capped at mu_surf |f1|: lift -(f2 + f3) min(mu_surf |f1| / |f2 + f3|, 1);
    * top face: n . v = -1, trailing, no force.
    Each element: lift coefficient x xi_n x its centroid's depth x its area, when its centroid is submerged."""
    from rft_mujoco.geometry.surface import box
    c = _table_coefficients()
    xi = media.rho_c * 9.81 * f_hat(media.mu_int)
    bottom = -c.sum()
    f1, f2, f3 = c[[0, 1, 4, 10]].sum(axis=0)
    side = -(f2 + f3) * min(media.mu_surf * abs(f1) / abs(f2 + f3), 1.0)
    el = box(half, size)
    depth = d - half[2] - el.centroids[:, 2]            # the box centre at z = half_z - d
    nz = el.normals[:, 2]
    coef = np.where(nz < -0.5, bottom, np.where(nz > 0.5, 0.0, side))
    return float(xi * np.sum(coef * np.maximum(depth, 0.0) * el.areas * (depth > 0.0)))


def _box_model(half) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(
        f"<mujoco><worldbody><body name='b' pos='0 0 {half[2]}'><freejoint/><geom type='box' "
        f"size='{half[0]} {half[1]} {half[2]}' mass='1'/></body></worldbody></mujoco>")


@pytest.mark.parametrize("load", [2.0, 21.58, 100.0, 200.0])
def test_box_rest_depth_matches_hand_calculation(load):
    """The plate of the load-path scenes (10 x 10 x 1 cm, 10 mm elements): at the rest depth the hand-computed
    lift equals the load, and just above it is smaller (the first depth that carries it)."""
    half, size, media = (0.05, 0.05, 0.005), 0.01, LI_LOOSE_GLASS_BEADS
    d = qs.rest_depth_of(_box_model(half), "b", load, element_size=size, media=media)
    assert _box_hand_lift(half, size, d, media) == pytest.approx(load, rel=1e-4)
    assert _box_hand_lift(half, size, d - 1e-5, media) < load


def test_plate_alone_near_thin_plate_formula():
    """The 0.2 kg plate alone: depth ~ load / (alpha_z xi_n A) with alpha_z = -sum(c) ~ 0.875 (3d-rft.md's
    sanity value), a little less because the submerged strip of the side faces lifts too."""
    c = _table_coefficients()
    alpha_z = -c.sum()
    assert alpha_z == pytest.approx(0.875, abs=0.01)
    depth, load = qs.scene_rest_depth("plate_alone")
    assert load == pytest.approx(0.2 * 9.81)
    thin = load / (alpha_z * LI_LOOSE_GLASS_BEADS.rho_c * 9.81 * f_hat(LI_LOOSE_GLASS_BEADS.mu_int) * 0.01)
    assert 0.8 * thin < depth <= thin * (1 + 1e-6)


def test_sphere_rest_depth_grows_with_load():
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body name='s' pos='0 0 0.02'><freejoint/><geom type='sphere' size='0.02' "
        "mass='0.05'/></body></worldbody></mujoco>")
    depths = [qs.rest_depth_of(model, "s", load, element_size=0.005) for load in (0.5, 2.0, 8.0, 30.0)]
    assert depths[0] > 0.0
    assert all(b > a for a, b in zip(depths, depths[1:])), depths
    with pytest.raises(ValueError, match="load must be > 0"):
        qs.rest_depth_of(model, "s", 0.0)


def test_scene_depths_and_loads():
    """Every load-path scene has a load and a depth; the plates rest within their thickness, the foot deeper
    than its radius (its centre below the surface) under the 3 kg trunk."""
    from rft_mujoco.studies import loadpath_scenes
    d_contact, load_contact = qs.scene_rest_depth("contact")
    assert load_contact == pytest.approx(2.2 * 9.81)
    assert 0.0 < d_contact < 0.01
    d_foot, load_foot = qs.scene_rest_depth("joint_limit")
    assert load_foot == pytest.approx(3.05 * 9.81)
    assert d_foot > 0.02
    d_servo, load_servo = qs.scene_rest_depth("actuator_limit")
    assert load_servo == pytest.approx(loadpath_scenes.ACTUATOR_FORCE + 0.05 * 9.81)
    assert 0.0 < d_servo < d_foot
    with pytest.raises(ValueError, match="valid names"):
        qs.scene_rest_depth("nope")


def test_swimmer_limit_zero_at_zero_amplitude():
    r = _swim(0.0, 8)
    assert r["speed_mps"] == 0.0 and r["eta"] == 0.0 and r["solves"] > 0


def test_swimmer_limit_swims_and_balances():
    r = _swim(0.9, 8)
    assert r["forward_mps"] > 0.0 and r["eta"] > 0.05, r
    # the balance holds to the level of one element's force switching on (a jump of the discretized law)
    assert r["mean_residual"] < 1e-4 and r["max_residual"] < 1e-2, r
    assert 0.5 < r["exposed_area_fraction"] < 0.9, r     # neighbouring links hide part of each other


@pytest.mark.parametrize("t", [0.3, 1.45, 2.7])
def test_swimmer_balance_mirror_symmetric(t):
    """The mirrored wave (-q) at the mirrored pose gives the mirrored root velocity (vx, -vy, -omega_z)."""
    from rft_mujoco.physics.media import MALADEN_GLASS_BEADS
    sw = qs._Swimmer(0.01, True, MALADEN_GLASS_BEADS)
    q, qd = qs._serpenoid(t, 0.9, 1.0, sw.n_joints)
    scale = 0.9 * 2 * math.pi * sw.length
    root = np.array([0.01, -0.02, 0.3])
    u = qs._Newton(scale, sw.length, qs.REG_SPEED).solve(sw.pose(root, q, qd)[0], np.zeros(3))[0]
    mirrored = root * [1.0, -1.0, -1.0]
    m = qs._Newton(scale, sw.length, qs.REG_SPEED).solve(sw.pose(mirrored, -q, -qd)[0], np.zeros(3))[0]
    assert np.linalg.norm(u) > 1e-3
    np.testing.assert_allclose(m, u * [1.0, -1.0, -1.0], rtol=1e-5, atol=1e-7 * scale)


def test_swimmer_limit_converged_in_steps():
    coarse, fine = _swim(0.9, 8), _swim(0.9, 16)
    assert fine["eta"] == pytest.approx(coarse["eta"], rel=0.02)


def test_swimmer_balance_matches_body_wrenches():
    """The swimmer's balance (its own element pass, eps = 0) against the per-body law of
    physics.elements.body_wrenches mapped through MuJoCo's COM Jacobians: the generalized force on the root."""
    from rft_mujoco.physics import elements
    from rft_mujoco.physics.law import PUBLISHED
    from rft_mujoco.physics.media import MALADEN_GLASS_BEADS
    from rft_mujoco.physics.terrain import FlatSurface
    sw = qs._Swimmer(0.01, True, MALADEN_GLASS_BEADS)
    q, qd = qs._serpenoid(1.3, 0.9, 1.0, sw.n_joints)
    root, u = np.array([0.02, 0.01, 0.4]), np.array([0.01, -0.004, 0.3])
    residual, _ = sw.pose(root, q, qd)
    got, _ = residual(u, 0.0)
    m, d = sw.model, sw.data                       # posed by sw.pose
    d.qvel[:3], d.qvel[3:] = u, qd
    ids, b = sw.bodies.ids, sw.bodies
    jp, jr = qs._jacobians(m, d, ids)
    v, w = jp @ d.qvel, jr @ d.qvel
    surface = elements.BodySurface(b.centroids, b.normals, b.areas, b.elem_body, ids.size)
    pose = elements.BodyPose(d.xpos[ids], d.xmat[ids].reshape(-1, 3, 3), d.xipos[ids])
    wr, _, _ = elements.body_wrenches(surface, pose, v, w, FlatSurface(0.0), np.array([0.0, 0.0, -1.0]),
                                      m.opt.gravity, MALADEN_GLASS_BEADS, PUBLISHED, b.exposed(d))
    gen = np.einsum("bij,bi->j", jp, wr[:, :3]) + np.einsum("bij,bi->j", jr, wr[:, 3:])
    want = gen[:3] * [1.0, 1.0, 1.0 / sw.length]
    assert np.linalg.norm(want) > 0.1
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
