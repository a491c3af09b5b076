"""The public rft_mujoco.element_forces: the compiled kernel by default, the numpy reference on request,
the same forces (to RTOL) and the same errors either way."""

import ast
import itertools
import pathlib

import numpy as np
import pytest

import rft_mujoco
from rft_mujoco import forces
from rft_mujoco import compiled
from rft_mujoco.compiled import law as fastlaw
from rft_mujoco.physics import law

MEDIA = rft_mujoco.LI_LOOSE_GLASS_BEADS
RTOL = 1e-12
"""Agreement of each element's force with the reference, relative to the element's force scale
``xi_n |z| dA`` (the law's ``|alpha| / xi_n`` is of order 1). Relative to the element's own force it can be
larger where the fitted force nearly vanishes: measured 2.3e-11 at worst over 1e6 random elements, whose
force there was 3e-6 of its scale; against the scale the worst was 1.2e-15."""
COMPILED = [pytest.param(b, marks=pytest.mark.skipif(not compiled.AVAILABLE, reason="numba not importable"))
            for b in ("auto", "numba")]


def random_elements(rng, n=3000):
    c = rng.normal(size=(n, 3)) * 0.1
    nrm = rng.normal(size=(n, 3)) * rng.uniform(0.5, 2.0, (n, 1))       # not unit: normalized inside
    v = rng.normal(size=(n, 3)) * rng.uniform(1e-3, 3.0, (n, 1))
    v[::17] = 0.0                                                        # at rest
    nrm[::23] = [0.0, 1.0, 0.0]                                          # exactly vertical
    a = rng.uniform(0.0, 1e-4, n)
    return c, nrm, a, v


def force_scale(centroids, areas, surface_height=0.0, gravity=(0.0, 0.0, -9.81)):
    """(N,) N: ``xi_n |z| dA`` of each element (0 above the surface)."""
    g_hat, g_mag = law.gravity_direction(gravity)
    depth = np.maximum(surface_height + np.asarray(centroids) @ g_hat, 0.0)
    return MEDIA.xi_n_at(g_mag) * depth * np.asarray(areas)


def assert_rows_match(got, ref, scale):
    err = np.linalg.norm(got - ref, axis=1)
    assert np.all(err <= RTOL * scale), f"worst error {np.max(err / np.maximum(scale, 1e-300)):.3g} of the scale"
    np.testing.assert_array_equal(got == 0.0, ref == 0.0)


def test_the_public_function_is_the_dispatcher_and_law_stays_the_reference():
    assert rft_mujoco.element_forces is forces.element_forces
    assert law.element_forces is not forces.element_forces
    c, nrm, a, v = random_elements(np.random.default_rng(0), 50)
    np.testing.assert_array_equal(rft_mujoco.element_forces(c, nrm, a, v, MEDIA, backend="numpy"),
                                  law.element_forces(c, nrm, a, v, MEDIA))


@pytest.mark.parametrize("backend", COMPILED)
@pytest.mark.parametrize("seed", range(2))
def test_compiled_backends_give_the_reference_forces(backend, seed):
    rng = np.random.default_rng(seed)
    c, nrm, a, v = random_elements(rng)
    gravity = [(0.0, 0.0, -9.81), (0.5, -1.0, -7.0)][seed]
    for flags in itertools.product((False, True), repeat=3):
        guards = law.Guards(*flags)
        ref = law.element_forces(c, nrm, a, v, MEDIA, 0.02, gravity, guards=guards)
        got = rft_mujoco.element_forces(c, nrm, a, v, MEDIA, 0.02, gravity, guards=guards, backend=backend)
        assert_rows_match(got, ref, force_scale(c, a, 0.02, gravity))
    assert np.count_nonzero(ref[:, 2]) > 100, "the test loads many elements"


def test_the_default_runs_the_compiled_kernel(monkeypatch):
    if not compiled.AVAILABLE:
        pytest.skip("numba not importable")
    calls = []
    real = fastlaw.element_forces
    monkeypatch.setattr(fastlaw, "element_forces", lambda *a, **k: calls.append(1) or real(*a, **k))
    c, nrm, a, v = random_elements(np.random.default_rng(1), 10)
    rft_mujoco.element_forces(c, nrm, a, v, MEDIA)
    assert calls == [1]


def test_auto_falls_back_to_numpy_without_numba_and_numba_says_why(monkeypatch):
    monkeypatch.setattr(compiled, "AVAILABLE", False)
    monkeypatch.setattr(compiled, "IMPORT_ERROR", "ModuleNotFoundError: No module named 'numba'")
    c, nrm, a, v = random_elements(np.random.default_rng(2), 20)
    np.testing.assert_array_equal(rft_mujoco.element_forces(c, nrm, a, v, MEDIA), law.element_forces(c, nrm, a, v, MEDIA))
    with pytest.raises(ValueError, match=r"backend='numba' needs numba.*No module named 'numba'.*'auto' or 'numpy'"):
        rft_mujoco.element_forces(c, nrm, a, v, MEDIA, backend="numba")


def test_unknown_backend_lists_the_valid_ones():
    with pytest.raises(ValueError, match=r"backend must be one of \('auto', 'numba', 'numpy'\), got 'gpu'"):
        rft_mujoco.element_forces([[0.0, 0.0, -0.1]], [[0.0, 0.0, 1.0]], [1e-3], [[0.0, 0.0, 1.0]], MEDIA,
                                  backend="gpu")


GOOD = dict(centroids=[[0.0, 0.0, -0.1]] * 2, normals=[[1.0, 0.0, 0.0]] * 2, areas=[1e-3, 1e-3],
            velocities=[[1.0, 0.0, 0.0]] * 2)
BAD = [
    dict(centroids=[[0.0, np.nan, -0.1], [0.0, 0.0, -0.1]]),
    dict(normals=[[1.0, 0.0, 0.0], [np.inf, 0.0, 0.0]]),
    dict(velocities=[[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0]]),
    dict(areas=[1e-3, np.nan]),
    dict(areas=[1e-3, -1e-3]),
    dict(normals=[[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    dict(centroids=np.zeros((2, 2))),
    dict(centroids=np.zeros(3)),
    dict(normals=np.ones((3, 3))),
    dict(velocities=np.ones((2, 3, 1))),
    dict(areas=np.ones(3)),
    dict(surface_height=np.nan),
    dict(gravity=(0.0, 0.0, np.inf)),
    dict(gravity=(0.0, 0.0, 0.0)),
    dict(gravity=(0.0, -9.81)),
]


@pytest.mark.parametrize("backend", COMPILED)
@pytest.mark.parametrize("bad", BAD, ids=lambda b: f"{next(iter(b))}={np.asarray(next(iter(b.values()))).tolist()}")
def test_bad_input_raises_the_reference_error(bad, backend):
    kwargs = {**GOOD, "media": MEDIA, **bad}
    with pytest.raises(ValueError) as ref:
        law.element_forces(**kwargs)
    with pytest.raises(ValueError) as got:
        rft_mujoco.element_forces(**kwargs, backend=backend)
    assert str(got.value) == str(ref.value)


@pytest.mark.parametrize("backend", ["numpy", *COMPILED])
def test_out_is_filled_and_checked(backend):
    c, nrm, a, v = random_elements(np.random.default_rng(3), 40)
    buf = np.full((40, 3), np.nan)
    got = rft_mujoco.element_forces(c, nrm, a, v, MEDIA, backend=backend, out=buf)
    assert got is buf
    assert_rows_match(buf, law.element_forces(c, nrm, a, v, MEDIA), force_scale(c, a))
    for bad in (np.zeros((39, 3)), np.zeros((40, 3), dtype=np.float32), np.zeros((3, 40)).T):
        with pytest.raises(ValueError, match=r"out must be a C-contiguous float64 array of shape \(40, 3\)"):
            rft_mujoco.element_forces(c, nrm, a, v, MEDIA, backend=backend, out=bad)


def test_physics_imports_neither_compiled_nor_coupling():
    """The layering that keeps rft_mujoco.forces free of cycles: physics/ is the bottom of the package."""
    root = pathlib.Path(rft_mujoco.__file__).parent
    for path in sorted((root / "physics").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert not name.startswith(("rft_mujoco.compiled", "rft_mujoco.coupling", "rft_mujoco.forces")), \
                    f"{path.name} imports {name}"
