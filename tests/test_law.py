"""The 3D-RFT stress law (rft_mujoco.physics.law) against a slow reference and the model's known properties.

Source of the model and of every golden value here: Agarwal, Goldman & Kamrin, PNAS 120 (2023)
e2214017120 (SI Table S3), restated in ../shared/reference/3d-rft.md.

The reference below is written independently of law.py, in the paper's *local cylindrical frame*
(tilt beta, twist psi, attack angle gamma), one element at a time with ``math``; law.py uses the
frame-free vector form ``f1 n' + f2 v + f3 g``. The two must agree to round-off.
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rft_mujoco.physics import law
from rft_mujoco.physics.law import Guards, alpha_gen, element_forces, stress_per_depth
from rft_mujoco.physics.media import DEM_GLASS_BEADS, MPM_VALIDATION, Media

G = (0.0, 0.0, -9.81)
G_HAT = np.array([0.0, 0.0, -1.0])
MEDIA = MPM_VALIDATION
PROPERTY = settings(max_examples=200, deadline=None)

# Table S3 transcribed from ../shared/reference/3d-rft.md (golden data; the library reads its own copy
# in rft_mujoco/data/agarwal2023_table_s3.csv, compared below). Rows k = 1..20: (c1, c2, c3).
TABLE_S3 = (
    (0.00212, -0.06796, -0.02634),    # 1
    (-0.02320, -0.10941, -0.03436),   # x1
    (-0.20890, 0.04725, 0.45256),     # x2
    (-0.43083, -0.06914, 0.00835),    # x3
    (-0.00259, -0.05835, 0.02553),    # x1^2
    (0.48872, -0.65880, -1.31290),    # x2^2
    (-0.00415, -0.11985, -0.05532),   # x3^2
    (0.07204, -0.25739, 0.06790),     # x1 x2
    (-0.02750, -0.26834, -0.16404),   # x2 x3
    (-0.08772, 0.02692, 0.02287),     # x3 x1
    (0.01992, -0.00736, 0.02927),     # x1^3
    (-0.45961, 0.63758, 0.95406),     # x2^3
    (0.40799, 0.08997, -0.00131),     # x3^3
    (-0.10107, 0.21069, -0.11028),    # x1 x2^2
    (-0.06576, 0.04748, 0.01487),     # x2 x1^2
    (0.05664, 0.20406, -0.02730),     # x2 x3^2
    (-0.09269, 0.18589, 0.10911),     # x3 x2^2
    (0.01892, 0.04934, -0.04097),     # x3 x1^2
    (0.01033, 0.13527, 0.07881),      # x1 x3^2
    (0.15120, -0.33207, -0.27519),    # x1 x2 x3
)


# =================================================================================================
# Slow reference: the paper's local-frame angle form, per element, plain Python
# =================================================================================================
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _scale(k, a):
    return (k * a[0], k * a[1], k * a[2])


def _add(*vectors):
    return tuple(sum(c) for c in zip(*vectors))


def _norm(a):
    return math.sqrt(_dot(a, a))


def _unit(a):
    return _scale(1.0 / _norm(a), a)


def _horizontal(a, z):
    return _add(a, _scale(-_dot(a, z), z))


def ref_f(x1, x2, x3, table=TABLE_S3):
    """f1, f2, f3: the cubic polynomials of Table S3, terms written out in the table's order."""
    t = (1.0, x1, x2, x3, x1 * x1, x2 * x2, x3 * x3, x1 * x2, x2 * x3, x3 * x1,
         x1 ** 3, x2 ** 3, x3 ** 3, x1 * x2 ** 2, x2 * x1 ** 2, x2 * x3 ** 2, x3 * x2 ** 2, x3 * x1 ** 2,
         x1 * x3 ** 2, x1 * x2 * x3)
    return tuple(sum(table[k][i] * t[k] for k in range(20)) for i in range(3))


def ref_local_frame(n, v, g_hat):
    """The element's cylindrical frame and angles.

    z is against gravity; r is along the horizontal part of the velocity (of n' when the velocity is
    vertical; any horizontal direction when both are vertical); theta = z x r. n' is n flipped so that
    g.n' >= 0 (exactly vertical elements: so that n'.v >= 0). Then, with n' = sin(beta) cos(psi) r +
    sin(beta) sin(psi) theta - cos(beta) z and v = cos(gamma) r - sin(gamma) z:
    beta in [-pi/2, pi/2] (cos(beta) = g.n' >= 0), psi in [-pi/2, pi/2] (sign of sin(beta) carries the
    sign of n'.r), gamma in [-pi/2, pi/2] (cos(gamma) = |v_horizontal| >= 0).
    """
    z = _scale(-1.0, g_hat)
    gn = _dot(g_hat, n)
    if gn > 0.0:
        n_prime = n
    elif gn < 0.0:
        n_prime = _scale(-1.0, n)
    else:                                   # exactly vertical element: tie-break n'.v >= 0
        n_prime = n if _dot(n, v) >= 0.0 else _scale(-1.0, n)
    v_h = _horizontal(v, z)
    n_h = _horizontal(n_prime, z)
    if _norm(v_h) > 0.0:
        r = _unit(v_h)
    elif _norm(n_h) > 0.0:                  # vertical velocity: r along the horizontal part of the normal
        r = _unit(n_h)
    else:                                   # horizontal plate moving vertically: any horizontal r
        helper = (1.0, 0.0, 0.0) if abs(z[0]) < 0.9 else (0.0, 1.0, 0.0)
        r = _unit(_horizontal(helper, z))
    theta = _cross(z, r)
    h_r, h_t = _dot(n_prime, r), _dot(n_prime, theta)
    s = 1.0 if h_r >= 0.0 else -1.0
    beta = math.atan2(s * math.hypot(h_r, h_t), _dot(g_hat, n_prime))
    psi = math.atan2(s * h_t, abs(h_r))     # +-pi/2 when n'_h is perpendicular to r (not 0!)
    gamma = math.atan2(_dot(g_hat, v), max(_dot(v, r), 0.0))
    return (r, theta, z), (beta, psi, gamma)


def ref_alpha_gen(n, v, g_hat, table=TABLE_S3):
    """alpha_gen (world frame, tuple) from the paper's local-frame angle form."""
    (r, theta, z), (beta, psi, gamma) = ref_local_frame(n, v, g_hat)
    x1 = math.sin(gamma)
    x2 = math.cos(beta)
    x3 = math.cos(psi) * math.cos(gamma) * math.sin(beta) + math.sin(gamma) * math.cos(beta)
    f1, f2, f3 = ref_f(x1, x2, x3, table)
    a_r = f1 * math.sin(beta) * math.cos(psi) + f2 * math.cos(gamma)
    a_theta = f1 * math.sin(beta) * math.sin(psi)
    a_z = -f1 * math.cos(beta) - f2 * math.sin(gamma) - f3
    return _add(_scale(a_r, r), _scale(a_theta, theta), _scale(a_z, z))


def ref_xi_n(media, g_mag):
    mu = media.mu_int
    return media.rho_c * g_mag * (894.0 * mu ** 3 - 386.0 * mu ** 2 + 89.0 * mu)


def ref_stress(n, v, media, gravity=G, table=TABLE_S3):
    """alpha = xi_n [alpha_n_gen + min(mu_surf |alpha_n_gen| / |alpha_t_gen|, 1) alpha_t_gen], N/m^3."""
    g_mag = _norm(gravity)
    g_hat = _scale(1.0 / g_mag, gravity)
    n, v = _unit(n), _unit(v)
    a = ref_alpha_gen(n, v, g_hat, table)
    a_n = _dot(a, n)
    a_t = _add(a, _scale(-a_n, n))
    t = _norm(a_t)
    cap = min(media.mu_surf * abs(a_n) / t, 1.0) if t > 0.0 else 0.0
    return _scale(ref_xi_n(media, g_mag), _add(_scale(a_n, n), _scale(cap, a_t)))


def ref_element_forces(centroids, normals, areas, velocities, media, surface_height=0.0, gravity=G):
    """Loop over elements: zero above the surface, at rest or trailing (n.v < 0); else alpha |z| dA."""
    g_hat = _unit(gravity)
    out = []
    for c, n, a, v in zip(centroids, normals, areas, velocities):
        c, n, v = tuple(map(float, c)), tuple(map(float, n)), tuple(map(float, v))
        depth = surface_height + _dot(c, g_hat)
        if depth <= 0.0 or _norm(v) == 0.0 or a == 0.0 or _dot(_unit(n), _unit(v)) < 0.0:
            out.append((0.0, 0.0, 0.0))
            continue
        out.append(_scale(depth * a, ref_stress(n, v, media, gravity)))
    return np.array(out).reshape(-1, 3)


# =================================================================================================
# helpers
# =================================================================================================
def assert_rows_close(actual, expected, rtol=1e-9, atol=0.0):
    """Row-wise vector comparison: |a - b| <= rtol * max(|a|, |b|) + atol for every row."""
    actual, expected = np.atleast_2d(actual), np.atleast_2d(expected)
    assert actual.shape == expected.shape
    err = np.linalg.norm(actual - expected, axis=1)
    scale = np.maximum(np.linalg.norm(actual, axis=1), np.linalg.norm(expected, axis=1))
    bad = err > rtol * scale + atol
    assert not np.any(bad), (f"{np.count_nonzero(bad)} rows differ, worst relative error "
                             f"{np.max(err / np.maximum(scale, 1e-300)):.3g}\n{actual[bad][:3]}\n{expected[bad][:3]}")


def random_units(rng, k):
    x = rng.normal(size=(k, 3))
    return x / np.linalg.norm(x, axis=1)[:, None]


def random_leading(rng, k, g_hat=G_HAT, margin=1e-3):
    """k random (normal, direction) pairs, uniform on the sphere, leading (n.v > margin), not vertical."""
    n, v = random_units(rng, 4 * k + 100), random_units(rng, 4 * k + 100)
    keep = (np.einsum("ij,ij->i", n, v) > margin) & (np.abs(n @ g_hat) > margin)
    n, v = n[keep][:k], v[keep][:k]
    assert len(n) == k
    return n, v


def from_angles(beta, psi, gamma):
    """n' and v in the frame r = x, theta = y, z = up (gravity -z)."""
    n = (math.sin(beta) * math.cos(psi), math.sin(beta) * math.sin(psi), -math.cos(beta))
    v = (math.cos(gamma), 0.0, -math.sin(gamma))
    return np.array([n]), np.array([v])


def rotation(q):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _normalized(a):
    a = np.array(a)
    a[np.abs(a) < 1e-100] = 0.0          # no subnormal components (scaling them by 2^k is inexact)
    return a / np.linalg.norm(a)


unit_vectors = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1).map(_normalized)
quaternions = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)
betas = st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)     # not exactly vertical
psis = st.floats(-math.pi, math.pi)
gammas = st.floats(-math.pi / 2, math.pi / 2)


# =================================================================================================
# 0. the reference itself and the coefficient table
# =================================================================================================
def test_coefficient_table_matches_reference_document():
    assert law.COEFFICIENTS.shape == (20, 3)
    np.testing.assert_array_equal(law.COEFFICIENTS, np.array(TABLE_S3))
    assert not law.COEFFICIENTS.flags.writeable


def test_cubic_terms_order():
    x1, x2, x3 = np.array([0.3]), np.array([-0.7]), np.array([0.2])
    for i in range(3):
        assert (law.cubic_terms(x1, x2, x3) @ law.COEFFICIENTS)[0, i] == pytest.approx(
            ref_f(0.3, -0.7, 0.2)[i], rel=1e-13, abs=1e-15)


@PROPERTY
@given(beta=st.floats(-math.pi / 2 + 0.01, math.pi / 2 - 0.01).filter(lambda b: abs(b) > 0.01),
       psi=st.floats(-math.pi / 2 + 0.01, math.pi / 2 - 0.01), gamma=st.floats(-math.pi / 2 + 0.01, math.pi / 2 - 0.01))
def test_reference_frame_recovers_the_angles(beta, psi, gamma):
    """Self-check of the reference: angles -> (n', v) -> angles is the identity on the paper's ranges."""
    n, v = from_angles(beta, psi, gamma)
    (r, theta, z), angles = ref_local_frame(tuple(n[0]), tuple(v[0]), tuple(G_HAT))
    np.testing.assert_allclose(angles, (beta, psi, gamma), atol=1e-9)
    np.testing.assert_allclose([r, theta, z], np.eye(3), atol=1e-12)


def test_side_face_twist_is_pi_over_two():
    """A face whose horizontal normal is perpendicular to the motion (side of a sliding box): psi = +-pi/2.

    There x1 = x2 = x3 = 0, so f_i = c_i1 and alpha_gen = (f2, f1, -f3) exactly (r = x, theta = y).
    The public mistake psi = 0 would give (f1 + f2, 0, -f3): a different force.
    """
    _, (beta, psi, gamma) = ref_local_frame((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), tuple(G_HAT))
    assert (abs(beta), abs(psi), gamma) == (math.pi / 2, math.pi / 2, 0.0)
    c1, c2, c3 = TABLE_S3[0]
    expected = np.array([[c2, c1, -c3]])
    assert_rows_close(ref_alpha_gen((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), tuple(G_HAT)), expected, rtol=1e-14)
    assert_rows_close(alpha_gen(np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), G_HAT), expected,
                      rtol=1e-14)
    # tilted side faces (n' has a vertical part, n'.r = 0) with psi = +-pi/2 too: law == reference
    for b in (0.3, 1.0, -0.7):
        n = np.array([[0.0, math.sin(b), -math.cos(b)]])
        v = np.array([[1.0, 0.0, -0.4]]) / math.hypot(1.0, 0.4)
        _, (_, psi, _) = ref_local_frame(tuple(n[0]), tuple(v[0]), tuple(G_HAT))
        assert abs(psi) == pytest.approx(math.pi / 2, abs=1e-15)
        assert_rows_close(alpha_gen(n, v, G_HAT), ref_alpha_gen(tuple(n[0]), tuple(v[0]), tuple(G_HAT)),
                          rtol=1e-12)


# =================================================================================================
# 1. the fast path agrees with the reference
# =================================================================================================
def test_stress_matches_reference_random_leading():
    rng = np.random.default_rng(20230501)
    n, v = random_leading(rng, 2000)
    for media in (MEDIA, DEM_GLASS_BEADS, MEDIA.replace(mu_surf=0.1)):
        fast = stress_per_depth(n, v, media, G)
        slow = np.array([ref_stress(tuple(a), tuple(b), media) for a, b in zip(n, v)])
        assert_rows_close(fast, slow, rtol=1e-9)


def test_stress_matches_reference_tilted_gravity():
    rng = np.random.default_rng(7)
    for _ in range(5):
        g_hat = random_units(rng, 1)[0]
        gravity = 3.7 * g_hat
        n, v = random_leading(rng, 200, g_hat=g_hat)
        fast = stress_per_depth(n, v, MEDIA, gravity)
        slow = np.array([ref_stress(tuple(a), tuple(b), MEDIA, tuple(gravity)) for a, b in zip(n, v)])
        assert_rows_close(fast, slow, rtol=1e-9)


def test_stress_matches_reference_vertical_velocity():
    """v = +-z: the frame's r comes from the normal; also a horizontal plate moving vertically."""
    rng = np.random.default_rng(11)
    for v_dir in ((0.0, 0.0, -1.0), (0.0, 0.0, 1.0)):
        n = random_units(rng, 2000)
        n = n[(n @ np.array(v_dir) > 1e-3) & (np.abs(n[:, 2]) > 1e-3)][:500]
        n = np.vstack([n, [[0.0, 0.0, v_dir[2]]]])                # the plate itself
        v = np.tile(v_dir, (len(n), 1))
        fast = stress_per_depth(n, v, MEDIA, G)
        slow = np.array([ref_stress(tuple(a), tuple(b), MEDIA) for a, b in zip(n, v)])
        assert_rows_close(fast, slow, rtol=1e-9)


def test_stress_matches_reference_exactly_vertical_elements():
    """g.n == 0 exactly: both use the tie-break n'.v >= 0."""
    rng = np.random.default_rng(3)
    phi = rng.uniform(-math.pi, math.pi, 500)
    n = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
    v = random_units(rng, 500)
    v = v[np.abs(np.einsum("ij,ij->i", n, v)) > 1e-3]
    n = n[:len(v)]
    fast = alpha_gen(n, v, G_HAT)
    slow = np.array([ref_alpha_gen(tuple(a), tuple(b), tuple(G_HAT)) for a, b in zip(n, v)])
    assert_rows_close(fast, slow, rtol=1e-9)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors)
def test_stress_matches_reference_property(n, v):
    assume(abs(n[2]) > 1e-3 and abs(n @ v) > 1e-3)
    assert_rows_close(stress_per_depth(n[None], v[None], MEDIA, G), ref_stress(tuple(n), tuple(v), MEDIA),
                      rtol=1e-9)


def test_element_forces_match_reference():
    rng = np.random.default_rng(42)
    k = 1500
    n = random_units(rng, k) * rng.uniform(0.2, 3.0, (k, 1))             # any positive length
    v = random_units(rng, k) * rng.uniform(1e-4, 10.0, (k, 1))
    cos = np.einsum("ij,ij->i", n, v) / np.linalg.norm(n, axis=1) / np.linalg.norm(v, axis=1)
    keep = (np.abs(cos) > 1e-3) & (np.abs(n[:, 2]) > 1e-3)
    n, v = n[keep], v[keep]
    k = len(n)
    v[::17] = 0.0                                                        # some at rest
    centroids = rng.uniform(-0.3, 0.1, (k, 3))                           # some above the surface
    centroids[::23, 2] = 0.05                                            # exactly at the surface
    areas = rng.uniform(0.0, 1e-3, k)
    areas[::29] = 0.0
    fast = element_forces(centroids, n, areas, v, MEDIA, surface_height=0.05, gravity=G)
    slow = ref_element_forces(centroids, n, areas, v, MEDIA, surface_height=0.05)
    assert_rows_close(fast, slow, rtol=1e-9)
    # the fixture exercised every branch
    loaded = np.any(slow != 0.0, axis=1)
    assert 0.2 * k < np.count_nonzero(loaded) < 0.6 * k
    assert np.all(fast[~loaded] == 0.0)


# =================================================================================================
# 2. sanity values and the extraction plate
# =================================================================================================
@pytest.mark.parametrize("n, v, expected", [
    ((0, 0, -1), (0, 0, -1), (0.0, 0.0, 0.875)),     # plate pushed down: lift against the motion
    ((1, 0, 0), (1, 0, 0), (-0.19, 0.0, 0.075)),     # vertical plate dragged: drag + a little lift
    ((0, 0, 1), (0, 0, 1), (0.0, 0.0, -0.080)),      # plate pulled up
])
def test_sanity_values(n, v, expected):
    n, v = np.array([n], float), np.array([v], float)
    np.testing.assert_allclose(alpha_gen(n, v, G_HAT)[0], expected, atol=2e-3)
    np.testing.assert_allclose(ref_alpha_gen(tuple(n[0]), tuple(v[0]), tuple(G_HAT)), expected, atol=2e-3)
    # fully rough and mu_surf = mu_int: these three are within the friction cone, so alpha = xi_n alpha_gen
    np.testing.assert_allclose(stress_per_depth(n, v, MEDIA, G)[0] / MEDIA.xi_n, expected, atol=2e-3)


def test_extraction_plate_sanity():
    """A horizontal plate pulled straight up is held down, at ~2.5x its overburden weight (MPM media).

    The reference document's provenance section: with the correct table the extraction resistance is
    about 2.5 times the weight of the sand above the plate; the transcription variants k=16 of c3 =
    -0.20770 (plate pushed *up*: positive power) and +0.20770 (about ten times the overburden) are wrong.
    """
    depth, area = 0.1, 0.01
    f = element_forces([[0.0, 0.0, -depth]], [[0.0, 0.0, 1.0]], [area], [[0.0, 0.0, 0.05]], MEDIA)[0]
    assert f[0] == 0.0 and f[1] == 0.0
    assert f[2] < 0.0                                     # downward: negative power
    overburden = MEDIA.rho_c * 9.81 * depth * area
    ratio = -f[2] / overburden
    print(f"extraction resistance / overburden weight = {ratio:.3f}")
    assert 2.0 < ratio < 3.0

    def variant_ratio(c3_k16):
        table = [list(row) for row in TABLE_S3]
        table[15][2] = c3_k16
        a = ref_stress((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), MEDIA, table=table)
        return -a[2] / (MEDIA.rho_c * 9.81)

    assert variant_ratio(-0.02730) == pytest.approx(ratio, rel=1e-12)
    assert variant_ratio(-0.20770) < 0.0                  # pushed up by the sand: rejected transcription
    assert 8.0 < variant_ratio(0.20770) < 12.0            # ~10x overburden: rejected transcription


# =================================================================================================
# 3. properties
# =================================================================================================
@PROPERTY
@given(n=unit_vectors, v=unit_vectors, g=unit_vectors, q=quaternions)
def test_global_rotation_invariance(n, v, g, q):
    assume(abs(g @ n) > 1e-3)                              # the n' tie-break flips at vertical elements
    R = rotation(q)
    gravity = 9.81 * g
    a = stress_per_depth(n[None], v[None], MEDIA, gravity)[0]
    b = stress_per_depth((R @ n)[None], (R @ v)[None], MEDIA, R @ gravity)[0]
    assert_rows_close(b, R @ a, rtol=1e-9, atol=1e-12 * MEDIA.xi_n)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors, q=quaternions, depth=st.floats(0.001, 1.0))
def test_element_forces_rotation_invariance(n, v, q, depth):
    assume(abs(n[2]) > 1e-3 and n @ v > 1e-3)
    R = rotation(q)
    c = np.array([[0.01, -0.02, -depth]])
    f = element_forces(c, n[None], [1e-3], 0.2 * v[None], MEDIA, 0.0, G)[0]
    fr = element_forces(c @ R.T, (R @ n)[None], [1e-3], 0.2 * (R @ v)[None], MEDIA, 0.0, R @ np.array(G))[0]
    assert np.linalg.norm(f) > 0.0
    assert_rows_close(fr, R @ f, rtol=1e-9, atol=1e-12 * np.linalg.norm(f))


@PROPERTY
@given(beta=betas, psi=psis, gamma=gammas)
def test_twist_symmetry(beta, psi, gamma):
    """alpha_r and alpha_z are even in psi, alpha_theta is odd (frame r = x, theta = y, z = up)."""
    a = stress_per_depth(*from_angles(beta, psi, gamma), MEDIA, G)[0]
    b = stress_per_depth(*from_angles(beta, -psi, gamma), MEDIA, G)[0]
    assert_rows_close(b, a * np.array([1.0, -1.0, 1.0]), rtol=1e-12, atol=1e-13 * MEDIA.xi_n)
    ga = alpha_gen(*from_angles(beta, psi, gamma), G_HAT)[0]
    gb = alpha_gen(*from_angles(beta, -psi, gamma), G_HAT)[0]
    assert_rows_close(gb, ga * np.array([1.0, -1.0, 1.0]), rtol=1e-12, atol=1e-15)


@PROPERTY
@given(psi=psis, gamma=gammas)
def test_tilt_symmetry(psi, gamma):
    """beta = 0 (horizontal plate facing down): alpha_theta = 0 and no dependence on psi."""
    a = alpha_gen(*from_angles(0.0, psi, gamma), G_HAT)[0]
    a0 = alpha_gen(*from_angles(0.0, 0.0, gamma), G_HAT)[0]
    assert a[1] == 0.0
    assert_rows_close(a, a0, rtol=1e-14)
    s = stress_per_depth(*from_angles(0.0, psi, gamma), MEDIA, G)[0]
    assert abs(s[1]) <= 1e-15 * np.linalg.norm(s)


@PROPERTY
@given(beta=betas, gamma=gammas)
def test_in_plane_limit(beta, gamma):
    """psi = 0 (n, v, g coplanar): alpha_theta = 0."""
    a = stress_per_depth(*from_angles(beta, 0.0, gamma), MEDIA, G)[0]
    assert abs(a[1]) <= 1e-15 * np.linalg.norm(a)


@PROPERTY
@given(beta=betas, psi=psis, sign=st.sampled_from([1.0, -1.0]))
def test_vertical_motion_symmetry(beta, psi, sign):
    """gamma = +-pi/2: changing psi at fixed beta rotates the horizontal force by psi."""
    a0 = stress_per_depth(*from_angles(beta, 0.0, sign * math.pi / 2), MEDIA, G)[0]
    a = stress_per_depth(*from_angles(beta, psi, sign * math.pi / 2), MEDIA, G)[0]
    c, s = math.cos(psi), math.sin(psi)
    expected = np.array([c * a0[0] - s * a0[1], s * a0[0] + c * a0[1], a0[2]])
    assert_rows_close(a, expected, rtol=1e-9, atol=1e-12 * MEDIA.xi_n)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors, depth=st.floats(1e-3, 1.0), k=st.floats(0.01, 100.0))
def test_linear_in_depth_area_and_xi_n(n, v, depth, k):
    assume(n @ v > 1e-3)
    c = np.array([[0.1, 0.2, -depth]])
    base = element_forces(c, n[None], [2e-4], v[None], MEDIA)[0]
    assert np.linalg.norm(base) > 0.0
    deeper = element_forces(c * np.array([1.0, 1.0, k]), n[None], [2e-4], v[None], MEDIA)[0]
    bigger = element_forces(c, n[None], [2e-4 * k], v[None], MEDIA)[0]
    lifted = element_forces(c, n[None], [2e-4], v[None], MEDIA, surface_height=depth * (k - 1.0))[0]
    for f in (deeper, bigger, lifted):
        assert_rows_close(f, k * base, rtol=1e-9)
    # xi_n = rho_c |g| f_hat(mu_int): linear in rho_c and in |g|
    denser = element_forces(c, n[None], [2e-4], v[None], MEDIA.replace(rho_c=MEDIA.rho_c * 1.7))[0]
    assert_rows_close(denser, 1.7 * base, rtol=1e-12)
    heavier = element_forces(c, n[None], [2e-4], v[None], MEDIA, gravity=(0.0, 0.0, -9.81 * 1.3))[0]
    assert_rows_close(heavier, 1.3 * base, rtol=1e-12)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors, speed=st.floats(1e-6, 1e6), power=st.integers(-30, 30))
def test_independent_of_speed(n, v, speed, power):
    assume(n @ v > 1e-3)
    c, a = [[0.0, 0.0, -0.2]], [1e-3]
    ref = element_forces(c, n[None], a, v[None], MEDIA)
    np.testing.assert_array_equal(element_forces(c, n[None], a, (2.0 ** power) * v[None], MEDIA), ref)
    assert_rows_close(element_forces(c, n[None], a, speed * v[None], MEDIA), ref, rtol=1e-12)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors, height=st.floats(0.0, 10.0))
def test_zero_above_surface_exactly(n, v, height):
    # at the surface (depth 0) and above it
    out = element_forces([[0.3, -0.1, 0.5], [0.0, 0.0, 0.5 + height]], np.stack([n, n]), [1e-3, 1e-3],
                         np.stack([v, v]), MEDIA, surface_height=0.5)
    np.testing.assert_array_equal(out, 0.0)


@PROPERTY
@given(n=unit_vectors, v=unit_vectors)
def test_zero_for_trailing_elements_exactly(n, v):
    assume(n @ v < -2 * law.LEADING_TOL)
    out = element_forces([[0.0, 0.0, -0.3]], n[None], [1e-3], v[None], MEDIA)
    np.testing.assert_array_equal(out, 0.0)


def test_zero_speed_gives_exact_zeros_never_nan():
    rng = np.random.default_rng(5)
    n = random_units(rng, 50)
    c = np.column_stack([rng.normal(size=(50, 2)), -rng.uniform(0.01, 0.5, 50)])
    out = element_forces(c, n, np.full(50, 1e-3), np.zeros((50, 3)), MEDIA)
    np.testing.assert_array_equal(out, 0.0)
    tiny = element_forces(c, n, np.full(50, 1e-3), np.full((50, 3), law.ZERO_SPEED / 10), MEDIA)
    np.testing.assert_array_equal(tiny, 0.0)
    # a mix of resting and moving elements: moving ones still loaded, all finite
    v = np.zeros((50, 3))
    v[::2] = n[::2]
    out = element_forces(c, n, np.full(50, 1e-3), v, MEDIA)
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[1::2], 0.0)
    assert np.all(np.linalg.norm(out[::2], axis=1) > 0.0)
    # no elements at all
    assert element_forces(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), MEDIA).shape == (0, 3)


GOOD = dict(centroids=[[0.0, 0.0, -0.1]] * 2, normals=[[1.0, 0.0, 0.0]] * 2, areas=[1e-3, 1e-3],
            velocities=[[1.0, 0.0, 0.0]] * 2)


@pytest.mark.parametrize("field, value", [
    ("centroids", [[0.0, np.nan, -0.1], [0.0, 0.0, -0.1]]),
    ("normals", [[1.0, 0.0, 0.0], [np.inf, 0.0, 0.0]]),
    ("velocities", [[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0]]),
    ("areas", [1e-3, np.nan]),
    ("areas", [1e-3, -1e-3]),
    ("normals", [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
])
def test_bad_values_raise(field, value):
    with pytest.raises(ValueError):
        element_forces(**{**GOOD, field: value}, media=MEDIA)


@pytest.mark.parametrize("kwargs", [dict(surface_height=np.nan), dict(gravity=(0.0, 0.0, np.inf)),
                                    dict(gravity=(0.0, 0.0, 0.0))])
def test_bad_scalars_raise(kwargs):
    with pytest.raises(ValueError):
        element_forces(**GOOD, media=MEDIA, **kwargs)


@pytest.mark.parametrize("field, value, shape", [
    ("centroids", np.zeros((2, 2)), "(2, 2)"),
    ("centroids", np.zeros(3), "(3,)"),
    ("normals", np.ones((3, 3)), "(3, 3)"),
    ("velocities", np.ones((2, 3, 1)), "(2, 3, 1)"),
    ("areas", np.ones(3), "(3,)"),
])
def test_bad_shapes_raise_with_the_shape(field, value, shape):
    with pytest.raises(ValueError) as info:
        element_forces(**{**GOOD, field: value}, media=MEDIA)
    assert shape in str(info.value)


def test_bad_gravity_shape_raises():
    with pytest.raises(ValueError, match="gravity"):
        element_forces(**GOOD, media=MEDIA, gravity=(0.0, -9.81))


# =================================================================================================
# 4. the leading-edge rule at n.v = 0
# =================================================================================================
def cube(side, centre):
    normals = np.vstack([np.eye(3), -np.eye(3)])
    return centre + 0.5 * side * normals, normals, np.full(6, side * side)


def test_faces_parallel_to_the_motion_are_leading():
    """A submerged cube sliding sideways: its top (n.v = 0 exactly) is loaded, round-off or not."""
    c, n, a = cube(0.075, np.array([0.0, 0.0, -0.27]))
    v = np.tile([0.1, 0.0, 0.0], (6, 1))
    f = element_forces(c, n, a, v, MEDIA)
    top = f[2]
    assert np.linalg.norm(top) > 0.0
    depth_top = 0.27 - 0.0375
    assert_rows_close(top, stress_per_depth(n[2:3], v[2:3] / 0.1, MEDIA)[0] * depth_top * a[2], rtol=1e-14)
    assert_rows_close(f, ref_element_forces(c, n, a, v, MEDIA), rtol=1e-9)    # reference: n.v >= 0 leads
    np.testing.assert_array_equal(f[3], 0.0)                                   # the back face trails
    for k in (1, 2, 4, 5):                                                     # all four n.v = 0 faces
        assert np.linalg.norm(f[k]) > 0.0
    # round-off: n.v = -1e-15 or +1e-15 on the top face changes nothing beyond round-off
    for tilt in (-1e-15, 1e-15):
        n_round = np.array([[tilt, 0.0, 1.0]])
        assert float(n_round[0] @ np.array([1.0, 0.0, 0.0])) == tilt
        f_round = element_forces(c[2:3], n_round, a[2:3], v[2:3], MEDIA)[0]
        assert_rows_close(f_round, top, rtol=1e-9)
    # clearly trailing is not loaded
    assert np.all(element_forces(c[2:3], [[-10 * law.LEADING_TOL, 0.0, 1.0]], a[2:3], v[2:3], MEDIA) == 0.0)
    share = np.linalg.norm(f[[1, 2, 4, 5]].sum(axis=0)) / np.linalg.norm(f.sum(axis=0))
    print(f"cube sliding sideways: n.v = 0 faces carry {share:.0%} of |F| (sum of those faces / total)")


# =================================================================================================
# 5. the vertical tie-break and the drag jump across vertical
# =================================================================================================
def test_vertical_element_tie_break():
    """g.n = 0 exactly: n' is the sign of n with n'.v >= 0, continuous with the downward-facing side."""
    for v in ([[1.0, 0.0, 0.0]], [[1.0, 0.0, -1.0]], [[1.0, 0.0, 1.0]], [[0.6, 0.8, 0.0]]):
        v = np.array(v) / np.linalg.norm(v)
        plus = alpha_gen(np.array([[1.0, 0.0, 0.0]]), v, G_HAT)
        minus = alpha_gen(np.array([[-1.0, 0.0, 0.0]]), v, G_HAT)
        np.testing.assert_array_equal(plus, minus)                      # both use n' = +x (n'.v > 0)
        f1, f2, f3 = ref_f(float(v[0] @ G_HAT), 0.0, float(v[0, 0]))
        assert_rows_close(plus, f1 * np.array([1.0, 0.0, 0.0]) + f2 * v[0] + f3 * G_HAT, rtol=1e-13)
        # continuous with the element tilted to face slightly down (g.n > 0: n' = n, no flip)
        down = alpha_gen(np.array([[1.0, 0.0, -1e-9]]) / math.hypot(1.0, 1e-9), v, G_HAT)
        assert_rows_close(plus, down, rtol=1e-7)
    # below VERTICAL_TOL counts as vertical
    tiny = alpha_gen(np.array([[1.0, 0.0, law.VERTICAL_TOL / 2]]), np.array([[1.0, 0.0, 0.0]]), G_HAT)
    assert_rows_close(tiny, alpha_gen(np.array([[1.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), G_HAT),
                      rtol=1e-3)


def test_drag_jump_across_vertical():
    """The fit's n' flips across vertical: a vertical plate dragged sideways jumps ~20% in drag."""
    eps = 10 * law.VERTICAL_TOL
    v = np.array([[0.1, 0.0, 0.0]])
    c = [[0.0, 0.0, -0.2]]
    down = element_forces(c, [[1.0, 0.0, -eps]], [1e-3], v, MEDIA)[0]     # facing slightly down
    up = element_forces(c, [[1.0, 0.0, eps]], [1e-3], v, MEDIA)[0]        # facing slightly up
    exact = element_forces(c, [[1.0, 0.0, 0.0]], [1e-3], v, MEDIA)[0]
    jump = up[0] / down[0] - 1.0
    print(f"drag jump across vertical (v = +x): {jump:+.1%}  (drag {-down[0]:.4g} N -> {-up[0]:.4g} N)")
    assert 0.05 < jump < 0.40
    assert_rows_close(exact, down, rtol=1e-2)                             # tie-break side: n'.v >= 0


# =================================================================================================
# 6. artefacts of the fit: kept by default, guards zero them (never flip them), friction cap
# =================================================================================================
@pytest.fixture(scope="module")
def orientations():
    """100k random leading (n, v) pairs, uniform on the sphere, g = -z."""
    rng = np.random.default_rng(2023)
    n, v = random_units(rng, 240_000), random_units(rng, 240_000)
    keep = np.einsum("ij,ij->i", n, v) >= 0.0
    return n[keep][:100_000], v[keep][:100_000]


def _parts(alpha, n, v):
    a_n = np.einsum("ij,ij->i", alpha, n)
    a_t = alpha - a_n[:, None] * n
    return a_n, a_t, np.einsum("ij,ij->i", a_t, v), np.einsum("ij,ij->i", alpha, v)


def test_artefact_fractions_of_the_published_fit(orientations):
    n, v = orientations
    assert len(n) == 100_000
    a_n, _, a_tv, power = _parts(stress_per_depth(n, v, MEDIA, G), n, v)
    tensile, forward, positive = np.mean(a_n > 0), np.mean(a_tv > 0), np.mean(power > 0)
    print(f"published fit over 100k leading orientations: tensile {tensile:.2%}, forward tangential "
          f"{forward:.2%}, positive power {positive:.3%}")
    assert 0.03 < tensile < 0.07
    assert 0.02 < forward < 0.05
    assert 0.0001 < positive < 0.002
    g_n, _, g_tv, g_power = _parts(alpha_gen(n, v, G_HAT), n, v)      # same signs before the cap
    np.testing.assert_array_equal(g_n > 0, a_n > 0)
    np.testing.assert_array_equal(g_tv > 0, a_tv > 0)


def test_no_tension_guard_zeroes_never_reverses(orientations):
    n, v = orientations
    pub = stress_per_depth(n, v, MEDIA, G)
    grd = stress_per_depth(n, v, MEDIA, G, Guards(no_tension=True))
    tensile = np.einsum("ij,ij->i", pub, n) > 0
    assert tensile.any()
    # the tensile normal is set to zero, and the friction it allowed with it; not turned compressive
    np.testing.assert_array_equal(grd[tensile], 0.0)
    np.testing.assert_array_equal(grd[~tensile], pub[~tensile])


def test_no_forward_tangential_guard_zeroes_never_flips(orientations):
    n, v = orientations
    pub = stress_per_depth(n, v, MEDIA, G)
    grd = stress_per_depth(n, v, MEDIA, G, Guards(no_forward_tangential=True))
    p_n, _, p_tv, _ = _parts(pub, n, v)
    g_n, g_t, g_tv, _ = _parts(grd, n, v)
    forward = p_tv > 0
    assert forward.any()
    tol = 1e-12 * MEDIA.xi_n
    np.testing.assert_allclose(g_n, p_n, rtol=1e-12, atol=tol)          # normal part untouched
    assert np.all(np.linalg.norm(g_t[forward], axis=1) <= tol)          # tangential zeroed, not flipped
    np.testing.assert_array_equal(grd[~forward], pub[~forward])


def test_no_positive_power_guard(orientations):
    n, v = orientations
    pub = stress_per_depth(n, v, MEDIA, G)
    grd = stress_per_depth(n, v, MEDIA, G, Guards(no_positive_power=True))
    positive = np.einsum("ij,ij->i", pub, v) > 0
    assert positive.any()
    np.testing.assert_array_equal(grd[positive], 0.0)
    np.testing.assert_array_equal(grd[~positive], pub[~positive])


def test_all_guards_leave_no_artefact(orientations):
    n, v = orientations
    a_n, _, a_tv, power = _parts(stress_per_depth(n, v, MEDIA, G, Guards.all()), n, v)
    tol = 1e-12 * MEDIA.xi_n
    assert Guards.all() == Guards(True, True, True)
    assert np.all(a_n <= tol) and np.all(a_tv <= tol) and np.all(power <= tol)


def test_guards_do_not_change_clean_elements():
    """A plate pushed down has none of the artefacts: every guard leaves it alone."""
    n, v = np.array([[0.0, 0.0, -1.0]]), np.array([[0.3, 0.0, -1.0]]) / math.hypot(0.3, 1.0)
    np.testing.assert_array_equal(stress_per_depth(n, v, MEDIA, G, Guards.all()), stress_per_depth(n, v, MEDIA, G))


def test_friction_cap(orientations):
    n, v = orientations[0][:20_000], orientations[1][:20_000]
    for mu in (0.4, 0.2, 0.05):
        media = MEDIA.replace(mu_surf=mu)
        g_n, g_t, _, _ = _parts(alpha_gen(n, v, G_HAT), n, v)
        a_n, a_t, _, _ = _parts(stress_per_depth(n, v, media, G) / media.xi_n, n, v)
        t = np.linalg.norm(a_t, axis=1)
        capped = mu * np.abs(g_n) < np.linalg.norm(g_t, axis=1)
        assert capped.any() and (~capped).any()
        np.testing.assert_allclose(a_n, g_n, rtol=1e-12, atol=1e-15)     # the cap never touches the normal
        assert np.all(t <= mu * np.abs(a_n) * (1 + 1e-12) + 1e-15)
        np.testing.assert_allclose(t[capped], mu * np.abs(a_n[capped]), rtol=1e-9, atol=1e-15)
        assert_rows_close(a_t[~capped], g_t[~capped], rtol=1e-12, atol=1e-15)
        # the cap scales the tangential stress, never turns it
        cos = np.einsum("ij,ij->i", a_t[capped], g_t[capped]) / t[capped] / np.linalg.norm(g_t[capped], axis=1)
        assert np.all(cos[t[capped] > 1e-12] > 1 - 1e-9)


def test_frictionless_surface_gives_purely_normal_stress(orientations):
    n, v = orientations[0][:20_000], orientations[1][:20_000]
    media = Media(3000.0, 0.4, 0.0)
    alpha = stress_per_depth(n, v, media, G)
    a_n, a_t, _, _ = _parts(alpha, n, v)
    assert np.all(np.linalg.norm(a_t, axis=1) <= 1e-12 * np.abs(a_n) + 1e-15 * media.xi_n)
    np.testing.assert_allclose(a_n, media.xi_n * _parts(alpha_gen(n, v, G_HAT), n, v)[0], rtol=1e-12, atol=1e-6)
