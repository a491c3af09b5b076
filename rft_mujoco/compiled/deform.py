"""The deformable surface's grid update, compiled: the numba mirror of :func:`rft_mujoco.physics.deform.press`.

:func:`press` does what the numpy :func:`~rft_mujoco.physics.deform.press` does (footprint, yield and reload
settlement, berm, slope flow, burying of the sand received), in the same order of operations, on one
MjData's state (the ``(2 ny, nx)`` heights-over-preload array of :func:`rft_mujoco.compiled.terrain.
deformable_heights`, ``cycles`` and ``reach`` (ny, nx)); the numpy function stays the reference
(tests/test_deform_compiled.py compares them on random and structured inputs: heights and preload to
round-off). What differs is the bookkeeping, so that a press costs what the pressed nodes cost and not the
grid's size: the nodes are found element by element (a node's lowest or highest body surface kept in
grid-sized scratch arrays that are cleared where they were written), and the reach is zeroed only at the
nodes the last press left it on (``live``: count, then the nodes). :func:`press_touching` gathers the
elements of the touching bodies that the compiled broadphase found (the coupling's
:func:`rft_mujoco.coupling.deformable.press_touching` in numpy) and presses with them.

``tp`` (the :class:`~rft_mujoco.physics.terrain_spec.TerrainSpec` of a :class:`~rft_mujoco.DeformableSurface`)
carries the grid and its rules, read by their named slots (:data:`rft_mujoco.physics.terrain_spec.PARAMS`).
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.physics import terrain_spec as ts

STATS = ("covered", "yielded", "displaced", "deposited", "lost", "settled")
"""Entries of :func:`press`'s ``stats`` (6,): those of :class:`rft_mujoco.physics.deform.PressResult`."""

STATE = ("grid", "cycles", "reach", "live")
"""The ``state`` bundle: one MjData's surface as the press reads and writes it: ``grid`` (2 ny, nx) heights over
preload, m (:func:`rft_mujoco.compiled.terrain.deformable_heights`), ``cycles`` and ``reach`` (ny, nx), ``live``
(ny nx + 1,) int: the number of nodes whose reach may be non-zero, then those nodes (:func:`buffers`)."""
ELEMENTS = ("pts", "nrm", "areas")
"""The ``elements`` bundle: world elements, ``pts`` (E, 3) m, unit ``nrm`` (E, 3), ``areas`` (E,) m^2 (the first
``n`` rows press; :func:`press_touching` gathers into :func:`buffers`' ``pts``, ``nrm``, ``ar``)."""
SCRATCH = ("mark", "val", "nodes", "low", "rim")
"""The ``scratch`` bundle (:func:`buffers`): ``mark`` (ny nx,) int, all 0 (left so), ``val`` (ny nx,), ``nodes``
(ny nx,) int, ``low`` (ny nx,), ``rim`` (ny nx,) int."""
SCHEDULE = ("clock", "time", "dt", "slack")
"""The ``schedule`` bundle of :func:`press_touching`: ``clock`` (2,) s, the times of the last update and of the
last evaluation with bodies touching (written), the evaluation's ``time`` (s), the model's timestep ``dt`` (s) and
``slack`` (1 + the schedule's tolerance: :func:`rft_mujoco.physics.deform.schedule`)."""
TOUCHING = ("touch", "body_pos", "body_mat")
"""The ``touching`` bundle: the broadphase's rows of the touching bodies, ``touch`` (indices into the handle's
bodies), their poses ``body_pos`` (k, 3) m and ``body_mat`` (k, 9) (the first ``k`` rows)."""
PACKED = ("centroids", "normals", "areas", "cluster_start", "body_clusters")
"""The ``packed`` bundle: the handle's packed elements (:func:`rft_mujoco.compiled.elements.pack`; the handle
constants' ``H_CENTROIDS`` (3, E) m and ``H_NORMALS`` (3, E) in the body frames, ``H_AREAS`` (E,) m^2,
``H_CLUSTER_START``, ``H_BODY_CLUSTERS``; padding slots are NaN)."""

_FACING = 1e-6              # rft_mujoco.physics.deform.FACING_DOWN (tests check they are equal)
_YIELD = 1e-12              # rft_mujoco.physics.deform.YIELD_TOL (likewise)
_RELAX_ITERATIONS = 10      # rft_mujoco.physics.deform.RELAX_ITERATIONS
_RELAX_SHARE = 0.125        # rft_mujoco.physics.deform.RELAX_SHARE


_TILE = 4
"""Nodes per side of the tiles over which :func:`_cover` skips the elements that cannot meet a node."""


@njit(**JIT)
def _tiles(h, nx, ny, i0, i1, j0, j1, facing, mark, want):
    """(rows, cols) tile maxima over the nodes ``[i0, i1] x [j0, j1]`` (clipped to the grid), tiles of
    :data:`_TILE` nodes from ``(i0, j0)``: of the heights ``h`` (``facing=-1``), or 1 where a node is marked
    ``want`` in ``mark`` and -1 elsewhere (``facing=+1``)."""
    i0, j0 = max(i0, 0), max(j0, 0)
    i1, j1 = min(i1, ny - 1), min(j1, nx - 1)
    out = np.full(((max(i1 - i0, -1) + _TILE) // _TILE, (max(j1 - j0, -1) + _TILE) // _TILE), -np.inf)
    for i in range(i0, i1 + 1):
        ti = (i - i0) // _TILE
        for j in range(j0, j1 + 1):
            node = i * nx + j
            v = h[node] if facing < 0 else (1.0 if mark[node] == want else -1.0)
            tj = (j - j0) // _TILE
            if v > out[ti, tj]:
                out[ti, tj] = v
    return out, i0, j0


@njit(**JIT)
def _cover(tp, nx, ny, h, elements, n, facing, mark, val, want, bbox, top):
    """One ``covering`` pass: every element (the first ``n`` of ``elements``, :data:`ELEMENTS`) facing ``facing``
    (-1: down, +1: up) over the nodes of its grown projected rectangle, at its plane's height there.
    ``facing=-1``: only where below ``h`` (the surface), the highest such height kept in ``val`` and the node
    marked 1 in ``mark`` (a node met first sets ``bbox``); ``facing=+1``: only nodes marked ``want`` (1) or 2
    (inside ``bbox``), the highest height in ``val`` and the mark set to 2. ``top``: m, no node is higher
    (elements wholly above it are skipped; NaN: none is). An element whose nodes are all above its lowest point
    (down) or none of them marked (up) is skipped by the maxima of :func:`_tiles` over the tiles its nodes are
    in: what it would have done is nothing, so the numbers are those of testing every node."""
    pts, nrm, areas = elements
    sx, sy, ox, oy = tp[ts.TP_GRID_DX], tp[ts.TP_GRID_DY], tp[ts.TP_GRID_X0], tp[ts.TP_GRID_Y0]
    smin = min(sx, sy)
    grow = tp[ts.TP_COVER_GROW] * smin
    half_max = 0.0
    xlo = ylo = np.inf
    xhi = yhi = -np.inf
    for e in range(n):
        if nrm[e, 2] * -facing < -_FACING:
            half_max = max(half_max, 0.5 * math.sqrt(areas[e]))
            xlo, xhi = min(xlo, pts[e, 0]), max(xhi, pts[e, 0])
            ylo, yhi = min(ylo, pts[e, 1]), max(yhi, pts[e, 1])
    k = int(math.ceil(half_max / smin)) + 2
    isx, isy = 1.0 / sx, 1.0 / sy
    if not xlo <= xhi:
        return
    if facing < 0:                                # the heights' maxima where the elements' nodes can be
        reach = (half_max + grow) * 1.5 + smin
        tiles, ti0, tj0 = _tiles(h, nx, ny, max(int(math.floor((ylo - reach - oy) * isy)), -1),
                                 int(math.ceil((yhi + reach - oy) * isy)), max(int(math.floor((xlo - reach - ox)
                                 * isx)), -1), int(math.ceil((xhi + reach - ox) * isx)), facing, mark, want)
    else:                                         # the marked nodes' tiles
        tiles, ti0, tj0 = _tiles(h, nx, ny, bbox[0], bbox[1], bbox[2], bbox[3], facing, mark, want)
    for e in range(n):
        n0, n1, n2 = nrm[e, 0], nrm[e, 1], nrm[e, 2]
        if not n2 * -facing < -_FACING:
            continue
        half = 0.5 * math.sqrt(areas[e])
        flat_h = math.sqrt(n0 * n0 + n1 * n1)
        level = flat_h <= _FACING
        tx = 1.0 if level else n0 / flat_h
        ty = 0.0 if level else n1 / flat_h
        along = half * abs(n2)
        slope = flat_h / n2
        p0, p1, p2 = pts[e, 0], pts[e, 1], pts[e, 2]
        # the nodes tested: numpy's window (k nodes around the nearest) cut to the grown rectangle's extent
        # along x and y, with slack (the test below decides, as in numpy)
        eu, ew = along + grow, half + grow
        ex = (eu * abs(tx) + ew * abs(ty)) * (1.0 + 1e-9) + 1e-12
        ey = (eu * abs(ty) + ew * abs(tx)) * (1.0 + 1e-9) + 1e-12
        a0 = max(int(math.floor((p1 - ey - oy) * isy)), 0)
        a1 = min(int(math.ceil((p1 + ey - oy) * isy)), ny - 1)
        b0 = max(int(math.floor((p0 - ex - ox) * isx)), 0)
        b1 = min(int(math.ceil((p0 + ex - ox) * isx)), nx - 1)
        if ex > (k - 2) * sx or ey > (k - 2) * sy:      # the extent may reach beyond numpy's window: cut it
            jc = int(np.rint((p0 - ox) / sx))
            ic = int(np.rint((p1 - oy) / sy))
            a0, a1 = max(a0, ic - k), min(a1, ic + k)
            b0, b1 = max(b0, jc - k), min(b1, jc + k)
        if facing < 0:                    # no node of the window is above this element's lowest point
            if p2 - abs(slope) * along >= top:
                continue
        elif a1 < bbox[0] or a0 > bbox[1] or b1 < bbox[2] or b0 > bbox[3]:
            continue                      # no node under a downward surface in its window
        t0, t1 = max(a0 - ti0, 0) // _TILE, min((a1 - ti0) // _TILE, tiles.shape[0] - 1)
        u0, u1 = max(b0 - tj0, 0) // _TILE, min((b1 - tj0) // _TILE, tiles.shape[1] - 1)
        most = -np.inf
        for ti in range(t0, t1 + 1):
            for tj in range(u0, u1 + 1):
                most = max(most, tiles[ti, tj])
        if facing < 0 and not p2 - abs(slope) * along < most or facing > 0 and most < 0.0:
            continue                      # (the window's nodes are within the tiles: see the region above)
        for ii in range(a0, a1 + 1):
            dy = (oy + sy * ii) - p1
            for jj in range(b0, b1 + 1):
                dx = (ox + sx * jj) - p0
                u = dx * tx + dy * ty
                w = dy * tx - dx * ty
                if not (abs(u) <= along + grow and abs(w) <= half + grow):
                    continue
                z = p2 - slope * min(max(u, -along), along)
                node = ii * nx + jj
                if facing < 0:
                    if not z < h[node]:
                        continue
                    if mark[node] == 0:
                        mark[node] = 1
                        val[node] = z
                        bbox[0] = min(bbox[0], ii)
                        bbox[1] = max(bbox[1], ii)
                        bbox[2] = min(bbox[2], jj)
                        bbox[3] = max(bbox[3], jj)
                    elif z > val[node]:
                        val[node] = z
                else:
                    m = mark[node]
                    if m == want:
                        mark[node] = 2
                        val[node] = z
                    elif m == 2 and z > val[node]:
                        val[node] = z


@njit(**JIT)
def _berm(tp, nx, ny, nodes, m, bbox, mark, rim):
    """``berm_nodes``: the nodes (sorted flat indices, into ``rim``) within ``berm_cells`` nodes (Chebyshev) of the
    ``m`` covered ``nodes`` (marked 3 in ``mark``) and not covered; returns their number."""
    r = int(tp[ts.TP_BERM_CELLS])
    i0, i1 = max(bbox[0] - r, 0), min(bbox[1] + r, ny - 1)
    j0, j1 = max(bbox[2] - r, 0), min(bbox[3] + r, nx - 1)
    rows, cols = i1 - i0 + 1, j1 - j0 + 1
    wide = np.zeros((rows + 1, cols), dtype=np.int64)    # row a + 1: covered nodes within r columns, rows <= a
    for t in range(m):
        i, j = nodes[t] // nx - i0, nodes[t] % nx - j0
        for b in range(max(j - r, 0), min(j + r, cols - 1) + 1):
            wide[i + 1, b] = 1
    for a in range(rows):                                # running sums down each column
        for j in range(cols):
            wide[a + 1, j] += wide[a, j]
    count = 0
    for i in range(rows):
        lo, hi = max(i - r, 0), min(i + r, rows - 1) + 1
        for j in range(cols):
            if wide[hi, j] - wide[lo, j] > 0:
                node = (i + i0) * nx + j + j0
                if mark[node] != 3:
                    rim[count] = node
                    count += 1
    return count


@njit(**JIT)
def _relax(tp, nx, ny, h, q, bbox, mark):
    """``relax``: the slope flow at the nodes within ``relax_cells`` nodes of the covered nodes (marked 3 in ``mark``;
    they exchange nothing), then ``bury`` of the sand received: the numpy sweeps' numbers in their order of
    operations (each sweep's fluxes from the heights at its start; ``h[1:] -= f``, then ``h[:-1] += f``), row by
    row over each row's free nodes, skipping the rows where nothing can flow: a row none of whose nodes changed
    since the last sweep of the same direction began moves nothing (every pair's flux was, and is, 0)."""
    r = int(tp[ts.TP_RELAX_CELLS])
    i0, i1 = max(bbox[0] - r, 0), min(bbox[1] + r, ny - 1) + 1
    j0, j1 = max(bbox[2] - r, 0), min(bbox[3] + r, nx - 1) + 1
    rows, cols = i1 - i0, j1 - j0
    w = np.empty((rows, cols))
    free = np.zeros((rows, cols), dtype=np.bool_)
    near = np.zeros((rows + 1, cols), dtype=np.int64)   # row a + 1: covered nodes within r columns, rows <= a
    for i in range(rows):
        for j in range(cols):
            node = (i + i0) * nx + j + j0
            w[i, j] = h[node]
            if mark[node] == 3:
                for b in range(max(j - r, 0), min(j + r, cols - 1) + 1):
                    near[i + 1, b] = 1
    for a in range(rows):
        for j in range(cols):
            near[a + 1, j] += near[a, j]
    span_lo, span_hi = np.full(rows, cols), np.full(rows, -1)    # each row's free nodes (first, last)
    for i in range(rows):                           # free: within r nodes of a covered node, not covered
        lo, hi = max(i - r, 0), min(i + r, rows - 1) + 1
        for j in range(cols):
            if near[hi, j] - near[lo, j] > 0 and mark[(i + i0) * nx + j + j0] != 3:
                free[i, j] = True
                span_lo[i] = min(span_lo[i], j)
                span_hi[i] = j
    before = w.copy()
    lim_x, lim_y = tp[ts.TP_SLOPE] * tp[ts.TP_GRID_DX], tp[ts.TP_SLOPE] * tp[ts.TP_GRID_DY]
    pair_x = np.zeros((rows, cols))                 # 1 where both nodes of a pair are free (floats: the loops
    pair_y = np.zeros((rows, cols))                 # below then have no branch, and vectorize)
    for i in range(rows):
        for j in range(cols - 1):
            pair_x[i, j] = 1.0 if free[i, j] and free[i, j + 1] else 0.0
            if i + 1 < rows:
                pair_y[i, j] = 1.0 if free[i, j] and free[i + 1, j] else 0.0
        if i + 1 < rows and cols > 0:
            pair_y[i, cols - 1] = 1.0 if free[i, cols - 1] and free[i + 1, cols - 1] else 0.0
    f = np.empty(max(cols - 1, 0))
    fy = np.empty((max(rows - 1, 0), cols))
    dirty_x = np.ones(rows, dtype=np.bool_)         # rows changed since the last x sweep began
    dirty_y = np.ones(rows, dtype=np.bool_)         # ... since the last y sweep began
    moved_y = np.zeros(rows, dtype=np.bool_)
    for _ in range(_RELAX_ITERATIONS):
        any_moved = False
        for i in range(rows):                       # along x
            if not dirty_x[i]:
                continue
            dirty_x[i] = False
            row, px = w[i], pair_x[i]
            t0, t1 = span_lo[i], span_hi[i]         # (outside the row's free span every pair's flux is 0)
            nz = 0
            for j in range(t0, t1):                 # numpy's RELAX_SHARE * sign(d) * max(|d| - lim, 0), 0 off pairs
                d = row[j + 1] - row[j]
                v = _RELAX_SHARE * math.copysign(max(abs(d) - lim_x, 0.0), d) * px[j]
                f[j] = v
                nz |= v != 0.0
            if nz:
                for j in range(t0, t1):
                    row[j + 1] -= f[j]
                for j in range(t0, t1):
                    row[j] += f[j]
                dirty_x[i] = dirty_y[i] = True
                any_moved = True
        for i in range(rows - 1):                   # along y: every flux first, from the sweep's start
            moved_y[i] = False
            if not (dirty_y[i] or dirty_y[i + 1]):
                continue
            lo, hi, py = w[i], w[i + 1], pair_y[i]
            fi = fy[i]
            t0, t1 = max(span_lo[i], span_lo[i + 1]), min(span_hi[i], span_hi[i + 1])
            for j in range(min(span_lo[i], span_lo[i + 1]), max(span_hi[i], span_hi[i + 1]) + 1):
                fi[j] = 0.0
            nz = 0
            for j in range(t0, t1 + 1):
                d = hi[j] - lo[j]
                v = _RELAX_SHARE * math.copysign(max(abs(d) - lim_y, 0.0), d) * py[j]
                fi[j] = v
                nz |= v != 0.0
            moved_y[i] = nz != 0
        for i in range(rows):
            dirty_y[i] = False
        for i in range(rows - 1):
            if moved_y[i]:
                hi, fi = w[i + 1], fy[i]
                for j in range(max(span_lo[i], span_lo[i + 1]), min(span_hi[i], span_hi[i + 1]) + 1):
                    hi[j] -= fi[j]
        for i in range(rows - 1):
            if moved_y[i]:
                lo, fi = w[i], fy[i]
                for j in range(max(span_lo[i], span_lo[i + 1]), min(span_hi[i], span_hi[i + 1]) + 1):
                    lo[j] += fi[j]
                dirty_x[i] = dirty_x[i + 1] = dirty_y[i] = dirty_y[i + 1] = True
                any_moved = True
        if not any_moved:
            break                                   # nothing moved: the next sweeps move nothing
    for i in range(rows):
        for j in range(cols):
            node = (i + i0) * nx + j + j0
            h[node] = w[i, j]
            q[node] = max(q[node] - max(w[i, j] - before[i, j], 0.0), 0.0)


@njit(**JIT)
def _flow_windows(tp, nx, nodes, m):
    """The slope flow's windows: (g, 4) int, the bounding boxes (rows i0, i1, columns j0, j1) of groups of the
    ``m`` covered ``nodes``, and g. Groups are merged until every two are more than ``2 r + 1`` nodes apart
    (``r = relax_cells``, the flow's margin), so that no flowing pair joins two of them: the flow of each group's
    window (its box and ``r`` nodes around) is then the flow of the window around all of them, number for
    number (:func:`_relax`), at the cost of the nodes near the bodies instead of the box that holds them all
    (four feet far apart). Starts from the nodes' boxes per tile of ``2 r + 2`` nodes."""
    r = int(tp[ts.TP_RELAX_CELLS])
    tile = 2 * r + 2
    boxes = np.empty((m, 4), dtype=np.int64)
    g = 0
    for t in range(m):                          # one box per occupied tile, found by a scan of the few boxes
        i, j = nodes[t] // nx, nodes[t] % nx
        ti, tj = i // tile, j // tile
        b = 0
        while b < g and not (boxes[b, 0] // tile == ti and boxes[b, 2] // tile == tj
                             and boxes[b, 1] // tile == ti and boxes[b, 3] // tile == tj):
            b += 1
        if b == g:
            boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3] = i, i, j, j
            g += 1
        else:
            boxes[b, 0], boxes[b, 1] = min(boxes[b, 0], i), max(boxes[b, 1], i)
            boxes[b, 2], boxes[b, 3] = min(boxes[b, 2], j), max(boxes[b, 3], j)
    merged = True
    while merged:                               # merge any two boxes within 2 r + 1 nodes of each other
        merged = False
        for a in range(g):
            for b in range(a + 1, g):
                if (boxes[b, 0] - boxes[a, 1] <= 2 * r + 1 and boxes[a, 0] - boxes[b, 1] <= 2 * r + 1
                        and boxes[b, 2] - boxes[a, 3] <= 2 * r + 1 and boxes[a, 2] - boxes[b, 3] <= 2 * r + 1):
                    for c in (0, 2):
                        boxes[a, c] = min(boxes[a, c], boxes[b, c])
                        boxes[a, c + 1] = max(boxes[a, c + 1], boxes[b, c + 1])
                    g -= 1
                    boxes[b] = boxes[g]
                    merged = True
                    break
            if merged:
                break
    return boxes, g


@njit(**JIT)
def press(tp, state, elements, n, scratch, stats, highest=np.nan):
    """Deform the ``state`` (:data:`STATE`) in place under the first ``n`` of the ``elements`` (:data:`ELEMENTS`):
    :func:`rft_mujoco.physics.deform.press`, its result in ``stats`` (:data:`STATS`); ``live`` is written for the
    next press. ``scratch``: :data:`SCRATCH`. ``highest``: the surface's highest point before the press (m; NaN:
    unknown). Returns the highest point after the press (m; at least the initial height), or NaN when no node was
    lowered (the heights did not change)."""
    grid, cycles, reach, live = state
    mark, val, nodes, low, rim = scratch
    ny, nx = cycles.shape
    size = ny * nx
    flat = grid.reshape(2 * size)
    h = flat[:size]
    q = flat[size:]
    cyc = cycles.reshape(size)
    rch = reach.reshape(size)
    for c in range(6):
        stats[c] = 0.0
    bbox = np.array((ny, -1, nx, -1))
    _cover(tp, nx, ny, h, elements, n, -1, mark, val, 1, bbox, highest)
    m = 0
    kept = np.array((ny, -1, nx, -1))                 # the kept nodes' rows and columns
    if bbox[1] >= 0:
        _cover(tp, nx, ny, h, elements, n, 1, mark, low, 1, bbox, highest)   # the highest upward surface
        for i in range(bbox[0], bbox[1] + 1):              # sorted; kept where no upward surface is under the sand
            for j in range(bbox[2], bbox[3] + 1):
                node = i * nx + j
                mk = mark[node]
                if mk == 0:
                    continue
                if mk == 1 or low[node] >= h[node]:
                    nodes[m] = node
                    low[m] = val[node]
                    m += 1
                    kept[0] = min(kept[0], i)
                    kept[1] = max(kept[1], i)
                    kept[2] = min(kept[2], j)
                    kept[3] = max(kept[3], j)
                mark[node] = 0
    w0 = val                                          # (val's grid use is over: the first m entries)
    for t in range(m):
        w0[t] = rch[nodes[t]]
    for t in range(int(live[0])):
        rch[live[1 + t]] = 0.0
    live[0] = m
    for t in range(m):
        live[1 + t] = nodes[t]
    if m == 0:
        return np.nan
    stats[0] = m
    ratio, sink, decay = tp[ts.TP_RELOAD_RATIO], tp[ts.TP_RELOAD_SINKAGE], tp[ts.TP_RELOAD_DECAY]
    n_yield = n_settle = 0
    displaced = 0.0
    for t in range(m):
        node = nodes[t]
        if w0[t] == 0.0:
            cyc[node] += 1.0
        qn = q[node]
        elastic = qn / ratio
        nc = cyc[node]
        a_n = sink * decay ** max(nc - 2.0, 0.0) if nc >= 2.0 else 0.0
        settle_rate = a_n * qn
        rate = elastic + settle_rate
        push = h[node] - low[t] - w0[t] * elastic
        along = max(min(push, (1.0 - w0[t]) * rate), 0.0)
        w1 = w0[t] + along / rate if rate > 0.0 else 1.0
        beyond = push - along
        yielded = beyond > _YIELD
        settle = settle_rate * (w1 - w0[t])
        rch[node] = 1.0 if yielded else w1
        q_new = qn + beyond if yielded else qn
        q[node] = q_new
        new_h = low[t] + q_new / ratio if yielded else h[node] - settle
        if yielded or settle > 0.0:
            n_yield += yielded
            n_settle += not yielded
            displaced += h[node] - new_h
            h[node] = new_h
    stats[1] = n_yield
    stats[5] = n_settle
    if n_yield + n_settle == 0:
        return np.nan
    cell_area = tp[ts.TP_GRID_DX] * tp[ts.TP_GRID_DY]
    displaced *= cell_area
    stats[2] = displaced
    volume = (1.0 - tp[ts.TP_COMPACTION]) * displaced
    for t in range(m):
        mark[nodes[t]] = 3
    nr = _berm(tp, nx, ny, nodes, m, kept, mark, rim)
    virgin = 0
    for t in range(nr):
        if q[rim[t]] == 0.0:
            rim[virgin] = rim[t]                          # (in place: virgin <= t)
            virgin += 1
    nr = virgin if virgin else nr
    if nr == 0:
        stats[4] = volume
    else:
        add = volume / (nr * cell_area)
        for t in range(nr):
            node = rim[t]
            h[node] += add
            q[node] = max(q[node] - add, 0.0)
        stats[3] = volume
        if tp[ts.TP_RELAX] != 0.0:
            boxes, g = _flow_windows(tp, nx, nodes, m)
            for b in range(g):
                _relax(tp, nx, ny, h, q, boxes[b], mark)
    for t in range(m):
        mark[nodes[t]] = 0
    # the highest point now (DeformedSurface.max_height): every node that changed is within the slope flow's
    # window; when a node there reaches the highest point before, it is the highest now, else look everywhere
    r = int(tp[ts.TP_RELAX_CELLS])
    top = tp[ts.TP_HEIGHT]
    for i in range(max(kept[0] - r, 0), min(kept[1] + r, ny - 1) + 1):
        for j in range(max(kept[2] - r, 0), min(kept[3] + r, nx - 1) + 1):
            top = max(top, h[i * nx + j])
    if not top >= highest:
        top = tp[ts.TP_HEIGHT]
        for node in range(size):
            top = max(top, h[node])
    return top


@njit(**JIT)
def press_touching(tp, state, schedule, k, touching, packed, max_height, gather, scratch, stats):
    """:func:`rft_mujoco.coupling.deformable.press_touching`, compiled: at an evaluation with bodies touching, when
    an update is due (``schedule``: :data:`SCHEDULE`; :func:`rft_mujoco.physics.deform.schedule`), unload every
    node if the last step had nothing touching, then press the ``state`` (:data:`STATE`) with the elements of the
    ``k`` touching bodies (``touching``: :data:`TOUCHING`) that are below ``max_height`` (m, the surface's highest
    point now), from the handle's ``packed`` elements (:data:`PACKED`; padding slots are NaN: never below).
    ``gather``: :data:`ELEMENTS` buffers of the handle's size; ``scratch``, ``stats``: as :func:`press`. Returns
    what :func:`press` returns (NaN, the heights unchanged, when no update is due)."""
    clock, time, dt, slack = schedule
    _, _, reach, live = state
    touch, body_pos, body_mat = touching
    centroids, normals, areas, cluster_start, body_clusters = packed
    pts, nrm, ar = gather
    since_touch, interval = time - clock[1], tp[ts.TP_UPDATE_INTERVAL]
    clock[1] = time
    if not (0.0 <= since_touch <= dt * slack):
        for t in range(int(live[0])):
            reach.reshape(-1)[live[1 + t]] = 0.0
        live[0] = 0
    elif time - clock[0] < interval * (2.0 - slack):
        return np.nan
    clock[0] = time
    n = 0
    for j in range(k):
        b = touch[j]
        r = body_mat[j]
        px, py, pz = body_pos[j, 0], body_pos[j, 1], body_pos[j, 2]
        for c in range(body_clusters[b], body_clusters[b + 1]):
            for e in range(cluster_start[c], cluster_start[c + 1]):
                l0, l1, l2 = centroids[0, e], centroids[1, e], centroids[2, e]
                z = pz + (r[6] * l0 + r[7] * l1 + r[8] * l2)
                if not z < max_height:
                    continue
                pts[n, 0] = px + (r[0] * l0 + r[1] * l1 + r[2] * l2)
                pts[n, 1] = py + (r[3] * l0 + r[4] * l1 + r[5] * l2)
                pts[n, 2] = z
                m0, m1, m2 = normals[0, e], normals[1, e], normals[2, e]
                nrm[n, 0] = r[0] * m0 + r[1] * m1 + r[2] * m2
                nrm[n, 1] = r[3] * m0 + r[4] * m1 + r[5] * m2
                nrm[n, 2] = r[6] * m0 + r[7] * m1 + r[8] * m2
                ar[n] = areas[e]
                n += 1
    return press(tp, state, gather, n, scratch, stats, max_height)


def buffers(shape: tuple[int, int], n_elements: int) -> dict:
    """The arrays :func:`press_touching` needs besides the state, for a grid of ``shape`` (ny, nx) and a handle of
    ``n_elements`` packed elements: ``live`` (state: the nodes whose reach may be non-zero; all zero: none),
    ``stats`` (the last press's :data:`STATS`), and scratch (``mark`` zero, the others uninitialized)."""
    size = shape[0] * shape[1]
    e = max(int(n_elements), 1)
    return dict(live=np.zeros(size + 1, np.int64), stats=np.zeros(len(STATS)), mark=np.zeros(size, np.int64),
                val=np.empty(size), nodes=np.empty(size, np.int64), low=np.empty(size), rim=np.empty(size, np.int64),
                pts=np.empty((e, 3)), nrm=np.empty((e, 3)), ar=np.empty(e))
