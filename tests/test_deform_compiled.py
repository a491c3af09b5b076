"""The compiled deformable surface against its numpy reference: the effective depth of the kernels
(rft_mujoco.compiled.terrain, kind DEFORMABLE) against DeformedSurface.depth, the compiled press
(rft_mujoco.compiled.deform.press) against physics.deform.press on random and structured inputs (heights and
preload to round-off, cycles and reach exactly or to round-off), and a box simulated on both backends."""

import mujoco
import numpy as np
import pytest

import rft_mujoco
from rft_mujoco.compiled import deform as cdeform
from rft_mujoco.compiled import terrain as cterrain
from rft_mujoco.physics import deform

pytest.importorskip("numba")

ROUND = 1e-15
"""m: heights and preload agree to round-off (the sums of the displaced volume run in another order)."""


def compiled_state(surface):
    """The compiled press's arrays for a numpy state: (tp, grid, cycles, reach, buffers), every node live."""
    kind, tp, _ = cterrain.terrain_spec(surface.grid)
    assert kind == cterrain.DEFORMABLE
    grid = np.vstack([surface.heights, surface.preload])
    return tp, grid, surface.cycles.copy(), surface.reach.copy()


def press_both(surface, state, buffers, pts, nrm, ar, known_top=True):
    """Press the numpy ``surface`` and the compiled ``state`` alike (``known_top``: the compiled press is told the
    highest point before, else it looks over the whole grid); returns (numpy result, compiled stats, compiled
    highest point)."""
    tp, grid, cycles, reach = state
    b = buffers
    highest = surface.max_height if known_top else np.nan
    top = cdeform.press(tp, (grid, cycles, reach, b["live"]), (pts, nrm, ar), len(ar),
                        tuple(b[name] for name in cdeform.SCRATCH), b["stats"], highest)
    result = deform.press(surface, pts, nrm, ar)
    assert b["mark"].max() == 0                        # the scratch is left clear
    return result, b["stats"].copy(), top


def assert_same(surface, state, result, stats, top):
    _, grid, cycles, reach = state
    ny = surface.grid.shape[0]
    np.testing.assert_allclose(grid[:ny], surface.heights, rtol=0, atol=ROUND)
    np.testing.assert_allclose(grid[ny:], surface.preload, rtol=0, atol=ROUND)
    np.testing.assert_array_equal(cycles, surface.cycles)
    np.testing.assert_allclose(reach, surface.reach, rtol=0, atol=1e-12)
    assert stats[0] == result.covered and stats[1] == result.yielded and stats[5] == result.settled
    np.testing.assert_allclose(stats[2:5], [result.displaced, result.deposited, result.lost], rtol=1e-12, atol=1e-20)
    if result.yielded + result.settled:
        assert top == pytest.approx(surface.max_height, abs=ROUND)
    else:
        assert np.isnan(top)


def test_the_constants_are_the_reference_s():
    assert cdeform._FACING == deform.FACING_DOWN and cdeform._YIELD == deform.YIELD_TOL
    assert cdeform._RELAX_ITERATIONS == deform.RELAX_ITERATIONS and cdeform._RELAX_SHARE == deform.RELAX_SHARE


@pytest.mark.parametrize("repose, compaction", [(30.0, 0.0), (None, 0.3), (20.0, 1.0)])
def test_press_matches_numpy_on_random_states_and_elements(repose, compaction):
    rng = np.random.default_rng(3)
    grid = deform.DeformableSurface(size=(0.3, 0.2), cell=0.01, center=(0.01, -0.02), repose_angle=repose,
                                    compaction=compaction, berm_width=0.03)
    ny, nx = grid.shape
    pressed = 0
    for trial in range(60):
        s = grid.initial()
        s.heights[:] = rng.normal(0.0, 0.003, grid.shape)
        s.preload[:] = np.maximum(rng.normal(0.002, 0.004, grid.shape), 0.0)
        s.cycles[:] = rng.integers(0, 4, grid.shape)
        s.reach[:] = np.where(rng.random(grid.shape) < 0.5, rng.random(grid.shape), 0.0)
        n = 40
        pts = np.column_stack([rng.uniform(-0.16, 0.17, n), rng.uniform(-0.14, 0.1, n), rng.normal(-0.003, 0.006, n)])
        nrm = rng.normal(size=(n, 3))
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        if trial % 2:
            nrm[: n // 2] = (0.0, 0.0, -1.0)            # level bottoms
        ar = rng.uniform(2e-5, 4e-4, n)
        state = compiled_state(s)
        b = cdeform.buffers(grid.shape, n)
        b["live"][0] = ny * nx                         # every node's reach may be non-zero
        b["live"][1:] = np.arange(ny * nx)
        result, stats, top = press_both(s, state, b, pts, nrm, ar, known_top=trial % 3 > 0)
        assert_same(s, state, result, stats, top)
        pressed += result.yielded > 0
    assert pressed > 40


def test_press_matches_numpy_through_loading_cycles():
    """A tilted box bottom pressed deeper in small steps, lifted (unload), pressed again (reload, settlement),
    moved aside: the state carried from press to press on both sides, the compiled reach bookkeeping included."""
    grid = deform.DeformableSurface(size=(0.2, 0.2), cell=0.005)
    s = grid.initial()
    state = compiled_state(s)
    b = cdeform.buffers(grid.shape, 0)
    xs, ys = np.meshgrid(np.linspace(-0.04, 0.04, 9), np.linspace(-0.03, 0.03, 7))
    tilt = np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0])
    bottom = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    bottom[:, 2] = -(tilt[0] * bottom[:, 0] + tilt[1] * bottom[:, 1]) / tilt[2]
    top_face = bottom + (0.0, 0.0, 0.03)
    pts0 = np.vstack([bottom, top_face])
    nrm = np.vstack([np.tile(tilt, (len(bottom), 1)), np.tile(-tilt, (len(bottom), 1))])
    ar = np.full(len(pts0), 1e-4)
    schedule = [(0.0, -0.002 * i) for i in range(1, 8)] + [None, None] + [(0.0, -0.004 * i) for i in range(1, 6)]
    schedule += [None] + [(0.02, -0.01), (0.02, -0.02), (0.05, -0.02)]
    settled = 0
    for step in schedule:
        if step is None:                               # lifted: the coupling unloads every node
            deform.unload(s)
            live = b["live"]
            state[3].reshape(-1)[live[1:1 + live[0]]] = 0.0
            live[0] = 0
            continue
        dx, z = step
        pts = pts0 + (dx, 0.0, z)
        result, stats, top = press_both(s, state, b, pts, nrm, ar)
        assert_same(s, state, result, stats, top)
        settled += result.settled
    assert settled > 0 and s.cycles.max() >= 2         # the reload settled in a second cycle
    assert deform.volume_change(s) == pytest.approx(0.0, abs=1e-12)


def test_a_body_over_the_whole_grid_loses_its_volume_on_both():
    grid = deform.DeformableSurface(size=(0.02, 0.02), cell=0.01)
    s = grid.initial()
    state = compiled_state(s)
    b = cdeform.buffers(grid.shape, 1)
    result, stats, top = press_both(s, state, b, np.array([[0.0, 0.0, -0.01]]), np.array([[0.0, 0.0, -1.0]]),
                                    np.array([0.0016]))
    assert result.lost > 0.0
    assert_same(s, state, result, stats, top)


def test_effective_depth_matches_the_deformed_surface():
    rng = np.random.default_rng(5)
    grid = deform.DeformableSurface(height=0.01, size=(0.2, 0.1), cell=0.01, center=(0.05, 0.0))
    s = grid.initial()
    s.heights[:] = 0.01 + rng.normal(0.0, 0.004, grid.shape)
    s.preload[:] = np.maximum(rng.normal(0.001, 0.003, grid.shape), 0.0)
    kind, tp, _ = cterrain.terrain_spec(grid)
    state = np.vstack([s.heights, s.preload])
    pts = np.column_stack([rng.uniform(-0.1, 0.2, 500), rng.uniform(-0.08, 0.08, 500), rng.uniform(-0.01, 0.03, 500)])
    pts[:5, :2] = [[-0.05, -0.05], [0.15, 0.05], [0.0, 0.0], [0.149999, -0.049999], [0.07, 0.0]]   # corners, nodes
    want = s.depth(pts, np.array([0.0, 0.0, -1.0]))
    got = np.array([cterrain._depth(x, y, z, 0.0, 0.0, -1.0, kind, tp, state) for x, y, z in pts])
    np.testing.assert_allclose(got, want, rtol=0, atol=ROUND)
    assert (want > 0).sum() > 100 and (want < 0).sum() > 100


BOX = """<mujoco><option timestep="0.001"/><worldbody>
<body name="box" pos="0 0 0.0201"><freejoint/><geom type="box" size="0.05 0.05 0.02" mass="5"/></body>
</worldbody></mujoco>"""


def _pushed_box(backend: str, interval: float, observed: bool = False):
    """The footprint study's box (5 kg, 10 x 10 x 4 cm, loose glass beads, 5 mm cells, dt 1 ms) dropped and pushed
    sideways and back for 400 steps; (qpos, surface, evaluation path, grid updates)."""
    model = mujoco.MjModel.from_xml_string(BOX)
    handle = rft_mujoco.attach(model, rft_mujoco.LI_LOOSE_GLASS_BEADS, backend=backend, monitor=False,
                               surface_height=rft_mujoco.DeformableSurface(size=(0.3, 0.3), cell=0.005,
                                                                          update_interval=interval))
    assert handle.backend == backend
    if observed:
        handle.observe(lambda data, wrenches, stage: None)      # an observer keeps the Python path
    data = mujoco.MjData(model)
    clocks = set()
    for i in range(400):
        data.xfrc_applied[1, 0] = 5.0 * np.sin(i * 0.01)
        mujoco.mj_step(model, data)
        clocks.add(handle.surface_updated(data))
    out = (data.qpos.copy(), handle.surface(data), handle.evaluation_path(data), len(clocks - {-np.inf}))
    handle.detach()
    return out


@pytest.mark.parametrize("interval", [0.0, 0.01])
def test_a_box_pushed_about_is_the_same_on_both_backends_and_paths(interval):
    """The box pushed about: the trajectory and the surface of the compiled runs, on the native route and on the
    Python path, follow the numpy run's to 1e-9 m (the kernels and the press agree with numpy to round-off; the
    simulation compounds it over 400 steps, measured 2e-17 m on this machine, and the bound leaves room for
    another CPU's round-off), with the grid updated at every step and every 10 ms (10 steps)."""
    q_np, s_np, path, updates = _pushed_box("numpy", interval)
    assert path == "python" and s_np.heights.min() < -0.01 and s_np.heights.max() > 0.001   # a print, a berm
    assert updates > 390 if interval == 0.0 else 35 <= updates <= 40      # (the box touches after a few steps)
    for observed, want in ((False, "native"), (True, "python")):
        q_nb, s_nb, path, n = _pushed_box("numba", interval, observed)
        assert path == want and n == updates
        np.testing.assert_allclose(q_nb, q_np, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s_nb.heights, s_np.heights, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s_nb.preload, s_np.preload, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(s_nb.cycles, s_np.cycles)


def test_the_update_schedule():
    """:func:`rft_mujoco.physics.deform.schedule`: due at the first step at least the interval after the last update,
    the loading restarted when the last step had nothing touching (a lift-off, a reset, the first update)."""
    dt = 0.002
    assert deform.schedule(np.inf, np.inf, 0.03, dt) == deform.RESTART
    assert deform.schedule(0.01, -dt, 0.03, dt) == deform.RESTART           # time went back
    assert deform.schedule(0.01, 2 * dt, 0.03, dt) == deform.RESTART         # a step with nothing touching
    assert deform.schedule(0.028, dt, 0.03, dt) == deform.SKIP
    assert deform.schedule(0.03 * (1 - 1e-12), dt, 0.03, dt) == deform.PRESS
    assert deform.schedule(0.031, dt, 0.03, dt) == deform.PRESS              # (an interval not a multiple of dt)
    assert deform.schedule(0.0, 0.0, 0.03, dt) == deform.SKIP                # evaluated again at the same time
    assert [deform.schedule(e, e, 0.0, dt) for e in (0.0, dt, 2 * dt)] == [deform.PRESS, deform.PRESS, deform.RESTART]
    with pytest.raises(ValueError, match="update_interval"):
        deform.DeformableSurface(update_interval=-0.01)


def test_the_cost_benchmark_times_both_surfaces():
    """``bench --deformable``'s function on a short trot: every run timed, on the backend it names (it raises
    otherwise), the numpy run skipped when asked."""
    from rft_mujoco.studies.bench.coupling import deformable_trot

    cpu = deformable_trot(seconds=0.02, reps=1, numpy_seconds=0.0)
    assert len(cpu["flat"]) == len(cpu["deformable"]) == 1 and cpu["deformable_numpy"] == []
    assert all(v > 0.0 for v in cpu["flat"] + cpu["deformable"])


def test_the_interval_sweep_measures_each_interval():
    """``bench --deformable --intervals``: one timed pair per interval, with the surface it left (a print, a berm)."""
    from rft_mujoco.studies.bench.coupling import interval_sweep

    rows = interval_sweep([0.0, 0.05], seconds=0.1)
    assert [r["interval"] for r in rows] == [0.0, 0.05]
    for r in rows:
        assert r["ratio"] > 0.0 and r["deepest"] > 0.01 and r["berm"] > 0.0 and abs(r["trunk_x"]) < 0.1
