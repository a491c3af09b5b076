"""The compiled kernels (rft_mujoco.compiled) against the numpy reference (rft_mujoco.physics.elements / law).

Agreement is to RTOL relative (round-off: the compiled loop sums in a different order than BLAS), on random
element sets, poses, velocities, guards and all three terrain types; then whole handles (rest treatment and
run-time culling included) with backend="numba" against backend="numpy".
"""

import itertools

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco import compiled
from rft_mujoco.physics import elements as kernel
from rft_mujoco.physics import law
from rft_mujoco.compiled import schema as compiled_schema
from rft_mujoco.coupling.evaluators import CompiledEvaluator, NumpyEvaluator
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion

from conftest import numpy_rollout

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="numba not importable")
if compiled.AVAILABLE:
    from rft_mujoco.compiled import element_pass as fastkernel
    from rft_mujoco.compiled import elements as packing
    from rft_mujoco.compiled import jit
    from rft_mujoco.compiled import law as fastlaw

RTOL = 1e-9
"""Relative agreement of compiled and numpy results, against the largest magnitude of the array."""
MEDIA = rft_mujoco.MPM_VALIDATION
GUARDS = [law.Guards(*flags) for flags in itertools.product((False, True), repeat=3)]


def bundled(c, n, a, eb, nb, pos, mat, com, *rest):
    """The arguments of both ``body_wrenches`` (numpy and compiled) from the flat arrays."""
    return (kernel.BodySurface(c, n, a, eb, nb), kernel.BodyPose(pos, mat, com), *rest)


def close(a, b, rtol=RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(np.abs(b).max(initial=0.0), 1e-300)
    return a.shape == b.shape and np.abs(a - b).max(initial=0.0) <= rtol * scale


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(n, 3, 3)


def terrains(rng):
    heights = 0.02 * rng.normal(size=(6, 7))
    hf = HeightfieldSurface(heights, (-0.3, 0.4), (-0.35, 0.3))
    return [FlatSurface(0.0), FlatSurface(0.013), hf, HeightfieldSurface(heights, (-0.2, 0.2), (-0.1, 0.3), "none"),
            SandRegion(FlatSurface(0.01), (-0.1, 0.25), (-0.2, 0.1)), SandRegion(hf, (-0.2, 0.3), (-0.3, 0.2))]


def random_problem(rng, n_bodies=4, n_elem=600):
    normals = rng.normal(size=(n_elem, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centroids = 0.05 * rng.normal(size=(n_elem, 3))
    areas = rng.uniform(1e-6, 1e-4, n_elem)
    elem_body = rng.integers(0, n_bodies, n_elem)
    body_pos = rng.uniform(-0.15, 0.15, (n_bodies, 3))
    body_pos[:, 2] = rng.uniform(-0.08, 0.03, n_bodies)
    body_mat = random_rotations(rng, n_bodies)
    body_com = body_pos + 0.01 * rng.normal(size=(n_bodies, 3))
    v_com = rng.normal(size=(n_bodies, 3)) * 0.2
    omega = rng.normal(size=(n_bodies, 3))
    return centroids, normals, areas, elem_body, body_pos, body_mat, body_com, v_com, omega


@pytest.mark.parametrize("seed", range(4))
def test_element_forces_match_law(seed):
    rng = np.random.default_rng(seed)
    n = 2000
    c = rng.normal(size=(n, 3)) * 0.1
    nrm = rng.normal(size=(n, 3)) * rng.uniform(0.5, 2.0, (n, 1))      # not unit: normalized inside
    v = rng.normal(size=(n, 3))
    v[::17] = 0.0                                                        # at rest
    a = rng.uniform(0.0, 1e-4, n)
    nrm[::23] = [0.0, 1.0, 0.0]                                          # exactly vertical elements
    v[::29] = np.cross(nrm[::29], [0.3, -0.2, 0.9])                      # n.v = 0 (sliding in plane)
    gravity = [(0.0, 0.0, -9.81), (0.5, -1.0, -7.0)][seed % 2]
    for guards in GUARDS:
        ref = law.element_forces(c, nrm, a, v, MEDIA, 0.02, gravity, guards=guards)
        got = fastlaw.element_forces(c, nrm, a, v, MEDIA, 0.02, gravity, guards=guards)
        assert close(got, ref)
        assert np.array_equal(got == 0.0, ref == 0.0)


def test_element_forces_errors_are_the_reference_errors():
    c = np.zeros((3, 3))
    with pytest.raises(ValueError, match="non-finite"):
        fastlaw.element_forces(c + [[np.nan, 0, 0]], c + 1, np.ones(3), c + 1, MEDIA)
    with pytest.raises(ValueError, match="areas"):
        fastlaw.element_forces(c, c + 1, -np.ones(3), c + 1, MEDIA)
    with pytest.raises(ValueError, match="zero normals"):
        fastlaw.element_forces(c, c, np.ones(3), c + 1, MEDIA)
    with pytest.raises(ValueError, match="shape"):
        fastlaw.element_forces(c[:, :2], c, np.ones(3), c + 1, MEDIA)


@pytest.mark.parametrize("field, value, message", [
    ("centroids", np.inf, "non-finite"), ("velocities", -np.inf, "non-finite"), ("normals", np.nan, "non-finite"),
    ("areas", np.nan, "areas"), ("areas", -1e-9, "areas")])
def test_element_forces_flags_bad_input_in_any_chunk(field, value, message):
    """One bad entry anywhere (here in the last, partial chunk) makes the compiled call raise the
    reference's error, whatever the kind of bad value."""
    rng = np.random.default_rng(3)
    n = 3 * fastlaw.CHUNK + 17
    arrays = dict(centroids=rng.normal(size=(n, 3)) * 0.1, normals=rng.normal(size=(n, 3)),
                  areas=rng.uniform(1e-6, 1e-5, n), velocities=rng.normal(size=(n, 3)))
    ok = fastlaw.element_forces(arrays["centroids"], arrays["normals"], arrays["areas"],
                                   arrays["velocities"], MEDIA)
    assert close(ok, law.element_forces(arrays["centroids"], arrays["normals"], arrays["areas"],
                                        arrays["velocities"], MEDIA))
    bad = arrays[field]
    bad[n - 5] = value
    with pytest.raises(ValueError, match=message):
        fastlaw.element_forces(arrays["centroids"], arrays["normals"], arrays["areas"],
                                  arrays["velocities"], MEDIA)


@pytest.mark.parametrize("seed", range(6))
def test_body_wrenches_match_numpy(seed):
    rng = np.random.default_rng(100 + seed)
    c, n, a, eb, pos, mat, com, vcom, om = random_problem(rng)
    g_hat = np.array([0.0, 0.0, -1.0])
    for terrain, guards in itertools.product(terrains(rng), GUARDS[::3]):
        args = bundled(c, n, a, eb, 4, pos, mat, com, vcom, om, terrain, g_hat, (0.0, 0.0, -9.81), MEDIA, guards)
        w_ref, cnt_ref, dep_ref = kernel.body_wrenches(*args)
        w, cnt, dep = fastkernel.body_wrenches(*args)
        assert close(w, w_ref), (terrain, guards)
        assert np.array_equal(cnt, cnt_ref)
        assert close(dep, dep_ref)
        assert cnt_ref.sum() > 0                                          # the case is not vacuous


def test_body_wrenches_tilted_gravity_and_slow_elements():
    rng = np.random.default_rng(7)
    c, n, a, eb, pos, mat, com, vcom, om = random_problem(rng, 3, 400)
    vcom[0] = 0.0
    om[0] = 0.0                                                           # body 0 at rest: zero force
    om[1] *= 1e-14                                                        # speeds near ZERO_SPEED
    vcom[1] *= 1e-14
    gravity = np.array([1.0, 2.0, -9.0])
    g_hat = gravity / np.linalg.norm(gravity)
    args = bundled(c, n, a, eb, 3, pos, mat, com, vcom, om, FlatSurface(0.02), g_hat, gravity, MEDIA,
            law.Guards.all())
    w_ref, cnt_ref, dep_ref = kernel.body_wrenches(*args)
    w, cnt, dep = fastkernel.body_wrenches(*args)
    assert close(w, w_ref) and np.array_equal(cnt, cnt_ref) and close(dep, dep_ref)
    assert cnt[0] == 0 and cnt[2] > 0


def test_clusters_wholly_partly_and_not_in_the_sand():
    """The compiled kernel sends a cluster wholly below flat sand through the law as it is and packs the
    submerged elements of one that crosses the surface: both equal the numpy reference."""
    rng = np.random.default_rng(11)
    n = 4000                                     # one tall body: ~31 clusters from 0.35 m deep to 0.1 m up
    c = np.column_stack([rng.uniform(-0.05, 0.05, n), rng.uniform(-0.05, 0.05, n), rng.uniform(-0.35, 0.1, n)])
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    areas = rng.uniform(1e-5, 1e-4, n)
    eb = np.zeros(n, dtype=np.int64)
    packed = packing.pack(c, nrm, areas, eb, 1)
    top = packed.cluster_center[:, 2] + packed.cluster_radius
    bottom = packed.cluster_center[:, 2] - packed.cluster_radius
    assert (top < 0.0).sum() >= 2 and ((bottom < 0.0) & (top > 0.0)).sum() >= 2     # both paths are taken
    for v in ([0.1, 0.0, -0.2], [0.0, 0.0, 0.3], [-0.2, 0.1, 0.05]):
        args = bundled(c, nrm, areas, eb, 1, np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), np.array([v]),
                np.array([[0.5, -1.0, 2.0]]), FlatSurface(0.0), np.array([0.0, 0.0, -1.0]), (0.0, 0.0, -9.81),
                MEDIA, law.PUBLISHED)
        w_ref, cnt_ref, dep_ref = kernel.body_wrenches(*args)
        w, cnt, dep = fastkernel.body_wrenches(*args)
        assert close(w, w_ref) and np.array_equal(cnt, cnt_ref) and close(dep, dep_ref)
        assert 0 < cnt[0] < n


def test_any_number_of_loaded_elements_takes_the_law_whole():
    """The law's loop runs over whole vectors (``element_pass.LAW_LANES``), padded with copies at zero depth and
    area: every count of loaded elements, each remainder modulo the vector included, and a full cluster whose
    count rounds up past the scratch's width, gives the reference's wrench and count."""
    rng = np.random.default_rng(23)
    for n, loaded in [(40, k) for k in range(1, 2 * fastkernel.LAW_LANES + 2)] + [(127, 127)]:
        z = np.where(np.arange(n) < loaded, -rng.uniform(0.001, 0.03, n), rng.uniform(0.001, 0.03, n))
        c = np.column_stack([rng.uniform(-0.02, 0.02, n), rng.uniform(-0.02, 0.02, n), z])
        nrm = rng.normal(size=(n, 3)) * 0.2 + [0.0, 0.0, -1.0]       # facing down: leading when moving down
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        args = bundled(c, nrm, rng.uniform(1e-5, 1e-4, n), np.zeros(n, dtype=np.int64), 1, np.zeros((1, 3)),
                       np.eye(3)[None], np.zeros((1, 3)), np.array([[0.02, -0.01, -0.1]]), np.array([[0.1, 0.2, 0.0]]),
                       FlatSurface(0.0), np.array([0.0, 0.0, -1.0]), (0.0, 0.0, -9.81), MEDIA, law.PUBLISHED)
        w_ref, cnt_ref, dep_ref = kernel.body_wrenches(*args)
        w, cnt, dep = fastkernel.body_wrenches(*args)
        assert cnt_ref[0] == loaded and np.array_equal(cnt, cnt_ref), (n, loaded)
        assert close(w, w_ref) and close(dep, dep_ref), (n, loaded)
        assert np.abs(w_ref).max() > 0.0


def test_heightfield_needs_vertical_gravity_in_both():
    rng = np.random.default_rng(3)
    c, n, a, eb, pos, mat, com, vcom, om = random_problem(rng, 2, 50)
    hf = terrains(rng)[2]
    g = np.array([0.6, 0.0, -0.8])
    args = bundled(c, n, a, eb, 2, pos, mat, com, vcom, om, hf, g, g * 9.81, MEDIA, law.PUBLISHED)
    for impl in (kernel.body_wrenches, fastkernel.body_wrenches):
        with pytest.raises(ValueError, match="gravity along -z"):
            impl(*args)


# --- the coupling with backend="numba" against backend="numpy" -----------------------------------------
SCENE = """
<mujoco>
  <option timestep="0.002" integrator="{integrator}"/>
  <worldbody>
    <body name="ball" pos="0 0 0.0">
      <freejoint/>
      <geom type="sphere" size="0.05" mass="1"/>
    </body>
    <body name="brick" pos="0.3 0 -0.02">
      <freejoint/>
      <geom type="box" size="0.04 0.03 0.02" euler="0.2 0.1 0" mass="0.5"/>
      <geom type="capsule" size="0.01 0.03" pos="-0.03 0 0.02" mass="0.1"/>
    </body>
    <body name="high" pos="0 0.5 1.0">
      <freejoint/>
      <geom type="ellipsoid" size="0.03 0.02 0.04" mass="0.3"/>
    </body>
    <body name="arm" pos="-0.3 0 0.05">
      <joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 -0.12" size="0.012" mass="0.2"/>
      <body name="hand" pos="0.1 0 -0.12">
        <joint type="hinge" axis="1 0 0"/>
        <geom type="cylinder" size="0.02 0.02" mass="0.1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def trajectory(integrator, terrain, stabilize, guards, steps=40, seed=0):
    """Full physics states along a sand rollout (numpy backend), one per step."""
    return numpy_rollout(SCENE.format(integrator=integrator), MEDIA, None, terrain, steps, 0.5, seed, guards=guards,
                         stabilize=stabilize)


def evaluate_states(model, states, backend, terrain, stabilize, guards):
    """xfrc_applied (user wrench on the ball + sand) and diagnostics after mj_forward at every state."""
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    xfrc, diags = [], []
    with rft_mujoco.attach(model, MEDIA, None, terrain, 0.01, guards=guards, stabilize=stabilize,
                           monitor=False, backend=backend) as handle:
        assert handle.backend == backend
        for i, state in enumerate(states):
            mujoco.mj_setState(model, data, state, spec)
            data.xfrc_applied[:] = 0.0
            if i % 2:
                data.xfrc_applied[1] = [0.0, 0.0, 3.0, 0.0, 0.01, 0.0]   # a user wrench on the ball
            mujoco.mj_forward(model, data)
            xfrc.append(data.xfrc_applied.copy())
            d = handle.diagnostics(data)
            diags.append(np.concatenate([d.force, d.torque, d.max_depth[:, None], d.scale[:, None],
                                         d.rft_force, d.occluded_area[:, None], d.submerged[:, None],
                                         d.resting[:, None]], axis=1))
    return np.array(xfrc), np.array(diags)


@pytest.mark.parametrize("integrator,stabilize,terrain_i", [
    ("Euler", True, 0), ("RK4", True, 2), ("implicitfast", False, 4), ("Euler", False, 5), ("Euler", True, 3)])
def test_attach_numba_equals_numpy(integrator, stabilize, terrain_i):
    """Both backends at the same states (along a rollout) write the same xfrc_applied and diagnostics, the
    rest treatment included (tests/test_compiled_rest.py compares its pieces)."""
    terrain = terrains(np.random.default_rng(11))[terrain_i]
    guards = law.Guards.all() if terrain_i % 2 else law.PUBLISHED
    model, states = trajectory(integrator, terrain, stabilize, guards)
    ref, dref = evaluate_states(model, states, "numpy", terrain, stabilize, guards)
    got, dgot = evaluate_states(model, states, "numba", terrain, stabilize, guards)
    assert np.abs(ref).max() > 0.1                                       # sand forces were applied
    assert np.count_nonzero(dref[:, :, -2]) > 10                         # on many bodies and states
    if terrain_i in (0, 3):                                               # the hand's cylinder hides the arm's end
        assert np.count_nonzero(dref[:, :, -3]) > 5
    for k in range(len(states)):                                          # each evaluation on its own scale
        assert close(got[k], ref[k]), k
        assert close(dgot[k], dref[k]), k


def test_unsupported_terrain_falls_back_to_numpy():
    class Bumpy:
        max_height = 0.0

        def depth(self, points, g_hat):
            return -points[:, 2] + 0.01 * np.sin(20 * points[:, 0])

    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    handle = rft_mujoco.SandHandle(model, MEDIA, [1], Bumpy(), 0.01, law.PUBLISHED, True, True,
                                   backend="auto")
    assert handle.backend == "numpy" and isinstance(handle.evaluator, NumpyEvaluator)
    assert handle.evaluator.spec is None and handle.evaluator.constants is None
    handle.terrain = rft_mujoco.FlatSurface(0.0)              # a terrain the kernels know: compiled again
    assert handle.backend == "numba" and isinstance(handle.evaluator, CompiledEvaluator)
    assert handle.evaluator.spec is not None and len(handle.evaluator.constants) == len(compiled_schema.HANDLE_FIELDS)
    handle.terrain = Bumpy()
    assert handle.backend == "numpy"
    with pytest.raises(ValueError, match="numba"):
        rft_mujoco.SandHandle(model, MEDIA, [1], Bumpy(), 0.01, law.PUBLISHED, True, True,
                               backend="numba")


def test_bad_backend_is_explained():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body>"
                                           "</worldbody></mujoco>")
    with pytest.raises(ValueError, match="backend must be"):
        rft_mujoco.attach(model, MEDIA, backend="fortran")


def test_without_numba_auto_is_numpy(monkeypatch):
    monkeypatch.setattr(jit, "AVAILABLE", False)
    monkeypatch.setattr(jit, "IMPORT_ERROR", "ImportError: simulated")
    model = mujoco.MjModel.from_xml_string(SCENE.format(integrator="Euler"))
    handle = rft_mujoco.attach(model, MEDIA, backend="auto", monitor=False)
    assert handle.backend == "numpy"
    handle.detach()
    with pytest.raises(ValueError, match="simulated"):
        rft_mujoco.attach(model, MEDIA, backend="numba")


def test_compile_notice_only_when_compiling(capsys):
    """ensure_compiled() is silent once the kernels are loaded (cache hit or earlier call)."""
    compiled.ensure_compiled()
    capsys.readouterr()
    assert compiled.ensure_compiled() == 0.0
    assert "compiling" not in capsys.readouterr().err
