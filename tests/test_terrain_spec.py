"""The terrains' kernel form (rft_mujoco.physics.terrain_spec): every terrain class satisfies the Terrain protocol
and writes its own TerrainSpec; the compiled depth of that spec equals the numpy ``depth`` at random points (every
kind, flat under tilted gravity, both heightfield ``outside`` modes, a region of each, a deformed surface with
memory); warp's float32 spec is the shared one cast; a terrain without a kernel form gives None (the coupling
falls back to numpy) and a malformed one a clear error."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.physics import law
from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.physics.deform import DeformableSurface, DeformedSurface
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion, Terrain, as_terrain

DEPTH_TOL = 1e-12
"""m: the compiled depth equals the numpy depth to round-off."""


def terrains(rng):
    """(name, terrain, g_hat) of every kind the kernels know; heightfields with random heights (m)."""
    heights = rng.uniform(-0.05, 0.05, (7, 9))
    tilted = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    down = np.array([0.0, 0.0, -1.0])
    edge = HeightfieldSurface(heights, (-0.4, 0.5), (-0.3, 0.35), "edge")
    none = HeightfieldSurface(heights, (-0.4, 0.5), (-0.3, 0.35), "none")
    return [("flat tilted", FlatSurface(0.02), tilted), ("flat", FlatSurface(-0.01), down),
            ("heightfield edge", edge, down), ("heightfield none", none, down),
            ("region of flat", SandRegion(FlatSurface(0.03), (-0.2, 0.3), (-0.25, 0.1)), down),
            ("region of heightfield edge", SandRegion(edge, (-0.5, 0.1), (-0.1, 0.4)), down),
            ("region of heightfield none", SandRegion(none, (-0.5, 0.1), (-0.1, 0.4)), down),
            ("deformable", DeformableSurface(height=0.01, size=(0.4, 0.3), cell=0.02, center=(0.05, -0.02)), down)]


def points(rng, n=4000):
    """(n, 3) world points (m) over and beyond the terrains' grids and regions, above and below the surface,
    with some on grid nodes and region edges exactly."""
    p = rng.uniform([-0.7, -0.6, -0.15], [0.7, 0.6, 0.15], (n, 3))
    p[:40, 0] = rng.choice([-0.4, 0.5, -0.2, 0.3, -0.5, 0.1], 40)
    p[40:80, 1] = rng.choice([-0.3, 0.35, -0.25, 0.1, -0.1, 0.4], 40)
    return p


def compiled_depths(p, g_hat, spec):
    """The compiled ``_depth`` of ``spec`` at the points ``p`` (n, 3), through a small njit loop."""
    pytest.importorskip("numba")
    from rft_mujoco.compiled.jit import njit
    from rft_mujoco.compiled.terrain import _depth

    @njit
    def loop(p, g, kind, tp, heights):
        out = np.empty(p.shape[0])
        for i in range(p.shape[0]):
            out[i] = _depth(p[i, 0], p[i, 1], p[i, 2], g[0], g[1], g[2], kind, tp, heights)
        return out

    return loop(p, g_hat, spec.kind, spec.params, spec.heights)


def deformed(surface: DeformableSurface, rng):
    """A deformed state of ``surface`` with random heights (m) and a preload (m) that is zero on a third of the
    nodes, in the kernels' (2 ny, nx) array (its halves are the numpy state's heights and preload)."""
    spec = ts.terrain_spec(surface)
    ny, nx = surface.shape
    grid = spec.heights
    grid[:ny] += rng.uniform(-0.02, 0.02, (ny, nx))
    grid[ny:] = rng.uniform(0.0, 0.01, (ny, nx)) * (rng.random((ny, nx)) > 0.33)
    zeros = np.zeros((ny, nx))
    return DeformedSurface(surface, grid[:ny], grid[ny:], zeros, zeros.copy()), spec._replace(heights=grid)


def test_every_terrain_class_is_a_terrain():
    for name, terrain, _ in terrains(np.random.default_rng(0)):
        assert isinstance(terrain, Terrain), name
        assert as_terrain(terrain) is terrain
        spec = ts.terrain_spec(terrain)
        assert isinstance(spec, ts.TerrainSpec) and spec.params.shape == (ts.N_PARAMS,), name
        assert spec.params[ts.TP_MAX_HEIGHT] == terrain.max_height, name
        assert spec.heights.dtype == np.float64 and spec.heights.flags.c_contiguous and spec.heights.flags.writeable
    assert ts.terrain_spec(terrains(np.random.default_rng(0))[0][1]).kind == ts.TerrainKind.FLAT
    assert isinstance(as_terrain(0.1), Terrain) and not isinstance(0.1, Terrain)


def test_the_named_slots_are_the_layout():
    assert len(set(ts.PARAMS)) == ts.N_PARAMS
    for i, name in enumerate(ts.PARAMS):
        assert getattr(ts, "TP_" + name.upper()) == i
    assert [int(k) for k in ts.TerrainKind] == [ts.FLAT, ts.HEIGHTFIELD, ts.DEFORMABLE] == [0, 1, 2]
    with pytest.raises(ValueError, match="no terrain parameter slot 'heigth'"):
        ts.new_params(heigth=1.0)


@pytest.mark.parametrize("case", range(8))
def test_compiled_depth_is_the_numpy_depth(case):
    rng = np.random.default_rng(case)
    name, terrain, g_hat = terrains(rng)[case]
    p = points(rng)
    spec = ts.terrain_spec(terrain)
    surface = terrain
    if isinstance(terrain, DeformableSurface):
        surface, spec = deformed(terrain, rng)
    want = surface.depth(p, g_hat)
    got = compiled_depths(p, g_hat, spec)
    assert np.isfinite(want).sum() > 300 and (want > 0).sum() > 100 and (want < 0).sum() > 100, name
    if "none" in name or "region" in name:
        assert np.isneginf(want).sum() > 100, name                          # points with no sand were met
    np.testing.assert_array_equal(np.isneginf(got), np.isneginf(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=DEPTH_TOL, err_msg=name)


def test_warp_spec_is_the_shared_spec_cast():
    pytest.importorskip("warp")
    pytest.importorskip("mujoco_warp")
    from rft_mujoco.warp.handle import _terrain_spec

    for name, terrain, _ in terrains(np.random.default_rng(3)):
        spec = ts.terrain_spec(terrain)
        if spec.kind == ts.DEFORMABLE:
            with pytest.raises(ValueError, match="DeformableSurface"):
                _terrain_spec(terrain)
            continue
        kind, tp, heights, flat_height = _terrain_spec(terrain)
        assert kind == spec.kind, name
        assert tp.dtype == np.float32 and heights.dtype == np.float32
        np.testing.assert_array_equal(tp, spec.params.astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(heights, spec.heights.astype(np.float32), err_msg=name)
        assert flat_height == (spec.params[ts.TP_HEIGHT] if kind == ts.FLAT else 0.0)


class Bumpy:
    """A user's terrain: depth and max_height, no kernel form."""

    max_height = 0.0

    def depth(self, points, g_hat):
        return -points[:, 2] + 0.01 * np.sin(20 * points[:, 0])


class WavyFlat(FlatSurface):
    """A FlatSurface subclass with its own depth: the inherited kernel_spec is not its depth."""

    def depth(self, points, g_hat):
        return super().depth(points, g_hat) + 0.01 * np.sin(20 * points[:, 0])


class Raised(FlatSurface):
    """A FlatSurface subclass that keeps the depth: its kernel form is the FlatSurface's."""


class Broken:
    max_height = 0.0

    def depth(self, points, g_hat):
        return -points[:, 2]

    def kernel_spec(self):
        return (0, np.zeros(11), np.zeros((2, 2)))          # the old tuple layout


def test_terrains_without_a_kernel_form_give_none():
    assert ts.terrain_spec(Bumpy()) is None
    assert as_terrain(Bumpy()).max_height == 0.0
    assert ts.terrain_spec(WavyFlat(0.1)) is None
    assert ts.terrain_spec(SandRegion(WavyFlat(0.1), (0, 1), (0, 1))) is None
    assert ts.terrain_spec(SandRegion(DeformableSurface(), (0, 1), (0, 1))) is None
    assert ts.terrain_spec(SandRegion(SandRegion(FlatSurface(), (0, 1), (0, 1)), (0, 1), (0, 1))) is None
    assert ts.terrain_spec(Raised(0.1)).kind == ts.FLAT
    assert ts.terrain_spec(Raised(0.1)).params[ts.TP_HEIGHT] == 0.1
    with pytest.raises(ValueError, match=r"Broken.kernel_spec\(\) must return None or a TerrainSpec"):
        ts.terrain_spec(Broken())
    with pytest.raises(ValueError, match="surface must be a height in m"):
        as_terrain("sand")


SCENE = """<mujoco><option timestep="0.002"/><worldbody><body name="box" pos="0 0 0.05"><freejoint/>
<geom type="box" size="0.05 0.05 0.05" mass="1"/></body></worldbody></mujoco>"""


@pytest.mark.parametrize("terrain", [Bumpy(), WavyFlat(0.0)], ids=["user", "subclass"])
def test_the_coupling_falls_back_to_numpy_without_a_kernel_form(terrain):
    pytest.importorskip("numba")
    model = mujoco.MjModel.from_xml_string(SCENE)
    handle = rft_mujoco.SandHandle(model, rft_mujoco.MPM_VALIDATION, [1], terrain, 0.01, law.PUBLISHED, True, True,
                                   backend="auto")
    assert handle.backend == "numpy"
    with pytest.raises(ValueError, match="backend='numba' supports .* kernel_spec"):
        rft_mujoco.SandHandle(model, rft_mujoco.MPM_VALIDATION, [1], terrain, 0.01, law.PUBLISHED, True, True,
                              backend="numba")
