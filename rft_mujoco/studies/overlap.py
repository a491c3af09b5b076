"""Overlapping geoms: the coupling's exposed-surface rule against a brute-force reference (issue #16).

Robot models overlap their geoms (capsules meeting at a joint, a foot sphere inside its calf); only the
surface that sand can reach feels it. Each case here is a MuJoCo scene whose attached bodies move
together at :data:`SPEED` (the root joint's velocity; every other joint at rest), fully below a flat
surface. The library's force (``attach(stabilize=False, passive=False)``, one evaluation at the pose,
the published law at the default resolution, with and without ``cull``) is compared with a brute-force
reference written here from the definitions alone: every geom of every attached body cut into
:data:`REFERENCE_SIZE` elements, each element dropped when its centroid is inside ANY other geom of the
model (:func:`rft_mujoco.geometry.occlusion.inside_geom`, geom by geom, no bounding spheres, no weld
groups), the law summed over the rest. Exposed areas are compared the same way.

Cases (:data:`CASES`): two capsules meeting at a hinge at several angles, a sphere (a foot) inside the
end of a capsule (a calf) on its own joint, the bundled swimmer (7 capsules whose caps overlap at every
joint), and the bundled quadruped's front-left leg (thigh, calf, foot; the trunk and hip occlude).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import attach
from rft_mujoco.geometry import occlusion, surface
from rft_mujoco.physics import law
from rft_mujoco.physics.media import MPM_VALIDATION
from rft_mujoco.tables import table

SPEED = 0.1
"""m/s of every motion."""
REFERENCE_SIZE = 0.001
"""m: element size of the brute-force reference (its exposed area still moves by ~1% between 1 and 1.5 mm
on the swimmer: an element is in or out by its centroid)."""
DEPTH = 0.3
"""m: the free surface this far above the scene's origin (every case is fully submerged)."""

_HINGE = """<mujoco><worldbody>
  <body name="upper" pos="0 0 0"><freejoint/>
    <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.02"/>
    <body name="lower" pos="0.1 0 0"><joint name="knee" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.02"/></body></body>
</worldbody></mujoco>"""
_FOOT = """<mujoco><worldbody>
  <body name="calf" pos="0 0 0"><freejoint/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.12" size="0.015"/>
    <body name="foot" pos="0 0 -0.12"><joint type="slide" axis="0 0 1"/>
      <geom type="sphere" size="0.022"/></body></body>
</worldbody></mujoco>"""


@dataclasses.dataclass(frozen=True)
class Case:
    """A scene: MJCF (or a bundled model name), attached bodies, joint positions, motions.

    ``motions``: name -> (root dof indices, velocity (m/s) of each); the other dofs are at rest."""

    name: str
    xml: str
    bodies: tuple
    qpos: dict
    motions: dict
    description: str


def _free(axis: int) -> tuple:
    return ((axis,), (SPEED,))


CASES = {
    **{f"hinge_{a}": Case(f"hinge_{a}", _HINGE, ("upper", "lower"), {"knee": math.radians(a)},
                          {"down": _free(2), "axial": _free(0), "lateral": _free(1)},
                          f"two capsules r 2 cm, 10 cm long, meeting at a hinge bent {a} deg")
       for a in (0, 45, 90, 135)},
    "foot_in_calf": Case("foot_in_calf", _FOOT, ("calf", "foot"), {},
                         {"down": _free(2), "forward": _free(0)},
                         "sphere r 2.2 cm (a foot) on the end of a capsule r 1.5 cm (a calf), own joint"),
    "swimmer": Case("swimmer", "sand_swimmer.xml", None, {},
                    {"axial": ((0,), (-SPEED,)), "lateral": ((1,), (SPEED,))},
                    "the bundled swimmer, straight: 7 capsules overlapping at every joint"),
    "quadruped_leg": Case("quadruped_leg", "quadruped.xml", ("FL_thigh", "FL_calf", "FL_foot"), {},
                          {"down": _free(2), "forward": _free(0)},
                          "the bundled quadruped's front-left leg at 'home' (trunk and hip occlude)"),
}
"""The overlap cases (name -> :class:`Case`)."""


def _model(case: Case) -> mujoco.MjModel:
    if case.xml.endswith(".xml"):
        from rft_mujoco.models import path
        return mujoco.MjModel.from_xml_path(str(path(case.xml)))
    return mujoco.MjModel.from_xml_string(case.xml)


def _posed(case: Case, model) -> mujoco.MjData:
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    for joint, value in case.qpos.items():
        data.qpos[model.joint(joint).qposadr[0]] = value
    mujoco.mj_kinematics(model, data)
    return data


def _body_ids(case: Case, model) -> list[int]:
    if case.bodies is None:
        return [b for b in range(1, model.nbody) if len(occlusion.surface_geoms(model, b))]
    return [model.body(n).id for n in case.bodies]


def reference(model, data, body_ids, velocity, size: float = REFERENCE_SIZE, surface_z: float = 0.0):
    """Brute force: (total force (3,) N, exposed area m^2, whole area m^2) of ``body_ids`` moving with
    ``velocity`` (3,) m/s under a flat surface at ``surface_z``; elements inside any other geom dropped."""
    others = [g for b in range(model.nbody) for g in occlusion.surface_geoms(model, b)]
    hulls = {}
    total = np.zeros(3)
    exposed = whole = 0.0
    for b in body_ids:
        for g in occlusion.surface_geoms(model, b):
            el = surface.geom_elements(model, int(g), size)
            rot = data.geom_xmat[g].reshape(3, 3)
            pts = data.geom_xpos[g] + el.centroids @ rot.T
            keep = np.ones(len(el), dtype=bool)
            for o in others:
                if o == g:
                    continue
                t = int(model.geom_type[o])
                local = (pts - data.geom_xpos[o]) @ data.geom_xmat[o].reshape(3, 3)
                hs = None
                if t == int(mujoco.mjtGeom.mjGEOM_MESH):
                    if o not in hulls:
                        m = int(model.geom_dataid[o])
                        va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
                        hulls[o] = occlusion.mesh_halfspaces(np.asarray(model.mesh_vert[va:va + vn], float))
                    hs = hulls[o]
                keep &= ~occlusion.inside_geom(local, t, model.geom_size[o], mesh_halfspaces=hs)
            whole += el.area()
            exposed += float(el.areas[keep].sum())
            v = np.tile(velocity, (int(keep.sum()), 1))
            f = law.element_forces(pts[keep], el.normals[keep] @ rot.T, el.areas[keep], v, MPM_VALIDATION,
                                   surface_z)
            total += f.sum(axis=0)
    return total, exposed, whole


def library(model, data, body_ids, dofs, speeds, *, cull: bool, surface_z: float = 0.0, resolution="default"):
    """The coupling's (total force (3,) N, exposed area m^2) at this pose, root dofs ``dofs`` moving at
    ``speeds`` (one evaluation of the published law, ``stabilize=False``)."""
    handle = attach(model, MPM_VALIDATION, body_ids, surface_z, resolution, stabilize=False, passive=False,
                    monitor=False, cull=cull)
    try:
        d = mujoco.MjData(model)
        d.qpos[:] = data.qpos
        d.qvel[:] = 0.0
        d.qvel[list(dofs)] = speeds
        mujoco.mj_forward(model, d)
        diag = handle.diagnostics(d)
        whole = sum(surface.body_elements(model, b, handle.element_size, cull=False).area() for b in body_ids)
        exposed = whole - float(handle.culled_area.sum()) - float(diag.occluded_area.sum())
        return diag.force.sum(axis=0).copy(), exposed
    finally:
        handle.detach()


def spin(model, data, body: int, dofs, speeds) -> np.ndarray:
    """(3,) rad/s, world frame: the angular velocity of ``body`` at ``data``'s pose with ``speeds`` on
    ``dofs`` (the motion of a case, whose bodies turn rigidly together)."""
    d = mujoco.MjData(model)
    d.qpos[:] = data.qpos
    d.qvel[list(dofs)] = speeds
    mujoco.mj_forward(model, d)
    vel = np.zeros(6)
    mujoco.mj_objectVelocity(model, d, mujoco.mjtObj.mjOBJ_BODY, body, vel, 0)
    return vel[3:]


def run_case(case: Case, size: float = REFERENCE_SIZE) -> list[dict]:
    """One row per motion of ``case``: library forces with and without culling against the reference."""
    model = _model(case)
    model.opt.gravity[:] = (0.0, 0.0, -9.81)
    data = _posed(case, model)
    ids = _body_ids(case, model)
    top = max(float(data.xpos[b][2]) for b in ids)
    z = top + DEPTH
    rows = []
    for motion, (dofs, speeds) in case.motions.items():
        f_ref, exposed_ref, whole = reference(model, data, ids, spin(model, data, ids[0], dofs, speeds), size, z)
        f_cull, exposed = library(model, data, ids, dofs, speeds, cull=True, surface_z=z)
        f_all, _ = library(model, data, ids, dofs, speeds, cull=False, surface_z=z)
        scale = float(np.linalg.norm(f_ref))
        rows.append(dict(case=case.name, motion=motion, bodies=len(ids), force_ref=f_ref.tolist(),
                         force=f_cull.tolist(), force_no_cull=f_all.tolist(),
                         error=float(np.linalg.norm(f_cull - f_ref) / scale),
                         error_no_cull=float(np.linalg.norm(f_all - f_ref) / scale),
                         overcount=float(np.linalg.norm(f_all) / scale),
                         hidden_fraction=1.0 - exposed_ref / whole, exposed_ref=exposed_ref, exposed=exposed,
                         area_error=abs(exposed - exposed_ref) / exposed_ref))
    return rows


def run(names=None, size: float = REFERENCE_SIZE) -> list[dict]:
    """Every case (or ``names``), as rows of :func:`run_case`."""
    return [r for n in (names or CASES) for r in run_case(CASES[n], size)]


def table_lines(rows) -> list[str]:
    """The table of :func:`run` rows (:func:`rft_mujoco.tables.table`), as lines."""
    return table(["case", "motion", "hidden", "|F| ref N", "err culled", "err no cull", "no cull/ref", "area err"],
                 [[r["case"], r["motion"], f"{100 * r['hidden_fraction']:.1f}%",
                   f"{np.linalg.norm(r['force_ref']):.4g}", f"{100 * r['error']:.2f}%",
                   f"{100 * r['error_no_cull']:.2f}%", f"{r['overcount']:.3f}", f"{100 * r['area_error']:.2f}%"]
                  for r in rows], align="<<>>>>>>").splitlines()
