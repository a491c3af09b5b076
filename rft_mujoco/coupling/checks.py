"""Set-up checks of :func:`rft_mujoco.attach`: mistakes that give wrong sand without any error.

Each check reads the model (and the handles or the terrain) as it is now and either raises
:class:`ValueError` (a set-up that cannot be right) or warns once per call with :class:`SandSetupWarning`
(one warning naming everything it found), saying what was given, what is allowed and what to do:

* :func:`check_not_attached` -- a body attached twice to one model gets the sand twice (raises);
* :func:`check_rigid_floor` -- a rigid floor the bodies collide with, at or above the sand's lowest
  point, carries them and the sand does nothing (warns); it reads ``geom_contype``/``geom_conaffinity``
  now, so run it after ``handle.replace_rigid`` had its chance (at the handle's first evaluation);
* :func:`check_timestep` -- timesteps beyond what the stability study measured (warns);
* :func:`check_resolution` -- bodies thinner than two element sizes, whose forces are the discretization's (warns);
* :func:`check_sand_surfaces` -- bodies whose sand surface is their visual geoms, or whose collision geoms
  cover far less than their visual ones (warns);
* :func:`check_replaced_floor` -- a floor replaced by the sand that is not at the sand's height (warns);
* :func:`check_actuation_flag` -- ``mjDSBL_ACTUATION`` makes MuJoCo skip ``mjcb_control``; the dispatcher
  then evaluates the sand from ``mjcb_passive``, which MuJoCo also skips once springs and dampers are
  disabled too: with all three flags there is no hook left (raises :data:`ACTUATION_DISABLED_MESSAGE`).

MuJoCo's collision filter (:func:`can_collide`, ``../shared/reference/mujoco-notes.md``): two geoms of
different weld bodies collide when ``contype1 & conaffinity2 or contype2 & conaffinity1`` and no
``<exclude>`` names their bodies, or when an explicit ``<pair>`` names them; ``mjDSBL_CONTACT`` or
``mjDSBL_CONSTRAINT`` switch every contact off. (The parent filter never applies to the world's geoms.)
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import mujoco
import numpy as np

from rft_mujoco.coupling.callers import user_stacklevel
from rft_mujoco.geometry.elements import SandSetupWarning
from rft_mujoco.physics.law import gravity_direction
from rft_mujoco.physics.terrain import HeightfieldSurface, SandRegion, Terrain, as_terrain

ACCURATE_TIMESTEP_MAX = 0.005
"""s: the rest treatment was measured accurate up to this timestep (the load-path study: 0.5-5 ms,
``rft_mujoco.studies.loadpaths.TIMESTEPS``); the timestep :func:`check_timestep` recommends."""
STUDIED_TIMESTEP_MAX = 0.01
"""s: the largest timestep of the stability study (0.25-10 ms, ``rft_mujoco.studies.stability.TIMESTEPS``);
:func:`check_timestep` warns above it."""
FLOOR_HEIGHT_TOL = 1e-9
"""m: a rigid plane this far below the sand's lowest point still counts as "at" it (round-off of poses)."""
HORIZONTAL_TOL = 1e-9
"""A plane whose unit normal has ``n . up >= 1 - HORIZONTAL_TOL`` is horizontal (``up = -g_hat``)."""
ACTUATION_DISABLED_MESSAGE = (
    "model.opt.disableflags has mjDSBL_ACTUATION, mjDSBL_SPRING and mjDSBL_DAMPER set: MuJoCo then skips "
    "both mjcb_control and mjcb_passive, through which rft_mujoco computes the sand, so there would be no "
    "sand at all (measured: a 0.2 kg plate on sand falls 4.9 m in 1 s). Clear one of the flags (with "
    "mjDSBL_ACTUATION alone the sand still acts), or zero data.ctrl or the actuator gains instead.")
"""What :func:`rft_mujoco.attach` raises when :func:`check_actuation_flag` is True."""

_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
_HFIELD = int(mujoco.mjtGeom.mjGEOM_HFIELD)


# --- one body, one sand -------------------------------------------------------------------------------
def check_not_attached(model, body_ids: Sequence[int], handles, *, terrain: Terrain | None = None) -> None:
    """Raise ValueError when a body of ``body_ids`` is already attached to ``model`` by a live handle.

    Both handles would add their sand to the body, twice the force. Allowed: the same bodies on several
    models, other bodies of the same model, and (with ``terrain`` given) the same bodies on sands whose
    :class:`~rft_mujoco.SandRegion` rectangles do not overlap (each patch loads only the elements above
    it; a body that straddles two patches at rest is held by both).

    Args:
        model: the MjModel being attached to.
        body_ids: (B,) int, the bodies of the new attachment.
        handles: the live handles (each with ``.model``, ``.body_ids``, ``.body_names``, ``.attached`` and,
            for the region exception, ``.terrain``).
        terrain: the new attachment's terrain (None: no exception for disjoint regions).
    """
    wanted = {int(b) for b in body_ids}
    for h in handles:
        if h.model is not model or not h.attached:
            continue
        shared = [int(b) for b in h.body_ids if int(b) in wanted]
        if not shared or (terrain is not None and _disjoint(terrain, getattr(h, "terrain", None))):
            continue
        names = [h.body_names[list(map(int, h.body_ids)).index(b)] or f"body {b}" for b in shared]
        raise ValueError(
            f"bodies {names} are already attached to this model by {h!r}: attaching them again would add "
            "the sand to them twice. Detach that handle first (handle.detach()), or leave these bodies out "
            "of bodies= (one handle per body; a different medium on a separate patch needs SandRegion "
            "terrains that do not overlap)")


def _disjoint(a, b) -> bool:
    """Whether terrains ``a`` and ``b`` are SandRegions whose rectangles share no area."""
    if not (isinstance(a, SandRegion) and isinstance(b, SandRegion)):
        return False
    return (a.x_range[1] <= b.x_range[0] or b.x_range[1] <= a.x_range[0]
            or a.y_range[1] <= b.y_range[0] or b.y_range[1] <= a.y_range[0])


# --- rigid floors --------------------------------------------------------------------------------------
def can_collide(model, geom1: int, geom2: int) -> bool:
    """Whether MuJoCo generates contacts between two geoms (its filters; see the module docstring)."""
    disabled = int(model.opt.disableflags)
    if disabled & (int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)):
        return False
    g1, g2 = int(geom1), int(geom2)
    for p in range(model.npair):
        if {int(model.pair_geom1[p]), int(model.pair_geom2[p])} == {g1, g2}:
            return True
    b1, b2 = int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])
    if model.body_weldid[b1] == model.body_weldid[b2]:
        return False
    signature = (min(b1, b2) << 16) + max(b1, b2)
    if model.nexclude and np.any(model.exclude_signature == signature):
        return False
    return bool(int(model.geom_contype[g1]) & int(model.geom_conaffinity[g2])
                or int(model.geom_contype[g2]) & int(model.geom_conaffinity[g1]))


def sand_low_point(terrain: Terrain) -> float:
    """Height (m, against gravity) of the lowest point of the sand surface."""
    surface = terrain.surface if isinstance(terrain, SandRegion) else terrain
    if isinstance(surface, HeightfieldSurface):
        return float(surface.heights.min())
    return float(terrain.max_height)


def _same_heightfield(model, geom: int, surface) -> bool:
    """Whether hfield geom ``geom`` has the shape of the HeightfieldSurface ``surface``."""
    if not isinstance(surface, HeightfieldSurface):
        return False
    try:
        own = HeightfieldSurface.from_model(model, int(geom))
    except ValueError:                    # rotated or not a world geom: not the sand's shape
        return False
    return (own.heights.shape == surface.heights.shape and np.allclose(own.heights, surface.heights)
            and np.allclose(own.x_range, surface.x_range) and np.allclose(own.y_range, surface.y_range))


def rigid_floors(model, body_ids: Sequence[int], terrain: Terrain) -> list[tuple[int, str]]:
    """Static planes and heightfields that would carry the bodies in place of the sand.

    A plane counts when it can collide with a geom of ``body_ids`` and reaches the sand's lowest point
    (:func:`sand_low_point`): horizontal at or above it (within :data:`FLOOR_HEIGHT_TOL`), or tilted
    upward (an infinite tilted plane crosses every height). Planes below the sand (a rigid bottom), walls
    (vertical) and ceilings (facing down) do not count. A heightfield counts when it has the sand's own
    shape (a :class:`~rft_mujoco.HeightfieldSurface` terrain, possibly in a region) and can collide.

    Returns:
        (geom id, description) per floor found, in geom order.
    """
    g_hat, _ = gravity_direction(model.opt.gravity)
    up = -g_hat
    low = sand_low_point(terrain)
    surface = terrain.surface if isinstance(terrain, SandRegion) else terrain
    bodies = {int(b) for b in body_ids}
    mine = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in bodies
            and int(model.geom_type[g]) not in (_PLANE, _HFIELD)]
    static = [g for g in range(model.ngeom) if model.body_weldid[model.geom_bodyid[g]] == 0
              and int(model.geom_type[g]) in (_PLANE, _HFIELD)]
    if not mine or not static:
        return []
    data = mujoco.MjData(model)           # static geoms' poses (world or static bodies)
    mujoco.mj_kinematics(model, data)
    found = []
    for g in static:
        if not any(can_collide(model, g, b) for b in mine):
            continue
        if int(model.geom_type[g]) == _HFIELD:
            if _same_heightfield(model, g, surface):
                found.append((g, "the heightfield of the sand surface itself"))
            continue
        normal = data.geom_xmat[g].reshape(3, 3)[:, 2]
        facing = float(normal @ up)
        height = float(data.geom_xpos[g] @ up)
        if facing >= 1.0 - HORIZONTAL_TOL:
            if height >= low - FLOOR_HEIGHT_TOL:
                found.append((g, f"a plane at height {height:g} m, at or above the sand's lowest point {low:g} m"))
        elif facing > HORIZONTAL_TOL:
            found.append((g, f"a tilted plane (normal . up = {facing:.3g}) that crosses the sand surface"))
    return found


def check_rigid_floor(model, body_ids: Sequence[int], terrain: Terrain) -> list[str]:
    """Warn (:class:`SandSetupWarning`, once for all of them) about the :func:`rigid_floors` of a sand.

    Returns the names (or ``"geom <id>"``) of the floors found, [] when none.
    """
    found = rigid_floors(model, body_ids, terrain)
    if not found:
        return []
    names = [model.geom(g).name or f"geom {g}" for g, _ in found]
    named = [model.geom(g).name for g, _ in found]
    what = "; ".join(f"{n!r}: {why}" for n, (_, why) in zip(names, found))
    bodies = [model.body(int(b)).name or f"body {int(b)}" for b in body_ids]
    how = (f"handle.replace_rigid({named!r})" if all(named) else
           f"handle.replace_rigid({[g for g, _ in found]!r})")
    region = (" Around a bounded SandRegion, build the rigid ground from box geoms outside the region."
              if isinstance(terrain, SandRegion) else "")
    warnings.warn(
        f"rft_mujoco: rigid floor geoms collide with the sand bodies {bodies} where the sand is ({what}): "
        "MuJoCo's contacts will carry the bodies and the sand will do (almost) nothing. Allowed: rigid "
        "geoms below the sand (a rigid bottom) or geoms that do not collide with the sand bodies. Do: "
        f"{how} to let the sand replace them (restored at detach), or lower them below the sand as a "
        f"rigid bottom, or set their contype/conaffinity to 0.{region}",
        SandSetupWarning, stacklevel=user_stacklevel())
    return names


# --- timestep ----------------------------------------------------------------------------------------
def check_timestep(model) -> bool:
    """Warn (:class:`SandSetupWarning`) when ``model.opt.timestep`` exceeds :data:`STUDIED_TIMESTEP_MAX`.

    Returns True when it warned.
    """
    dt = float(model.opt.timestep)
    if dt <= STUDIED_TIMESTEP_MAX:
        return False
    warnings.warn(
        f"rft_mujoco: timestep {dt:g} s is beyond the validated range: the stability study covers up to "
        f"{STUDIED_TIMESTEP_MAX:g} s, and the rest treatment was measured accurate up to "
        f"{ACCURATE_TIMESTEP_MAX:g} s. At {dt:g} s bodies may chatter, sink or come to rest late. Use "
        f"model.opt.timestep <= {ACCURATE_TIMESTEP_MAX:g} (with a frame_skip to keep the control period).",
        SandSetupWarning, stacklevel=user_stacklevel())
    return True


# --- actuation flag ----------------------------------------------------------------------------------
def check_actuation_flag(model) -> bool:
    """True when MuJoCo would call neither of the dispatcher's hooks: ``mjDSBL_ACTUATION`` (no
    ``mjcb_control``) together with ``mjDSBL_SPRING`` and ``mjDSBL_DAMPER`` (no ``mjcb_passive``)."""
    flags, bit = int(model.opt.disableflags), mujoco.mjtDisableBit
    off = int(bit.mjDSBL_ACTUATION) | int(bit.mjDSBL_SPRING) | int(bit.mjDSBL_DAMPER)
    return flags & off == off


# --- what the sand sees ----------------------------------------------------------------------------------
VISUAL_COVERAGE_MIN = 0.25
"""A body whose collision geoms' surface area is below this fraction of the surface area of the convex hull
of its visual geoms gets a :class:`SandSetupWarning` from :func:`check_sand_surfaces` (measured on public
models: a humanoid's 5 mm collision spheres under a visual sole, 0.03; capsule limbs under visual limb
meshes, 0.5-1)."""
FLOOR_MATCH_TOL = 1e-3
"""m: a floor plane replaced by the sand (``handle.replace_rigid``) further than this from the sand's surface
height gets a :class:`SandSetupWarning` from :func:`check_replaced_floor`."""


COARSE_ELEMENTS = 2.0
"""A body whose thinnest geom is thinner than this many element sizes gets a :class:`SandSetupWarning` from
:func:`check_resolution`: its surface is a few elements across, and the forces on it are the discretization's
(the bundled swimmer, 8-14 mm capsules, at the default 10 mm elements: wave efficiency 6-20% above the value
converged in element size; docs/rest.md, "The default resolution on small bodies")."""


COARSE_MESSAGE = "rft_mujoco: bodies thinner than"
"""How :func:`check_resolution`'s warning starts (a ``warnings.filterwarnings(message=...)`` pattern for code
that chose a coarse resolution on purpose, as the gymnasium tasks do for speed)."""


def check_resolution(model, body_ids: Sequence[int], element_size: float) -> list:
    """Warn (:class:`SandSetupWarning`, once, naming every body) when attached bodies are thinner than
    :data:`COARSE_ELEMENTS` element sizes (``element_size`` m; a body's thinnest sand geom,
    :func:`rft_mujoco.coupling.setup.smallest_feature`). Returns ``[(name, thinnest m), ...]`` of those bodies."""
    from rft_mujoco.coupling import setup

    thin = []
    for b in body_ids:
        used = setup.occlusion.surface_geoms(model, int(b))
        smallest = min((setup.smallest_feature(model, int(g)) for g in used), default=0.0)
        if 0.0 < smallest < COARSE_ELEMENTS * element_size:
            thin.append((model.body(int(b)).name or f"body {int(b)}", smallest))
    if thin:
        finest = min(t for _, t in thin)
        suggest = float(f"{finest / 4:.1g}")
        listed = ", ".join(f"{n!r} {t * 1e3:.3g} mm" for n, t in sorted(thin, key=lambda x: x[1])[:6]) + (
            f" and {len(thin) - 6} more" if len(thin) > 6 else "")
        warnings.warn(
            f"{COARSE_MESSAGE} {COARSE_ELEMENTS:g} element sizes ({element_size * 1e3:g} mm): "
            f"{listed}. The sand sees them through a few elements each, and their forces carry the "
            "discretization's error (on the bundled swimmer's 8-14 mm links, 10 mm elements put the wave "
            f"efficiency 6-20% above its converged value). Do: attach(..., resolution={suggest:g}) (about a "
            "quarter of the thinnest; it costs elements: handle.summary() counts them), or filter "
            "SandSetupWarning if the error is acceptable.", SandSetupWarning, stacklevel=user_stacklevel())
    return thin


def _collidable(model, g: int) -> bool:
    return bool(model.geom_contype[g] != 0 or model.geom_conaffinity[g] != 0)


def visual_hull_area(model, body_id: int) -> float:
    """m^2: surface area of the convex hull of a body's visual geoms (contype = conaffinity = 0; meshes by
    their vertices, primitives by their surface elements at 2 cm), in the body frame; 0 when it has none."""
    from scipy.spatial import ConvexHull, QhullError

    from rft_mujoco.geometry import surface

    pts = []
    for g in np.flatnonzero(np.asarray(model.geom_bodyid) == int(body_id)):
        t = int(model.geom_type[g])
        if _collidable(model, g) or t in (_PLANE, _HFIELD) or t == int(mujoco.mjtGeom.mjGEOM_SDF):
            continue
        if t == int(mujoco.mjtGeom.mjGEOM_MESH):
            m = int(model.geom_dataid[g])
            local = np.asarray(model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]],
                               dtype=float)
        else:
            try:
                local = surface.geom_elements(model, int(g), 0.02).centroids
            except ValueError:
                continue
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, np.asarray(model.geom_quat[g], dtype=float))
        pts.append(model.geom_pos[g] + local @ mat.reshape(3, 3).T)
    if not pts:
        return 0.0
    try:
        return float(ConvexHull(np.concatenate(pts)).area)
    except (QhullError, ValueError):
        return 0.0


_MESH = int(mujoco.mjtGeom.mjGEOM_MESH)


def check_sand_surfaces(model, body_ids: Sequence[int], surface_area) -> dict:
    """Warn (:class:`SandSetupWarning`, one warning per finding naming every body) when the sand surface of
    an attached body is not what its collisions are: (a) the body has no collision geoms and some of its geoms
    are meshes, so its visual meshes are its sand surface (non-colliding primitives alone are taken as meant
    for the sand); (b) its collision geoms' area is below :data:`VISUAL_COVERAGE_MIN` of its
    visual geoms' hull area.

    Args:
        model: the MjModel.
        body_ids: (B,) int, the attached bodies.
        surface_area: (B,) m^2, each body's sand surface area (exposed plus culled at attach).
    Returns:
        ``{"visual": [names], "covered": [(name, collision m^2, visual hull m^2)]}``.
    """
    visual, covered = [], []
    for b, area in zip(body_ids, surface_area):
        b = int(b)
        geoms = [g for g in np.flatnonzero(np.asarray(model.geom_bodyid) == b)
                 if int(model.geom_type[g]) not in (_PLANE, _HFIELD)]
        if not geoms:
            continue
        name = model.body(b).name or f"body {b}"
        if not any(_collidable(model, g) for g in geoms):
            if any(int(model.geom_type[g]) == _MESH for g in geoms):
                visual.append(name)          # visual meshes; a body of non-colliding primitives (the bundled
            continue                         # swimmer's capsules) is a sand body made so on purpose
        if not any(not _collidable(model, g) for g in geoms):
            continue
        hull = visual_hull_area(model, b)
        if hull > 0 and float(area) < VISUAL_COVERAGE_MIN * hull:
            covered.append((name, float(area), hull))
    if visual:
        warnings.warn(
            f"rft_mujoco: bodies {visual} have no collision geoms (contype = conaffinity = 0 on every geom): "
            "their sand surface is made of their visual geoms, which MuJoCo never collides with and which are "
            "often fine meshes (handle.summary() lists each body's geoms, area and elements). Do: give them "
            "collision geoms, or leave them out of bodies= if they never reach the sand; if the visual shape "
            "is what the sand should see, filter SandSetupWarning.", SandSetupWarning, stacklevel=user_stacklevel())
    if covered:
        what = "; ".join(f"{n!r}: {a:.3g} m^2 of collision surface against {h:.3g} m^2 of visual hull "
                         f"({a / h:.0%})" for n, a, h in covered)
        warnings.warn(
            f"rft_mujoco: the collision geoms of bodies {[c[0] for c in covered]} cover far less than their "
            f"visual geoms ({what}; warned below {VISUAL_COVERAGE_MIN:.0%}): the sand sees only the collision "
            "geoms (e.g. small spheres under a visual sole), so these bodies sink where their visual shape "
            "would be held. Do: add a collision geom with the visual shape (a box or capsule for a sole), or "
            "filter SandSetupWarning if the small collision shape is intended.",
            SandSetupWarning, stacklevel=user_stacklevel())
    return {"visual": visual, "covered": covered}


def check_replaced_floor(model, geoms: Sequence[int], terrain: Terrain) -> list[tuple[str, float]]:
    """Warn (:class:`SandSetupWarning`, once for all of them) when a horizontal plane that the sand replaces
    (``handle.replace_rigid``) is not at the sand's surface height: what stood on that floor drops to the
    sand (plane above it) or starts buried (plane below it). Flat sand only (a :class:`FlatSurface`, or a
    region of one); tilted planes and heightfields are not compared.

    Returns:
        (name, height m) of each plane warned about.
    """
    surface = terrain.surface if isinstance(terrain, SandRegion) else terrain
    if isinstance(surface, HeightfieldSurface):
        return []
    sand = float(terrain.max_height)
    g_hat, _ = gravity_direction(model.opt.gravity)
    up = -g_hat
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    found = []
    for g in geoms:
        g = int(g)
        if int(model.geom_type[g]) != _PLANE:
            continue
        if float(data.geom_xmat[g].reshape(3, 3)[:, 2] @ up) < 1.0 - HORIZONTAL_TOL:
            continue
        height = float(data.geom_xpos[g] @ up)
        if abs(height - sand) > FLOOR_MATCH_TOL:
            found.append((model.geom(g).name or f"geom {g}", height))
    if found:
        what = "; ".join(f"{n!r} at {z:g} m ({'above' if z > sand else 'below'} it by {abs(z - sand):.3g} m)"
                         for n, z in found)
        warnings.warn(
            f"rft_mujoco: the floor planes replaced by the sand are not at the sand's surface height {sand:g} m "
            f"({what}): bodies placed on the floor drop onto the sand, or start buried in it. Do: attach with "
            f"surface_height={found[0][1]:g} (the floor's height), or move the plane to {sand:g} m.",
            SandSetupWarning, stacklevel=user_stacklevel())
    return found


SURFACE_HEIGHT_MAX = 1e6
"""m: the highest free surface (in absolute value) :func:`rft_mujoco.attach` takes; beyond it the stresses (rho_c |g|
depth) overflow or a unit was mistaken."""


def checked_terrain(surface) -> Terrain:
    """:func:`as_terrain`, refusing a surface height beyond :data:`SURFACE_HEIGHT_MAX`."""
    terrain = as_terrain(surface)
    if not abs(float(terrain.max_height)) <= SURFACE_HEIGHT_MAX:
        raise ValueError(f"surface height {terrain.max_height!r} m is beyond +-{SURFACE_HEIGHT_MAX:g} m: the sand's "
                         "stresses would overflow. Give the height in m of the sand surface (e.g. 0.0)")
    return terrain


def check_model_edits(handle) -> None:
    """Raise ValueError on a model edit since attach that the sand cannot follow: a timestep that is not
    finite and > 0, a zero or non-finite gravity (or one off -z under a heightfield or region), a geom of
    the sand's bodies or of their occluders resized (the elements were built from the sizes at attach).
    A new positive timestep is checked as at attach (:func:`check_timestep`); ``handle`` is a
    :class:`~rft_mujoco.SandHandle` (its :meth:`_check_model`, called by the dispatcher:
    :func:`rft_mujoco.compiled.route.model_changed`)."""
    dt = float(handle.model.opt.timestep)
    if not (np.isfinite(dt) and dt > 0.0):
        raise ValueError(f"model.opt.timestep is {dt!r} s, set after attach; the sand needs a finite timestep "
                         "> 0 s (its rest treatment stops bodies within one step). Set a positive timestep, "
                         f"e.g. the {handle._timestep_checked:g} s of before")
    if dt != handle._timestep_checked:
        check_timestep(handle.model)
        handle._timestep_checked = dt
    try:
        handle._gravity()
    except ValueError as exc:
        raise ValueError(f"model.opt.gravity is {handle._opt_gravity.tolist()} m/s^2, set after attach: {exc}") \
            from None
    sizes = handle.model.geom_size[handle._geoms]
    if not np.array_equal(sizes, handle._geom_size0):
        i = int(np.flatnonzero(np.any(sizes != handle._geom_size0, axis=1))[0])
        g = int(handle._geoms[i])
        name = handle.model.geom(g).name or f"#{g}"
        body = handle.model.body(int(handle.model.geom_bodyid[g])).name or f"#{int(handle.model.geom_bodyid[g])}"
        raise ValueError(f"geom {name!r} (body {body!r}) was resized after attach: geom_size "
                         f"{handle._geom_size0[i].tolist()} -> {sizes[i].tolist()} m, but the sand's surface "
                         "elements and occluders were built from the sizes at attach. Detach and attach the "
                         "sand again after resizing geoms (or set geom_size back)")


def raise_not_finite(body_names: Sequence[str], diag, touch) -> None:
    """Raise a FloatingPointError naming the touching bodies (indices ``touch``) whose sand wrench in ``diag``
    (:class:`rft_mujoco.coupling.workspace.Diagnostics`) is not finite."""
    bad = [body_names[i] for i in touch
           if not (np.all(np.isfinite(diag.force[i])) and np.all(np.isfinite(diag.torque[i])))]
    raise FloatingPointError(f"non-finite sand wrench on bodies {bad}; nothing was written to xfrc_applied. "
                             "Check the model's inputs (ctrl, qfrc_applied, xfrc_applied, masses) for NaN/inf")


def mass_matrix_layout_ok(model, request: str) -> bool:
    """Whether MuJoCo's mass-matrix factor (qLD) is laid out as the compiled kernels read it
    (:func:`rft_mujoco.compiled.rest.check_layout`); with ``request == "numba"`` a ValueError if not, otherwise
    a RuntimeWarning (the caller falls back to the numpy reference)."""
    from rft_mujoco.compiled.rest import check_layout
    if check_layout(model, mujoco.MjData(model)):
        return True
    if request == "numba":
        raise ValueError(f"backend='numba': MuJoCo's mass-matrix factor (qLD) is not laid out as this version of "
                         f"rft_mujoco reads it (mujoco {mujoco.__version__}); install the mujoco version of "
                         "pyproject.toml or use backend='numpy'")
    warnings.warn("rft_mujoco: MuJoCo's mass-matrix factor (qLD) is not laid out as this version of rft_mujoco reads "
                  f"it (mujoco {mujoco.__version__}); using the numpy reference (same forces, slower). Install the "
                  "mujoco version of pyproject.toml.", RuntimeWarning, stacklevel=5)
    return False
