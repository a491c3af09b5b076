"""Compile every kernel of the coupling once, for exactly the argument types the package passes (a tiny model,
two terrains). :func:`rft_mujoco.compiled.law.element_forces`, which the coupling does not use, compiles at
its first call."""

from __future__ import annotations

import mujoco
import numpy as np

from rft_mujoco.compiled import elements, evaluate, law, route
from rft_mujoco.compiled.terrain import terrain_spec
from rft_mujoco.geometry import surface
from rft_mujoco.physics import law as plaw
from rft_mujoco.physics import rest as prest
from rft_mujoco.physics.law import PUBLISHED
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface

_MODEL = """<mujoco><worldbody>
  <body name="a" pos="0 0 0.01"><freejoint/><geom type="sphere" size="0.03" mass="1"/>
    <body name="b" pos="0.04 0 0"><joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.1"/></body></body>
  <geom type="box" pos="0.3 0 0" size="0.02 0.02 0.02"/>
</worldbody></mujoco>"""


class _Groups:
    def __init__(self, n):
        self.of_body = np.arange(n, dtype=np.int64)
        self.ref = np.arange(n, dtype=np.int64)
        self.radius = np.full(n, 0.1)


def run() -> None:
    model = mujoco.MjModel.from_xml_string(_MODEL)
    data = mujoco.MjData(model)
    data.qvel[:] = 0.1
    mujoco.mj_forward(model, data)
    ids = np.array([1, 2], dtype=np.int64)
    parts = [surface.body_elements(model, int(b), 0.02) for b in ids]
    el = surface.Elements.concatenate(parts)
    elem_body = np.repeat(np.arange(2), [len(p) for p in parts])
    packed = elements.pack(el.centroids, el.normals, el.areas, elem_body, 2)
    occ = elements.occluders(model, ids)
    settings = np.array([prest.DEPENDENT_TOL, prest.WEIGHT_FLOOR, prest.CAPACITY_TOL, 1e-300])
    x = np.linspace(-1, 1, 3)
    for terrain in (FlatSurface(0.0), HeightfieldSurface(np.zeros((3, 3)), (-1, 1), (-1, 1))):
        spec = terrain_spec(terrain)
        for stabilize in (True, False):
            params = evaluate.params_array(0.0, 1.0, 0.4, PUBLISHED, spec[0], stabilize, True, 1e-6)
            hc = evaluate.handle_constants(model, ids, model.body_rootid[ids], _Groups(2), np.zeros((2, 3)),
                                           np.full(2, 0.2), packed, occ, spec, plaw.COEFFICIENTS,
                                           law.tolerances(), settings, params)
            ws = evaluate.build_workspace(2, 2, model.nv, elements.CLUSTER_SIZE)
            wt = tuple(ws[name] for name, _ in evaluate.WORK_FIELDS)
            md = evaluate.mjdata_arrays(data)
            sand = np.zeros((model.nbody, 6))
            evaluate.broadphase(md, hc, wt, 0.0, 0.002)
            wt[45][2] = 2.0
            evaluate.evaluate(md, hc, wt, data.xfrc_applied, 0.002, sand, evaluate.friction_arrays(data))
    del x
    try:
        route.warm_up(model, data)
    except RuntimeError:                             # no route here (route.efc_layout): the Python path runs
        pass
    from rft_mujoco.compiled import native  # noqa: F401  (compiles the native callbacks)
