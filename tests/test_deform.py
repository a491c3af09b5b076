"""The deformable surface's physics (rft_mujoco.physics.deform): pure numpy, no MuJoCo.

Each vectorized function is compared with a plain loop; the footprint, conservation and memory rules are
checked on plates pressed into the grid.
"""

import numpy as np
import pytest

from rft_mujoco.physics import deform
from rft_mujoco.physics.deform import DeformableSurface, effective_depth
from rft_mujoco.physics.terrain import FlatSurface

G = np.array([0.0, 0.0, -1.0])


def plate(half: float, z: float, size: float = 0.01, center=(0.0, 0.0), tilt: float = 0.0):
    """Downward-facing elements (centroids, normals, areas) of a square plate of half-width ``half`` m with
    its centre at height ``z``, tilted by ``tilt`` rad about the y axis."""
    n = int(round(2 * half / size))
    c = -half + size * (np.arange(n) + 0.5)
    xx, yy = np.meshgrid(c, c)
    p = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    ct, st = np.cos(tilt), np.sin(tilt)
    rot = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    p = p @ rot.T + [center[0], center[1], z]
    nrm = np.tile(rot @ [0, 0, -1.0], (p.shape[0], 1))
    return p, nrm, np.full(p.shape[0], size * size)


def test_virgin_surface_is_the_flat_one():
    grid = DeformableSurface(height=0.1, size=(0.3, 0.2), cell=0.01, center=(0.05, -0.02))
    s = grid.initial()
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.3, -0.3, 0.0], [0.3, 0.3, 0.2], (500, 3))
    np.testing.assert_array_equal(s.depth(pts, G), FlatSurface(0.1).depth(pts, G))
    assert s.max_height == 0.1
    assert grid.shape == (21, 31) and grid.x[0] == pytest.approx(-0.1) and grid.y[-1] == pytest.approx(0.08)


def test_effective_depth_branches_and_continuity():
    q, r = np.full(5, 0.02), 20.0
    d = np.array([-0.01, 0.0, 0.0005, 0.001, 0.003])
    np.testing.assert_allclose(effective_depth(d, q, r), [-0.01, 0.0, 0.01, 0.02, 0.022])
    e = 0.02 / r                                   # continuous at the elastic depth
    below, above = effective_depth(np.array([e * (1 - 1e-9), e * (1 + 1e-9)]), q[:2], r)
    assert abs(below - above) < 1e-9
    np.testing.assert_array_equal(effective_depth(d, np.zeros(5), r), d)     # virgin: unchanged


def _covering_loop(grid, points, normals, areas):
    """The plain loop: every node, every downward element, the plane height where its projected square (half-sides
    sqrt(area)/2 across the tilt, |n_z| sqrt(area)/2 along it), grown by COVER_GROW cells, covers it."""
    low = {}
    for (px, py, pz), n, a in zip(points, normals, areas):
        if n[2] >= -deform.FACING_DOWN:
            continue
        half = 0.5 * np.sqrt(a)
        t = n[:2] / np.linalg.norm(n[:2]) if np.linalg.norm(n[:2]) > deform.FACING_DOWN else np.array([1.0, 0.0])
        for i, y in enumerate(grid.y):
            for j, x in enumerate(grid.x):
                along = (x - px) * t[0] + (y - py) * t[1]
                across = (y - py) * t[0] - (x - px) * t[1]
                grow = deform.COVER_GROW * grid.cell
                if abs(along) <= half * -n[2] + grow and abs(across) <= half + grow:
                    clamped = min(max(along, half * n[2]), -half * n[2])      # on the element, along the tilt
                    z = pz - np.hypot(n[0], n[1]) * clamped / n[2]
                    k = i * grid.shape[1] + j
                    low[k] = min(low.get(k, np.inf), z)
    keys = np.array(sorted(low), dtype=np.int64)
    return keys, np.array([low[k] for k in keys])


@pytest.mark.parametrize("tilt, spin", [(0.0, 0.0), (0.3, 0.0), (0.5, 0.7)])
def test_covering_matches_a_plain_loop(tilt, spin):
    grid = DeformableSurface(size=(0.1, 0.08), cell=0.005)
    p, n, a = plate(0.02, -0.01, size=0.007, center=(0.011, -0.004), tilt=tilt)
    c, s_ = np.cos(spin), np.sin(spin)                 # the tilted plate turned about z: tilt along x and y
    rz = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1.0]])
    p, n = p @ rz.T, n @ rz.T
    nodes, low = deform.covering(grid, p, n, a)
    ref_nodes, ref_low = _covering_loop(grid, p, n, a)
    np.testing.assert_array_equal(nodes, ref_nodes)
    np.testing.assert_allclose(low, ref_low, atol=1e-15)


def test_berm_nodes_match_a_distance_test():
    grid = DeformableSurface(size=(0.1, 0.1), cell=0.005, berm_width=0.012)
    covered = np.array([20 * 21 + 3, 10 * 21 + 10, 10 * 21 + 11, 11 * 21 + 10])
    rim = np.sort(deform.berm_nodes(grid, covered))
    ci, cj = np.divmod(covered, 21)
    ref = [i * 21 + j for i in range(21) for j in range(21)
           if i * 21 + j not in covered and np.min(np.maximum(abs(ci - i), abs(cj - j))) <= 2]
    np.testing.assert_array_equal(rim, ref)


def test_plate_footprint_outline_depth_and_conservation():
    grid = DeformableSurface(size=(0.3, 0.3), cell=0.005, repose_angle=None)     # the deposit rule alone
    s = grid.initial()
    p, n, a = plate(0.05, -0.012)
    res = deform.press(s, p, n, a)
    under = (np.abs(grid.x)[None, :] <= 0.05 + 1e-12) & (np.abs(grid.y)[:, None] <= 0.05 + 1e-12)
    # the plate's outline, the footprint at the plate less the elastic depth, preload = the depth pressed
    np.testing.assert_allclose(s.heights[under], -0.012 + 0.012 / grid.reload_ratio)
    np.testing.assert_allclose(s.preload[under], 0.012)
    assert np.all(s.heights[~under] >= 0.0) and np.all(s.preload[~under] == 0.0)
    assert res.yielded == under.sum() and res.lost == 0.0
    assert res.displaced == pytest.approx(deform.footprint_volume(s))
    assert abs(deform.volume_change(s)) < 1e-12 * res.displaced + 1e-18
    # the berm: the ring within berm_width of the footprint, evenly
    ring = ((np.abs(grid.x)[None, :] <= 0.1 + 1e-12) & (np.abs(grid.y)[:, None] <= 0.1 + 1e-12)) & ~under
    assert np.all(s.heights[ring] > 0.0) and np.ptp(s.heights[ring]) < 1e-15
    assert np.all(s.heights[~ring & ~under] == 0.0)


def test_compaction_fraction_leaves_the_grid():
    grid = DeformableSurface(size=(0.3, 0.3), cell=0.005, compaction=0.25)
    s = grid.initial()
    res = deform.press(s, *plate(0.05, -0.01))
    assert deform.volume_change(s) == pytest.approx(-0.25 * res.displaced)


def test_pressing_keeps_the_pressing_depth_and_steps_add_up():
    """The effective depth of the pressing plate is unchanged by the update, and many small presses give
    the same surface as one (the memory makes the grid update's frequency irrelevant on virgin sand)."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005)
    p, n, a = plate(0.03, -0.015)
    one = grid.initial()
    before = one.depth(p, G)
    deform.press(one, p, n, a)
    np.testing.assert_allclose(one.depth(p, G), before, rtol=1e-12)
    many = grid.initial()
    for z in np.linspace(-0.001, -0.015, 15):
        pz = p.copy()
        pz[:, 2] = z
        deform.press(many, pz, n, a)
    np.testing.assert_allclose(many.preload, one.preload, atol=1e-15)
    under = one.preload > 0
    np.testing.assert_allclose(many.heights[under], one.heights[under], atol=1e-15)
    assert deform.volume_change(many) == pytest.approx(0.0, abs=1e-18)


def test_unload_reload_and_virgin_beyond():
    """After pressing to depth q and lifting, a plate back in its footprint carries q's stress within q/ratio of
    sinkage (stiff), and deeper it follows the virgin line: effective depth = depth below the initial surface."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005, reload_ratio=20.0)
    s = grid.initial()
    q = 0.012
    p, n, a = plate(0.03, -q)
    deform.press(s, p, n, a)
    bottom = -q + q / 20.0
    for extra, expect in ((0.0, 0.0), (q / 40, q / 2), (q / 20, q), (q / 20 + 0.005, q + 0.005)):
        pz = p.copy()
        pz[:, 2] = bottom - extra
        np.testing.assert_allclose(s.depth(pz, G), expect, atol=1e-15)
    pz = p.copy()
    pz[:, 2] = -2 * q                             # twice as deep as virgin: the virgin stress of 2q
    np.testing.assert_allclose(s.depth(pz, G), 2 * q, rtol=1e-12)
    deform.press(s, pz, n, a)                     # yielding there: memory 2q, footprint at 2q less elastic
    np.testing.assert_allclose(s.preload[s.preload > 0], 2 * q)


def test_lost_volume_when_the_footprint_covers_the_grid():
    grid = DeformableSurface(size=(0.04, 0.04), cell=0.005)
    s = grid.initial()
    res = deform.press(s, *plate(0.05, -0.01))
    assert res.deposited == 0.0 and res.lost == pytest.approx(res.displaced) and res.displaced > 0


def test_upward_and_vertical_elements_do_not_press():
    grid = DeformableSurface(size=(0.1, 0.1), cell=0.005)
    s = grid.initial()
    p, n, a = plate(0.02, -0.01)
    res = deform.press(s, p, -n, a)
    res2 = deform.press(s, p, np.tile([1.0, 0.0, 0.0], (p.shape[0], 1)), a)
    assert res.covered == res2.covered == 0 and np.all(s.heights == 0.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(cell=0.0), "cell"), (dict(size=(0.001, 1.0)), "size"), (dict(size="big"), "size"),
    (dict(reload_ratio=1.0), "reload_ratio"), (dict(compaction=1.5), "compaction"),
    (dict(berm_width=-1.0), "berm_width"), (dict(height=np.inf), "height"), (dict(repose_angle=90.0), "repose"),
    (dict(size=(100.0, 100.0), cell=0.001), "nodes")])
def test_bad_settings_say_what_is_allowed(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DeformableSurface(**kwargs)


def test_tilted_gravity_is_refused():
    s = DeformableSurface().initial()
    with pytest.raises(ValueError, match="gravity along -z"):
        s.depth(np.zeros((1, 3)), np.array([0.6, 0.0, -0.8]))


def test_the_berm_avoids_earlier_footprints():
    """A plate pressed beside an earlier footprint puts its berm on virgin sand only, not into that footprint."""
    grid = DeformableSurface(size=(0.4, 0.2), cell=0.005, repose_angle=None)
    s = grid.initial()
    deform.press(s, *plate(0.03, -0.01, center=(-0.05, 0.0)))
    first = s.heights.copy()
    old = s.preload > 0
    second = plate(0.03, -0.01, center=(0.02, 0.0))
    res = deform.press(s, *second)
    covered = np.zeros(grid.shape[0] * grid.shape[1], bool)
    covered[deform.covering(grid, *second)[0]] = True
    stay = old & ~covered.reshape(grid.shape)          # the first footprint's nodes the second plate left alone
    assert stay.any() and np.array_equal(s.heights[stay], first[stay])
    assert abs(deform.volume_change(s)) < 1e-12 * res.displaced + 1e-18


def test_a_cylinder_lowers_every_node_under_it():
    """The lower half of a horizontal cylinder (axis y, radius 0.1 m, 6 cm wide, 14.3 x 15 mm elements) sunk 2 cm:
    every node within its chord and width is lowered, none is left standing between elements."""
    r, width, size = 0.1, 0.06, 0.015
    step = 2 * np.pi / 44                                                # arcs of 14.3 mm: elements not square
    th = np.arange(np.pi + step / 2, 2 * np.pi, step)                    # angles of the lower half
    ys = -width / 2 + size * (np.arange(int(width / size)) + 0.5)
    T, Y = np.meshgrid(th, ys)
    n = np.column_stack([np.cos(T).ravel(), np.zeros(T.size), np.sin(T).ravel()])
    p = np.column_stack([r * n[:, 0], Y.ravel(), r * n[:, 2] + r - 0.02])
    grid = DeformableSurface(size=(0.3, 0.2), cell=0.005)
    s = grid.initial()
    deform.press(s, p, n, np.full(len(p), step * r * size))
    chord = np.sqrt(r ** 2 - (r - 0.02) ** 2)
    inside = (np.abs(grid.x)[None, :] < 0.8 * chord) & (np.abs(grid.y)[:, None] <= width / 2 - 1e-9)
    assert np.all(s.heights[inside] < -0.005) and np.all(s.preload[inside] > 0.0)


def test_nearly_vertical_elements_do_not_dig():
    """A wall element tilted 1e-5 from vertical covers a node or two; it lowers them by at most its half-size."""
    grid = DeformableSurface(size=(0.1, 0.1), cell=0.005)
    s = grid.initial()
    n = np.array([[np.sqrt(1 - 1e-10), 0.0, -1e-5]])
    deform.press(s, np.array([[0.001, 0.0, -0.01]]), n, np.array([1e-4]))
    assert s.heights.min() >= -0.01 - 0.005 - 1e-12


def test_relax_flows_steep_slopes_down_and_conserves_volume():
    """A berm's steep edges and a trench's walls flow toward the angle of repose; the nodes under the body
    keep their heights; the volume is unchanged."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005, repose_angle=30.0)
    s = grid.initial()
    s.heights[15:26, 15:26] = -0.02                  # a footprint under a body (covered) ...
    s.heights[8:15, 15:26] = 0.01                    # ... a berm beside it, and a trench beyond
    s.heights[30:33, 5:35] = -0.015
    covered = np.flatnonzero((np.zeros(grid.shape, bool) | (s.heights == -0.02)).ravel())
    before, under = deform.volume_change(s), s.heights[15:26, 15:26].copy()
    steep = lambda: np.abs(np.diff(s.heights[:14, :], axis=0)).max()       # noqa: E731  (berm side)
    start = steep()
    for _ in range(200):
        deform.relax(s, covered)
    np.testing.assert_array_equal(s.heights[15:26, 15:26], under)
    assert deform.volume_change(s) == pytest.approx(before, abs=1e-15)
    limit = np.tan(np.radians(30.0)) * 0.005
    assert start > 2 * limit and steep() <= limit * 1.05
    assert s.heights[30:33, 5:35].min() > -0.015     # the trench walls slumped into it


def test_a_buried_body_leaves_the_surface_alone():
    """A box entirely under the surface (its top 1 cm deep) lowers no node and keeps its virgin depth; the same
    box piercing the surface (top above it) leaves its footprint."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005)
    bottom, _, area = plate(0.03, -0.05)
    top_pts = bottom.copy()
    top_pts[:, 2] = -0.01
    pts = np.vstack([bottom, top_pts])
    nrm = np.vstack([np.tile([0, 0, -1.0], (len(bottom), 1)), np.tile([0, 0, 1.0], (len(bottom), 1))])
    areas = np.concatenate([area, area])
    s = grid.initial()
    assert deform.press(s, pts, nrm, areas).yielded == 0 and np.all(s.heights == 0.0)
    pts[len(bottom):, 2] = 0.01                     # the top above the surface: it pierces
    assert deform.press(s, pts, nrm, areas).yielded > 0 and s.heights.min() < -0.04


def test_stacked_bodies_keep_the_sand_between_them():
    """A lower leg (its bottom 2 cm deep, its top out of the sand) over a foot (bottom 5 cm, top 4 cm deep): the
    column is lowered to the leg's bottom, not the foot's, and the foot keeps its virgin effective depth."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005)
    leg, nl, al = plate(0.02, -0.02)
    foot, nf, af = plate(0.02, -0.05)
    up = np.tile([0, 0, 1.0], (len(leg), 1))
    pts = np.vstack([leg, leg + [0, 0, 0.04], foot, foot + [0, 0, 0.01]])
    nrm = np.vstack([nl, up, nf, up])
    s = grid.initial()
    deform.press(s, pts, nrm, np.concatenate([al, al, af, af]))
    assert s.heights.min() == pytest.approx(-0.02 + 0.02 / grid.reload_ratio)
    np.testing.assert_allclose(s.depth(foot, G), 0.05, rtol=1e-12)


def _press_loop(grid, h, q, cycles, reach, nodes, low):
    """The plain loop of the repeated-loading rule (module docstring of deform) on the pressed ``nodes`` (flat
    indices, unique) with the body surface ``low`` over each: one node at a time, in order: a new cycle when its
    reach is 0; reload up to the preload with plastic sinkage a_N q per unit of reach; the virgin line beyond."""
    h, q, cycles, reach = h.copy(), q.copy(), cycles.copy(), reach.copy()
    old = reach.copy()
    reach[:] = 0.0
    e = grid.reload_ratio
    for k, z in zip(nodes, low):
        w = old[k]
        if w == 0.0:
            cycles[k] += 1
        a = grid.reload_sinkage * grid.reload_decay ** (cycles[k] - 2) if cycles[k] >= 2 else 0.0
        d = h[k] - z
        if q[k] == 0.0:                                   # virgin: yields, all of it
            q[k] = d
            h[k] = z + q[k] / e
            reach[k] = 1.0
            continue
        per = q[k] / e + a * q[k]                         # m of penetration per unit of reach
        push = d - w * q[k] / e
        if push <= 0.0:
            reach[k] = w
        elif push <= (1.0 - w) * per:
            reach[k] = w + push / per
            h[k] -= a * q[k] * (reach[k] - w)
        else:
            q[k] += push - (1.0 - w) * per
            h[k] = z + q[k] / e
            reach[k] = 1.0
    return h, q, cycles, reach


def test_repeated_loading_matches_a_plain_loop():
    """One element over each node of a block, each at its own depth (above the reach already taken, within the
    reload, beyond the preload), on nodes in every state (virgin, first cycle, later cycles, part-reloaded,
    unloaded): heights, preload, cycles and reach as the loop; the volume goes to the berm."""
    grid = DeformableSurface(size=(0.1, 0.1), cell=0.005, repose_angle=None, berm_width=0.0)
    rng = np.random.default_rng(3)
    s = grid.initial()
    shape = grid.shape
    s.heights[:] = rng.uniform(-0.02, 0.0, shape)
    s.preload[:] = np.where(rng.random(shape) < 0.2, 0.0, rng.uniform(0.005, 0.03, shape))
    s.cycles[:] = np.where(s.preload > 0, rng.integers(1, 5, shape), 0)
    s.reach[:] = np.where(rng.random(shape) < 0.5, 0.0, rng.uniform(0.0, 1.0, shape))
    ii, jj = np.meshgrid(np.arange(5, 16), np.arange(4, 17), indexing="ij")
    block = (ii * shape[1] + jj).ravel()
    depth = rng.uniform(-0.001, 0.004, block.size)       # some above the surface: those nodes are not pressed
    bottom = np.column_stack([grid.x[jj.ravel()], grid.y[ii.ravel()], s.heights.reshape(-1)[block] - depth])
    pts = np.vstack([bottom, bottom + [0.0, 0.0, 0.1]])  # and its top out of the sand: it pierces
    nrm = np.vstack([np.tile([0, 0, -1.0], (block.size, 1)), np.tile([0, 0, 1.0], (block.size, 1))])
    areas = np.full(2 * block.size, 0.005 ** 2)
    flat = [a.reshape(-1) for a in (s.heights, s.preload, s.cycles, s.reach)]
    nodes, low = deform.covering(grid, pts, nrm, areas, below=flat[0])
    np.testing.assert_array_equal(nodes, np.sort(block[depth > 0]))      # one node per element
    ref = _press_loop(grid, *flat, nodes, low)
    before_h, before_v = flat[0].copy(), deform.volume_change(s)
    res = deform.press(s, pts, nrm, areas)
    pressed = np.zeros(flat[0].size, bool)
    pressed[nodes] = True
    for got, want in zip(flat, ref):
        np.testing.assert_allclose(got[pressed], want[pressed], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(flat[3][~pressed], 0.0)                  # the rest is unloaded
    assert res.yielded > 0 and res.settled > 0 and res.covered == nodes.size
    assert res.displaced == pytest.approx(float(np.sum(before_h[pressed] - flat[0][pressed])) * 0.005 ** 2,
                                          rel=1e-12)
    assert deform.volume_change(s) == pytest.approx(before_v, abs=1e-15)   # all of it in the berm
    assert np.all(flat[0][~pressed] >= before_h[~pressed])


def test_reloads_settle_by_diminishing_increments():
    """A plate pressed to q, lifted and set back to the same stress each cycle sinks a_N q more each time:
    reload_sinkage q, then reload_decay times less; it carries the same stress (effective depth q) each time."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005, reload_sinkage=0.1, reload_decay=0.5, repose_angle=None)
    s = grid.initial()
    q, e = 0.012, grid.reload_ratio
    p, n, a = plate(0.03, -q)
    deform.press(s, p, n, a)
    under = s.preload > 0
    bottoms = [float(s.heights[under].mean())]
    for cycle in range(2, 6):
        deform.unload(s)
        a_n = 0.1 * 0.5 ** (cycle - 2)
        pz = p.copy()
        pz[:, 2] = bottoms[-1] - q / e - a_n * q          # down to the preload through the settlement
        res = deform.press(s, pz, n, a)
        assert res.settled + res.yielded == under.sum()   # yielded: by round-off past the preload
        np.testing.assert_allclose(s.cycles[under], cycle)
        np.testing.assert_allclose(s.reach[under], 1.0, rtol=1e-12)
        np.testing.assert_allclose(s.preload[under], q, rtol=1e-12)         # settled at constant preload
        np.testing.assert_allclose(s.depth(pz, G), q, rtol=1e-9)             # the same stress as the first time
        bottoms.append(float(s.heights[under].mean()))
    steps = -np.diff(bottoms)
    np.testing.assert_allclose(steps, q * 0.1 * 0.5 ** np.arange(4), rtol=1e-9)
    assert abs(deform.volume_change(s)) < 1e-15


def test_a_reload_in_small_presses_settles_as_one():
    """Within one cycle the reload is linear in the reach: ten small presses give the surface of one; a press
    that does not go past the reach already taken changes nothing; no unload between presses: one cycle."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005, repose_angle=None)
    p, n, a = plate(0.03, -0.01)
    states = []
    for steps in (1, 10):
        s = grid.initial()
        deform.press(s, p, n, a)
        deform.unload(s)
        under = s.preload > 0
        top = float(s.heights[under].mean())
        for z in np.linspace(top - 0.0012 / steps, top - 0.0012, steps):
            pz = p.copy()
            pz[:, 2] = z
            deform.press(s, pz, n, a)
        before = s.heights.copy()
        pz[:, 2] = top - 0.0011                           # backed off a little: nothing more
        assert deform.press(s, pz, n, a).settled == 0
        np.testing.assert_array_equal(s.heights, before)
        np.testing.assert_allclose(s.cycles[under], 2.0)
        states.append(s)
    one, many = states
    np.testing.assert_allclose(many.heights, one.heights, atol=1e-15)
    np.testing.assert_allclose(many.reach, one.reach, atol=1e-12)
    assert 0.0 < one.reach.max() < 1.0                   # part of the way to the preload


def _two_layer_depth(d, q, loose, e):
    """Effective depth (a plain loop) under ``loose`` m of memoryless sand on a column that remembers q: virgin in
    the loose layer; below it the column reloads stiffly from the loose layer's own load to q, virgin beyond."""
    out = []
    for di in d:
        if di <= loose:
            out.append(di)
            continue
        x, start = di - loose, loose
        if start >= q:
            out.append(di)
        elif x <= (q - start) / e:
            out.append(start + e * x)
        else:
            out.append(q + x - (q - start) / e)
    return np.array(out)


def test_buried_preload_is_the_two_layer_column_from_the_remembered_stress_on():
    """bury: preload less the loose thickness, not below 0; with it the one-layer effective depth equals a loose
    layer on the remembered column wherever the stress reaches the remembered one, and beyond."""
    e = 20.0
    q = np.array([0.03, 0.03, 0.01, 0.0])
    loose = np.array([0.01, 0.0, 0.02, 0.005])
    buried = q.copy()
    deform.bury(buried, loose)
    np.testing.assert_allclose(buried, [0.02, 0.03, 0.0, 0.0])
    for qi, li, bi in zip(q, loose, buried):
        d = np.linspace(0.0, 0.06, 601)
        two = _two_layer_depth(d, qi, li, e)
        one = effective_depth(d, np.full(d.size, bi), e)
        reached = two >= qi
        np.testing.assert_allclose(one[reached], two[reached], atol=1e-15)
        assert np.all(one >= two - 1e-15)                 # stiffer in the loose layer (one number per node)


def test_flowed_sand_buries_the_preload_it_lands_on():
    """The slope flow into a pressed trench: each node that gained sand lost as much preload; the others kept it."""
    grid = DeformableSurface(size=(0.2, 0.2), cell=0.005, repose_angle=30.0)
    s = grid.initial()
    s.heights[18:23, 5:35] = -0.02                       # a trench, pressed to 25 mm
    s.preload[18:23, 5:35] = 0.025
    s.heights[15:18, 5:35] = 0.01                        # a berm beside it
    h0, q0 = s.heights.copy(), s.preload.copy()
    deform.relax(s, np.array([30 * 41 + 20]))            # a body far off the trench: it all may flow
    gain = np.maximum(s.heights - h0, 0.0)
    assert gain[18:23, 5:35].max() > 0.001
    np.testing.assert_allclose(s.preload, np.maximum(q0 - gain, 0.0), atol=1e-15)


@pytest.mark.parametrize("kwargs, match", [(dict(reload_sinkage=-0.1), "reload_sinkage"),
                                           (dict(reload_sinkage=np.nan), "reload_sinkage"),
                                           (dict(reload_decay=1.0), "reload_decay")])
def test_bad_repeated_loading_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DeformableSurface(**kwargs)
