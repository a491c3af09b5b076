"""What ``attach`` computes once: the attached bodies' surface elements, their weld groups, their culling.

* Elements (:func:`rft_mujoco.geometry.surface.body_elements`) in each body's frame, with elements inside
  another geom of the same body removed.
* Groups (:class:`Groups`): attached bodies welded together move as one rigid body; the rest treatment
  solves per group.
* Culling across bodies: elements inside a geom of another body of the same weld group (a foot sphere
  inside its calf: their relative pose never changes) are removed here; geoms of other weld groups are
  the run-time occluders (:func:`rft_mujoco.compiled.elements.occluders`), tested at each evaluation.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import mujoco
import numpy as np

from rft_mujoco.coupling.callers import user_stacklevel
from rft_mujoco.geometry import occlusion, surface
from rft_mujoco.tables import table

MAX_ELEMENTS_PER_BODY = 1_000_000
"""Most surface elements one body may be cut into (memory and time guard against absurd resolutions)."""


def body_id(model, name) -> int:
    if isinstance(name, (int, np.integer)):
        if not 0 < int(name) < model.nbody:
            raise ValueError(f"body id {name} out of range 1..{model.nbody - 1} (0 is the world)")
        return int(name)
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if bid < 0:
        names = [model.body(i).name for i in range(1, model.nbody)]
        raise ValueError(f"no body named {name!r} in the model; bodies are {names}")
    if bid == 0:
        raise ValueError("the world body cannot be a sand intruder")
    return bid


_TERRAIN_GEOMS = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)


def body_ids(model, bodies) -> list[int]:
    """The bodies to attach: ``bodies`` (a name, an id, or a sequence of them) as MuJoCo ids, or, for None,
    every body but the world that has a geom other than a plane or heightfield. Raises ValueError on an
    unknown name, an id out of range, the world, a body listed twice, or nothing to attach."""
    if bodies is None:
        ids = [b for b in range(1, model.nbody)
               if any(model.geom_bodyid[g] == b and model.geom_type[g] not in _TERRAIN_GEOMS
                      for g in range(model.ngeom))]
    else:
        if isinstance(bodies, (str, int, np.integer)):
            bodies = [bodies]
        ids = [body_id(model, b) for b in bodies]
        if len(set(ids)) != len(ids):
            raise ValueError(f"bodies lists a body twice: {list(bodies)}")
    if not ids:
        raise ValueError("no bodies to attach sand to: the model has no body with surface geoms")
    return ids


@dataclasses.dataclass(frozen=True, eq=False)
class Groups:
    """The attached bodies of one handle grouped by MuJoCo weld group (bodies welded together move as one).

    Attributes:
        of_body: (B,) int, the group of each attached body.
        ref: (G,) int, the attached body (index into ``body_ids``) whose COM is the group's reference point.
        radius: (G,) m, radius about the reference point of a sphere holding the group's elements.
    """

    of_body: np.ndarray
    ref: np.ndarray
    radius: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class Surfaces:
    """The attached bodies' elements (body frames, concatenated) and what culling removed.

    Attributes:
        centroids, normals: (E, 3) float, m and unit, each element in its body's frame.
        areas: (E,) float, m^2.
        elem_body: (E,) int, the attached body (index into ``body_ids``) of each element.
        culled_area: (B,) float, m^2 of each body's surface removed at attach (inside its own other geoms or
            inside a geom welded to it).
    """

    centroids: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    elem_body: np.ndarray
    culled_area: np.ndarray


def _check_element_count(model, body_id: int, name: str, size: float) -> None:
    """Raise before tessellating if ``size`` would cut the body into more than MAX_ELEMENTS_PER_BODY."""
    geoms = np.flatnonzero(model.geom_bodyid == body_id)
    area = sum(4.0 * np.pi * float(model.geom_rbound[g]) ** 2 for g in geoms
               if model.geom_type[g] not in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD))
    estimate = area / size**2
    if estimate > MAX_ELEMENTS_PER_BODY:
        coarsest = math.sqrt(area / MAX_ELEMENTS_PER_BODY)
        raise ValueError(f"resolution {size:g} m would cut body {name!r} (surface ~{area:.3g} m^2) into about "
                         f"{estimate:.3g} surface elements (limit {MAX_ELEMENTS_PER_BODY}); use an element "
                         f"size of at least {coarsest:.3g} m, or a preset name "
                         f"{dict(surface.RESOLUTIONS)}")


def surfaces(model, body_ids, names, size: float, cull: bool = True) -> Surfaces:
    """Elements of every attached body, culled (``cull``) inside its own geoms and inside geoms welded to it.

    Raises one ValueError naming every body and geom that cannot be cut into elements (each with what to
    do). The geometry's warnings (a mesh used as given, approximated: :class:`SandSetupWarning`) are
    re-issued at the user's line.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = _surfaces(model, body_ids, names, size, cull)
    seen = set()
    for w in caught:                            # once per text: a mesh asset used by several geoms warns once
        if (str(w.message), w.category) not in seen:
            seen.add((str(w.message), w.category))
            warnings.warn(w.message, w.category, stacklevel=user_stacklevel())
    return out


def _surfaces(model, body_ids, names, size: float, cull: bool) -> Surfaces:
    data = mujoco.MjData(model)                 # relative poses inside a weld group never change
    mujoco.mj_kinematics(model, data)
    parts, culled, errors = [], np.zeros(len(body_ids)), []
    for i, (b, name) in enumerate(zip(body_ids, names)):
        _check_element_count(model, int(b), name, size)
        try:
            if cull:
                kept, cut = surface.body_elements_with_culled(model, int(b), size)
            else:
                kept = surface.body_elements(model, int(b), size, cull=False)
                cut = surface.Elements(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        except ValueError as exc:
            errors.append((name, str(exc)))
            parts.append(surface.Elements.concatenate([]))
            continue
        culled[i] = cut.area()
        # the other bodies of the same weld group, posed in this body's frame
        welded = [w for w in range(1, model.nbody) if w != b and model.body_weldid[w] == model.body_weldid[b]]
        if cull and welded and len(kept):
            rot = data.xmat[b].reshape(3, 3)
            occluders = []
            for w in welded:
                rel_rot = rot.T @ data.xmat[w].reshape(3, 3)
                rel_pos = rot.T @ (data.xpos[w] - data.xpos[b])
                occluders += [o.transformed(rel_pos, rel_rot) for o in occlusion.geom_occluders(model, w)]
            inside = occlusion.occluded(kept.centroids, occluders) if occluders else np.zeros(len(kept), bool)
            if inside.any():
                culled[i] += float(kept.areas[inside].sum())
                keep = ~inside
                kept = surface.Elements(kept.centroids[keep], kept.normals[keep], kept.areas[keep])
        mass = model.body_subtreemass[model.body_weldid[b]]
        if len(kept) and mass <= 0:
            raise ValueError(f"body {name!r} has zero mass (mass of its weld group {mass}); sand forces on a "
                             "massless body have nothing to act on: give it a mass or leave it out of bodies=")
        parts.append(kept)
    if errors:
        bad = [n for n, _ in errors]
        raise ValueError(f"cannot cut {len(errors)} bodies into surface elements: "
                         + "; ".join(f"body {n!r}: {e}" for n, e in errors)
                         + f". Fix each as said, or leave these bodies out of bodies= (failing: {bad})")
    counts = [len(p) for p in parts]
    if sum(counts) == 0:
        raise ValueError(f"bodies {list(names)} have no surface geoms (planes and heightfields are terrain, not "
                         "intruders); choose bodies with sphere/capsule/box/... geoms")
    el = surface.Elements.concatenate(parts)
    return Surfaces(np.ascontiguousarray(el.centroids), np.ascontiguousarray(el.normals),
                    np.ascontiguousarray(el.areas), np.repeat(np.arange(len(body_ids)), counts), culled)


def bounding_spheres(centroids, elem_body, n_bodies: int, size: float):
    """(B, 3) centres and (B,) radii (m, body frames) of spheres holding each body's elements, grown by the
    element size; radius -inf for a body without elements (never a broadphase candidate)."""
    center = np.zeros((n_bodies, 3))
    radius = np.full(n_bodies, -np.inf)
    for i in range(n_bodies):
        pts = centroids[elem_body == i]
        if pts.size:
            center[i] = 0.5 * (pts.min(0) + pts.max(0))
            radius[i] = np.linalg.norm(pts - center[i], axis=1).max() + size
    return center, radius


def groups(model, body_ids: np.ndarray, centroids: np.ndarray, elem_body: np.ndarray, size: float) -> Groups:
    """The weld groups of the attached bodies, their reference bodies and radii."""
    weld = model.body_weldid[body_ids]
    keys, of_body = np.unique(weld, return_inverse=True)
    ref = np.array([int(np.flatnonzero(of_body == g)[0]) for g in range(keys.size)], dtype=np.int64)
    data = mujoco.MjData(model)                 # the relative poses inside a weld group never change
    mujoco.mj_kinematics(model, data)
    radius = np.full(keys.size, size)
    for i, b in enumerate(body_ids):
        pts = centroids[elem_body == i]
        if not pts.size:
            continue
        world = data.xpos[b] + pts @ data.xmat[b].reshape(3, 3).T
        g = of_body[i]
        far = float(np.linalg.norm(world - data.xipos[body_ids[ref[g]]], axis=1).max())
        radius[g] = max(radius[g], far + size)
    return Groups(of_body.astype(np.int64), ref, radius)


def smallest_feature(model, geom: int) -> float:
    """m: the smallest dimension of a geom (diameter of a sphere, capsule or cylinder, smallest full extent
    of a box or ellipsoid, smallest extent of a mesh's bounding box in its frame); 0 for terrain."""
    t, s = int(model.geom_type[geom]), np.asarray(model.geom_size[geom], dtype=float)
    g = mujoco.mjtGeom
    if t in (g.mjGEOM_SPHERE, g.mjGEOM_CAPSULE):
        return 2.0 * float(s[0])
    if t == g.mjGEOM_CYLINDER:
        return 2.0 * float(min(s[0], s[1]))
    if t in (g.mjGEOM_BOX, g.mjGEOM_ELLIPSOID):
        return 2.0 * float(s[:3].min())
    if t == g.mjGEOM_MESH:
        m = int(model.geom_dataid[geom])
        v = np.asarray(model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]])
        return float((v.max(axis=0) - v.min(axis=0)).min()) if v.size else 0.0
    return 0.0


def describe(model, body_ids, elem_body: np.ndarray, areas: np.ndarray, culled_area: np.ndarray) -> list[dict]:
    """What the sand sees, per attached body: ``body``, ``geoms`` (names, or ``type#id``), ``source``
    ("collision" or "visual": the rule of :func:`rft_mujoco.geometry.occlusion.surface_geoms`), ``area``
    (m^2 exposed, after culling), ``culled`` (m^2 removed at attach), ``elements`` and ``smallest`` (m,
    :func:`smallest_feature` over the geoms used)."""
    n = len(body_ids)
    count = np.bincount(elem_body, minlength=n)
    area = np.bincount(elem_body, areas, minlength=n)
    rows = []
    for i, b in enumerate(body_ids):
        used = occlusion.surface_geoms(model, int(b))
        collide = [bool(model.geom_contype[g] or model.geom_conaffinity[g]) for g in used]
        names = []
        for g in used:
            t = mujoco.mjtGeom(int(model.geom_type[g])).name.removeprefix("mjGEOM_").lower()
            names.append(f"{model.geom(int(g)).name or t + '#' + str(int(g))}"
                         + (f" ({t})" if model.geom(int(g)).name else ""))
        rows.append(dict(body=model.body(int(b)).name or f"body {int(b)}", geoms=names,
                         source="collision" if any(collide) else ("visual" if len(used) else "-"),
                         area=float(area[i]), culled=float(culled_area[i]), elements=int(count[i]),
                         smallest=min((smallest_feature(model, int(g)) for g in used), default=0.0)))
    return rows


def summary_text(rows: list[dict], size: float) -> str:
    """:func:`describe`'s rows as a table, with the totals and the element size (m)."""
    body = [[r["body"], r["source"], str(r["elements"]), f"{r['area']:.4g}", f"{r['culled']:.3g}",
             f"{r['smallest']:.3g}" + (" (< element)" if 0 < r["smallest"] < size else ""),
             ", ".join(r["geoms"]) if len(r["geoms"]) <= 4
             else ", ".join(r["geoms"][:3]) + f", ... ({len(r['geoms'])})"]
            for r in rows]
    total_a = sum(r["area"] for r in rows)
    total_n = sum(r["elements"] for r in rows)
    return "\n".join([table(["body", "source", "elements", "area m^2", "culled m^2", "smallest m", "geoms"], body,
                             align="<<>>>><"),
                      f"total: {total_n} elements over {total_a:.4g} m^2 at element size {size:g} m "
                      f"({total_n / max(total_a / size**2, 1e-300):.2f} x area / size^2)"])


def attachable_bodies(model, bodies) -> list[int]:
    """The body ids :func:`rft_mujoco.attach` takes for ``bodies`` (None, a name or id, or a sequence of them):
    :func:`body_ids` with the mistakes it would misreport said plainly, without static and mocap bodies."""
    return _movable(model, bodies, _body_ids(model, bodies))


def _body_ids(model, bodies) -> list[int]:
    """:func:`body_ids`, with the mistakes it would misreport said plainly."""
    if bodies is not None and not isinstance(bodies, (str, int, np.integer)):
        try:
            bodies = list(bodies)
        except TypeError:
            raise TypeError(f"bodies must be None (every body), a body name or id, or a sequence of them; got "
                            f"{type(bodies).__name__}") from None
        if not bodies:
            raise ValueError("bodies is empty: name the bodies that touch the sand, or pass None for every body "
                             "with surface geoms")
        bad = [b for b in bodies if not isinstance(b, (str, int, np.integer))]
        if bad:
            raise TypeError(f"bodies must hold body names (str) or ids (int), got {bad!r}")
    return body_ids(model, bodies)


def _movable(model, bodies, ids: list[int]) -> list[int]:
    """The bodies of ``ids`` that sand forces can move: not welded to the world (static) and not mocap.
    Those are dropped when ``bodies`` is None and refused when named (they would feel nothing)."""
    fixed = [b for b in ids if model.body_weldid[b] == 0 or model.body_mocapid[b] >= 0]
    if not fixed:
        return ids
    if bodies is not None:
        names = [model.body(b).name or f"#{b}" for b in fixed]
        raise ValueError(f"bodies {names} are static or mocap (welded to the world or moved by mocap_pos): forces "
                         "in xfrc_applied cannot move them, so they would feel nothing. Give them a joint "
                         "(e.g. <freejoint/>) to let the sand act on them, or use rft_mujoco.coupling.rollout to "
                         "record the sand force along a prescribed motion")
    ids = [b for b in ids if b not in fixed]
    if not ids:
        raise ValueError("no movable body with surface geoms to attach sand to: every body with geoms is static "
                         "or mocap; give a body a joint (e.g. <freejoint/>)")
    return ids
