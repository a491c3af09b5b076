"""Quasi-static references: what the law alone says, without the coupling's solve and without dynamics.

``python -m rft_mujoco quasistatic [--quick]``. Two references that the sand solve (issue 26) is measured
against. Both use only the exposed surface elements that ``attach`` builds
(:func:`rft_mujoco.coupling.setup.surfaces`, culled inside a body's own geoms at attach, and inside other
bodies' geoms at each pose as the coupling's run-time culling does), the published law
(:func:`rft_mujoco.physics.law.stress_per_depth`, through :func:`rft_mujoco.physics.elements.body_wrenches`
for the depths; guards off, flat free surface) and force balance.
MuJoCo places the links for a given ``qpos`` (``mj_kinematics``, ``mj_comPos``, ``mj_jacBodyCom``) and
nothing else: no ``mj_step``, no masses, no constraint solve.

1. :func:`swimmer_limit`: the inertia-free limit of the bundled swimmer driven by the swim study's
   serpenoid (:mod:`rft_mujoco.studies.swim`). At each instant the joint angles and rates are exactly the
   commanded ones; the planar root velocity ``u = (vx, vy, omega_z)`` (the root joints ``root_x``,
   ``root_y``, ``root_yaw``) is the one at which the sand's generalized force on the three root dofs
   vanishes (zero in-plane force, zero torque about z: quasi-Newton, finite-difference Jacobian, warm
   started; the element forces regularized at a tiny speed, :class:`_Newton`). The root pose is integrated with classical RK4 (a solve per stage). eta, speed and A/lambda
   are defined as in :func:`rft_mujoco.studies.swim.swim`, so the numbers compare one to one.
2. :func:`rest_depth_of` / :func:`scene_rest_depth`: the depth at which the sand first carries a given
   load on a body moving straight down along the load (bisection on the law's force against the body's
   displacement; the law is rate-independent, so only the direction of motion enters).

Units: SI (m, s, N, rad) throughout.
"""

from __future__ import annotations

import argparse
import math
import time

import mujoco
import numpy as np

from rft_mujoco.coupling import setup
from rft_mujoco.geometry import occlusion
from rft_mujoco.physics import elements, law
from rft_mujoco.physics.law import PUBLISHED
from rft_mujoco.physics.media import MALADEN_GLASS_BEADS, Media, get_media
from rft_mujoco.physics.terrain import FlatSurface
from rft_mujoco.studies import loadpath_scenes
from rft_mujoco.tables import RIGHT, Columns

# --- settings: one place ---------------------------------------------------------------------------------
SWIM_ELEMENT_SIZE = 0.003
"""m: the swimmer's element size. The limit wanders by +-3% with the element size from 4 to 1 mm (the run-time
culling at the joints), 3 mm at its low end; without culling it is converged there (docs/rest.md,
"Quasi-static references")."""
STEPS_PER_CYCLE = 50
"""RK4 steps per wave period of :func:`swimmer_limit` (25, 50 and 100 agree to 0.1%: docs/rest.md)."""
NEWTON_RTOL = 1e-9
"""Balance tolerance of the swimmer's solve: |generalized root force| (N, and N m over the body length) over
the gross element force sum |f_e| (N)."""
NEWTON_MAX_ITER = 40
FD_STEP = 1e-4
"""The finite-difference step of the swimmer's Jacobian, as a fraction of |u|."""
REG_SPEED = 1e-6
"""The regularization speed of the swimmer's solve as a fraction of its speed scale a 2 pi f L (see :class:`_Newton`)."""
DEPTH_TOL = 1e-7
"""m: bisection tolerance of the rest depths."""
DEPTH_MAX = 1.0
"""m: the deepest displacement searched for a rest depth (more is an error: the load is out of reach)."""
SWIM_AMPLITUDES = (0.3, 0.5, 0.7, 0.9, 1.1, 1.3)
"""rad: the amplitudes of issue 26's "any mass" check."""


# --- shared: elements, run-time culling, the law -----------------------------------------------------------
class _Bodies:
    """The exposed surface of some bodies of a model (as ``attach(cull=cull)`` builds it) and their run-time
    occluders (the surface geoms of every other weld group, as :func:`rft_mujoco.compiled.elements.occluders`)."""

    def __init__(self, model, bodies, element_size: float, cull: bool):
        self.model = model
        self.ids = np.asarray(setup.body_ids(model, bodies), dtype=np.int64)
        names = [model.body(int(b)).name for b in self.ids]
        s = setup.surfaces(model, self.ids, names, float(element_size), cull)
        self.centroids, self.normals, self.areas, self.elem_body = s.centroids, s.normals, s.areas, s.elem_body
        self.cull = cull
        self.center, self.radius = setup.bounding_spheres(self.centroids, self.elem_body, self.ids.size,
                                                          float(element_size))
        weld = model.body_weldid
        # occluders of body i: (other body id, Occluder in that body's frame)
        self.occluders = []
        for b in self.ids:
            occ = []
            if cull:
                for other in range(model.nbody):
                    if weld[other] != weld[b]:
                        occ += [(other, o) for o in occlusion.geom_occluders(model, other)]
            self.occluders.append(occ)

    def exposed(self, data) -> np.ndarray:
        """(E,) bool: elements not inside another weld group's geom at the pose of ``data`` (kinematics done)."""
        active = np.ones(self.areas.size, dtype=bool)
        for i, b in enumerate(self.ids):
            if not self.occluders[i]:
                continue
            rows = np.flatnonzero(self.elem_body == i)
            rot = data.xmat[b].reshape(3, 3)
            center = data.xpos[b] + rot @ self.center[i]
            world = data.xpos[b] + self.centroids[rows] @ rot.T
            hidden = np.zeros(rows.size, dtype=bool)
            for other, occ in self.occluders[i]:
                o_rot = data.xmat[other].reshape(3, 3)
                o_pos = data.xpos[other] + o_rot @ occ.pos
                if np.linalg.norm(o_pos - center) > self.radius[i] + self.model.geom_rbound[occ.geom_id]:
                    continue                            # the bounding spheres are apart
                hidden |= occ.transformed(data.xpos[other], o_rot).contains(world)
            active[rows] = ~hidden
        return active

    def wrenches(self, data, v_com, omega, media, terrain, gravity, active) -> np.ndarray:
        """(B, 6) law wrenches [force N, torque N m about each COM] for body twists (B, 3) m/s and rad/s."""
        g_hat = gravity / np.linalg.norm(gravity)
        ids = self.ids
        e = np.flatnonzero(active)                      # the culled elements carry nothing: leave them out
        surface = elements.BodySurface(self.centroids[e], self.normals[e], self.areas[e], self.elem_body[e], ids.size)
        pose = elements.BodyPose(data.xpos[ids], data.xmat[ids].reshape(-1, 3, 3), data.xipos[ids])
        w, _, _ = elements.body_wrenches(surface, pose, v_com, omega, terrain, g_hat, gravity, media, PUBLISHED)
        return w


def _jacobians(model, data, ids) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3, nv) linear and angular Jacobians of the bodies' COMs (kinematics and comPos done)."""
    jp = np.zeros((ids.size, 3, model.nv))
    jr = np.zeros((ids.size, 3, model.nv))
    for i, b in enumerate(ids):
        mujoco.mj_jacBodyCom(model, data, jp[i], jr[i], int(b))
    return jp, jr


# --- 1. the swimmer's inertia-free limit -------------------------------------------------------------------
def _serpenoid(t: float, amplitude: float, frequency: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles (n,) rad and rates (n,) rad/s of swim.py's drive: ``ramp(t) a sin(2 pi f t - 2 pi i / n)``
    with ``ramp = min(1, f t)`` (the first period ramps the amplitude up)."""
    i = np.arange(n)
    phase = 2 * math.pi * frequency * t - 2 * math.pi * i / n
    ramp, dramp = (frequency * t, frequency) if t < 1.0 / frequency else (1.0, 0.0)
    q = ramp * amplitude * np.sin(phase)
    qd = dramp * amplitude * np.sin(phase) + ramp * amplitude * 2 * math.pi * frequency * np.cos(phase)
    return q, qd


class _Swimmer:
    """The bundled swimmer's kinematics, surface and root balance."""

    ROOT = ("root_x", "root_y", "root_yaw")

    def __init__(self, element_size: float, cull: bool, media: Media):
        from rft_mujoco.models import path

        self.model = mujoco.MjModel.from_xml_path(str(path("sand_swimmer.xml")))
        self.data = mujoco.MjData(self.model)
        m = self.model
        root = [m.joint(n) for n in self.ROOT]
        if [int(j.qposadr[0]) for j in root] != [0, 1, 2] or [int(j.dofadr[0]) for j in root] != [0, 1, 2]:
            raise RuntimeError("the bundled swimmer's root joints must be qpos/dof 0..2 (root_x, root_y, "
                               "root_yaw); the model changed")
        self.n_joints = m.nq - 3
        self.bodies = _Bodies(m, None, element_size, cull)
        self.media = media
        self.terrain = FlatSurface(0.0)                 # the floor plane at z = 0 replaced by sand (swim.py)
        self.gravity = np.array(m.opt.gravity, dtype=float)
        self.length = 0.025 + 0.017 * self.n_joints     # m, tip to tip (the scale of torques and yaw rates)
        self.head = m.body("head").id
        self.yaw_joint = m.joint("root_yaw").id
        self.g_hat = self.gravity / np.linalg.norm(self.gravity)

    def pose(self, root: np.ndarray, q: np.ndarray, qd: np.ndarray):
        """Place the links at root pose (x m, y m, yaw rad) and joint angles ``q`` (rad) moving at ``qd`` (rad/s).
        Returns the balance ``r(u, eps)`` of the root velocity u = (vx, vy, omega_z) and the share of the surface
        area that is exposed (not inside a neighbouring link).

        ``r(u, eps)`` -> ((3,) the sand's generalized force on root_x, root_y (N) and root_yaw (N m) over the
        body length, the gross force sum |f_e| in N): each exposed, submerged, leading element feels the law's
        force at its own velocity's direction, times ``|v| / sqrt(|v|^2 + eps^2)`` (eps in m/s; 0: the law
        itself, whose force at zero velocity is set-valued)."""
        m, d = self.model, self.data
        d.qpos[:3] = root
        d.qpos[3:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        ids = self.bodies.ids
        jp, jr = _jacobians(m, d, ids)
        v_joint = jp[:, :, 3:] @ qd                     # (B, 3) COM velocities from the joint rates alone
        w_joint = jr[:, :, 3:] @ qd
        e = np.flatnonzero(self.bodies.exposed(d))      # culled elements carry nothing
        eb = self.bodies.elem_body[e]
        rot = d.xmat[ids].reshape(-1, 3, 3)[eb]
        pos = d.xpos[ids][eb] + np.einsum("eij,ej->ei", rot, self.bodies.centroids[e])
        nrm = np.einsum("eij,ej->ei", rot, self.bodies.normals[e])
        v_j = v_joint[eb] + np.cross(w_joint[eb], pos - d.xipos[ids][eb])
        arm = pos - d.xanchor[self.yaw_joint]           # lever about the yaw axis
        depth = self.terrain.depth(pos, self.g_hat)
        sub = depth > 0.0
        depth_area = (depth * self.bodies.areas[e])[sub]
        nrm, v_j, arm = nrm[sub], v_j[sub], arm[sub]

        def residual(u: np.ndarray, eps: float) -> tuple[np.ndarray, float]:
            v = v_j.copy()
            v[:, 0] += u[0] - u[2] * arm[:, 1]
            v[:, 1] += u[1] + u[2] * arm[:, 0]
            speed = np.linalg.norm(v, axis=1)
            live = speed > law.ZERO_SPEED
            v_hat = v[live] / speed[live, None]
            lead = np.einsum("ij,ij->i", nrm[live], v_hat) >= -law.LEADING_TOL
            idx = np.flatnonzero(live)[lead]
            sp = speed[idx]
            weight = depth_area[idx] * (sp / np.sqrt(sp * sp + eps * eps) if eps > 0.0 else 1.0)
            f = law.stress_per_depth(nrm[idx], v_hat[lead], self.media, self.gravity) * weight[:, None]
            gen = np.array([f[:, 0].sum(), f[:, 1].sum(),
                            (arm[idx, 0] * f[:, 1] - arm[idx, 1] * f[:, 0]).sum() / self.length])
            return gen, float(np.abs(f).sum())

        return residual, float(self.bodies.areas[e].sum() / self.bodies.areas.sum())

    def com(self) -> np.ndarray:
        """(2,) the whole body's centre of mass in the plane (m) at the last pose."""
        return self.data.subtree_com[self.head, :2].copy()


class _Newton:
    """Quasi-Newton solve of the swimmer's balance r(u) = 0 in the scaled unknowns s = (vx, vy, omega_z L).

    The law is rate-independent: a body (the head, whose twist is u itself) at rest feels a set-valued force,
    and r jumps across u = 0; a link at rest in the sand can anchor the rest (a stuck solution, like dry
    friction). The solve therefore works on the element forces scaled by ``|v| / sqrt(|v|^2 + eps^2)``: with
    :data:`REG_SPEED` (a tiny fraction of the body's speed scale) the answer is the law's wherever every
    loaded element moves faster than eps, and the stuck solution's limit where one body is at rest.
    Jacobian: central differences over :data:`FD_STEP` of |s|, kept from one solve to the next, Broyden updates
    after accepted steps, recomputed when a step fails; a trust region of 0.1 of the speed scale per step.
    When the iteration stalls above :data:`NEWTON_RTOL`, it is rerun by continuation in eps from
    1e-2 of the speed scale down; the best point is kept (its residual is reported)."""

    def __init__(self, speed_scale: float, length: float, reg: float):
        self.sc = np.array([1.0, 1.0, 1.0 / length])    # u = s * sc
        self.scale = speed_scale
        self.max_step = 0.1 * speed_scale
        self.eps = reg * speed_scale
        self.jac = None
        self.continuations = 0

    def _fd(self, residual, s, eps) -> np.ndarray:
        h = FD_STEP * max(float(np.linalg.norm(s)), 1e-3 * self.scale)
        jac = np.empty((3, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            jac[:, k] = (residual((s + e) * self.sc, eps)[0] - residual((s - e) * self.sc, eps)[0]) / (2 * h)
        return jac

    def solve(self, residual, u0: np.ndarray) -> tuple[np.ndarray, float, int]:
        """(u, |r| / gross at u, residual evaluations)."""
        u, rel, evals = self._newton(residual, u0, self.eps)
        if rel > NEWTON_RTOL:
            self.continuations += 1
            v = u0
            for eps in self.scale * np.logspace(-2, math.log10(self.eps / self.scale), 5)[:-1]:
                v, _, n = self._newton(residual, v, eps, fresh_jac=True)
                evals += n
            v, rel2, n = self._newton(residual, v, self.eps, fresh_jac=True)
            evals += n
            if rel2 < rel:
                u, rel = v, rel2
        return u, rel, evals

    def _newton(self, residual, u0: np.ndarray, eps: float, fresh_jac: bool = False):
        s = u0 / self.sc
        r, gross = residual(s * self.sc, eps)
        evals, fresh = 1, False
        if self.jac is None or fresh_jac:
            self.jac, fresh, evals = self._fd(residual, s, eps), True, evals + 6
        for _ in range(NEWTON_MAX_ITER):
            norm = float(np.linalg.norm(r))
            if norm <= NEWTON_RTOL * max(gross, 1e-300):
                break
            try:
                step = -np.linalg.solve(self.jac, r)
            except np.linalg.LinAlgError:
                step = -np.linalg.lstsq(self.jac, r, rcond=None)[0]
            size = float(np.linalg.norm(step))
            if size > self.max_step:
                step *= self.max_step / size
            lam, accepted = 1.0, False
            while lam >= 1.0 / 16:
                r_new, gross_new = residual((s + lam * step) * self.sc, eps)
                evals += 1
                if np.linalg.norm(r_new) < norm:
                    accepted = True
                    break
                lam *= 0.5
            if accepted:
                ds, dr = lam * step, r_new - r
                self.jac = self.jac + np.outer(dr - self.jac @ ds, ds) / float(ds @ ds)
                s, r, gross, fresh = s + ds, r_new, gross_new, False
            elif fresh:
                break                                   # a fresh Jacobian cannot do better: the jumps' level
            else:
                self.jac, fresh, evals = self._fd(residual, s, eps), True, evals + 6
        return s * self.sc, float(np.linalg.norm(r) / max(gross, 1e-300)), evals


def swimmer_limit(amplitude: float, frequency: float = 1.0, *, element_size: float = SWIM_ELEMENT_SIZE,
                  cull: bool = True, cycles: int = 4, measured_cycles: int = 2,
                  steps_per_cycle: int = STEPS_PER_CYCLE, media: Media | str = MALADEN_GLASS_BEADS,
                  mirror: bool = False, reg: float = REG_SPEED) -> dict:
    """The bundled swimmer's inertia-free (quasi-static) swimming under the swim study's serpenoid.

    Method: for each instant t the joints follow ``q_i = ramp(t) a sin(2 pi f t - 2 pi i / 6)`` exactly
    (``mirror``: ``-q_i``, the mirrored wave); the planar root velocity u = (vx m/s, vy m/s, omega_z rad/s) is
    the root of the sand's generalized force on the three root dofs (in-plane force and torque about z of the
    whole body: every link, the exposed surface), solved by quasi-Newton from the last instant's u
    (:class:`_Newton`: the element forces regularized at ``reg`` times the speed scale, so that a link at
    rest, whose force the law leaves set-valued, can anchor the rest); the root pose is advanced by classical
    RK4 with ``steps_per_cycle`` steps per period. No inertia, no servo, no MuJoCo dynamics. The swim study's
    floor plane is the sand surface (height 0, :data:`MALADEN_GLASS_BEADS`).

    Args:
        amplitude: joint amplitude a, rad.
        frequency: f, Hz.
        element_size: m, the surface element size of ``attach(resolution=...)``.
        cull: the exposed surface only (attach's ``cull=True``: culling at attach and at run time).
        cycles: periods simulated; the first ramps the amplitude up.
        measured_cycles: the last periods over which the speed is measured (swim.py: 2 of 4).
        steps_per_cycle: RK4 steps per period.
        media: the granular medium.
        mirror: drive the mirrored wave (-q); the motion must be the mirror image (a test).
        reg: the regularization speed over the speed scale (:class:`_Newton`; the result must not depend on it).
    Returns:
        dict: amplitude_rad, frequency_hz, element_size_m, steps_per_cycle, cull, a_over_lambda, wavelength_m,
        speed_mps (|COM displacement| over the measured span), forward_mps (its x part), lateral_mps (y part),
        eta (speed / (f lambda)), yaw_drift_rad (over the measured span), max_residual and mean_residual
        (of the balance over the gross force, over the solves), n_elements, exposed_area_fraction (the mean
        share of the surface area not inside a neighbouring link), solves (balance solves), evaluations (of the
        balance), continuations (solves rerun by continuation in the regularization), reg, wall_s (s).
    """
    from rft_mujoco.studies.swim import wave_shape

    if not amplitude >= 0.0 or not frequency > 0.0:
        raise ValueError(f"amplitude must be >= 0 rad and frequency > 0 Hz, got {amplitude!r}, {frequency!r}")
    if not (isinstance(cycles, int) and isinstance(measured_cycles, int) and 0 < measured_cycles < cycles):
        raise ValueError(f"need integers 0 < measured_cycles < cycles, got {measured_cycles!r}, {cycles!r}")
    if steps_per_cycle < 4:
        raise ValueError(f"steps_per_cycle must be >= 4, got {steps_per_cycle!r}")
    t0 = time.perf_counter()
    sw = _Swimmer(element_size, cull, get_media(media))
    sign = -1.0 if mirror else 1.0
    h = 1.0 / (frequency * steps_per_cycle)
    speed_scale = max(amplitude * 2 * math.pi * frequency * sw.length, 1e-6)   # m/s, the body's joint speeds
    state = dict(u=np.zeros(3), worst=0.0, solves=0, exposed=0.0, evals=0, mean_residual=0.0)
    newton = _Newton(speed_scale, sw.length, reg)

    def velocity(t: float, root: np.ndarray) -> np.ndarray:
        q, qd = _serpenoid(t, amplitude, frequency, sw.n_joints)
        residual, exposed = sw.pose(root, sign * q, sign * qd)
        u, res, evals = newton.solve(residual, state["u"])
        state["u"] = u
        state["evals"] += evals
        state["worst"] = max(state["worst"], res)
        state["solves"] += 1
        state["exposed"] += exposed
        state["mean_residual"] += res
        return u

    root = sw.data.qpos[:3].copy()   # the model's qpos0 = the keyframe "buried" (straight, heading +x)
    n_steps = cycles * steps_per_cycle
    start = (cycles - measured_cycles) * steps_per_cycle
    com0 = yaw0 = None
    for k in range(n_steps + 1):
        t = k * h
        if k == start:
            velocity(t, root)      # poses the body at t (also a warm start)
            com0, yaw0 = sw.com(), float(root[2])
        if k == n_steps:
            break
        k1 = velocity(t, root)
        k2 = velocity(t + h / 2, root + h / 2 * k1)
        k3 = velocity(t + h / 2, root + h / 2 * k2)
        k4 = velocity(t + h, root + h * k3)
        root = root + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    velocity(n_steps * h, root)
    disp = sw.com() - com0
    span = measured_cycles / frequency
    ratio, lam, _ = wave_shape(amplitude)
    speed = float(np.linalg.norm(disp) / span)
    return dict(amplitude_rad=float(amplitude), frequency_hz=float(frequency), element_size_m=float(element_size),
                steps_per_cycle=int(steps_per_cycle), cull=bool(cull), mirror=bool(mirror),
                a_over_lambda=ratio, wavelength_m=lam, speed_mps=speed, forward_mps=float(disp[0] / span),
                lateral_mps=float(disp[1] / span), eta=speed / (frequency * lam),
                yaw_drift_rad=float(root[2]) - yaw0, max_residual=state["worst"],
                n_elements=int(sw.bodies.areas.size),
                mean_residual=state["mean_residual"] / max(state["solves"], 1),
                exposed_area_fraction=state["exposed"] / max(state["solves"], 1),
                solves=state["solves"], evaluations=state["evals"],
                continuations=newton.continuations, reg=float(reg), wall_s=time.perf_counter() - t0)


# --- 2. rest depths ----------------------------------------------------------------------------------------
def _force_along(bodies: _Bodies, data, row: int, shift: np.ndarray, g_hat: np.ndarray, media: Media,
                 terrain, gravity: np.ndarray) -> float:
    """The law's force (N) against ``g_hat`` on body ``row`` of ``bodies`` translated by ``shift`` (3,) m from the
    pose of ``data`` and moving along ``g_hat`` (any speed: the law is rate-independent). The other bodies of
    the model move with it (their relative poses, hence the run-time culling, are those of ``data``); the
    world's geoms stay."""
    ids = bodies.ids
    xpos, xipos = data.xpos.copy(), data.xipos.copy()
    try:
        data.xpos[1:] += shift
        data.xipos[1:] += shift
        active = bodies.exposed(data)
        v = np.zeros((ids.size, 3))
        v[row] = g_hat
        w = bodies.wrenches(data, v, np.zeros((ids.size, 3)), media, terrain, gravity, active)
    finally:
        data.xpos[:] = xpos
        data.xipos[:] = xipos
    return float(-w[row, :3] @ g_hat)


def rest_depth_of(model, body, load: float, *, g_dir=None, qpos=None, element_size: float = 0.01,
                  media: Media | str = "li_loose_glass_beads", surface_height: float = 0.0, cull: bool = True,
                  scan_step: float = 1e-3) -> float:
    """How far (m) ``body`` must move along the load from its pose at ``qpos`` before the law carries ``load``.

    Method: the body's exposed surface (as ``attach(bodies=[body], resolution=element_size, cull=cull)`` builds
    it; the run-time culling by other bodies' geoms at the displaced pose, the model's other bodies moved
    with it) is translated by ``d`` along ``g_dir`` and moved along ``g_dir``; the law's force component
    against ``g_dir`` is F(d). The result is the smallest d with F(d) >= ``load``: a scan in steps of
    ``scan_step`` m, then bisection to :data:`DEPTH_TOL`. When the body's lowest point touches the free
    surface at ``qpos`` (every load-path scene), d is the depth of that lowest point at rest.

    Args:
        model: the MjModel.
        body: the sand body's name or id.
        load: N, > 0, the load the sand must carry (along ``g_dir``).
        g_dir: (3,) direction of the load and of the motion; default the model's gravity (depth is measured
            along gravity; the flat surface at ``surface_height``).
        qpos: (nq,) the pose to start from; default ``model.qpos0``.
        element_size: m.
        media: the granular medium (a preset name or a Media).
        surface_height: m, the flat free surface's height against gravity.
        cull: the exposed surface only.
        scan_step: m, the step of the scan for the first crossing.
    Returns:
        d in m.
    Raises:
        ValueError: a non-positive load, or a load the sand does not carry within :data:`DEPTH_MAX`.
    """
    if not load > 0.0:
        raise ValueError(f"load must be > 0 N, got {load!r}")
    media = get_media(media)
    gravity = np.array(model.opt.gravity, dtype=float)
    if not np.linalg.norm(gravity) > 0.0:
        raise ValueError("the model's gravity is zero: 3D-RFT depths are measured along gravity")
    g_hat = gravity / np.linalg.norm(gravity) if g_dir is None else np.asarray(g_dir, dtype=float)
    if g_hat.shape != (3,) or not np.linalg.norm(g_hat) > 0.0:
        raise ValueError(f"g_dir must be a non-zero 3-vector, got {g_dir!r}")
    g_hat = g_hat / np.linalg.norm(g_hat)
    data = mujoco.MjData(model)
    if qpos is not None:
        data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    bodies = _Bodies(model, [body], element_size, cull)
    terrain = FlatSurface(float(surface_height))

    def force(d: float) -> float:
        return _force_along(bodies, data, 0, d * g_hat, g_hat, media, terrain, gravity)

    lo, hi = 0.0, 0.0
    while force(hi) < load:
        lo, hi = hi, hi + scan_step
        if hi > DEPTH_MAX:
            raise ValueError(f"the sand does not carry {load:g} N on body {model.body(bodies.ids[0]).name!r} within "
                             f"{DEPTH_MAX:g} m of motion along {g_hat.tolist()}")
    while hi - lo > DEPTH_TOL:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if force(mid) < load else (lo, mid)
    return 0.5 * (lo + hi)


SELF_WEIGHT = {
    "plate_alone": ("<mujoco><worldbody><body name='plate' pos='0 0 0.005'><freejoint/><geom type='box' "
                    "size='0.05 0.05 0.005' mass='0.2'/></body></worldbody></mujoco>", "plate"),
    "foot_alone": ("<mujoco><worldbody><body name='foot' pos='0 0 0.02'><freejoint/><geom type='sphere' "
                   "size='0.02' mass='0.05'/></body></worldbody></mujoco>", "foot"),
    "ball_alone": ("<mujoco><worldbody><body name='ball' pos='0 0 0.03'><freejoint/><geom type='sphere' "
                   "size='0.03' mass='1'/></body></worldbody></mujoco>", "ball"),
}
"""The load-path scenes' sand bodies alone under their own weight: name -> (MJCF, body); each starts with its
lowest point on the surface."""


def scene_load(name: str) -> tuple[mujoco.MjModel, str, float]:
    """(model, sand body, load N) of a load-path scene (:data:`rft_mujoco.studies.loadpath_scenes.SCENES`: the load is
    :func:`rft_mujoco.studies.loadpath_scenes.expected_force`'s vertical part: the scene's total weight, the
    saturated servo force plus the foot's weight for ``actuator_limit``, the ball's weight for ``rock``) or of
    :data:`SELF_WEIGHT` (the body's weight)."""
    if name in loadpath_scenes.SCENES:
        xml, bodies = loadpath_scenes.SCENES[name]
        model = mujoco.MjModel.from_xml_string(xml.format(dt=0.002, integrator="Euler"))
        load, _ = loadpath_scenes.expected_force(name, model)
        return model, bodies[0], float(load[2])
    if name in SELF_WEIGHT:
        xml, body = SELF_WEIGHT[name]
        model = mujoco.MjModel.from_xml_string(xml)
        return model, body, float(model.body(body).mass[0] * -model.opt.gravity[2])
    raise ValueError(f"unknown scene {name!r}; valid names: {sorted(loadpath_scenes.SCENES) + sorted(SELF_WEIGHT)}")


def scene_rest_depth(name: str, *, element_size: float | None = None, media: Media | str | None = None
                     ) -> tuple[float, float]:
    """(depth m, load N): the quasi-static rest depth of a load-path scene's sand body under the scene's load.

    The depth is the body's displacement from the scene's start pose (its lowest point on the surface), i.e.
    what :class:`rft_mujoco.studies.loadpaths.Result` reports as ``sinkage`` and the depth of its lowest point;
    :func:`rest_depth_of` with the scene's medium and element size (default
    :data:`rft_mujoco.studies.loadpath_scenes.MEDIA` and :data:`~rft_mujoco.studies.loadpath_scenes.RESOLUTION`: the
    surface the simulation has). Scenes: :data:`rft_mujoco.studies.loadpath_scenes.SCENES` and :data:`SELF_WEIGHT`.
    """
    model, body, load = scene_load(name)
    depth = rest_depth_of(model, body, load, element_size=loadpath_scenes.RESOLUTION if element_size is None
                          else element_size, media=loadpath_scenes.MEDIA if media is None else media)
    return depth, load


# --- command line --------------------------------------------------------------------------------------------
def run(quick: bool = False, progress=print) -> dict:
    """The swimmer's limits at :data:`SWIM_AMPLITUDES` (1 Hz) and every scene's rest depth; prints tables."""
    size, steps = (0.006, 25) if quick else (SWIM_ELEMENT_SIZE, STEPS_PER_CYCLE)
    progress(f"swimmer, inertia-free limit (1 Hz, {size * 1e3:g} mm elements, {steps} RK4 steps per period, "
             f"speed over the last 2 of 4 periods)")
    columns = Columns(["a rad", "A/lambda", "eta", "forward m/s", "lateral m/s", "yaw drift", "residual", "wall s"],
                      widths=[6, 8, 7, 11, 11, 9, 8, 7], align=RIGHT * 8)
    progress(columns.header())
    swims = []
    for a in SWIM_AMPLITUDES:
        r = swimmer_limit(a, 1.0, element_size=size, steps_per_cycle=steps)
        swims.append(r)
        progress(columns.row([f"{a:.2f}", f"{r['a_over_lambda']:.3f}", f"{r['eta']:.4f}", f"{r['forward_mps']:.5f}",
                              f"{r['lateral_mps']:.5f}", f"{r['yaw_drift_rad']:.4f}", f"{r['max_residual']:.1e}",
                              f"{r['wall_s']:.1f}"]))
    progress(f"\nquasi-static rest depths ({loadpath_scenes.MEDIA}, {loadpath_scenes.RESOLUTION * 1e3:g} mm elements as the "
             "load-path study; depth = the sand body's displacement from its start pose = its lowest point's depth)")
    names = list(loadpath_scenes.SCENES) + list(SELF_WEIGHT)
    columns = Columns(["scene", "load N", "depth mm"], widths=[max(map(len, names)), 8, 9])
    progress(columns.header())
    depths = {}
    for name in names:
        d, load = scene_rest_depth(name)
        depths[name] = (d, load)
        progress(columns.row([name, f"{load:.3f}", f"{d * 1e3:.3f}"]))
    return dict(swim=swims, depths=depths)


def main(argv: list[str] | None = None, command: str = "quasistatic") -> int:
    parser = argparse.ArgumentParser(prog=f"python -m rft_mujoco {command}",
                                     description="Quasi-static references: the swimmer's inertia-free limit and "
                                                 "the rest depths of the load-path scenes.")
    parser.add_argument("--quick", action="store_true", help="6 mm elements and 25 steps per period (minutes)")
    args = parser.parse_args(argv)
    run(quick=args.quick)
    return 0
