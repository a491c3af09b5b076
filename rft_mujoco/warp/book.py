"""The ``xfrc_applied`` bookkeeping of the batched sand (:mod:`rft_mujoco.coupling.dispatch`): the user's part of
each attached body's row before an evaluation (with the broadphase and the zeroing of the accumulators),
``user + sand`` after it, and the user's part back at detach."""

from __future__ import annotations

import warp as wp

from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.warp.common import F64, FLAT, gravity_of


# --- the user's part of xfrc_applied (rft_mujoco.coupling.dispatch) --------------------------------
@wp.func
def _untouched_minus_added(x: wp.spatial_vector, wr: wp.spatial_vector, ad: wp.spatial_vector):
    """``x - ad`` on the components the user left as written (coupling.book.untouched_components): every
    component when the whole row is as written, else those equal to a non-zero written value."""
    row_same = int(1)
    for c in range(6):
        if x[c] != wr[c]:
            row_same = 0
    out = x
    for c in range(6):
        if x[c] == wr[c] and (row_same == 1 or wr[c] != 0.0):
            out[c] = x[c] - ad[c]
    return out


@wp.kernel
def user_part(body_id: wp.array(dtype=int), xfrc: wp.array2d(dtype=wp.spatial_vector),
              written: wp.array2d(dtype=wp.spatial_vector), added: wp.array2d(dtype=wp.spatial_vector),
              bound_center: wp.array(dtype=wp.vec3), bound_radius: wp.array(dtype=F64),
              xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), gravity: wp.array(dtype=wp.vec3),
              kind: int, flat_height: wp.array(dtype=float), tp: wp.array(dtype=float),
              user: wp.array2d(dtype=wp.spatial_vector), cand: wp.array2d(dtype=int), touch: wp.array2d(dtype=int),
              wrench: wp.array2d(dtype=wp.spatial_vector), count: wp.array2d(dtype=int),
              max_depth: wp.array2d(dtype=float), occluded: wp.array2d(dtype=float)):
    """``user = xfrc - added`` on the components the user left as written (coupling.book.untouched_components);
    the broadphase (cand[w, b] = 0 when body b's bounding sphere is above the highest point of the sand, as
    SandHandle._touching_numpy: a shortcut, nothing changes); zeroes this evaluation's accumulators."""
    w, b = wp.tid()
    bid = body_id[b]
    center = xpos[w, bid] + xmat[w, bid] * bound_center[b]
    g, _mag = gravity_of(gravity, w)
    top = tp[ts.TP_MAX_HEIGHT]                    # the terrain's highest point at attach
    if kind == FLAT:
        top = flat_height[w % flat_height.shape[0]]
    cand[w, b] = 0
    if -wp.dot(center, g) - float(bound_radius[b]) < top:
        cand[w, b] = 1
    x = xfrc[w, body_id[b]]
    wr = written[w, b]
    ad = added[w, b]
    out = _untouched_minus_added(x, wr, ad)
    user[w, b] = out
    touch[w, b] = 0
    wrench[w, b] = wp.spatial_vector()
    count[w, b] = 0
    max_depth[w, b] = 0.0
    occluded[w, b] = 0.0


# --- xfrc_applied = user + sand (dispatch.Dispatcher.__call__, commit) -----------------------------
@wp.kernel
def commit(body_id: wp.array(dtype=int), user: wp.array2d(dtype=wp.spatial_vector),
           sand: wp.array2d(dtype=wp.spatial_vector), xfrc: wp.array2d(dtype=wp.spatial_vector),
           added: wp.array2d(dtype=wp.spatial_vector), written: wp.array2d(dtype=wp.spatial_vector)):
    w, b = wp.tid()
    s = sand[w, b]
    x = user[w, b] + s
    xfrc[w, body_id[b]] = x
    added[w, b] = s
    written[w, b] = x


@wp.kernel
def remove_sand(body_id: wp.array(dtype=int), xfrc: wp.array2d(dtype=wp.spatial_vector),
                written: wp.array2d(dtype=wp.spatial_vector), added: wp.array2d(dtype=wp.spatial_vector),
                user: wp.array2d(dtype=wp.spatial_vector)):
    """Detach: xfrc_applied rows := the user's part (dispatch.Dispatcher.remove_sand)."""
    w, b = wp.tid()
    x = xfrc[w, body_id[b]]
    wr = written[w, b]
    ad = added[w, b]
    out = _untouched_minus_added(x, wr, ad)
    xfrc[w, body_id[b]] = out
    added[w, b] = wp.spatial_vector()
    written[w, b] = out
